"""ORB-SLAM3 alone, with jaxvo's dynamic masks (streaming), and with hand-drawn masks.

ORB-SLAM3 runs in its own process (``bench/orbslam3_peer.py``; pyorbslam3 is GPL-3.0 and
optional: without it this prints why and exits 0). jaxvo's masks reach it as a robot would
give them: ``jaxvo.Odometry.process`` frame by frame, each frame handed to the peer one
frame late with its dynamic pixels (``orbslam3_peer.streaming_keep``); the OpenCV peers get
them the same way. ORB-SLAM3 is multi-threaded and not deterministic, so each ORB-SLAM3
configuration runs ``--repeats`` times and the report gives the median and the range.

* **dev** (``bench/splits.py``: tuned on): the composites on 7-Scenes frames 0-149 and the
  static frames 0-149; ORB-SLAM3 alone and with jaxvo's masks taken out of its input in each
  way of ``orbslam3_peer.VARIANTS`` (depth only, colour too, grown masks). The masks come
  from one streaming pass per case (jaxvo is deterministic: the same masks as a live loop),
  so every variant sees the same masks. The variant with the lowest geometric mean of
  ATE(variant) / ATE(alone) over the cases is the one to set as ``orbslam3_peer.CHOSEN``.
* **val** (never tuned on), with ``CHOSEN``, each ORB-SLAM3 x jaxvo run a live loop (a
  fresh ``Odometry`` each): the TUM walking clip, which has no ground truth: every
  trajectory's distance (ATE after rigid alignment) from a *reference*, ORB-SLAM3 with the
  depth under the hand-drawn people masks (``bench/people_masks.py``) set to 0: the medoid
  of ``REFERENCE_RUNS`` such runs made apart from the rows; the 300 static 7-Scenes frames (ATE, ground truth); the composites
  on frames 150-299 (ATE; ORB-SLAM3 with the true object masks as the upper bound).

Run: ``.venv/bin/python bench/bench_orbslam3.py [--split dev|val|all] [--repeats 3]
[--only CASE ...] [--out results/]``. Writes ``orbslam3.md`` and ``orbslam3.json``.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import orbslam3_peer as orb
from _common import SEVEN_SCENES, TUM_WALKING, load_average, log, machine, markdown_table
from splits import available, cases

import jaxvo
from jaxvo.evaluation.scores import trajectory_scores
from jaxvo.host.readers.io import InMemorySequence, data_root, first_pose, open_sequence
from jaxvo.host.services.peers import OPENCV_PEERS, run_peer

ALONE = "ORB-SLAM3"
# ORB-SLAM3 runs that make the TUM clip's reference (their medoid: the run with the least
# median distance from the others, so that the reference is not one run's own wander)
REFERENCE_RUNS = 5
DEV_STATIC = "static_dev_every1"  # the static dev case (every 2nd / 4th frame left out: CPU)


def _odometry(seq):
    return jaxvo.Odometry(seq.intrinsics, seed=0, T_w_c0=first_pose(seq))


def error_m(target, traj) -> float:
    """ATE RMSE of ``traj`` against ``target`` (ground truth or the reference), metres."""
    return float(trajectory_scores(target, traj)["ate_rmse_m"])


def jaxvo_pass(seq):
    """jaxvo streaming over ``seq``: its trajectory, each frame's mask, its ms per frame
    (median, the first two frames apart: the first compiles) and the first frame's ms."""
    odo = _odometry(seq)
    masks, ms = [], []
    stream = orb.streaming_masks(seq, odo)
    while True:
        t0 = time.perf_counter()
        try:
            _, mask = next(stream)
        except StopIteration:
            break
        ms.append(1e3 * (time.perf_counter() - t0))
        masks.append(mask)
    # the first item waits for frames 0 and 1 (the compile), the last for no frame
    return odo.trajectory, masks, {"ms_per_frame": float(np.median(ms[1:-1])),
                                   "first_ms": ms[0]}


def orb_rows(seq, target, keep_of, masking, repeats: int) -> dict:
    """ORB-SLAM3 ``repeats`` times (``keep_of()`` gives each run's keep, or None)."""
    runs = []
    for _ in range(repeats):
        peer, run = orb.run_orbslam3(seq, keep=keep_of(), masking=masking)
        runs.append({"error_m": error_m(target, peer.trajectory), "ms_per_frame": run.ms_per_frame,
                     "first_ms": float(run.ms[0]), "load_s": run.load_s,
                     "tracked": len(peer.trajectory), "not_ok": run.lost})
    errs = [r["error_m"] for r in runs]
    return {"masking": masking.name, "runs": runs, "error_m": float(np.median(errs)),
            "error_min_m": min(errs), "error_max_m": max(errs),
            "ms_per_frame": float(np.median([r["ms_per_frame"] for r in runs]))}


