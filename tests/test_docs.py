"""The documentation: no page, benchmark or report names a folder of the machine it was
written on (data by its path under the data root, the ORB-SLAM3 vocabulary by its name)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# An absolute path of a machine: a home, the root's, a work or temporary folder, a mount,
# a macOS or Windows user folder. System paths every machine has (/dev/null, /proc/cpuinfo,
# /usr/bin/env) are not a machine's. Not after a word character, a dot, ~ or a variable:
# "results/tmp/" and "$TMPDIR/x" are relative or the user's.
MACHINE_PATH = re.compile(
    r"(?<![\w.~$})\]-])/(?:home|root|work|tmp|Users|mnt|media|scratch|srv|opt|private)(?:/|\b)"
    r"|\b[A-Za-z]:\\(?:Users|home)\\")


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
