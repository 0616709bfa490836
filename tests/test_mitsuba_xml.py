"""The Mitsuba scene reader (foveawarp.io.mitsuba): small scenes written in tmp_path, checked against NumPy
matrices composed here, against Mitsuba 3 itself (variant scalar_rgb: the sensor's transform, field of view and
ray directions, the shapes' bounding boxes and UVs, a conductor's reflectance) and against the documented
material mapping; the Grey & White Room from the shared scenes folder when it is there."""

from __future__ import annotations

import math
import struct
import warnings
import zlib

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

import foveawarp as fw
from foveawarp import meshio
from foveawarp.io.mitsuba import CONDUCTOR_F0, fov_y_deg, mitsuba_transform, read_mitsuba

mi = pytest.importorskip("mitsuba")
mi.set_variant("scalar_rgb")


def _png(path, rgba: np.ndarray) -> None:
    """Write an 8-bit RGBA PNG (zlib + struct, no image library)."""
    h, w, _ = rgba.shape
    raw = b"".join(b"\x00" + rgba[y].astype(np.uint8).tobytes() for y in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def _scene(tmp_path, body: str, version: str = "3.0.0", name: str = "scene.xml"):
    p = tmp_path / name
    p.write_text(f'<?xml version="1.0"?>\n<scene version="{version}">\n{body}\n</scene>\n')
    return p


def _read(p, **kw):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        d = read_mitsuba(p, **kw)
    return d, [str(x.message) for x in w]


def _shape_arrays(d, i):
    s = d.shapes[i]
    a, b = s.vertex_range
    t0, t1 = s.triangle_range
    return d.vertices[a:b].astype(np.float64), d.triangles[t0:t1] - a, d.uvs[a:b], d.normals[a:b]


# --------------------------------------------------------------------------------------------------------------
# transforms


def _np_rotate(axis, angle_deg):
    m = np.eye(4)
    rotvec = np.asarray(axis, float) / np.linalg.norm(axis) * math.radians(angle_deg)
    m[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    return m


def _np_translate(t):
    m = np.eye(4)
    m[:3, 3] = t
    return m


def _np_look_at(o, t, up):
    o, t, up = (np.asarray(x, float) for x in (o, t, up))
    z = (t - o) / np.linalg.norm(t - o)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.block([[np.stack([x, y, z, o], axis=1)], [np.array([[0.0, 0.0, 0.0, 1.0]])]])


def test_transform_ops_compose_in_mitsuba_order():
    xml = ('<transform name="to_world"><scale x="2" y="0.5" z="3"/><rotate x="0.3" y="1" z="-0.2" angle="37"/>'
           '<translate x="1" y="-2" z="0.5"/><matrix value="1 0 0 0.25  0 0 -1 0  0 1 0 0  0 0 0 1"/>'
           '<scale value="1.5"/></transform>')
    m = mitsuba_transform(xml)
    ref = (np.diag([1.5, 1.5, 1.5, 1.0]) @ np.array([[1, 0, 0, 0.25], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1.0]])
           @ _np_translate([1, -2, 0.5]) @ _np_rotate([0.3, 1, -0.2], 37) @ np.diag([2.0, 0.5, 3.0, 1.0]))
    np.testing.assert_allclose(m, ref, atol=1e-12)
    la = mitsuba_transform('<transform name="to_world"><lookat origin="1, 2, 3" target="0,0,0" up="0 1 0"/>'
                           '</transform>')
    np.testing.assert_allclose(la, _np_look_at([1, 2, 3], [0, 0, 0], [0, 1, 0]), atol=1e-12)
    # version 0.5 spelling of the tag, 3x3 matrices and the value form of translate
    m2 = mitsuba_transform('<transform name="toWorld"><lookAt origin="0 0 0" target="0 0 -1" up="0 1 0"/>'
                           '<translate value="0 1 0"/><matrix value="2 0 0 0 2 0 0 0 2"/></transform>')
    np.testing.assert_allclose(m2, np.diag([2.0, 2, 2, 1]) @ _np_translate([0, 1, 0])
                               @ _np_look_at([0, 0, 0], [0, 0, -1], [0, 1, 0]), atol=1e-12)


_unit3 = st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 0.2).map(
    lambda v: tuple(float(c) for c in np.asarray(v) / np.linalg.norm(v)))
_ops = st.one_of(
    st.tuples(st.just("translate"), st.tuples(*[st.floats(-5, 5)] * 3)),
    st.tuples(st.just("scale"), st.tuples(*[st.floats(0.2, 3)] * 3)),
    st.tuples(st.just("rotate"), st.tuples(_unit3, st.floats(-180, 180))),
    st.tuples(st.just("lookat"), st.tuples(st.tuples(*[st.floats(-3, 3)] * 3), _unit3)),
)


def _op_xml(kind, a) -> str:
    if kind == "translate":
        return '<translate x="{!r}" y="{!r}" z="{!r}"/>'.format(*a)
    if kind == "scale":
        return '<scale x="{!r}" y="{!r}" z="{!r}"/>'.format(*a)
    if kind == "rotate":
        (x, y, z), ang = a
        return f'<rotate x="{x!r}" y="{y!r}" z="{z!r}" angle="{ang!r}"/>'
    o, d = a
    t = [float(c) for c in np.asarray(o) + np.asarray(d)]
    up = (0.0, 0.0, 1.0) if abs(d[1]) > 0.9 else (0.0, 1.0, 0.0)
    return (f'<lookat origin="{o[0]!r}, {o[1]!r}, {o[2]!r}" target="{t[0]!r}, {t[1]!r}, {t[2]!r}" '
            f'up="{up[0]}, {up[1]}, {up[2]}"/>')


@settings(max_examples=20, deadline=None)
@given(st.lists(_ops, min_size=1, max_size=4))
def test_random_transforms_match_mitsubas_composition(ops):
    xml = '<transform name="to_world">' + "".join(_op_xml(k, a) for k, a in ops) + "</transform>"
    ours = mitsuba_transform(xml)
    shape = mi.load_string(f'<scene version="3.0.0"><shape type="rectangle">{xml}</shape></scene>').shapes()[0]
    ref = np.array(mi.traverse(shape)["to_world"].matrix, dtype=np.float64)
    np.testing.assert_allclose(ours, ref, atol=1e-4 * max(1.0, float(np.abs(ref).max())))


