"""Compaction / reordering ops (thesis A3) on NumPy or Warp masks."""

from __future__ import annotations

import numpy as np
import warp as wp

from .._util import as_wp, check_image_size, get_device
from ..config import ReorderConfig, check_array, check_choice, check_int_range
from ..stages.reorder import ReorderStage

__all__ = ["compact", "reorder_rows"]


def _mask(mask, device):
    m = check_array("mask", mask)
    if m.ndim != 2 or m.shape[0] < 1 or m.shape[1] < 1:
        raise ValueError(f"mask must be a non-empty (H, W) array, got shape {m.shape}")
    check_image_size(m.shape[1], m.shape[0])
    return as_wp((m != 0).astype(np.uint8), wp.uint8, device, name="mask")


def compact(mask, *, order: str = "tile", tile: int = 8, device=None) -> np.ndarray:
    """Flat indices (y * W + x) of the nonzero pixels, each exactly once: ``order="row"`` raster order
    (exclusive scan + scatter), ``order="tile"`` screen tiles of ``tile`` x ``tile`` in Morton order (raster
    order inside a tile; ``tile`` a power of two in [2, 64]). ``mask``: (H, W) finite numbers, nonzero = set."""
    check_choice("order", order, ("row", "tile"))
    tile = check_int_range("tile", tile, 2, 64)
    if tile & (tile - 1):
        raise ValueError(f"tile must be a power of two in [2, 64], got {tile!r}")
    dev = get_device(device)
    m = _mask(mask, dev)
    h, w = m.shape
    stage = ReorderStage(w, h, ReorderConfig(strategy="scan" if order == "row" else "tile", tile=tile), dev)
    stage.run(m)
    n = int(stage.count.numpy()[0])
    return stage.work.numpy()[:n].copy()


def reorder_rows(mask, *, balance_rows: int = 0, device=None):
    """The thesis's strategy 1 (row CSR): ``coords`` (H, W, 2) int32 with each row's sampled (x, y) packed to
    the left, and ``counts`` (H,) int32. With ``balance_rows = k > 0``, strategy 2 over blocks of k rows."""
    check_int_range("balance_rows", balance_rows, 0, 1024)
    dev = get_device(device)
    m = _mask(mask, dev)
    h, w = m.shape
    cfg = ReorderConfig(strategy="rows+balance" if balance_rows else "rows", balance_rows=max(balance_rows, 1))
    stage = ReorderStage(w, h, cfg, dev)
    stage.run(m)
    coords = stage.coords.numpy().reshape(h, w, 2).astype(np.int32)
    counts = stage.counts.numpy().astype(np.int32)
    return coords, counts
