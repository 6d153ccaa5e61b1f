"""The documentation: the README stays a first hour's read with every page it sends the
reader to there, and no page, benchmark or report names a folder of the machine it was
written on (data by its path under the data root, the ORB-SLAM3 vocabulary by its name)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

# An absolute path of a machine: a home, the root's, a work or temporary folder, a mount,
# a macOS or Windows user folder. System paths every machine has (/dev/null, /proc/cpuinfo,
# /usr/bin/env) are not a machine's. Not after a word character, a dot, ~ or a variable:
# "results/tmp/" and "$TMPDIR/x" are relative or the user's.
MACHINE_PATH = re.compile(
    r"(?<![\w.~$})\]-])/(?:home|root|work|tmp|Users|mnt|media|scratch|srv|opt|private)(?:/|\b)"
    r"|\b[A-Za-z]:\\(?:Users|home)\\")

LINK = re.compile(r"\]\(([^)\s]+)\)")


def _text_files() -> list[Path]:
    files = [ROOT / "README.md"]
    for folder in ("docs", "bench"):
        files += [p for p in sorted((ROOT / folder).rglob("*")) if p.is_file()]
    out = []
    for p in files:
        try:
            p.read_text(encoding="utf-8")
        except UnicodeDecodeError:  # figures
            continue
        out.append(p)
    return out


def test_the_pattern_finds_machine_paths_and_leaves_the_rest():
    for bad in ("/work/shared/data/7scenes", "`/home/me/ORBvoc.txt`", '"/tmp/flow_old.py"',
                "at /root", "C:\\Users\\me\\data", "/Users/me/x", "/mnt/data/seq"):
        assert MACHINE_PATH.search(bad), bad
    for good in ("7scenes_static_0000_0299", "ORBvoc.txt", "results/tmp/x", "$TMPDIR/x",
                 "#!/usr/bin/env bash", "2>/dev/null", "/proc/cpuinfo", "docs/report/work.md",
                 "~/.cache/jaxvo/xla", "../shared/data", "fx,fy/cx"):
        assert not MACHINE_PATH.search(good), good


def test_no_machine_path_in_docs_bench_or_the_readme():
    found = [f"{p.relative_to(ROOT)}:{i}: {line.strip()[:120]}"
             for p in _text_files()
             for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1)
             if MACHINE_PATH.search(line)]
    assert not found, "absolute paths of a machine:\n" + "\n".join(found)


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def _pages() -> list[Path]:
    """The pages written by hand (the reports under docs/report and docs/study are a run's
    copies: they link figures of the run that are not committed, as their README says)."""
    return [ROOT / "README.md", ROOT / "bench" / "README.md",
            ROOT / "docs" / "report" / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_link_of_a_page_leads_somewhere(page):
    text = page.read_text(encoding="utf-8")
    broken = []
    for target in LINK.findall(text):
        if re.match(r"[a-z]+:", target):  # https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(target)
        elif anchor and dest.is_file() and dest.suffix == ".md":
            headings = re.findall(r"^#+ (.*)$", dest.read_text(encoding="utf-8"), re.MULTILINE)
            if anchor not in {_slug(h) for h in headings}:
                broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)}: broken links {broken}"


def test_the_readme_is_short_and_sends_the_reader_to_every_reference_page():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) < 100
    linked = set(LINK.findall(readme))
    for page in ("docs/cli.md", "docs/inputs.md", "docs/python.md", "docs/speed.md",
                 "docs/study.md", "docs/architecture.md", "bench/README.md"):
        assert page in linked, page
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", readme)
    assert images and all((ROOT / i).is_file() for i in images)


def _section(text: str, heading: str) -> str:
    """The body of the markdown section ``heading`` (up to the next heading)."""
    body = text.split(f"\n{heading}\n", 1)[1]
    return re.split(r"\n#+ ", body, maxsplit=1)[0]


def test_the_top_level_is_the_user_names_and_python_md_says_where_every_name_lives():
    """``jaxvo.__all__`` holds at most 25 names (it held 79 from 23 modules, internals beside
    ``Odometry``); docs/python.md's reference lists each of them with the module that
    defines it, and the other public names under their modules, none of them at the top."""
    import importlib

    import jaxvo

    assert len(jaxvo.__all__) <= 25
    text = (ROOT / "docs" / "python.md").read_text(encoding="utf-8")
    top: dict[str, list[str]] = {}
    for row in _section(text, "### The top level").splitlines():
        cells = [c.strip() for c in row.strip("|").split("|")]
        if row.startswith("| `"):
            modules = re.findall(r"`([\w.]+)`", cells[2])
            for name in re.findall(r"`(\w+)`", cells[0]):
                top[name] = modules
    assert sorted(top) == sorted(jaxvo.__all__)
    for name, modules in top.items():
        assert any(getattr(importlib.import_module(m), name, None) is getattr(jaxvo, name)
                   for m in modules), name
    below = re.findall(r"^- `(jaxvo[\w.]*)`: (.*(?:\n  .*)*)",
                       _section(text, "### Under the subpackages"), re.MULTILINE)
    assert len(below) >= 15
    for module, names in below:
        mod = importlib.import_module(module)
        for name in re.findall(r"`(\w+)`", names):
            assert hasattr(mod, name), f"{module}.{name}"
            assert name not in jaxvo.__all__, name
    with pytest.raises(AttributeError, match="docs/python.md"):
        jaxvo.jit_step  # noqa: B018 - under jaxvo.core.pipeline now


def test_the_report_readme_names_every_report_in_its_folder():
    """docs/report/README.md says what each file there is (``x.md`` / ``.json`` names both;
    the map's reports were missing)."""
    text = (ROOT / "docs" / "report" / "README.md").read_text(encoding="utf-8")
    named = set(re.findall(r"`([\w.]+\.\w+)`", text))
    named |= {md.replace(".md", ".json")
              for md in re.findall(r"`([\w.]+\.md)`\s*/\s*`\.json`", text)}
    missing = [p.name for p in sorted((ROOT / "docs" / "report").iterdir())
               if p.suffix in (".md", ".json") and p.name != "README.md" and p.name not in named]
    assert not missing, f"docs/report/README.md does not say what these are: {missing}"