def test_shape_transforms_and_bounding_boxes_match_mitsuba(tmp_path):
    (tmp_path / "tet.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 2 0\nv 0 0 3\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    (tmp_path / "tri.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                      "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                                      "end_header\n0 0 0\n2 0 0\n0 1 1\n3 0 1 2\n")
    # unit rotation axes: Mitsuba 3 takes the axis as given, this reader normalizes it
    tf = ('<transform name="to_world"><scale x="0.7" y="1.3" z="0.9"/><rotate x="0.6" y="0" z="0.8" angle="{a}"/>'
          '<translate x="{t}" y="0.4" z="-1"/></transform>')
    # a sphere takes a uniform scale only (Mitsuba keeps it a sphere)
    tf_sphere = ('<transform name="to_world"><scale value="0.8"/><rotate x="0" y="0.6" z="0.8" angle="75"/>'
                 '<translate x="-3" y="0.4" z="-1"/></transform>')
    body = "\n".join([
        f'<shape type="rectangle" id="s0">{tf.format(a=30, t=0.1)}</shape>',
        f'<shape type="cube" id="s1">{tf.format(a=-50, t=2)}</shape>',
        f'<shape type="sphere" id="s2"><point name="center" x="0.5" y="-1" z="2"/><float name="radius" value="1.5"/>'
        f'{tf_sphere}</shape>',
        f'<shape type="disk" id="s3">{tf.format(a=15, t=4)}</shape>',
        f'<shape type="obj" id="s4"><string name="filename" value="tet.obj"/>{tf.format(a=120, t=6)}</shape>',
        f'<shape type="ply" id="s5"><string name="filename" value="tri.ply"/>{tf.format(a=-20, t=8)}</shape>',
    ])
    p = _scene(tmp_path, body)
    d, _ = _read(p)
    ref = mi.load_file(str(p))
    assert [s.kind for s in d.shapes] == ["rectangle", "cube", "sphere", "disk", "obj", "ply"]
    assert sorted(sh.id() for sh in ref.shapes()) == [f"s{i}" for i in range(6)]
    for sh in ref.shapes():
        i = int(sh.id()[1:])
        assert d.shapes[i].name == sh.id()
        bb = sh.bbox()
        lo, hi = np.array(bb.min, dtype=np.float64), np.array(bb.max, dtype=np.float64)
        v, _, _, _ = _shape_arrays(d, i)
        size = float(np.max(hi - lo))
        # meshes exactly; the tessellated sphere and disk within their facets (0.3 % of the size)
        tol = 3e-3 * size if d.shapes[i].kind in ("sphere", "disk") else 1e-5 * size
        np.testing.assert_allclose(v.min(axis=0), lo, atol=tol, err_msg=d.shapes[i].kind)
        np.testing.assert_allclose(v.max(axis=0), hi, atol=tol, err_msg=d.shapes[i].kind)
        # the tessellation lies within the true shape's box
        assert (v.min(axis=0) >= lo - 1e-5 * size).all() and (v.max(axis=0) <= hi + 1e-5 * size).all()


def _ray_triangles(o, dvec, v, f):
    """Brute-force nearest hit (t, triangle, b1, b2) of one ray against triangles (Moller-Trumbore in NumPy)."""
    p0, p1, p2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    pv = np.cross(dvec, e2)
    det = np.einsum("ij,ij->i", e1, pv)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - p0
    b1 = np.einsum("ij,ij->i", s, pv) * inv
    q = np.cross(s, e1)
    b2 = (q @ dvec) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > 1e-9)
    if not hit.any():
        return None
    i = int(np.argmin(np.where(hit, t, np.inf)))
    return t[i], i, b1[i], b2[i]


@pytest.mark.parametrize("kind, tol", [("rectangle", 1e-5), ("sphere", 1.5e-2), ("disk", 1.5e-2)])
def test_shape_uvs_match_mitsuba(tmp_path, kind, tol):
    extra = '<float name="radius" value="1.2"/>' if kind == "sphere" else ""
    body = (f'<shape type="{kind}">{extra}<transform name="to_world"><rotate x="1" angle="-60"/>'
            f'<translate y="0.2"/></transform></shape>')
    p = _scene(tmp_path, body)
    d, _ = _read(p)
    ref = mi.load_file(str(p))
    v, f, uv, _ = _shape_arrays(d, 0)
    rng = np.random.default_rng(4)
    n = 0
    for _ in range(40):
        o = np.array([rng.uniform(-0.8, 0.8), 5.0, rng.uniform(-0.8, 0.8)])
        dvec = np.array([0.0, -1.0, 0.05])
        dvec /= np.linalg.norm(dvec)
        si = ref.ray_intersect(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*dvec)))
        ours = _ray_triangles(o, dvec, v, f)
        if not si.is_valid() or ours is None:
            continue
        _, tri, b1, b2 = ours
        u = (1 - b1 - b2) * uv[f[tri, 0]] + b1 * uv[f[tri, 1]] + b2 * uv[f[tri, 2]]
        ru = np.array([si.uv[0], si.uv[1]])
        du = np.abs(u - ru)
        if kind == "sphere":
            du[0] = min(du[0], 1.0 - du[0])  # u is periodic
        if kind == "disk" and si.uv[0] < 0.1:
            continue  # the angle is ill-defined near the centre
        assert du.max() < tol, (kind, u, ru)
        n += 1
    assert n >= 10


