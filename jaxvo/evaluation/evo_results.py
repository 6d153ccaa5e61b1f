"""jaxvo's ATE / RPE results as evo writes them: result zips ``evo_res`` reads, and plots.

evo (github.com/MichaelGrupp/evo, GPL-3.0) is never imported: this is our own writer of its
documented file layout, so that ``jaxvo eval ... --save_results r.zip`` drops beside the zips
of ``evo_ape`` / ``evo_rpe --save_results`` and ``evo_res`` compares them. A result zip holds

* ``info.json``: ``title`` (evo's wording, e.g. ``"APE w.r.t. translation part (m)\\n(with
  SE(3) Umeyama alignment)"``: ``evo_res`` warns when titles differ, so results of the same
  metric must carry the same one), ``ref_name``, ``est_name``, ``label`` (``"APE (m)"``);
* ``stats.json``: rmse, mean, median, std, min, max, sse;
* ``.npy`` arrays: ``error_array`` (one error per pose or pair), ``timestamps`` (the
  estimate's stamps of those poses, seconds; for RPE the second pose of each pair),
  ``seconds_from_start``, ``distances`` and ``distances_from_start`` (path length along the
  aligned estimate and the ground truth, metres; for RPE along the poses the pairs visit) and,
  when aligned, ``alignment_transformation_sim3`` (4x4 ``[[s R, t], [0, 1]]``).

The plot is evo's two figures side by side: the errors over time with their rmse, median,
mean and a band of one std about the mean; and the trajectory (``plot_mode`` axes) with the
ground truth dashed grey and the estimate coloured by its error (``jet``, min to max).

Both are made in memory (:func:`result_zip`, :func:`result_figure`, :func:`figure_bytes`);
the host writes them (``jaxvo.host.writers.outputs.write_bytes``: whole or not at all), so that the
evaluation imports nothing of the host.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from jaxvo.errors import InputError

if TYPE_CHECKING:  # `jaxvo --help` builds eval's options from this module: kept light
    from jaxvo.evaluation.metrics import Alignment, AteResult, RpeResult, Stats

# evo's names of what an error measures (PoseRelation values) and of their units
RELATIONS = {
    "trans_part": ("translation part", "m"),
    "angle_deg": ("rotation angle in degrees", "deg"),
}
PLOT_MODES = ("xy", "xz", "yx", "yz", "zx", "zy", "xyz")
_STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")


class EvoResult(NamedTuple):
    """One metric's result in evo's layout (see the module docstring)."""

    info: dict[str, str]
    stats: dict[str, float]
    arrays: dict[str, np.ndarray]
    gt_poses: np.ndarray  # (k, 4, 4) the ground-truth poses the errors belong to, for plots
    est_poses: np.ndarray  # (k, 4, 4) the estimate's, aligned as the errors were taken


def _distances(positions: np.ndarray) -> np.ndarray:
    """(k,) path length from the first position to each, metres (evo's ``distances``)."""
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=-1)
    return np.concatenate([[0.0], np.cumsum(steps)])


def _stats(stats: Stats) -> dict[str, float]:
    return {k: float(getattr(stats, k)) for k in _STATS}


def _apply(alignment: Alignment | None, poses: np.ndarray) -> np.ndarray:
    return alignment.apply_poses(poses) if alignment is not None else poses


def ape_result(res: AteResult, *, ref_name: str, est_name: str, align_line: str) -> EvoResult:
    """``evo_ape``'s result for jaxvo's ATE (translation part, metres).

    Args:
      res: the ATE, with its matched poses.
      ref_name: the ground truth's name (evo: its file path).
      est_name: the estimate's name.
      align_line: evo's alignment line, from :func:`alignment_line`.
    Returns:
      :class:`EvoResult`.
    """
    m = res.matched
    est = _apply(res.alignment, m.est_poses)
    t = m.est_timestamps
    arrays = {
        "error_array": np.asarray(res.errors, np.float64),
        "seconds_from_start": t - t[0],
        "timestamps": t,
        "distances_from_start": _distances(m.gt_poses[:, :3, 3]),
        "distances": _distances(est[:, :3, 3]),
    }
    if res.alignment is not None:
        arrays["alignment_transformation_sim3"] = res.alignment.matrix()
    info = {
        "title": f"APE w.r.t. translation part (m)\n{align_line}",
        "ref_name": ref_name,
        "est_name": est_name,
        "label": "APE (m)",
    }
    return EvoResult(info, _stats(res.stats), arrays, m.gt_poses, est)