def opencv_rows(seq, target, keep_of) -> dict:
    """Each OpenCV peer once alone and once with jaxvo's masks (they are deterministic)."""
    out = {}
    for kind in OPENCV_PEERS:
        for name, keep in ((kind, None), (f"{kind} x jaxvo", keep_of())):
            r = run_peer(seq, kind, keep=keep)
            out[name] = {"error_m": error_m(target, r.trajectory), "ms_per_frame": r.ms_per_frame}
    return out


def dev_case(case, repeats: int) -> dict:
    seq = case.build()
    log(f"{case.name}: jaxvo streaming pass ({len(seq)} frames)")
    traj, masks, timing = jaxvo_pass(seq)
    gt = seq.groundtruth
    res = {"frames": len(seq), "jaxvo": {"error_m": error_m(gt, traj), **timing},
           "dynamic_pct": 100.0 * float(np.mean(masks))}
    log(f"{case.name}: ORB-SLAM3 alone x{repeats}")
    res[ALONE] = orb_rows(seq, gt, lambda: None, orb.CHOSEN, repeats)
    for v in orb.VARIANTS:
        log(f"{case.name}: ORB-SLAM3 x jaxvo, {v.name} x{repeats}")
        res[f"{ALONE} x jaxvo, {v.name}"] = orb_rows(
            seq, gt, lambda: (lambda i: ~masks[i]), v, repeats)
    return res


def val_case(name, seq, target, repeats: int, *, truth_keep=None, reference=None) -> dict:
    log(f"{name}: jaxvo streaming pass ({len(seq)} frames)")
    traj, masks, timing = jaxvo_pass(seq)
    res = {"frames": len(seq), "jaxvo": {"error_m": error_m(target, traj), **timing},
           "dynamic_pct": 100.0 * float(np.mean(masks)), "masking": orb.CHOSEN.name}
    if reference is not None:
        res["reference"] = reference
    log(f"{name}: ORB-SLAM3 alone x{repeats}")
    res[ALONE] = orb_rows(seq, target, lambda: None, orb.CHOSEN, repeats)
    log(f"{name}: ORB-SLAM3 x jaxvo (live loop), x{repeats}")
    res[f"{ALONE} x jaxvo"] = orb_rows(
        seq, target, lambda: orb.streaming_keep(seq, _odometry(seq)), orb.CHOSEN, repeats)
    if truth_keep is not None:
        label, keep = truth_keep
        log(f"{name}: ORB-SLAM3 x {label} x{repeats}")
        res[f"{ALONE} x {label}"] = orb_rows(seq, target, lambda: keep, orb.CHOSEN, repeats)
    log(f"{name}: OpenCV peers alone and x jaxvo (live loop)")
    res["opencv"] = opencv_rows(seq, target, lambda: orb.streaming_keep(seq, _odometry(seq)))
    return res


def people_reference(seq, hand):
    """The TUM clip's reference: the medoid of :data:`REFERENCE_RUNS` runs of ORB-SLAM3 with
    the depth under the hand-drawn people masks (``hand(i)``: keep) set to 0; returns its
    trajectory and what the report says of it (the others' distances from it)."""
    log(f"tum_walking: the reference, the medoid of {REFERENCE_RUNS} runs of ORB-SLAM3 "
        "with the depth under the hand-drawn people masks set to 0")
    refs = [orb.run_orbslam3(seq, keep=hand, masking=orb.Masking(False, 0))[0].trajectory
            for _ in range(REFERENCE_RUNS)]
    dist = np.array([[error_m(a, b) if a is not b else 0.0 for b in refs] for a in refs])
    medoid = int(np.argmin(np.median(dist, axis=1)))
    return refs[medoid], {"masking": "depth", "runs": REFERENCE_RUNS,
                          "tracked": len(refs[medoid]),
                          "others_from_it_m": [float(x) for j, x in enumerate(dist[medoid])
                                               if j != medoid]}


