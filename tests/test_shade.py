"""Shading kernel: analytic Lambert on a plane, shadow rays against brute-force occlusion, AO bounds."""

import numpy as np
import pytest
import warp as wp

import foveawarp as fw
import foveawarp.scene
from foveawarp.kernels.shade import visible
from foveawarp.scenes import SceneBuilder

W, H = 48, 36
NO_AMBIENT = fw.Config(shading=fw.ShadingConfig(ambient=(0, 0, 0), specular=0.0, background=(0, 0, 0)))


def _plane_scene(occluder=False, light_kind="point"):
    b = SceneBuilder()
    b.add_quad((-5, 0, -5), (0, 0, 10), (10, 0, 0), (0.6, 0.5, 0.4))  # y = 0, normal +y
    if occluder:
        b.add_box((0.3, 1.0, 0.0), (0.8, 0.1, 0.8), (0.5, 0.5, 0.5))
    light = fw.Light(kind=light_kind, position=(0.0, 2.0, 0.0), direction=(0, -1, 0), cone_deg=40.0,
                     intensity=(3.0, 2.0, 1.0), penumbra=0.25)
    cam = fw.Camera(eye=(0.0, 4.0, 3.0), target=(0.0, 0.0, 0.0), fov_y_deg=60.0)
    return b.build(lights=[light], camera=cam)


def _lambert_np(pos, albedo, light_pos, intensity):
    d = light_pos - pos
    dist2 = np.sum(d * d, axis=-1)
    cos = d[..., 1] / np.sqrt(dist2)  # plane normal is +y
    return albedo * intensity * (np.clip(cos, 0, None) / dist2)[..., None] / np.pi


def test_point_light_lambert_matches_analytic(device):
    scene = _plane_scene()
    loop = fw.FrameLoop(scene, W, H, config=NO_AMBIENT, device=device)
    loop.render_reference(scene.camera)
    g = loop.gbuffer.numpy()
    rad = loop.radiance.numpy()
    hit = g["hit"].astype(bool)
    expect = _lambert_np(g["position"][hit].astype(np.float64), np.array([0.6, 0.5, 0.4]),
                         np.array([0.0, 2.0, 0.0]), np.array([3.0, 2.0, 1.0]))
    np.testing.assert_allclose(rad[hit], expect, rtol=1e-4, atol=1e-7)


def test_spot_cone_cuts_light(device):
    scene = _plane_scene(light_kind="spot")
    loop = fw.FrameLoop(scene, W, H, config=NO_AMBIENT, device=device)
    loop.render_reference(scene.camera)
    g = loop.gbuffer.numpy()
    rad = loop.radiance.numpy()
    hit = g["hit"].astype(bool)
    p = g["position"][hit].astype(np.float64)
    d = p - np.array([0.0, 2.0, 0.0])
    ang = np.degrees(np.arccos(np.clip(-d[:, 1] / np.linalg.norm(d, axis=1), -1, 1)))
    outside = ang > 40.0 + 1e-3
    inside_core = ang < 40.0 * 0.75 - 1e-3
    assert outside.any() and inside_core.any()
    assert np.all(rad[hit][outside] == 0)
    expect = _lambert_np(p, np.array([0.6, 0.5, 0.4]), np.array([0.0, 2.0, 0.0]), np.array([3.0, 2.0, 1.0]))
    np.testing.assert_allclose(rad[hit][inside_core], expect[inside_core], rtol=1e-4)


def _segment_hits_triangles(p, q, tris):
    """Brute-force Moller-Trumbore: does the open segment p->q cross any triangle (N points x M tris)?"""
    d = q - p
    v0, v1, v2 = tris[:, 0], tris[:, 1], tris[:, 2]
    e1, e2 = v1 - v0, v2 - v0
    pv = np.cross(d[:, None, :], e2[None])
    det = np.sum(e1[None] * pv, axis=-1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = p[:, None, :] - v0[None]
    u = np.sum(tv * pv, -1) * inv
    qv = np.cross(tv, e1[None])
    v = np.sum(d[:, None, :] * qv, -1) * inv
    t = np.sum(e2[None] * qv, -1) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6) & (t < 1 - 1e-6)
    return hit.any(axis=1)