def rpe_result(res: RpeResult, relation: str, *, ref_name: str, est_name: str,
               align_line: str) -> EvoResult:
    """``evo_rpe``'s result for jaxvo's RPE, one error per pose pair.

    Args:
      res: the RPE, with its matched poses.
      relation: ``"trans_part"`` (metres) or ``"angle_deg"`` (degrees), evo's ``-r``.
      ref_name: the ground truth's name.
      est_name: the estimate's name.
      align_line: evo's alignment line, from :func:`alignment_line`.
    Returns:
      :class:`EvoResult`; its poses are those evo keeps for the plot: the first matched
      pose, then the second pose of each pair.
    """
    what, unit = RELATIONS[relation]
    m = res.matched
    errors, stats = ((res.trans_errors, res.trans) if relation == "trans_part"
                     else (res.rot_errors, res.rot))
    keep = np.concatenate([[0], res.pairs[:, 1]])
    est = _apply(res.alignment, m.est_poses)[keep]
    gt = m.gt_poses[keep]
    t = m.est_timestamps[keep]
    arrays = {
        "error_array": np.asarray(errors, np.float64),
        "seconds_from_start": (t - t[0])[1:],
        "timestamps": t[1:],
        "distances_from_start": _distances(gt[:, :3, 3])[1:],
        "distances": _distances(est[:, :3, 3])[1:],
    }
    if res.alignment is not None:
        arrays["alignment_transformation_sim3"] = res.alignment.matrix()
    delta_unit = "frames" if res.delta_unit == "frames" else "s"
    pairs = "all pairs" if res.all_pairs else "consecutive pairs"
    info = {
        "title": f"RPE w.r.t. {what} ({unit})\nfor delta = {res.delta:g} ({delta_unit}) "
                 f"using {pairs}\n{align_line}",
        "ref_name": ref_name,
        "est_name": est_name,
        "label": f"RPE ({unit})",
    }
    return EvoResult(info, _stats(stats), arrays, gt, est)


def alignment_line(*, align: bool, scale: bool) -> str:
    """evo's line saying how the estimate was aligned, for its ``-a`` / ``-s`` flags."""
    if align:
        return "(with Sim(3) Umeyama alignment)" if scale else "(with SE(3) Umeyama alignment)"
    return "(scale corrected)" if scale else "(not aligned)"


def result_zip(result: EvoResult) -> bytes:
    """``result`` as evo's result zip (``evo_res`` and evo's ``load_res_file`` read it).

    Args:
      result: from :func:`ape_result` or :func:`rpe_result`.
    Returns:
      the zip file's bytes.
    """
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        archive.writestr("info.json", json.dumps(result.info))
        archive.writestr("stats.json", json.dumps(result.stats))
        for name, array in result.arrays.items():
            buf = io.BytesIO()
            np.save(buf, np.asarray(array))
            archive.writestr(f"{name}.npy", buf.getvalue())
    return out.getvalue()


