"""ReorderStage: turns the sampling map into the work the tracing kernel launches over."""

from __future__ import annotations

import numpy as np
import warp as wp

from .._util import check_image_size, get_device
from ..config import REORDER_STRATEGIES, ReorderConfig, check_choice, resolve_reorder_strategy, show
from ..kernels.reorder import (
    block_scan_kernel,
    compact_count_kernel,
    compact_count_words_kernel,
    compact_scatter_kernel,
    compact_scatter_words_kernel,
    rows_balance_kernel,
    rows_compact_kernel,
)

__all__ = ["ReorderStage", "morton_tile_order"]

_CUDA_BLOCK = 256  # threads per block of the compaction / row kernels on CUDA (the CPU runs blocks of 1)
_CUDA_SCAN_BLOCK = 1024  # threads of the one-block offset scan on CUDA
_CUDA_PER_THREAD = 4  # consecutive output positions per compaction thread on CUDA
_CPU_PER_THREAD = 256  # on the CPU (blocks of one thread: longer runs, fewer blocks)
_CUDA_WORDS = 1  # 8-pixel words per compaction thread on CUDA (the word kernels)


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
    """Compaction buffers for one image size; ``run(mask)`` fills them for ``config.strategy`` ("auto" resolved
    for the device: "tile" on CUDA, "none" on the CPU).

    Outputs (device arrays, valid after ``run``):
      - "scan" / "tile": ``work`` (N,) int32 flat indices y * W + x, ``count`` (1,) int32;
      - "rows" / "rows+balance": ``coords`` (H, W) vec2i and ``counts`` (H,) int32 (row CSR);
      - "none": nothing (the caller launches over the mask).

    Launches per ``run``: "scan" / "tile": 3 (count, one-block scan of the per-block counts, scatter; the
    mask is read twice, the list written once); "rows": 1; "rows+balance": 2. No memset, no temporary
    allocation, no host read (CUDA-graph capturable).

    With ``packed`` (default: on CUDA) and an image width that is a multiple of 8, "scan" and "tile" with 8 x 8
    tiles read the mask as 8-pixel words (``compact_*_words_kernel``): the same list.
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
        t = config.tile
        self.tiles_x = (width + t - 1) // t
        self.tiles_y = (height + t - 1) // t
        nt = self.tiles_x * self.tiles_y
        self.tile_order = wp.array(morton_tile_order(self.tiles_x, self.tiles_y), dtype=wp.int32, device=device)
        self.coords = wp.zeros((height, width), dtype=wp.vec2i, device=device)
        self.counts = wp.zeros(height, dtype=wp.int32, device=device)
        self._block_dim = _CUDA_BLOCK if device.is_cuda else 1
        self._scan_block_dim = _CUDA_SCAN_BLOCK if device.is_cuda else 1
        self._per_thread = _CUDA_PER_THREAD if device.is_cuda else _CPU_PER_THREAD
        per_block = self._block_dim * self._per_thread
        # positions of the output order: every pixel (raster), or every slot of every tile (partial tiles too)
        self._n_order = {"scan": n, "tile": nt * t * t}
        nb = max(1, (max(self._n_order.values()) + per_block - 1) // per_block)
        self.block_counts = wp.zeros(nb, dtype=wp.int32, device=device)
        self.block_offsets = wp.zeros(nb, dtype=wp.int32, device=device)
        self._blocks = {}  # strategy -> (blocks, count view, offset view): views made once, not per run
        for s, no in self._n_order.items():
            b = (no + per_block - 1) // per_block
            self._blocks[s] = (b, self.block_counts[:b], self.block_offsets[:b])
        # the word kernels: runs of 8 positions (fewer blocks than the byte kernels' at these block sizes)
        self.packed = device.is_cuda
        self._words = _CUDA_WORDS if device.is_cuda else _CPU_PER_THREAD // 8
        self._word_blocks = {}
        if width % 8 == 0:
            for s, no in self._n_order.items():
                nw = no // 8
                b = (nw + self._block_dim * self._words - 1) // (self._block_dim * self._words)
                if b <= nb:  # fits the block buffers (always, at these block sizes)
                    self._word_blocks[s] = (nw, b, self.block_counts[:b], self.block_offsets[:b])
        self._views = {}  # id(mask) -> (mask, its uint64 view): the masks compacted by words

    @property
    def strategy(self) -> str:
        """The configured strategy with "auto" resolved for the stage's device."""
        return resolve_reorder_strategy(self.config.strategy, self.device)

    def _check_mask(self, name: str, a) -> None:
        if (not isinstance(a, wp.array) or a.dtype != wp.uint8
                or tuple(a.shape) != (self.height, self.width) or a.device != self.device):
            raise ValueError(f"{name} must be a ({self.height}, {self.width}) uint8 wp.array on {self.device}, got "
                             f"{type(a).__name__} {getattr(a, 'dtype', None)} "
                             f"{tuple(getattr(a, 'shape', ()))} on {getattr(a, 'device', None)}")

    def _words_view(self, a) -> wp.array:
        """A non-owning uint64 view of the bytes of ``a``, made once per array (the last few kept)."""
        v = self._views.get(id(a))
        if v is None or v[0] is not a:
            if len(self._views) >= 4:
                self._views.clear()
            v = (a, wp.array(ptr=a.ptr, dtype=wp.uint64, shape=(self.width * self.height // 8,), device=a.device))
            self._views[id(a)] = v
        return v[1]

    def run(self, mask, strategy: str | None = None, keep=None) -> None:
        """Compact ``mask`` ((H, W) uint8 wp.array on the stage's device, nonzero = sampled) with ``strategy``
        (default: the config's). Launches only (no host reads of the mask).

        ``keep`` (optional, the same kind of array): list only the pixels set in both ``mask`` and ``keep``
        (``FrameLoop`` passes the G-buffer's hit mask: a sampled pixel whose primary ray missed needs no shading,
        and in the list it would hold a lane of a warp whose other lanes trace). None: every set pixel of
        ``mask``. Ignored by "none", which lists nothing."""
        s = resolve_reorder_strategy(self.config.strategy if strategy is None
                                     else check_choice("strategy", strategy, REORDER_STRATEGIES), self.device)
        self._check_mask("mask", mask)
        if keep is None:
            keep = mask
        else:
            self._check_mask("keep", keep)
        dev = self.device
        if s == "none":
            return
        if s in ("rows", "rows+balance"):
            wp.launch_tiled(rows_compact_kernel, dim=[self.height], inputs=[mask, keep],
                            outputs=[self.coords, self.counts], block_dim=self._block_dim, device=dev)
            if s == "rows+balance":
                k = self.config.balance_rows
                nb = (self.height + k - 1) // k
                wp.launch(rows_balance_kernel, dim=nb, inputs=[self.coords, self.counts, k], device=dev)
            return
        tile = 0 if s == "scan" else self.config.tile
        if self.packed and s in self._word_blocks and tile in (0, 8) and mask.is_contiguous and keep.is_contiguous:
            # by 8-pixel words: non-owning uint64 views of the masks' bytes
            nw, nb, counts, offsets = self._word_blocks[s]
            kernels = (compact_count_words_kernel, compact_scatter_words_kernel)
            common = [self._words_view(mask), self._words_view(keep), self.tile_order, tile, self.tiles_x,
                      self.width // 8, self.height, nw, self._words]
        else:
            nb, counts, offsets = self._blocks[s]
            kernels = (compact_count_kernel, compact_scatter_kernel)
            common = [mask, keep, self.tile_order, tile, self.tiles_x, self._n_order[s], self._per_thread]
        wp.launch_tiled(kernels[0], dim=[nb], inputs=common, outputs=[counts], block_dim=self._block_dim, device=dev)
        wp.launch_tiled(block_scan_kernel, dim=[1], inputs=[counts], outputs=[offsets, self.count],
                        block_dim=self._scan_block_dim, device=dev)
        wp.launch_tiled(kernels[1], dim=[nb], inputs=[*common, offsets], outputs=[self.work],
                        block_dim=self._block_dim, device=dev)