def test_shadow_rays_match_brute_force_occlusion(device):
    scene = _plane_scene(occluder=True)
    loop = fw.FrameLoop(scene, W, H, config=NO_AMBIENT, device=device)
    loop.render_reference(scene.camera)
    g = loop.gbuffer.numpy()
    rad = loop.radiance.numpy()
    on_plane = g["hit"].astype(bool) & (g["face"] < 2)
    p = g["position"][on_plane].astype(np.float64)
    occluder_tris = scene.vertices[scene.faces[2:]].astype(np.float64)
    blocked = _segment_hits_triangles(p, np.broadcast_to([0.0, 2.0, 0.0], p.shape), occluder_tris)
    assert 0.02 < blocked.mean() < 0.9  # the test scene has both lit and shadowed floor pixels
    lit = rad[on_plane].sum(axis=1) > 0
    disagree = lit == blocked
    # pixels whose shadow ray grazes the occluder's edge may differ by float rounding
    assert disagree.mean() <= 0.005, f"{disagree.sum()} of {len(lit)} pixels disagree"


def test_ambient_occlusion_bounded_and_deterministic(device):
    cfg = fw.Config(shading=fw.ShadingConfig(ao_samples=8, ambient=(0.5, 0.5, 0.5), specular=0.0))
    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, W, H, config=cfg, device=device)
    loop.render_reference(scene.camera)
    a = loop.radiance.numpy().copy()
    loop.frame_index = 0
    loop.render_reference(scene.camera)
    b = loop.radiance.numpy()
    np.testing.assert_array_equal(a, b)
    g = loop.gbuffer.numpy()
    hit = g["hit"].astype(bool)
    # ambient part never exceeds the un-occluded ambient term
    no_ao = fw.FrameLoop(scene, W, H, config=cfg.with_(shading={"ao_samples": 0}), device=device)
    no_ao.render_reference(scene.camera)
    c = no_ao.radiance.numpy()
    assert np.all(a[hit] <= c[hit] + 1e-5)
    # corners where walls meet are darker with AO than without
    assert (c[hit] - a[hit]).sum() > 0


def test_tonemap_display_range_and_monotone(device):
    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, W, H, device=device)
    img = loop.render_reference().numpy()
    assert img.min() >= 0.0 and img.max() <= 1.0 and np.all(np.isfinite(img))
    rad = loop.radiance.numpy().reshape(-1, 3)[:, 0]
    out = img.reshape(-1, 3)[:, 0]
    order = np.argsort(rad)
    assert np.all(np.diff(out[order]) >= -1e-6)


def test_tonemap_against_numpy_hable(device):
    import warp as wp

    from foveawarp.kernels.tonemap import tonemap_kernel

    def hable(x):
        A, B, C, D, E, F = 0.15, 0.5, 0.1, 0.2, 0.02, 0.3
        return (x * (A * x + C * B) + D * E) / (x * (A * x + B) + D * F) - E / F

    x = np.linspace(0, 50, 64 * 3).reshape(8, 8, 3).astype(np.float32)
    hdr = wp.array(x, dtype=wp.vec3, device=device)
    out = wp.zeros((8, 8), dtype=wp.vec3, device=device)
    fw.parallel.launch(tonemap_kernel, dim=(8, 8), inputs=[hdr, 2.0, 11.2], outputs=[out], device=device)
    expect = np.clip(hable(2.0 * x.astype(np.float64)) / hable(11.2), 0, 1) ** (1 / 2.2)
    np.testing.assert_allclose(out.numpy(), expect, atol=2e-5)


