"""Device metrics (psnr_device, ssim_device, region_metrics_device) against the host metrics (NumPy and
scikit-image's structural_similarity, which are independent of the Warp kernels).

Tolerance: 1e-9 absolute on SSIM and 1e-9 dB on PSNR. Both sides compute in float64 from the same input values
(float32 images are widened exactly), so the differences are rounding only (about 1e-15 measured on the CPU).
"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from foveawarp import metrics

TOL = 1e-9
REPO = Path(__file__).resolve().parent.parent
SIZES = [(48, 64), (53, 97)]  # (H, W)


def _same(host, dev, tol=TOL):
    """Equal within ``tol``, or both NaN, or both the same infinity."""
    if math.isnan(host) or math.isinf(host):
        return (math.isnan(host) and math.isnan(dev)) or host == dev
    return abs(host - dev) <= tol


def _assert_dicts(host, dev):
    assert list(host) == list(dev)
    bad = {k: (host[k], dev[k]) for k in host if not _same(host[k], dev[k])}
    assert not bad, bad


def _pair(kind, h, w, rng):
    """(a, b) float32 test images of one kind."""
    if kind == "random":
        a = rng.random((h, w, 3))
        b = np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1)
    elif kind == "smooth":  # low-frequency content: the variances are small differences of large moments
        yy, xx = np.mgrid[0:h, 0:w] / max(h, w)
        a = np.stack([0.5 + 0.4 * np.sin(3 * xx + c) * np.cos(2 * yy - c) for c in range(3)], axis=2)
        b = a + 0.01 * np.sin(9 * xx + 5 * yy)[:, :, None]
    elif kind == "hdr":  # outside [0, 1]: negative values and values up to ~8
        a = rng.normal(1.0, 2.0, (h, w, 3))
        b = a * 0.9 + rng.normal(0, 0.3, a.shape)
    elif kind == "constant":
        a = np.full((h, w, 3), 0.3)
        b = np.full((h, w, 3), 0.7)
    else:
        raise AssertionError(kind)
    return a.astype(np.float32), b.astype(np.float32)


KINDS = ["random", "smooth", "hdr", "constant"]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("shape", SIZES)
def test_region_metrics_device_matches_host(device, kind, shape, rng):
    h, w = shape
    a, b = _pair(kind, h, w, rng)
    for gaze, fov in (((0.4 * w, 0.6 * h), 60.0), ((0.0, 0.0), 90.0), ((-3.0 * w, 0.5 * h), 30.0)):
        host = metrics.region_metrics(a, b, gaze, fov)
        dev = metrics.region_metrics_device(a, b, gaze, fov, device=device)
        _assert_dicts(host, dev)
    # the off-screen gaze leaves the fovea empty: NaN there on both sides
    assert math.isnan(dev["psnr_fovea"]) and math.isnan(dev["ssim_fovea"])


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("shape", SIZES)
def test_psnr_ssim_device_match_host(device, kind, shape, rng):
    h, w = shape
    a, b = _pair(kind, h, w, rng)
    for mask in (None, rng.random((h, w)) < 0.3, (rng.random((h, w)) < 0.5).astype(np.uint8)):
        assert _same(metrics.psnr(a, b, mask=mask), metrics.psnr_device(a, b, mask=mask, device=device))
        assert _same(metrics.ssim(a, b, mask=mask), metrics.ssim_device(a, b, mask=mask, device=device))
    for dr in (0.5, 255.0):
        assert _same(metrics.psnr(a, b, data_range=dr), metrics.psnr_device(a, b, data_range=dr, device=device))


def test_empty_mask_gives_nan_like_the_host(device, rng):
    a, b = _pair("random", 48, 64, rng)
    empty = np.zeros((48, 64), dtype=bool)
    assert math.isnan(metrics.psnr(a, b, mask=empty)) and math.isnan(metrics.ssim(a, b, mask=empty))
    assert math.isnan(metrics.psnr_device(a, b, mask=empty, device=device))
    assert math.isnan(metrics.ssim_device(a, b, mask=empty, device=device))


def test_identical_images(device, rng):
    a, _ = _pair("random", 53, 97, rng)
    assert metrics.psnr(a, a) == math.inf and metrics.psnr_device(a, a, device=device) == math.inf
    assert metrics.psnr_device(a, a, mask=np.ones((53, 97)), device=device) == math.inf
    assert _same(metrics.ssim(a, a), metrics.ssim_device(a, a, device=device))
    assert abs(metrics.ssim_device(a, a, device=device) - 1.0) <= TOL
    r = metrics.region_metrics_device(a, a, (40.0, 20.0), 60.0, device=device)
    assert all(r[k] == math.inf for k in r if k.startswith("psnr"))
    assert all(abs(r[k] - 1.0) <= TOL for k in r if k.startswith("ssim"))


def test_near_identical_images_keep_a_tiny_positive_mse(device, rng):
    """One float32 ulp apart at a few pixels: MSE ~1e-17, a finite PSNR (~170 dB) equal to the host's."""
    a, _ = _pair("random", 48, 64, rng)
    b = a.copy()
    idx = (rng.integers(0, 48, 5), rng.integers(0, 64, 5), rng.integers(0, 3, 5))
    b[idx] = np.nextafter(a[idx], np.float32(2.0))
    host, dev = metrics.psnr(a, b), metrics.psnr_device(a, b, device=device)
    assert math.isfinite(host) and host > 150.0
    assert _same(host, dev)
    # float64 inputs stay float64 on the device: a 1e-9 difference is not rounded away
    a64 = a.astype(np.float64)
    b64 = a64 + 1e-9
    host, dev = metrics.psnr(a64, b64), metrics.psnr_device(a64, b64, device=device)
    assert _same(host, dev) and abs(dev - 180.0) < 1e-3
    assert _same(metrics.ssim(a64, b64), metrics.ssim_device(a64, b64, device=device))


