"""The package's layout is its architecture: the traced pipeline (``jaxvo.core``) imports
no OpenCV, no host code and no command line, so it stays pure and jittable whatever the
host side does."""

from __future__ import annotations

import ast
import pkgutil
import subprocess
import sys
from pathlib import Path

import jaxvo.core

CORE = Path(jaxvo.core.__file__).parent


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def test_the_traced_pipeline_imports_no_host_code():
    for path in sorted(CORE.glob("*.py")):
        bad = {m for m in _imports(path) if m.split(".")[0] in ("cv2", "pathlib", "os")
               or m.startswith(("jaxvo.host", "jaxvo.cli", "jaxvo.study", "jaxvo.synth",
                                "jaxvo.evaluation", "jaxvo.odometry"))}
        assert not bad, f"{path.name} imports {sorted(bad)}"


def test_importing_the_traced_pipeline_loads_no_opencv():
    modules = [m.name for m in pkgutil.iter_modules([str(CORE)], "jaxvo.core.")]
    assert "jaxvo.core.pipeline" in modules
    code = (f"import importlib, sys\nfor m in {modules!r}: importlib.import_module(m)\n"
            "assert 'cv2' not in sys.modules\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
