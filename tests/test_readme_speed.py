"""The speed paragraph (docs/speed.md, linked from the README) is written from the
committed benchmark report (bench/readme_speed.py from docs/report/pipeline.json), never
typed in by hand."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
_spec = importlib.util.spec_from_file_location("readme_speed", ROOT / "bench" / "readme_speed.py")
readme_speed = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readme_speed)

REPORT = ROOT / "docs" / "report" / "pipeline.json"


def test_the_speed_paragraph_is_the_committed_reports():
    """Regenerate it after a new report: ``python bench/readme_speed.py
    docs/report/pipeline.json``."""
    report = json.loads(REPORT.read_text())
    page = readme_speed.PAGE.read_text()
    assert readme_speed.update_page(page, readme_speed.speed_paragraph(report)) == page


def test_the_paragraph_carries_the_reports_figures_and_replaces_only_its_block():
    report = json.loads(REPORT.read_text())
    report["headline"] = dict(report["headline"], run_ms_per_frame=12.34, peer_process_s=56.78,
                              scan_frames_per_second=901.5)
    text = readme_speed.speed_paragraph(report)
    for figure in ("12.34 ms a frame", "56.78 s", "901.5 frames/s"):
        assert figure in " ".join(text.split()), figure
    assert max(len(line) for line in text.splitlines()) <= 100

    before = f"# title\n\n{readme_speed.BEGIN}\nold figures\n{readme_speed.END}\n\nrest\n"
    after = readme_speed.update_page(before, text)
    assert after == f"# title\n\n{readme_speed.BEGIN}\n{text}\n{readme_speed.END}\n\nrest\n"
    with pytest.raises(ValueError, match="expected one"):
        readme_speed.update_page("# no markers\n", text)