@pytest.mark.parametrize("kind", ["sphere", "cube", "disk", "rectangle"])
def test_primitives_are_closed_with_the_right_area(tmp_path, kind):
    d, _ = _read(_scene(tmp_path, f'<shape type="{kind}"/>'))
    v, f, _, nrm = _shape_arrays(d, 0)
    p = v[f]
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert (np.linalg.norm(cross, axis=1) > 0).all()  # no degenerate triangles
    area = 0.5 * np.linalg.norm(cross, axis=1).sum()
    exact = {"sphere": 4 * math.pi, "cube": 24.0, "disk": math.pi, "rectangle": 4.0}[kind]
    assert area == pytest.approx(exact, rel=2e-3 if kind in ("sphere", "disk") else 1e-12)
    mesh = trimesh.Trimesh(v, f, process=True)  # merges the seams' duplicated vertices
    if kind in ("sphere", "cube"):
        assert mesh.is_watertight and mesh.is_winding_consistent
        assert mesh.volume > 0  # outward winding
    # the winding agrees with the normals
    assert (np.einsum("ij,ij->i", cross, nrm[f].mean(axis=1)) > 0).all()


def test_cube_matches_mitsubas_mesh(tmp_path):
    p = _scene(tmp_path, '<shape type="cube"/>')
    d, _ = _read(p)
    v, f, uv, nrm = _shape_arrays(d, 0)
    ref = mi.traverse(mi.load_dict({"type": "cube"}))
    rv = np.array(ref["vertex_positions"], dtype=np.float64).reshape(-1, 3)
    rf = np.array(ref["faces"]).reshape(-1, 3)

    def face_corners(vv, ff):  # each face's corner set (the two readers split the quads differently)
        out = {}
        for t in ff:
            c = vv[t]
            n = tuple(np.round(np.cross(c[1] - c[0], c[2] - c[0]) / 4.0, 6))
            out.setdefault(n, set()).update(tuple(np.round(x, 6)) for x in c)
        return out

    assert face_corners(v, f) == face_corners(rv, rf)
    assert len(f) == len(rf) == 12
    # counter-clockwise seen from outside, normals outward, every face's UVs span [0, 1]^2
    tv = v[f]
    geo = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
    assert (np.einsum("ij,ij->i", geo, tv.mean(axis=1)) > 0).all()
    np.testing.assert_allclose(np.abs(nrm).max(axis=1), 1.0)
    assert uv.min() == 0.0 and uv.max() == 1.0


@pytest.mark.parametrize("flip", [False, True])
def test_negative_radius_turns_the_sphere_inward_as_mitsuba_does(tmp_path, flip):
    """A sphere of radius -0.5 (with and without flip_normals): the same surface as radius 0.5, its shading normals
    and winding against the ones Mitsuba 3 reports where rays along the axes hit it."""
    fl = '<boolean name="flip_normals" value="true"/>' if flip else ""
    p = _scene(tmp_path, f'<shape type="sphere"><point name="center" x="1" y="2" z="3"/>'
                         f'<float name="radius" value="-0.5"/>{fl}</shape>')
    d, _ = _read(p)
    v, f, _, nrm = _shape_arrays(d, 0)
    c = np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(np.linalg.norm(v - c, axis=1), 0.5, rtol=1e-6)
    outward = np.einsum("ij,ij->i", nrm, v - c) > 0
    geo = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    geo_out = np.einsum("ij,ij->i", geo, v[f].mean(axis=1) - c) > 0
    assert outward.all() == flip and (~outward).all() == (not flip)
    assert geo_out.all() == flip and (~geo_out).all() == (not flip)
    mi.set_variant("scalar_rgb")
    ms = mi.load_file(str(p))
    for axis in range(3):
        o = c.copy()
        o[axis] += 5.0
        dvec = np.zeros(3)
        dvec[axis] = -1.0
        si = ms.ray_intersect(mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*dvec)))
        assert si.is_valid()
        assert (float(np.dot(np.array(si.n), np.array(si.p) - c)) > 0) == flip


# --------------------------------------------------------------------------------------------------------------
# the sensor against Mitsuba 3


@pytest.mark.parametrize("axis", ["x", "y", "diagonal", "smaller", "larger"])
@pytest.mark.parametrize("size", [(64, 36), (30, 50)])
def test_sensor_rays_match_mitsuba(tmp_path, axis, size):
    w, h = size
    body = (f'<sensor type="perspective"><float name="fov" value="52"/><string name="fov_axis" value="{axis}"/>'
            f'<transform name="to_world"><lookat origin="1, 2, 3" target="-0.5, 0.3, 0" up="0.1, 1, 0"/>'
            f'</transform><film type="hdrfilm"><integer name="width" value="{w}"/>'
            f'<integer name="height" value="{h}"/></film></sensor>')
    p = _scene(tmp_path, body)
    d, _ = _read(p)
    assert d.film_size == (w, h) and d.camera is not None and len(d.cameras) == 1
    s = mi.load_file(str(p)).sensors()[0]
    x_fov = float(mi.traverse(s)["x_fov"])
    np.testing.assert_allclose(math.degrees(d.camera.fov_x_rad()), x_fov, rtol=1e-5)
    np.testing.assert_allclose(d.camera.fov_y_deg, fov_y_deg(52.0, axis, w / h), rtol=1e-12)
    m = np.array(s.world_transform().matrix, dtype=np.float64)
    np.testing.assert_allclose(d.camera.eye, m[:3, 3], atol=1e-5)
    np.testing.assert_allclose(d.camera.forward, m[:3, 2] / np.linalg.norm(m[:3, 2]), atol=1e-5)
    cam = fw.Camera(**d.camera.camera_kwargs())
    px, py = np.meshgrid(np.linspace(0.5, w - 0.5, 5), np.linspace(0.5, h - 0.5, 4))
    ours = cam.ray_dirs(px.ravel(), py.ravel(), w, h)
    for (x, y), dv in zip(zip(px.ravel(), py.ravel()), ours):
        ray, _ = s.sample_ray(0.0, 0.5, mi.Point2f(x / w, y / h), mi.Point2f(0.5, 0.5))
        np.testing.assert_allclose(dv, np.array(ray.d, dtype=np.float64), atol=2e-5)


