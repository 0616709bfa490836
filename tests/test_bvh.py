"""The scene BVH choices (``Scene.bvh_constructor`` / ``bvh_leaf_size``, ``scene.resolve_bvh``): every constructor
and leaf size traces the same closest hits and the same blocked segments as a float64 brute-force Moller-Trumbore
written here, before and after a refit of moving geometry; "auto" resolves per device."""

import numpy as np
import pytest
import warp as wp

import foveawarp as fw
from foveawarp.scene import BVH_CONSTRUCTORS, DeviceScene, resolve_bvh

# closest hit against float64 brute force: t relative 1e-4 (float32 traversal); the face must match unless the
# brute force's second-nearest face is within 1e-4 relative of the nearest (a shared edge or coplanar faces);
# only rays within 1e-5 (barycentric) of the nearest triangle's edge may disagree on hit / miss
T_RTOL = 1e-4
EDGE_TOL = 1e-5
CHOICES = [("auto", None), ("sah", None), ("sah", 1), ("sah", 2), ("median", 3), ("cubql", None), ("cubql", 2),
           ("lbvh", 2)]


def test_resolve_bvh_per_device():
    assert resolve_bvh("auto", None, "cpu") == ("sah", None)
    assert resolve_bvh("sah", 3, "cpu") == ("sah", 3)
    assert resolve_bvh("cubql", None, "cpu") == ("cubql", None)
    assert resolve_bvh("lbvh", 2, "cpu") == ("sah", 2)  # a CPU tree has no "lbvh" (Warp would fall back, warning)
    if wp.is_cuda_available():
        assert resolve_bvh("auto", None, "cuda:0") == ("cubql", None)
        assert resolve_bvh("sah", None, "cuda:0") == ("sah", 2)
        assert resolve_bvh("lbvh", 8, "cuda:0") == ("lbvh", 8)
    assert set(BVH_CONSTRUCTORS) == {"auto", "sah", "median", "lbvh", "cubql"}
    for bad in (0, 65, -1, 2.5, "2", True):
        with pytest.raises(ValueError, match="bvh_leaf_size"):
            resolve_bvh("sah", bad, "cpu")
    with pytest.raises(ValueError, match="bvh_constructor.*'kd'"):
        resolve_bvh("kd", None, "cpu")


