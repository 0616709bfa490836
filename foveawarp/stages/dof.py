"""Depth-of-field stage: pixel-intensity scatter (Lee, Kim, Choi; ALGORITHMS.md B), computed as a tiled gather.

One frame is four launches: per-pixel preparation (CoC, weights), per-tile max disc radius, tile dilation,
gather.
``method="scatter"`` replaces the last two by the atomic scatter + normalization (the reference the gather
matches within float rounding).
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
import warp as wp

from .. import parallel
from .._util import check_image_size, get_device
from ..config import DofConfig, check_choice, check_int_range, check_range
from ..kernels.dof import (
    FOCUS_FAR_M,
    DofParams,
    dof_focus_at_pixel_kernel,
    dof_gather_kernel,
    dof_normalize_kernel,
    dof_prepare_kernel,
    dof_scatter_kernel,
    dof_tile_dilate_kernel,
    dof_tile_r2_kernel,
)

__all__ = ["DofStage", "DOF_METHODS", "check_focus", "disc_reach_host"]

DOF_METHODS = ("gather", "scatter")


def lens_scale(aperture_m: float, focal_m: float, px_per_m: float) -> float:
    """E * F * px_per_m, the kernels' ``coc_scale``; a product below float32's smallest normal (1.2e-38) is 0, a
    pinhole, since as a float32 denormal it would carry a relative error of up to 100%."""
    s = float(aperture_m) * float(focal_m) * float(px_per_m)
    return s if s >= float(np.finfo(np.float32).tiny) else 0.0


def check_focus(focus_depth_m, focal_length_m: float) -> float:
    """Validate a host focus depth: a finite number of metres in (focal_length_m, inf)."""
    return check_range("focus_depth_m", focus_depth_m, float(focal_length_m), None, lo_open=True)


def disc_reach_host(radius_px: float) -> int:
    """Host twin of ``kernels.dof.disc_reach`` for a radius: the largest n with n^2 <= fl32(r)^2."""
    r = np.float32(radius_px)
    r2 = float(np.float32(r * r))
    n = int(math.floor(math.sqrt(max(r2, 0.0))))
    while float((n + 1) * (n + 1)) <= r2:
        n += 1
    while n > 0 and float(n * n) > r2:
        n -= 1
    return n


class DofStage:
    """Thin-lens depth of field of one (H, W) color + depth image per frame.

    Allocates every buffer in ``__init__``; :meth:`run` and :meth:`focus_at_pixel` only launch kernels
    (fixed launch sizes, no host reads), so a CUDA graph can replay them.

    Args:
        width, height: image size in pixels, each in [1, 16384].
        config: the :class:`DofConfig` (aperture, focal length, px_per_m, gamma, eps, max CoC, fixes).
            ``config.focus_depth_m`` (metres) is used when :meth:`run` gets ``focus_depth_m=None``.
        device: Warp device or None.
        method: "gather" (default; tiled gather) or "scatter" (atomic scatter, the reference).
        tile_px: edge in pixels of the tiles over which the gather window is bounded, in [1, 64].

    Attributes:
        focus_m: (1,) float32 device array holding the focus depth (view depth, metres) that :meth:`run` uses
            when it is given ``None`` and the config has no fixed focus; written by :meth:`focus_at_pixel`
            and :meth:`set_focus`. Starts at 1e30 m (focus at infinity).
        coc: (H, W) float32, the clamped CoC diameter in pixels of the last run.
    """

    def __init__(self, width: int, height: int, config: DofConfig, device=None, *, method: str = "gather",
                 tile_px: int = 8):
        self.width, self.height = check_image_size(width, height)
        if not isinstance(config, DofConfig):
            raise ValueError(f"config must be a foveawarp.DofConfig, got {type(config).__name__}")
        self.config = config
        self.device = get_device(device)
        self.method = check_choice("method", method, DOF_METHODS)
        self.tile_px = check_int_range("tile_px", tile_px, 1, 64)
        h, w, dev = self.height, self.width, self.device
        self.coc = wp.zeros((h, w), dtype=float, device=dev)
        self.pm = wp.zeros((h, w), dtype=wp.vec4, device=dev)
        self.geo = wp.zeros((h, w), dtype=wp.vec2, device=dev)
        self.accum = wp.zeros((h, w), dtype=wp.vec4, device=dev) if self.method == "scatter" else None
        self.tiles = ((h + self.tile_px - 1) // self.tile_px, (w + self.tile_px - 1) // self.tile_px)
        # per tile: max floor(R^2) of its sources, then the max over the neighbouring tiles (pixels^2)
        self.tile_r2 = wp.zeros(self.tiles, dtype=wp.int32, device=dev)
        self.tile_window = wp.zeros(self.tiles, dtype=wp.int32, device=dev)
        # a source disc reaches at most n_max pixels; its tile is then within ceil(n_max / tile) tiles
        self.max_reach_px = disc_reach_host(max(0.5 * config.max_coc_px, 0.5))
        self.dilate_tiles = -(-self.max_reach_px // self.tile_px)
        f0 = config.focus_depth_m if config.focus_depth_m is not None else FOCUS_FAR_M
        self.focus_m = wp.full(1, value=float(f0), dtype=float, device=dev)
        self._no_hit = wp.zeros((1, 1), dtype=wp.uint8, device=dev)
        self._params = {}

    # -- helpers ---------------------------------------------------------------------------------------
    def params(self, *, fov_y_deg: Optional[float] = None, use_hit: bool = True) -> DofParams:
        """The kernel parameters (cached per field of view and hit-mask use)."""
        key = (None if fov_y_deg is None else float(fov_y_deg), bool(use_hit))
        p = self._params.get(key)
        if p is None:
            c = self.config
            p = DofParams()
            p.coc_scale = lens_scale(c.aperture_m, c.focal_length_m, c.px_per_m)
            p.focal_m = float(c.focal_length_m)
            p.max_coc_px = float(c.max_coc_px)
            p.gamma = float(c.gamma)
            p.eps_px = float(c.eps_px)
            p.fg_fix = 1 if c.foreground_fix else 0
            p.bg_fix = 1 if c.background_fix else 0
            p.use_hit = 1 if use_hit else 0
            if fov_y_deg is None:
                p.tan_half_fov_y = 0.0
            else:
                fov = check_range("fov_y_deg", fov_y_deg, 0.0, 180.0, lo_open=True, hi_open=True)
                p.tan_half_fov_y = math.tan(math.radians(fov) * 0.5)
            p.aspect = float(self.width) / float(self.height)
            p.width = self.width
            p.height = self.height
            self._params[key] = p
        return p

    def _check(self, name, a, dtype):
        if not isinstance(a, wp.array):
            raise ValueError(f"{name} must be a ({self.height}, {self.width}) wp.array of "
                             f"{getattr(dtype, '__name__', dtype)}, got {type(a).__name__}")
        if tuple(a.shape) != (self.height, self.width) or a.dtype != dtype:
            raise ValueError(f"{name} must be a ({self.height}, {self.width}) wp.array of "
                             f"{getattr(dtype, '__name__', dtype)}, got shape {tuple(a.shape)} of {a.dtype}")
        if a.device != self.device:
            raise ValueError(f"{name} must be on {self.device}, got {a.device}")
        return a

    def set_focus(self, focus_depth_m: float) -> None:
        """Write a host focus depth (view depth, metres, > focal length) into :attr:`focus_m` (a device fill)."""
        self.focus_m.fill_(check_focus(focus_depth_m, self.config.focal_length_m))

    def focus_at_pixel(self, depth, hit, gaze_px, *, fov_y_deg: Optional[float] = None) -> wp.array:
        """Set :attr:`focus_m` to the view depth at the gaze pixel (on the device) and return it.

        Args:
            depth: (H, W) float32 wp.array: view depth in metres, or (with ``fov_y_deg``) the distance from the
                eye as in the G-buffer.
            hit: (H, W) uint8 wp.array or None; a miss at the gaze pixel focuses at infinity (1e30 m).
            gaze_px: (x, y) in pixels; off-screen points clamp to the nearest pixel.
            fov_y_deg: the camera's vertical field of view in degrees when ``depth`` is a distance.
        """
        from ..camera import _check_gaze

        g = _check_gaze(gaze_px)
        self._check("depth", depth, wp.float32)
        if hit is not None:
            self._check("hit", hit, wp.uint8)
        wp.launch(dof_focus_at_pixel_kernel, dim=1,
                  inputs=[self.params(fov_y_deg=fov_y_deg, use_hit=hit is not None), depth,
                          hit if hit is not None else self._no_hit, g[0], g[1]],
                  outputs=[self.focus_m], device=self.device)
        return self.focus_m

    # -- the pass --------------------------------------------------------------------------------------
    def run(self, color_in, depth, hit, focus_depth_m, color_out, *, fov_y_deg: Optional[float] = None) -> None:
        """Blur ``color_in`` by its circles of confusion into ``color_out``.

        Args:
            color_in: (H, W) vec3 wp.array, linear or display-referred (the blur is a weighted mean of it).
            depth: (H, W) float32 wp.array: view depth in metres (along the view axis, as in the thin-lens
                model); with ``fov_y_deg`` it is the distance from the eye (the G-buffer's depth) and is
                converted per pixel. Depth <= 0 or NaN counts as at the lens (largest CoC, foreground).
            hit: (H, W) uint8 wp.array or None; pixels with hit == 0 are background at infinite depth.
            focus_depth_m: view depth of the focal plane in metres: a float (> focal length, else ValueError),
                a (1,) float32 device array (clamped on the device to (F, 1e30]), or None: the config's
                ``focus_depth_m`` when set, else :attr:`focus_m` (see :meth:`focus_at_pixel`).
            color_out: (H, W) vec3 wp.array; may be ``color_in`` (each output pixel reads only its own input).
            fov_y_deg: vertical field of view in degrees, in (0, 180), when ``depth`` is a distance.
        """
        self._check("color_in", color_in, wp.vec3)
        self._check("depth", depth, wp.float32)
        self._check("color_out", color_out, wp.vec3)
        if hit is not None:
            self._check("hit", hit, wp.uint8)
        if focus_depth_m is None and self.config.focus_depth_m is not None:
            focus_depth_m = self.config.focus_depth_m
        if focus_depth_m is None:
            focus = self.focus_m
        elif isinstance(focus_depth_m, wp.array):
            if focus_depth_m.shape != (1,) or focus_depth_m.dtype != wp.float32:
                raise ValueError(f"focus_depth_m as an array must be a (1,) float32 wp.array, "
                                 f"got shape {focus_depth_m.shape} of {focus_depth_m.dtype}")
            if focus_depth_m.device != self.device:
                raise ValueError(f"focus_depth_m must be on {self.device}, got {focus_depth_m.device}")
            focus = focus_depth_m
        else:
            self.set_focus(focus_depth_m)
            focus = self.focus_m
        p = self.params(fov_y_deg=fov_y_deg, use_hit=hit is not None)
        dev, dim = self.device, (self.height, self.width)
        parallel.launch(dof_prepare_kernel, dim=dim,
                        inputs=[p, focus, color_in, depth, hit if hit is not None else self._no_hit],
                        outputs=[self.coc, self.pm, self.geo], device=dev)
        if self.method == "scatter":
            self.accum.zero_()
            wp.launch(dof_scatter_kernel, dim=dim, inputs=[p, self.coc, self.pm, self.geo],
                      outputs=[self.accum], device=dev)
            parallel.launch(dof_normalize_kernel, dim=dim, inputs=[self.accum, color_in], outputs=[color_out],
                            device=dev)
            return
        wp.launch(dof_tile_r2_kernel, dim=self.tiles, inputs=[self.geo, self.tile_px],
                  outputs=[self.tile_r2], device=dev)
        wp.launch(dof_tile_dilate_kernel, dim=self.tiles, inputs=[self.tile_r2, self.dilate_tiles],
                  outputs=[self.tile_window], device=dev)
        parallel.launch(dof_gather_kernel, dim=dim,
                        inputs=[p, self.coc, self.pm, self.geo, self.tile_window, self.tile_px, color_in],
                        outputs=[color_out], device=dev)
