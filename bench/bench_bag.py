"""What does writing a ROS 2 bag (``jaxvo run --out-bag``) cost a run?

**The run.** ``jaxvo run`` over the clip as its own process, without and with ``--out-bag``
(MCAP; odometry, tf, the dynamic masks and their camera), in pairs (off then on, then on then
off: the second run of a pair was faster on a busy machine), ``--reps`` pairs after one
warm-up pair (the step then loads from the compile cache): each run's steady
ms/frame from its summary (the main loop, reading and writing included; the bag is written on
its own thread behind it), the process's wall and CPU seconds (the bag's import, thread,
close and rename included). Each figure's ratio on / off is taken pair by pair, so that the
machine's speed drifting between pairs (it is shared) does not enter it; the report gives the
median and the spread of the ratios. The target: the bag costs at most a tenth of the steady
ms/frame.

**In this process.** ``Odometry.submit`` over the clip's frames (read beforehand), each
result's dynamic mask made (as ``--dynamic-masks`` makes it, in both arms) and, with the
bag, its pose and mask given to a :class:`jaxvo.host.writers.bagout.BagWriter`, in pairs whose order
alternates: the steady ms/frame as the summary counts it and the ratio pair by pair, the
bag's ``finish`` apart. No reading or PNG writing here, so less of the machine's noise.

**The writer alone.** In this process, :class:`jaxvo.host.writers.bagout.BagWriter` fed the clip's
frames (poses and masks of one run): the first call apart (the writer made: its message
definitions, the temporary folder, the file opened; and the first frame's connections), then
the steady ms/frame of the rest, its ``finish`` (close and rename) included, for each storage.
This is the work the bag's thread does beside the run: its CPU time (this process's, the
thread's included; less noisy than the clock on a shared machine), also as a share of the
run's steady ms/frame.

Run: ``.venv/bin/python bench/bench_bag.py [--reps 5] [--sequence NAME] [--out results/]``;
writes ``bag.md`` and ``bag.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import TUM_WALKING, load_average, log, machine, machine_line, markdown_table

from jaxvo.host.readers.io import InMemorySequence, data_root, open_sequence
from jaxvo.trajectory import read_trajectory

TARGET = 0.10  # the bag may add this share of the steady ms/frame


def cli_run(folder: Path, tmp: Path, bag: bool) -> dict:
    """One ``jaxvo run`` process: its summary's steady ms/frame, wall and CPU seconds."""
    target = tmp / "run_bag"
    shutil.rmtree(target, ignore_errors=True)  # a bag is written into a new folder only
    cmd = [sys.executable, "-m", "jaxvo.cli.main", "run", str(folder), "--out",
           str(tmp / "traj.txt"), "--dynamic-masks", str(tmp / "dyn"), "-q", "--json"]
    cmd += ["--out-bag", str(target)] if bag else []
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    summary = json.loads(done.stdout)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    row = {"ms_per_frame": 1e3 / summary["frames_per_second"], "wall_s": wall, "cpu_s": cpu,
           "frames": summary["poses_written"]}
    if bag:
        row["bag_mib"] = sum(p.stat().st_size for p in target.iterdir()) / 2**20
        row["bag_messages"] = summary["bag_messages"]
    return row


