"""Vertex attributes every reader completes the same way: normalization, area-weighted vertex normals and
tangents from UVs (glTF's convention: v grows downwards, the bitangent points to the image's top)."""

from __future__ import annotations

import numpy as np

__all__ = ["normalize_rows", "any_perpendicular", "compute_normals", "compute_tangents", "complete_tangents",
           "normal_matrix", "transform_mesh", "face_normals", "split_flat"]


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


def normal_matrix(m3: np.ndarray) -> np.ndarray:
    """The matrix that maps normals under the linear map ``m3``: its inverse-transpose, or, for a singular
    ``m3``, its cofactor matrix (det * inverse-transpose, defined for every matrix)."""
    if abs(float(np.linalg.det(m3))) > 1e-300:
        return np.linalg.inv(m3).T
    return np.stack([np.cross(m3[:, 1], m3[:, 2]), np.cross(m3[:, 2], m3[:, 0]),
                     np.cross(m3[:, 0], m3[:, 1])], axis=1)


def transform_mesh(positions: np.ndarray, normals: np.ndarray, triangles: np.ndarray,
                   matrix: np.ndarray) -> tuple:
    """(positions, normals, triangles) placed by the 4x4 ``matrix``: points by the matrix, normals by its
    inverse-transpose (renormalized); a negative determinant reverses the triangles' winding so that the
    triangles' front (counter-clockwise) side stays the side the normals face."""
    m = np.asarray(matrix, dtype=np.float64)
    m3 = m[:3, :3]
    pos = positions @ m3.T + m[:3, 3]
    nrm = normalize_rows(normals @ normal_matrix(m3).T, (0.0, 0.0, 1.0))
    tri = triangles[:, [0, 2, 1]] if float(np.linalg.det(m3)) < 0 else triangles
    return pos, nrm, tri


def face_normals(positions: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(F, 3) unit normals of the counter-clockwise triangles; (0, 0, 1) for a degenerate one."""
    p = positions[triangles]
    return normalize_rows(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), (0.0, 0.0, 1.0))


def split_flat(triangles: np.ndarray, *attributes) -> tuple:
    """Three vertices of its own per triangle: (new triangles, each attribute gathered per corner (None stays
    None)). The positions go among ``attributes``; face normals are then :func:`face_normals` of the result."""
    flat = triangles.reshape(-1)
    out = tuple(None if a is None else a[flat] for a in attributes)
    return (np.arange(flat.shape[0], dtype=np.int64).reshape(-1, 3),) + out
