"""Frame-to-keyframe tracking (``Config.keyframes``, issue 27) against frame to frame.

On the real 7-Scenes frames (all 300, and the development and validation halves of
``bench/splits.py``) at every 1st, 2nd and 4th frame, and on the validation composites
(frames 150-299, seed 1): ATE and RPE (1 frame) with and without keyframes, and how many
keyframes were taken. Then ``Odometry.process`` on the first ``--timing-frames`` frames,
keyframes off and on in alternating runs (the first 5 frames of each apart), median ms a
frame. ORB-SLAM3's figures on the same frames are in ``docs/report/orbslam3_val.md``.

Run: ``.venv/bin/python bench/bench_keyframes.py [--out results/] [--timing-frames 150]``;
writes ``keyframes.md`` and ``keyframes.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SEVEN_SCENES, log, machine_line
from splits import COMPOSITES, HALF

from jaxvo.config import Config
from jaxvo.evaluation.metrics import ate, rpe
from jaxvo.host.io import InMemorySequence, data_root, open_sequence
from jaxvo.odometry import Odometry, run_sequence
from jaxvo.synth.scenes import composite_sequence


def scores(seq) -> dict:
    """ATE, RPE (mm) and keyframes of ``seq`` with keyframes off and on."""
    row = {}
    for kf in (False, True):
        r = run_sequence(seq, cfg=Config(keyframes=kf))
        gt = seq.groundtruth
        row["on" if kf else "off"] = {
            "ate_mm": 1e3 * float(ate(gt, r.trajectory).stats.rmse),
            "rpe_mm": 1e3 * float(rpe(gt, r.trajectory, delta=1).trans.rmse),
            "keyframes": int(r.outputs.keyframes[-1]) if kf else 0}
    return row


def process_ms(seq, frames: int, repeats: int = 2) -> dict:
    """Median ms a frame of ``Odometry.process``, keyframes off and on, alternating."""
    times: dict[bool, list] = {False: [], True: []}
    for _ in range(repeats):
        for kf in (False, True):
            odo = Odometry(seq.intrinsics, cfg=Config(keyframes=kf))
            ts = []
            for f in list(seq)[:frames]:
                t0 = time.perf_counter()
                odo.process(f.bgr, f.depth, f.timestamp)
                ts.append(time.perf_counter() - t0)
            times[kf] += ts[5:]
    return {("on" if kf else "off"): 1e3 * float(np.median(t)) for kf, t in times.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="results", help="folder for keyframes.md / .json")
    ap.add_argument("--timing-frames", type=int, default=150)
    args = ap.parse_args(argv)
    folder = data_root() / SEVEN_SCENES
    if not folder.is_dir():
        print(f"bench_keyframes: skipped, the 7-Scenes frames are not at {folder}")
        return 0
    full = open_sequence(folder)
    rows = {}
    for name, start, count in (("7-Scenes 300", 0, len(full)), ("dev 0-149", 0, HALF),
                               ("val 150-299", HALF, HALF)):
        for k in (1, 2, 4):
            label = f"{name}, every {k}"
            log(label)
            rows[label] = scores(InMemorySequence(full, start=start, frames=-(-count // k),
                                                  step=k))
    for scenario in COMPOSITES:
        label = f"comp_{scenario}_val"
        log(label)
        rows[label] = scores(InMemorySequence(composite_sequence(
            folder, scenario, start=HALF, frames=HALF, seed=1)))
    log("Odometry.process timing")
    timing = process_ms(InMemorySequence(full, frames=args.timing_frames), args.timing_frames)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "keyframes.json").write_text(json.dumps({"rows": rows, "process_ms": timing},
                                                   indent=1))
    L = ["# Frame-to-keyframe tracking against frame to frame", "", machine_line(), "",
         "| frames | ATE off [mm] | ATE on [mm] | RPE off [mm] | RPE on [mm] | keyframes |",
         "|---|---|---|---|---|---|"]
    L += [f"| {k} | {r['off']['ate_mm']:.2f} | {r['on']['ate_mm']:.2f} | "
          f"{r['off']['rpe_mm']:.2f} | {r['on']['rpe_mm']:.2f} | {r['on']['keyframes']} |"
          for k, r in rows.items()]
    L += ["", (f"`Odometry.process`, median of 2 alternating runs over the first "
               f"{args.timing_frames} frames: {timing['off']:.2f} ms a frame without keyframes, "
               f"{timing['on']:.2f} ms with (+{timing['on'] - timing['off']:.2f} ms)."), ""]
    (out / "keyframes.md").write_text("\n".join(L))
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
