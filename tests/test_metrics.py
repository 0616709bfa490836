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


# --------------------------------------------------------------------------------------------------------------
# FovVideoVDP (optional: pyfvvdp on PyTorch)

def _fovvdp_video(seed=0, frames=6, h=72, w=128):
    rng = np.random.default_rng(seed)
    ref = (0.25 + 0.5 * rng.random((frames, h, w, 3))).astype(np.float32)
    noise = rng.normal(0.0, 0.08, ref.shape).astype(np.float32)
    return ref, noise


def test_fovvdp_identical_is_ten_and_error_lowers_it():
    pytest.importorskip("pyfvvdp")
    from foveawarp.metrics import fovvdp

    ref, noise = _fovvdp_video()
    g = np.tile([64.0, 36.0], (ref.shape[0], 1))
    assert fovvdp(ref, ref, g, 60.0) == pytest.approx(10.0, abs=1e-4)
    assert fovvdp(np.clip(ref + noise, 0, 1), ref, g, 60.0) < 9.5


def test_fovvdp_follows_the_gaze():
    """The same error patch costs more JOD under the gaze than 40 degrees away from it (foveated mode)."""
    pytest.importorskip("pyfvvdp")
    from foveawarp.metrics import fovvdp

    ref, noise = _fovvdp_video(1)
    f, h, w = ref.shape[:3]
    patch = np.zeros((h, w, 1), np.float32)
    patch[4:28, 4:28] = 1.0
    test = np.clip(ref + noise * patch, 0, 1)
    near = fovvdp(test, ref, np.tile([16.0, 16.0], (f, 1)), 60.0)
    far = fovvdp(test, ref, np.tile([w - 8.0, h - 8.0], (f, 1)), 60.0)
    assert near < far < 10.0


@pytest.mark.parametrize("kw", [{"fov_y_deg": 0.0}, {"fov_y_deg": float("nan")}, {"gaze_px": [[1.0, 2.0]] * 3},
                                {"test": np.zeros((6, 72, 128, 4))}])
def test_fovvdp_bad_input_is_named(kw):
    pytest.importorskip("pyfvvdp")
    from foveawarp.metrics import fovvdp

    ref, _ = _fovvdp_video()
    args = {"test": ref, "ref": ref, "gaze_px": [64.0, 36.0], "fov_y_deg": 60.0}
    args.update(kw)
    with pytest.raises(ValueError, match=r"fov_y_deg|gaze_px|test and ref"):
        fovvdp(args.pop("test"), args.pop("ref"), args.pop("gaze_px"), args.pop("fov_y_deg"))