def val_cases(repeats: int, only) -> dict:
    from people_masks import people_masks

    out = {}
    want = (lambda n: True) if not only else (lambda n: n in only)
    if want("tum_walking") and (data_root() / TUM_WALKING).is_dir():
        seq = InMemorySequence(open_sequence(data_root() / TUM_WALKING))
        people = people_masks(data_root() / TUM_WALKING)
        hand = lambda i: ~people[i]
        ref, reference = people_reference(seq, hand)
        out["tum_walking"] = val_case(
            "tum_walking", seq, ref, repeats, truth_keep=("hand-drawn masks", hand),
            reference=reference)
    if want("7scenes_static_300") and (data_root() / SEVEN_SCENES).is_dir():
        seq = InMemorySequence(open_sequence(data_root() / SEVEN_SCENES))
        out["7scenes_static_300"] = val_case("7scenes_static_300", seq, seq.groundtruth, repeats)
    for case in cases():
        if case.split != "val" or case.kind != "composite" or not want(case.name):
            continue
        if available(case):
            continue
        seq = case.build()
        out[case.name] = val_case(case.name, seq, seq.groundtruth, repeats,
                                  truth_keep=("true masks", lambda i, s=seq: s[i].mask == 0))
    return out


# -------------------------------------------------------------------------------- report


def _mm(x) -> str:
    return "-" if x is None else f"{1e3 * x:.1f}"


def _spread(row: dict) -> str:
    return f"{_mm(row['error_m'])} [{_mm(row['error_min_m'])}-{_mm(row['error_max_m'])}]"


def choose(dev: dict) -> tuple[str, dict]:
    """The variant with the lowest geometric mean of ATE(variant) / ATE(alone) over the
    dev cases (medians over the repeats), and every variant's mean."""
    names = [f"{ALONE} x jaxvo, {v.name}" for v in orb.VARIANTS]
    gm = {n: float(np.exp(np.mean([np.log(d[n]["error_m"] / d[ALONE]["error_m"])
                                   for d in dev.values()]))) for n in names}
    return min(gm, key=gm.get), gm


def report(res: dict) -> str:
    m = res["meta"]
    L = ["# ORB-SLAM3 beside jaxvo, and jaxvo's masks inside ORB-SLAM3\n",
         (f"{m['date']} by `{m['command']}`; {m['machine']['cpu_model']}, "
         f"{m['machine']['cores']} cores, load average {m['machine']['load_average_start']} at "
         f"start, {m['load_average_end']} at end; jax {m['machine']['jax']}, opencv "
         f"{m['machine']['opencv']}, pyorbslam3 {m['pyorbslam3']}; {m['repeats']} runs of each "
         f"ORB-SLAM3 configuration (median [min-max]).\n"),
         f"{m['vocabulary_note']}\n",
         ("ORB-SLAM3's trajectory is its end-of-run one (after its final optimisation), frames "
          "before initialisation or while lost left out (*tracked*). Masks: jaxvo's "
          "`StepOutput.dynamic` as pixels, frame by frame from `Odometry.process` (each frame "
          "one frame late); *depth*: the depth of the masked pixels set to 0, *depth+image*: "
          "their colour blacked out too; *grown k px*: the mask dilated by k pixels first. "
          "ms/frame: median of ORB-SLAM3's `track_rgbd` calls in its own process (first frame "
          "apart), jaxvo's `Odometry.process` (first frame, which compiles, apart); the "
          "streaming rows run jaxvo and the peer side by side on the same cores.\n")]
    if "dev" in res:
        dev = res["dev"]
        names = [f"{ALONE} x jaxvo, {v.name}" for v in orb.VARIANTS]
        best, gm = choose(dev)
        L += ["## Development split: which masking serves ORB-SLAM3 (ATE mm)\n"]
        rows = [[c, str(d["frames"]), f"{d['dynamic_pct']:.1f}", _mm(d["jaxvo"]["error_m"]),
                 _spread(d[ALONE])] + [_spread(d[n]) for n in names] for c, d in dev.items()]
        rows.append(["geometric mean over alone", "", "", "", "1"] + [f"{gm[n]:.3f}" for n in names])
        L += [markdown_table(["case", "frames", "masked px %", "jaxvo", ALONE]
                             + [n.replace(f"{ALONE} x jaxvo, ", "x jaxvo, ") for n in names], rows)]
        L += [(f"\nLowest geometric mean: **{best.replace(f'{ALONE} x jaxvo, ', '')}**, "
               "to be set as `orbslam3_peer.CHOSEN` (now "
               f"`{orb.CHOSEN.name}`). The static case's masks are empty (nothing moves), so "
               "its columns are repeated runs of ORB-SLAM3 alone: its run-to-run spread.\n")]
    if "val" in res:
        L += [f"## Validation split (never tuned on), masking `{orb.CHOSEN.name}`\n"]
        for c, d in res["val"].items():
            what = (f"distance from the reference (the medoid of {d['reference']['runs']} runs "
                    "of ORB-SLAM3 with the depth under the hand-drawn people masks set to 0, "
                    "apart from the rows), mm" if "reference" in d else "ATE, mm")
            L += [(f"### {c} ({d['frames']} frames; {what}; jaxvo's masks cover "
                  f"{d['dynamic_pct']:.2f} % of the pixels)\n")]
            rows = [["jaxvo", _mm(d["jaxvo"]["error_m"]), "-", f"{d['jaxvo']['ms_per_frame']:.1f}",
                     "-"]]
            for n in [k for k in d if k.startswith(ALONE)]:
                r = d[n]
                rows.append([n, _spread(r), "/".join(str(x["tracked"]) for x in r["runs"]),
                             f"{r['ms_per_frame']:.1f}",
                             f"{np.median([x['load_s'] for x in r['runs']]):.1f}"])
            for n, r in d["opencv"].items():
                rows.append([n, _mm(r["error_m"]), "-", f"{r['ms_per_frame']:.1f}", "-"])
            L += [markdown_table(["method", "mm: median [min-max]", "tracked", "ms/frame",
                                  "start-up s"], rows), ""]
            if "reference" in d:
                o = d["reference"]["others_from_it_m"]
                L += [(f"The other {len(o)} reference runs lie {_mm(min(o))}-{_mm(max(o))} mm "
                      "from the reference: ORB-SLAM3's own run-to-run spread on this clip.\n")]
        L += [target_lines(res["val"])]
    return "\n".join(L) + "\n"


