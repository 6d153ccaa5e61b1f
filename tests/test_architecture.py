"""docs/architecture.md stays the map of the package: every module of the traced step
(``jaxvo/core/``) and of the host side (``jaxvo/host/``) has a row in its module table."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "architecture.md"


def table_modules(text: str) -> set[str]:
    """The modules the table's first column names (``core/x.py``, several to a row)."""
    names: set[str] = set()
    for line in text.splitlines():
        if line.startswith("|"):
            first = line.split("|")[1]
            names.update(re.findall(r"`([\w/]+\.py)`", first))
    return names


def package_modules(*folders: str) -> set[str]:
    return {f"{folder}/{p.name}" for folder in folders
            for p in sorted((ROOT / "jaxvo" / folder).glob("*.py")) if p.name != "__init__.py"}


def test_the_table_is_read_from_its_first_column_only():
    text = ("| module | side | holds |\n| --- | --- | --- |\n"
            "| `core/a.py`, `core/b.py` | device | see `core/c.py` |\n"
            "`core/d.py` in a sentence\n")
    assert table_modules(text) == {"core/a.py", "core/b.py"}


def test_every_core_and_host_module_has_a_row_in_the_architecture():
    modules = package_modules("core", "host")
    assert {"core/pipeline.py", "host/flow.py"} <= modules  # the walk sees the package
    missing = sorted(modules - table_modules(DOC.read_text(encoding="utf-8")))
    assert not missing, f"docs/architecture.md's module table lacks {missing}"
