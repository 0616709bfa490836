"""OBJ + MTL (foveawarp.io.obj): the geometry against trimesh's loader, indices, polygons and normals against
NumPy, the MTL statements against the mapping the module documents, and what happens with missing or broken
files."""

from __future__ import annotations

import struct
import warnings
import zlib

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp.io.obj import ns_to_roughness, parse_obj, read_obj


def _png(path, rgba: np.ndarray) -> None:
    """Write an 8-bit RGBA PNG (zlib + struct, no image library)."""
    h, w, _ = rgba.shape
    raw = b"".join(b"\x00" + rgba[y].astype(np.uint8).tobytes() for y in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def _read(p, **kw):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        d = read_obj(p, **kw)
    return d, [str(x.message) for x in w]


def _tri_set(v, f):
    """Triangles as position triples, rotated to start at their smallest corner (winding kept), sorted."""
    out = []
    for t in np.asarray(f):
        c = [tuple(np.round(np.asarray(v, dtype=np.float64)[i], 6)) for i in t]
        k = c.index(min(c))
        out.append(tuple(c[k:] + c[:k]))
    return sorted(out)


_BOX = """# a box with UVs and normals on some faces, quads and a pentagon cap
v -1 -1 -1
v 1 -1 -1
v 1 1 -1
v -1 1 -1
v -1 -1 1
v 1 -1 1
v 1 1 1
v -1 1 1
v 0 1.5 0
vt 0 0
vt 1 0
vt 1 1
vt 0 1
vn 0 0 -1
vn 0 0 1
f 1/1/1 4/4/1 3/3/1 2/2/1
f 5/1/2 6/2/2 7/3/2 8/4/2
f 1/1 2/2 6/3 5/4
f 2 3 7 6
f 4 8 7 9 3
f 1//1 5//1 8//1
f 1 8 4
"""


def test_geometry_matches_trimesh(tmp_path):
    p = tmp_path / "box.obj"
    p.write_text(_BOX)
    m = parse_obj(p)
    ref = trimesh.load(str(p), process=False, force="mesh")
    assert _tri_set(m.positions, m.triangles) == _tri_set(ref.vertices, ref.faces)
    # every distinct (v, vt, vn) corner is one vertex
    assert m.positions.shape[0] == len({c for line in _BOX.splitlines() if line.startswith("f ")
                                        for c in line.split()[1:]})
    d, _ = _read(p)
    assert d.num_triangles == len(ref.faces) and np.isfinite(d.tangents).all()


def test_negative_indices_equal_positive_ones(tmp_path):
    pos = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\n"
    a = tmp_path / "a.obj"
    a.write_text(pos + "f 1/1/1 2/2/1 3/3/1\nv 2 0 0\nf 2 5 3\n")
    b = tmp_path / "b.obj"
    b.write_text(pos + "f -4/-3/-1 -3/-2/-1 -2/-1/-1\nv 2 0 0\nf -4 -1 -3\n")
    ma, mb = parse_obj(a), parse_obj(b)
    assert _tri_set(ma.positions, ma.triangles) == _tri_set(mb.positions, mb.triangles)
    np.testing.assert_array_equal(ma.triangles, mb.triangles)
    np.testing.assert_allclose(ma.uvs, mb.uvs)
    c = tmp_path / "c.obj"
    c.write_text(pos + "f 1 2 -5\n")  # -5 refers before the first vertex
    with pytest.raises(ValueError, match=r"c\.obj:9: face v index"):
        parse_obj(c)
    c.write_text(pos + "f 1 2 7\n")
    with pytest.raises(ValueError, match=r"c\.obj:9: .*'7'"):
        parse_obj(c)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.integers(3, 12), st.floats(0.2, 3.0), st.booleans())
