"""``jaxvo eval``: score an estimated trajectory against ground truth (ATE, RPE).

Both files are TUM trajectories (``timestamp tx ty tz qx qy qz qw``, camera-to-world).
The table is for people; ``--json`` prints one JSON object for scripts; ``--save_results``
writes evo's result zip (``evo_res`` compares it with evo's own) and ``--plot`` evo's
figures (:mod:`jaxvo.evaluation.evo_results`). evo's option names are accepted where they mean the same.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

_STAT_FIELDS = ("rmse", "mean", "median", "std", "min", "max")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from jaxvo.cli.later import Later

    parser.epilog = (
        "examples:\n"
        "  jaxvo eval ate groundtruth.txt estimate.txt\n"
        "  jaxvo eval rpe groundtruth.txt estimate.txt --delta 1 --delta-unit seconds --json\n"
        "  jaxvo eval ate gt.txt est.txt --save_results jaxvo.zip --plot ate.png\n"
        "  evo_ape tum gt.txt other.txt -a --save_results other.zip\n"
        "  evo_res jaxvo.zip other.zip\n\n"
        "evo's options: -a/--align, -s/--correct_scale (-as: Sim(3)), --t_max_diff, --delta,\n"
        "--delta_unit f, --all_pairs, -r/--pose_relation, --plot_mode, --save_results mean what\n"
        "they mean in evo_ape / evo_rpe. Unlike evo_ape, jaxvo eval ate aligns (rigidly) by\n"
        "default (--no-align: as given), and matches timestamps within 0.02 s (evo: 0.01)."
    )
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    sub = parser.add_subparsers(dest="metric", metavar="METRIC")
    sub.required = True

    p = sub.add_parser(
        "ate",
        help="absolute trajectory error (thesis eqs. 5.6-5.8), metres",
        description="Absolute trajectory error: the estimate is aligned onto the ground "
        "truth by a rigid Umeyama fit of the matched positions (Sim(3) with --scale or -as; "
        "--no-align --scale or -s alone: the scale only), then the distance of each matched "
        "position is summarised.",
    )
    _common(p)
    p.add_argument("--scale", action="store_true",
                   help="also fit a scale: with the alignment Sim(3), as evo's -as; with "
                   "--no-align the scale alone, as evo's -s")
    p.add_argument("--no-align", dest="align", action="store_false",
                   help="compare the trajectories as given (evo_ape without -a)")

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
        "--delta-unit", "--delta_unit", "-u",
        default="frames",
        help="unit of --delta: frames (evo's f, the default) or seconds; evo's d, r, m "
        "(degrees, radians, metres travelled) are not offered",
    )
    p.add_argument("-r", "--pose_relation", default="trans_part", metavar="RELATION",
                   choices=Later("jaxvo.evaluation.evo_results", "RELATIONS", sorted),
                   help="the error --save_results and --plot carry: trans_part (m, the "
                   "default) or angle_deg (evo's names); the table shows both")
    pairs = p.add_mutually_exclusive_group()
    pairs.add_argument(
        "--all-pairs", "--all_pairs",
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
    from jaxvo.cli.later import Later

    p.add_argument("gt", metavar="GT", help="ground-truth trajectory, TUM format")
    p.add_argument("est", metavar="EST", help="estimated trajectory, TUM format; - (or "
                   "/dev/stdin) reads it from standard input: jaxvo run SEQ --out - | jaxvo "
                   "eval ate GT -")
    p.add_argument("-a", "--align", dest="align", action="store_const", const=True,
                   default=None, help="rigid Umeyama alignment (evo's -a; jaxvo's ATE default)")
    p.add_argument("-s", "--correct_scale", action="store_true",
                   help="evo's -s: with -a a Sim(3) alignment (-as), alone only the scale")
    p.add_argument(
        "--max-diff", "--t_max_diff",
        type=float,
        default=0.02,
        metavar="S",
        help="largest time difference of matched poses, seconds (default 0.02)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--save_results", "--save-results", metavar="FILE.zip",
                   help="write the result as evo's result zip, which evo_res reads")
    p.add_argument("--plot", metavar="FILE",
                   help="draw evo's figures (errors over time, trajectory coloured by error) "
                   "into an image whose extension gives the format (.png, .pdf, .svg, .jpg, .eps, "
                   ".tiff, ...: matplotlib's); needs matplotlib (jaxvo[plot])")
    p.add_argument("--plot_mode", "--plot-mode", default="xyz", metavar="MODE",
                   choices=Later("jaxvo.evaluation.evo_results", "PLOT_MODES"),
                   help="axes of the trajectory panel: %(choices)s (default xyz, 3D, as evo)")


def _alignment(args) -> tuple[bool, bool]:
    """(align, scale) from jaxvo's and evo's flags: ``-a`` / ``--no-align`` / jaxvo's default
    (ATE aligned, RPE not: it needs no alignment); ``-s`` with the alignment Sim(3), alone
    only the scale (evo's meaning); ``--scale`` Sim(3) (``-as``)."""
    scale = args.correct_scale or getattr(args, "scale", False)
    if getattr(args, "scale", False):
        return args.align is not False, True
    if args.align is None:
        return (args.metric == "ate" and not args.correct_scale), scale
    return args.align, scale


def _delta_unit(text: str) -> str:
    """``frames`` or ``seconds`` from jaxvo's or evo's spelling (InputError otherwise)."""
    from jaxvo.errors import InputError

    units = {"frames": "frames", "f": "frames", "seconds": "seconds", "s": "seconds"}
    if text not in units:
        raise InputError(f"--delta_unit {text!r}: jaxvo pairs poses by frames (f) or seconds; "
                         "evo's d, r and m (degrees, radians, metres travelled) are not offered")
    return units[text]


def _outputs(args) -> None:
    """Check --save_results and --plot before any work (InputError), before NumPy loads
    but where only matplotlib can judge --plot's format (:func:`_check_plot`)."""
    from jaxvo.host.writers.outputs import check_outputs, output_file

    given = {option: Path(p) for option, p in (("--save_results", args.save_results),
                                               ("--plot", args.plot)) if p}
    check_outputs((Path(args.gt), Path(args.est)), files=given)
    if args.plot:
        _check_plot(args.plot)
    for option, path in given.items():
        output_file(path, what=option)


# image formats that every matplotlib jaxvo[plot] takes writes (FigureCanvasBase's default
# file types; tests/test_startup.py holds them to the installed one's)
PLOT_FORMATS = frozenset({"eps", "jpeg", "jpg", "pdf", "png", "ps", "svg", "svgz", "tif",
                          "tiff"})


def _check_plot(path: str) -> None:
    """``require_matplotlib(path)``, which imports matplotlib (and NumPy), asked only where
    its answer is not known without: matplotlib installed and ``path`` one of
    :data:`PLOT_FORMATS` pass it, as they would there."""
    import importlib.util

    if (importlib.util.find_spec("matplotlib") is not None
            and Path(path).suffix.lower().lstrip(".") in PLOT_FORMATS):
        return
    from jaxvo.evaluation.evo_results import require_matplotlib

    require_matplotlib(path)


def _delta(args) -> tuple[float | int, str]:
    """RPE's ``(delta, unit)`` from --delta and --delta_unit, checked (InputError)."""
    import math

    from jaxvo.errors import InputError

    unit = _delta_unit(args.delta_unit)
    delta = args.delta
    if not (math.isfinite(delta) and delta > 0):
        raise InputError(f"--delta must be a positive number of {unit}, got {delta:g}")
    if unit == "frames":
        if delta != int(delta):
            raise InputError(f"--delta in frames must be a whole number, got {delta:g}")
        delta = int(delta)
    return delta, unit


def prepare(args: argparse.Namespace) -> tuple[float | int | None, str | None]:
    """The options, the outputs and the two files checked in the order they always were,
    before NumPy loads: ``(delta, unit)`` for :func:`run` (None, None for ATE). Only a
    --plot format that matplotlib alone can judge, or matplotlib missing, loads it
    (:func:`_check_plot`), still before the files."""
    import math

    from jaxvo.cli.inputs import require_trajectory
    from jaxvo.errors import InputError

    if not (math.isfinite(args.max_diff) and args.max_diff >= 0):
        raise InputError(f"--max-diff must be a number of seconds >= 0, got {args.max_diff}")
    delta, unit = _delta(args) if args.metric == "rpe" else (None, None)
    if args.save_results or args.plot:
        _outputs(args)
    if sum(_is_stdin(p) for p in (args.gt, args.est)) > 1:
        raise InputError("only one of the trajectories can come from standard input (-)")
    require_trajectory(args.gt)
    require_trajectory(args.est)
    return delta, unit


def run(args: argparse.Namespace, prepared: tuple | None = None) -> int:
    from jaxvo.evaluation import evo_results, metrics
    from jaxvo.host.writers.outputs import write_bytes
    from jaxvo.trajectory import read_trajectory

    delta, unit = prepared or prepare(args)
    if args.plot:  # one line, not a traceback, where matplotlib is there but fails to import
        evo_results.require_matplotlib(args.plot)
    align, scale = _alignment(args)
    gt = read_trajectory(args.gt)
    est = read_trajectory(args.est)
    names = (args.gt, args.est)
    line = evo_results.alignment_line(align=align, scale=scale)
    if args.metric == "ate":
        res = metrics.ate(gt, est, max_diff=args.max_diff, align=align, scale=scale, names=names)
        report = _ate_report(args, res, len(gt), len(est), line)
        evo = evo_results.ape_result(res, ref_name=args.gt, est_name=args.est, align_line=line)
    else:
        res = metrics.rpe(gt, est, delta=delta, delta_unit=unit, max_diff=args.max_diff,
                          all_pairs=args.all_pairs, align=align, scale=scale, names=names)
        report = _rpe_report(args, res, len(gt), len(est), line)
        evo = evo_results.rpe_result(res, args.pose_relation, ref_name=args.gt,
                                     est_name=args.est, align_line=line)
    if args.save_results:
        write_bytes(args.save_results, evo_results.result_zip(evo))
    if args.plot:
        write_bytes(args.plot, evo_results.result_image(args.plot, evo,
                                                        plot_mode=args.plot_mode))
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print(_table(report))
    return 0


def _is_stdin(path: str) -> bool:
    """``-``, or a path that is this process's standard input (``/dev/stdin``)."""
    import os

    if path == "-":
        return True
    try:
        return os.path.samestat(os.stat(path), os.fstat(0))
    except (OSError, ValueError):
        return False


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


# evo's alignment line -> the words of jaxvo's table and JSON
_ALIGNMENT_WORDS = {
    "(not aligned)": "none",
    "(with SE(3) Umeyama alignment)": "SE(3) Umeyama (rigid, no scale)",
    "(with Sim(3) Umeyama alignment)": "Sim(3) Umeyama",
    "(scale corrected)": "scale only (Umeyama's scale)",
}


def _alignment_fields(res, line: str) -> dict:
    return {
        "alignment": _ALIGNMENT_WORDS[line],
        "scale": res.alignment.scale if res.alignment is not None else 1.0,
    }


def _ate_report(args, res, n_gt: int, n_est: int, line: str) -> dict:
    return {
        **_report_head("ate", args, res, n_gt, n_est),
        **_alignment_fields(res, line),
        "results": {"trans": {"unit": "m", **res.stats.as_dict()}},
    }


def _rpe_report(args, res, n_gt: int, n_est: int, line: str) -> dict:
    return {
        **_report_head("rpe", args, res, n_gt, n_est),
        **_alignment_fields(res, line),
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
        what = "matched poses"
    else:
        kind = "all pairs" if report["all_pairs"] else "consecutive pairs"
        lines.append("metric        RPE, relative pose error")
        lines.append(f"delta         {report['delta']:g} {report['delta_unit']} ({kind})")
        what = "pose pairs"
    scaled = report["alignment"].startswith(("Sim", "scale"))
    scale = f", scale {report['scale']:.6f}" if scaled else ""
    lines.append(f"alignment     {report['alignment']}{scale}")
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
