"""Vertex attributes every reader completes the same way: normalization, area-weighted vertex normals and
tangents from UVs (glTF's convention: v grows downwards, the bitangent points to the image's top)."""

from __future__ import annotations

import numpy as np

__all__ = ["normalize_rows", "any_perpendicular", "compute_normals", "compute_tangents", "complete_tangents"]


def normalize_rows(v: np.ndarray, fallback) -> np.ndarray:
    """Unit rows; a zero-length (or non-finite) row becomes ``fallback``."""
    n = np.linalg.norm(v, axis=1, keepdims=True)
    ok = (n[:, 0] > 1e-30) & np.isfinite(n[:, 0])
    out = np.empty_like(v)
    out[ok] = v[ok] / n[ok]
    out[~ok] = fallback
    return out


def any_perpendicular(n: np.ndarray) -> np.ndarray:
    """A unit vector orthogonal to each unit row of ``n``."""
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    t = a - n * np.sum(a * n, axis=1, keepdims=True)
    return normalize_rows(t, (1.0, 0.0, 0.0))


def _scatter_add(triangles: np.ndarray, per_triangle: np.ndarray, n: int) -> np.ndarray:
    """(n, 3) sums over the triangles at each of their corners of the per-triangle (F, 3) vectors."""
    idx = triangles.reshape(-1)
    vals = np.repeat(per_triangle, 3, axis=0)
    return np.stack([np.bincount(idx, weights=vals[:, c], minlength=n) for c in range(3)], axis=1)


def compute_normals(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals: the sum of the (unnormalized) face normals around each vertex, normalized;
    (0, 0, 1) for a vertex of no or only degenerate triangles."""
    p = positions[triangles]
    fn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # length = twice the area
    return normalize_rows(_scatter_add(triangles, fn, positions.shape[0]), (0.0, 0.0, 1.0))


def compute_tangents(positions: np.ndarray, normals: np.ndarray, uvs: np.ndarray,
                     triangles: np.ndarray) -> np.ndarray:
    """(V, 4) tangents from the UVs: ``T = dP/du`` and ``B = dP/dv_up`` (``v_up = -v``: glTF's v points down)
    per triangle, summed per vertex; T made orthogonal to the normal; ``w = sign(dot(cross(N, T), B))``.
    Vertices without a usable UV gradient get any tangent orthogonal to the normal and w = +1."""
    p = positions[triangles]
    t = uvs[triangles]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    du1, du2 = t[:, 1, 0] - t[:, 0, 0], t[:, 2, 0] - t[:, 0, 0]
    dv1, dv2 = -(t[:, 1, 1] - t[:, 0, 1]), -(t[:, 2, 1] - t[:, 0, 1])
    det = du1 * dv2 - du2 * dv1
    ok = np.abs(det) > 1e-20
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)[:, None]
    # Lengyel's per-triangle frame: [T B] = [e1 e2] [[du1 du2], [dv1 dv2]]^-1
    ft = (e1 * dv2[:, None] - e2 * dv1[:, None]) * inv
    fb = (e2 * du1[:, None] - e1 * du2[:, None]) * inv
    acc_t = _scatter_add(triangles, ft, positions.shape[0])
    acc_b = _scatter_add(triangles, fb, positions.shape[0])
    tg = acc_t - normals * np.sum(acc_t * normals, axis=1, keepdims=True)
    n = np.linalg.norm(tg, axis=1)
    good = (n > 1e-12 * np.maximum(np.linalg.norm(acc_t, axis=1), 1e-30)) & (n > 1e-30)
    out = np.empty((positions.shape[0], 4), dtype=np.float64)
    out[:, :3] = any_perpendicular(normals)
    out[good, :3] = tg[good] / n[good, None]
    w = np.sign(np.sum(np.cross(normals, out[:, :3]) * acc_b, axis=1))
    out[:, 3] = np.where(w < 0, -1.0, 1.0)
    return out



def complete_tangents(positions: np.ndarray, normals: np.ndarray, uvs, triangles: np.ndarray) -> np.ndarray:
    """:func:`compute_tangents` from ``uvs``, or, without UVs, any tangent orthogonal to each normal with w = +1."""
    if uvs is not None:
        return compute_tangents(positions, normals, uvs, triangles)
    return np.concatenate([any_perpendicular(normals), np.ones((normals.shape[0], 1))], axis=1)