def test_ngons_fan_with_the_polygons_area(tmp_path, n, radius, negative):
    # a convex polygon in the plane z = 0.5, written with positive or negative indices
    ang = np.linspace(0.0, 2 * np.pi, n, endpoint=False) + 0.3
    xy = np.stack([radius * np.cos(ang), 0.7 * radius * np.sin(ang)], axis=1)
    lines = [f"v {x:.9f} {y:.9f} 0.5" for x, y in xy]
    idx = [str(i - n) for i in range(n)] if negative else [str(i + 1) for i in range(n)]
    p = tmp_path / "poly.obj"
    p.write_text("\n".join(lines) + "\nf " + " ".join(idx) + "\n")
    m = parse_obj(p)
    assert m.triangles.shape == (n - 2, 3)
    v = m.positions[m.triangles]
    area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum()
    shoelace = 0.5 * abs(np.dot(xy[:, 0], np.roll(xy[:, 1], -1)) - np.dot(xy[:, 1], np.roll(xy[:, 0], -1)))
    assert area == pytest.approx(shoelace, rel=1e-7)
    np.testing.assert_allclose(m.normals, np.tile([0.0, 0.0, 1.0], (n, 1)), atol=1e-9)  # counter-clockwise


def test_missing_normals_are_area_weighted(tmp_path):
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(12, 3))
    hull = trimesh.convex.convex_hull(pts)
    lines = [f"v {x:.12f} {y:.12f} {z:.12f}" for x, y, z in hull.vertices] + ["vn 0 1 0"]
    faces = list(hull.faces)
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces[1:]]
    a, b, c = faces[0]
    lines.append(f"f {a + 1}//1 {b + 1}//1 {c + 1}//1")  # one face with a given normal
    p = tmp_path / "hull.obj"
    p.write_text("\n".join(lines) + "\n")
    m = parse_obj(p)
    v, f = np.asarray(hull.vertices), np.asarray(faces[1:] + [faces[0]])
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    ref = np.zeros_like(v)
    for j in range(3):
        np.add.at(ref, f[:, j], fn)
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    given_n = np.zeros(len(m.positions), dtype=bool)
    for t in m.triangles[-1:]:
        given_n[t] = True
    for i in range(len(m.positions)):
        j = int(np.argmin(np.linalg.norm(v - m.positions[i], axis=1)))
        expect = [0.0, 1.0, 0.0] if given_n[i] else ref[j]
        np.testing.assert_allclose(m.normals[i], expect, atol=1e-9)


def test_odd_whitespace_and_ragged_rows(tmp_path):
    p = tmp_path / "ws.obj"
    p.write_text("v\t0  0 0\nv 1 0 0 1.0\nv 0\u00a01 0\nvt 0.5\nvt 0.25 0.75\nvt 1 1\nf 1/1 2/2 3/3\n",
                 encoding="utf-8")
    m = parse_obj(p)
    np.testing.assert_allclose(np.sort(m.positions, axis=0), np.sort([[0, 0, 0], [1, 0, 0], [0, 1, 0]], axis=0))
    np.testing.assert_allclose(np.sort(m.uvs[:, 0]), [0.25, 0.5, 1.0])
    np.testing.assert_allclose(np.sort(m.uvs[:, 1]), [0.0, 0.25, 1.0])  # a missing v reads 0, flipped to 1 - 0


def test_uvs_flip_and_vertex_colours(tmp_path):
    p = tmp_path / "uv.obj"
    p.write_text("v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nvt 0.25 0.1\nvt 0.75 0.2\nvt 0.5 0.9\n"
                 "f 1/1 2/2 3/3\n")
    m = parse_obj(p)
    order = np.argsort(m.positions[:, 0] + 2 * m.positions[:, 1])
    np.testing.assert_allclose(m.uvs[order], [[0.25, 0.9], [0.75, 0.8], [0.5, 0.1]])  # v' = 1 - v
    np.testing.assert_allclose(m.colors[order][:, :3], np.eye(3))
    m2 = parse_obj(p, flip_v=False)
    np.testing.assert_allclose(m2.uvs[np.argsort(m2.positions[:, 0] + 2 * m2.positions[:, 1])],
                               [[0.25, 0.1], [0.75, 0.2], [0.5, 0.9]])


# --------------------------------------------------------------------------------------------------------------
# MTL


