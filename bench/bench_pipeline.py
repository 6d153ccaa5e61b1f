"""Real-time headroom of the odometry (issue 20's table), every row measured in one run.

On the 300 real 7-Scenes frames of the data root (a synthetic 300-frame sequence written to
a temporary folder when they are absent), on this machine:

1. ``jaxvo run`` as a child process, as a user runs it: steady ms per frame (reading and
   writing included, as its summary reports it), the whole process's wall time on the first
   run on the machine (a fresh compile-cache folder: the step compiles) and on later runs
   (the step loaded from that cache), its first frame pair's time (the compile or the load),
   its ATE;
2. OpenCV's RGB odometry (``jaxvo.host.services.peers``) the same ways: a child process reading the same
   folder, for the whole-process ratio, and in this process on the same frames preloaded,
   for the per-frame ratio;
3. in this process, on the frames preloaded: ``Odometry.process`` per frame (median, p90;
   the first pair, which compiles, apart) and the pipelined ``Odometry.submit``;
4. the whole-sequence ``lax.scan`` (``run_scan``) from precomputed flow: frames per second,
   the compile apart.

Only public APIs are used (``jaxvo run``, ``Odometry``, ``run_scan``, ``run_peer``), so the
bench measures whatever the per-frame step is. This process runs without the persistent
compile cache (its compiles are timed as compiles); the machine, JAX's version and device
and the load average before and after are recorded. Writes ``pipeline.json`` and
``pipeline.md`` under ``--out``; ``bench/readme_speed.py`` turns the JSON into the speed
paragraph of ``docs/speed.md``.

Usage: ``python bench/bench_pipeline.py [--warm-runs 3] [--out results/]``
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SEVEN_SCENES, data_name, load_average, log, machine

from jaxvo.config import Config, Params, grid_shape, params_as_arrays
from jaxvo.core.pipeline import run_scan
from jaxvo.host.frontend.flow import sequence_flows
from jaxvo.host.readers.io import InMemorySequence, data_root, open_sequence
from jaxvo.host.services.peers import run_peer
from jaxvo.odometry import Odometry
from jaxvo.synth.scenes import make_sequence, write_sequence

FRAMES = 300
PEER = "opencv_rgb"

# The targets, each with the row it applies to (README and report say them so).
TARGETS = {
    "run_ms_per_frame_vs_peer": 1 / 3,  # jaxvo run steady ms/frame <= 1/3 of the peer's
    "run_process_warm_vs_peer": 1 / 2,  # whole process, later runs, <= 1/2 of the peer's
    "first_pair_cold_s": 5.0,
    "first_pair_warm_s": 2.0,
    "process_median_ms": 5.8,
    "submit_median_ms": 4.0,
    "scan_frames_per_second": 1000.0,
}

# The peer over a folder as a process of its own, as a user would run it.
PEER_CHILD = (
    "import sys; from jaxvo.host.readers.io import open_sequence; from jaxvo.host.services.peers import run_peer; "
    f"run_peer(open_sequence(sys.argv[1]), {PEER!r})"
)


def sequence_folder(tmp: str) -> Path:
    """The 7-Scenes frames, else a synthetic sequence of as many frames written to ``tmp``."""
    seq_dir = data_root() / SEVEN_SCENES
    if (seq_dir / "associations.txt").is_file():
        return seq_dir
    seq_dir = Path(tmp) / "synthetic_300"
    write_sequence(make_sequence("handheld_slow", frames=FRAMES, seed=0), seq_dir)
    return seq_dir


CFG = Config()  # the settings of every jaxvo run here (--keyframes: everything on)


def child_env() -> dict:
    return dict(os.environ, JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu"))


def jaxvo_run(seq_dir: Path, out: Path, cache: Path) -> dict:
    """One ``jaxvo run`` child with the compile cache in ``cache``: its JSON summary, its
    wall time, and whether it said that it compiled."""
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "jaxvo.cli.main", "run", str(seq_dir), "--out", str(out),
         "--json", "--frames", str(FRAMES), "--compile-cache", str(cache),
         "--keyframes" if CFG.keyframes else "--no-keyframes"],
        capture_output=True, text=True, check=False, env=child_env(),
    )
    wall = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"jaxvo run failed ({proc.returncode}): {proc.stderr[-2000:]}")
    summary = json.loads(proc.stdout)
    fps = summary["frames_per_second"]
    return {
        "process_s": round(wall, 2),
        "steady_ms_per_frame": round(1e3 / fps, 2) if fps else None,
        "first_pair_s": summary["first_frame_pair_seconds"],
        "compile": summary["compile"],
        "said_compiling": "jaxvo: compiling" in proc.stderr,
        "ate_rmse_m": summary.get("ate_rmse_m"),
        "peak_rss_mib": summary["peak_rss_mib"],
    }


def bench_cli(seq_dir: Path, tmp: str, *, warm_runs: int) -> dict:
    """``jaxvo run`` once on a fresh compile-cache folder (cold), then ``warm_runs`` times on
    it (warm); medians of the warm runs."""
    cache = Path(tmp) / "compile_cache"
    out = Path(tmp) / "traj.txt"
    cold = jaxvo_run(seq_dir, out, cache)
    log(f"jaxvo run, first run on the machine (cold compile cache): {cold}")
    warm = []
    for k in range(warm_runs):
        warm.append(jaxvo_run(seq_dir, out, cache))
        log(f"jaxvo run, later run {k + 1} (warm compile cache): {warm[-1]}")

    def med(key):
        return round(float(np.median([w[key] for w in warm])), 3)

    return {
        "cold": cold,
        "warm_runs": warm,
        "warm_median": {k: med(k) for k in ("process_s", "steady_ms_per_frame", "first_pair_s")},
    }


def bench_peer_process(seq_dir: Path, *, runs: int) -> dict:
    """The peer over the folder as a child process: wall seconds, median of ``runs``."""
    walls = []
    for _ in range(runs):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", PEER_CHILD, str(seq_dir)], check=True,
                       capture_output=True, env=child_env())
        walls.append(time.perf_counter() - t0)
    return {"process_s": round(float(np.median(walls)), 2),
            "process_s_runs": [round(w, 2) for w in walls]}


def bench_streaming(frames: list, K, *, pipelined: bool) -> dict:
    """Per-frame wall time of ``Odometry.process`` (latency: the frame's pose is back when
    the call returns), or of ``Odometry.submit`` (throughput: the call returns the previous
    frame's result while this frame's device step keeps running). A fresh ``Odometry``; the
    step compiles on the first pair's call unless this process compiled it already."""
    odo = Odometry(K, cfg=CFG, seed=0)
    call = odo.submit if pipelined else odo.process
    times = []
    for f in frames:
        t0 = time.perf_counter()
        call(f.bgr, f.depth, f.timestamp)
        times.append(time.perf_counter() - t0)
    odo.flush()
    steady = np.asarray(times[3:]) * 1e3
    return {
        "first_pair_s": round(max(times[1:3]), 3),
        "median_ms_per_frame": round(float(np.median(steady)), 2),
        "p90_ms_per_frame": round(float(np.percentile(steady, 90)), 2),
        "frames": len(frames),
    }


