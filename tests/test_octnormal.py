"""Octahedral 32-bit normals (kernels/octnormal.py, the temporal history's normals) against a NumPy reference
written from the mapping's definition: the packed words, the decoded directions, and the precision bound."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
import warp as wp

from foveawarp.kernels.octnormal import oct_decode_kernel, oct_encode_kernel


def np_oct_encode(n):
    """(N, 3) float -> (N,) uint32: project on |x|+|y|+|z| = 1, fold the lower half over the diagonals, round
    u, v to int16 steps of 1/32767, u in the low half-word."""
    n = np.asarray(n, np.float64).reshape(-1, 3)
    s = np.abs(n).sum(1)
    p = n / np.maximum(s, 1e-30)[:, None]
    u, v = p[:, 0].copy(), p[:, 1].copy()
    low = n[:, 2] < 0
    su = np.where(u < 0, -1.0, 1.0)
    sv = np.where(v < 0, -1.0, 1.0)
    fu, fv = (1 - np.abs(v)) * su, (1 - np.abs(u)) * sv
    u[low], v[low] = fu[low], fv[low]
    qu = np.round(np.clip(u, -1, 1) * 32767).astype(np.int64)
    qv = np.round(np.clip(v, -1, 1) * 32767).astype(np.int64)
    return ((qu & 0xFFFF) | ((qv & 0xFFFF) << 16)).astype(np.uint32)


def np_oct_decode(p):
    p = np.asarray(p, np.uint32).astype(np.int64)
    qu, qv = p & 0xFFFF, (p >> 16) & 0xFFFF
    qu = np.where(qu >= 0x8000, qu - 0x10000, qu)
    qv = np.where(qv >= 0x8000, qv - 0x10000, qv)
    u, v = qu / 32767.0, qv / 32767.0
    w = 1 - np.abs(u) - np.abs(v)
    low = w < 0
    fu = (1 - np.abs(v)) * np.where(u < 0, -1.0, 1.0)
    fv = (1 - np.abs(u)) * np.where(v < 0, -1.0, 1.0)
    u, v = np.where(low, fu, u), np.where(low, fv, v)
    d = np.stack([u, v, w], 1)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _angle(a, b):
    """Angle between rows of a and b (radians; atan2 of the cross and dot products, exact near 0)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), (a * b).sum(1))


def _kernel_roundtrip(n, device):
    a = wp.array(np.asarray(n, np.float32).reshape(-1, 3), dtype=wp.vec3, device=device)
    p = wp.empty(a.shape[0], dtype=wp.uint32, device=device)
    wp.launch(oct_encode_kernel, dim=a.shape[0], inputs=[a], outputs=[p], device=device)
    d = wp.empty(a.shape[0], dtype=wp.vec3, device=device)
    wp.launch(oct_decode_kernel, dim=a.shape[0], inputs=[p], outputs=[d], device=device)
    return p.numpy(), d.numpy()


def _special_vectors():
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    diag = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], np.float64)
    # on the fold's edges: z = 0 with mixed signs, and the equator's diagonals
    edges = np.array([[1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0], [1, 0, -1e-9], [0, -1, -1e-9]], np.float64)
    return np.concatenate([axes, diag, edges])


def test_matches_numpy_reference(device):
    rng = np.random.default_rng(11)
    n = rng.normal(size=(4000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n = np.concatenate([n, _special_vectors() / np.linalg.norm(_special_vectors(), axis=1, keepdims=True)])
    n32 = n.astype(np.float32)
    words, dec = _kernel_roundtrip(n32, device)
    ref_words = np_oct_encode(n32)
    # float32 kernel arithmetic against float64: a word may differ by one rounding step where u or v lies on a
    # half step; every other word is equal
    diff = words != ref_words
    assert diff.mean() < 0.01, diff.mean()
    for a, b in zip(words[diff], ref_words[diff]):
        du = abs(int(np.int16(a & 0xFFFF)) - int(np.int16(b & 0xFFFF)))
        dv = abs(int(np.int16(a >> 16)) - int(np.int16(b >> 16)))
        assert max(du, dv) <= 1 or (np.int16(a & 0xFFFF) in (-32767, 32767)), (a, b)
    # decoding: the kernel's decode of its words equals NumPy's decode of the same words (float32 rounding)
    np.testing.assert_allclose(dec, np_oct_decode(words), atol=2e-7)
    # the precision the temporal test relies on: within 1e-4 rad of the input, unit length
    ang = _angle(dec, n)
    assert ang.max() < 1e-4, ang.max()
    np.testing.assert_allclose(np.linalg.norm(dec, axis=1), 1.0, atol=1e-6)


def test_axes_and_signs_exact(device):
    v = np.concatenate([np.eye(3), -np.eye(3)]).astype(np.float32)
    _, dec = _kernel_roundtrip(v, device)
    np.testing.assert_array_equal(dec, v)


def test_zero_and_tiny_vectors_decode_to_unit_vectors(device):
    v = np.array([[0, 0, 0], [1e-30, 0, 0], [0, -1e-35, 0], [0, 0, -1e-38], [-0.0, -0.0, -0.0]], np.float32)
    _, dec = _kernel_roundtrip(v, device)
    assert np.isfinite(dec).all()
    np.testing.assert_allclose(np.linalg.norm(dec, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(dec[0], [0, 0, 1], atol=0)  # the zero vector: +z
    np.testing.assert_allclose(dec[1], [1, 0, 0], atol=1e-6)  # direction kept down to tiny lengths
    np.testing.assert_allclose(dec[3], [0, 0, -1], atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-1e6, 1e6, allow_nan=False, allow_subnormal=True)] * 3),
                min_size=1, max_size=16))
def test_any_finite_vector_roundtrips_to_its_direction(vecs):
    v = np.array(vecs, np.float32)
    _, dec = _kernel_roundtrip(v, "cpu")
    assert np.isfinite(dec).all()
    np.testing.assert_allclose(np.linalg.norm(dec, axis=1), 1.0, atol=1e-6)
    v64 = v.astype(np.float64)
    ln = np.linalg.norm(v64, axis=1)
    ok = ln > 1e-30
    if ok.any():
        ang = _angle(dec[ok], v64[ok])
        assert ang.max() < 1e-4, ang.max()