def _quad_with(tmp_path, mtl: str, name="q"):
    (tmp_path / f"{name}.mtl").write_text(mtl)
    p = tmp_path / f"{name}.obj"
    p.write_text(f"mtllib {name}.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                 f"usemtl m\nf 1/1 2/2 3/3 4/4\n")
    return p


def test_map_kd_with_scale_and_offset(tmp_path):
    _png(tmp_path / "tex.png", np.full((2, 2, 4), 200, dtype=np.uint8))
    p = _quad_with(tmp_path, "newmtl m\nKd 0.5 0.25 1\nmap_Kd -s 2 3 -o 0.1 0.2 tex.png\n")
    d, msgs = _read(p)
    assert not msgs
    m = d.materials[0]
    assert m.base_color_factor == (0.5, 0.25, 1.0, 1.0) and m.double_sided
    t = m.base_color_texture
    assert t is not None and t.color_space == "srgb" and d.images[t.image].path.name == "tex.png"
    # OBJ looks up (s_u u + o_u, s_v v + o_v) in bottom-left coordinates; UVs are stored top-left (v' = 1 - v)
    rng = np.random.default_rng(0)
    uv_obj = rng.uniform(-1, 2, size=(20, 2))
    uv = np.stack([uv_obj[:, 0], 1.0 - uv_obj[:, 1]], axis=1)
    looked_up = np.stack([2 * uv_obj[:, 0] + 0.1, 3 * uv_obj[:, 1] + 0.2], axis=1)
    np.testing.assert_allclose(t.transform_uv(uv), np.stack([looked_up[:, 0], 1.0 - looked_up[:, 1]], axis=1),
                               atol=1e-12)
    # a single -s value scales u only (v's default is 1)
    d, _ = _read(_quad_with(tmp_path, "newmtl m\nmap_Kd -s 4 tex.png\n", name="s1"))
    np.testing.assert_allclose(d.materials[0].base_color_texture.transform_uv([[0.5, 0.25]]), [[2.0, 0.25]])
    # -clamp on, and a file name with a space
    _png(tmp_path / "my tex.png", np.full((2, 2, 4), 9, dtype=np.uint8))
    d, _ = _read(_quad_with(tmp_path, "newmtl m\nmap_Kd -clamp on my tex.png\n", name="c"))
    t = d.materials[0].base_color_texture
    assert (t.wrap_s, t.wrap_t) == ("clamp", "clamp") and d.images[t.image].path.name == "my tex.png"


def test_normal_and_bump_maps(tmp_path):
    nm = np.zeros((8, 8, 4), dtype=np.uint8)
    nm[..., :3] = (128, 128, 255)
    nm[..., 3] = 255
    _png(tmp_path / "n.png", nm)
    height = np.zeros((8, 8, 4), dtype=np.uint8)
    height[..., :3] = np.linspace(0, 255, 8, dtype=np.uint8)[:, None, None]
    height[..., 3] = 255
    _png(tmp_path / "h.png", height)
    d, msgs = _read(_quad_with(tmp_path, "newmtl m\nnorm -bm 0.5 n.png\n", name="a"))
    m = d.materials[0]
    assert m.normal_texture is not None and m.normal_texture.color_space == "linear" and m.normal_scale == 0.5
    assert not msgs
    for kw in ("map_Bump", "bump"):
        d, msgs = _read(_quad_with(tmp_path, f"newmtl m\n{kw} n.png\n", name="b" + kw))
        assert d.materials[0].normal_texture is not None and not msgs  # a normal map written as bump
        d, msgs = _read(_quad_with(tmp_path, f"newmtl m\n{kw} -bm 2 h.png\n", name="c" + kw))
        assert d.materials[0].normal_texture is None
        assert len(msgs) == 1 and "h.png" in msgs[0] and "height map" in msgs[0]


def test_emission_roughness_and_opacity(tmp_path):
    d, _ = _read(_quad_with(tmp_path, "newmtl m\nKd 0.1 0.2 0.3\nKe 4 2 0\n", name="e"))
    m = d.materials[0]
    assert m.emission == pytest.approx((4.0, 2.0, 0.0))
    np.testing.assert_array_equal(d.emissive_triangles, [0, 1])
    for ns in (0.0, 10.0, 96.0, 1000.0):
        d, _ = _read(_quad_with(tmp_path, f"newmtl m\nKs 0.5 0.5 0.5\nNs {ns}\n", name=f"n{int(ns)}"))
        alpha = np.sqrt(2.0 / (ns + 2.0))  # Walter et al. 2007, eq. 33
        assert d.materials[0].roughness_factor == pytest.approx(np.sqrt(alpha), rel=1e-6)
        assert ns_to_roughness(ns) == pytest.approx(np.sqrt(alpha), rel=1e-12)
    d, _ = _read(_quad_with(tmp_path, "newmtl m\nNs 50\n", name="noks"))
    assert d.materials[0].roughness_factor == 1.0  # no highlight without Ks
    d, _ = _read(_quad_with(tmp_path, "newmtl m\nKs 1 1 1\nNs 50\nPr 0.3\nPm 0.8\n", name="pbr"))
    assert (d.materials[0].roughness_factor, d.materials[0].metallic_factor) == pytest.approx((0.3, 0.8))
    d, _ = _read(_quad_with(tmp_path, "newmtl m\nd 0.5\n", name="d"))
    assert d.materials[0].base_color_factor[3] == 0.5 and d.materials[0].alpha_mode == "BLEND"
    d, _ = _read(_quad_with(tmp_path, "newmtl m\nTr 0.25\n", name="tr"))
    assert d.materials[0].base_color_factor[3] == 0.75
    _png(tmp_path / "cut.png", np.full((2, 2, 4), 128, dtype=np.uint8))
    d, _ = _read(_quad_with(tmp_path, "newmtl m\nmap_Kd cut.png\nmap_d cut.png\n", name="mask"))
    assert d.materials[0].alpha_mode == "MASK"


# --------------------------------------------------------------------------------------------------------------
# missing and broken pieces


def test_missing_texture_warns_or_raises(tmp_path):
    p = _quad_with(tmp_path, "newmtl m\nKd 0.3 0.3 0.3\nmap_Kd absent.png\n")
    d, msgs = _read(p)
    assert d.materials[0].base_color_texture is None and d.materials[0].base_color_factor[0] == 0.3
    assert len(msgs) == 1 and "absent.png" in msgs[0] and any("absent.png" in w for w in d.warnings)
    with pytest.raises(ValueError, match="absent.png"):
        read_obj(p, strict=True)
    # a missing library and an undefined material: warnings, the default material
    q = tmp_path / "nolib.obj"
    q.write_text("mtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl ghost\nf 1 2 3\n")
    d, msgs = _read(q)
    assert any("gone.mtl" in w for w in msgs) and any("'ghost'" in w for w in msgs)
    assert d.materials[0].base_color_factor == (0.8, 0.8, 0.8, 1.0)
    with pytest.raises(ValueError, match="gone.mtl"):
        read_obj(q, strict=True)


def test_corrupt_image_is_named_when_the_scene_is_built(tmp_path):
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)
    p = _quad_with(tmp_path, "newmtl m\nmap_Kd broken.png\n")
    d, _ = _read(p)  # the reader does not decode base colour images
    assert d.materials[0].base_color_texture is not None
    with pytest.raises(ValueError, match="broken.png"):
        fw.load_scene(str(p))


