"""Stress: the whole frame (G-buffer, sampling, reorder, shading, indirect, temporal, reconstruction, DoF, tone
map) through ``FrameLoop.render_reference`` and ``FrameLoop.render`` on scenes scaled 1e-4 to 1e5, triangle
soups with degenerate and sliver triangles and duplicated vertices, cameras inside geometry or on a surface,
rays grazing edges and parallel to faces, lights on surfaces; with gazes anywhere and varied configs."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp.config import REORDER_STRATEGIES
from foveawarp.scenes import SceneBuilder, cornell, earth
from stress_util import assert_binary, assert_finite, examples, frame_size

SMALL_INDIRECT = {"rsm_size": 16, "start_level": 1, "limit_level": 2}


# -- checks -------------------------------------------------------------------------------------------------------


def check_frame(loop, frame, label: str) -> None:
    """Every output of a frame: finite; image in [0, 1]; radiance >= 0; maps binary; G-buffer consistent."""
    img = assert_finite(f"{label}: image", frame.numpy())
    assert img.min() >= 0.0 and img.max() <= 1.0, f"{label}: image outside [0, 1]"
    g = frame.gbuffer.numpy()
    for name in ("position", "normal", "depth", "albedo", "velocity", "reproj_uv"):
        assert_finite(f"{label}: gbuffer.{name}", g[name])
    hit = assert_binary(f"{label}: gbuffer.hit", g["hit"]).astype(bool)
    assert (g["depth"] >= 0).all(), f"{label}: negative depth"
    assert ((g["face"] >= 0) == hit).all(), f"{label}: face index and hit flag disagree"
    if hit.any():
        nl = np.linalg.norm(g["normal"][hit], axis=-1)
        assert ((nl > 0.99) & (nl < 1.01)).all(), f"{label}: non-unit normal at a hit, |n| in [{nl.min()}, {nl.max()}]"
    rad = assert_finite(f"{label}: radiance", loop.radiance.numpy())
    assert rad.min() >= 0.0, f"{label}: negative radiance"
    assert_binary(f"{label}: sampling_map", frame.sampling_map.numpy())
    for k, v in frame.extras.items():
        if hasattr(v, "numpy"):
            assert_finite(f"{label}: extras[{k}]", v.numpy())
    for k in ("sampling_rate", "cache_hit_rate"):
        v = frame.stats[k]
        assert math.isfinite(v) and 0.0 <= v <= 1.0, f"{label}: stats[{k}] = {v}"


def run_frames(scene, cams_gazes, config, size, device, label) -> int:
    """Reference + foveated frames along ``cams_gazes``; returns the number of frames checked."""
    w, h = frame_size(device, size)
    loop = fw.FrameLoop(scene, w, h, config=config, device=device)
    n = 0
    for i, (cam, gaze) in enumerate(cams_gazes):
        if i == 0:
            fr = loop.render_reference(cam, gaze_px=gaze)
            check_frame(loop, fr, f"{label} reference")
            n += 1
        fr = loop.render(cam, gaze_px=gaze)
        check_frame(loop, fr, f"{label} frame {i} gaze={gaze}")
        n += 1
    return n


# -- strategies ---------------------------------------------------------------------------------------------------

coords = st.one_of(st.floats(-50.0, 80.0), st.sampled_from([0.0, -1e6, 1e6, 1e30, -3.4e38, 3.4e38]),
                   st.floats(-1e20, 1e20))
gazes = st.one_of(st.none(), st.tuples(coords, coords))
sizes = st.one_of(st.just((32, 24)), st.sampled_from([(1, 1), (7, 3), (3, 9), (33, 25), (16, 1)]))


@st.composite
def configs(draw):
    dof = draw(st.sampled_from([0.0, 0.0, 0.02, 10.0]))  # 10 m: the maximum aperture, CoC at the clamp
    over = {
        "foveation": {"block": draw(st.sampled_from([1, 2, 4, 8])),
                      "min_probability": draw(st.sampled_from([0.0, 0.05, 1.0]))},
        "reorder": {"strategy": draw(st.sampled_from(REORDER_STRATEGIES))},
        "shading": {"shadows": draw(st.booleans()), "ao_samples": draw(st.sampled_from([0, 0, 2])),
                    "indirect": draw(st.sampled_from(["none", "lighttree"]))},
        "indirect": dict(SMALL_INDIRECT),
        "dof": {"aperture_m": dof, "max_coc_px": draw(st.sampled_from([1.0, 16.0, 128.0]))},
    }
    return fw.Config().with_(**over)


# -- scenes -------------------------------------------------------------------------------------------------------


def scaled(scene: fw.Scene, s: float) -> fw.Scene:
    """``scene`` with every length multiplied by ``s`` (geometry, lights, area lights, camera); the light
    intensities stay, so irradiance scales as 1 / s^2."""
    lights = [fw.Light(kind=l.kind, position=tuple(np.asarray(l.position) * s), direction=l.direction,
                       cone_deg=l.cone_deg, intensity=l.intensity, penumbra=l.penumbra) for l in scene.lights]
    areas = [fw.AreaLight(corner=tuple(np.asarray(a.corner) * s), edge_u=tuple(np.asarray(a.edge_u) * s),
                          edge_v=tuple(np.asarray(a.edge_v) * s), radiance=a.radiance) for a in scene.area_lights]
    c = scene.camera
    cam = fw.Camera(eye=tuple(np.asarray(c.eye) * s), target=tuple(np.asarray(c.target) * s), up=c.up,
                    fov_y_deg=c.fov_y_deg)
    return fw.Scene(vertices=scene.vertices.astype(np.float64) * s, faces=scene.faces, face_albedo=scene.face_albedo,
                    face_emission=scene.face_emission, vertex_normals=scene.vertex_normals,
                    face_smooth=scene.face_smooth, lights=lights, area_lights=areas, camera=cam,
                    name=f"{scene.name} x{s:g}")


def orbit(cam: fw.Camera, deg: float) -> fw.Camera:
    """``cam`` with its eye rotated by ``deg`` about the vertical axis through the target."""
    e, t = np.asarray(cam.eye), np.asarray(cam.target)
    a = math.radians(deg)
    r = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    return fw.Camera(eye=tuple(t + r @ (e - t)), target=cam.target, up=cam.up, fov_y_deg=cam.fov_y_deg)


_BASE = {}


def base_scene(name):
    if name not in _BASE:
        _BASE[name] = {"cornell": lambda: cornell(), "cornell_area": lambda: cornell(area_light=True),
                       "earth": lambda: earth(spin=False)}[name]()
    return _BASE[name]


# -- tests --------------------------------------------------------------------------------------------------------


@examples(150, 1000)
@given(name=st.sampled_from(["cornell", "cornell_area", "earth"]),
       exponent=st.one_of(st.sampled_from([-4.0, 5.0, 0.0]), st.floats(-4.0, 5.0)), config=configs(),
       size=sizes, g=st.lists(gazes, min_size=3, max_size=3), move=st.sampled_from([0.0, 0.5, 5.0, 90.0]))
def test_scenes_scaled_1e_minus4_to_1e5(device, cases, name, exponent, config, size, g, move):
    """A scene scaled by 10^-4 .. 10^5 (lights and camera with it): the reference frame and three foveated
    frames (a small move for reprojection, then a larger one, possibly a cut) are finite and in range."""
    s = 10.0 ** exponent
    scene = scaled(base_scene(name), s)
    cam = scene.camera
    seq = [(cam, g[0]), (orbit(cam, move), g[1]), (orbit(cam, 2 * move), g[2])]
    n = run_frames(scene, seq, config, size, device, f"{name} x{s:g}")
    # geometry is scale invariant: the same pixels hit, at s times the unit-scale distance
    w, h = frame_size(device, size)
    g_s = fw.FrameLoop(scene, w, h, config=config, device=device).render_reference(cam).gbuffer.numpy()
    unit = base_scene(name)
    g_1 = fw.FrameLoop(unit, w, h, config=config, device=device).render_reference(unit.camera).gbuffer.numpy()
    differ = g_s["hit"] != g_1["hit"]
    assert differ.sum() <= 1 + 0.02 * differ.size, f"x{s:g}: hit mask differs at {int(differ.sum())} pixels"
    same = (g_s["face"] == g_1["face"]) & (g_1["hit"] != 0)
    np.testing.assert_allclose(g_s["depth"][same] / s, g_1["depth"][same], rtol=1e-3)
    cases.add("scenes scaled 1e-4..1e5 (frames)", n)


def _soup(rng, n_tri, kinds, scale):
    """A floor quad plus ``n_tri`` triangles of the given kinds (degenerate, slivers, duplicated vertices)."""
    v = [[-2, 0, -2], [2, 0, -2], [2, 0, 2], [-2, 0, 2]]
    f = [[0, 2, 1], [0, 3, 2]]
    for k in range(n_tri):
        kind = kinds[k % len(kinds)]
        a = rng.uniform([-1, 0.1, -1], [1, 1.5, 1])
        b = a + rng.normal(size=3) * 0.5
        c = a + rng.normal(size=3) * 0.5
        i = len(v)
        if kind == "point":  # three identical positions: zero area
            v += [a, a, a]
        elif kind == "repeated_index":  # a face naming one vertex twice
            v += [a, b]
            f.append([i, i, i + 1])
            continue
        elif kind == "collinear":
            v += [a, b, a + 0.37 * (b - a)]
        elif kind == "needle":  # one edge 1e-7 long
            v += [a, a + rng.normal(size=3) * 1e-7, c]
        elif kind == "sliver":  # height 1e-6 over a long base
            m = 0.5 * (a + b)
            perp = np.cross(b - a, rng.normal(size=3))
            v += [a, b, m + perp / max(np.linalg.norm(perp), 1e-30) * 1e-6]
        elif kind == "dup_positions" and len(f) > 2:  # a copy of the last triangle with new indices
            j = f[-1]
            v += [v[j[0]], v[j[1]], v[j[2]]]
        elif kind == "dup_face" and len(f) > 2:  # the same face twice, and reversed
            f.append(list(f[-1]))
            f.append(list(reversed(f[-1])))
            continue
        elif kind == "huge":
            v += [a, a + rng.normal(size=3) * 1e3, a + rng.normal(size=3) * 1e3]
        else:
            v += [a, b, c]
        f.append([i, i + 1, i + 2])
    v = np.asarray(v, dtype=np.float64) * scale
    f = np.asarray(f, dtype=np.int64)
    nf = len(f)
    vn = rng.normal(size=v.shape)
    vn[rng.random(len(v)) < 0.3] = 0.0  # zero vertex normals on smooth faces: the face normal is used
    smooth = (rng.random(nf) < 0.5).astype(np.uint8)
    return v, f, rng.random((nf, 3)), vn, smooth


TRI_KINDS = ("normal", "point", "repeated_index", "collinear", "needle", "sliver", "dup_positions", "dup_face",
             "huge")


@examples(200, 1500)
@given(kinds=st.lists(st.sampled_from(TRI_KINDS), min_size=1, max_size=6), n_tri=st.integers(1, 60),
       seed=st.integers(0, 2**32 - 1), scale=st.sampled_from([1e-4, 1.0, 1e5]), config=configs(), size=sizes,
       light_on_vertex=st.booleans(), g=st.lists(gazes, min_size=2, max_size=2),
       bvh=st.sampled_from(["sah", "median", "lbvh"]))
def test_degenerate_and_sliver_triangles_duplicated_vertices(device, cases, kinds, n_tri, seed, scale, config, size,
                                                             light_on_vertex, g, bvh):
    """Triangle soups mixing zero-area triangles (three equal positions, a repeated index, collinear
    vertices), needles, slivers, duplicated vertices and faces (also reversed), huge triangles, zero smooth
    normals; a point light exactly on a vertex; every BVH builder: all frame outputs finite."""
    rng = np.random.default_rng(seed)
    v, f, alb, vn, smooth = _soup(rng, n_tri, kinds, scale)
    lp = tuple(v[f[-1][0]]) if light_on_vertex else (0.3 * scale, 2.0 * scale, 0.1 * scale)
    lights = [fw.Light(kind="point", position=lp, intensity=(4.0, 4.0, 4.0)),
              fw.Light(kind="spot", position=(0.0, 3.0 * scale, 0.0), direction=(0, -1, 0), cone_deg=70.0)]
    cam = fw.Camera(eye=tuple(np.array([0.5, 2.5, 3.5]) * scale), target=(0.0, 0.5 * scale, 0.0), fov_y_deg=50.0)
    scene = fw.Scene(vertices=v, faces=f, face_albedo=alb, vertex_normals=vn, face_smooth=smooth, lights=lights,
                     camera=cam, bvh_constructor=bvh)
    seq = [(cam, g[0]), (orbit(cam, 3.0), g[1])]
    n = run_frames(scene, seq, config, size, device, f"soup {kinds}")
    cases.add("degenerate / sliver triangles, duplicated vertices (frames)", n)


def _box_world(scale):
    b = SceneBuilder()
    b.add_quad((-2, 0, -2), (0, 0, 4), (4, 0, 0), (0.7, 0.7, 0.7))  # floor, y = 0, normal +y
    b.add_box((0.0, 1.0, 0.0), (1.0, 1.0, 1.0), (0.9, 0.3, 0.2))  # closed box [-0.5, 0.5] x [0.5, 1.5] x ...
    b.add_sphere((1.2, 0.6, -0.8), 0.5, n_lon=12, n_lat=9)
    sc = b.build(lights=[fw.Light(kind="spot", position=(0.0, 1.0, 0.0), direction=(0, -1, 0), cone_deg=80.0),
                         fw.Light(kind="point", position=(1.5, 2.5, 1.5))])
    return scaled(sc, scale) if scale != 1.0 else sc


@examples(150, 1000)
@given(where=st.sampled_from(["box_center", "box_corner", "on_box_face", "on_box_edge", "sphere_center",
                              "on_floor", "below_floor", "on_sphere_vertex"]),
       look=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(
           lambda d: 0.1 < np.linalg.norm(d)),
       scale=st.sampled_from([1e-4, 1.0, 1e5]), fov=st.sampled_from([1e-3, 30.0, 90.0, 179.0]), config=configs(),
       size=sizes, g=st.lists(gazes, min_size=2, max_size=2))
def test_camera_inside_geometry(device, cases, where, look, scale, fov, config, size, g):
    """The eye inside a closed box or a sphere, exactly on a face, an edge, a vertex, below the floor (every
    ray sees back faces or starts on a surface): all frame outputs finite (the spot light sits inside the
    box as well)."""
    scene = _box_world(scale)
    eye = {"box_center": (0.0, 1.0, 0.0), "box_corner": (0.49, 1.49, -0.49), "on_box_face": (0.5, 1.0, 0.1),
           "on_box_edge": (0.5, 1.5, 0.0), "sphere_center": (1.2, 0.6, -0.8), "on_floor": (0.3, 0.0, 0.7),
           "below_floor": (0.3, -1.0, 0.7), "on_sphere_vertex": (1.2, 1.1, -0.8)}[where]
    eye = np.asarray(eye) * scale
    d = np.asarray(look, dtype=np.float64)
    up = (0.0, 1.0, 0.0) if abs(d[1]) < 0.99 * np.linalg.norm(d) else (1.0, 0.0, 0.0)
    cam = fw.Camera(eye=tuple(eye), target=tuple(eye + d * scale), up=up, fov_y_deg=fov)
    cam2 = fw.Camera(eye=tuple(eye), target=tuple(eye + (d + [0.05, 0.0, 0.02]) * scale), up=up, fov_y_deg=fov)
    n = run_frames(scene, [(cam, g[0]), (cam2, g[1])], config, size, device, f"inside {where}")
    cases.add("camera inside geometry (frames)", n)


@examples(200, 1500)
@given(setup=st.sampled_from(["eye_in_floor_plane", "eye_in_wall_plane", "shared_edge", "shared_vertex",
                              "edge_extension", "light_in_plane", "light_on_surface"]),
       scale=st.sampled_from([1e-4, 1.0, 1e5]), fov=st.sampled_from([1e-4, 0.01, 10.0, 120.0]),
       size=st.sampled_from([(33, 25), (7, 3), (1, 1), (31, 1), (1, 31)]),
       yaw=st.one_of(st.sampled_from([0.0, 45.0, 90.0]), st.floats(0.0, 360.0)), config=configs(),
       g=st.lists(gazes, min_size=2, max_size=2))
def test_rays_grazing_edges_and_parallel_to_faces(device, cases, setup, scale, fov, size, yaw, config, g):
    """Odd image sizes put the middle pixel's ray exactly on the view axis: the eye in the floor's plane (the
    middle row runs parallel to it), aimed exactly at a shared quad diagonal or a fan's shared vertex
    (tiny fields of view keep every ray within a hair of it), along an edge's extension, and lights in a
    face's plane or on the surface (shadow rays parallel to / starting on faces): finite outputs."""
    b = SceneBuilder()
    b.add_quad((-1, 0, -1), (0, 0, 2), (2, 0, 0), (0.8, 0.8, 0.8))  # floor y = 0; diagonal (-1,0,-1)-(1,0,1)
    b.add_quad((-1, 0, -1), (2, 0, 0), (0, 1, 0), (0.3, 0.6, 0.9))  # wall z = -1
    fan_c = np.array([0.0, 0.5, 0.5])
    ring = [fan_c + 0.3 * np.array([math.cos(a), 0.0, math.sin(a)]) for a in np.linspace(0, 2 * math.pi, 7)[:-1]]
    b.add_mesh(np.array([fan_c] + ring), [[0, 1 + (k + 1) % 6, 1 + k] for k in range(6)], (0.9, 0.9, 0.2))
    a = math.radians(yaw)
    horiz = np.array([math.cos(a), 0.0, math.sin(a)])
    lights = [fw.Light(kind="point", position=(0.2, 1.5, 0.3), intensity=(3, 3, 3))]
    up = (0.0, 1.0, 0.0)
    if setup == "eye_in_floor_plane":
        eye, tgt = np.array([0.1, 0.0, 0.2]) - 3 * horiz, np.array([0.1, 0.0, 0.2])
    elif setup == "eye_in_wall_plane":
        eye, tgt = np.array([-3.0, 0.5, -1.0]), np.array([0.0, 0.5, -1.0])
    elif setup == "shared_edge":  # the floor's diagonal, seen from above at an angle
        tgt = np.array([0.25, 0.0, 0.25])
        eye = tgt + np.array([0.0, 1.0, 0.0]) + 0.7 * horiz
    elif setup == "shared_vertex":
        tgt = fan_c
        eye = fan_c + np.array([0.0, 1.5, 0.0]) + 0.4 * horiz
    elif setup == "edge_extension":  # along the floor's front edge z = 1, y = 0
        eye, tgt = np.array([-3.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0])
    elif setup == "light_in_plane":
        lights = [fw.Light(kind="point", position=(3.0, 0.0, 0.2), intensity=(3, 3, 3)),
                  fw.Light(kind="spot", position=(0.0, 0.5, -1.0), direction=(0, 0, 1), cone_deg=90.0)]
        eye, tgt = np.array([0.0, 1.5, 2.5]), np.array([0.0, 0.0, 0.0])
    else:  # light_on_surface: point lights exactly on the floor and on the fan centre
        lights = [fw.Light(kind="point", position=(0.1, 0.0, 0.1), intensity=(3, 3, 3)),
                  fw.Light(kind="point", position=tuple(fan_c), intensity=(1, 2, 3))]
        eye, tgt = np.array([0.0, 1.5, 2.5]), np.array([0.0, 0.0, 0.0])
    scene = scaled(b.build(lights=lights), scale)
    cam = fw.Camera(eye=tuple(eye * scale), target=tuple(tgt * scale), up=up, fov_y_deg=fov)
    cam2 = fw.Camera(eye=tuple(eye * scale), target=tuple((tgt + 1e-3 * horiz) * scale), up=up, fov_y_deg=fov)
    n = run_frames(scene, [(cam, g[0]), (cam2, g[1])], config, size, device, f"grazing {setup}")
    cases.add("rays grazing edges / parallel to faces (frames)", n)
