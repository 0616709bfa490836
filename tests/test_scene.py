"""Scene loading (OBJ / PLY / GLB written to a temp dir), built-in scenes, and bad inputs."""

import numpy as np
import pytest
import trimesh
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

import foveawarp as fw


@pytest.mark.parametrize("ext", ["obj", "ply", "glb", "stl"])
def test_load_mesh_files(tmp_path, ext):
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    if ext in ("ply", "glb"):
        m.visual.face_colors = np.tile([200, 30, 30, 255], (len(m.faces), 1)).astype(np.uint8)
    p = tmp_path / f"ball.{ext}"
    m.export(p)
    s = fw.load_scene(str(p))
    ground = 0 if ext == "glb" else 2  # a mesh goes on a ground quad; a glTF file is a scene of its own
    assert s.num_triangles == len(m.faces) + ground
    if ground:
        assert abs(s.vertices[2:, 1].min() - 0.0) < 1e-5 or s.vertices[:, 1].min() >= -1e-5  # sits on the ground
    else:
        np.testing.assert_allclose(s.bounds[0], m.bounds[0], atol=1e-5)  # the file's own placement
    if ext in ("ply", "glb"):
        # face colours become albedo
        np.testing.assert_allclose(s.face_albedo[ground:], np.tile(np.array([200, 30, 30]) / 255.0,
                                                                   (len(m.faces), 1)), atol=1e-3)
    loop = fw.FrameLoop(s, 32, 24, device="cpu")
    f = loop.render_reference()
    assert f.gbuffer.hit.numpy().any()


def test_builtin_scenes_deterministic_and_sized():
    a = fw.load_scene("cornell")
    b = fw.load_scene("cornell")
    np.testing.assert_array_equal(a.vertices, b.vertices)
    e = fw.load_scene("earth")
    assert e.num_triangles == 960
    ey = fw.load_scene("eyechart")
    assert ey.num_triangles > 1000
    for s in (a, e, ey):
        assert s.lights and s.camera is not None and s.camera_path is not None


def test_city_has_a_million_triangles():
    c = fw.load_scene("city")
    assert c.num_triangles >= 1_000_000
    c2 = fw.load_scene("city")
    np.testing.assert_array_equal(c.faces[:1000], c2.faces[:1000])


def test_missing_file():
    with pytest.raises(ValueError, match="neither a built-in name"):
        fw.load_scene("no/such/file.obj")


def test_non_mesh_file(tmp_path):
    p = tmp_path / "notes.obj"
    p.write_text("this is not a mesh\njust words\n")
    with pytest.raises(ValueError, match="no triangle mesh|could not be read"):
        fw.load_scene(str(p))
    q = tmp_path / "data.bin"
    q.write_bytes(b"\x00\x01\x02garbage")
    with pytest.raises(ValueError, match=r"data\.bin"):
        fw.load_scene(str(q))


def test_points_only_file(tmp_path):
    p = tmp_path / "pts.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(ValueError, match="no triangle mesh|could not be read"):
        fw.load_scene(str(p))


def test_bad_scene_arrays():
    with pytest.raises(ValueError, match="faces"):
        fw.Scene(vertices=np.zeros((3, 3)), faces=np.zeros((0, 3), int), face_albedo=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="faces"):
        fw.Scene(vertices=np.zeros((4, 3)), faces=np.zeros((2, 4), int), face_albedo=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="vertices"):
        fw.Scene(vertices=np.full((3, 3), np.nan), faces=[[0, 1, 2]], face_albedo=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="indices"):
        fw.Scene(vertices=np.zeros((3, 3)), faces=[[0, 1, 5]], face_albedo=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="face_albedo"):
        fw.Scene(vertices=np.eye(3), faces=[[0, 1, 2]], face_albedo=(2.0, 0.5, 0.5))


@pytest.mark.parametrize("w,h", [(0, 10), (10, 0), (-3, 5), (10.5, 5)])
def test_zero_size_image(w, h):
    with pytest.raises(ValueError, match="width|height"):
        fw.FrameLoop("cornell", w, h, device="cpu")