def test_unknown_statements_are_warned_once(tmp_path):
    p = tmp_path / "odd.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nfoo 1\nfoo 2\nbar\ncstype bezier\nl 1 2\nf 1 2 3\nf 1 2\n")
    d, msgs = _read(p)
    assert d.num_triangles == 1
    ignored = [m for m in msgs if "ignored statement" in m]
    assert len(ignored) == 1 and "'foo' (2)" in ignored[0] and "'bar' (1)" in ignored[0] and "'cstype'" in ignored[0]
    assert any("line/point" in m for m in msgs) and any("fewer than 3" in m for m in msgs)


def test_malformed_numbers_name_the_line(tmp_path):
    p = tmp_path / "bad.obj"
    p.write_text("v 0 0 0\nv 1 zero 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"bad\.obj:2"):
        read_obj(p)
    q = tmp_path / "bad.mtl"
    q.write_text("newmtl m\nKd 0.1 x 0.3\n")
    (tmp_path / "m.obj").write_text("mtllib bad.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"bad\.mtl:2"):
        read_obj(tmp_path / "m.obj")
    with pytest.raises(ValueError, match="not found"):
        read_obj(tmp_path / "none.obj")


@pytest.mark.parametrize("stmt", ["Kd 0.5 nan 0.5", "Ke inf 1 1", "Ns nan", "d -inf", "Pr nan",
                                  "map_Kd -s nan 1 1 t.png"])
def test_non_finite_mtl_numbers_name_the_line(tmp_path, stmt):
    """NaN or Inf in an MTL statement is a ValueError naming the file, the line and the statement (clamped
    to [0, 1] by min and max, a NaN base colour would become 0 without a word)."""
    (tmp_path / "t.png").write_bytes(b"")
    (tmp_path / "bad.mtl").write_text(f"newmtl m\nKs 1 1 1\n{stmt}\n")
    (tmp_path / "m.obj").write_text("mtllib bad.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n")
    with pytest.raises(ValueError, match=r"bad\.mtl:3: " + stmt.split()[0] + " must be followed by finite numbers"):
        read_obj(tmp_path / "m.obj")


_MTL_KEYS = ["Kd", "Ks", "Ke", "Ns", "d", "Tr", "Pr", "Pm", "Ni"]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.sampled_from(_MTL_KEYS), st.lists(st.floats(width=32), min_size=1, max_size=3)),
                min_size=1, max_size=6))
