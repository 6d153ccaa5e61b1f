"""Which way of taking jaxvo's dynamic pixels out of ORB-SLAM3's input serves it on the TUM
walking clip (two people walking), the case the plug-in is for (issue 37).

``orbslam3_peer.CHOSEN`` was first chosen on the dev split (colour and depth masked, grown
8 px; composites, whose objects are boxes), within ORB-SLAM3's spread; on the clip
depth-only masks, not grown (what ``jaxvo run --dynamic-masks`` writes), looked better, and
this comparison made them the choice (docs/report/orbslam3_clip_masking.md). Here every
variant of ``orbslam3_peer.VARIANTS`` runs ``--repeats`` times on the same masks (one
streaming pass of jaxvo: it is deterministic), each run's distance taken from the
reference of ``bench_orbslam3.py`` (the medoid of 5 runs of ORB-SLAM3 with the depth under
the hand-drawn people masks set to 0), beside ORB-SLAM3 with those hand-drawn masks.

Run: ``.venv/bin/python bench/orbslam3_clip_masking.py [--repeats 6] [--out results/]``.
Writes ``orbslam3_clip_masking.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import orbslam3_peer as orb
from _common import TUM_WALKING, load_average, log, machine, markdown_table
from bench_orbslam3 import jaxvo_pass, orb_rows, people_reference

from jaxvo.host.readers.io import InMemorySequence, data_root, open_sequence

HAND = "hand-drawn people masks, depth"


def _mm(x: float) -> str:
    return f"{1e3 * x:.1f}"


def report(res: dict) -> str:
    m = res["meta"]
    ref = res["reference"]["others_from_it_m"]
    rows = []
    for name, r in res["rows"].items():
        errs = sorted(x["error_m"] for x in r["runs"])
        rows.append([name + (" (CHOSEN now)" if name == orb.CHOSEN.name else ""),
                     f"{_mm(r['error_m'])} [{_mm(r['error_min_m'])}-{_mm(r['error_max_m'])}]",
                     ", ".join(_mm(e) for e in errs),
                     "/".join(str(x["tracked"]) for x in r["runs"])])
    best = min((n for n in res["rows"] if n != HAND), key=lambda n: res["rows"][n]["error_m"])
    return "\n".join([
        "# ORB-SLAM3 x jaxvo on the TUM walking clip: which masking\n",
        (f"{m['date']} by `{m['command']}`; {m['machine']['cpu_model']}, "
         f"{m['machine']['cores']} cores, load average {m['machine']['load_average_start']} at "
         f"start, {m['load_average_end']} at end; pyorbslam3 {m['pyorbslam3']}; "
         f"{m['repeats']} runs of each row.\n"),
        (f"{res['frames']} frames; jaxvo's masks (one streaming pass) cover "
         f"{res['dynamic_pct']:.2f} % of the pixels. Distance (ATE after rigid alignment) from "
         "the reference, the medoid of 5 runs of ORB-SLAM3 with the depth under the hand-drawn "
         f"people masks set to 0; the other 4 lie {_mm(min(ref))}-{_mm(max(ref))} mm from it.\n"),
        markdown_table(["masking", "mm: median [min-max]", "every run, mm", "tracked"], rows),
        f"\nLowest median: **{best}**.\n",
    ]) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=6, help="runs of each row")
    ap.add_argument("--out", type=Path, default=Path("results"))
    args = ap.parse_args(argv)
    why = orb.missing()
    if why or not (data_root() / TUM_WALKING).is_dir():
        print(f"orbslam3_clip_masking: skipped: {why or 'no ' + TUM_WALKING + ' in the data'}")
        return 0
    from people_masks import people_masks

    res = {"meta": {
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
        "command": "python bench/orbslam3_clip_masking.py " + " ".join(
            argv if argv is not None else sys.argv[1:]),
        "machine": machine(), "pyorbslam3": importlib.metadata.version("pyorbslam3"),
        "repeats": args.repeats}}
    seq = InMemorySequence(open_sequence(data_root() / TUM_WALKING))
    people = people_masks(data_root() / TUM_WALKING)
    hand = lambda i: ~people[i]
    target, res["reference"] = people_reference(seq, hand)
    log(f"tum_walking: jaxvo streaming pass ({len(seq)} frames)")
    _, masks, _ = jaxvo_pass(seq)
    res["frames"], res["dynamic_pct"] = len(seq), 100.0 * float(np.mean(masks))
    res["rows"] = {}
    for v in orb.VARIANTS:
        log(f"tum_walking: ORB-SLAM3 x jaxvo, {v.name} x{args.repeats}")
        res["rows"][v.name] = orb_rows(seq, target, lambda: (lambda i: ~masks[i]), v,
                                       args.repeats)
    log(f"tum_walking: ORB-SLAM3 x {HAND} x{args.repeats}")
    res["rows"][HAND] = orb_rows(seq, target, lambda: hand, orb.Masking(False, 0), args.repeats)
    res["meta"]["load_average_end"] = load_average()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "orbslam3_clip_masking.json").write_text(json.dumps(res, indent=1))
    (args.out / "orbslam3_clip_masking.md").write_text(report(res))
    print(report(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
