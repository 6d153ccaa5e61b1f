"""Shared fixtures: where the real data lives, and skipping cleanly when it is absent.

Use ``data_root`` for the folder itself, or ``require_data("name", ...)`` for a path under
it; either skips the test, naming the missing path, when the data is not there (set
``JAXVO_DATA`` to point elsewhere). The persistent compile cache is off in the tests.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from jaxvo.host.io import data_root as _data_root

# The jaxvo commands keep compiled programs in the user's cache folder by default. The tests
# (and the `jaxvo run` children they start, which inherit this) must neither write there nor
# find a warm cache that hides a compile a test waits for; tests of the cache pass their own
# folder with --compile-cache, which wins over this.
os.environ["JAXVO_COMPILE_CACHE"] = "off"


def _require(*parts: str) -> Path:
    path = _data_root().joinpath(*parts)
    if not path.exists():
        pytest.skip(f"real data not found at {path} (set JAXVO_DATA to the shared data folder)")
    return path


@pytest.fixture
def data_root() -> Path:
    """The real-data folder (``jaxvo.host.io.data_root()``); skips the test when it is absent."""
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

    from jaxvo.host.io import Trajectory
    from jaxvo.host.transforms import pose_from_tq

    def make(rng, n: int, t0: float):
        t = t0 + np.arange(n) / 30.0
        q = rng.normal(size=(n, 4)) * 0.05 + [0, 0, 0, 1]
        return Trajectory(t, pose_from_tq(np.cumsum(rng.normal(size=(n, 3)) * 0.02, 0), q))

    return make
