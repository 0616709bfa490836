"""Reconstruction ops: jump flooding, Voronoi fill and discrete Sibson interpolation (ALGORITHMS.md A5-A6).

NumPy (or Warp) arrays in, NumPy arrays out; each call builds a :class:`ReconstructStage` and runs the same
kernels as FrameLoop. Pixel (x, y) is column x, row y; distances are Euclidean between pixel centres.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import warp as wp

from .._util import check_image_size, get_device
from ..config import JFA_VARIANTS, ReconstructionConfig, check_array, check_choice, check_int_range
from ..stages.reconstruct import (
    ReconstructStage,
    jfa_start_step_for_block,
    jfa_steps,
    max_seed_distance_for_block,
    sibson_window_for_block,
)

__all__ = [
    "jump_flood",
    "voronoi",
    "sibson",
    "sibson_window_for_block",
    "jfa_start_step_for_block",
    "jfa_steps",
    "max_seed_distance_for_block",
]


def _mask(seed_mask, dev) -> wp.array:
    if isinstance(seed_mask, wp.array):
        if seed_mask.ndim != 2:
            raise ValueError(f"seed_mask must be 2-D (H, W), got shape {tuple(seed_mask.shape)}")
        if seed_mask.dtype == wp.uint8 and seed_mask.device == dev:
            check_image_size(seed_mask.shape[1], seed_mask.shape[0])
            return seed_mask
    m = check_array("seed_mask", seed_mask)
    if m.ndim != 2:
        raise ValueError(f"seed_mask must be 2-D (H, W), got shape {tuple(m.shape)}")
    check_image_size(m.shape[1], m.shape[0])
    return wp.array(np.ascontiguousarray(m != 0, dtype=np.uint8), dtype=wp.uint8, device=dev)


def _colors(colors, shape, mask_np, dev) -> wp.array:
    c_np = check_array("colors", colors)
    if c_np.shape != (shape[0], shape[1], 3):
        raise ValueError(f"colors must have shape {(shape[0], shape[1], 3)} (H, W, 3), got {tuple(c_np.shape)}")
    return wp.array(np.ascontiguousarray(c_np, dtype=np.float32), dtype=wp.vec3, device=dev)


def _nearest(nearest, mask_np, dev) -> wp.array:
    n = check_array("nearest", nearest)
    h, w = mask_np.shape
    if n.shape != (h, w, 2):
        raise ValueError(f"nearest must have shape {(h, w, 2)} (H, W, 2) of (x, y), got {tuple(n.shape)}")
    if n.dtype.kind not in "iu":
        raise ValueError(f"nearest must hold integers, got dtype {n.dtype}")
    n = n.astype(np.int64)
    nx, ny = n[..., 0], n[..., 1]
    none = (nx == -1) & (ny == -1)
    inside = (nx >= 0) & (nx < w) & (ny >= 0) & (ny < h)
    if not np.all(none | inside):
        iy, ix = (int(i) for i in np.argwhere(~(none | inside))[0])
        raise ValueError(f"nearest must hold (x, y) with 0 <= x < {w}, 0 <= y < {h}, or (-1, -1), got "
                         f"{tuple(int(c) for c in n[iy, ix])} at pixel (y, x) = ({iy}, {ix})")
    if not np.all(none | mask_np[np.clip(ny, 0, h - 1), np.clip(nx, 0, w - 1)]):
        raise ValueError("nearest must point at seed pixels (nonzero seed_mask) or be (-1, -1)")
    yy, xx = np.mgrid[0:h, 0:w]
    if not np.all(~mask_np | ((nx == xx) & (ny == yy))):
        raise ValueError("nearest of a seed pixel must be the seed itself")
    return wp.array(np.ascontiguousarray(n, dtype=np.int32), dtype=wp.vec2i, device=dev)


def jump_flood(seed_mask, *, variant: str = "1+jfa", start_step: Optional[int] = None, device=None) -> np.ndarray:
    """Nearest seed of every pixel by jump flooding (Rong & Tan 2006).

    Args:
        seed_mask: (H, W) array; nonzero pixels are seeds.
        variant: "jfa", "jfa+1", "jfa+2" or "1+jfa".
        start_step: first step in pixels, in [1, 16384] (default: half of max(H, W) rounded up to a power of
            two). With a seed in every aligned k x k tile, ``jfa_start_step_for_block(k)`` is enough.
    Returns:
        (H, W, 2) int32: (x, y) of the nearest seed found; (-1, -1) everywhere when there is no seed.
        Never nearer than the exact nearest seed; JFA can miss it at a few pixels.
    """
    check_choice("variant", variant, JFA_VARIANTS)
    if start_step is not None:
        start_step = check_int_range("start_step", start_step, 1, 16384)
    dev = get_device(device)
    mask = _mask(seed_mask, dev)
    h, w = mask.shape
    stage = ReconstructStage(w, h, ReconstructionConfig(jfa_variant=variant, bounded_jfa_start=False), 1, dev,
                             start_step=start_step)
    stage.run_jfa(mask)
    return stage.nearest.numpy().reshape(h, w, 2)


def _interpolate(colors, seed_mask, nearest, variant, dev, *, sibson_on, window, exact):
    check_choice("variant", variant, JFA_VARIANTS)
    mask = _mask(seed_mask, dev)
    h, w = mask.shape
    mask_np = mask.numpy() != 0
    col = _colors(colors, (h, w), mask_np, dev)
    cfg = ReconstructionConfig(jfa_variant=variant, sibson=sibson_on, bounded_jfa_start=False)
    stage = ReconstructStage(w, h, cfg, 1, dev, exact_sibson=exact, window=window)
    if nearest is None:
        stage.run_jfa(mask)
        near = None
    else:
        near = _nearest(nearest, mask_np, dev)
    out = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    stage.run_interpolate(col, out, nearest=near)
    return out.numpy().reshape(h, w, 3), stage


def voronoi(colors, seed_mask, *, variant: str = "1+jfa", nearest=None, device=None) -> np.ndarray:
    """Nearest-seed (Voronoi) fill: every pixel takes the color of its nearest seed (JFA ``variant``, or the
    given ``nearest`` map of shape (H, W, 2) (x, y)). ``colors``: (H, W, 3), read at seeds only.
    Returns (H, W, 3) float32; zeros when there is no seed."""
    out, _ = _interpolate(colors, seed_mask, nearest, variant, get_device(device), sibson_on=False, window=None,
                          exact=False)
    return out


def sibson(colors, seed_mask, *, window: Optional[int] = None, nearest=None, variant: str = "1+jfa",
           return_max_radius: bool = False, device=None):
    """Discrete natural-neighbour (Sibson) interpolation of the seed colors.

    Args:
        colors: (H, W, 3) float array (linear RGB, any finite values; finite everywhere, also where unread),
            read at the seed pixels only.
        seed_mask: (H, W) array; nonzero pixels are seeds.
        window: None for the exact discrete Sibson (Park et al. 2006 scatter, atomics); an int J in [1, 256]
            for the bounded gather over [p - J, p + J]^2 (thesis Code 4), exact when J >= the largest
            nearest-seed distance (``sibson_window_for_block(k)`` under the k x k block guarantee).
        nearest: optional (H, W, 2) integer (x, y) nearest-seed map to use instead of running JFA (seeds must
            map to themselves, other pixels to a seed or (-1, -1)).
        variant: the JFA variant when ``nearest`` is None.
        return_max_radius: also return the largest nearest-seed distance in pixels (0.0 without seeds).
    Returns:
        (H, W, 3) float32 (and the radius as a float). Seeds keep their color exactly; pixels with no seed
        at all get 0; the output is finite.
    """
    if window is not None:
        window = check_int_range("window", window, 1, 256)
    dev = get_device(device)
    out, stage = _interpolate(colors, seed_mask, nearest, variant, dev, sibson_on=True, window=window,
                              exact=window is None)
    if return_max_radius:
        return out, float(stage.max_radius.numpy()[0])
    return out