def test_mtl_numbers_load_finite_or_fail_at_their_line(tmp_path, stmts):
    """Any numbers, NaN, Inf and float32's extremes included, in any MTL statement: the file loads with finite
    material factors, or raises ValueError; a non-finite number or a colour of two numbers raises naming the first
    line that holds one."""
    import math

    lines = ["newmtl m"] + [f"{k} " + " ".join(repr(v) for v in vals[:3 if k in ('Kd', 'Ks', 'Ke') else 1])
                            for k, vals in stmts]
    (tmp_path / "h.mtl").write_text("\n".join(lines) + "\n")
    (tmp_path / "h.obj").write_text("mtllib h.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl m\nf 1 2 3\n")
    bad = [no for no, ln in enumerate(lines[1:], 2) if any(not math.isfinite(float(t)) for t in ln.split()[1:])
           or len(ln.split()) == 3]  # a colour of two numbers: neither r nor r g b
    try:
        d, _ = _read(tmp_path / "h.obj")
    except ValueError as e:
        if bad:
            assert f"h.mtl:{bad[0]}:" in str(e)
        else:  # finite but outside a field's range (an IOR of 1e30): the material names itself
            assert "'m'" in str(e) or "h.mtl" in str(e), str(e)
        return
    assert not bad
    (m,) = d.materials
    for name in ("base_color_factor", "emissive_factor", "metallic_factor", "roughness_factor", "emissive_strength",
                 "ior", "transmission_factor", "alpha_cutoff"):
        assert np.isfinite(np.asarray(getattr(m, name), dtype=np.float64)).all(), name
    assert 0.0 <= min(m.base_color_factor) and max(m.base_color_factor) <= 1.0


def test_load_scene_obj_with_and_without_materials(tmp_path):
    _png(tmp_path / "tex.png", np.tile(np.array([255, 0, 0, 255], dtype=np.uint8), (4, 4, 1)))
    p = _quad_with(tmp_path, "newmtl m\nKd 1 1 1\nmap_Kd tex.png\n")
    s = fw.load_scene(str(p))
    assert s.num_triangles == 2 and s.materials is not None  # a scene file: no ground
    np.testing.assert_allclose(s.face_albedo, [[1.0, 0.0, 0.0]] * 2, atol=1e-6)
    bare = tmp_path / "bare.obj"
    bare.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    s2 = fw.load_scene(str(bare))
    assert s2.num_triangles == 3 and s2.materials is None  # a mesh on the ground quad
