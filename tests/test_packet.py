"""Packets of primary rays (kernels/packet.py) against ``wp.mesh_query_ray`` one ray at a time, and against a
brute-force NumPy ray cast (float64 Moller-Trumbore over every triangle, written here)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
import warp as wp

import foveawarp as fw
from foveawarp.kernels.gbuffer import gbuffer_kernel, gbuffer_rows_kernel
from foveawarp.kernels.packet import PACKET, packet_ray_kernel, single_ray_kernel
from foveawarp.scene import find_named_mesh


def _cast(mesh_id, eye, dirs_np, device, max_t=1.0e6):
    """(t, face, uv, normal) of every ray, from the packet kernel and from mesh_query_ray per ray."""
    n = len(dirs_np)
    dirs = wp.array(np.ascontiguousarray(dirs_np, dtype=np.float32), dtype=wp.vec3, device=device)
    res = {}
    for key, kernel, dim in (("packet", packet_ray_kernel, (n + PACKET - 1) // PACKET), ("single", single_ray_kernel, n)):
        out = [wp.full(n, -3.0, dtype=float, device=device), wp.full(n, -7, dtype=wp.int32, device=device),
               wp.zeros(n, dtype=wp.vec2, device=device), wp.zeros(n, dtype=wp.vec3, device=device)]
        wp.launch(kernel, dim, inputs=[mesh_id, wp.vec3(*[float(v) for v in eye]), dirs, max_t], outputs=out + [0],
                  device=device)
        res[key] = [a.numpy() for a in out]
    return res["packet"], res["single"]


def _assert_same_hits(p, s):
    """Every ray has the same distance, face, (u, v) and normal bits (the normal and (u, v) where it hits)."""
    np.testing.assert_array_equal(p[0].view(np.int32), s[0].view(np.int32))
    np.testing.assert_array_equal(p[1], s[1])
    hit = s[1] >= 0
    np.testing.assert_array_equal(p[2][hit].view(np.int32), s[2][hit].view(np.int32))
    np.testing.assert_array_equal(p[3][hit].view(np.int32), s[3][hit].view(np.int32))


def _scenes():
    names = ["cornell", "earth", "eyechart", "city"]
    if find_named_mesh("bunny") is not None:
        names.append("bunny")
    return names


@pytest.mark.parametrize("name", _scenes())
def test_packets_equal_single_rays_on_scene_views(name, device):
    """Primary rays of a 97 x 61 view (a partial last packet) at two times of the camera path, in raster
    order as the G-buffer traces them: the same hits bit for bit."""
    scene = fw.load_scene(name)
    ds = fw.scene.DeviceScene(scene, device)
    w, h = 97, 61
    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    for t in (0.0, 0.6):
        cam = scene.camera_at(t)
        dirs = cam.ray_dirs(xs.ravel(), ys.ravel(), w, h)
        p, s = _cast(ds.mesh.id, cam.eye, dirs, device)
        assert (s[1] >= 0).any() and (s[1] < 0).any()
        _assert_same_hits(p, s)


def _brute_force(tris, eye, dirs):
    """Nearest hit distance (inf on a miss) of each ray against every triangle, float64 Moller-Trumbore."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    e1, e2 = b - a, c - a
    out = np.full(len(dirs), np.inf)
    for i, d in enumerate(dirs):
        pv = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, pv)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = eye - a
        u = np.einsum("ij,ij->i", tv, pv) * inv
        qv = np.cross(tv, e1)
        v = (qv @ d) * inv
        t = np.einsum("ij,ij->i", e2, qv) * inv
        m = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0)
        if m.any():
            out[i] = t[m].min()
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), ntri=st.integers(1, 40), nray=st.integers(1, 29),
       zero_axis=st.sampled_from([None, 0, 1, 2]), odd=st.sampled_from([None, 1e-40, np.nan, np.inf]),
       shared=st.booleans())