def test_per_frame_upload_equals_fresh_parameters(device):
    """``upload_shade_params`` keeps one struct per ``ao_samples`` and only sets the eye and frame again: what
    it uploads equals a freshly built ``shade_params`` struct, frame after frame, camera after camera."""
    loop = fw.FrameLoop("cornell", 16, 12, device=device)
    scene = loop.scene
    for i, ao in enumerate([None, None, 3, None, 3]):
        cam = scene.camera_at(0.2 * i) if scene.camera_path is not None else fw.Camera(eye=(0.1 * i, 1.0, 3.5))
        loop.frame_index = 7 * i
        got = loop.upload_shade_params(cam, ao_samples=ao).numpy()[0].copy()
        want = loop.shade.upload(loop.shade_params(cam, ao_samples=ao)).numpy()[0]
        assert got.tobytes() == want.tobytes()
        assert tuple(got["eye"]) == pytest.approx(cam.eye)


@wp.kernel(enable_backward=False)
def _visibility_kernel(mesh: wp.uint64, p: wp.array(dtype=wp.vec3), n: wp.array(dtype=wp.vec3),
                       to: wp.array(dtype=wp.vec3), dist: wp.array(dtype=float), eps: float,
                       vis: wp.array(dtype=float), closest: wp.array(dtype=float)):
    i = wp.tid()
    vis[i] = visible(mesh, p[i], n[i], eps, to[i], dist[i])
    # the closest-hit query the any-hit one replaced, on the same segment
    c = 1.0
    if dist[i] > 2.0 * eps:
        q = wp.mesh_query_ray(mesh, p[i] + n[i] * eps, to[i], dist[i] - 2.0 * eps)
        if q.result:
            c = 0.0
    closest[i] = c