def bench_scan(seq, cfg: Config, *, repeats: int = 5) -> dict:
    """``run_scan`` over the sequence's precomputed flow: the first call (compile) apart,
    then the median of ``repeats`` calls."""
    chain = sequence_flows(seq, cfg)
    flows = jax.tree.map(jnp.asarray, chain.flows)
    kfs = None if chain.keyframes is None else jax.tree.map(jnp.asarray, chain.keyframes)
    grid = grid_shape(seq.height, seq.width, cfg.cell)
    p = params_as_arrays(Params())
    T0 = jnp.eye(4, dtype=jnp.float32)
    t0 = time.perf_counter()
    jax.block_until_ready(run_scan(flows, jax.random.key(0), p, T0, cfg=cfg.step, grid=grid,
                                   keyframes=kfs))
    compile_s = time.perf_counter() - t0
    runs = []
    for r in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(run_scan(flows, jax.random.key(r), p, T0, cfg=cfg.step, grid=grid,
                                       keyframes=kfs))
        runs.append(time.perf_counter() - t0)
    n = int(flows.valid.shape[0])
    med = float(np.median(runs))
    return {
        "pairs": n,
        "first_call_s": round(compile_s, 2),
        "frames_per_second": round(n / med, 1),
        "best_frames_per_second": round(n / min(runs), 1),
    }


