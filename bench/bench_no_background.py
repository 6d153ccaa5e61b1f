"""Keyframes through a stretch with no background in view: a wall-sized box sweeping over
the whole view for 11-14 of 90 synthetic frames, jaxvo with keyframes off and on, seeds 0-4
(ATE mm, median [best-worst]; docs/report/keyframes_no_background.md).

Run: ``.venv/bin/python bench/bench_no_background.py``
"""

from __future__ import annotations

import numpy as np

import jaxvo
from jaxvo.config import Config
from jaxvo.synth.scenario import ObjectSpec, Scenario

WALL = Scenario("sweep_wall", "a wall-sized box sweeping across the whole view",
                camera="handheld", camera_speed=0.15,
                objects=(ObjectSpec(size=(1.7, 1.4, 0.2), centre=(0.0, 0.2, 1.0),
                                    amplitude=(1.6, 0.0, 0.0), period=(6.0, 5.0, 5.0),
                                    spin=0.0, phase=(-np.pi / 2, 0.0, 0.0)),))


def main() -> int:
    res: dict[bool, list[float]] = {False: [], True: []}
    for seed in range(5):
        seq = jaxvo.make_sequence(WALL, frames=90, seed=seed)
        full = sum(float((seq[i].mask > 0).mean()) > 0.97 for i in range(len(seq)))
        for kf in (False, True):
            r = jaxvo.run_sequence(seq, seed=seed, cfg=Config(keyframes=kf))
            res[kf].append(1e3 * jaxvo.ate(seq.groundtruth, r.trajectory).stats.rmse)
        print(f"seed {seed}: {full} frames fully covered; ATE mm keyframes off "
              f"{res[False][-1]:.1f}, on {res[True][-1]:.1f}", flush=True)
    for kf in (False, True):
        a = np.array(res[kf])
        print(f"keyframes {'on' if kf else 'off'}: {np.median(a):.1f} [{a.min():.1f}-{a.max():.1f}] mm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
