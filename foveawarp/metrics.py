"""Image-quality metrics against the full-resolution reference, and eccentricity region masks."""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np
import warp as wp

from ._util import get_device
from .config import check_array, check_int_range, check_range, show

__all__ = ["psnr", "ssim", "eccentricity_np", "region_masks", "region_metrics", "flip", "flip_available", "fovvdp",
           "fovvdp_available", "REGIONS_DEG", "psnr_device", "ssim_device", "region_metrics_device"]

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



def fovvdp_available() -> bool:
    """Whether FovVideoVDP (the optional ``pyfvvdp`` package, on PyTorch) can be imported."""
    try:
        import pyfvvdp  # noqa: F401
        import torch  # noqa: F401
    except Exception:
        return False
    return True


def fovvdp(test, ref, gaze_px, fov_y_deg: float, *, fps: float = 30.0, display: str = "standard_fhd",
           torch_device=None) -> float:
    """FovVideoVDP quality in JOD (Mantiuk et al. 2021; 10 = no visible difference) of the video ``test`` against
    ``ref``, in its foveated mode with the gaze of each frame.

    ``test``, ``ref``: (F, H, W, 3) display-encoded frames in [0, 1] (what ``FrameLoop`` returns), F >= 1;
    ``gaze_px``: (F, 2) or (2,) gaze in pixels (pixel centres at x + 0.5); ``fov_y_deg``: the camera's vertical
    field of view, which sets the display's (so the metric's eccentricities are the renderer's); ``display``: the
    ``pyfvvdp`` display whose photometry is used (peak luminance, black level); ``torch_device``: None picks CUDA
    when PyTorch sees it, else the CPU. Needs the optional ``pyfvvdp`` and PyTorch."""
    if not fovvdp_available():
        raise ValueError("fovvdp needs the optional packages pyfvvdp and torch (pip install pyfvvdp)")
    import pyfvvdp
    import torch

    t = np.asarray(test, dtype=np.float32)
    r = np.asarray(ref, dtype=np.float32)
    if t.ndim == 3:
        t, r = t[None], r[None] if r.ndim == 3 else r
    if t.ndim != 4 or t.shape[-1] != 3 or t.shape != r.shape:
        raise ValueError(f"fovvdp: test and ref must be (F, H, W, 3) videos of one shape, got {t.shape} and "
                         f"{r.shape}")
    f, h, w = t.shape[:3]
    g = np.asarray(gaze_px, dtype=np.float64).reshape(-1, 2)
    if g.shape[0] not in (1, f) or not np.isfinite(g).all():
        raise ValueError(f"fovvdp: gaze_px must be finite, (2,) or ({f}, 2), got shape {np.shape(gaze_px)}")
    fov = check_range("fov_y_deg", fov_y_deg, 0.0, 180.0, lo_open=True, hi_open=True)
    fps = check_range("fps", fps, 0.0, None, lo_open=True)
    dev = torch.device(torch_device if torch_device is not None else ("cuda" if torch.cuda.is_available() else "cpu"))
    geometry = pyfvvdp.fvvdp_display_geometry((w, h), distance_m=0.6, fov_vertical=fov)
    metric = pyfvvdp.fvvdp(display_name=display, display_geometry=geometry, foveated=True, quiet=True, device=dev)
    fix = torch.tensor(np.broadcast_to(g - 0.5, (f, 2)).copy(), dtype=torch.float32)  # pyfvvdp: pixel indices
    with torch.no_grad():
        jod, _ = metric.predict(torch.from_numpy(np.clip(np.nan_to_num(t), 0.0, 1.0)),
                                torch.from_numpy(np.clip(np.nan_to_num(r), 0.0, 1.0)), dim_order="FHWC",
                                frames_per_second=float(fps) if f > 1 else 0, fixation_point=fix if f > 1 else fix[0])
    return float(jod)


# ================================================================================================================
# The same metrics on a Warp device (kernels in kernels/metrics.py): no image leaves the device, one small host read.

_SSIM_SIGMA = 1.5
_SSIM_TRUNCATE = 3.5  # scikit-image's truncation for gaussian_weights=True
_SSIM_RADIUS = int(_SSIM_TRUNCATE * _SSIM_SIGMA + 0.5)  # 5 (radius as scipy.ndimage), an 11-tap window
_SSIM_MIN = 2 * _SSIM_RADIUS + 1
_SSIM_C1 = (0.01 * 1.0) ** 2  # (K1 * data_range)^2
_SSIM_C2 = (0.03 * 1.0) ** 2
_STRIP_ROWS = 16  # rows one thread of the sums kernel adds up
_SUM_BLOCK = 64  # partial sums one thread of a reduction level adds up
_SCRATCH_MAX = 4  # (shape, device) entries kept; older ones are freed
_RGB_DTYPES = (wp.vec3, wp.vec3d)


