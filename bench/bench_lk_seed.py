"""Would a forward LK seeded from the predicted motion pay (issue 53's "cheaper front end")?

Two figures decide it, both on the shared real frames:

* how far each grid point's track lands from where the last pair's track of its cell
  predicts it (a constant image velocity per cell: what the camera's predicted motion and
  the cell's depth give, less the depth's noise), against the track's own length: a seeded
  LK can drop a pyramid level only where the prediction error stays within what the
  remaining levels reach (about half the window on the finest level, twice that per level
  above);
* what one forward LK call over the grid costs on 0-3 levels, unseeded and seeded at its
  own answer (the best a prediction can do).

    .venv/bin/python bench/bench_lk_seed.py [--frames 150] [--repeat 200]
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
from _common import SEVEN_SCENES, TUM_WALKING, machine_line, real_present

from jaxvo.config import Config
from jaxvo.host.frontend.camera import grid_pixels
from jaxvo.host.frontend.flow import GridFlowTracker
from jaxvo.host.readers.io import data_root, open_sequence

PERCENTILES = (50, 90, 95, 99)


def prediction_errors(name: str, frames: int, cfg: Config):
    """``(error px, track length px)`` of every valid track of ``name``'s first ``frames``
    frames whose cell had a valid track in the pair before."""
    seq = open_sequence(data_root() / name)
    first = seq[0]
    tracker = GridFlowTracker(seq.intrinsics, cfg, height=first.depth.shape[0],
                              width=first.depth.shape[1])
    tracker.push(first.bgr, first.depth)
    last, errors, lengths = None, [], []
    for i in range(1, min(frames, len(seq))):
        f = seq[i]
        flow = tracker.push(f.bgr, f.depth)
        d = np.where(flow.valid[:, None], flow.uv_cur - flow.uv_prev, np.nan)
        if last is not None:
            both = flow.valid & ~np.isnan(last[:, 0])
            errors.append(np.hypot(*(d[both] - last[both]).T))
            lengths.append(np.hypot(*d[flow.valid].T))
        last = d
    return np.concatenate(errors), np.concatenate(lengths)


def lk_costs(cfg: Config, repeat: int) -> dict:
    """ms per forward LK call over the whole grid of two 7-Scenes frames, by pyramid levels,
    unseeded and seeded at its own answer."""
    seq = open_sequence(data_root() / SEVEN_SCENES)
    a, b = (cv2.cvtColor(seq[i].bgr, cv2.COLOR_BGR2GRAY) for i in (150, 151))
    pts = grid_pixels(*a.shape, cfg.cell)
    win = (cfg.lk_window, cfg.lk_window)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, cfg.lk_iters, cfg.lk_eps)

    def ms(fn):
        fn()
        t = time.perf_counter()
        for _ in range(repeat):
            fn()
        return 1e3 * (time.perf_counter() - t) / repeat

    answer = cv2.calcOpticalFlowPyrLK(a, b, pts, None, winSize=win, maxLevel=cfg.lk_levels,
                                      criteria=crit)[0]
    out = {}
    for levels in range(4):
        out[f"levels {levels}"] = {
            "unseeded_ms": ms(lambda lv=levels: cv2.calcOpticalFlowPyrLK(
                a, b, pts, None, winSize=win, maxLevel=lv, criteria=crit,
                flags=cv2.OPTFLOW_LK_GET_MIN_EIGENVALS)),
            "seeded_ms": ms(lambda lv=levels: cv2.calcOpticalFlowPyrLK(
                a, b, pts, answer.copy(), winSize=win, maxLevel=lv, criteria=crit,
                flags=cv2.OPTFLOW_USE_INITIAL_FLOW | cv2.OPTFLOW_LK_GET_MIN_EIGENVALS)),
        }
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--repeat", type=int, default=200)
    args = ap.parse_args(argv)
    present = real_present()
    if SEVEN_SCENES not in present:
        print(f"the shared real frames are absent under {data_root()}: nothing to measure")
        return 0
    cfg = Config()
    print(machine_line())
    for name in present:
        err, length = prediction_errors(name, args.frames, cfg)
        q = lambda x: " / ".join(f"{v:.2f}" for v in np.percentile(x, PERCENTILES))
        print(f"{name}: prediction error px (p{'/'.join(map(str, PERCENTILES))}) {q(err)}; "
              f"track length {q(length)}; beyond 4 px {100 * np.mean(err > 4):.1f} %, "
              f"beyond 8 px {100 * np.mean(err > 8):.1f} % of {len(err)} tracks")
    print(f"forward LK over the {cfg.cell}-pixel grid, {cfg.lk_window}-pixel window "
          f"(default levels {cfg.lk_levels}), ms a call:")
    for levels, c in lk_costs(cfg, args.repeat).items():
        print(f"  {levels}: unseeded {c['unseeded_ms']:.2f}, seeded at its answer "
              f"{c['seeded_ms']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
