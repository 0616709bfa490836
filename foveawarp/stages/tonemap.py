"""Tone map stage: Uncharted 2 filmic curve with exposure, white point and display gamma (ALGORITHMS.md A4)."""

from __future__ import annotations

import warp as wp

from .. import parallel
from ..kernels.tonemap import tonemap_kernel, tonemap_rows_kernel

__all__ = ["TonemapStage"]


class TonemapStage:
    """Maps linear HDR radiance to display-referred [0, 1] with a :class:`ShadingConfig`'s exposure and white
    point."""

    def __init__(self, config, width: int, height: int, device):
        self.config, self.width, self.height, self.device = config, width, height, device

    def run(self, hdr, out) -> None:
        sc = self.config
        # on the CPU a thread per row, the row's display gamma one vectorized loop (the same values)
        parallel.launch_rows(tonemap_kernel, tonemap_rows_kernel, (self.height, self.width),
                             inputs=[hdr, float(sc.exposure), float(sc.white_point)], outputs=[out], device=self.device)
