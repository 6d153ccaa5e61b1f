"""``jaxvo eval``: score an estimated trajectory against ground truth (ATE, RPE).

Both files are TUM trajectories (``timestamp tx ty tz qx qy qz qw``, camera-to-world).
The table is for people; ``--json`` prints one JSON object for scripts.
"""

from __future__ import annotations

import argparse
import json

_STAT_FIELDS = ("rmse", "mean", "median", "std", "min", "max")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.epilog = (
        "examples:\n"
        "  jaxvo eval ate groundtruth.txt estimate.txt\n"
        "  jaxvo eval rpe groundtruth.txt estimate.txt --delta 1 --delta-unit seconds --json"
    )
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    sub = parser.add_subparsers(dest="metric", metavar="METRIC")
    sub.required = True

    p = sub.add_parser(
        "ate",
        help="absolute trajectory error (thesis eqs. 5.6-5.8), metres",
        description="Absolute trajectory error: the estimate is aligned onto the ground "
        "truth by a rigid Umeyama fit of the matched positions (no scale unless --scale), "
        "then the distance of each matched position is summarised.",
    )
    _common(p)
    p.add_argument("--scale", action="store_true", help="also fit a scale (Sim(3) alignment)")
    p.add_argument(
        "--no-align", dest="align", action="store_false", help="compare the trajectories as given"
    )

    p = sub.add_parser(
        "rpe",
        help="relative pose error (thesis eqs. 5.4, 5.5), metres and degrees",
        description="Relative pose error over pose pairs DELTA apart: translational drift "
        "(m) and rotational drift (deg). Frames: evo's consecutive pairs (0,d), (d,2d), ...; "
        "seconds: every pose paired with the one nearest t + DELTA (TUM evaluate_rpe).",
    )
    _common(p)
    p.add_argument("--delta", type=float, default=1.0, help="pair spacing (default 1)")
    p.add_argument(
        "--delta-unit",
        choices=("frames", "seconds"),
        default="frames",
        help="unit of --delta (default frames)",
    )
    pairs = p.add_mutually_exclusive_group()
    pairs.add_argument(
        "--all-pairs",
        dest="all_pairs",
        action="store_const",
        const=True,
        help="every start pose (default with seconds)",
    )
    pairs.add_argument(
        "--consecutive-pairs",
        dest="all_pairs",
        action="store_const",
        const=False,
        help="non-overlapping consecutive pairs (default with frames, as evo)",
    )


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("gt", metavar="GT", help="ground-truth trajectory, TUM format")
    p.add_argument("est", metavar="EST", help="estimated trajectory, TUM format")
    p.add_argument(
        "--max-diff",
        type=float,
        default=0.02,
        metavar="S",
        help="largest time difference of matched poses, seconds (default 0.02)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")


def run(args: argparse.Namespace) -> int:
    from jaxvo.errors import InputError
    from jaxvo.evaluation import metrics
    from jaxvo.host.io import read_trajectory

    if not args.max_diff >= 0:
        raise InputError(f"--max-diff must be >= 0 seconds, got {args.max_diff}")
    gt = read_trajectory(args.gt)
    est = read_trajectory(args.est)
    names = (args.gt, args.est)
    if args.metric == "ate":
        res = metrics.ate(
            gt, est, max_diff=args.max_diff, align=args.align, scale=args.scale, names=names
        )
        report = _ate_report(args, res, len(gt), len(est))
    else:
        delta = args.delta
        if args.delta_unit == "frames":
            if delta != int(delta):
                raise InputError(f"--delta in frames must be a whole number, got {delta:g}")
            delta = int(delta)
        res = metrics.rpe(
            gt,
            est,
            delta=delta,
            delta_unit=args.delta_unit,
            max_diff=args.max_diff,
            all_pairs=args.all_pairs,
            names=names,
        )
        report = _rpe_report(args, res, len(gt), len(est))
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print(_table(report))
    return 0


def _report_head(metric: str, args, res, n_gt: int, n_est: int) -> dict:
    """The fields every report starts with: what was compared and how it was associated."""
    return {
        "metric": metric,
        "gt": args.gt,
        "est": args.est,
        "poses_gt": n_gt,
        "poses_est": n_est,
        "pairs": res.num_pairs,
        "max_diff_s": res.max_diff,
    }


def _ate_report(args, res, n_gt: int, n_est: int) -> dict:
    if res.alignment is None:
        alignment = "none"
    else:
        alignment = "Sim(3) Umeyama" if args.scale else "SE(3) Umeyama (rigid, no scale)"
    return {
        **_report_head("ate", args, res, n_gt, n_est),
        "alignment": alignment,
        "scale": res.alignment.scale if res.alignment is not None else 1.0,
        "results": {"trans": {"unit": "m", **res.stats.as_dict()}},
    }


def _rpe_report(args, res, n_gt: int, n_est: int) -> dict:
    return {
        **_report_head("rpe", args, res, n_gt, n_est),
        "delta": res.delta,
        "delta_unit": res.delta_unit,
        "all_pairs": res.all_pairs,
        "results": {
            "trans": {"unit": "m", **res.trans.as_dict()},
            "rot": {"unit": "deg", **res.rot.as_dict()},
        },
    }


def _table(report: dict) -> str:
    lines = [f"ground truth  {report['gt']}  ({report['poses_gt']} poses)"]
    lines.append(f"estimate      {report['est']}  ({report['poses_est']} poses)")
    if report["metric"] == "ate":
        lines.append("metric        ATE, absolute trajectory error")
        scale = f", scale {report['scale']:.6f}" if report["alignment"].startswith("Sim") else ""
        lines.append(f"alignment     {report['alignment']}{scale}")
        what = "matched poses"
    else:
        kind = "all pairs" if report["all_pairs"] else "consecutive pairs"
        lines.append("metric        RPE, relative pose error")
        lines.append(f"delta         {report['delta']:g} {report['delta_unit']} ({kind})")
        what = "pose pairs"
    lines.append(
        f"{what:<13} {report['pairs']} (timestamps matched within {report['max_diff_s']:g} s)"
    )
    lines.append("")
    header = f"{'':<16}" + "".join(f"{f:>11}" for f in _STAT_FIELDS)
    lines.append(header)
    for key, label in (("trans", "translation"), ("rot", "rotation")):
        if key not in report["results"]:
            continue
        r = report["results"][key]
        row = f"{label + ' [' + r['unit'] + ']':<16}" + "".join(
            f"{r[f]:>11.6f}" for f in _STAT_FIELDS
        )
        lines.append(row)
    return "\n".join(lines)