def test_sensor_matrix_version_05_names_and_defaults(tmp_path):
    mat = ("0.264209 0.071763 -0.961792 5.10518 0 0.997228 0.074407 0.731065 0.964465 -0.019659 0.263476 -2.31789 "
           "0 0 0 1")
    body = (f'<sensor type="perspective"><float name="fov" value="90"/><string name="fovAxis" value="y"/>'
            f'<float name="nearClip" value="0.05"/><transform name="toWorld"><matrix value="{mat}"/></transform>'
            f'</sensor>')
    d, _ = _read(_scene(tmp_path, body, version="0.5.0"))
    assert d.film_size == (768, 576)  # Mitsuba's default film
    np.testing.assert_allclose(d.camera.fov_y_deg, 90.0)
    assert d.camera.znear == pytest.approx(0.05)
    m = np.array(mat.split(), dtype=float).reshape(4, 4)
    np.testing.assert_allclose(d.camera.eye, m[:3, 3])
    np.testing.assert_allclose(d.camera.forward, m[:3, 2] / np.linalg.norm(m[:3, 2]), atol=1e-12)
    # no fov: a 50 mm lens on a 36 mm wide film
    d2, _ = _read(_scene(tmp_path, '<sensor type="perspective"/>', name="b.xml"))
    np.testing.assert_allclose(math.degrees(d2.camera.fov_x_rad()), math.degrees(2 * math.atan(18 / 50)), rtol=1e-9)


# --------------------------------------------------------------------------------------------------------------
# BSDFs


def _material(tmp_path, bsdf_xml: str, version="3.0.0", files=()):
    p = _scene(tmp_path, f'{bsdf_xml}<shape type="rectangle"><ref id="m"/></shape>', version=version)
    d, msgs = _read(p)
    assert len(d.materials) == 1 and (d.material_ids == 0).all()
    return d.materials[0], d, msgs


def test_diffuse_plastic_and_twosided(tmp_path):
    m, _, msgs = _material(tmp_path, '<bsdf type="diffuse" id="m"><rgb name="reflectance" value="0.2, 0.4, 0.6"/>'
                                     '</bsdf>')
    assert m.name == "m" and m.base_color_factor == (0.2, 0.4, 0.6, 1.0)
    assert (m.metallic_factor, m.roughness_factor, m.double_sided) == (0.0, 1.0, False) and not msgs
    m, _, _ = _material(tmp_path, '<bsdf type="twosided" id="m"><bsdf type="roughplastic">'
                                  '<float name="alpha" value="0.09"/><srgb name="diffuse_reflectance" value="#808080"/>'
                                  '<float name="int_ior" value="1.5"/></bsdf></bsdf>')
    lin = ((128 / 255 + 0.055) / 1.055) ** 2.4
    np.testing.assert_allclose(m.base_color_factor, (lin, lin, lin, 1.0), rtol=1e-6)
    assert m.roughness_factor == pytest.approx(0.3) and m.metallic_factor == 0.0 and m.double_sided
    m, _, _ = _material(tmp_path, '<bsdf type="plastic" id="m"/>')
    assert m.base_color_factor == (0.5, 0.5, 0.5, 1.0) and m.roughness_factor == 0.0
    # version 0.5 camelCase names, a spectrum of one value
    m, _, _ = _material(tmp_path, '<bsdf type="roughplastic" id="m"><spectrum name="diffuseReflectance" '
                                  'value="0.25"/><float name="alpha" value="0.25"/></bsdf>', version="0.5.0")
    assert m.base_color_factor == (0.25, 0.25, 0.25, 1.0) and m.roughness_factor == pytest.approx(0.5)


def test_principled(tmp_path):
    m, _, msgs = _material(tmp_path, '<bsdf type="principled" id="m"><rgb name="base_color" value="0.3, 0.5, 0.7"/>'
                                     '<float name="metallic" value="0.25"/><float name="roughness" value="0.6"/>'
                                     '<float name="clearcoat" value="0.5"/></bsdf>')
    assert m.base_color_factor == (0.3, 0.5, 0.7, 1.0) and (m.metallic_factor, m.roughness_factor) == (0.25, 0.6)
    assert not msgs
    m, _, _ = _material(tmp_path, '<bsdf type="principled" id="m"/>')
    assert (m.base_color_factor, m.metallic_factor, m.roughness_factor) == ((0.5, 0.5, 0.5, 1.0), 0.0, 0.5)


def _mitsuba_f0(props: dict) -> np.ndarray:
    b = mi.load_dict(props)
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    _, w = b.sample(mi.BSDFContext(), si, 0.5, mi.Point2f(0.5, 0.5))
    return np.array(w, dtype=np.float64)


def test_conductors_against_mitsuba(tmp_path):
    m, _, _ = _material(tmp_path, '<bsdf type="roughconductor" id="m"><float name="alpha" value="0.04"/>'
                                  '<rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.9, 2.4, 2.2"/>'
                                  '<rgb name="specular_reflectance" value="0.9, 0.8, 1"/></bsdf>')
    ref = _mitsuba_f0({"type": "conductor", "eta": {"type": "rgb", "value": [0.2, 0.9, 1.1]},
                       "k": {"type": "rgb", "value": [3.9, 2.4, 2.2]},
                       "specular_reflectance": {"type": "rgb", "value": [0.9, 0.8, 1.0]}})
    np.testing.assert_allclose(m.base_color_factor[:3], ref, rtol=1e-5)
    assert m.metallic_factor == 1.0 and m.roughness_factor == pytest.approx(0.2)
    for name in ("Au", "Cu", "Al", "Ag", "Cr"):
        m, _, _ = _material(tmp_path, f'<bsdf type="conductor" id="m"><string name="material" value="{name}"/></bsdf>')
        np.testing.assert_allclose(m.base_color_factor[:3], _mitsuba_f0({"type": "conductor", "material": name}),
                                   atol=6e-4, err_msg=name)  # the table's 3 decimals
        assert m.roughness_factor == 0.0
    # the default named material: Cu before version 2, a perfect mirror from version 2 on
    m05, _, _ = _material(tmp_path, '<bsdf type="conductor" id="m"/>', version="0.5.0")
    m3, _, _ = _material(tmp_path, '<bsdf type="conductor" id="m"/>')
    assert m05.base_color_factor[:3] == CONDUCTOR_F0["Cu"] and m3.base_color_factor[:3] == (1.0, 1.0, 1.0)
    ma, _, msgs = _material(tmp_path, '<bsdf type="roughconductor" id="m"><float name="alpha_u" value="0.01"/>'
                                      '<float name="alpha_v" value="0.16"/></bsdf>')
    assert ma.roughness_factor == pytest.approx(math.sqrt(0.04)) and "anisotropic" in msgs[0]


