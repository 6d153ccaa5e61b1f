"""Shared fixtures: where the real data lives, and skipping cleanly when it is absent.

Use ``data_root`` for the folder itself, or ``require_data("name", ...)`` for a path under
it; either skips the test, naming the missing path, when the data is not there (set
``JAXVO_DATA`` to point elsewhere). Compiled programs are shared through one persistent
compile cache of the test session (:func:`pytest_configure`).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from jaxvo.host.readers.io import data_root as _data_root
from jaxvo.host.services.compile_cache import ENV, OFF, setup_compile_cache, use_compile_cache

# Folder (under pytest's cache, .pytest_cache/d/) of the compiled programs the tests share
XLA_CACHE = "jaxvo-xla"


def _take_ctrl_c() -> None:
    """Ctrl-C as an interactive shell delivers it, also when the suite was started as a
    background job: a shell without job control starts those with SIGINT ignored, which
    their children inherit, and then the tests of what Ctrl-C does (in this process and in
    `jaxvo` children) see nothing arrive. A handler, unlike "ignored", is not inherited
    through exec, so the children get the default back too."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def pytest_configure(config):
    """Many tests compile the same program (the per-frame step at one grid, a scan, a
    study) in their own jit or their own `jaxvo` child process; each compiled it afresh.
    One persistent compile cache for the session (this process, from before its first
    compile, and every child, which inherits ``JAXVO_COMPILE_CACHE``) compiles each once.
    It lives in pytest's cache folder, so a later session loads what an earlier one
    compiled (``pytest --cache-clear`` starts cold); without pytest's cache
    (``-p no:cacheprovider``) in a temporary folder of the session. Never the user's own
    cache folder. ``JAXVO_COMPILE_CACHE=off pytest`` compiles everything afresh.

    Tests that need a compile to happen (the compile cache's own, a Ctrl-C during a
    compile) give their child its own folder or ``off``, which win over this.
    """
    _take_ctrl_c()
    if os.environ.get(ENV, "").strip().lower() == OFF:
        config._jaxvo_xla = None
        return
    cache = getattr(config, "cache", None)
    if cache is not None:
        root, temporary = cache.mkdir(XLA_CACHE), None
    else:
        root = temporary = Path(tempfile.mkdtemp(prefix="jaxvo-xla-"))
    os.environ[ENV] = str(root)
    config._jaxvo_xla = setup_compile_cache(None).folder  # the versioned subfolder
    config._jaxvo_xla_temporary = temporary


def pytest_unconfigure(config):
    temporary = getattr(config, "_jaxvo_xla_temporary", None)
    if temporary is not None:
        shutil.rmtree(temporary, ignore_errors=True)


@pytest.fixture(autouse=True)
def _session_compile_cache(request):
    """Put the session's compile cache back after a test that pointed JAX elsewhere or
    turned it off in this process (the compile cache's tests, a `jaxvo` command called
    in-process with ``--compile-cache``)."""
    yield
    folder = request.config._jaxvo_xla
    if folder is None:
        return
    import jax

    if not (jax.config.jax_enable_compilation_cache
            and jax.config.jax_compilation_cache_dir == str(folder)):
        use_compile_cache(folder)


def _require(*parts: str) -> Path:
    path = _data_root().joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not found at {path} (set JAXVO_DATA to the shared data folder)")
    return path


def bench_module(name: str):
    """A script of ``bench/`` imported as a module (they import each other by name, from
    their own folder, so the folder is on the path while it loads)."""
    import importlib

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.pop(0)


@pytest.fixture
def data_root() -> Path:
    """The real-data folder (``jaxvo.host.readers.io.data_root()``); skips the test when it is absent."""
    return _require()


@pytest.fixture
def require_data():
    """``require_data(*parts) -> Path`` under the data folder; skips when that path is absent."""
    return _require


@pytest.fixture
def random_groundtruth():
    """``make(rng, n, t0)``: a hand-held-like ground truth of ``n`` poses at 30 Hz from
    ``t0`` s (random-walk positions, small random rotations), drawn from ``rng``."""
    import numpy as np

    from jaxvo.trajectory import Trajectory
    from jaxvo.transforms import pose_from_tq

    def make(rng, n: int, t0: float):
        t = t0 + np.arange(n) / 30.0
        q = rng.normal(size=(n, 4)) * 0.05 + [0, 0, 0, 1]
        return Trajectory(t, pose_from_tq(np.cumsum(rng.normal(size=(n, 3)) * 0.02, 0), q))

    return make


def python_code(code: str, *, timeout: float = 120) -> subprocess.CompletedProcess:
    """``code`` run in a fresh interpreter (what it imports, how it exits), its output
    captured as text; never raises on its exit status."""
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=timeout, check=False)