def run_cost(folder: Path, reps: int) -> dict:
    """``--reps`` pairs (off, on) after a warm-up pair; per figure the pairs' ratios."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        cli_run(folder, tmp, False)  # warm-up: the step into the compile cache
        cli_run(folder, tmp, True)
        pairs = []
        for rep in range(reps):
            if rep % 2:
                on, off = cli_run(folder, tmp, True), cli_run(folder, tmp, False)
            else:
                off, on = cli_run(folder, tmp, False), cli_run(folder, tmp, True)
            pairs.append({"off": off, "on": on, "load": load_average()})
            log(f"pair {rep}: steady {off['ms_per_frame']:.2f} / {on['ms_per_frame']:.2f} "
                f"ms/frame, wall {off['wall_s']:.2f} / {on['wall_s']:.2f} s, load "
                f"{pairs[-1]['load']}")
    ratios = {m: [p["on"][m] / p["off"][m] for p in pairs]
              for m in ("ms_per_frame", "wall_s", "cpu_s")}
    return {"pairs": pairs, "ratios": ratios,
            "median": {k: {m: float(np.median([p[k][m] for p in pairs]))
                           for m in ("ms_per_frame", "wall_s", "cpu_s")} for k in ("off", "on")}}


def in_process(seq, bag_dir: Path | None) -> dict:
    """``Odometry.submit`` over ``seq``, each result's dynamic mask made, and its pose and
    mask written to a bag in ``bag_dir`` (None: no bag): the steady ms/frame as the run's
    summary counts it (each frame's submit and its writes, from the third frame on), and
    the bag's ``finish`` apart. The bag is opened half a second before the first frame, as
    the run's first frame (its step loaded) gives it time to."""
    from jaxvo.host.writers.bagout import BagWriter
    from jaxvo.host.writers.masks import dynamic_pixels
    from jaxvo.host.writers.plugin import mask_png
    from jaxvo.odometry import Odometry

    odo = Odometry(seq.intrinsics)
    bag = None if bag_dir is None else BagWriter(bag_dir / "bag", seq)
    time.sleep(0.5)
    frames, times = {}, []

    def record(r) -> None:
        f = frames.pop(r.index)
        if r.dropped is not None:
            return
        mask = (None if r.output is None else
                mask_png(dynamic_pixels(r.output.dynamic, seq.height, seq.width, 16)))
        if bag is not None:
            bag.write_pose(f.index, r.T_w_c)
            if mask is not None:
                bag.write_mask(f, mask)

    for k, f in enumerate(seq):
        t0 = time.perf_counter()
        frames[k] = f
        r = odo.submit(f.bgr, f.depth, f.timestamp)
        if r is not None:
            record(r)
        times.append(time.perf_counter() - t0)
    r = odo.flush()
    if r is not None:
        record(r)
    t0 = time.perf_counter()
    if bag is not None:
        bag.finish()
    return {"ms_per_frame": 1e3 * float(np.mean(times[2:])),
            "finish_s": time.perf_counter() - t0}


def in_process_cost(seq, reps: int) -> dict:
    """``reps`` pairs of :func:`in_process` without and with the bag, order alternating,
    after a warm-up pair (the step compiled in this process)."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)

        def one(bag: bool, k: int) -> dict:
            folder = tmp / f"{k}_{bag}"
            folder.mkdir()
            return in_process(seq, folder if bag else None)

        one(False, -1), one(True, -1)
        pairs = []
        for k in range(reps):
            if k % 2:
                on, off = one(True, k), one(False, k)
            else:
                off, on = one(False, k), one(True, k)
            pairs.append({"off": off, "on": on, "load": load_average()})
            log(f"in process {k}: {off['ms_per_frame']:.2f} / {on['ms_per_frame']:.2f} "
                f"ms/frame, finish {on['finish_s']:.3f} s")
    return {"pairs": pairs,
            "ratios": [p["on"]["ms_per_frame"] / p["off"]["ms_per_frame"] for p in pairs],
            "median": {k: float(np.median([p[k]["ms_per_frame"] for p in pairs]))
                       for k in ("off", "on")},
            "finish_s": float(np.median([p["on"]["finish_s"] for p in pairs]))}


def writer_cost(seq, traj, masks: Path, storage: str, repeats: int = 3) -> dict:
    """The writer alone, in this process: a bag of the first frame alone, cold (the first
    call: rosbags imported, the writer made, its message definitions and serialisers, close
    and rename), then ``repeats`` times a bag of one frame and a bag of every frame, whose
    CPU time (this process's, the bag's thread included: on a shared machine less noisy than
    the clock) beyond the one-frame bag's is the steady cost of a frame; the wall time too."""
    import cv2

    from jaxvo.host.writers.bagout import BagWriter

    frames = [seq[i] for i in range(len(traj))]
    png = {p.name: cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in masks.glob("*.png")}

    def bag_of(n: int, folder: Path) -> tuple[float, float]:
        t0, c0 = time.perf_counter(), time.process_time()
        bag = BagWriter(folder, seq, storage=storage)
        for f, T in zip(frames[:n], traj.poses[:n]):
            bag.write_pose(f.index, T)
            bag.write_mask(f, png[f"{f.timestamp:.6f}.png"])
        bag.finish()
        return time.perf_counter() - t0, time.process_time() - c0

    with tempfile.TemporaryDirectory() as tmp:
        first = bag_of(1, Path(tmp) / "first")[0]
        cpu, wall = [], []
        for k in range(repeats):
            one, whole = bag_of(1, Path(tmp) / f"one{k}"), bag_of(len(frames), Path(tmp) / f"all{k}")
            wall.append(1e3 * (whole[0] - one[0]) / (len(frames) - 1))
            cpu.append(1e3 * (whole[1] - one[1]) / (len(frames) - 1))
    return {"first_s": first, "cpu_ms_per_frame": float(np.median(cpu)),
            "wall_ms_per_frame": float(np.median(wall)), "cpu_runs": cpu, "wall_runs": wall}


def report(name: str, run: dict, inproc: dict, writers: dict) -> list[str]:
    m, r = run["median"], run["ratios"]

    def spread(v):
        return f"{np.median(v):.3f} ({min(v):.3f} to {max(v):.3f})"

    first = run["pairs"][0]["on"]
    L = ["# What writing a ROS 2 bag costs `jaxvo run`", "", machine_line(), "",
         (f"`{name}`, {first['frames']} frames, 640x480; the bag: {first['bag_messages']} "
          f"messages, {first['bag_mib']:.1f} MiB (MCAP). {len(run['pairs'])} pairs of "
          "processes, without then with `--out-bag`, after a warm-up pair; both write the "
          "trajectory and `--dynamic-masks`. Ratio: on / off of each pair, median (min to "
          "max) over the pairs."), "",
         markdown_table(["", "without (median)", "with --out-bag (median)",
                         "ratio on / off, per pair"],
                        [["steady ms/frame (summary)", f"{m['off']['ms_per_frame']:.2f}",
                          f"{m['on']['ms_per_frame']:.2f}", spread(r["ms_per_frame"])],
                         ["process wall s", f"{m['off']['wall_s']:.2f}",
                          f"{m['on']['wall_s']:.2f}", spread(r["wall_s"])],
                         ["process CPU s", f"{m['off']['cpu_s']:.2f}", f"{m['on']['cpu_s']:.2f}",
                          spread(r["cpu_s"])]]), "",
         (f"The bag's cost on the steady ms/frame: {100 * (np.median(r['ms_per_frame']) - 1):.1f} "
          f"% (median of the pairs; target at most {100 * TARGET:.0f} %). Load average per "
          f"pair: {[p['load'] for p in run['pairs']]}."
          + (" The machine was busier than its cores (load above them): the clock's ratios "
             "spread widely, and the CPU seconds are the steadier measure."
             if max(p["load"][0] for p in run["pairs"]) > (os.cpu_count() or 1) else "")), "",
         markdown_table(["in this process (frames read beforehand)", "without (median)",
                         "with the bag (median)", "ratio on / off, per pair"],
                        [["steady ms/frame (Odometry.submit and the writes)",
                          f"{inproc['median']['off']:.2f}", f"{inproc['median']['on']:.2f}",
                          spread(inproc["ratios"])]]), "",
         (f"The bag's `finish` (close and rename) after the frames: "
          f"{inproc['finish_s']:.3f} s (median)."), "",
         "The writer alone (this process; the bag's thread's work, beside the run):", "",
         markdown_table(["storage", "first call s (a bag of one frame, cold)",
                         "steady CPU ms/frame (odometry, tf, mask, camera info)",
                         "steady wall ms/frame", "CPU share of the run's steady ms/frame"],
                        [[k, f"{v['first_s']:.3f}", f"{v['cpu_ms_per_frame']:.2f}",
                          f"{v['wall_ms_per_frame']:.2f}",
                          f"{v['cpu_ms_per_frame'] / m['off']['ms_per_frame']:.3f}"]
                         for k, v in writers.items()]),
         "", ("Steady: a bag of every frame less a bag of one, per frame beyond the first "
              "(finish included), median of 3; the share: over the runs' steady ms/frame "
              "without the bag (median)."), ""]
    return L


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=5, help="pairs of runs (default 5)")
    ap.add_argument("--sequence", default=TUM_WALKING, metavar="NAME",
                    help="the data root's sequence (default the TUM clip)")
    ap.add_argument("--out", default="results", help="folder for bag.md / bag.json")
    args = ap.parse_args(argv)
    folder = data_root() / args.sequence
    if not (folder / "rgb.txt").is_file():
        print(f"bench_bag: {folder} not found (set JAXVO_DATA); nothing timed")
        return 0
    run = run_cost(folder, args.reps)
    seq = open_sequence(folder)
    inproc = in_process_cost(InMemorySequence(seq), args.reps)
    with tempfile.TemporaryDirectory() as tmp:  # one run's poses and masks for the writer
        tmp = Path(tmp)
        subprocess.run([sys.executable, "-m", "jaxvo.cli.main", "run", str(folder), "--out",
                        str(tmp / "t.txt"), "--dynamic-masks", str(tmp / "dyn"), "-q"],
                       check=True, capture_output=True)
        traj = read_trajectory(tmp / "t.txt")
        writers = {s: writer_cost(seq, traj, tmp / "dyn", s) for s in ("mcap", "sqlite3")}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bag.json").write_text(json.dumps(
        {"machine": machine(), "sequence": args.sequence, "run": run, "in_process": inproc,
         "writer": writers,
         "load_average_end": load_average()}, indent=1))
    L = report(args.sequence, run, inproc, writers)
    (out / "bag.md").write_text("\n".join(L))
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
