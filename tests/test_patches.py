"""The checks a tracked point passes (jaxvo.host.frontend.patches): patches and their correlation."""

import numpy as np

from jaxvo.host.frontend.patches import lk_converged, patch_correlation, sample_patches, similar


def test_patch_correlation_matches_numpy_corrcoef():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((20, 49)).astype(np.float32)
    b = (0.5 * a + rng.standard_normal((20, 49))).astype(np.float32)
    ref = [np.corrcoef(x, y)[0, 1] for x, y in zip(a.astype(np.float64), b.astype(np.float64))]
    np.testing.assert_allclose(patch_correlation(a, b), ref, atol=1e-5)  # tolerance: float32
    flat = np.full((1, 49), 7.0, np.float32)
    assert patch_correlation(flat, a[:1])[0] == 0.0  # flat patch: no evidence, no NaN


def test_sample_patches_is_bilinear():
    rng = np.random.default_rng(4)
    g = rng.integers(0, 256, (40, 50)).astype(np.uint8)
    uv = np.array([[10.25, 12.5], [30.0, 20.75]], np.float32)
    p = sample_patches(g, uv, 3)
    # reference: explicit bilinear interpolation at the 3x3 offsets, tolerance 0.1 grey level
    # (OpenCV interpolates with 5-bit fixed-point weights on uint8 inputs converted to float)
    ref = []
    for x, y in uv.astype(np.float64):
        row = []
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                xx, yy = x + dx, y + dy
                x0, y0 = int(np.floor(xx)), int(np.floor(yy))
                ax, ay = xx - x0, yy - y0
                gf = g.astype(np.float64)
                row.append(
                    (1 - ay) * ((1 - ax) * gf[y0, x0] + ax * gf[y0, x0 + 1])
                    + ay * ((1 - ax) * gf[y0 + 1, x0] + ax * gf[y0 + 1, x0 + 1])
                )
        ref.append(row)
    np.testing.assert_allclose(p, ref, atol=0.1 * 255 / 32)


# ----------------------------------------------------------------------------- depth


def test_similar_and_lk_converged_are_the_checks_they_name():
    """``similar``: the correlation reaches the bound (a patch against itself, not against
    noise); ``lk_converged``: LK's status, a finite position, inside the image."""
    rng = np.random.default_rng(5)
    g = rng.integers(0, 256, (40, 50)).astype(np.float32)
    noise = rng.integers(0, 256, (40, 50)).astype(np.float32)
    uv = np.array([[10.0, 12.0], [30.0, 20.0]], np.float32)
    np.testing.assert_array_equal(similar(g, uv, g, uv, side=7, least=0.9), [True, True])
    np.testing.assert_array_equal(similar(g, uv, noise, uv, side=7, least=0.9), [False, False])
    found = np.array([[1.0, 1.0], [np.nan, 2.0], [49.5, 3.0], [2.0, 39.0], [5.0, 5.0]], np.float32)
    status = np.array([[1], [1], [1], [1], [0]], np.uint8)
    np.testing.assert_array_equal(lk_converged(found, status, width=50, height=40),
                                  [True, False, False, True, False])
