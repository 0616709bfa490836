"""G-buffer kernel against an independent trimesh ray cast (trimesh's pure-NumPy ray/triangle intersector)."""

import numpy as np
import pytest
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
