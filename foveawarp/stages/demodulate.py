"""Albedo demodulation around the reconstruction (``ReconstructionConfig.demodulate``; kernels/demodulate.py).

How a frame calls it: ``demodulate(color, gbuffer)`` before the reconstruction (it reads ``color`` at the
seeds and writes its own buffer, ``demod``: the temporal history is left as it is), then, after the
reconstruction and the optional periphery filter, ``remodulate(recon, gbuffer, out)``. Launches only, fixed
arguments (a captured CUDA graph replays them).
"""

from __future__ import annotations

import warp as wp

from .. import parallel
from ..kernels.demodulate import modulate_kernel

__all__ = ["DemodulateStage"]


class DemodulateStage:
    """Demodulation at ``width`` x ``height`` on ``device`` for the device scene ``dscene`` (its per-face albedo and
    emission serve an untextured G-buffer; a textured one carries its own per-pixel fields)."""

    def __init__(self, dscene, width: int, height: int, device):
        self.device = wp.get_device(device)
        self.width, self.height = int(width), int(height)
        self.dscene = dscene
        self.demod = wp.zeros((self.height, self.width), dtype=wp.vec3, device=self.device)
        self._dummy2 = wp.zeros((1, 1), dtype=wp.vec3, device=self.device)

    def _surface_args(self, gbuffer) -> list:
        ds = self.dscene
        if gbuffer.textured:
            return [1, gbuffer.albedo, gbuffer.emission, gbuffer.face, ds.face_albedo, ds.face_emission]
        return [0, self._dummy2, self._dummy2, gbuffer.face, ds.face_albedo, ds.face_emission]

    def demodulate(self, color, gbuffer) -> wp.array:
        """``color`` ((H, W) vec3 radiance) demodulated into ``self.demod``, which is returned."""
        parallel.launch(modulate_kernel, dim=(self.height, self.width),
                        inputs=[color, gbuffer.hit, *self._surface_args(gbuffer), 0], outputs=[self.demod],
                        device=self.device)
        return self.demod

    def remodulate(self, demod, gbuffer, out) -> None:
        """``demod`` ((H, W) vec3, a reconstruction of demodulated values) times each pixel's albedo plus its
        emission into ``out`` (another (H, W) vec3 array)."""
        parallel.launch(modulate_kernel, dim=(self.height, self.width),
                        inputs=[demod, gbuffer.hit, *self._surface_args(gbuffer), 1], outputs=[out],
                        device=self.device)