def test_grayscale_and_mixed_precision_inputs(device, rng):
    g1, g2 = rng.random((40, 30)), rng.random((40, 30))
    assert _same(metrics.psnr(g1, g2), metrics.psnr_device(g1, g2, device=device))
    assert _same(metrics.ssim(g1, g2), metrics.ssim_device(g1, g2, device=device))
    a, b = _pair("random", 40, 30, rng)
    assert _same(metrics.ssim(a, b.astype(np.float64)), metrics.ssim_device(a, b.astype(np.float64), device=device))


def test_warp_inputs_match_numpy_inputs(device, rng):
    a, b = _pair("smooth", 53, 97, rng)
    wa, wb = (wp.array(v, dtype=wp.vec3, device=device) for v in (a, b))
    m = rng.random((53, 97)) < 0.4
    wm = wp.array(m.astype(np.uint8), dtype=wp.uint8, device=device)
    assert metrics.psnr_device(wa, wb, mask=wm) == metrics.psnr_device(a, b, mask=m, device=device)
    assert metrics.ssim_device(wa, wb, mask=wm) == metrics.ssim_device(a, b, mask=m, device=device)
    _assert_dicts(metrics.region_metrics(a, b, (10.0, 30.0), 70.0),
                  metrics.region_metrics_device(wa, wb, (10.0, 30.0), 70.0))


def test_region_pixel_counts_equal_region_masks(device, rng):
    """The device's eccentricity regions hold exactly the pixels of region_masks (counts and squared errors)."""
    from foveawarp.kernels import metrics as km

    h, w = 53, 97
    a, b = _pair("random", h, w, rng)
    x, y = (wp.array(v, dtype=wp.vec3, device=device) for v in (a, b))
    for gaze, fov in (((20.0, 40.0), 60.0), ((97.0, 0.0), 100.0), ((48.5, 26.5), 15.0)):
        sums = metrics._device_sums(x, y, wp.get_device(device), with_ssim=False, view=(w, h, gaze, fov))
        d2 = ((a.astype(np.float64) - b) ** 2).sum(axis=2)
        for k, m in enumerate(metrics.region_masks(w, h, gaze, fov).values()):
            assert sums[km.REGION0 + 3 * k] == m.sum()
            assert sums[km.REGION0 + 3 * k + 1] == pytest.approx(d2[m].sum(), rel=1e-12, abs=1e-300)