def test_bad_device():
    with pytest.raises(ValueError, match="device"):
        fw.FrameLoop("cornell", 8, 8, device="tpu:7")


def test_bad_config_fields():
    with pytest.raises(ValueError, match="FoveationConfig.block"):
        fw.FoveationConfig(block=0)
    with pytest.raises(ValueError, match="ReorderConfig.strategy"):
        fw.ReorderConfig(strategy="sorted")
    with pytest.raises(ValueError, match="ShadingConfig.exposure"):
        fw.ShadingConfig(exposure=float("nan"))
    with pytest.raises(ValueError, match="IndirectConfig.rsm_size"):
        fw.IndirectConfig(rsm_size=100)
    with pytest.raises(ValueError, match="DofConfig.focus_depth_m"):
        fw.DofConfig(focal_length_m=0.05, focus_depth_m=0.05)
    with pytest.raises(ValueError, match="config"):
        fw.FrameLoop("cornell", 8, 8, config={"block": 4}, device="cpu")
    cfg = fw.Config().with_(foveation={"block": 8})
    assert cfg.foveation.block == 8 and cfg.foveation.effective_min_probability >= 1 / 64


# -- rigid motion on the device (DeviceScene.set_time, kernels/motion.py) ----------------------------------------

def _f32_ulps(a, b):
    """Per-element distance in float32 units in the last place (a, b float32 arrays of one shape)."""
    ia = np.asarray(a, np.float32).view(np.int32).astype(np.int64)
    ib = np.asarray(b, np.float32).view(np.int32).astype(np.int64)
    ia = np.where(ia < 0, np.int64(-(2 ** 31)) - ia, ia)  # sign-magnitude to a monotonic integer line
    ib = np.where(ib < 0, np.int64(-(2 ** 31)) - ib, ib)
    return np.abs(ia - ib)


def _motion_tolerance(scene, t, rest, translate):
    """Per-coordinate bound on |device - host| for vertices (``translate``) or normals at time t: one float32
    ulp of the host's value, or, where a coordinate cancels to near zero, 1e-14 of its terms' magnitude (both
    sides sum the same float64 products, in orders that can differ by an ulp of float64 before the float32
    rounding). Static vertices: 0 (not moved)."""
    tol = np.zeros(rest.shape, np.float64)
    for o in scene.objects:
        if o.motion is None:
            continue
        m = o.transform_at(t)
        a, b = o.vertex_range
        terms = np.abs(rest[a:b].astype(np.float64)) @ np.abs(m[:3, :3]).T
        if translate:
            terms = terms + np.abs(m[:3, 3])
        tol[a:b] = np.maximum(1e-14 * terms, 0.0)
    return tol


def _check_device_motion(scene, times, device="cpu"):
    """DeviceScene.set_time against the host's Scene.vertices_at / normals_at (NumPy float64, rounded): every
    position and normal within one float32 ulp or the cancellation bound of ``_motion_tolerance``; previous
    positions = the positions of the time before. Returns the fraction of coordinates equal to the host's."""
    ds = fw.DeviceScene(scene, device=device)
    prev = None
    exact = total = 0
    for t in times:
        ds.set_time(t)
        p = ds.points.numpy().copy()  # on the CPU device numpy() is a view of the live array
        want = scene.vertices_at(t)
        ok = (_f32_ulps(p, want) <= 1) | (np.abs(p.astype(np.float64) - want) <= _motion_tolerance(
            scene, t, scene.vertices, True))
        assert ok.all(), (t, np.argwhere(~ok)[:5])
        exact += int((p == want).sum())
        total += p.size
        if scene.vertex_normals is not None:
            n, wn = ds.vertex_normals.numpy(), scene.normals_at(t)
            ok = (_f32_ulps(n, wn) <= 1) | (np.abs(n.astype(np.float64) - wn) <= _motion_tolerance(
                scene, t, scene.vertex_normals, False))
            assert ok.all(), t
        np.testing.assert_array_equal(ds.points_prev.numpy(), p if prev is None else prev)
        prev = p
    return exact / total


