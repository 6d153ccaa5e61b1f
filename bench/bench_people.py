"""What jaxvo's segmentation costs on real people, without ground truth (issue 26).

The reference: jaxvo on the TUM walking clip with the depth under the hand-drawn people
masks (``bench/annotations``) set to 0, so that no point on a person enters the fit; the
medoid of ``--seeds`` seeded runs (the run with the least median distance from the others).
Then jaxvo on the clip as it is, each seed: the distance of its trajectory from the
reference (ATE after rigid alignment) is the error its segmentation lets in. Beside it the
reference runs' own spread (seed to seed). The people masks' coverage by jaxvo's plug-in
mask, and what it flags outside them, are ``bench_robustness.py``'s.

Run: ``.venv/bin/python bench/bench_people.py [--seeds 5] [--out results/]``; writes
``people.md`` and ``people.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import TUM_WALKING, log, machine_line
from people_masks import people_clip

from jaxvo.evaluation.metrics import ate
from jaxvo.host.readers.io import InMemorySequence
from jaxvo.odometry import run_sequence


def without_people(seq: InMemorySequence, people: dict[int, np.ndarray]) -> InMemorySequence:
    """The same frames with the depth under the people masks set to 0 (no reading)."""
    out = InMemorySequence(seq)
    out._frames = [f._replace(depth=np.where(people[i], 0.0, f.depth).astype(np.float32))
                   for i, f in enumerate(out._frames)]
    return out


def distance_mm(a, b) -> float:
    return 1e3 * float(ate(a, b).stats.rmse)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5, help="seeded runs of each (default 5)")
    ap.add_argument("--out", default="results", help="folder for people.md / people.json")
    args = ap.parse_args(argv)
    clip = people_clip("bench_people")
    if clip is None:
        return 0
    seq, people = InMemorySequence(clip[0]), clip[1]
    masked = without_people(seq, people)
    log(f"reference: jaxvo without the people's depth, {args.seeds} seeds")
    refs = [run_sequence(masked, seed=s).trajectory for s in range(args.seeds)]
    d = np.array([[distance_mm(a, b) if i != j else 0.0 for j, b in enumerate(refs)]
                  for i, a in enumerate(refs)])
    medoid = int(np.argmin(np.median(d, axis=1)))
    spread = [float(x) for j, x in enumerate(d[medoid]) if j != medoid]
    log("jaxvo on the clip as it is")
    rows = []
    for s in range(args.seeds):
        r = run_sequence(seq, seed=s)
        rows.append({"seed": s, "distance_mm": distance_mm(refs[medoid], r.trajectory)})
        log(f"seed {s}: {rows[-1]}")
    dist = [r["distance_mm"] for r in rows]
    res = {"frames": len(seq), "reference_seed": medoid, "reference_spread_mm": spread,
           "runs": rows, "distance_median_mm": float(np.median(dist))}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "people.json").write_text(json.dumps(res, indent=1))
    med = lambda k: float(np.median([r[k] for r in rows]))
    L = ["# jaxvo on real people: distance from the people-masked reference", "",
         machine_line(), "",
         (f"TUM `{TUM_WALKING}`, {len(seq)} frames. Reference: jaxvo with the depth under the "
          f"hand-drawn people masks set to 0, the medoid of {args.seeds} seeds (seed {medoid}; "
          f"the others lie {min(spread):.1f}-{max(spread):.1f} mm from it)."), "",
         "| seed | distance from the reference [mm] |", "|---|---|"]
    L += [f"| {r['seed']} | {r['distance_mm']:.1f} |" for r in rows]
    L += [f"| median | {med('distance_mm'):.1f} |", "",
          ("People covered and flagged outside them: `bench_robustness.py --only tum_walking`."),
          ""]
    (out / "people.md").write_text("\n".join(L))
    print("\n".join(L))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
