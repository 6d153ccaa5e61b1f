"""Where the TUM clip's error against its oracle comes from, cell by cell (issue 51).

jaxvo on the TUM walking clip and on its oracle (the depth under the hand-drawn people
masks set to 0, ``bench_seeds.reference_case``), the same seeds and settings, and three
questions asked of both runs with the masks:

* how much of the ego-motion's fit lies on the people: the share of the points it used and
  of their weight (each point's belief as background, ``background.belief_weights``, from
  the evidence entering the pair), over the clip and pair by pair;
* the room's cells: how many are established static, unestablished or moving, apart for
  the cells a person covered in the last five frames (``revealed``) and the rest;
* the pose error of each pair (translation mm, rotation deg), median over the seeds.

    .venv/bin/python bench/people_diagnosis.py [--seeds 5] [--config keyframes=true]
        [--cache results/cache]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from _common import first_pose, groundtruth, machine_line
from _options import config_from, config_setting
from bench_robustness import prepare
from bench_seeds import reference_case, run_seeds
from people_masks import people_masks
from splits import cases

from jaxvo.config import Params
from jaxvo.core.background import belief_weights
from jaxvo.core.evidence import moving_logodds
from jaxvo.evaluation.metrics import rpe
from jaxvo.evaluation.scores import trajectory_scores
from jaxvo.host.readers.io import data_root

RECENT = 5  # frames since a person covered a cell for it to count as revealed


def on_people(data: dict, masks: dict) -> np.ndarray:
    """(T, n) bool each pair's grid points (in its previous image) inside a people mask."""
    uv = np.asarray(data["flow_uv_prev"])
    h, w = (int(x) for x in data["size"])
    out = np.zeros(uv.shape[:2], bool)
    for k in range(len(uv)):
        if k in masks:
            u = np.clip(np.rint(uv[k, :, 0]).astype(int), 0, w - 1)
            v = np.clip(np.rint(uv[k, :, 1]).astype(int), 0, h - 1)
            out[k] = masks[k][v, u]
    return out


def pair_errors(gt, traj) -> np.ndarray:
    """(T, 2) each frame pair's translation error, mm, and rotation error, deg: the RPE of
    one frame (:func:`jaxvo.evaluation.metrics.rpe`) at the pair's first frame, NaN where
    either frame has no ground truth."""
    r = rpe(gt, traj, delta=1)
    frame = np.searchsorted(traj.timestamps, r.matched.est_timestamps)
    i, j = frame[r.pairs[:, 0]], frame[r.pairs[:, 1]]
    out = np.full((len(traj.poses) - 1, 2), np.nan)
    one = j == i + 1
    out[i[one]] = np.stack([1e3 * r.trans_errors[one], r.rot_errors[one]], axis=1)
    return out


def diagnose(case, cfg, seeds: int, people: dict | None, cache: Path) -> dict:
    data = prepare(case, cache, cfg)
    trajs, outs = run_seeds(data, first_pose(data), Params(), cfg, seeds)
    gt = groundtruth(data)
    onp = on_people(data, people) if people is not None else None
    used = np.asarray(outs.static)
    ev = np.asarray(outs.evidence)
    prior = np.concatenate([np.zeros_like(ev[:, :1]), ev[:, :-1]], axis=1)
    weight = np.asarray(belief_weights(prior, Params())) * used
    return {"ate": [1e3 * trajectory_scores(gt, t)["ate_rmse_m"] for t in trajs],
            "pairs": np.nanmedian(np.stack([pair_errors(gt, t) for t in trajs]), axis=0),
            "used": used, "weight": weight, "evidence": ev, "onp": onp,
            "valid": np.asarray(data["flow_valid"]), "keyframes": outs.keyframes}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--config", nargs="*", default=[], type=config_setting)
    ap.add_argument("--cache", type=Path, default=Path("results/cache"))
    args = ap.parse_args(argv)
    case = next((c for c in cases() if c.kind == "people"), None)
    if case is None or not (data_root() / case.source / "associations.txt").is_file():
        print(f"the TUM walking clip is absent under {data_root()}: nothing to diagnose")
        return 0
    cfg = config_from(args.config)
    masks = people_masks(data_root() / case.source)
    print(machine_line())
    L = float(moving_logodds(Params()))
    runs = {"jaxvo": diagnose(case, cfg, args.seeds, masks, args.cache),
            "oracle": diagnose(reference_case(case), cfg, args.seeds, masks, args.cache)}
    onp = runs["jaxvo"]["onp"]  # the masks on the clip's own grid points
    recent = np.zeros_like(onp)
    for j in range(1, RECENT + 1):
        recent[j:] |= onp[:-j]
    for name, r in runs.items():
        used, weight, ev = r["used"], r["weight"], r["evidence"]
        room = r["valid"] & ~onp
        kf = ("" if r["keyframes"] is None
              else f", keyframes {int(np.median(r['keyframes'][:, -1]))}")
        print(f"\n{name}: ATE mm {np.round(r['ate'], 1).tolist()} (median "
              f"{np.median(r['ate']):.1f}){kf}")
        print(f"  points used on people: {100 * (used & onp).sum() / max(used.sum(), 1):.1f} %,"
              f" of the fit's weight {100 * (weight * onp).sum() / max(weight.sum(), 1e-9):.1f} %")
        for label, cells in ((f"room revealed (a person there <= {RECENT} frames before)",
                              room & recent), ("room, the rest", room & ~recent)):
            sel = np.broadcast_to(cells, ev.shape)
            e = ev[sel]
            print(f"  {label}: {cells.sum()} cells; moving {100 * np.mean(e > L):.1f} %, "
                  f"unestablished {100 * np.mean(np.abs(e) <= L):.1f} %, established static "
                  f"{100 * np.mean(e < -L):.1f} %, used {100 * np.mean(used[sel]):.1f} %")
    print("\npair: translation / rotation error (mm, deg; jaxvo | oracle), people's share of "
          "jaxvo's fit weight %, room points established static in jaxvo's fit | oracle's")
    j, o = runs["jaxvo"], runs["oracle"]
    share = np.median((j["weight"] * onp).sum(-1) / np.maximum(j["weight"].sum(-1), 1e-9), 0)
    est = lambda r: np.median(((r["weight"] >= 1) & ~onp).sum(-1), 0)  # noqa: E731
    ej, eo = est(j), est(o)
    for k in range(len(share)):
        print(f"{k:3d}  {j['pairs'][k, 0]:5.1f} / {j['pairs'][k, 1]:4.2f} | "
              f"{o['pairs'][k, 0]:5.1f} / {o['pairs'][k, 1]:4.2f}   {100 * share[k]:5.1f}   "
              f"{ej[k]:4.0f} | {eo[k]:4.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
