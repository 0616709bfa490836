"""The periphery's spatial filter of a foveated path-traced frame (``ShadingConfig.path_filter = "atrous"``):
``path_filter_iterations`` edge-avoiding a-trous iterations (steps 1, 2, 4, ...; ``kernels/atrous.py``) over the
reconstructed HDR frame, guided by the G-buffer's depth, normals and hits, then blended back to the unfiltered
frame by eccentricity so that the fovea (``path_filter_fovea_deg``) is left as traced. With
``path_filter_guide = "variance"`` it first updates each pixel's temporal luminance moments, whose variance guides
the iterations' luminance stop; ``reset()`` forgets them when a frame that does not run the filter comes between.

How a frame calls it: ``run(hdr, gbuffer, frame_params, out, use_history)`` after the reconstruction and before
depth of field and the tone map, with fixed arguments (a captured CUDA graph replays it).

The periphery's history (``ShadingConfig.path_history``; :class:`PeripheryHistoryStage`) follows it: each frame's
output blended with the previous one's where the periphery lies, ``run(hdr, gbuffer, frame_params, out,
use_history)`` then ``reset()`` when a frame that does not run it (a full-resolution one) comes between.
"""

from __future__ import annotations

import warp as wp

from .. import parallel
from ..kernels.atrous import (atrous_kernel, blend_by_eccentricity_kernel, keep_history_kernel,
                              luminance_moments_kernel, periphery_history_kernel)
from ..kernels.atrous_guided import atrous_guided_kernel

__all__ = ["PathFilterStage", "PeripheryHistoryStage"]


class PathFilterStage:
    """The a-trous filter at ``width`` x ``height`` on ``device`` with ``iterations`` (1-5) and the unfiltered
    fovea's radius ``fovea_deg`` (degrees of eccentricity; full strength from twice it). ``guide``: "relative"
    (the relative luminance stop) or "variance" (SVGF's, from each pixel's temporal luminance moments, carried
    from frame to frame with taps matching in depth within ``depth_eps_rel``)."""

    #: the moments' exponential weight once a pixel has 1 / MOMENTS_ALPHA frames (SVGF's 0.2)
    MOMENTS_ALPHA = 0.2

    def __init__(self, width: int, height: int, device, iterations: int, fovea_deg: float,
                 guide: str = "relative", depth_eps_rel: float = 0.01):
        self.device = wp.get_device(device)
        self.width, self.height = int(width), int(height)
        self.iterations = int(iterations)
        self.fovea_deg = float(fovea_deg)
        self.guide, self.depth_eps_rel = str(guide), float(depth_eps_rel)
        shape = (self.height, self.width)
        self._ping = wp.zeros(shape, dtype=wp.vec3, device=self.device)
        self._pong = wp.zeros(shape, dtype=wp.vec3, device=self.device)
        if self.guide == "variance":
            self.moments = wp.zeros(shape, dtype=wp.vec3, device=self.device)
            self.moments_history = wp.zeros(shape, dtype=wp.vec3, device=self.device)
            self.history_depth = wp.zeros(shape, dtype=float, device=self.device)
            self.valid = wp.zeros(1, dtype=wp.int32, device=self.device)
            self.variance = [wp.zeros(shape, dtype=float, device=self.device) for _ in range(3)]

    def run(self, hdr, gbuffer, frame_params, out, use_history: bool = True) -> None:
        """Filter ``hdr`` ((H, W) vec3) into ``out`` (another (H, W) vec3 array); ``use_history`` False (first
        frame, cut) starts the variance guide's moments afresh."""
        dim = (self.height, self.width)
        g = gbuffer
        src = hdr
        bufs = (self._ping, self._pong)
        if self.guide == "variance":
            var = self.variance[0]
            parallel.launch(luminance_moments_kernel, dim=dim,
                            inputs=[hdr, g.hit, g.depth, g.reproj_uv, g.prev_dist, self.moments_history,
                                    self.history_depth, self.valid, int(bool(use_history)), self.MOMENTS_ALPHA,
                                    self.depth_eps_rel], outputs=[self.moments, var], device=self.device)
            parallel.launch(keep_history_kernel, dim=dim, inputs=[self.moments, g.depth],
                            outputs=[self.moments_history, self.history_depth, self.valid], device=self.device)
        for k in range(self.iterations):
            dst = bufs[k % 2]
            if self.guide == "variance":
                var_dst = self.variance[1 + k % 2]
                parallel.launch(atrous_guided_kernel, dim=dim,
                                inputs=[src, var, g.depth, g.normal, g.hit, 1 << k], outputs=[dst, var_dst],
                                device=self.device)
                var = var_dst
            else:
                parallel.launch(atrous_kernel, dim=dim, inputs=[src, g.depth, g.normal, g.hit, 1 << k],
                                outputs=[dst], device=self.device)
            src = dst
        parallel.launch(blend_by_eccentricity_kernel, dim=dim, inputs=[frame_params, hdr, src, self.fovea_deg],
                        outputs=[out], device=self.device)

    def reset(self) -> None:
        """Forget the variance guide's moments (a frame that does not run the filter came between)."""
        if self.guide == "variance":
            self.valid.zero_()


class PeripheryHistoryStage:
    """The periphery's history blend (kernels/atrous.py) at ``width`` x ``height`` on ``device``: the previous
    frame's weight ``weight`` (in (0, 0.95]) from twice ``fovea_deg`` on, none within it; reprojected taps must
    match in depth within ``depth_eps_rel`` (``TemporalConfig.depth_eps_rel``)."""

    def __init__(self, width: int, height: int, device, weight: float, fovea_deg: float, depth_eps_rel: float):
        self.device = wp.get_device(device)
        self.width, self.height = int(width), int(height)
        self.weight, self.fovea_deg, self.depth_eps_rel = float(weight), float(fovea_deg), float(depth_eps_rel)
        shape = (self.height, self.width)
        self.history = wp.zeros(shape, dtype=wp.vec3, device=self.device)
        self.history_depth = wp.zeros(shape, dtype=float, device=self.device)
        self.valid = wp.zeros(1, dtype=wp.int32, device=self.device)

    def run(self, hdr, gbuffer, frame_params, out, use_history: bool) -> None:
        """Blend ``hdr`` ((H, W) vec3) with the history into ``out`` (another (H, W) vec3 array), which becomes
        the next frame's history; ``use_history`` False (first frame, cut) leaves ``hdr`` as it is."""
        dim = (self.height, self.width)
        g = gbuffer
        parallel.launch(periphery_history_kernel, dim=dim,
                        inputs=[frame_params, hdr, g.hit, g.depth, g.reproj_uv, g.prev_dist, self.history,
                                self.history_depth, self.valid, int(bool(use_history)), self.weight, self.fovea_deg,
                                self.depth_eps_rel], outputs=[out], device=self.device)
        parallel.launch(keep_history_kernel, dim=dim, inputs=[out, g.depth],
                        outputs=[self.history, self.history_depth, self.valid], device=self.device)

    def reset(self) -> None:
        """Forget the history (the next ``run`` leaves its input as it is)."""
        self.valid.zero_()
