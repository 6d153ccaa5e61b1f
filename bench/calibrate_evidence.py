"""The inverse sensor model of the moving evidence, measured on the development split.

Each frame the pipeline classes every measured grid point by its residual under the
ego-motion (``jaxvo.pipeline.evidence_delta``): explained (evidence of static), unexplained
in a segment that moves as a whole (strong evidence of motion), unexplained otherwise (an
outlier, weak evidence). The log-likelihood ratio of a class is
``log P(class | the point moves) / P(class | it is static)``, counted against the exact masks
of the development cases that have them (synthetic scenes and composites on 7-Scenes frames
0-149) plus the static real frames (every point static). The ratios are the defaults of
``Params.evidence_static / evidence_moving / evidence_outlier``; the validation split is
never read here.

Run: ``.venv/bin/python bench/calibrate_evidence.py [--rounds 2]``. The classes depend on the
ego-motion, which depends on the ratios, so the measurement is repeated with the ratios it
gave (``--rounds``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_robustness import CFG, prepare, run_jaxvo  # noqa: E402
from splits import available, cases  # noqa: E402

from jaxvo.config import Params  # noqa: E402
from jaxvo.noise import NoiseScale, residuals  # noqa: E402
from jaxvo.pipeline import evidence_delta, init_pipeline  # noqa: E402
from jaxvo.spatial import Segmentation, frame_points  # noqa: E402

# class codes: the deltas evidence_delta returns for these ratios
_PROBE = Params(evidence_static=-1.0, evidence_moving=1.0, evidence_outlier=0.5)
_CLASSES = {-1.0: "explained", 1.0: "segment moves", 0.5: "outlier"}


def classes(data: dict, outs, params: Params):
    """(T, n) class codes of every measured point (nan where not measured) and the truth."""
    flows = {k[5:]: data[k] for k in data if k.startswith("flow_")}
    state0 = init_pipeline(cfg=CFG, grid=(1, 1), params=params).noise
    noise = [state0] + [NoiseScale(outs.noise.pixel_sigma[k], outs.noise.depth_coeff[k])
                        for k in range(len(outs.status) - 1)]

    @jax.jit
    def one(pp, pc, valid, focal, scale, T, labels, ok):
        pts = frame_points(pp, pc, valid, params, focal=focal, scale=scale)
        d2 = residuals(T, pts.src, pts.dst, pts.noise)[0]
        seg = Segmentation(labels, None, None, None, None, None, None)
        delta, _ = evidence_delta(seg, d2, pts.valid & ok, pts.thr, _PROBE, cfg=CFG)
        return jnp.where(pts.valid & ok, delta, jnp.nan)

    out = []
    for k in range(len(outs.status)):
        out.append(np.asarray(one(flows["pts_prev"][k], flows["pts_cur"][k],
                                  flows["valid"][k] & (flows["status"][k] == 0),
                                  flows["focal"][k], noise[k], outs.T_cur_prev[k],
                                  outs.labels[k], outs.status[k] == 0)))
    return np.stack(out)


def measure(params: Params, cache: Path) -> dict:
    counts = {True: {c: 0 for c in _CLASSES}, False: {c: 0 for c in _CLASSES}}
    for case in cases():
        if case.split != "dev" or available(case):
            continue
        data = prepare(case, cache, CFG)
        if "grid_gt" not in data and case.kind != "static":
            continue
        _, outs, _, _ = run_jaxvo(data, params, CFG, seed=0)
        cls = classes(data, outs, params)
        truth = data["grid_gt"][: len(cls)] if "grid_gt" in data else np.zeros(cls.shape, bool)
        for moving in (True, False):
            for code in _CLASSES:
                counts[moving][code] += int(np.sum((cls == code) & (truth == moving)))
    return counts


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--cache", type=Path, default=Path("results/cache"))
    args = ap.parse_args(argv)
    params = Params()
    for r in range(args.rounds):
        counts = measure(params, args.cache)
        tot = {m: max(sum(counts[m].values()), 1) for m in counts}
        llr = {}
        print(f"round {r + 1} with static {params.evidence_static:.2f}, moving "
              f"{params.evidence_moving:.2f}, outlier {params.evidence_outlier:.2f}:")
        for code, name in _CLASSES.items():
            pm = (counts[True][code] + 0.5) / tot[True]
            ps = (counts[False][code] + 0.5) / tot[False]
            llr[name] = float(np.log(pm / ps))
            print(f"  {name:14s} P(.|moving) {pm:.4f} ({counts[True][code]}), P(.|static) "
                  f"{ps:.5f} ({counts[False][code]}): log-likelihood ratio {llr[name]:+.2f}")
        params = params._replace(evidence_static=llr["explained"],
                                 evidence_moving=llr["segment moves"],
                                 evidence_outlier=llr["outlier"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