def _brute_closest(o, d, tris):
    """(t, face, second-nearest t) of each ray (o, d) against every triangle, float64 Moller-Trumbore; t = inf
    for a miss. Also the smallest barycentric margin of the nearest hit (how close it is to an edge)."""
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    n = len(o)
    t_best = np.full(n, np.inf)
    t_second = np.full(n, np.inf)
    face = np.full(n, -1)
    margin = np.full(n, np.inf)
    for s in range(0, n, 64):
        oo, dd = o[s:s + 64, None, :], d[s:s + 64, None, :]
        p = np.cross(dd, e2[None])
        det = np.einsum("rfk,fk->rf", p, e1)
        ok = np.abs(det) > 1e-300
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = oo - v0[None]
        u = np.einsum("rfk,rfk->rf", tv, p) * inv
        q = np.cross(tv, e1[None])
        v = np.einsum("rfk,rfk->rf", dd, q) * inv
        t = np.einsum("fk,rfk->rf", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
        tt = np.where(hit, t, np.inf)
        order = np.argsort(tt, axis=1)
        rows = np.arange(len(tt))
        t_best[s:s + 64] = tt[rows, order[:, 0]]
        t_second[s:s + 64] = tt[rows, order[:, 1]] if tt.shape[1] > 1 else np.inf
        face[s:s + 64] = np.where(np.isfinite(t_best[s:s + 64]), order[:, 0], -1)
        j = order[:, 0]
        margin[s:s + 64] = np.minimum.reduce([u[rows, j], v[rows, j], 1 - u[rows, j] - v[rows, j]])
    return t_best, face, t_second, margin


@wp.kernel(enable_backward=False)
def _closest_kernel(mesh: wp.uint64, o: wp.array(dtype=wp.vec3), d: wp.array(dtype=wp.vec3),
                    t: wp.array(dtype=float), face: wp.array(dtype=wp.int32), blocked: wp.array(dtype=wp.int32),
                    seg: float):
    i = wp.tid()
    q = wp.mesh_query_ray(mesh, o[i], d[i], 1.0e6)
    if q.result:
        t[i] = q.t
        face[i] = q.face
    else:
        t[i] = -1.0
        face[i] = -1
    a = wp.mesh_query_ray_anyhit(mesh, o[i], d[i], seg)
    blocked[i] = wp.where(a, 1, 0)


def _rays(scene, k, seed):
    """Rays from points around the scene's bounding box towards random points inside it (unit directions)."""
    rng = np.random.default_rng(seed)
    lo, hi = scene.vertices.min(0).astype(np.float64), scene.vertices.max(0).astype(np.float64)
    c, r = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
    dirs = rng.normal(size=(k, 3))
    o = c + 1.5 * r * dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    target = lo + rng.random((k, 3)) * (hi - lo)
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return o, d, 1.5 * r


def _check_against_brute(ds, tris, o, d, seg, device, label, misses=True):
    k = len(o)
    arr = lambda x: wp.array(np.asarray(x, np.float32), dtype=wp.vec3, device=device)  # noqa: E731
    t = wp.zeros(k, dtype=float, device=device)
    face = wp.zeros(k, dtype=wp.int32, device=device)
    blocked = wp.zeros(k, dtype=wp.int32, device=device)
    wp.launch(_closest_kernel, dim=k, inputs=[ds.mesh.id, arr(o), arr(d)], outputs=[t, face, blocked, seg],
              device=device)
    t, face, blocked = t.numpy(), face.numpy(), blocked.numpy()
    tb, fb, t2, margin = _brute_closest(o, d, tris)
    clear = ~(np.isfinite(tb) & (margin < EDGE_TOL))  # not grazing an edge of the nearest triangle
    hit_k, hit_b = t >= 0, np.isfinite(tb)
    assert hit_b.mean() > 0.2 and (not misses or hit_b.mean() < 0.98), label  # both outcomes occur
    disagree = (hit_k != hit_b) & clear  # away from the nearest triangle's edges the answers must agree
    assert not disagree.any(), f"{label}: {np.sum(disagree)} of {k} rays disagree on hit / miss"
    assert clear.mean() > 0.95, label  # and that is nearly every ray
    both = hit_k & hit_b
    rel = np.abs(t[both] - tb[both]) / np.maximum(tb[both], 1e-12)
    assert np.quantile(rel, 0.995) <= T_RTOL, f"{label}: t differs by {rel.max():.2e}"
    separated = both & (t2 > tb * (1 + T_RTOL)) & clear
    assert np.all(face[separated] == fb[separated]), f"{label}: {np.sum(face[separated] != fb[separated])} faces"
    # any hit within seg: a brute-force hit closer than seg (away from the boundary at seg)
    want = hit_b & (tb < seg)
    sure = clear & (np.abs(tb - seg) > T_RTOL * seg)
    assert 0 < want[sure].mean() < 1, label  # blocked and clear segments both occur
    assert np.all((blocked == 1)[sure] == want[sure]), f"{label}: any-hit disagrees"


@pytest.mark.parametrize("ctor,leaf", CHOICES)
def test_every_bvh_choice_traces_like_brute_force(device, ctor, leaf):
    """Closest hits (t, face) and any-hit answers of 1500 rays through the earth scene (2k triangles) and of
    1000 through cornell (large, axis-aligned quads with shared edges), per constructor and leaf size."""
    for name, k in (("earth", 1500), ("cornell", 1000)):
        scene = fw.load_scene(name)
        ds = DeviceScene(scene, device=device, bvh_constructor=ctor, bvh_leaf_size=leaf)
        assert (ds.bvh_constructor, ds.bvh_leaf_size) == resolve_bvh(ctor, leaf, device)
        o, d, r = _rays(scene, k, seed=11)
        tris = scene.vertices[scene.faces].astype(np.float64)
        _check_against_brute(ds, tris, o, d, seg=1.2 * r, device=device, label=f"{name} {ctor}/{leaf}",
                             misses=name != "cornell")  # a closed box: every ray hits


@pytest.mark.parametrize("ctor", ["auto", "sah", "cubql"])
def test_refit_follows_moving_geometry(device, ctor):
    """cornell with its moving box: after ``set_time`` (a refit of the BVH built by ``ctor``) the rays hit the
    moved triangles (brute force on ``vertices_at(t)``), not the rest positions."""
    scene = fw.load_scene("cornell", motion=True)
    ds = DeviceScene(scene, device=device, bvh_constructor=ctor)
    o, d, r = _rays(scene, 800, seed=5)
    for t in (0.0, 0.9, 1.7):
        ds.set_time(t)
        tris = scene.vertices_at(t)[scene.faces].astype(np.float64)
        _check_against_brute(ds, tris, o, d, seg=1.2 * r, device=device, label=f"{ctor} t={t}", misses=False)
    moved = scene.vertices_at(1.7)[scene.faces] != scene.vertices[scene.faces]
    assert moved.any()  # the check above saw moved geometry


def test_device_scene_passes_the_choice_to_warp(monkeypatch):
    """The wp.Mesh arguments DeviceScene passes: on the CPU "auto" is SAH with Warp's default leaf size (None:
    Warp's own default), an explicit leaf size and constructor reach Warp, and the scene's fields
    are overridden by DeviceScene's arguments."""
    seen = []
    real = wp.Mesh.__init__

    def spy(self, *a, **k):
        seen.append((k.get("bvh_constructor"), k.get("bvh_leaf_size")))
        real(self, *a, **k)

    monkeypatch.setattr(wp.Mesh, "__init__", spy)
    scene = fw.load_scene("cornell")
    ds = DeviceScene(scene, "cpu")
    assert seen[-1] == ("sah", None) and (ds.bvh_constructor, ds.bvh_leaf_size) == ("sah", None)
    DeviceScene(scene, "cpu", bvh_constructor="median", bvh_leaf_size=3)
    assert seen[-1] == ("median", 3)
    scene.bvh_constructor, scene.bvh_leaf_size = "cubql", 2
    DeviceScene(scene, "cpu")
    assert seen[-1] == ("cubql", 2)
    DeviceScene(scene, "cpu", bvh_constructor="sah", bvh_leaf_size=5)
    assert seen[-1] == ("sah", 5)


def test_scene_builders_and_load_scene_take_the_bvh_choice(tmp_path):
    """``load_scene`` passes ``bvh_constructor`` / ``bvh_leaf_size`` to the builders, and the scene carries them to
    its DeviceScene; a file mesh (the on-ground builder) takes them too."""
    sc = fw.load_scene("cornell", bvh_constructor="median", bvh_leaf_size=2)
    assert (sc.bvh_constructor, sc.bvh_leaf_size) == ("median", 2)
    ds = DeviceScene(sc, "cpu")
    assert (ds.bvh_constructor, ds.bvh_leaf_size) == ("median", 2)
    for name in ("eyechart", "earth"):
        sc = fw.load_scene(name, bvh_leaf_size=3)
        assert (sc.bvh_constructor, sc.bvh_leaf_size) == ("auto", 3)
    obj = tmp_path / "tri.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    sc = fw.load_scene(str(obj), bvh_constructor="sah", bvh_leaf_size=5)
    assert (sc.bvh_constructor, sc.bvh_leaf_size) == ("sah", 5)
    with pytest.raises(ValueError, match=r"bvh_leaf_size.*\[1, 64\].*0"):
        fw.load_scene("cornell", bvh_leaf_size=0)


def test_auto_falls_back_to_sah_when_cubql_cannot_be_built(monkeypatch):
    """Where "auto" picks cuBQL (CUDA; simulated here on the CPU) and Warp cannot build it, DeviceScene warns and
    builds SAH, and records that; an explicit "cubql" fails loudly. The scene's own "cubql" does not block the
    fallback when the caller asks for "auto"."""
    import foveawarp.scene as scene_mod

    real_resolve, real_init = scene_mod.resolve_bvh, wp.Mesh.__init__

    def resolve_as_cuda(ctor, leaf, device):
        c, lf = real_resolve(ctor, leaf, device)
        return ("cubql", lf) if ctor == "auto" else (c, lf)

    def no_cubql(self, *a, **k):
        if k.get("bvh_constructor") == "cubql":
            raise RuntimeError("this Warp has no cuBQL")
        real_init(self, *a, **k)

    monkeypatch.setattr(scene_mod, "resolve_bvh", resolve_as_cuda)
    monkeypatch.setattr(wp.Mesh, "__init__", no_cubql)
    scene = fw.load_scene("cornell")
    with pytest.warns(RuntimeWarning, match="cuBQL"):
        ds = DeviceScene(scene, "cpu")
    assert (ds.bvh_constructor, ds.bvh_leaf_size) == ("sah", None)
    with pytest.raises(RuntimeError, match="no cuBQL"):
        DeviceScene(scene, "cpu", bvh_constructor="cubql")
    scene.bvh_constructor = "cubql"
    with pytest.warns(RuntimeWarning, match="cuBQL"):
        ds = DeviceScene(scene, "cpu", bvh_constructor="auto")
    assert ds.bvh_constructor == "sah"
    o, d, r = _rays(scene, 300, seed=2)  # the fallback tree traces like brute force
    _check_against_brute(ds, scene.vertices[scene.faces].astype(np.float64), o, d, 1.2 * r, "cpu", "fallback",
                         misses=False)


def test_builds_of_the_same_scene_render_the_same_frame(device):
    """Two DeviceScenes of one scene (two BVH builds with the device's default choice) give bit-equal
    reference frames: the build is deterministic, ties between faces included (cornell's shared edges)."""
    frames = []
    for _ in range(2):
        loop = fw.FrameLoop("cornell", 96, 64, device=device)
        loop.render_reference(loop.scene.camera)
        frames.append(loop.image.numpy())
    np.testing.assert_array_equal(frames[0], frames[1])