def target_lines(val: dict) -> str:
    """Issue 28's targets, as measured."""
    out = ["## Targets (issue 28)\n"]
    d = val.get("tum_walking")
    if d:
        a, b = d[f"{ALONE} x jaxvo"]["error_m"], d[f"{ALONE} x hand-drawn masks"]["error_m"]
        out.append(f"- TUM clip: ORB-SLAM3 x jaxvo {_spread(d[f'{ALONE} x jaxvo'])} mm from the "
                   f"reference, x hand-drawn masks {_spread(d[f'{ALONE} x hand-drawn masks'])} "
                   f"mm: ratio of the medians {a / b:.2f} (target <= 1.2: "
                   f"{'met' if a <= 1.2 * b else 'not met'}); ORB-SLAM3 alone "
                   f"{_spread(d[ALONE])} mm.")
    d = val.get("7scenes_static_300")
    if d:
        a, b = d[f"{ALONE} x jaxvo"]["error_m"], d[ALONE]["error_m"]
        out.append(f"- 7-Scenes static, 300 frames: ORB-SLAM3 x jaxvo {_spread(d[f'{ALONE} x jaxvo'])} "
                   f"mm ATE, alone {_spread(d[ALONE])} mm: ratio of the medians {a / b:.3f} "
                   f"(target <= 1.05: {'met' if a <= 1.05 * b else 'not met'}).")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=("dev", "val", "all"), default="all")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each ORB-SLAM3 configuration")
    ap.add_argument("--only", nargs="*", help="case names")
    ap.add_argument("--out", type=Path, default=Path("results"))
    args = ap.parse_args(argv)
    why = orb.missing()
    if why:
        print(f"bench_orbslam3: ORB-SLAM3 skipped: {why}")
        return 0
    started = time.perf_counter()
    res = {"meta": {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "command": "python bench/bench_orbslam3.py " + " ".join(
            argv if argv is not None else sys.argv[1:]),
        "machine": machine(), "pyorbslam3": importlib.metadata.version("pyorbslam3"),
        "vocabulary": orb.vocabulary().name, "vocabulary_note": orb.vocabulary_note(),
        "repeats": args.repeats, "chosen": orb.CHOSEN.name}}
    if args.split in ("dev", "all"):
        res["dev"] = {}
        for case in cases():
            if (case.split == "dev" and (case.kind == "composite" or case.name == DEV_STATIC)
                    and (not args.only or case.name in args.only) and not available(case)):
                res["dev"][case.name] = dev_case(case, args.repeats)
    if args.split in ("val", "all"):
        res["val"] = val_cases(args.repeats, args.only)
    res["meta"]["load_average_end"] = load_average()
    res["meta"]["wall_s"] = time.perf_counter() - started
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "orbslam3.json").write_text(json.dumps(res, indent=1))
    md = report(res)
    (args.out / "orbslam3.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