def _gaussian_taps() -> np.ndarray:
    """Normalised Gaussian weights exp(-k^2 / (2 sigma^2)), k = -radius..radius (the scipy.ndimage kernel)."""
    k = np.arange(-_SSIM_RADIUS, _SSIM_RADIUS + 1, dtype=np.float64)
    g = np.exp(-0.5 * k * k / (_SSIM_SIGMA * _SSIM_SIGMA))
    return g / g.sum()


class _DeviceConstants:
    """Per-device constant arrays: Gaussian taps, the default region bounds, 1 x 1 stand-ins for unused inputs
    and (CUDA) a pinned host row for the one read back."""

    def __init__(self, dev):
        from .kernels import metrics as km

        self.taps = wp.array(_gaussian_taps(), dtype=wp.float64, device=dev)
        bounds = np.array(list(REGIONS_DEG.values()), dtype=np.float64)
        self.region_names = list(REGIONS_DEG)
        self.region_lo = wp.array(np.ascontiguousarray(bounds[:, 0]), dtype=wp.float64, device=dev)
        self.region_hi = wp.array(np.ascontiguousarray(bounds[:, 1]), dtype=wp.float64, device=dev)
        self.no_moments = wp.zeros((1, 1), dtype=wp.vec3d, device=dev)
        self.no_mask = wp.zeros((1, 1), dtype=wp.uint8, device=dev)
        self.host_row = wp.zeros((1, km.NUM_SUMS), dtype=wp.float64, device="cpu", pinned=True) if dev.is_cuda \
            else None


class _Scratch:
    """Buffers of one image size on one device: the five horizontal moment images (SSIM), the per-strip sums and
    the levels of the block reduction."""

    def __init__(self, h, w, dev):
        from .kernels import metrics as km

        self.moments = None  # allocated on the first SSIM call
        self.h, self.w, self.dev = h, w, dev
        self.strips = (h + _STRIP_ROWS - 1) // _STRIP_ROWS
        n = self.strips * w
        self.partial = wp.zeros((n, km.NUM_SUMS), dtype=wp.float64, device=dev)
        self.levels = []  # (rows in, array out)
        while n > 1:
            m = (n + _SUM_BLOCK - 1) // _SUM_BLOCK
            self.levels.append((n, wp.zeros((m, km.NUM_SUMS), dtype=wp.float64, device=dev)))
            n = m

    def moment_images(self):
        if self.moments is None:
            self.moments = [wp.zeros((self.h, self.w), dtype=wp.vec3d, device=self.dev) for _ in range(5)]
        return self.moments


_SCRATCH: OrderedDict = OrderedDict()
_CONSTANTS: dict = {}
_LOCK = threading.Lock()


def _scratch(h, w, dev) -> tuple:
    key = (h, w, dev.alias)
    with _LOCK:
        s = _SCRATCH.get(key)
        if s is None:
            s = _SCRATCH[key] = _Scratch(h, w, dev)
            while len(_SCRATCH) > _SCRATCH_MAX:
                _SCRATCH.popitem(last=False)
        else:
            _SCRATCH.move_to_end(key)
        c = _CONSTANTS.get(dev.alias)
        if c is None:
            c = _CONSTANTS[dev.alias] = _DeviceConstants(dev)
    return s, c


def _resolve_device(device, *arrays):
    if device is not None:
        return get_device(device)
    for x in arrays:
        if isinstance(x, wp.array):
            return x.device
    return get_device(None)


