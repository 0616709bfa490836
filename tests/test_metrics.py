"""Metrics against independent formulas."""

import numpy as np
import pytest

from foveawarp import metrics


def test_psnr_formula(rng):
    a = rng.random((20, 30, 3))
    b = np.clip(a + rng.normal(0, 0.05, a.shape), 0, 1)
    mse = np.mean((a - b) ** 2)
    assert metrics.psnr(a, b) == pytest.approx(10 * np.log10(1 / mse))
    assert metrics.psnr(a, a) == float("inf")


def test_ssim_identity_and_noise(rng):
    a = rng.random((32, 40, 3))
    assert metrics.ssim(a, a) == pytest.approx(1.0)
    b = np.clip(a + rng.normal(0, 0.2, a.shape), 0, 1)
    assert metrics.ssim(a, b) < 0.9


def test_region_masks_partition_and_eccentricity():
    e = metrics.eccentricity_np(64, 48, (32, 24), 60.0)
    # the centre pixel's eccentricity is ~0; the corner's follows tan geometry
    f = 24 / np.tan(np.radians(30))
    corner = np.degrees(np.arctan(np.hypot(31.5, 23.5) / f))
    assert e[0, 0] == pytest.approx(corner, abs=1e-6)
    m = metrics.region_masks(64, 48, (32, 24), 60.0)
    total = sum(v.astype(int) for v in m.values())
    assert np.all(total == 1)


def test_region_metrics_keys(rng):
    a = rng.random((48, 64, 3))
    r = metrics.region_metrics(a, a * 0.9, (32, 24), 60.0)
    assert {"psnr", "ssim", "psnr_fovea", "ssim_far"} <= set(r)


def test_bad_shapes():
    with pytest.raises(ValueError, match="same shape"):
        metrics.psnr(np.zeros((4, 4)), np.zeros((5, 4)))