def test_dielectrics_become_glass_with_a_note(tmp_path):
    """dielectric: smooth glass (transmission 1) with the relative index of refraction int_ior / ext_ior (numbers,
    named media, Mitsuba's defaults bk7 / air), tinted by specular_transmittance, double-sided; the note says the
    direct integrator shows its reflection only. thindielectric: a cut-out. roughdielectric: glass of roughness
    sqrt(alpha) (default alpha 0.1)."""
    m, d, msgs = _material(tmp_path, '<bsdf type="dielectric" id="m"><float name="int_ior" value="1.5"/></bsdf>')
    assert m.transmission_factor == 1.0 and m.ior == pytest.approx(1.5 / 1.000277) and m.double_sided
    assert m.base_color_factor == (1.0, 1.0, 1.0, 1.0) and m.roughness_factor == 0.0
    assert len(msgs) == 1 and "dielectric" in msgs[0] and "reflection only" in d.warnings[0]
    m, _, _ = _material(tmp_path, '<bsdf type="dielectric" id="m"><string name="int_ior" value="water"/>'
                                  '<string name="ext_ior" value="vacuum"/>'
                                  '<rgb name="specular_transmittance" value="0.5, 0.8, 1"/></bsdf>')
    assert m.ior == pytest.approx(1.333) and m.base_color_factor == pytest.approx((0.5, 0.8, 1.0, 1.0))
    m, _, _ = _material(tmp_path, '<bsdf type="dielectric" id="m"/>')
    assert m.ior == pytest.approx(1.5046 / 1.000277)
    m, _, msgs = _material(tmp_path, '<bsdf type="dielectric" id="m"><string name="int_ior" value="unobtainium"/>'
                                     '</bsdf>')
    assert m.ior == pytest.approx(1.5046 / 1.000277) and "unobtainium" in msgs[0]
    m, _, msgs = _material(tmp_path, '<bsdf type="thindielectric" id="m"/>')
    assert m.alpha_mode == "MASK" and m.base_color_factor[3] == 0.0 and "thindielectric" in msgs[0]
    assert m.transmission_factor == 0.0
    m, _, msgs = _material(tmp_path, '<bsdf type="roughdielectric" id="m"><float name="alpha" value="0.36"/>'
                                     '</bsdf>')
    assert m.roughness_factor == pytest.approx(0.6) and m.transmission_factor == 1.0 and m.double_sided
    assert len(msgs) == 1 and "reflection only" in msgs[0]
    m, _, _ = _material(tmp_path, '<bsdf type="roughdielectric" id="m"/>')
    assert m.roughness_factor == pytest.approx(math.sqrt(0.1))
    with pytest.raises(ValueError, match="index of refraction must be > 0"):
        _material(tmp_path, '<bsdf type="dielectric" id="m"><float name="int_ior" value="-1"/></bsdf>')


def test_bitmaps_masks_and_normal_maps(tmp_path):
    img = np.zeros((4, 4, 4), dtype=np.uint8)
    img[..., 0] = 200
    img[..., 3] = np.array([[0, 255, 255, 0]] * 4)
    _png(tmp_path / "leaf.png", img)
    nm = np.full((2, 2, 4), 255, dtype=np.uint8)
    nm[..., :3] = (128, 128, 255)
    _png(tmp_path / "n.png", nm)
    bsdf = ('<bsdf type="mask" id="m"><texture name="opacity" type="bitmap"><string name="filename" value="leaf.png"/>'
            '</texture><bsdf type="normalmap"><texture name="normalmap" type="bitmap">'
            '<boolean name="raw" value="true"/>'
            '<string name="filename" value="n.png"/></texture><bsdf type="twosided"><bsdf type="diffuse">'
            '<texture name="reflectance" type="bitmap"><string name="filename" value="leaf.png"/>'
            '<string name="filter_type" value="nearest"/><string name="wrap_mode" value="mirror"/>'
            '<transform name="to_uv"><scale x="2" y="3"/><translate x="0.5" y="0.25"/></transform>'
            '</texture></bsdf></bsdf></bsdf></bsdf>')
    m, d, msgs = _material(tmp_path, bsdf)
    assert not msgs
    t = m.base_color_texture
    assert t is not None and d.images[t.image].path.name == "leaf.png" and t.color_space == "srgb"
    assert (t.filter, t.wrap_s, t.wrap_t) == ("nearest", "mirror", "mirror")
    np.testing.assert_allclose(t.transform_uv([[0.1, 0.2]]), [[0.1 * 2 + 0.5, 0.2 * 3 + 0.25]])
    assert m.alpha_mode == "MASK" and m.alpha_cutoff == 0.5 and m.double_sided
    assert m.normal_texture is not None and d.images[m.normal_texture.image].path.name == "n.png"
    assert len(d.images) == 2  # leaf.png once
    # version 0.5: wrapModeU/V and the u/v scale and offset; a constant opacity
    m, _, msgs = _material(tmp_path, '<bsdf type="mask" id="m"><float name="opacity" value="0.3"/>'
                                     '<bsdf type="diffuse"><texture name="reflectance" type="bitmap">'
                                     '<string name="filename" value="leaf.png"/>'
                                     '<string name="wrapModeU" value="clamp"/>'
                                     '<float name="uscale" value="4"/><float name="voffset" value="0.5"/></texture>'
                                     '</bsdf></bsdf>', version="0.5.0")
    t = m.base_color_texture
    assert (t.wrap_s, t.wrap_t) == ("clamp", "repeat")
    np.testing.assert_allclose(t.transform_uv([[0.25, 0.25]]), [[1.0, 0.75]])
    assert m.alpha_mode == "BLEND" and m.base_color_factor[3] == pytest.approx(0.3) and not msgs
    # a bump map's height texture is dropped, named in the warning
    m, d, msgs = _material(tmp_path, '<bsdf type="bumpmap" id="m"><texture type="bitmap"><string name="filename" '
                                     'value="leaf.png"/></texture><bsdf type="diffuse"/></bsdf>')
    assert m.normal_texture is None and any("bumpmap" in w for w in d.warnings) and len(msgs) == 1