def _device_image(x, name, dev):
    """A (H, W) vec3 / vec3d Warp array on ``dev``: a Warp array of that kind is used as is (copied when on
    another device); anything else is checked on the host like ``psnr``'s inputs, a (H, W) image repeated into
    three channels, and uploaded (float32 when that is exact for its dtype, else float64)."""
    if isinstance(x, wp.array) and x.dtype in _RGB_DTYPES:
        shape = (*x.shape, 3)
        if x.ndim != 2 or x.size == 0:
            raise ValueError(f"{name} must be a non-empty (H, W) or (H, W, 3) image, got shape {shape}")
        return x if x.device == dev else wp.clone(x, device=dev)
    arr = check_array(name, x)
    if arr.ndim not in (2, 3) or arr.size == 0 or (arr.ndim == 3 and arr.shape[2] != 3):
        raise ValueError(f"{name} must be a non-empty (H, W) or (H, W, 3) image, got shape {arr.shape}")
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    exact32 = arr.dtype == np.float32 or arr.dtype.kind == "b" or arr.dtype.itemsize <= 2
    np_dtype, dtype = (np.float32, wp.vec3) if exact32 else (np.float64, wp.vec3d)
    return wp.array(np.ascontiguousarray(arr, dtype=np_dtype), dtype=dtype, device=dev)


def _device_pair(a, b, names, dev):
    x, y = _device_image(a, names[0], dev), _device_image(b, names[1], dev)
    if x.shape != y.shape:
        raise ValueError(f"{names[0]} and {names[1]} must have the same shape, got {(*x.shape, 3)} and "
                         f"{(*y.shape, 3)}")
    if x.dtype != y.dtype:  # one float32, one float64: compare in float64
        x, y = (wp.array(v.numpy().astype(np.float64), dtype=wp.vec3d, device=dev) for v in (x, y))
    return x, y


def _device_mask(mask, shape_hw, dev):
    """A (H, W) uint8 Warp array used as is (nonzero = inside), or anything ``_mask`` accepts, uploaded."""
    if isinstance(mask, wp.array) and mask.dtype == wp.uint8 and mask.ndim == 2:
        if tuple(mask.shape) != shape_hw:
            raise ValueError(f"mask must have shape {shape_hw}, got {tuple(mask.shape)}")
        return mask if mask.device == dev else wp.clone(mask, device=dev)
    m = _mask(mask, shape_hw)
    return wp.array(m.astype(np.uint8), dtype=wp.uint8, device=dev)


def _check_ssim_size(shape_hw, names):
    if min(shape_hw) < _SSIM_MIN:
        raise ValueError(f"{names[0]} and {names[1]} must be images at least {_SSIM_MIN} x {_SSIM_MIN} for ssim "
                         f"(Gaussian window), got {shape_hw}")


def _device_sums(x, y, dev, *, with_ssim, mask=None, view=None) -> np.ndarray:
    """All sums of kernels/metrics.py (NUM_SUMS float64) for images ``x``, ``y`` on ``dev``, with region 0 =
    ``mask`` or, given ``view`` = (width, height, gaze_px, fov_y_deg), the REGIONS_DEG regions. One host read."""
    from .kernels import metrics as km

    h, w = x.shape
    s, c = _scratch(h, w, dev)
    if with_ssim:
        moments = s.moment_images()
        wp.launch(km.ssim_rows_kernel, dim=(h, w), inputs=[x, y, c.taps, _SSIM_RADIUS], outputs=moments, device=dev)
    else:
        moments = [c.no_moments] * 5
    geo = [0.0] * 7
    lo, hi, n_regions = c.region_lo, c.region_hi, 0
    if mask is not None:
        n_regions = 1
    elif view is not None:
        vw, vh, gaze, fov = view
        f = 0.5 * vh / np.tan(np.radians(fov) * 0.5)  # as eccentricity_np
        gx, gy = float(gaze[0]) - 0.5 * vw, float(gaze[1]) - 0.5 * vh
        geo = [0.5 * vw, 0.5 * vh, gx, gy, f, float(np.sqrt(gx * gx + gy * gy + f * f)), 180.0 / np.pi]
        n_regions = len(c.region_names)
    wp.launch(km.metric_sums_kernel, dim=(s.strips, w),
              inputs=[x, y, _STRIP_ROWS, int(with_ssim), *moments, c.taps, _SSIM_RADIUS, wp.float64(_SSIM_C1),
                      wp.float64(_SSIM_C2), int(mask is not None), c.no_mask if mask is None else mask, n_regions,
                      lo, hi, *[wp.float64(v) for v in geo]],
              outputs=[s.partial], device=dev)
    src = s.partial
    for n, dst in s.levels:
        wp.launch(km.sum_blocks_kernel, dim=dst.shape, inputs=[src, n, _SUM_BLOCK], outputs=[dst], device=dev)
        src = dst
    if c.host_row is not None:
        wp.copy(c.host_row, src, count=km.NUM_SUMS)
        wp.synchronize_device(dev)
        src = c.host_row
    return src.numpy()[0].copy()