def headline(res: dict) -> dict:
    """The issue's table from the measurements: each row's figure, target and ratio."""
    cli, peer = res["jaxvo_run"], res["peer"]
    run_ms = cli["warm_median"]["steady_ms_per_frame"]
    rows = {
        "run_ms_per_frame": run_ms,
        "peer_ms_per_frame": peer["ms_per_frame_preloaded"],
        "run_ms_per_frame_vs_peer": round(run_ms / peer["ms_per_frame_preloaded"], 3),
        "run_process_cold_s": cli["cold"]["process_s"],
        "run_process_warm_s": cli["warm_median"]["process_s"],
        "peer_process_s": peer["process_s"],
        "run_process_cold_vs_peer": round(cli["cold"]["process_s"] / peer["process_s"], 3),
        "run_process_warm_vs_peer": round(cli["warm_median"]["process_s"] / peer["process_s"],
                                          3),
        "first_pair_cold_s": cli["cold"]["first_pair_s"],
        "first_pair_warm_s": cli["warm_median"]["first_pair_s"],
        "said_compiling_cold": cli["cold"]["said_compiling"],
        "said_compiling_warm": any(w["said_compiling"] for w in cli["warm_runs"]),
        "process_first_pair_s": res["process"]["first_pair_s"],
        "scan_first_call_s": res["scan"]["first_call_s"],
        "process_median_ms": res["process"]["median_ms_per_frame"],
        "process_p90_ms": res["process"]["p90_ms_per_frame"],
        "submit_median_ms": res["submit"]["median_ms_per_frame"],
        "scan_frames_per_second": res["scan"]["frames_per_second"],
        "ate_rmse_m": cli["cold"]["ate_rmse_m"],
    }
    met = {}
    for key, target in TARGETS.items():
        value = rows[key]
        met[key] = bool(value >= target) if key == "scan_frames_per_second" else bool(
            value <= target)
    rows["targets"] = TARGETS
    rows["met"] = met
    return rows