@pytest.mark.parametrize("scene_name", ["cornell", "bunny"])
def test_visibility_any_hit_equals_closest_hit_and_brute_force(device, scene_name):
    """``visible`` (an any-hit query) against Warp's closest-hit query on the same segments (the same answer,
    every one) and against brute-force Moller-Trumbore in float64 (segments that graze an edge may differ):
    4000 random segments from surface points of a real mesh, some with zero length."""
    scene = fw.load_scene(scene_name)
    ds = fw.scene.DeviceScene(scene, device=device)
    rng = np.random.default_rng(3)
    tris = scene.vertices[scene.faces].astype(np.float64)
    k = 4000
    f = rng.integers(0, len(tris), k)
    a, b = rng.random(k), rng.random(k)
    sw = a + b > 1
    a[sw], b[sw] = 1 - a[sw], 1 - b[sw]
    t = tris[f]
    p = t[:, 0] + a[:, None] * (t[:, 1] - t[:, 0]) + b[:, None] * (t[:, 2] - t[:, 0])
    nrm = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-30)
    d = rng.normal(size=(k, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where(np.sum(d * nrm, axis=1, keepdims=True) < 0, -d, d)  # leave on the normal's side
    extent = float(np.ptp(scene.vertices, axis=0).max())
    dist = rng.uniform(0.0, extent, k)
    dist[:50] = 0.0
    eps = 1.0e-4 * extent
    arr = lambda x, dt=wp.vec3: wp.array(np.asarray(x, np.float32), dtype=dt, device=device)  # noqa: E731
    vis = wp.zeros(k, dtype=float, device=device)
    closest = wp.zeros(k, dtype=float, device=device)
    wp.launch(_visibility_kernel, dim=k, inputs=[ds.mesh.id, arr(p), arr(nrm), arr(d), arr(dist, float), eps],
              outputs=[vis, closest], device=device)
    vis, closest = vis.numpy(), closest.numpy()
    np.testing.assert_array_equal(vis, closest)
    assert set(np.unique(vis)) <= {0.0, 1.0} and np.all(vis[:50] == 1.0)
    # brute force on every segment of cornell, on 400 of bunny's (70k triangles)
    m = k if len(tris) < 1000 else 400
    o = p[:m] + nrm[:m] * eps
    q = o + d[:m] * np.maximum(dist[:m] - 2 * eps, 0.0)[:, None]
    blocked = np.zeros(m, bool)
    step = max(1, 2_000_000 // len(tris))
    for s in range(0, m, step):
        blocked[s:s + step] = _segment_hits_triangles(o[s:s + step], q[s:s + step], tris)
    blocked[:50] = False
    assert 0.05 < blocked.mean() < 0.95  # both answers occur
    disagree = (vis[:m] == 0.0) != blocked
    assert disagree.mean() <= 0.005, f"{disagree.sum()} of {m} segments disagree with brute force"


@pytest.mark.parametrize("ao, lanes", [(8, 8), (8, 3), (5, 8), (5, 2), (2, 16), (256, 16), (3, 1)])
def test_ao_lanes_trace_the_same_rays(device, ao, lanes):
    """``ShadingConfig.ao_lanes``: a work list's AO rays traced ``min(lanes, ao)`` threads per pixel, then the
    pixels shaded with their counts, give the values of one thread per pixel tracing them all, bit for bit, and
    those of the full-frame shading at the listed pixels; with an area light whose samples come first in each
    pixel's random stream, lanes left without a ray (5 rays on 8 lanes), misses in the list, two frames; with
    the light sources' part shaded apart from the AO pass too (``ShadeStage.split_direct``)."""
    scene = fw.load_scene("cornell", area_light=True)
    cfg = fw.Config().with_(shading={"ao_samples": ao, "ao_lanes": lanes})
    loop = fw.FrameLoop(scene, W, H, config=cfg, device=device, policy="full")
    one = fw.FrameLoop(scene, W, H, config=cfg.with_(shading={"ao_lanes": 1}), device=device, policy="full")
    assert loop.shade.stochastic() and scene.area_lights
    rng = np.random.default_rng(ao * 17 + lanes)
    for frame in range(2):
        cam = scene.camera_at(frame / 10)
        loop.frame_index = one.frame_index = frame  # the AO noise of this frame (render_reference keeps the index)
        loop.render_reference(cam)
        one.render_reference(cam)
        full = loop.radiance.numpy().copy()
        full_st = loop.radiance_stoch.numpy().copy()
        hit = loop.gbuffer.hit.numpy().astype(bool)
        pick = np.flatnonzero(rng.random(W * H) < 0.3)
        assert (~hit.ravel()[pick]).any() and hit.ravel()[pick].any()  # misses and hits in the list
        work = wp.array(np.concatenate([rng.permutation(pick), np.zeros(7, np.int64)]).astype(np.int32),
                        dtype=wp.int32, device=device)
        count = wp.array([len(pick)], dtype=wp.int32, device=device)
        res = {}
        # lanes, then the pixels shaded with the counts; the light sources' part apart from the AO pass
        # (ShadeStage.split_direct: on CUDA on a second stream); one thread per pixel
        for name, lp, split in (("lanes", loop, False), ("split", loop, True), ("one", one, False)):
            lp.shade.split_direct = split
            out = wp.array(np.full((H, W, 3), -3.0, np.float32), dtype=wp.vec3, device=device)
            lp.radiance_stoch.assign(np.full((H, W, 3), -3.0, np.float32))
            lp.shade_list(cam, work, count, out)
            res[name] = (out.numpy().copy(), lp.radiance_stoch.numpy().copy())
        assert loop.shade.ao_lanes() == min(lanes, ao) and one.shade.ao_lanes() == 1
        for other in ("split", "one"):
            for a, b in zip(res["lanes"], res[other]):
                np.testing.assert_array_equal(a, b)
        out, st = res["lanes"]
        flat = lambda a: a.reshape(-1, 3)  # noqa: E731
        np.testing.assert_array_equal(flat(out)[pick], flat(full)[pick])
        np.testing.assert_array_equal(flat(st)[pick], flat(full_st)[pick])
        rest = np.setdiff1d(np.arange(W * H), pick)
        assert np.all(flat(out)[rest] == -3.0)  # nothing written outside the list


def _lights_scene(n_lights):
    """A plane under two boxes lit by ``n_lights`` point and spot lights around and above them (some behind the
    plane's back, some casting the boxes' shadows)."""
    b = SceneBuilder()
    b.add_quad((-5, 0, -5), (0, 0, 10), (10, 0, 0), (0.6, 0.5, 0.4))
    b.add_box((0.3, 0.5, 0.0), (0.8, 1.0, 0.8), (0.5, 0.5, 0.5))
    b.add_box((-1.0, 0.3, 0.6), (0.5, 0.6, 0.5), (0.4, 0.6, 0.5))
    rng = np.random.default_rng(n_lights)
    lights = []
    for k in range(n_lights):
        pos = (float(rng.uniform(-2, 2)), float(rng.uniform(-0.5, 3.0)), float(rng.uniform(-2, 2)))
        lights.append(fw.Light(kind="spot" if k % 3 == 0 else "point", position=pos, direction=(0, -1, 0),
                               cone_deg=50.0, intensity=(4.0, 3.5, 3.0), penumbra=0.2))
    cam = fw.Camera(eye=(0.0, 4.0, 4.0), target=(0.0, 0.0, 0.0), fov_y_deg=60.0)
    return b.build(lights=lights, camera=cam)


@pytest.mark.parametrize("n_lights, shadows", [(3, True), (3, False), (34, True)])
def test_ao_lanes_with_many_lights_equal_one_thread(device, n_lights, shadows):
    """The list shading with its AO rays traced ahead in lanes, its light sources' part shaded apart or not
    (``ShadeStage.split_direct``), equals one thread per pixel tracing every ray,
    bit for bit, and the full-frame shading at the listed pixels, with 3 and 34 point and spot lights whose
    shadows matter (checked against the same frame without shadows), shadows on and off."""
    scene = _lights_scene(n_lights)
    cfg = fw.Config().with_(shading={"ao_samples": 4, "ao_lanes": 2, "shadows": shadows})
    loop = fw.FrameLoop(scene, W, H, config=cfg, device=device, policy="full")
    one = fw.FrameLoop(scene, W, H, config=cfg.with_(shading={"ao_lanes": 1}), device=device, policy="full")
    noshadow = fw.FrameLoop(scene, W, H, config=cfg.with_(shading={"shadows": False}), device=device, policy="full")
    loop.render_reference(scene.camera)
    one.render_reference(scene.camera)
    noshadow.render_reference(scene.camera)
    full = loop.radiance.numpy().copy()
    if shadows:
        assert (np.abs(full - noshadow.radiance.numpy()).max(axis=2) > 1e-3).mean() > 0.02
    pick = np.flatnonzero(np.random.default_rng(5).random(W * H) < 0.4).astype(np.int32)
    work = wp.array(pick, dtype=wp.int32, device=device)
    count = wp.array([len(pick)], dtype=wp.int32, device=device)
    res = []
    for lp, split in ((loop, False), (loop, True), (one, False)):
        lp.frame_index = 0
        lp.shade.split_direct = split
        out = wp.zeros((H, W), dtype=wp.vec3, device=device)
        lp.shade_list(scene.camera, work, count, out)
        res.append(out.numpy().reshape(-1, 3).copy())
    np.testing.assert_array_equal(res[0], res[1])
    np.testing.assert_array_equal(res[0], res[2])
    np.testing.assert_array_equal(res[0][pick], full.reshape(-1, 3)[pick])


@pytest.mark.needs_cuda
def test_split_direct_in_captured_frames_cuda():
    """On CUDA the list's light sources' part runs on a second stream beside its AO pass (fork and join inside
    the captured frame graph): frames along a moving path, replayed from the graph, equal those of a loop that
    shades the list in one stream (``split_direct=False``), bit for bit."""
    scene = fw.load_scene("cornell", motion=True, area_light=True)
    cfg = fw.Config().with_(shading={"ao_samples": 8}, reorder={"strategy": "tile"})
    on = fw.FrameLoop(scene, W, H, config=cfg, device="cuda:0", timing=False, policy="foveated")
    off = fw.FrameLoop(scene, W, H, config=cfg, device="cuda:0", timing=False, policy="foveated")
    off.shade.split_direct = False
    assert on.shade.split_direct is None and on.shade.splits() and on.shade.ao_lanes() >= 2
    assert on.shade._side is not None  # made with the stage, before any capture
    states = []
    for i in range(12):
        cam, t, gaze = scene.camera_at(i / 40.0), i / 30.0, (20.0 + 3 * i, 30.0 - i)
        a = on.render(cam, gaze_px=gaze, time=t)
        b = off.render(cam, gaze_px=gaze, time=t)
        states.append(a.stats["graph"])
        np.testing.assert_array_equal(a.numpy(), b.numpy(), err_msg=str(i))
        np.testing.assert_array_equal(on.temporal.color.numpy(), off.temporal.color.numpy(), err_msg=str(i))
    assert on.shade._light is not None and off.shade._light is None  # only the first loop split its lists
    assert states.count("replayed") >= 6, states


def test_split_direct_default_rule():
    """``ShadeStage.splits()``: by default only on CUDA up to SPLIT_MAX_PIXELS pixels; forced either way by
    ``split_direct``; never without AO lanes (fewer than 2: the list has no AO pass to run beside)."""
    from foveawarp.stages.shade import ShadeStage

    loop = fw.FrameLoop(fw.load_scene("cornell"), W, H, config=fw.Config().with_(shading={"ao_samples": 4}),
                        device="cpu", policy="full")
    st = loop.shade
    assert st.split_direct is None and not st.splits()  # the CPU: one pass after the other gains nothing
    st.split_direct = True
    assert st.splits()
    st.upload(st.params(loop.scene.camera, 0, ao_samples=1))  # one AO ray: no lanes
    assert st.ao_lanes() == 1 and not st.splits()
    st.upload(st.params(loop.scene.camera, 0))
    assert st.splits()
    st.split_direct = False
    assert not st.splits()
    st.split_direct = "yes"  # not a bool: refused, naming the attribute and the allowed values
    with pytest.raises(ValueError, match=r"split_direct must be None \(the default rule\), True or False, got 'yes'"):
        st.splits()
    st.split_direct = None

    class _Cuda:  # the rule's only use of the device
        is_cuda = True

    probe = ShadeStage.__new__(ShadeStage)
    probe.device, probe.config, probe._ao_samples, probe.split_direct = _Cuda(), st.config, 8, None
    for (w, h), want in (((1920, 1080), True), ((2560, 1440), False), ((3840, 2160), False), ((64, 48), True)):
        probe.width, probe.height = w, h
        assert probe.splits() is want, (w, h)


def test_ao_launch_shape_rule():
    """``ShadeStage._ao_launch_shape``: on CUDA blocks of ``AO_BLOCK_DIM`` threads and at most
    ``AO_THREADS_PER_SM`` threads per SM (whole blocks, at least one per SM); the CPU has no blocks (0, 0)."""
    from foveawarp.stages.shade import ShadeStage

    loop = fw.FrameLoop(fw.load_scene("cornell"), W, H, config=fw.Config().with_(shading={"ao_samples": 4}),
                        device="cpu", policy="full")
    assert loop.shade._ao_launch_shape() == (0, 0)

    class _Cuda:
        is_cuda = True
        sm_count = 132

    probe = ShadeStage.__new__(ShadeStage)
    probe.device = _Cuda()
    assert (ShadeStage.AO_BLOCK_DIM, ShadeStage.AO_THREADS_PER_SM) == (128, 16384)
    assert probe._ao_launch_shape() == (128 * 132, 128)
    for bd, per_sm, want in ((256, 8192, (32 * 132, 256)), (128, 100, (132, 128)), (1024, 16384, (16 * 132, 1024))):
        probe.AO_BLOCK_DIM, probe.AO_THREADS_PER_SM = bd, per_sm
        assert probe._ao_launch_shape() == want, (bd, per_sm)


@pytest.mark.parametrize("block_dim, threads_per_sm", [(128, 16384), (32, 32), (1024, 1024), (256, 8192)])
def test_ao_lanes_launch_shape_same_values(device, block_dim, threads_per_sm):
    """The AO lanes launch in any CUDA block size and grid cap (a grid so small that each thread takes many entry
    lanes, a grid larger than the list) gives the counts of one thread per pixel tracing every ray, bit for bit
    (on the CPU the shape is not used: the same check of the lanes)."""
    scene = fw.load_scene("cornell", area_light=True)
    cfg = fw.Config().with_(shading={"ao_samples": 8, "ao_lanes": 4})
    loop = fw.FrameLoop(scene, W, H, config=cfg, device=device, policy="full")
    one = fw.FrameLoop(scene, W, H, config=cfg.with_(shading={"ao_lanes": 1}), device=device, policy="full")
    loop.shade.AO_BLOCK_DIM, loop.shade.AO_THREADS_PER_SM = block_dim, threads_per_sm
    cam = scene.camera_at(0.2)
    loop.render_reference(cam)
    one.render_reference(cam)
    rng = np.random.default_rng(block_dim + threads_per_sm)
    pick = rng.permutation(W * H)[: W * H // 2].astype(np.int32)
    work = wp.array(pick, dtype=wp.int32, device=device)
    count = wp.array([len(pick)], dtype=wp.int32, device=device)
    res = []
    for lp in (loop, one):
        lp.shade.split_direct = False
        out = wp.array(np.full((H, W, 3), -3.0, np.float32), dtype=wp.vec3, device=device)
        lp.shade_list(cam, work, count, out)
        res.append((out.numpy().copy(), lp.radiance_stoch.numpy().copy()))
    assert loop.shade.ao_lanes() == 4
    for a, b in zip(*res):
        np.testing.assert_array_equal(a, b)
    assert np.all(res[0][0].reshape(-1, 3)[np.setdiff1d(np.arange(W * H), pick)] == -3.0)


@pytest.mark.parametrize("split_stochastic", [1, 0])
def test_split_direct_repeated_pixels_and_no_stochastic_part(device, split_stochastic):
    """The split keeps each list entry's light part apart (per entry, not in the output), so a list that names
    pixels more than once gets the unsplit list's values; parameters without a stochastic part leave
    ``out_stoch`` untouched, as the unsplit list does."""
    scene = fw.load_scene("cornell", area_light=True)
    loop = fw.FrameLoop(scene, W, H, config=fw.Config().with_(shading={"ao_samples": 6}), device=device,
                        policy="full")
    loop.render_reference(scene.camera)
    st = loop.shade
    rng = np.random.default_rng(9)
    pick = rng.choice(W * H, size=300, replace=False)
    work_np = np.concatenate([pick, pick[:80], pick[:40]]).astype(np.int32)  # 120 pixels listed again
    rng.shuffle(work_np)
    work = wp.array(work_np, dtype=wp.int32, device=device)
    count = wp.array([len(work_np)], dtype=wp.int32, device=device)
    sp = st.params(scene.camera, 3)
    sp.split_stochastic = split_stochastic
    res = []
    for split in (False, True):
        st.split_direct = split
        st.upload(sp)
        out = wp.array(np.full((H, W, 3), -3.0, np.float32), dtype=wp.vec3, device=device)
        ost = wp.array(np.full((H, W, 3), -5.0, np.float32), dtype=wp.vec3, device=device)
        st.list(loop.gbuffer, work, count, out, ost)
        res.append((out.numpy().copy(), ost.numpy().copy()))
    assert st.splits()
    np.testing.assert_array_equal(res[0][0], res[1][0])
    np.testing.assert_array_equal(res[0][1], res[1][1])
    listed = np.zeros(W * H, bool)
    listed[pick] = True
    out, ost = res[1][0].reshape(-1, 3), res[1][1].reshape(-1, 3)
    assert np.all(out[~listed] == -3.0) and np.all(out[listed] != -3.0)
    if split_stochastic:
        assert np.all(ost[~listed] == -5.0) and np.all(ost[listed] != -5.0)
    else:
        assert np.all(ost == -5.0)
