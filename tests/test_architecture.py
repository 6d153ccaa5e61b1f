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
    """Every module under the ``folders`` of jaxvo/, its rooms' included, as 'folder/...py'."""
    return {p.relative_to(ROOT / "jaxvo").as_posix() for folder in folders
            for p in sorted((ROOT / "jaxvo" / folder).rglob("*.py")) if p.name != "__init__.py"}


def test_the_table_is_read_from_its_first_column_only():
    text = ("| module | side | holds |\n| --- | --- | --- |\n"
            "| `core/a.py`, `core/b.py` | device | see `core/c.py` |\n"
            "`core/d.py` in a sentence\n")
    assert table_modules(text) == {"core/a.py", "core/b.py"}


def test_every_core_and_host_module_has_a_row_in_the_architecture():
    modules = package_modules("core", "host")
    assert {"core/pipeline.py", "host/frontend/flow.py"} <= modules  # the walk sees the package
    missing = sorted(modules - table_modules(DOC.read_text(encoding="utf-8")))
    assert not missing, f"docs/architecture.md's module table lacks {missing}"


# what a dotted name in the page may start with besides a module of jaxvo: libraries, and
# a Config (`cfg.cell`) or Params (`params.confidence`) value, whose fields are checked
LIBRARIES = {"jax", "lax", "cv2", "os"}
FILE_TYPES = {"md", "jsonl", "json", "csv", "png", "txt", "toml", "ply", "npz", "rrd", "zip"}


def _modules() -> dict[str, list[str]]:
    """Each module's and subpackage's last name -> its dotted names under jaxvo."""
    names: dict[str, list[str]] = {}
    for path in sorted((ROOT / "jaxvo").rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        names.setdefault(parts[-1], []).append(".".join(parts))
    return names


def _file_exists(name: str, folder: str | None) -> bool:
    """A ``x.py`` or ``dir/x.py`` the page names: under ``folder`` of jaxvo where its row
    says so, else under jaxvo/ (``core/x.py``), the checkout (``bench/x.py``) or anywhere
    in jaxvo/, tests/ or bench/ (a bare name)."""
    if "/" in name:
        return (ROOT / "jaxvo" / name).is_file() or (ROOT / name).is_file()
    if folder is not None:
        return (ROOT / "jaxvo" / folder / name).is_file()
    return any(any((ROOT / top).rglob(name)) for top in ("jaxvo", "tests", "bench"))


def stale_names(text: str) -> list[str]:
    """What the page names that is not where it says: a module file that is not there, an
    attribute its module lacks (``temporal.reported_ids`` once it moved to ``evidence``), a
    module that no longer exists (``study_report.write_report``), a field Config or Params
    lacks."""
    import importlib

    from jaxvo.config import Config, Params, config_fields

    settings = {*config_fields(), *Config.__dataclass_fields__}  # cfg.cell, cfg.flow

    modules, stale = _modules(), []
    for line in text.splitlines():
        first = line.split("|")[1] if line.startswith("|") else ""
        row = re.fullmatch(r"\s*\*\*`(\w+)/`\*\*\s*", first)  # a folder's row: its own files
        for name in re.findall(r"[\w/]+\.py\b", line):
            if not _file_exists(name, row.group(1) if row and "/" not in name else None):
                stale.append(name)
        for token in re.findall(r"`([^`]+)`", line):
            for dotted in re.findall(r"(?<![\w.])([a-z_]\w*(?:\.\w+)+)", token):
                head, *rest = dotted.split(".")
                if rest[-1] in FILE_TYPES or rest[-1] == "py" or head in LIBRARIES:
                    continue
                if head in ("cfg", "params"):
                    fields = settings if head == "cfg" else Params._fields
                    stale += [dotted] if rest[0] not in fields else []
                    continue
                found = False
                for module in modules.get(head, []):
                    obj = importlib.import_module(module)
                    for part in rest:
                        try:
                            obj = getattr(obj, part)
                        except AttributeError:
                            try:
                                obj = importlib.import_module(f"{obj.__name__}.{part}")
                            except (AttributeError, ImportError):
                                break
                    else:
                        found = True
                if not found:
                    stale.append(dotted)
    return stale


def test_the_stale_names_check_finds_what_moved_and_what_is_gone():
    assert stale_names("`evidence.reported_ids`, `flow.GridFlow`, `cfg.cell`, `cfg.step`") == []
    assert stale_names("`temporal.reported_ids` and `study_report.write_report`, "
                       "`cfg.window`, `core/window.py`") == [
        "core/window.py", "temporal.reported_ids", "study_report.write_report", "cfg.window"]
    folder_row = "| **`evaluation/`** | host | `metrics.py` ATE; `io.py` trajectories |"
    assert stale_names(folder_row) == ["io.py"]  # io.py is host's, not evaluation's


def test_every_module_and_name_the_architecture_names_is_where_it_says():
    stale = stale_names(DOC.read_text(encoding="utf-8"))
    assert not stale, f"docs/architecture.md names what is not where it says: {stale}"


def test_the_host_is_rooms_that_say_what_they_hold():
    """host/ holds no module of its own, only its rooms, each with a docstring saying what
    it holds, so that a newcomer finds where a format is read or written by the folders."""
    host = ROOT / "jaxvo" / "host"
    assert [p.name for p in host.glob("*.py")] == ["__init__.py"]
    rooms = sorted(p.name for p in host.iterdir() if p.is_dir() and p.name != "__pycache__")
    assert rooms == ["frontend", "readers", "services", "writers"]
    for room in rooms:
        text = (host / room / "__init__.py").read_text()
        assert text.startswith('"""') and len(text) > 60, room