# --------------------------------------------------------------------------------------------------------------
# parameters, references, includes


def test_defaults_params_refs_and_includes(tmp_path):
    (tmp_path / "part.xml").write_text('<scene version="3.0.0"><bsdf type="diffuse" id="red">'
                                       '<rgb name="reflectance" value="$col"/></bsdf></scene>')
    body = ('<default name="col" value="0.9, 0.1, 0.1"/><default name="r" value="2"/>'
            '<include filename="part.xml"/>'
            '<shape type="sphere" id="ball"><float name="radius" value="$r"/><ref id="red"/></shape>'
            '<shape type="rectangle"><ref name="bsdf" id="red"/></shape>')
    p = _scene(tmp_path, body)
    d, msgs = _read(p)
    assert not msgs and len(d.materials) == 1 and d.materials[0].base_color_factor == (0.9, 0.1, 0.1, 1.0)
    assert d.shapes[0].name == "ball"
    v, _, _, _ = _shape_arrays(d, 0)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 2.0, rtol=1e-6)
    d2, _ = _read(p, params={"r": "0.5", "col": "0.2 0.3 0.4"})
    assert d2.materials[0].base_color_factor == (0.2, 0.3, 0.4, 1.0)
    np.testing.assert_allclose(np.abs(d2.vertices[: d2.shapes[0].vertex_range[1]]).max(), 0.5, rtol=1e-6)


# --------------------------------------------------------------------------------------------------------------
# emitters


def test_emitters(tmp_path):
    (tmp_path / "sky.hdr").write_bytes(b"#?RADIANCE\n")  # only its presence is checked when the scene is read
    body = ('<shape type="rectangle"><bsdf type="diffuse"/><emitter type="area"><rgb name="radiance" '
            'value="4, 2, 1"/></emitter></shape>'
            '<shape type="rectangle"><transform name="to_world"><translate z="-3"/></transform></shape>'
            '<emitter type="point"><point name="position" x="1" y="2" z="3"/><rgb name="intensity" value="10, 5, 0"/>'
            '</emitter>'
            '<emitter type="spot"><transform name="to_world"><lookat origin="0,4,0" target="0,0,0" up="0,0,1"/>'
            '</transform><float name="intensity" value="7"/><float name="cutoff_angle" value="30"/></emitter>'
            '<emitter type="directional"><vector name="direction" x="0" y="-1" z="-1"/>'
            '<spectrum name="irradiance" value="3"/></emitter>'
            '<emitter type="envmap"><string name="filename" value="sky.hdr"/><float name="scale" value="2"/>'
            '<transform name="to_world"><rotate y="1" angle="90"/></transform></emitter>')
    d, msgs = _read(_scene(tmp_path, body))
    assert not msgs
    emit = [m for m in d.materials if max(m.emission) > 0]
    assert len(emit) == 1 and emit[0].emission == pytest.approx((4.0, 2.0, 1.0))
    np.testing.assert_array_equal(d.emissive_triangles, [0, 1])
    pt, spot, sun = d.lights
    assert pt.kind == "point" and pt.position == (1, 2, 3) and pt.radiant == pytest.approx((10, 5, 0))
    assert spot.kind == "spot" and spot.direction == pytest.approx((0, -1, 0)) and spot.intensity == 7
    assert spot.outer_cone_rad == pytest.approx(math.radians(30)) and spot.inner_cone_rad == pytest.approx(
        math.radians(22.5)) and spot.spot_falloff == "linear_angle"
    assert sun.kind == "directional" and sun.direction == pytest.approx((0, -2 ** -0.5, -2 ** -0.5))
    assert sun.radiant == pytest.approx((3, 3, 3))
    env = d.environment
    assert env.image.name == "sky.hdr" and env.scale == 2.0
    np.testing.assert_allclose(env.to_world, _np_rotate([0, 1, 0], 90)[:3, :3], atol=1e-12)
    # a constant environment is a 1 x 1 map
    d2, _ = _read(_scene(tmp_path, '<shape type="disk"/><emitter type="constant"><rgb name="radiance" '
                                   'value="0.5, 1, 2"/></emitter>', name="c.xml"))
    assert d2.environment.is_constant
    np.testing.assert_allclose(d2.environment.image[0, 0], [0.5, 1, 2])


# --------------------------------------------------------------------------------------------------------------
# errors and unsupported content


@pytest.mark.parametrize("body, version, what", [
    ('<shape type="obj"><string name="filename" value="nope.obj"/></shape>', "3.0.0", "nope.obj"),
    ('<shape type="rectangle"><bsdf type="diffuse"><texture name="reflectance" type="bitmap">'
     '<string name="filename" value="gone.png"/></texture></bsdf></shape>', "3.0.0", "gone.png"),
    ('<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>', "3.0.0", "sky.exr"),
    ('<include filename="other.xml"/>', "3.0.0", "other.xml"),
    ('<shape type="rectangle"><ref id="nothing"/></shape>', "3.0.0", "'nothing'"),
    ('<shape type="sphere"><float name="radius" value="$rad"/></shape>', "3.0.0", "$rad"),
    ('<shape type="disk"/>', "1.0.0", "version '1.0.0'"),
    ('<shape type="disk"/>', "0.4.0", "version '0.4.0'"),
    ('<shape type="sphere"><float name="radius" value="big"/></shape>', "3.0.0", "'big'"),
    ('<shape type="disk"><bsdf type="roughconductor"><float name="alpha" value="-0.2"/></bsdf></shape>', "3.0.0",
     "alpha must be >= 0, got -0.2"),
    ('<shape type="disk"><bsdf type="roughplastic"><float name="alpha_u" value="0.1"/>'
     '<float name="alpha_v" value="-1"/></bsdf></shape>', "3.0.0", "alpha_u and alpha_v must be >= 0"),
])
def test_errors_name_the_file_and_what_was_wrong(tmp_path, body, version, what):
    p = _scene(tmp_path, body, version=version)
    with pytest.raises(ValueError) as e:
        read_mitsuba(p)
    assert str(p) in str(e.value) and what in str(e.value)