def _raise_nonfinite(sums, names):
    from .kernels import metrics as km

    for name, slot in zip(names, (km.NONFINITE_A, km.NONFINITE_B)):
        if sums[slot] > 0:
            raise ValueError(f"{name} must hold finite real numbers, got {int(sums[slot])} non-finite value(s)")


def _psnr_from_sums(d2, n, data_range) -> float:
    if n <= 0:
        return float("nan")
    mse = d2 / (n * 3.0)
    if mse <= 0.0:
        return float("inf")
    return float(10.0 * np.log10(data_range * data_range / mse))


def psnr_device(a, b, *, mask=None, data_range: float = 1.0, device=None) -> float:
    """``psnr`` computed on a Warp device (float64 sums; ``inf`` for identical images, NaN for an empty mask).

    ``a``, ``b``: (H, W) Warp arrays of vec3 / vec3d (used where they are) or (H, W) / (H, W, 3) arrays of real
    numbers (checked and uploaded); ``mask``: (H, W), nonzero = inside (a uint8 Warp array is used as is);
    ``device``: default the device of ``a`` (or ``b``), else Warp's default. Warp inputs are checked for
    non-finite values on the device (ValueError after the read)."""
    from .kernels import metrics as km

    dev = _resolve_device(device, a, b)
    x, y = _device_pair(a, b, ("a", "b"), dev)
    data_range = check_range("data_range", data_range, 0.0, None, lo_open=True)
    m = None if mask is None else _device_mask(mask, x.shape, dev)
    sums = _device_sums(x, y, dev, with_ssim=False, mask=m)
    _raise_nonfinite(sums, ("a", "b"))
    if m is None:
        return _psnr_from_sums(sums[km.SUM_D2], x.shape[0] * x.shape[1], data_range)
    return _psnr_from_sums(sums[km.REGION0 + 1], sums[km.REGION0], data_range)


def ssim_device(a, b, *, mask=None, device=None) -> float:
    """``ssim`` computed on a Warp device: the scikit-image SSIM (Gaussian weights, sigma 1.5, data_range 1,
    population covariance, channels averaged; images at least 11 x 11), averaged over the interior 5 pixels away
    from the border, or over the whole map inside ``mask`` (NaN for an empty mask). Inputs as ``psnr_device``."""
    from .kernels import metrics as km

    dev = _resolve_device(device, a, b)
    x, y = _device_pair(a, b, ("a", "b"), dev)
    _check_ssim_size(tuple(x.shape), ("a", "b"))
    m = None if mask is None else _device_mask(mask, x.shape, dev)
    sums = _device_sums(x, y, dev, with_ssim=True, mask=m)
    _raise_nonfinite(sums, ("a", "b"))
    if m is None:
        return float(sums[km.SUM_SSIM_CROP] / sums[km.N_CROP])
    n = sums[km.REGION0]
    return float(sums[km.REGION0 + 2] / n) if n > 0 else float("nan")


def region_metrics_device(img, ref, gaze_px, fov_y_deg: float, *, device=None) -> dict:
    """``region_metrics`` computed on a Warp device (same keys and values): PSNR and SSIM over the whole frame and
    each REGIONS_DEG eccentricity region (NaN for a region with no pixel). One launch sequence, one read of a
    row of sums; buffers are kept per (size, device), so repeated calls with Warp inputs allocate nothing."""
    from .kernels import metrics as km

    dev = _resolve_device(device, img, ref)
    x, y = _device_pair(img, ref, ("img", "ref"), dev)
    h, w = x.shape
    view = _view(w, h, gaze_px, fov_y_deg)
    _check_ssim_size((h, w), ("img", "ref"))
    sums = _device_sums(x, y, dev, with_ssim=True, view=view)
    _raise_nonfinite(sums, ("img", "ref"))
    out = {"psnr": _psnr_from_sums(sums[km.SUM_D2], h * w, 1.0),
           "ssim": float(sums[km.SUM_SSIM_CROP] / sums[km.N_CROP])}
    for k, name in enumerate(_CONSTANTS[dev.alias].region_names):
        n = sums[km.REGION0 + 3 * k]
        out[f"psnr_{name}"] = _psnr_from_sums(sums[km.REGION0 + 3 * k + 1], n, 1.0)
        out[f"ssim_{name}"] = float(sums[km.REGION0 + 3 * k + 2] / n) if n > 0 else float("nan")
    return out