def markdown(res: dict) -> str:
    """The report: the issue's table with this run's figures, then the details."""
    h, m, met = res["headline"], res["machine"], res["headline"]["met"]

    def ok(*keys: str) -> str:
        return ", ".join("yes" if met[k] else "no" for k in keys)

    rows = [
        (f"`jaxvo run`, {FRAMES} frames, steady ms/frame (reading, writing included)",
         (f"{h['run_ms_per_frame']} ms = {h['run_ms_per_frame_vs_peer']:.2f} x the peer's "
         f"{h['peer_ms_per_frame']} ms (frames preloaded)"),
         "<= 1/3 of the peer's", ok("run_ms_per_frame_vs_peer")),
        (f"`jaxvo run` whole process, {FRAMES} frames",
         (f"first run {h['run_process_cold_s']} s ({h['run_process_cold_vs_peer']:.2f} x), "
         f"later runs {h['run_process_warm_s']} s ({h['run_process_warm_vs_peer']:.2f} x the "
         f"peer's {h['peer_process_s']} s)"),
         "later runs <= 1/2 of the peer's", ok("run_process_warm_vs_peer")),
        ("first pose of a run (compile)",
         (f"`jaxvo run` first pair {h['first_pair_cold_s']} s on the first run, "
         f"{h['first_pair_warm_s']} s later (step from the compile cache); in process: step "
         f"{h['process_first_pair_s']} s, scan {h['scan_first_call_s']} s"),
         "first run <= 5 s, later <= 2 s", ok("first_pair_cold_s", "first_pair_warm_s")),
        ("`Odometry.process` median / p90",
         f"{h['process_median_ms']} / {h['process_p90_ms']} ms", "median <= 5.8 ms",
         ok("process_median_ms")),
        ("`Odometry.submit` median", f"{h['submit_median_ms']} ms", "<= 4 ms",
         ok("submit_median_ms")),
        ("whole-sequence scan from precomputed flow", f"{h['scan_frames_per_second']} frames/s",
         ">= 1000 frames/s", ok("scan_frames_per_second")),
    ]
    said = {True: "yes", False: "no"}
    lines = [
        "# Real-time headroom (`bench/bench_pipeline.py`)",
        "",
        (f"{res['date']}; {m['cpu_model']}, {m['cores']} cores; {m['platform']}; JAX "
         f"{m['jax']} ({', '.join(m['jax_devices'])}); OpenCV {m['opencv']}; load average "
         f"{m['load_average_start']} at the start, {res['load_average_end']} at the end."),
        (f"Sequence: `{res['sequence']}`, {FRAMES} frames; the peer is OpenCV's RGB odometry "
         f"(`{PEER}`), timed per pair as `run_peer` times it. jaxvo's keyframes and their "
         f"window: {'on' if res.get('keyframes') else 'off'}."),
        "",
        "| measure | this run | target | met |",
        "|---|---|---|---|",
        *("| " + " | ".join(row) + " |" for row in rows),
        "",
        (f"`jaxvo run` ATE on this sequence: {h['ate_rmse_m']} m rmse. It said that it was "
         f"compiling on the first run: {said[h['said_compiling_cold']]}; on a later run: "
         f"{said[h['said_compiling_warm']]}."),
        "",
        ("Every `jaxvo run` (child processes; `process_s` is the parent's wall clock around "
         "the child):"),
        "",
        "```json",
        json.dumps(res["jaxvo_run"], indent=1),
        "```",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--warm-runs", type=int, default=3,
                    help="jaxvo run children after the first (warm compile cache)")
    ap.add_argument("--peer-runs", type=int, default=2, help="peer child processes")
    ap.add_argument("--out", default="results", help="folder for pipeline.json / .md")
    ap.add_argument("--keyframes", action="store_true",
                    help="everything on: keyframes and their window (jaxvo run --keyframes)")
    args = ap.parse_args()
    global CFG
    CFG = Config(keyframes=args.keyframes)
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)

    res = {"date": datetime.datetime.now().isoformat(timespec="seconds"),
           "machine": machine(), "frames": FRAMES, "keyframes": CFG.keyframes}
    log(f"machine: {res['machine']}")
    with tempfile.TemporaryDirectory() as tmp:
        seq_dir = sequence_folder(tmp)
        res["sequence"] = data_name(seq_dir)  # under the data root, else synthetic_300
        res["jaxvo_run"] = bench_cli(seq_dir, tmp, warm_runs=args.warm_runs)
        res["peer"] = bench_peer_process(seq_dir, runs=args.peer_runs)
        log(f"{PEER} as a process: {res['peer']}")
        mem = InMemorySequence(open_sequence(seq_dir), FRAMES)  # read up front: untimed
        frames = list(mem)
        res["peer"]["ms_per_frame_preloaded"] = round(run_peer(mem, PEER).ms_per_frame, 2)
        log(f"{PEER} in process, frames preloaded: {res['peer']['ms_per_frame_preloaded']} ms")
        res["process"] = bench_streaming(frames, mem.intrinsics, pipelined=False)
        log(f"Odometry.process: {res['process']}")
        res["submit"] = bench_streaming(frames, mem.intrinsics, pipelined=True)
        log(f"Odometry.submit: {res['submit']}")
        res["scan"] = bench_scan(mem, CFG)
        log(f"run_scan from precomputed flow: {res['scan']}")
    res["load_average_end"] = load_average()
    res["headline"] = headline(res)
    (out_dir / "pipeline.json").write_text(json.dumps(res, indent=1) + "\n")
    (out_dir / "pipeline.md").write_text(markdown(res))
    print(markdown(res))
    log(f"wrote {out_dir / 'pipeline.json'} and {out_dir / 'pipeline.md'}")


if __name__ == "__main__":
    main()
