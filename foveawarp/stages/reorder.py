"""ReorderStage: turns the sampling map into the work the tracing kernel launches over."""

from __future__ import annotations

import numpy as np
import warp as wp

from .._util import check_image_size, get_device
from ..config import REORDER_STRATEGIES, ReorderConfig, check_choice, show
from ..kernels.reorder import (
    flags_kernel,
    rows_balance_kernel,
    rows_compact_kernel,
    scatter_kernel,
    tile_count_kernel,
    tile_scatter_kernel,
    total_kernel,
)

__all__ = ["ReorderStage", "morton_tile_order"]


def _part1by1(v: np.ndarray) -> np.ndarray:
    v = v.astype(np.uint64) & 0xFFFF
    v = (v | (v << 8)) & 0x00FF00FF
    v = (v | (v << 4)) & 0x0F0F0F0F
    v = (v | (v << 2)) & 0x33333333
    v = (v | (v << 1)) & 0x55555555
    return v


def morton_tile_order(tiles_x: int, tiles_y: int) -> np.ndarray:
    """Flat tile indices (ty * tiles_x + tx) sorted by the Morton (Z-order) code of (tx, ty)."""
    ty, tx = np.mgrid[0:tiles_y, 0:tiles_x]
    code = _part1by1(tx.ravel()) | (_part1by1(ty.ravel()) << np.uint64(1))
    return np.argsort(code, kind="stable").astype(np.int32)


class ReorderStage:
    """Compaction buffers for one image size; ``run(mask)`` fills them for ``config.strategy``.

    Outputs (device arrays, valid after ``run``):
      - "scan" / "tile": ``work`` (N,) int32 flat indices y * W + x, ``count`` (1,) int32;
      - "rows" / "rows+balance": ``coords`` (H, W) vec2i and ``counts`` (H,) int32 (row CSR);
      - "none": nothing (the caller launches over the mask).
    """

    def __init__(self, width: int, height: int, config: ReorderConfig, device):
        width, height = check_image_size(width, height)
        if not isinstance(config, ReorderConfig):
            raise ValueError(f"config must be a ReorderConfig, got {show(config)} ({type(config).__name__})")
        device = get_device(device)
        self.width, self.height, self.config, self.device = width, height, config, device
        n = width * height
        self.count = wp.zeros(1, dtype=wp.int32, device=device)
        self.work = wp.zeros(n, dtype=wp.int32, device=device)
        self.flags = wp.zeros(n, dtype=wp.int32, device=device)
        self.offsets = wp.zeros(n, dtype=wp.int32, device=device)
        t = config.tile
        self.tiles_x = (width + t - 1) // t
        self.tiles_y = (height + t - 1) // t
        nt = self.tiles_x * self.tiles_y
        self.tile_order = wp.array(morton_tile_order(self.tiles_x, self.tiles_y), dtype=wp.int32, device=device)
        self.tile_counts = wp.zeros(nt, dtype=wp.int32, device=device)
        self.tile_offsets = wp.zeros(nt, dtype=wp.int32, device=device)
        self.coords = wp.zeros((height, width), dtype=wp.vec2i, device=device)
        self.counts = wp.zeros(height, dtype=wp.int32, device=device)

    @property
    def strategy(self) -> str:
        return self.config.strategy

    def run(self, mask, strategy: str | None = None) -> None:
        """Compact ``mask`` ((H, W) uint8 wp.array on the stage's device, nonzero = sampled) with ``strategy``
        (default: the config's). Launches only (no host reads of the mask)."""
        s = self.config.strategy if strategy is None else check_choice("strategy", strategy, REORDER_STRATEGIES)
        if (not isinstance(mask, wp.array) or mask.dtype != wp.uint8
                or tuple(mask.shape) != (self.height, self.width) or mask.device != self.device):
            raise ValueError(f"mask must be a ({self.height}, {self.width}) uint8 wp.array on {self.device}, got "
                             f"{type(mask).__name__} {getattr(mask, 'dtype', None)} "
                             f"{tuple(getattr(mask, 'shape', ()))} on {getattr(mask, 'device', None)}")
        dev = self.device
        if s == "none":
            return
        if s in ("rows", "rows+balance"):
            wp.launch(rows_compact_kernel, dim=self.height, inputs=[mask], outputs=[self.coords, self.counts],
                      device=dev)
            if s == "rows+balance":
                k = self.config.balance_rows
                nb = (self.height + k - 1) // k
                wp.launch(rows_balance_kernel, dim=nb, inputs=[self.coords, self.counts, k], device=dev)
            return
        if s == "scan":
            wp.launch(flags_kernel, dim=(self.height, self.width), inputs=[mask], outputs=[self.flags], device=dev)
            wp.utils.array_scan(self.flags, self.offsets, inclusive=False)
            wp.launch(scatter_kernel, dim=self.flags.shape[0], inputs=[self.flags, self.offsets],
                      outputs=[self.work], device=dev)
            wp.launch(total_kernel, dim=1, inputs=[self.flags, self.offsets], outputs=[self.count], device=dev)
            return
        if s == "tile":
            nt = self.tile_counts.shape[0]
            t = self.config.tile
            wp.launch(tile_count_kernel, dim=nt, inputs=[mask, self.tile_order, t, self.tiles_x],
                      outputs=[self.tile_counts], device=dev)
            wp.utils.array_scan(self.tile_counts, self.tile_offsets, inclusive=False)
            wp.launch(tile_scatter_kernel, dim=nt, inputs=[mask, self.tile_order, t, self.tiles_x,
                      self.tile_offsets], outputs=[self.work], device=dev)
            wp.launch(total_kernel, dim=1, inputs=[self.tile_counts, self.tile_offsets], outputs=[self.count],
                      device=dev)
            return
