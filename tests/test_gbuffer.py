"""G-buffer kernel against an independent trimesh ray cast (trimesh's pure-NumPy ray/triangle intersector)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
import warp as wp

import foveawarp as fw
from foveawarp.kernels.saliency import face_lab_at, sobel_lab_by_face, sobel_vec3
from foveawarp.scene import find_named_mesh

W, H = 64, 48
# agreement tolerances: depth relative 1e-4 (float32 BVH traversal vs float64 trimesh), normals 1e-4
DEPTH_RTOL = 1e-4
NORMAL_ATOL = 1e-4


def _scenes():
    names = ["cornell", "earth", "eyechart"]
    if find_named_mesh("bunny") is not None:
        names.append("bunny")
    return names


class _AllCandidates:
    """Stands in for trimesh's r-tree (rtree is not a dependency): every triangle is a candidate, so trimesh's
    ray/triangle math runs brute force."""

    def __init__(self, tris):
        self.n = len(tris)
        flat = tris.reshape(-1, 3)
        self.bounds = np.concatenate([flat.min(0) - 1.0, flat.max(0) + 1.0])

    def intersection(self, bounds):
        return np.arange(self.n)


def _trimesh_cast(scene, cam, xs, ys, chunk=8):
    from trimesh.ray.ray_triangle import ray_triangle_id

    tris = scene.vertices[scene.faces].astype(np.float64)
    dirs = cam.ray_dirs(xs + 0.5, ys + 0.5, W, H)
    origins = np.broadcast_to(np.asarray(cam.eye, float), dirs.shape).copy()
    depth = np.full(len(xs), np.inf)
    tri = np.full(len(xs), -1)
    tree = _AllCandidates(tris)
    for s in range(0, len(xs), chunk):
        o, d = origins[s:s + chunk], dirs[s:s + chunk]
        itri, iray, loc = ray_triangle_id(tris, o, d, tree=tree, multiple_hits=True)
        for k in range(len(o)):
            sel = iray == k
            if sel.any():
                dist = np.linalg.norm(loc[sel] - o[k], axis=1)
                j = np.argmin(dist)
                depth[s + k] = dist[j]
                tri[s + k] = itri[sel][j]
    e1 = tris[:, 1] - tris[:, 0]
    e2 = tris[:, 2] - tris[:, 0]
    fn = np.cross(e1, e2)
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    return depth, tri, fn, dirs


@pytest.mark.parametrize("name", _scenes())
def test_gbuffer_matches_trimesh(name, device, rng):
    scene = fw.load_scene(name)
    loop = fw.FrameLoop(scene, W, H, device=device)
    cam = scene.camera
    loop.render_reference(cam)
    g = loop.gbuffer.numpy()
    n = 150
    xs = rng.integers(0, W, n)
    ys = rng.integers(0, H, n)
    depth, tri, fn, dirs = _trimesh_cast(scene, cam, xs, ys)
    hit = g["hit"][ys, xs].astype(bool)
    # hit/miss agreement (grazing edge rays may disagree: allow 2 of 150)
    assert np.sum(hit != np.isfinite(depth)) <= 2
    both = hit & np.isfinite(depth)
    d_k = g["depth"][ys, xs][both]
    rel = np.abs(d_k - depth[both]) / depth[both]
    # edge pixels may hit a neighbouring triangle at a different depth; nearly all must agree
    assert np.mean(rel < DEPTH_RTOL) >= 0.98, np.sort(rel)[-5:]
    # world position = eye + depth * dir
    pos = g["position"][ys, xs][both]
    np.testing.assert_allclose(pos, np.asarray(cam.eye) + dirs[both] * g["depth"][ys, xs][both][:, None],
                               rtol=1e-4, atol=1e-4 * scene.extent)
    nk = g["normal"][ys, xs][both]
    np.testing.assert_allclose(np.linalg.norm(nk, axis=1), 1.0, atol=1e-5)
    smooth_px = scene.face_smooth[np.maximum(g["face"][ys, xs][both], 0)].astype(bool)
    # flat shading normals face the viewer (interpolated ones may tilt away at silhouettes)
    assert np.all(np.sum(nk[~smooth_px] * dirs[both][~smooth_px], axis=1) <= 1e-6)
    same_tri = g["face"][ys, xs][both] == tri[both]
    geo = fn[tri[both]] * -np.sign(np.sum(fn[tri[both]] * dirs[both], axis=1))[:, None]
    smooth = scene.face_smooth[tri[both]].astype(bool)
    flat = same_tri & ~smooth
    if flat.any():
        np.testing.assert_allclose(nk[flat], geo[flat], atol=NORMAL_ATOL)
    if (same_tri & smooth).any():
        assert np.all(np.sum(nk[same_tri & smooth] * geo[same_tri & smooth], axis=1) > 0.0)
    # albedo follows the face
    np.testing.assert_allclose(g["albedo"][ys, xs][both][same_tri], scene.face_albedo[tri[both]][same_tri])
    # misses: background values, never NaN
    for k, v in g.items():
        assert np.all(np.isfinite(v)), k
    miss = ~g["hit"].astype(bool)
    assert np.all(g["face"][miss] == -1) and np.all(g["normal"][miss] == 0)


def test_static_camera_reprojects_to_own_pixel(device):
    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, W, H, device=device)
    loop.render_reference(scene.camera)
    loop.render_reference(scene.camera)
    g = loop.gbuffer.numpy()
    hit = g["hit"].astype(bool)
    ys, xs = np.nonzero(hit)
    np.testing.assert_allclose(g["reproj_uv"][hit], np.stack([xs + 0.5, ys + 0.5], 1), atol=2e-3)
    np.testing.assert_allclose(g["velocity"][hit], 0.0, atol=2e-3)


def test_moving_camera_reprojection_matches_numpy_projection(device):
    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, W, H, device=device)
    c0 = scene.camera_at(0.0)
    c1 = scene.camera_at(0.4)
    loop.render_reference(c0)
    loop.render_reference(c1)
    g = loop.gbuffer.numpy()
    hit = g["hit"].astype(bool)
    expect = c0.project(g["position"][hit].astype(np.float64), W, H)
    np.testing.assert_allclose(g["reproj_uv"][hit], expect[:, :2], atol=5e-3)
    ys, xs = np.nonzero(hit)
    np.testing.assert_allclose(g["velocity"][hit], np.stack([xs + 0.5, ys + 0.5], 1) - expect[:, :2], atol=5e-3)


def test_object_motion_velocity(device):
    scene = fw.load_scene("cornell", motion=True)
    loop = fw.FrameLoop(scene, W, H, device=device)
    cam = scene.camera
    loop.render_reference(cam, time=0.0)
    loop.render_reference(cam, time=0.25)
    g = loop.gbuffer.numpy()
    obj = next(o for o in scene.objects if o.name == "short_block")
    a, b = obj.vertex_range
    faces_of_block = np.nonzero(np.all((scene.faces >= a) & (scene.faces < b), axis=1))[0]
    on_block = np.isin(g["face"], faces_of_block)
    assert on_block.sum() > 10
    # the block moved by dx in world space between t=0 and t=0.25: its pixels have non-zero velocity
    dx = obj.motion(0.25)[0, 3] - obj.motion(0.0)[0, 3]
    prev_pos = g["position"][on_block] - np.array([dx, 0, 0])
    expect = cam.project(prev_pos.astype(np.float64), W, H)
    np.testing.assert_allclose(g["reproj_uv"][on_block], expect[:, :2], atol=5e-3)
    assert np.abs(g["velocity"][on_block][:, 0]).min() > 0.5
    static = g["hit"].astype(bool) & ~on_block
    np.testing.assert_allclose(g["velocity"][static], 0.0, atol=2e-3)
    # moved: 1 exactly on the moving block (its surface points changed place), 0 on static surfaces and misses
    assert g["moved"][on_block].all() and not g["moved"][~on_block].any()
    # prev_dist: the block's points at their previous place, seen from the (static) eye
    np.testing.assert_allclose(g["prev_dist"][on_block], np.linalg.norm(prev_pos - cam.eye, axis=1), rtol=1e-4)
    np.testing.assert_allclose(g["prev_dist"][static], g["depth"][static], rtol=1e-4)


# -- the sampling map's CIE-Lab albedo, read by face from the scene's table ------------------------------------


def _lab_reference(albedo):
    """Independent CIE-Lab of linear RGB (skimage's rgb2lab of the sRGB-encoded values decodes them again)."""
    from skimage.color import rgb2lab

    a = np.asarray(albedo, np.float64)
    srgb = np.where(a <= 0.0031308, 12.92 * a, 1.055 * np.power(np.maximum(a, 0.0031308), 1.0 / 2.4) - 0.055)
    return rgb2lab(srgb)


@wp.kernel(enable_backward=False)
def _lab_by_face_kernel(face: wp.array2d(dtype=wp.int32), table: wp.array(dtype=wp.vec3),
                        lab: wp.array2d(dtype=wp.vec3), out_lab: wp.array2d(dtype=wp.vec3),
                        out_grad: wp.array2d(dtype=float), out_grad_ref: wp.array2d(dtype=float)):
    y, x = wp.tid()
    out_lab[y, x] = face_lab_at(face, table, x, y)
    out_grad[y, x] = sobel_lab_by_face(face, table, x, y)
    out_grad_ref[y, x] = sobel_vec3(lab, x, y)


@pytest.mark.parametrize("name", ["cornell", "eyechart"])
def test_lab_by_face_equals_the_conversion(name, device):
    """The scene's per-face Lab table read through the G-buffer's face index gives bit for bit the Lab prepass
    of the G-buffer's albedo (misses included) and the same Sobel gradient, and is within 2e-3 Lab units of
    skimage; the table holds one entry per face, then black."""
    from foveawarp.kernels.saliency import lab_kernel

    scene = fw.load_scene(name)
    loop = fw.FrameLoop(scene, W, H, device=device)
    cam = scene.camera
    loop.gbuffer_stage.run(loop.gbuffer, cam, cam)
    g = loop.gbuffer
    assert g.hit.numpy().sum() > 0
    prepass = wp.zeros((H, W), dtype=wp.vec3, device=loop.device)
    wp.launch(lab_kernel, dim=(H, W), inputs=[g.albedo], outputs=[prepass, 0], device=loop.device)
    got = wp.zeros((H, W), dtype=wp.vec3, device=loop.device)
    grad = wp.zeros((H, W), dtype=float, device=loop.device)
    grad_ref = wp.zeros((H, W), dtype=float, device=loop.device)
    wp.launch(_lab_by_face_kernel, dim=(H, W), inputs=[g.face, loop.dscene.face_lab, prepass],
              outputs=[got, grad, grad_ref], device=loop.device)
    assert np.array_equal(got.numpy(), prepass.numpy())
    assert np.array_equal(grad.numpy(), grad_ref.numpy())
    assert grad.numpy().max() > 0.0  # edges exist, so the comparison means something
    assert np.abs(got.numpy() - _lab_reference(g.albedo.numpy())).max() < 2e-3
    table = loop.dscene.face_lab.numpy()
    assert table.shape == (scene.num_triangles + 1, 3)
    assert np.abs(table[:-1] - _lab_reference(scene.face_albedo[None])[0]).max() < 2e-3
    assert np.abs(table[-1]).max() < 1e-4


def test_frame_loop_sampling_map_equals_the_prepass_path(device):
    """A foveated frame's sampling map reads the Lab albedo through the face table: launching the stage again on
    the same G-buffer and history through the Lab prepass gives the same sample map, cache hits and indices."""
    w, h = 192, 108  # large enough for a periphery
    loop = fw.FrameLoop("eyechart", w, h, device=device, policy="foveated")
    for i in range(3):
        t = 0.05 * i
        loop.render(loop.scene.camera_at(t), gaze_px=(w * 0.2 + 5 * i, h * 0.5), time=t)
    s = loop.sampling
    # the last frame's inputs: the history the frame read is the one before its resolve, so run the stage
    # right after a render on the current G-buffer with the current history, both ways
    hist = (loop.temporal.depth, loop.temporal.filled)
    s.launch(loop.gbuffer, depth_prev=hist[0], valid_prev=hist[1], face_lab=loop.dscene.face_lab)
    by_face = [a.numpy().copy() for a in (s.sample_map, s.cache_hit, s.prev_index)]
    s.launch(loop.gbuffer, depth_prev=hist[0], valid_prev=hist[1])
    prepass = [a.numpy() for a in (s.sample_map, s.cache_hit, s.prev_index)]
    for a, b in zip(by_face, prepass):
        assert np.array_equal(a, b)
    assert 0 < by_face[0].sum() < by_face[0].size


def test_sampling_launch_face_lab_is_checked(device):
    loop = fw.FrameLoop("cornell", W, H, device=device, policy="foveated")
    loop.render()
    for bad in (wp.zeros((3, 3), dtype=wp.vec3, device=loop.device), wp.zeros(4, dtype=float, device=loop.device),
                np.zeros((4, 3))):
        with pytest.raises(ValueError, match="face_lab must be"):
            loop.sampling.launch(loop.gbuffer, face_lab=bad)


# -- the attributes the G-buffer pass does not store: velocity from reproj_uv, albedo from face ---------------------


def _velocity_reference(uv, cell=1, image_size=None):
    """GBuffer.velocity in NumPy: the centre of the pixel each entry's ray went through (a cell's middle pixel,
    clamped, with cell > 1) minus reproj_uv, in float32; 0 where reproj_uv is (-1e4, -1e4) (no previous position)."""
    h, w = uv.shape[:2]
    iw, ih = image_size if image_size is not None else (w * cell, h * cell)
    px = (np.minimum(np.arange(w) * cell + cell // 2, iw - 1) + 0.5).astype(np.float32)
    py = (np.minimum(np.arange(h) * cell + cell // 2, ih - 1) + 0.5).astype(np.float32)
    centre = np.stack(np.broadcast_arrays(px[None, :], py[:, None]), -1)
    none = (uv == np.float32(-1e4)).all(-1)
    return np.where(none[..., None], np.float32(0.0), centre - uv)


@pytest.mark.parametrize("scene", ["cornell", "earth"])
def test_derived_velocity_and_albedo_equal_what_the_pass_stored(device, scene):
    """The G-buffer pass stores neither the velocity nor the albedo; reading them gives what it stored before
    (pixel centre minus the previous position, the face's albedo; bit for bit against NumPy), in motion (the
    earth turns), with misses (velocity 0, albedo 0)."""
    sc = fw.load_scene(scene)
    loop = fw.FrameLoop(sc, W, H, device=device, policy="foveated")
    for i in range(3):
        f = loop.render(sc.camera_at(0.2 * i), time=0.2 * i)
    g = f.gbuffer.numpy()
    uv, face, hit = g["reproj_uv"], g["face"], g["hit"].astype(bool)
    np.testing.assert_array_equal(g["velocity"], _velocity_reference(uv))
    albedo = np.where(face[..., None] >= 0, sc.face_albedo.astype(np.float32)[np.maximum(face, 0)], np.float32(0))
    np.testing.assert_array_equal(g["albedo"], albedo)
    assert (~hit).any() and np.abs(g["velocity"][hit]).max() > 0.0
    assert (g["velocity"][~hit] == 0).all() and (g["albedo"][~hit] == 0).all()


@settings(max_examples=30, deadline=None)
@given(data=st.data(), cell=st.integers(1, 6), w=st.integers(1, 9), h=st.integers(1, 7))
def test_derived_velocity_against_numpy(data, cell, w, h):
    """``GBuffer.velocity`` of hand-set reprojections: any finite values (far off screen, huge, the exact
    no-reprojection marker), full resolution and coarse cells with partial edge cells; finite everywhere."""
    from foveawarp.buffers import GBuffer

    vals = st.one_of(st.floats(-1e30, 1e30, allow_subnormal=False).map(np.float32),
                     st.sampled_from([-1e4, 0.0, 0.5, -5e3, 1e4]))
    uv = np.array(data.draw(st.lists(vals, min_size=h * w * 2, max_size=h * w * 2)), np.float32).reshape(h, w, 2)
    uv[data.draw(st.integers(0, h - 1)), data.draw(st.integers(0, w - 1))] = -1e4  # one entry without
    iw = data.draw(st.integers(max(1, (w - 1) * cell + 1), w * cell))  # partial cells at the right / bottom
    ih = data.draw(st.integers(max(1, (h - 1) * cell + 1), h * cell))
    g = GBuffer(w, h, "cpu", cell=cell, image_size=(iw, ih))
    g.reproj_uv.assign(uv)
    got = g.velocity.numpy()
    np.testing.assert_array_equal(got, _velocity_reference(uv, cell, (iw, ih)))
    assert np.isfinite(got).all()


def test_gbuffer_albedo_binding_and_its_errors():
    """Unbound, ``albedo`` is a plain array the caller fills (hand-made G-buffers); bound, it is the table looked
    up by face on every read; a table that is not a 1-D vec3 array on the G-buffer's device is refused by name."""
    from foveawarp.buffers import GBuffer

    g = GBuffer(3, 2, "cpu")
    g.albedo.fill_(wp.vec3(0.25, 0.5, 0.75))
    assert np.allclose(g.albedo.numpy(), [0.25, 0.5, 0.75])
    table = wp.array(np.array([[0.1, 0.2, 0.3], [0.9, 0.8, 0.7]], np.float32), dtype=wp.vec3, device="cpu")
    g.bind_albedo(table)
    g.face.assign(np.array([[0, 1, -1], [1, 1, 0]], np.int32))
    np.testing.assert_array_equal(g.albedo.numpy(), np.array([[[0.1, 0.2, 0.3], [0.9, 0.8, 0.7], [0, 0, 0]],
                                                              [[0.9, 0.8, 0.7], [0.9, 0.8, 0.7], [0.1, 0.2, 0.3]]],
                                                             np.float32))
    for bad in (np.zeros((2, 3), np.float32), wp.zeros((2, 2), dtype=wp.vec3, device="cpu"),
                wp.zeros(2, dtype=wp.vec2, device="cpu")):
        with pytest.raises(ValueError, match="face_albedo must be a 1-D wp.array of vec3"):
            g.bind_albedo(bad)
    with pytest.raises(ValueError, match="cell must be"):
        GBuffer(3, 2, "cpu", cell=0)
    for size, name in (((0, 5), r"image_size\[0\]"), ((4, 1e9), r"image_size\[1\]"), (7, "image_size must be")):
        with pytest.raises(ValueError, match=name):
            GBuffer(3, 2, "cpu", image_size=size)