def test_packets_equal_single_rays_on_random_soups(seed, ntri, nray, zero_axis, odd, shared):
    """Random triangle soups (some degenerate, some sharing an edge) and rays from one eye, some with a zero
    direction component, a denormal one (its reciprocal overflows) or a non-finite one (all traced by
    mesh_query_ray itself): the packets give mesh_query_ray's hits, and the distances of the finite rays agree with
    a float64 brute-force cast (tolerance 1e-4 relative; misses where it misses, but for rays within 1e-5 of an
    edge)."""
    rng = np.random.default_rng(seed)
    tris = rng.uniform(-1.0, 1.0, (ntri, 3, 3)).astype(np.float32)
    tris[:, :, 2] += 3.0
    if ntri > 2:
        tris[1] = tris[0][[0, 0, 1]]  # degenerate: two equal corners
    if shared and ntri > 3:
        tris[3, 0], tris[3, 1] = tris[2, 0], tris[2, 1]  # an edge shared by two triangles
    pts = tris.reshape(-1, 3)
    idx = np.arange(len(pts), dtype=np.int32)
    mesh = wp.Mesh(points=wp.array(pts, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(idx, dtype=wp.int32, device="cpu"))
    eye = np.array([0.0, 0.0, 0.0], np.float32)
    target = tris[rng.integers(0, ntri, nray)].mean(axis=1) + rng.normal(0, 0.3, (nray, 3)).astype(np.float32)
    dirs = (target - eye).astype(np.float32)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    if zero_axis is not None:
        dirs[::3, zero_axis] = 0.0
    if odd is not None:
        dirs[1::4, 2 if zero_axis is None else (zero_axis + 1) % 3] = odd
    p, s = _cast(mesh.id, eye, dirs, "cpu")
    _assert_same_hits(p, s)
    finite = np.isfinite(dirs).all(axis=1)
    p = [a[finite] for a in p]
    dirs = dirs[finite]
    ref = _brute_force(tris.astype(np.float64), eye.astype(np.float64), dirs.astype(np.float64))
    hit = p[1] >= 0
    agree = hit == np.isfinite(ref)
    if not agree.all():  # only grazing rays may disagree: recheck them with the triangles grown by 1e-5
        grown = tris.astype(np.float64)
        centre = grown.mean(axis=1, keepdims=True)
        grown = centre + (grown - centre) * (1 + 1e-5)
        ref_g = _brute_force(grown, eye.astype(np.float64), dirs.astype(np.float64)[~agree])
        shrunk = centre + (tris.astype(np.float64) - centre) * (1 - 1e-5)
        ref_s = _brute_force(shrunk, eye.astype(np.float64), dirs.astype(np.float64)[~agree])
        assert np.all(np.isfinite(ref_g) != np.isfinite(ref_s)), "a non-grazing ray disagrees"
    both = hit & np.isfinite(ref)
    np.testing.assert_allclose(p[0][both], ref[both], rtol=1e-4)
    assert np.all(p[0][~hit] == np.float32(1.0e6))


def _box(lo, hi):
    """The 12 triangles of an axis-aligned box."""
    c = np.array([[lo[0], lo[1], lo[2]], [hi[0], lo[1], lo[2]], [hi[0], hi[1], lo[2]], [lo[0], hi[1], lo[2]],
                  [lo[0], lo[1], hi[2]], [hi[0], lo[1], hi[2]], [hi[0], hi[1], hi[2]], [lo[0], hi[1], hi[2]]])
    f = [[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [3, 7, 6], [3, 6, 2], [0, 4, 7],
         [0, 7, 3], [1, 2, 6], [1, 6, 5]]
    return c[np.array(f)]


@pytest.mark.parametrize("seed", range(3))
def test_packets_equal_single_rays_on_overlapping_coplanar_boxes(seed):
    """Boxes on a floor, half of them with a second box whose faces lie in the same planes, seen from random
    cameras: coplanar faces hit an ulp apart, where the nearer hit kept depends on the order in which a ray's
    walk visits the two children of a node (the packets let each ray visit them in its own order). The same
    bits as mesh_query_ray on every ray."""
    rng = np.random.default_rng(seed)
    parts = [_box((-10.0, -1.0, -10.0), (10.0, 0.0, 10.0))]
    for _ in range(12):
        lo = np.round(rng.uniform(-6, 5, 3), 1)
        lo[1] = 0.0
        hi = lo + np.round(rng.uniform(0.5, 3, 3), 1)
        parts.append(_box(lo, hi))
        if rng.random() < 0.5:
            parts.append(_box(lo + [0.3, 0.0, 0.0], hi + [0.4, 0.0, 0.7]))
    tris = np.concatenate(parts).astype(np.float32)
    pts = tris.reshape(-1, 3)
    mesh = wp.Mesh(points=wp.array(pts, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(np.arange(len(pts), dtype=np.int32), dtype=wp.int32, device="cpu"))
    w, h = 97, 61
    sx, sy = np.meshgrid((np.arange(w) + 0.5) / w * 2 - 1, (np.arange(h) + 0.5) / h * 2 - 1)
    for _ in range(4):
        eye = np.array([rng.uniform(-9, 9), rng.uniform(1, 6), rng.uniform(-9, 9)], np.float32)
        fwd = np.array([rng.uniform(-3, 3), 0.5, rng.uniform(-3, 3)]) - eye
        fwd /= np.linalg.norm(fwd)
        right = np.cross([0.0, 1.0, 0.0], fwd)
        right /= np.linalg.norm(right)
        up = np.cross(fwd, right)
        dirs = fwd + 0.7 * sx.ravel()[:, None] * right - 0.45 * sy.ravel()[:, None] * up
        p, s = _cast(mesh.id, eye, dirs.astype(np.float32), "cpu")
        assert (s[1] >= 0).any()
        _assert_same_hits(p, s)


@pytest.mark.parametrize("leaf", [1, 4])
def test_packets_send_infinite_directions_to_mesh_query_ray(leaf):
    """A direction with an infinite component has a finite reciprocal (0). With boxes whose distance from the eye
    overflows, its slab distance is 0 * inf = NaN, where Warp's min and max (NaN ignored) and the packet's differ:
    such rays are traced by mesh_query_ray (here three triangles near the ends of the float range, the eye at
    -2.5e38)."""
    tris = np.array([[[2.95e38, 0.7, -0.8], [2.9e38, -0.4, -0.2], [2.96e38, -0.8, 0.5]],
                     [[1.8e38, 0.4, -0.1], [1.85e38, -0.8, 0.5], [1.86e38, 0.7, 0.0]],
                     [[-2.4e38, -0.5, -0.1], [-2.45e38, 0.3, -0.4], [-2.47e38, -0.1, 0.9]]], np.float32)
    pts = tris.reshape(-1, 3)
    mesh = wp.Mesh(points=wp.array(pts, dtype=wp.vec3, device="cpu"),
                   indices=wp.array(np.arange(9, dtype=np.int32), dtype=wp.int32, device="cpu"),
                   bvh_constructor="sah", bvh_leaf_size=leaf)
    rng = np.random.default_rng(2)
    dirs = np.stack([np.full(64, np.inf), rng.uniform(-0.5, 0.5, 64), rng.uniform(0.5, 1.5, 64)], 1)
    dirs[1::2, 0] = 1.0e30
    p, s = _cast(mesh.id, np.array([-2.5e38, 0.0, 0.0], np.float32), dirs.astype(np.float32), "cpu")
    assert (s[1] >= 0).any()
    _assert_same_hits(p, s)


@pytest.mark.parametrize("name,w,h", [("cornell", 67, 41), ("earth", 64, 48)])
def test_gbuffer_rows_kernel_equals_the_pixel_kernel(name, w, h):
    """The CPU G-buffer (rows of packets) and the one-ray-per-pixel kernel write the same entries bit for bit,
    with a moving camera (the reprojection) and, on the earth, moving geometry (the previous positions)."""
    from foveawarp.buffers import GBuffer
    from foveawarp.stages.gbuffer import GBufferStage

    scene = fw.load_scene(name)
    ds = fw.scene.DeviceScene(scene, "cpu")
    ds.set_time(0.2)
    ds.set_time(0.5)
    stage = GBufferStage(ds, w, h, "cpu")
    cam, prev = scene.camera_at(0.5), scene.camera_at(0.2)
    from foveawarp.frame_context import FrameContextBuilder

    ctx = FrameContextBuilder(w, h).build(cam, prev, (0.0, 0.0), 0, stage.max_t(cam))
    inputs = [ds.mesh.id, ds.indices, ds.points_prev, ds.vertex_normals, ds.face_smooth, ctx.struct]
    got = {}
    for key, kernel, dim in (("rows", gbuffer_rows_kernel, h), ("pixels", gbuffer_kernel, (h, w))):
        g = GBuffer(w, h, "cpu")
        outputs = [g.position, g.normal, g.depth, g.face, g.hit, g.reproj_uv, g.prev_dist, g.moved, 0]
        wp.launch(kernel, dim, inputs=inputs, outputs=outputs + [0], device="cpu")
        got[key] = [a.numpy() for a in outputs[:-1]]
    assert (got["pixels"][3] >= 0).any() and (got["pixels"][3] < 0).any()
    for a, b in zip(got["rows"], got["pixels"]):
        np.testing.assert_array_equal(a.view(np.uint8), b.view(np.uint8))
