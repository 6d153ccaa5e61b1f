"""How long ``Odometry.process`` takes a frame, steady, on real frames: one line of figures.

For before/after comparisons of the per-frame step (issue 47's "at most 15 % slower"): run
this script alternately under two checkouts (``PYTHONPATH=OTHER_CHECKOUT python
bench/time_process.py``, A B A B ...) on the same frames and compare the medians. It reads
``--frames`` of the 7-Scenes frames of the data root (every ``--step``-th) into memory, then
times each ``Odometry.process`` call with the clock around it (the step's outputs are host
arrays, so the call returns when the frame is done); the first calls, which compile or load
the compiled step, are reported apart.

Each call's time is also split in two: the host's grid flow (``FrameChain.push``: the LK
tracking, the checks, the depth lookups) and the rest (the step dispatched and waited for,
its outputs brought to the host), medians ``flow_median_ms`` and ``step_median_ms``.

Usage: ``python bench/time_process.py [--frames 120] [--step 1] [--skip 10]
[--config NAME=VALUE ...]``; prints one JSON line: ``{"code": ..., "config": ..., "first_s":
..., "median_ms": ..., "p90_ms": ..., "flow_median_ms": ..., "step_median_ms": ...,
"frames": ...}``. ``--config`` sets ``Config`` fields (``_options.config_from``), for a
setting's cost on the same code.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SEVEN_SCENES, load_average
from _options import check_options, config_from, config_setting, count

import jaxvo
from jaxvo.host.readers.io import InMemorySequence, data_root, open_sequence
from jaxvo.odometry import Odometry


def timed_flow() -> list[float]:
    """The seconds of every ``FrameChain.push`` from now on (the host's share of a frame),
    appended to the list returned, one a frame."""
    from jaxvo.host.frontend import flow

    seconds: list[float] = []
    push = flow.FrameChain.push

    def timed(self, *args, **kwargs):
        t0 = time.perf_counter()
        try:
            return push(self, *args, **kwargs)
        finally:
            seconds.append(time.perf_counter() - t0)

    flow.FrameChain.push = timed
    return seconds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=count(2), default=120)
    ap.add_argument("--step", type=count(1), default=1)
    ap.add_argument("--skip", type=count(0), default=10,
                    help="first calls left out of the steady figures")
    ap.add_argument("--config", nargs="*", default=[], metavar="NAME=VALUE",
                    type=config_setting, help="Config values to run with (e.g. lk_window=13)")
    args = ap.parse_args(argv)
    # the settings at 7-Scenes' 640 x 480 frames, with the run's memory
    check_options(ap, args, data=[SEVEN_SCENES], image=(480, 640))
    real = open_sequence(data_root() / SEVEN_SCENES)
    read = min(args.frames, len(range(0, len(real), args.step)))
    if not args.skip < read:
        ap.error(f"argument --skip: {args.skip} leaves no frame to time of the {read} read")
    seq = InMemorySequence(real, frames=args.frames, step=args.step)
    odo = Odometry(seq.intrinsics, cfg=config_from(args.config), seed=0)
    flow_times = timed_flow()
    times = []
    for frame in seq:
        t0 = time.perf_counter()
        odo.process(frame.bgr, frame.depth, frame.timestamp)
        times.append(time.perf_counter() - t0)
    steady = 1e3 * np.asarray(times[args.skip:])
    flow = 1e3 * np.asarray(flow_times[args.skip:len(times)])
    print(json.dumps({"code": str(Path(jaxvo.__file__).resolve().parent.parent),
                      "config": args.config,
                      "first_s": round(times[0] + times[1], 3),
                      "median_ms": round(float(np.median(steady)), 3),
                      "p90_ms": round(float(np.percentile(steady, 90)), 3),
                      "flow_median_ms": round(float(np.median(flow)), 3),
                      "step_median_ms": round(float(np.median(steady - flow)), 3),
                      "frames": len(steady), "load": load_average()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