def test_deterministic_and_no_allocation_on_repeat(device, rng, monkeypatch):
    """Bitwise the same result on every call; a repeated call with Warp inputs constructs no Warp array and
    reads the device once."""
    a, b = _pair("random", 48, 64, rng)
    wa, wb = (wp.array(v, dtype=wp.vec3, device=device) for v in (a, b))
    first = metrics.region_metrics_device(wa, wb, (30.0, 20.0), 60.0)
    counts = {"init": 0, "numpy": 0}
    init, to_numpy = wp.array.__init__, wp.array.numpy

    def counting_init(self, *args, **kw):
        counts["init"] += 1
        return init(self, *args, **kw)

    def counting_numpy(self):
        counts["numpy"] += 1
        return to_numpy(self)

    monkeypatch.setattr(wp.array, "__init__", counting_init)
    monkeypatch.setattr(wp.array, "numpy", counting_numpy)
    again = [metrics.region_metrics_device(wa, wb, (30.0, 20.0), 60.0) for _ in range(3)]
    monkeypatch.undo()
    assert counts == {"init": 0, "numpy": 3}
    for r in again:
        assert list(r.items()) == list(first.items())


def test_non_finite_warp_input_is_reported(device):
    a = np.full((12, 12, 3), 0.5, dtype=np.float32)
    b = a.copy()
    b[3, 4, 1] = np.nan
    b[5, 5, 0] = np.inf
    wa, wb = (wp.array(v, dtype=wp.vec3, device=device) for v in (a, b))
    with pytest.raises(ValueError, match=r"ref must hold finite real numbers, got 2 non-finite value"):
        metrics.region_metrics_device(wa, wb, (6.0, 6.0), 60.0)
    with pytest.raises(ValueError, match=r"b must hold finite real numbers, got 2 non-finite value"):
        metrics.psnr_device(wa, wb)


# -- degenerate sizes (property tests) ----------------------------------------------------------------------------


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(h=st.integers(1, 24), w=st.integers(1, 24), seed=st.integers(0, 2**31 - 1), masked=st.booleans())
def test_degenerate_sizes(device, h, w, seed, masked):
    """1 x N, N x 1 and images smaller than the 11 x 11 window: PSNR matches the host at every size; SSIM
    matches it from 11 x 11 on and, like the host, raises ValueError below."""
    rng = np.random.default_rng(seed)
    a = rng.random((h, w, 3)).astype(np.float32)
    b = rng.random((h, w, 3)).astype(np.float32)
    mask = rng.random((h, w)) < 0.5 if masked else None
    assert _same(metrics.psnr(a, b, mask=mask), metrics.psnr_device(a, b, mask=mask, device=device))
    if min(h, w) < 11:
        with pytest.raises(ValueError, match="at least 11 x 11"):
            metrics.ssim(a, b, mask=mask)
        with pytest.raises(ValueError, match=r"a and b must be images at least 11 x 11 .*got \(%d, %d\)" % (h, w)):
            metrics.ssim_device(a, b, mask=mask, device=device)
        with pytest.raises(ValueError, match="img and ref must be images at least 11 x 11"):
            metrics.region_metrics_device(a, b, (0.5 * w, 0.5 * h), 60.0, device=device)
    else:
        assert _same(metrics.ssim(a, b, mask=mask), metrics.ssim_device(a, b, mask=mask, device=device))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(h=st.integers(11, 30), w=st.integers(11, 30), gx=st.floats(-100, 100), gy=st.floats(-100, 100),
       fov=st.floats(1.0, 179.0), seed=st.integers(0, 2**31 - 1))
def test_region_metrics_any_view(device, h, w, gx, gy, fov, seed):
    rng = np.random.default_rng(seed)
    a = rng.random((h, w, 3)).astype(np.float32)
    b = np.clip(a + rng.normal(0, 0.2, a.shape), 0, 1).astype(np.float32)
    _assert_dicts(metrics.region_metrics(a, b, (gx, gy), fov),
                  metrics.region_metrics_device(a, b, (gx, gy), fov, device=device))


# -- benchmark smoke run -------------------------------------------------------------------------------------------


def test_benchmark_quick(device, tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "stages.py"), "--parts", "metrics", "--quick",
                        "--device", device, "--out", str(tmp_path)], capture_output=True, text=True, cwd=REPO, env=env, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    tag = "cuda" if wp.get_device(device).is_cuda else "cpu"
    res = json.loads((tmp_path / f"stages-{tag}.json").read_text())
    assert (tmp_path / f"stages-{tag}.md").is_file()
    assert res["benchmark"] == "stages" and res["device_alias"] == wp.get_device(device).alias
    for row in res["records"]:
        assert row["device_ms"] > 0 and row["host_ms"] > 0
        assert row["max_abs_diff"] <= TOL
