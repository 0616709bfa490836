"""The periphery's spatial filter of a foveated path-traced frame (``ShadingConfig.path_filter = "atrous"``):
``path_filter_iterations`` edge-avoiding a-trous iterations (steps 1, 2, 4, ...; ``kernels/atrous.py``) over the
reconstructed HDR frame, guided by the G-buffer's depth, normals and hits, then blended back to the unfiltered
frame by eccentricity so that the fovea (``path_filter_fovea_deg``) is left as traced.

How a frame calls it: ``run(hdr, gbuffer, frame_params, out)`` after the reconstruction and before depth of field
and the tone map, with fixed arguments (a captured CUDA graph replays it).

The periphery's history (``ShadingConfig.path_history``; :class:`PeripheryHistoryStage`) follows it: each frame's
output blended with the previous one's where the periphery lies, ``run(hdr, gbuffer, frame_params, out,
use_history)`` then ``reset()`` when a frame that does not run it (a full-resolution one) comes between.
"""

from __future__ import annotations

import warp as wp

from .. import parallel
from ..kernels.atrous import (atrous_kernel, blend_by_eccentricity_kernel, keep_history_kernel,
                              periphery_history_kernel)

__all__ = ["PathFilterStage", "PeripheryHistoryStage"]


class PathFilterStage:
    """The a-trous filter at ``width`` x ``height`` on ``device`` with ``iterations`` (1-5) and the unfiltered
    fovea's radius ``fovea_deg`` (degrees of eccentricity; full strength from twice it)."""

    def __init__(self, width: int, height: int, device, iterations: int, fovea_deg: float):
        self.device = wp.get_device(device)
        self.width, self.height = int(width), int(height)
        self.iterations = int(iterations)
        self.fovea_deg = float(fovea_deg)
        self._ping = wp.zeros((self.height, self.width), dtype=wp.vec3, device=self.device)
        self._pong = wp.zeros((self.height, self.width), dtype=wp.vec3, device=self.device)

    def run(self, hdr, gbuffer, frame_params, out) -> None:
        """Filter ``hdr`` ((H, W) vec3) into ``out`` (another (H, W) vec3 array)."""
        dim = (self.height, self.width)
        src = hdr
        bufs = (self._ping, self._pong)
        for k in range(self.iterations):
            dst = bufs[k % 2]
            parallel.launch(atrous_kernel, dim=dim, inputs=[src, gbuffer.depth, gbuffer.normal, gbuffer.hit, 1 << k],
                            outputs=[dst], device=self.device)
            src = dst
        parallel.launch(blend_by_eccentricity_kernel, dim=dim, inputs=[frame_params, hdr, src, self.fovea_deg],
                        outputs=[out], device=self.device)


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