def test_malformed_and_versionless_files(tmp_path):
    p = tmp_path / "bad.xml"
    p.write_text('<scene version="3.0.0"><shape type="disk"></scene>')
    with pytest.raises(ValueError, match="malformed XML"):
        read_mitsuba(p)
    p.write_text('<scene><shape type="disk"/></scene>')
    with pytest.raises(ValueError, match="no version"):
        read_mitsuba(p)
    with pytest.raises(ValueError, match="does not exist"):
        read_mitsuba(tmp_path / "absent.xml")
    with pytest.raises(ValueError, match="could not be read as a Mitsuba scene"):
        fw.load_scene(str(p))


def test_unsupported_content_is_named_in_one_warning(tmp_path):
    body = ('<integrator type="path"/><medium type="homogeneous" id="fog"/>'
            '<shape type="cylinder"/><shape type="disk"><bsdf type="hair"/></shape>'
            '<shape type="rectangle"><bsdf type="diffuse"><texture name="reflectance" type="checkerboard"/>'
            '<float name="wobble" value="1"/></bsdf></shape>'
            '<emitter type="sunsky"/><sensor type="orthographic"/>')
    d, msgs = _read(_scene(tmp_path, body))
    assert len(msgs) == 1
    for what in ("medium", "'cylinder'", "'hair'", "'checkerboard'", "'wobble'", "'sunsky'", "'orthographic'"):
        assert what in msgs[0], what
        assert any(what in w for w in d.warnings), what
    assert len(d.shapes) == 2 and d.camera is None and d.lights == []
    np.testing.assert_allclose(d.materials[0].base_color_factor, (0.5, 0.5, 0.5, 1.0))  # the hair -> diffuse 0.5


@pytest.mark.parametrize("value, expect", [("1.5, 0.5, 0.5", (1.0, 0.5, 0.5)), ("-0.5, 0.25, 1", (0.0, 0.25, 1.0))])
def test_a_colour_outside_0_1_is_clamped_and_named(tmp_path, value, expect):
    d, msgs = _read(_scene(tmp_path, f'<shape type="rectangle"><bsdf type="diffuse" id="wall"><rgb name="reflectance" '
                                     f'value="{value}"/></bsdf></shape>'))
    np.testing.assert_allclose(d.materials[0].base_color_factor, expect + (1.0,))
    assert len(msgs) == 1 and "bsdf 'wall' (diffuse): a colour outside [0, 1] (clamped)" in msgs[0]
    d, msgs = _read(_scene(tmp_path, '<shape type="rectangle"><bsdf type="diffuse"><rgb name="reflectance" '
                                     'value="1, 0, 0.5"/></bsdf></shape>', name="in.xml"))
    assert msgs == []


_SNIPPETS = [
    '<shape type="sphere"><float name="radius" value="0"/></shape>',
    '<shape type="rectangle"><transform name="to_world"><scale value="0"/></transform></shape>',
    '<shape type="cube"><transform name="to_world"><scale x="-1"/></transform><boolean name="flip_normals" '
    'value="true"/></shape>',
    '<shape type="disk"><boolean name="face_normals" value="true"/></shape>',
    '<shape type="cylinder"/>',
    '<bsdf type="roughconductor" id="rc"><float name="alpha" value="0"/></bsdf>',
    '<shape type="rectangle"><ref id="rc"/></shape>',
    '<emitter type="point"><rgb name="intensity" value="0, 0, 0"/></emitter>',
    '<emitter type="spot"><float name="cutoff_angle" value="0"/></emitter>',
    '<emitter type="constant"/>',
    '<sensor type="perspective"><float name="fov" value="1"/><transform name="to_world"><scale x="-1"/>'
    '</transform></sensor>',
    '<shape type="sphere"><bsdf type="mask"><bsdf type="bumpmap"><bsdf type="plastic"/></bsdf></bsdf></shape>',
    '<foo type="bar"/>',
]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.sampled_from(range(len(_SNIPPETS))), min_size=1, max_size=6))
def test_degenerate_scenes_load_finite_or_fail_cleanly(tmp_path, picks):
    p = _scene(tmp_path, "\n".join(_SNIPPETS[i] for i in picks), name="h.xml")
    try:
        d, msgs = _read(p)
    except ValueError as e:  # a ref without its target: named
        assert str(p) in str(e) and "'rc'" in str(e)
        return
    assert len(msgs) <= 1
    for a in (d.vertices, d.normals, d.tangents, d.uvs):
        assert np.isfinite(a).all()
    if d.num_triangles:
        np.testing.assert_allclose(np.linalg.norm(d.normals, axis=1), 1.0, atol=1e-5)
        assert d.material_ids.max() < len(d.materials)
    for light in d.lights:
        assert all(math.isfinite(c) for c in light.radiant)


# --------------------------------------------------------------------------------------------------------------
# load_scene and the Grey & White Room


def test_load_scene_reads_xml(tmp_path):
    body = ('<sensor type="perspective"><float name="fov" value="60"/><transform name="to_world">'
            '<lookat origin="0, 1, 4" target="0, 0.5, 0" up="0, 1, 0"/></transform><film type="hdrfilm">'
            '<integer name="width" value="40"/><integer name="height" value="30"/></film></sensor>'
            '<shape type="cube"><bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.6, 0.2"/></bsdf>'
            '<transform name="to_world"><scale value="0.5"/><translate y="0.5"/></transform></shape>'
            '<emitter type="point"><point name="position" x="2" y="3" z="3"/><float name="intensity" value="20"/>'
            '</emitter>')
    p = _scene(tmp_path, body)
    s = fw.load_scene(str(p))
    assert s.num_triangles == 12 and len(s.lights) == 1
    np.testing.assert_allclose(s.face_albedo, np.tile([0.1, 0.6, 0.2], (12, 1)), atol=1e-6)
    np.testing.assert_allclose(s.camera.eye, (0, 1, 4))
    assert s.camera.fov_y_deg == pytest.approx(fov_y_deg(60, "x", 40 / 30))
    loop = fw.FrameLoop(s, 40, 30, device="cpu")
    f = loop.render_reference()
    hit = f.gbuffer.hit.numpy().astype(bool)
    assert hit[15, 20] and not hit[0, 0]
    np.testing.assert_allclose(f.gbuffer.albedo.numpy()[15, 20], (0.1, 0.6, 0.2), atol=1e-4)
    # the depth at the centre pixel: the ray from the eye meets the cube's front face z = 0.5
    ray = fw.Camera(**{k: getattr(s.camera, k) for k in ("eye", "target", "up", "fov_y_deg")}).ray_dirs(
        [20.5], [15.5], 40, 30)[0]
    t = (0.5 - 4.0) / ray[2]
    assert float(f.gbuffer.depth.numpy()[15, 20]) == pytest.approx(t, rel=1e-4)


