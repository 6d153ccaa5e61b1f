"""Write the speed paragraph of ``docs/speed.md`` (linked from the README) from a
``bench/bench_pipeline.py`` report, so that no figure in it is typed in by hand.

The paragraph sits between the markers ``<!-- speed: ... -->`` and ``<!-- /speed -->`` in
the page; everything outside them is left as it is.

Usage: ``python bench/readme_speed.py [results/pipeline.json] [--page docs/speed.md]``
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

BEGIN = "<!-- speed: written by bench/readme_speed.py from bench/bench_pipeline.py's report -->"
END = "<!-- /speed -->"
PAGE = Path(__file__).resolve().parent.parent / "docs" / "speed.md"


def speed_paragraph(report: dict) -> str:
    """The paragraph, from the ``pipeline.json`` of :mod:`bench_pipeline`.

    Args:
      report: the parsed JSON report.
    Returns:
      Markdown text, lines of at most about 92 characters, without the markers.
    """
    h, m = report["headline"], report["machine"]
    load = m["load_average_start"][0] if m.get("load_average_start") else "unknown"
    seq = Path(report["sequence"]).name
    text = (
        f"Speed (`docs/report/pipeline.md`, by `bench/bench_pipeline.py` on "
        f"{report['date'][:10]}, {m['cores']} cores of "
        f"{m['cpu_model']}, JAX {m['jax']} on the CPU, load average {load}): `jaxvo run` over "
        f"{report['frames']} real 640x480 frames (`{seq}`) takes {h['run_ms_per_frame']} ms a "
        f"frame at steady state, reading and writing included, {h['run_ms_per_frame_vs_peer']:.2f}"
        f" times the {h['peer_ms_per_frame']} ms of OpenCV's RGB odometry on the same frames "
        f"(preloaded). The whole process takes {h['run_process_cold_s']} s the first time on a "
        f"machine, where the per-frame step compiles (its first frame pair "
        f"{h['first_pair_cold_s']} s), and {h['run_process_warm_s']} s afterwards, the step "
        f"loaded from the compile cache (first pair {h['first_pair_warm_s']} s), against "
        f"{h['peer_process_s']} s for the OpenCV RGB peer as a process over the same folder. "
        f"From Python, `Odometry.process` takes a median of {h['process_median_ms']} ms a "
        f"frame (p90 {h['process_p90_ms']} ms) and the pipelined `Odometry.submit` "
        f"{h['submit_median_ms']} ms; the whole-sequence scan from precomputed flow runs at "
        f"{h['scan_frames_per_second']:g} frames/s."
    )
    return _wrap(text, 92)


def _wrap(text: str, width: int) -> str:
    """Greedy line filling at spaces (Markdown joins the lines again)."""
    lines, line = [], ""
    for word in text.split(" "):
        if line and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}" if line else word
    return "\n".join([*lines, line])


def update_page(page: str, paragraph: str) -> str:
    """``page`` with the text between the speed markers replaced by ``paragraph``.

    Raises:
      ValueError: the markers are missing, or there is more than one pair.
    """
    pattern = re.compile(re.escape(BEGIN) + r"\n.*?" + re.escape(END), re.DOTALL)
    if len(pattern.findall(page)) != 1:
        raise ValueError(f"speed page: expected one {BEGIN!r} ... {END!r} block")
    return pattern.sub(lambda _: f"{BEGIN}\n{paragraph}\n{END}", page)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", nargs="?", default="results/pipeline.json")
    ap.add_argument("--page", default=str(PAGE))
    args = ap.parse_args()
    report = json.loads(Path(args.report).read_text())
    page = Path(args.page)
    page.write_text(update_page(page.read_text(), speed_paragraph(report)))
    print(f"{page}: speed paragraph written from {args.report}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
