"""A sha256 digest of jaxvo's outputs on every case of the splits, to check that a change
keeps the same bits.

For each case of ``bench/splits.py`` (dev, val, fresh: the built-in scenes and the
composites, static and people sequences) the streaming step runs over the case's cached
flow (``bench_robustness.py``'s cache; built here when absent, without the peers) and the
digest prints one line per run: the case, then the first 12 hex digits of the sha256 of the
poses, of the identifiers, of the moving cells, of the plug-in mask cells, of the spatial
labels, of the evidence, and of all of them with the statuses. Same lines before and after
a change: the same bits.

Run: ``.venv/bin/python bench/digest.py [--split dev|val|fresh|all] [--only CASE ...]
[--cache results/cache] > digest.txt``
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_robustness import _flow_key, build_flow, run_jaxvo
from splits import available, cases, in_split

from jaxvo.config import Config, Params

FIELDS = ("T_w_c", "ids", "moving", "dynamic", "labels", "evidence")


def cached_flow(case, cache: Path, cfg: Config) -> dict:
    """The case's flow from ``bench_robustness.py``'s cache (the same file), else built."""
    path = cache / f"{case.name}__{_flow_key(cfg)}.npz"
    if path.is_file():
        z = np.load(path, allow_pickle=False)
        return {k: z[k] for k in z.files if k != "grid_gt"}
    return build_flow(case, path, cfg)[0]


def _sha(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:12]


def digest(data: dict, cfg: Config, seed: int) -> list[str]:
    traj, outs, final_moving, _ = run_jaxvo(data, Params(), cfg, seed)
    parts = [_sha(np.asarray(getattr(outs, f))) for f in FIELDS]
    every = _sha(traj.poses, np.asarray(outs.status), final_moving,
                 *(np.asarray(getattr(outs, f)) for f in FIELDS))
    return [*parts, every]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", choices=("dev", "val", "fresh", "all"), default="all")
    ap.add_argument("--only", nargs="*")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cache", type=Path, default=Path("results/cache"))
    args = ap.parse_args(argv)
    print("case " + " ".join(FIELDS) + " all", flush=True)
    for case in cases():
        if not in_split(case, args.split) or (args.only and case.name not in args.only):
            continue
        why = available(case)
        if why:
            print(f"{case.name} skipped: {why}", flush=True)
            continue
        data = cached_flow(case, args.cache, Config())
        print(case.name, *digest(data, Config(), args.seed), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
