"""Lens distortion undone at the tracked points: a scene seen through a lens, with and without
the lens given, against the same scene seen through a pinhole.

For each seed, one synthetic scene (``--scenario``, ``--frames``) is rendered twice: through
a pinhole, and through ``--lens`` (each pinhole render remapped as the lens shows it,
``make_sequence(lens=...)``). jaxvo runs three times: on the pinhole images; on the lens's
images with the lens given (the sequence's intrinsics carry it: the tracked points are
undistorted before they become 3D points); and on the lens's images with the lens left out
(taken as pinhole, what jaxvo did with every calibration before). Each variant's ATE
(rigid alignment, metres) is reported as the median and the spread [best-worst] over the
seeds; seed ``s`` draws the scene and the run's PRNG key alike. The lens given should come
within 5 % of the pinhole scene's median.

Run: ``.venv/bin/python bench/bench_distortion.py [--frames 60] [--seeds 5]
[--scenario handheld_slow] [--lens tum_fr1] [--out docs/report]``; writes
``distortion.md`` and ``distortion.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import log, machine, machine_line, markdown_table

from jaxvo.evaluation.metrics import ate
from jaxvo.host.frontend.camera import TUM_DISTORTION, describe_distortion
from jaxvo.host.writers.outputs import write_text
from jaxvo.odometry import run_sequence
from jaxvo.synth.scenes import SCENARIOS, make_sequence

VARIANTS = ("pinhole scene", "lens scene, lens given", "lens scene, taken as pinhole")
WITHIN = 0.05  # the lens given: its median ATE within 5 % of the pinhole scene's


def run_seed(scenario: str, frames: int, seed: int, lens) -> dict:
    """The three variants' ATE (metres), run seconds and summary lens line for one seed."""
    plain = make_sequence(scenario, frames=frames, seed=seed)
    seen = make_sequence(scenario, frames=frames, seed=seed, lens=lens)
    blind = make_sequence(scenario, frames=frames, seed=seed, lens=lens)
    blind.intrinsics = blind.intrinsics._replace(distortion=None)
    out = {}
    for name, seq in zip(VARIANTS, (plain, seen, blind)):
        t0 = time.perf_counter()
        res = run_sequence(seq, seed=seed)
        err = ate(seq.groundtruth, res.trajectory, align=True, max_diff=0.02).stats.rmse
        out[name] = {"ate_m": float(err), "seconds": round(time.perf_counter() - t0, 2),
                     "lens": describe_distortion(seq.intrinsics)}
        log(f"seed {seed} {name}: ATE {1000 * err:.3f} mm ({out[name]['seconds']} s)")
    return out


def spread_mm(values: list[float]) -> str:
    """Median [best-worst] of ATEs in metres, as millimetres."""
    v = 1000 * np.asarray(values)
    return f"{np.median(v):.3f} [{v.min():.3f}-{v.max():.3f}]"


def report(runs: dict[int, dict], args, meta: dict) -> str:
    seeds = sorted(runs)
    ates = {name: [runs[s][name]["ate_m"] for s in seeds] for name in VARIANTS}
    base = float(np.median(ates[VARIANTS[0]]))
    rows = []
    for name in VARIANTS:
        med = float(np.median(ates[name]))
        rows.append([name, spread_mm(ates[name]), f"{med / base:.3f}",
                     " ".join(f"{1000 * a:.3f}" for a in ates[name]),
                     runs[seeds[0]][name]["lens"]])
    given = float(np.median(ates[VARIANTS[1]])) / base
    verdict = "within" if abs(given - 1) <= WITHIN else "NOT within"
    setting = (f"Scene `{args.scenario}`, {args.frames} frames, seeds {seeds[0]}-{seeds[-1]} "
               f"(scene and run); lens `{args.lens}`: {meta['lens']}. ATE rmse after rigid "
               "alignment, millimetres, median [best-worst] over the seeds; the ratio is each "
               "median over the pinhole scene's. The lens's images are each pinhole render "
               "remapped as the lens shows it (colour bilinear, depth bilinear on one surface "
               "and nearest across edges) before the sensor model.")
    table = markdown_table(["variant", "ATE mm, median [best-worst]", "median / pinhole",
                            "per seed (mm)", "run summary says"], rows)
    verdict_line = (f"The lens given: median {given:.3f} of the pinhole scene's, {verdict} "
                    f"{100 * WITHIN:.0f} %. Made by `bench/bench_distortion.py --frames "
                    f"{args.frames} --seeds {args.seeds} --scenario {args.scenario} --lens "
                    f"{args.lens}`.")
    parts = [machine_line(), setting, table, verdict_line]
    return "# Lens distortion undone at the tracked points\n\n" + "\n\n".join(parts) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--scenario", choices=sorted(SCENARIOS), default="handheld_slow")
    parser.add_argument("--lens", choices=sorted(TUM_DISTORTION), default="tum_fr1",
                        help="the distortion coefficients the scene is seen through")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1]
                        / "docs" / "report")
    args = parser.parse_args()
    if args.frames < 3 or args.seeds < 1:
        parser.error("--frames must be at least 3 and --seeds at least 1")
    lens = TUM_DISTORTION[args.lens]
    log(f"machine: {machine_line()}")
    runs = {s: run_seed(args.scenario, args.frames, s, lens) for s in range(args.seeds)}
    meta = {"machine": machine(), "scenario": args.scenario, "frames": args.frames,
            "lens": lens.describe(), "lens_name": args.lens}
    args.out.mkdir(parents=True, exist_ok=True)
    write_text(args.out / "distortion.json",
               json.dumps({"meta": meta, "runs": {str(s): r for s, r in runs.items()}},
                          indent=1) + "\n")
    text = report(runs, args, meta)
    write_text(args.out / "distortion.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
