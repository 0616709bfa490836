"""Depth-of-field ops: circle of confusion and the pixel-intensity scatter (ALGORITHMS.md B), NumPy out."""

from __future__ import annotations

import numpy as np
import warp as wp

from .. import parallel
from .._util import check_image_size, get_device
from ..config import DofConfig, check_array, check_bool, check_range
from ..kernels.dof import DofParams, coc_kernel
from ..stages.dof import DofStage, check_focus, lens_scale

__all__ = ["circle_of_confusion_px", "dof_scatter"]

# "no clamp" for circle_of_confusion_px: the largest value below float32 max
_UNCLAMPED_PX = 3.0e38


def _to_wp(a, dtype, np_dtype, device, *, name: str, shape=None) -> wp.array:
    """NumPy or Warp array -> Warp array of ``dtype`` on ``device`` (copies only when needed)."""
    if isinstance(a, wp.array):
        if a.dtype == dtype and a.device == device and (shape is None or tuple(a.shape) == tuple(shape)):
            return a
        a = a.numpy()
    arr = np.asarray(a)
    if shape is not None and tuple(arr.shape) != tuple(shape):
        raise ValueError(f"{name} must have shape {tuple(shape)}, got {tuple(arr.shape)}")
    return wp.array(np.ascontiguousarray(arr, dtype=np_dtype), dtype=dtype, device=device)


def _check_lens(focal_length_m, focus_depth_m, aperture_m, px_per_m):
    f = check_range("focal_length_m", focal_length_m, 0.0, None, lo_open=True)
    z = check_focus(focus_depth_m, f)
    e = check_range("aperture_m", aperture_m, 0.0, None)
    k = check_range("px_per_m", px_per_m, 0.0, None, lo_open=True)
    return f, z, e, k


def circle_of_confusion_px(depth_m, *, focal_length_m: float, focus_depth_m: float, aperture_m: float,
                           px_per_m: float, max_coc_px=None, device=None) -> np.ndarray:
    """Circle-of-confusion diameter in pixels for every depth (any shape), float32:
    ``(aperture * focal / (focus - focal)) * |depth - focus| / depth * px_per_m``.

    Args:
        depth_m: view depths in metres, finite (NaN and +-Inf are a ValueError; a large depth such as 1e30
            gives the far limit ``aperture * focal / (focus - focal) * px_per_m``); depth <= 0 (at or behind
            the lens) gives the clamp value.
        focal_length_m: F > 0. focus_depth_m: Z_f in (F, inf), else ValueError. aperture_m: E >= 0.
        px_per_m: pixels per metre of CoC on the sensor, > 0.
        max_coc_px: clamp in pixels (> 0), or None for no clamp (values stay below 3e38).
    """
    f, z, e, k = _check_lens(focal_length_m, focus_depth_m, aperture_m, px_per_m)
    cmax = _UNCLAMPED_PX if max_coc_px is None else check_range("max_coc_px", max_coc_px, 0.0, None, lo_open=True)
    dev = get_device(device)
    d = check_array("depth_m", depth_m)
    shape = d.shape
    d2 = np.ascontiguousarray(d, dtype=np.float32).reshape(1, -1) if d.ndim != 2 else d
    if d2.size == 0:
        return np.zeros(shape, dtype=np.float32)
    dw = _to_wp(d2, wp.float32, np.float32, dev, name="depth_m")
    p = DofParams()
    p.coc_scale = lens_scale(e, f, k)
    p.focal_m = f
    p.max_coc_px = float(cmax)
    p.tan_half_fov_y = 0.0
    p.aspect = 1.0
    p.width = int(dw.shape[1])
    p.height = int(dw.shape[0])
    focus = wp.full(1, value=z, dtype=float, device=dev)
    out = wp.zeros(dw.shape, dtype=float, device=dev)
    parallel.launch(coc_kernel, dim=dw.shape, inputs=[p, focus, dw], outputs=[out], device=dev)
    return out.numpy().reshape(shape)


def dof_scatter(color, depth_m, *, focal_length_m: float, focus_depth_m: float, aperture_m: float,
                px_per_m: float, gamma: float = 2.0, eps_px: float = 1.0, max_coc_px: float = 16.0,
                foreground_fix: bool = True, background_fix: bool = True, method: str = "gather", hit=None,
                tile_px: int = 8, device=None) -> np.ndarray:
    """Depth of field by pixel-intensity scatter (Lee, Kim, Choi) of an (H, W, 3) image; (H, W, 3) float32.

    Every pixel p spreads over a disc of radius ``R_p = max(C_p / 2, 0.5)`` px (``C_p`` clamped to
    ``max_coc_px``) with weight ``K / (pi R_p^2)``; K = (Z_f / Z_p)^gamma in the foreground with
    ``foreground_fix``, the background-leak factor W(C_p, C_q) in the background with ``background_fix``,
    else 1. The output is the weighted mean at each pixel.

    Args:
        color: (H, W, 3) linear or display colors, finite (NumPy or wp.array of vec3 / float (H, W, 3)).
        depth_m: (H, W) view depth in metres, finite; <= 0 is at the lens (use ``hit`` for background at
            infinite depth).
        focal_length_m, focus_depth_m, aperture_m, px_per_m: the lens (see :func:`circle_of_confusion_px`).
        gamma: foreground exponent in [0, 16]. eps_px: loose in-focus range in pixels, > 0.
        max_coc_px: CoC clamp in pixels, in [1, 128].
        method: "gather" (tiled gather, fast) or "scatter" (atomics; the reference).
        hit: optional (H, W) mask of finite numbers; pixels with 0 are background at infinite depth.
        tile_px: gather tile edge in pixels, in [1, 64].
    """
    f, z, e, k = _check_lens(focal_length_m, focus_depth_m, aperture_m, px_per_m)
    check_range("gamma", gamma, 0.0, 16.0)
    check_range("eps_px", eps_px, 0.0, None, lo_open=True)
    check_range("max_coc_px", max_coc_px, 1.0, 128.0)
    check_bool("foreground_fix", foreground_fix)
    check_bool("background_fix", background_fix)
    cfg = DofConfig(aperture_m=e, focal_length_m=f, focus_depth_m=z, px_per_m=k, gamma=gamma, eps_px=eps_px,
                    max_coc_px=max_coc_px, foreground_fix=bool(foreground_fix),
                    background_fix=bool(background_fix))
    dev = get_device(device)
    c = check_array("color", color).astype(np.float32)
    if c.ndim != 3 or c.shape[2] != 3:
        raise ValueError(f"color must have shape (H, W, 3), got {tuple(c.shape)}")
    h, w = c.shape[:2]
    check_image_size(w, h)
    dw = _to_wp(check_array("depth_m", depth_m), wp.float32, np.float32, dev, name="depth_m", shape=(h, w))
    cw = wp.array(np.ascontiguousarray(c), dtype=wp.vec3, device=dev)
    if hit is not None:
        hm = check_array("hit", hit)
        if hm.shape != (h, w):
            raise ValueError(f"hit must have shape {(h, w)}, got {tuple(hm.shape)}")
        hit = (hm != 0).astype(np.uint8)
    hw = None if hit is None else _to_wp(hit, wp.uint8, np.uint8, dev, name="hit", shape=(h, w))
    stage = DofStage(w, h, cfg, dev, method=method, tile_px=tile_px)
    out = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    stage.run(cw, dw, hw, z, out)
    return out.numpy().reshape(h, w, 3)
