"""Two or more settings compared over the composites' draws, not over one composite.

A composite is one draw of its boxes (their textures, paths and the sensor noise on them:
the composite's seed), and ``bench_seeds.py`` varies only the method's seeds over it. A setting
can then win or lose a composite by the draw: a ±0.05 change of ``keyframe_overlap``,
which only moves when keyframes are taken, moved the validation three_boxes from 22.4 to
41.6 mm with keyframes on (docs/report/keyframes.md). The ``draws``
split (``bench/splits.py``) holds each composite at five more draws on the validation
frames; this script reads the ``seeds.json`` of ``bench_seeds.py --split draws`` run once
per setting and gives, per scenario:

* the best OpenCV peer's ATE on the same frames, over the draws: median [best-worst];
* each setting's ATE pooled over every draw and seed: median [best-worst];
* the same for its oracle (the boxes' depth removed);
* against the first setting, draw by draw: the ratio of the medians over seeds, its median
  over the draws [lowest-highest], and in how many draws the setting is within 5 % or better.

    .venv/bin/python bench/compare_draws.py results/draws_off results/draws_keyframes
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

import numpy as np
from _common import markdown_table
from bench_seeds import fmt_spread, spread

WITHIN = 1.05  # "within 5 % or better"
_DRAW = re.compile(r"^(?P<scenario>.+)_draw(?P<draw>\d+)$")


def by_scenario(rows: list[dict], key: str = "ate_mm") -> dict[str, dict[int, list[float]]]:
    """Each scenario's per-seed figures ``key`` by draw, from ``seeds.json`` rows named
    ``<scenario>_draw<k>`` (other rows and rows without the figure are left out); a figure
    of one number (the best peer's) is one value."""
    out: dict[str, dict[int, list[float]]] = {}
    for r in rows:
        m = _DRAW.match(r["case"])
        figure = r.get(key)
        values = (figure.get("values") if isinstance(figure, dict)
                  else [figure] if isinstance(figure, (int, float)) else None)
        if m and values:
            out.setdefault(m["scenario"], {})[int(m["draw"])] = list(values)
    return out


def pooled(draws: dict[int, list[float]]) -> str:
    """Every draw's figures together, as ``median [best-worst]``."""
    return fmt_spread(spread(np.concatenate([np.asarray(x, np.float64)
                                             for x in draws.values()])))


def paired(base: dict[int, list[float]], other: dict[int, list[float]]) -> str:
    """The per-draw ratio of ``other``'s median to ``base``'s, over the draws both have."""
    common = sorted(set(base) & set(other))
    if not common:
        return "-"
    r = np.array([np.median(other[k]) / np.median(base[k]) for k in common])
    return (f"{np.median(r):.2f} [{r.min():.2f}-{r.max():.2f}], "
            f"{int(np.sum(r <= WITHIN))}/{len(r)} within 5 %")


def load(folder: Path) -> tuple[str, list[dict]]:
    """A run's title and rows; ``ValueError`` saying why in one line when it has none."""
    path = folder / "seeds.json"
    if not path.is_file():
        raise ValueError(f"{path} not found (run bench/bench_seeds.py --split draws "
                         f"--out {folder})")
    try:
        doc = json.loads(path.read_text())
    except ValueError as e:
        raise ValueError(f"{path} is not JSON ({e})") from None
    rows = doc.get("rows") if isinstance(doc, dict) else None
    if not isinstance(rows, list) or not all(isinstance(r, dict) and "case" in r for r in rows):
        raise ValueError(f"{path} is not a bench_seeds.py result (no rows with a case)")
    meta = doc.get("meta")
    title = (meta.get("title") if isinstance(meta, dict) else None) or folder.name
    return title, rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="bench_seeds.py --out folders, the "
                    "first the setting the others are compared with")
    args = ap.parse_args(argv)
    try:
        runs = [load(f) for f in args.runs]
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    ates = [by_scenario(rows) for _, rows in runs]
    oracles = [by_scenario(rows, "oracle_ate_mm") for _, rows in runs]
    scenarios = sorted(set().union(*ates))
    if not scenarios:
        print("error: no <scenario>_draw<k> rows in these runs", file=sys.stderr)
        return 2
    peers = by_scenario(runs[0][1], "best_peer_mm")  # the same frames in every run
    head = ["scenario", "draws", "best OpenCV peer mm"]
    for i, (title, _) in enumerate(runs):
        head += [f"{title}: ATE mm", "oracle"] + ([f"{title} / {runs[0][0]}"] if i else [])
    cells = []
    for s in scenarios:
        row = [s, str(len(ates[0].get(s, {}))), pooled(peers[s]) if s in peers else "-"]
        for i in range(len(runs)):
            a, o = ates[i].get(s), oracles[i].get(s)
            row += [pooled(a) if a else "-", pooled(o) if o else "-"]
            if i:
                row.append(paired(ates[0][s], a) if a and s in ates[0] else "-")
        cells.append(row)
    print(f"ATE over every draw and seed, median [best-worst]; ratios per draw of the medians "
          f"over seeds ({', '.join(str(f) for f in args.runs)})\n")
    print(markdown_table(head, cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