def test_grey_white_room():
    p = meshio.find_textured_scene("grey-white-room")
    if p is None:
        pytest.skip(meshio.textured_scene_help("grey-white-room"))
    d, msgs = _read(p)
    assert d.film_size == (1280, 720) and d.num_triangles == 143163 and len(d.shapes) == 65
    assert d.camera.fov_x_rad(1280 / 720) == pytest.approx(math.radians(90.0))
    np.testing.assert_allclose(d.camera.eye, (5.10518, 0.731065, -2.31789))
    assert d.environment is not None and d.environment.image.name == "Sky 19.exr"
    assert len(msgs) == 1 and "dielectric" in msgs[0] and len(d.warnings) == 1
    names = {m.name: m for m in d.materials}
    assert names["Leaves"].alpha_mode == "MASK" and names["Floor"].base_color_texture is not None
    assert names["Mirror"].metallic_factor == 1.0 and names["Mirror"].roughness_factor == 0.0
    assert names["BrushedStainlessSteel"].roughness_factor == pytest.approx(math.sqrt(0.02))
    assert len(d.images) == 4 and np.isfinite(d.vertices).all()


def test_gbuffer_depth_and_albedo_match_mitsuba(tmp_path):
    """The same XML scene in both renderers, pixel-centre rays: the G-buffer's distance and base colour against
    Mitsuba's hit distance and diffuse reflectance, on pixels whose 3 x 3 neighbourhood sees one shape."""
    img = np.zeros((16, 16, 4), dtype=np.uint8)
    yy, xx = np.mgrid[0:16, 0:16]
    img[..., 0] = 40 + 12 * xx  # red grows to the right, green downwards: a flipped lookup would show
    img[..., 1] = 40 + 12 * yy
    img[..., 2] = 90
    img[..., 3] = 255
    _png(tmp_path / "grad.png", img)
    w, h = 48, 32
    body = (f'<sensor type="perspective"><float name="fov" value="55"/><transform name="to_world">'
            f'<lookat origin="0.4, 0.9, 4.5" target="0, 0.2, 0" up="0, 1, 0"/></transform><film type="hdrfilm">'
            f'<integer name="width" value="{w}"/><integer name="height" value="{h}"/></film></sensor>'
            '<shape type="rectangle" id="wall"><bsdf type="diffuse"><texture name="reflectance" type="bitmap">'
            '<string name="filename" value="grad.png"/></texture></bsdf><transform name="to_world">'
            '<scale value="2.5"/><translate z="-1"/></transform></shape>'
            '<shape type="sphere" id="ball"><point name="center" x="-0.6" y="0.1" z="0.3"/>'
            '<float name="radius" value="0.6"/><bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.2, 0.1"/>'
            '</bsdf></shape>'
            '<shape type="cube" id="box"><transform name="to_world"><scale value="0.4"/><rotate y="1" angle="30"/>'
            '<translate x="0.9" y="-0.2" z="0.2"/></transform><bsdf type="twosided"><bsdf type="roughplastic">'
            '<rgb name="diffuse_reflectance" value="0.1, 0.3, 0.8"/></bsdf></bsdf></shape>'
            '<emitter type="point"><point name="position" x="1" y="3" z="3"/><float name="intensity" value="20"/>'
            '</emitter>')
    p = _scene(tmp_path, body)
    ref = mi.load_file(str(p))
    sensor = ref.sensors()[0]
    eye = np.array(sensor.world_transform().matrix, dtype=np.float64)[:3, 3]
    ids = np.full((h, w), -1)
    dist = np.zeros((h, w))
    alb = np.zeros((h, w, 3))
    names = ["wall", "ball", "box"]
    for y in range(h):
        for x in range(w):
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((x + 0.5) / w, (y + 0.5) / h), mi.Point2f(0.5, 0.5))
            si = ref.ray_intersect(ray)
            if si.is_valid():
                ids[y, x] = names.index(si.shape.id())
                dist[y, x] = np.linalg.norm(np.array(si.p, dtype=np.float64) - eye)
                alb[y, x] = np.array(si.bsdf().eval_diffuse_reflectance(si), dtype=np.float64)
    s = _quiet_load(p)
    cfg = fw.Config().with_(shading={"texture_lod": "none"})  # Mitsuba's bitmap has no MIP maps
    g = fw.FrameLoop(s, w, h, device="cpu", config=cfg).render_reference().gbuffer
    hit = g.hit.numpy().astype(bool)
    interior = np.zeros((h, w), dtype=bool)
    interior[1:-1, 1:-1] = True
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            interior[1:-1, 1:-1] &= ids[1 + dy:h - 1 + dy, 1 + dx:w - 1 + dx] == ids[1:-1, 1:-1]
    interior &= ids >= 0
    assert interior.sum() > 0.5 * h * w and (ids[interior] == 1).sum() > 20 and (ids[interior] == 2).sum() > 20
    assert hit[interior].all() and not hit[ids < 0].any()
    depth = g.depth.numpy()
    # depth: the tessellated sphere's facets lie up to 0.054 % of its radius inside it
    np.testing.assert_allclose(depth[interior], dist[interior], rtol=1e-3)
    # albedo: 8-bit sRGB texels decoded and filtered the same way; 2e-3 of float32 UV and filter differences
    np.testing.assert_allclose(g.albedo.numpy()[interior], alb[interior], atol=2e-3)


def _quiet_load(p):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fw.load_scene(str(p))
