"""A study's results as files (host side): the tidy table, the summary over seeds, plots.

Files written under the study's folder by :func:`write_report`:

* ``results.csv`` / ``results.json``: one row per run (sequence, every setting the spec
  names and every ``Params`` field, seed, every metric of :data:`jaxvo.study.spec.METRICS`,
  whether the ATE was aligned, and a digest of the run's raw outputs: equal digests,
  equal bits); an empty cell (``null``) where a sequence has nothing to
  score a metric against (no ground truth, no masks, under 1 s for the per-second RPE);
* ``summary.csv`` / ``summary.json`` / ``summary.md``: per sequence and configuration, the
  spec's metrics over the seeds: mean, standard deviation (population), min, max, count;
* ``plot.png``: each metric against each swept setting (needs matplotlib, the ``plot``
  extra; without it the plot is skipped and :func:`write_report` says so).
"""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import numpy as np

from jaxvo.config import Params
from jaxvo.evaluation.evo_results import figure_bytes
from jaxvo.host.writers.outputs import write_bytes, write_text
from jaxvo.study.spec import METRICS, StudySpec


def table_columns(spec: StudySpec) -> list[str]:
    """Columns of the results table, in order."""
    settings = list(spec.settings) + [f for f in Params._fields if f not in spec.settings]
    return ["sequence", *settings, "seed", *METRICS, "ate_aligned", "digest"]


def tidy_rows(spec: StudySpec, rows: list[dict]) -> list[dict]:
    """The rows with every table column (a ``Params`` field the spec leaves alone takes its
    default, a metric with nothing to score against None)."""
    defaults = Params()._asdict()
    return [{c: row.get(c, defaults.get(c)) for c in table_columns(spec)} for row in rows]


def summarise(spec: StudySpec, rows: list[dict]) -> list[dict]:
    """Per sequence and configuration: each of the spec's metrics over the seeds.

    Returns:
      One dict per (sequence, configuration) in the spec's order: ``sequence``, every
      setting the spec names, ``seeds`` (how many runs), and ``<metric>_mean``, ``_std``
      (population, as numpy's default), ``_min``, ``_max`` over the runs that have a
      value (None when none has).
    """
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        key = (row["sequence"], *(_key(row[k]) for k in spec.settings))
        groups.setdefault(key, []).append(row)
    out = []
    for key, group in groups.items():
        entry = {"sequence": key[0], **{k: group[0][k] for k in spec.settings},
                 "seeds": len(group)}
        for m in spec.metrics:
            v = np.asarray([r[m] for r in group if r.get(m) is not None], np.float64)
            stats = (v.mean(), v.std(), v.min(), v.max()) if v.size else (None,) * 4
            entry.update({f"{m}_{s}": None if x is None else float(x)
                          for s, x in zip(("mean", "std", "min", "max"), stats, strict=True)})
        out.append(entry)
    return out


def _key(v):
    return json.dumps(v)


def write_csv(path: Path, rows: list[dict], columns: list[str]) -> None:
    """``rows`` as a CSV table, written whole or not at all."""
    import io

    with io.StringIO(newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns)
        w.writeheader()
        for row in rows:
            w.writerow({c: "" if row.get(c) is None else row[c] for c in columns})
        text = fh.getvalue()
    write_text(path, text)


def display(metric: str) -> tuple[str, float]:
    """How a metric reads in the Markdown table and the plot: ``(label, scale)``, lengths
    in millimetres (``ate_rmse_m`` -> ``("ate_rmse [mm]", 1000.0)``); the files keep SI."""
    m = re.fullmatch(r"(.+)_(m|deg)(?:_per_(frame|s))?", metric)
    if m is None:
        return (f"{metric} [s]", 1.0) if metric == "seconds" else (metric, 1.0)
    unit = "mm" if m[2] == "m" else "deg"
    return (f"{m[1]} [{unit}{'/' + m[3] if m[3] else ''}]",
            1000.0 if m[2] == "m" else 1.0)


