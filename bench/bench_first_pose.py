"""Where the time to the first pose goes: a fresh process, as a script or ``jaxvo run``
starts, from the interpreter's start to the pose of the first frame pair.

Each measure runs in a child process of its own (JAX opens its compile cache, traces and
compiles once a process), on the first frames of the 7-Scenes sequence of the data root
(a synthetic scene when it is absent), with the persistent compile cache in a temporary
folder that a first, uncounted child fills (``--cold``: every child starts from an empty
one). A child reports:

* ``import_s``: ``import jaxvo.odometry`` (JAX, OpenCV, the step's modules);
* ``init_s``: ``Odometry(...)`` (the compile cache set up, the key and parameters on the
  device);
* ``frame0_s``: the first ``process`` call (the first image's grid, the start state);
* ``frame1_s``: the second ``process`` call, whose result is the first pose: the pair's flow,
  the step traced, lowered, loaded from the cache (or compiled) and run;
* ``first_pose_s``: ``init_s + frame0_s + frame1_s``, the issue's "first pose" figure, and
  ``since_start_s`` from the interpreter's start (imports included).

The second call's parts, from JAX's own monitoring events during it: ``trace_s`` (Python
to jaxpr), ``lower_s`` (jaxpr to StableHLO), ``load_or_compile_s`` (the compile cache's
lookup and the executable's deserialisation, or XLA's compile), ``rest_s`` (the rest: the
pair's flow, loading an exported step, the step's first run). The script runs under any
checkout's interpreter (``OTHER/.venv/bin/python bench/bench_first_pose.py``) for a before /
after comparison.

Usage: ``python bench/bench_first_pose.py [--runs 5] [--cold]``; prints a JSON line
per child, then the medians as one JSON line.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHILD = r"""
import json, sys, time
t_start = float(sys.argv[1])
t0 = time.perf_counter()
import jax
import jaxvo.odometry
from jaxvo.odometry import Odometry
t_import = time.perf_counter() - t0
from jaxvo.host.services.compile_cache import setup_compile_cache
setup_compile_cache()  # as the commands do (JAXVO_COMPILE_CACHE): older code lacks the default
parts, on = {}, [False]
def note(event, seconds, **kw):
    if on[0]:
        parts[event] = parts.get(event, 0.0) + seconds
jax.monitoring.register_event_duration_secs_listener(note)
sys.path.insert(0, sys.argv[2])
from bench_first_pose import first_frames
K, frames = first_frames(2)
t0 = time.perf_counter()
odo = Odometry(K, seed=0)
t_init = time.perf_counter() - t0
times = []
for k, f in enumerate(frames):
    on[0] = k == 1
    t0 = time.perf_counter()
    r = odo.process(f.bgr, f.depth, f.timestamp)
    times.append(time.perf_counter() - t0)
since = time.time() - t_start
trace = parts.get("/jax/core/compile/jaxpr_trace_duration", 0.0)
lower = parts.get("/jax/core/compile/jaxpr_to_mlir_module_duration", 0.0)
load = parts.get("/jax/core/compile/backend_compile_duration", 0.0)
out = {"import_s": t_import, "init_s": t_init, "frame0_s": times[0], "frame1_s": times[1],
       "trace_s": trace, "lower_s": lower, "load_or_compile_s": load,
       "rest_s": times[1] - trace - lower - load,
       "first_pose_s": t_init + sum(times), "since_start_s": since}
print(json.dumps({k: round(v, 4) for k, v in out.items()}))
"""


def first_frames(n: int):
    """The camera and the first ``n`` frames (in memory) of the bench's sequence."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import SEVEN_SCENES

    from jaxvo.host.readers.io import InMemorySequence, data_root, open_sequence

    folder = data_root() / SEVEN_SCENES
    if (folder / "associations.txt").is_file():
        seq = InMemorySequence(open_sequence(folder), frames=n)
    else:
        from jaxvo.synth.scenes import make_sequence

        seq = InMemorySequence(make_sequence("handheld_slow", frames=n, seed=0))
    return seq.intrinsics, list(seq)


def child(cache: Path) -> dict:
    """One fresh process's figures (the CHILD above), the compile cache in ``cache``."""
    env = dict(os.environ, JAXVO_COMPILE_CACHE=str(cache),
               JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu"))
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    done = subprocess.run(
        [sys.executable, "-c", CHILD, repr(time.time()), str(Path(__file__).resolve().parent)],
        capture_output=True, text=True, env=env, check=False)
    if done.returncode:
        raise RuntimeError(done.stderr[-3000:])
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--cold", action="store_true", help="an empty compile cache each child")
    ap.add_argument("--cache", type=Path, help="keep the compile cache in this folder between "
                    "calls (default: a temporary one)")
    args = ap.parse_args(argv)
    import numpy as np

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        warm = args.cache or Path(tmp) / "cache"
        if not args.cold:
            child(warm)  # fills the cache: not counted
        for k in range(args.runs):
            cache = Path(tmp) / f"cold{k}" if args.cold else warm
            rows.append(child(cache))
            print(json.dumps(rows[-1]), flush=True)
    medians = {key: round(float(np.median([r[key] for r in rows])), 3) for key in rows[0]}
    print(json.dumps({"median": medians, "runs": len(rows), "cold": args.cold,
                      "load": os.getloadavg()[0]}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
