"""Seed / sample masks shared by the reconstruction and reorder benchmarks.

* ``sparse_mask``: what foveated sampling alone traces: a probability falling with the distance to the gaze
  (dense fovea, ``xi = 1 / block^2`` in the periphery), binarized with stratified thresholds (a random rank
  per pixel inside every aligned ``block`` x ``block`` tile), so every tile holds a sample (ALGORITHMS.md A2.5).
* ``filled_mask``: the frame loop's ``filled`` buffer once temporal history fills most pixels: the sparse
  mask OR everything outside disocclusion holes. Holes are thin random ellipses (slivers along object edges,
  1-4 px wide, 3-40 px long) covering ``hole_fraction`` of the image; inside a hole only traced pixels are
  seeds, so the block guarantee still holds.
"""

from __future__ import annotations

import numpy as np


def _stratified_rank(h, w, block, rng):
    """(rank + u) / block^2 with a random permutation of ranks inside every aligned block x block tile."""
    th, tw = -(-h // block), -(-w // block)
    ranks = rng.permuted(np.broadcast_to(np.arange(block * block), (th * tw, block * block)), axis=1)
    full = ranks.reshape(th, tw, block, block).transpose(0, 2, 1, 3).reshape(th * block, tw * block)[:h, :w]
    return (full + rng.random((h, w))) / (block * block)


def sparse_mask(w, h, rate, rng, block=4, gaze=None):
    """Foveated sample mask with mean sampling rate ~``rate`` (>= 1 / block^2) and the block guarantee."""
    gx, gy = gaze or (w * 0.55, h * 0.45)
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot(xx + 0.5 - gx, yy + 0.5 - gy) / h
    xi = 1.0 / (block * block)
    lo, hi = 0.0, 1e4
    rs = r[::4, ::4]  # the mean rate from a subsample is close enough and much faster at 4K
    for _ in range(60):
        k = 0.5 * (lo + hi)
        if np.clip(1 - k * rs, xi, 1).mean() > rate:
            lo = k
        else:
            hi = k
    p = np.clip(1 - k * r, xi, 1)
    # the rank-0 pixel of a tile has threshold < 1 / block^2 <= p: every tile holds a sample
    return (_stratified_rank(h, w, block, rng) < p).astype(np.uint8)


def hole_mask(w, h, hole_fraction, rng):
    """Boolean (H, W): union of thin random ellipses covering about ``hole_fraction`` of the pixels."""
    holes = np.zeros((h, w), bool)
    target = hole_fraction * w * h
    covered = 0
    while covered < target:
        n = max(16, int((target - covered) / 60))
        cx, cy = rng.uniform(0, w, n), rng.uniform(0, h, n)
        a, b = rng.uniform(1.5, 20.0, n), rng.uniform(0.5, 2.0, n)
        th = rng.uniform(0, np.pi, n)
        for i in range(n):
            r = int(np.ceil(a[i])) + 1
            x0, x1 = max(0, int(cx[i]) - r), min(w, int(cx[i]) + r + 1)
            y0, x1y = max(0, int(cy[i]) - r), min(h, int(cy[i]) + r + 1)
            if x0 >= x1 or y0 >= x1y:
                continue
            yy, xx = np.mgrid[y0:x1y, x0:x1]
            dx, dy = xx + 0.5 - cx[i], yy + 0.5 - cy[i]
            u = dx * np.cos(th[i]) + dy * np.sin(th[i])
            v = -dx * np.sin(th[i]) + dy * np.cos(th[i])
            holes[y0:x1y, x0:x1] |= (u / a[i]) ** 2 + (v / b[i]) ** 2 <= 1.0
        covered = int(holes.sum())
    return holes


def filled_mask(w, h, rng, block=4, rate=0.25, hole_fraction=0.06, sampled=None):
    """Mostly-filled seed mask (~90-97 % seeds): sampled pixels (``sampled``, or a new sparse mask) plus
    everything outside the holes."""
    if sampled is None:
        sampled = sparse_mask(w, h, rate, rng, block)
    return ((sampled != 0) | ~hole_mask(w, h, hole_fraction, rng)).astype(np.uint8)


def bench_masks(w, h, rng, block=4):
    """The two cases every reconstruct / reorder benchmark reports: (name, uint8 mask)."""
    sparse = sparse_mask(w, h, 0.25, rng, block)
    return [("sparse", sparse), ("filled", filled_mask(w, h, rng, block, sampled=sparse))]