def test_device_motion_near_zero_coordinates():
    """Vertices that a rotation sends onto an axis (a coordinate that cancels to ~0): host and device sum the same
    float64 products in their own orders, so they may differ there by far more float32 ulps than elsewhere, but
    by no more than 1e-14 of the terms' size."""
    from foveawarp.scene import SceneObject

    c, s_ = 0.8, 0.6  # a rotation that sends (3k, 4k, z) onto the y axis: x' = 0.8 * 3k - 0.6 * 4k = 0
    m = np.array([[c, -s_, 0, 0], [s_, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    k = np.arange(1, 61, dtype=np.float64)
    v = np.stack([3 * k, 4 * k, k], axis=1).astype(np.float32)
    scene = fw.Scene(v, np.arange(60, dtype=np.int32).reshape(20, 3), (0.5, 0.5, 0.5),
                     objects=[SceneObject("o", (0, 60), lambda t: m if t else np.eye(4))])
    _check_device_motion(scene, [0.0, 1.0])
    assert np.abs(scene.vertices_at(1.0)[:, 0]).max() < 1e-12  # the case is the one named: x' ~ 1e-14


@pytest.mark.parametrize("name, kw", [("earth", {}), ("cornell", {"motion": True})])
def test_device_motion_matches_host(name, kw, device):
    """earth spins (rotation, smooth normals), cornell's short block slides (translation); on every test device
    (CUDA's float64 arithmetic too)."""
    scene = fw.load_scene(name, **kw)
    assert scene.is_animated
    frac = _check_device_motion(scene, [0.0, 0.25, 0.25, 1.7, -3.0, 40.0], device)
    assert frac > 0.99  # the same float64 values rounded: all but rare ties and near-zero sums are equal


def test_device_motion_overlap_order_and_errors():
    """Two moving objects over one vertex: the later one's motion wins, as on the host; static vertices stay at
    rest. A motion that fails leaves the device state untouched (all motions are evaluated first)."""
    from foveawarp.scene import SceneObject

    rng = np.random.default_rng(3)
    v = rng.uniform(-5.0, 5.0, (12, 3)).astype(np.float32)
    f = np.arange(12, dtype=np.int32).reshape(4, 3)
    calls = {"bad": False}

    def rot(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[c, -s, 0, 1.5 * t], [s, c, 0, 0], [0, 0, 1, -t], [0, 0, 0, 1]])

    def shift(t):
        if calls["bad"]:
            return np.full((4, 4), np.nan)
        return np.array([[1, 0, 0, 0], [0, 1, 0, t], [0, 0, 1, 0], [0, 0, 0, 1.0]])

    objs = [SceneObject("a", (0, 6), rot), SceneObject("b", (4, 9), shift), SceneObject("still", (9, 12))]
    scene = fw.Scene(v, f, (0.5, 0.5, 0.5), objects=objs)
    _check_device_motion(scene, [0.0, 0.3, 1.1])
    ds = fw.DeviceScene(scene, device="cpu")
    ds.set_time(0.2)
    ds.set_time(0.5)  # points_prev (t = 0.2) now differs from points (t = 0.5)
    assert not np.array_equal(ds.points_prev.numpy(), ds.points.numpy())
    np.testing.assert_array_equal(ds.points.numpy()[9:], v[9:])
    before = ds.points.numpy().copy(), ds.points_prev.numpy().copy()
    calls["bad"] = True
    with pytest.raises(ValueError, match="motion"):
        ds.set_time(0.9)
    np.testing.assert_array_equal(ds.points.numpy(), before[0])
    np.testing.assert_array_equal(ds.points_prev.numpy(), before[1])


@settings(max_examples=25, deadline=None)
@given(angles=st.tuples(*[st.floats(-10.0, 10.0)] * 3), trans=st.tuples(*[st.floats(-1e4, 1e4)] * 3),
       scale=st.sampled_from([1e-6, 1.0, 1e5]), seed=st.integers(0, 2 ** 16))
def test_device_motion_any_rigid_transform(angles, trans, scale, seed):
    """Any rotation and translation, vertices from tiny to huge: within one float32 ulp of the host's values."""
    from foveawarp.scene import SceneObject

    a, b, c = angles
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    m = np.eye(4)
    m[:3, :3] = rz @ ry @ rx
    m[:3, 3] = trans
    v = (np.random.default_rng(seed).standard_normal((9, 3)) * scale).astype(np.float32)
    n = np.random.default_rng(seed + 1).standard_normal((9, 3)).astype(np.float32)
    scene = fw.Scene(v, np.arange(9, dtype=np.int32).reshape(3, 3), (0.5, 0.5, 0.5), vertex_normals=n,
                     objects=[SceneObject("o", (0, 9), lambda t: m if t else np.eye(4))])
    _check_device_motion(scene, [0.0, 1.0])


@wp.kernel(enable_backward=False)
def _cast_kernel(mesh: wp.uint64, origin: wp.vec3, dirs: wp.array(dtype=wp.vec3), t_out: wp.array(dtype=float),
                 f_out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    q = wp.mesh_query_ray(mesh, origin, dirs[i], 1.0e6)
    t_out[i] = wp.where(q.result, q.t, -1.0)
    f_out[i] = wp.where(q.result, q.face, -1)


@pytest.mark.needs_cuda
@pytest.mark.parametrize("name, kw", [("earth", {}), ("cornell", {"motion": True})])
def test_scene_update_graph_replay_equals_eager(name, kw):
    """On CUDA the update of the moving objects (previous positions, motion kernels, BVH refit) replays a graph
    captured on its second use; against the same updates run eagerly: positions, previous positions and normals
    bit for bit, and rays cast through the refit BVH hit the same faces at the same distances, over frames."""
    scene = fw.load_scene(name, **kw)
    graph, eager = fw.DeviceScene(scene, device="cuda:0"), fw.DeviceScene(scene, device="cuda:0")
    eager.update_graph_error = "off (the test's eager twin)"
    cam = scene.camera_at(0.0)
    xs, ys = np.meshgrid(np.arange(48) + 0.5, np.arange(32) + 0.5)
    dirs = wp.array(np.ascontiguousarray(cam.ray_dirs(xs.ravel(), ys.ravel(), 48, 32), dtype=np.float32),
                    dtype=wp.vec3, device="cuda:0")
    origin = wp.vec3(*[float(v) for v in cam.eye])
    hits = 0
    for i, t in enumerate([0.0, 0.3, 0.7, 1.1, 1.1, 2.5, -4.0, 9.0]):
        assert graph.set_time(t) == eager.set_time(t)
        for a in ("points", "points_prev", "vertex_normals"):
            np.testing.assert_array_equal(getattr(graph, a).numpy(), getattr(eager, a).numpy(), err_msg=f"{a} {t}")
        cast = []
        for ds in (graph, eager):
            tt = wp.zeros(dirs.shape[0], dtype=float, device="cuda:0")
            ff = wp.zeros(dirs.shape[0], dtype=wp.int32, device="cuda:0")
            wp.launch(_cast_kernel, dim=dirs.shape[0], inputs=[ds.mesh.id, origin, dirs, tt, ff], device="cuda:0")
            cast.append((tt.numpy(), ff.numpy()))
        np.testing.assert_array_equal(cast[0][1], cast[1][1])
        np.testing.assert_array_equal(cast[0][0], cast[1][0])
        hits += int((cast[0][1] >= 0).sum())
    assert graph.update_graph_error is None and len(graph._update_graphs) == 1 and not eager._update_graphs
    assert hits > 0


def test_cornell_area_light_faces_into_the_box():
    """The area light under the ceiling emits downwards (its normal cross(edge_u, edge_v) points into the box),
    so it lights the floor: the direct integrator's area-light term at the floor is, as a
    NumPy estimate of the light's irradiance there (cos_i cos_l / r^2 over the light, 64 x 64 midpoints) says."""
    scene = fw.load_scene("cornell", area_light=True)
    (a,) = scene.area_lights
    n = np.cross(a.edge_u, a.edge_v)
    assert n[1] < 0.0
    p = np.array([-0.5, 0.0, 0.6])  # a floor point that sees the whole light past the blocks
    s = (np.arange(64) + 0.5) / 64
    q = (np.asarray(a.corner) + s[:, None, None] * np.asarray(a.edge_u) + s[None, :, None] * np.asarray(a.edge_v))
    d = q - p
    r2 = (d ** 2).sum(-1)
    cos_i = d[..., 1] / np.sqrt(r2)
    cos_l = -(d @ (n / np.linalg.norm(n))) / np.sqrt(r2)
    e = float(np.mean(cos_i * cos_l / r2) * np.linalg.norm(n))
    assert e > 0.03
    w, h = 16, 9
    loop = fw.FrameLoop(scene, w, h, config=fw.Config().with_(shading={"area_light_samples": 64}), device="cpu",
                        policy="full")
    cam = fw.Camera(eye=(-0.5, 1.0, 0.6), target=tuple(p), up=(0.0, 0.0, -1.0), fov_y_deg=1.0)
    loop.render_reference(cam)
    st = loop.radiance_stoch.numpy()[h // 2, w // 2]
    albedo = np.asarray(loop.gbuffer.albedo.numpy()[h // 2, w // 2], np.float64)
    # the stochastic part is albedo / pi times the light's irradiance (its 64-sample estimate: 10% here)
    np.testing.assert_allclose(st, albedo / np.pi * e * np.asarray(a.radiance), rtol=0.1)


def test_with_materials_expresses_per_face_colours():
    """scenes.with_materials: one material per distinct (albedo, emission), each face's base colour and emission
    exactly its albedo and emission; rendered by the textured kernels, the look is kept up to the change of
    model (Blinn-Phong to GGX): display PSNR 40.7 dB on cornell at 160 x 90 measured, bound 37 dB."""
    from foveawarp.metrics import psnr
    from foveawarp.scenes import with_materials

    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    f = np.array([[0, 1, 2], [1, 3, 2]], np.int32)
    sc = fw.Scene(v, f, np.array([[0.5, 0.2, 0.1], [0.5, 0.2, 0.1]], np.float32),
                  face_emission=np.array([[0, 0, 0], [2.0, 1.0, 0.0]], np.float32))
    m = with_materials(sc)
    assert len(m.materials) == 2
    t = m.materials
    np.testing.assert_allclose(t.base_color_factor[m.face_material][:, :3], sc.face_albedo)
    np.testing.assert_allclose(t.emission[m.face_material], sc.face_emission)
    assert np.all(t.metallic_factor == 0.0) and np.all(t.double_sided == 1)
    np.testing.assert_allclose(t.roughness_factor, (2.0 / 50.0) ** 0.25, rtol=1e-6)
    assert with_materials(m) is m
    with pytest.raises(ValueError, match="scene must be a foveawarp.Scene"):
        with_materials("cornell")
    with pytest.raises(ValueError, match=r"roughness must be in \[0\.0, 1\.0\]"):
        with_materials(sc, roughness=2.0)
    c = fw.load_scene("cornell")
    cm = with_materials(c)
    assert len(cm.materials) == len(np.unique(c.face_albedo, axis=0))
    a = fw.FrameLoop(c, 160, 90, device="cpu").render_reference().image.numpy()
    b = fw.FrameLoop(cm, 160, 90, device="cpu").render_reference().image.numpy()
    assert np.isfinite(b).all() and psnr(a, b) >= 37.0, psnr(a, b)
