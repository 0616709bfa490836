"""The periphery's spatial filter of a foveated path-traced frame (``ShadingConfig.path_filter = "atrous"``):
``path_filter_iterations`` edge-avoiding a-trous iterations (steps 1, 2, 4, ...; ``kernels/atrous.py``) over the
reconstructed HDR frame, guided by the G-buffer's depth, normals and hits, then blended back to the unfiltered
frame by eccentricity so that the fovea (``path_filter_fovea_deg``) is left as traced.

How a frame calls it: ``run(hdr, gbuffer, frame_params, out)`` after the reconstruction and before depth of field
and the tone map, with fixed arguments (a captured CUDA graph replays it).
"""

from __future__ import annotations

import warp as wp

from .. import parallel
from ..kernels.atrous import atrous_kernel, blend_by_eccentricity_kernel

__all__ = ["PathFilterStage"]


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
