"""The depth readings' quantisation read from depth images alone
(``bench/depth_quantisation.py``): a sensor that measures disparity in fixed steps gives
readings ``q z^2`` apart, and the script finds ``q`` again."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import bench_module


@pytest.fixture(scope="module")
def quant():
    return bench_module("depth_quantisation")


def _disparity_sensor(z: np.ndarray, q: float) -> np.ndarray:
    """Depth ``z`` as a sensor reads it that quantises disparity ``1 / z`` in steps of
    ``q``: readings ``q z^2`` apart."""
    return 1.0 / (np.round((1.0 / z) / q) * q)


def test_a_disparity_quantised_sensor_reads_as_its_step(quant):
    rng = np.random.default_rng(0)
    q = 2.9e-3
    frames = [_disparity_sensor(rng.uniform(0.7, 6.5, (240, 320)), q) for _ in range(3)]
    r = quant.quantisation(frames)
    assert r["q"] == pytest.approx(q, rel=0.05)
    centre = np.array([(lo + hi) / 2 for lo, hi in quant.BANDS])
    np.testing.assert_allclose(r["step"], q * centre ** 2, rtol=0.1)


def test_unquantised_depth_reads_as_no_step_and_an_empty_band_as_none(quant):
    rng = np.random.default_rng(1)
    z = rng.uniform(1.0, 3.0, (240, 320))
    z[:, :10] = 0.0  # no reading
    steps = quant.band_steps(z)
    inside = [lo >= 1.0 and hi <= 3.0 for lo, hi in quant.BANDS]
    assert all(s <= 2 * quant.RESOLUTION for s, i in zip(steps, inside) if i)
    assert all(np.isnan(s) for s, i in zip(steps, inside) if not i)  # no reading there


def test_depth_without_readings_or_frames_has_no_step(quant):
    assert np.isnan(quant.quantisation([np.zeros((48, 64))])["q"])
    assert np.isnan(quant.quantisation([])["q"])