def summary_markdown(spec: StudySpec, summary: list[dict], *, title: str | None = None) -> str:
    """The summary as a Markdown table: swept settings, seeds, each metric's mean ± std
    (lengths in mm, see :func:`display`)."""
    head = ["sequence", *spec.swept, "seeds", *(display(m)[0] for m in spec.metrics)]
    lines = [f"# {title or spec.name}", "",
             f"Mean ± standard deviation (population) over {len(spec.seeds)} seed(s) "
             f"({', '.join(map(str, spec.seeds))}); settings not listed are at "
             + (", ".join(f"{k} = {spec.base[k]:g}" if isinstance(spec.base[k], float)
                          else f"{k} = {spec.base[k]}" for k in spec.settings
                          if k not in spec.swept) or "their defaults")
             + ".", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for e in summary:
        cells = [e["sequence"], *(_fmt(e[k]) for k in spec.swept), str(e["seeds"])]
        for m in spec.metrics:
            mean, std = e[f"{m}_mean"], e[f"{m}_std"]
            scale = display(m)[1]
            cells.append("n/a" if mean is None else f"{mean * scale:.3g} ± {std * scale:.2g}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _fmt(x) -> str:
    if isinstance(x, float):
        return f"{x:.4g}"
    return str(x)


def plot_points(spec: StudySpec, summary: list[dict], setting: str, metric: str):
    """Per sequence, ``(values, means, stds)`` of ``metric`` against ``setting``.

    At each value of ``setting``, the configurations whose other swept settings are at
    their base values (``fixed``, else the defaults) when the spec has any such (a sweep
    around the base, or a grid through it), else every configuration with that value,
    averaged: the mean over those configurations of the mean over seeds, and the mean of
    the standard deviations over seeds.
    """
    others = [k for k in spec.swept if k != setting]
    out = {}
    for seq in dict.fromkeys(e["sequence"] for e in summary):
        entries = [e for e in summary if e["sequence"] == seq
                   and e.get(f"{metric}_mean") is not None]
        at_base = [e for e in entries if all(_key(e[k]) == _key(spec.base[k]) for k in others)]
        values = sorted({e[setting] for e in entries}, key=float)
        pts = []
        for v in values:
            chosen = [e for e in at_base if e[setting] == v] or \
                     [e for e in entries if e[setting] == v]
            pts.append((float(v), float(np.mean([e[f"{metric}_mean"] for e in chosen])),
                        float(np.mean([e[f"{metric}_std"] for e in chosen]))))
        if pts:
            out[seq] = tuple(np.asarray(p) for p in zip(*pts, strict=True))
    return out


def write_plot(spec: StudySpec, summary: list[dict], path: Path) -> str | None:
    """Each metric (rows) against each swept setting (columns) in one PNG.

    Returns:
      None when written, else why not (no swept setting, or no matplotlib).
    """
    numeric = [k for k in spec.swept
               if all(isinstance(e[k], int | float) and not isinstance(e[k], bool)
                      for e in summary)]
    if not numeric:
        return "no numeric setting is swept"
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "matplotlib is not installed (pip install 'jaxvo[plot]')"
    rows, cols = len(spec.metrics), len(numeric)
    height = 2.8 * rows + 0.7  # and the legend above, the caption below
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, height), squeeze=False)
    for i, metric in enumerate(spec.metrics):
        for j, setting in enumerate(numeric):
            ax = axes[i][j]
            label, scale = display(metric)
            for seq, (x, y, s) in plot_points(spec, summary, setting, metric).items():
                ax.errorbar(x, y * scale, yerr=s * scale, marker="o", ms=3, capsize=2,
                            label=seq)
            values = [float(e[setting]) for e in summary]
            if min(values) > 0 and max(values) / min(values) >= 20:
                ax.set_xscale("log")  # lambda, delta: decades apart
            ax.axvline(float(spec.base[setting]), color="0.7", lw=0.8, ls=":")
            ax.set_xlabel(setting)
            if j == 0:
                ax.set_ylabel(label)
            ax.grid(True, alpha=0.3)
    handles, labels = axes[0][0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper center", ncol=min(len(labels), 4),
                   fontsize="small", frameon=False)
    fig.suptitle(f"{spec.name}: mean over {len(spec.seeds)} seed(s), bars one standard "
                 "deviation; dotted: base value", fontsize="small", y=0.005, va="bottom")
    fig.tight_layout(rect=(0, 0.3 / height, 1, 1 - 0.4 / height))
    write_bytes(path, figure_bytes(fig, path))
    plt.close(fig)
    return None


def write_report(spec: StudySpec, rows: list[dict], out_dir: str | Path, *,
                 plot: bool = True) -> dict[str, str]:
    """Write the table, the summary and the plot of ``rows`` (runs of ``spec``), each file
    whole or not at all (:class:`jaxvo.host.writers.outputs.OutputFile`; a failure, e.g. a full
    disk, raises ``OSError`` naming the file).

    Returns:
      ``{file name: what happened}``: "written", or why a file was skipped.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tidy = tidy_rows(spec, rows)
    columns = table_columns(spec)
    write_csv(out / "results.csv", tidy, columns)
    write_text(out / "results.json", json.dumps(_finite(tidy), indent=1) + "\n")
    summary = summarise(spec, rows)
    write_csv(out / "summary.csv", summary, list(summary[0]) if summary else ["sequence"])
    write_text(out / "summary.json", json.dumps(_finite(summary), indent=1) + "\n")
    write_text(out / "summary.md", summary_markdown(spec, summary))
    status = dict.fromkeys(("results.csv", "results.json", "summary.csv", "summary.json",
                            "summary.md"), "written")
    if plot and summary:
        why = write_plot(spec, summary, out / "plot.png")
        status["plot.png"] = why or "written"
    return status


def _finite(x):
    """JSON has no NaN: a non-finite float becomes null."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return x