def require_matplotlib(path: str | Path | None = None) -> None:
    """Raise :class:`InputError` in one line when matplotlib (the ``plot`` extra) is absent,
    or when ``path``'s extension names no format matplotlib writes (checked before any work:
    matplotlib says so only when it saves)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise InputError("--plot needs matplotlib: pip install 'jaxvo[plot]'") from None
    if path is None:
        return
    from matplotlib.backend_bases import FigureCanvasBase

    formats = FigureCanvasBase.get_supported_filetypes()
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in formats:
        said = f"its extension .{ext}" if ext else "no extension"
        raise InputError(f"--plot {path}: {said} names no image format matplotlib writes; "
                         f"give one of {', '.join('.' + f for f in sorted(formats))}")


def result_image(path: str | Path, result: EvoResult, *, plot_mode: str = "xyz") -> bytes:
    """evo's two figures of ``result`` side by side, as the image file ``path`` holds them.

    Args:
      path: the image's name (``.png``, ``.pdf``, ``.svg``: matplotlib picks by extension).
      result: from :func:`ape_result` or :func:`rpe_result`.
      plot_mode: the axes of the trajectory panel, evo's ``--plot_mode`` (``xyz``: 3D).
    Returns:
      the image file's bytes.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(13, 5.5))
    _plot_errors(fig.add_subplot(1, 2, 1), result)
    axes = ["xyz".index(c) for c in plot_mode]
    ax = fig.add_subplot(1, 2, 2, projection="3d" if len(axes) == 3 else None)
    _plot_trajectory(fig, ax, result, axes)
    fig.tight_layout()
    data = figure_bytes(fig, path)
    plt.close(fig)
    return data


def figure_bytes(fig, path: str | Path) -> bytes:
    """``fig`` at 110 dpi as the image file ``path`` holds it (the format from the
    extension)."""
    out = io.BytesIO()
    fig.savefig(out, dpi=110, format=Path(path).suffix.lstrip(".").lower() or None)
    return out.getvalue()


def _plot_errors(ax, result: EvoResult) -> None:
    """evo's raw-value figure: the errors over seconds from start, with their statistics."""
    colours = iter(["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728"])
    x = result.arrays["seconds_from_start"]
    ax.plot(x, result.arrays["error_array"], color="grey", label=result.info["label"])
    st = result.stats
    for name in ("rmse", "median", "mean", "std"):
        colour = next(colours)
        if name == "std":
            ax.axhspan(st["mean"] - st["std"] / 2, st["mean"] + st["std"] / 2, color=colour,
                       alpha=0.5, label="std")
        else:
            ax.axhline(st[name], color=colour, linewidth=2.0, label=name)
    ax.set_xlabel("$t$ (s)")
    ax.set_ylabel(result.info["label"])
    ax.set_title(result.info["title"], fontsize=9)
    ax.legend(frameon=True)


def _plot_trajectory(fig, ax, result: EvoResult, axes: list[int]) -> None:
    """evo's map figure: ground truth dashed, the estimate coloured by its error."""
    import matplotlib as mpl

    names = "xyz"
    gt = result.gt_poses[:, :3, 3][:, axes]
    est = result.est_poses[:, :3, 3][:, axes]
    ax.plot(*gt.T, linestyle="--", color="#444444", alpha=0.5, label="reference")
    err = result.arrays["error_array"]
    # a segment takes the error of the pose it ends at (ATE) or of the pair it closes (RPE,
    # whose poses start with the first matched one: one more pose than errors)
    colours = err[1:] if len(err) == len(est) else err
    norm = mpl.colors.Normalize(vmin=float(err.min()), vmax=float(err.max()))
    cmap = mpl.colormaps["jet"]
    segments = np.stack([est[:-1], est[1:]], axis=1)  # one segment per pose, its colour
    if len(axes) == 3:
        from mpl_toolkits.mplot3d.art3d import Line3DCollection

        lines = Line3DCollection(segments, cmap=cmap, norm=norm, linewidths=1.5)
        lines.set_array(colours)
        ax.add_collection3d(lines)
    else:
        lines = mpl.collections.LineCollection(segments, cmap=cmap, norm=norm, linewidths=1.5)
        lines.set_array(colours)
        ax.add_collection(lines)
    ax.scatter(*est[0], marker="o", color="black", label="start")
    ax.scatter(*est[-1], marker="x", color="black", label="end")
    fig.colorbar(mpl.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax,
                 label=result.info["label"])
    labels = [f"${names[i]}$ (m)" for i in axes]
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    if len(axes) == 3:
        ax.set_zlabel(labels[2])
    else:
        ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(result.info["title"], fontsize=9)
    ax.legend(frameon=True)
