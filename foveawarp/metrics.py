"""Image-quality metrics against the full-resolution reference, and eccentricity region masks."""

from __future__ import annotations

import numpy as np

from .config import check_array, check_int_range, check_range, show

__all__ = ["psnr", "ssim", "eccentricity_np", "region_masks", "region_metrics", "flip", "flip_available", "REGIONS_DEG"]

# region bounds in degrees of eccentricity: fovea < 5 deg, mid 5-20 deg, far > 20 deg
REGIONS_DEG = {"fovea": (0.0, 5.0), "mid": (5.0, 20.0), "far": (20.0, 1.0e9)}


def _img(a, name):
    a = check_array(name, a).astype(np.float64)
    if a.ndim not in (2, 3) or a.size == 0:
        raise ValueError(f"{name} must be a non-empty (H, W) or (H, W, C) image, got shape {a.shape}")
    return a


def _mask(mask, shape):
    m = check_array("mask", mask)
    if m.shape != shape:
        raise ValueError(f"mask must have shape {shape}, got {m.shape}")
    return m != 0


def _view(width, height, gaze_px, fov_y_deg):
    from .camera import _check_gaze

    w = check_int_range("width", width, 1, 16384)
    h = check_int_range("height", height, 1, 16384)
    g = _check_gaze(gaze_px)
    fov = check_range("fov_y_deg", fov_y_deg, 0.0, 180.0, lo_open=True, hi_open=True)
    return w, h, g, fov


def psnr(a, b, mask=None, data_range: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB (``inf`` for identical images) over all pixels or ``mask`` (NaN for an
    empty mask). Images: finite (H, W) or (H, W, C) arrays; ``data_range`` > 0."""
    x, y = _img(a, "a"), _img(b, "b")
    if x.shape != y.shape:
        raise ValueError(f"a and b must have the same shape, got {x.shape} and {y.shape}")
    data_range = check_range("data_range", data_range, 0.0, None, lo_open=True)
    d = (x - y) ** 2
    if mask is not None:
        m = _mask(mask, x.shape[:2])
        if not m.any():
            return float("nan")
        d = d[m]
    mse = float(np.mean(d))
    if mse <= 0.0:
        return float("inf")
    return float(10.0 * np.log10(data_range * data_range / mse))


def ssim(a, b, mask=None) -> float:
    """SSIM (scikit-image, Gaussian weights, sigma 1.5, data_range 1), averaged over ``mask`` when given."""
    val, smap = _ssim_map(a, b)
    if mask is None:
        return val
    return _masked_mean(smap, _mask(mask, smap.shape))


def _masked_mean(smap, mask) -> float:
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return float("nan")
    return float(smap[m].mean())


def _ssim_map(a, b):
    """(mean SSIM, per-pixel SSIM map averaged over channels)."""
    from skimage.metrics import structural_similarity

    x, y = _img(a, "a"), _img(b, "b")
    if x.shape != y.shape:
        raise ValueError(f"a and b must have the same shape, got {x.shape} and {y.shape}")
    kw = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0, full=True)
    if x.ndim == 3:
        kw["channel_axis"] = 2
    if min(x.shape[:2]) < 11:  # the Gaussian window (sigma 1.5, truncated at 3.5 sigma) is 11 x 11
        raise ValueError(f"a and b must be images at least 11 x 11 for ssim (Gaussian window), got {x.shape[:2]}")
    val, smap = structural_similarity(x, y, **kw)
    if smap.ndim == 3:
        smap = smap.mean(axis=2)
    return float(val), smap


def eccentricity_np(width: int, height: int, gaze_px, fov_y_deg: float) -> np.ndarray:
    """Eccentricity in degrees of every pixel centre about the gaze point (pinhole, square pixels)."""
    width, height, gaze_px, fov_y_deg = _view(width, height, gaze_px, fov_y_deg)
    f = 0.5 * height / np.tan(np.radians(fov_y_deg) * 0.5)  # focal length in pixels
    xs = np.arange(width) + 0.5 - 0.5 * width
    ys = np.arange(height) + 0.5 - 0.5 * height
    gx, gy = float(gaze_px[0]) - 0.5 * width, float(gaze_px[1]) - 0.5 * height
    px, py = np.meshgrid(xs, ys)
    dot = px * gx + py * gy + f * f
    n1 = np.sqrt(px * px + py * py + f * f)
    n2 = np.sqrt(gx * gx + gy * gy + f * f)
    return np.degrees(np.arccos(np.clip(dot / (n1 * n2), -1.0, 1.0)))


def region_masks(width: int, height: int, gaze_px, fov_y_deg: float, regions=None) -> dict:
    """Boolean (H, W) masks of the foveal / mid / far regions by eccentricity (degrees) about the gaze."""
    e = eccentricity_np(width, height, gaze_px, fov_y_deg)
    regions = REGIONS_DEG if regions is None else regions
    if not isinstance(regions, dict) or not regions:
        raise ValueError(f"regions must be a non-empty dict name -> (lo_deg, hi_deg), got {show(regions)}")
    for k, v in regions.items():
        try:
            lo, hi = v
        except (TypeError, ValueError):
            raise ValueError(f"regions[{k!r}] must be (lo_deg, hi_deg) with 0 <= lo < hi, got {show(v)}") from None
        lo = check_range(f"regions[{k!r}][0]", lo, 0.0, None)
        check_range(f"regions[{k!r}][1]", hi, lo, None, lo_open=True)
    return {k: (e >= lo) & (e < hi) for k, (lo, hi) in regions.items()}


def region_metrics(img, ref, gaze_px, fov_y_deg: float) -> dict:
    """PSNR and SSIM over the whole frame and each eccentricity region."""
    x, y = _img(img, "img"), _img(ref, "ref")
    h, w = x.shape[:2]
    _view(w, h, gaze_px, fov_y_deg)
    val, smap = _ssim_map(x, y)
    out = {"psnr": psnr(x, y), "ssim": val}
    for k, m in region_masks(w, h, gaze_px, fov_y_deg).items():
        out[f"psnr_{k}"] = psnr(x, y, mask=m)
        out[f"ssim_{k}"] = _masked_mean(smap, m)
    return out


def flip_available() -> bool:
    try:
        import flip_evaluator  # noqa: F401
    except Exception:
        return False
    return True


def flip(a, b) -> float:
    """Mean NVIDIA FLIP error (needs the optional ``flip-evaluator`` package)."""
    if not flip_available():
        raise ValueError("flip needs the optional package flip-evaluator (pip install flip-evaluator)")
    import flip_evaluator

    x, y = _img(a, "a").astype(np.float32), _img(b, "b").astype(np.float32)
    _, mean_err, _ = flip_evaluator.evaluate(y, x, "LDR")
    return float(mean_err)
