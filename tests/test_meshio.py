"""Mesh files (foveawarp.meshio): PLY triangle strips, multi-mesh glTF / OBJ with transforms and base colours,
named meshes from the package assets, and the import structure of scene.py / scenes.py.

References are independent of the code under test: strips against hand-listed triangles and a plain loop, files
written byte by byte here (struct), transforms applied here with NumPy, the shipped PLY files against trimesh's
reader."""

from __future__ import annotations

import ast
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp import meshio

REPO = Path(__file__).resolve().parent.parent

# --------------------------------------------------------------------------------------------------------------
# triangle strips

# a hand-built strip over a 2 x 3 grid of points in the plane z = 0, then a restart and a second strip
#   0---2---4        top row y = 1
#   | \ | \ |
#   1---3---5        bottom row y = 0      (second strip: 6, 7, 8 a separate triangle)
STRIP_VERTS = np.array([[0, 1, 0], [0, 0, 0], [1, 1, 0], [1, 0, 0], [2, 1, 0], [2, 0, 0],
                        [3, 0, 0], [4, 0, 0], [3, 1, 0]], dtype=np.float64)
STRIP = [0, 1, 2, 3, 4, 5, -1, 6, 7, 8]
# written out by hand: even triangles (a, b, c), odd ones (b, a, c)
STRIP_TRIS = np.array([[0, 1, 2], [2, 1, 3], [2, 3, 4], [4, 3, 5], [6, 7, 8]])
STRIP_COLORS = np.array([[255, 0, 0]] * 6 + [[0, 0, 255]] * 3, dtype=np.uint8)


def _strip_reference(s):
    """A plain loop: restart at -1, flip the first two indices of every other triangle, drop degenerate ones."""
    out, cur = [], []
    for i in list(s) + [-1]:
        if i == -1:
            for k in range(len(cur) - 2):
                a, b, c = cur[k], cur[k + 1], cur[k + 2]
                if k % 2:
                    a, b = b, a
                if a != b and b != c and a != c:
                    out.append((a, b, c))
            cur = []
        else:
            cur.append(i)
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def test_strips_to_triangles_hand_built():
    np.testing.assert_array_equal(meshio.strips_to_triangles(STRIP), STRIP_TRIS)
    # the same strips given as a list of lists
    np.testing.assert_array_equal(meshio.strips_to_triangles([STRIP[:6], STRIP[7:]]), STRIP_TRIS)
    # every triangle of the planar strip faces the same way (+z): the alternation keeps one winding
    v = STRIP_VERTS[STRIP_TRIS]
    nz = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])[:, 2]
    assert (nz < 0).all() or (nz > 0).all()
    # a degenerate triangle (repeated index, used to join strips) is dropped, the parity is kept
    # k = 1, 2 are degenerate; k = 3 is odd: (s[4], s[3], s[5])
    np.testing.assert_array_equal(meshio.strips_to_triangles([0, 1, 2, 2, 3, 4]), [[0, 1, 2], [3, 2, 4]])
    assert meshio.strips_to_triangles([0, 1]).shape == (0, 3)
    assert meshio.strips_to_triangles([-1, -1, 0, 1, 2]).tolist() == [[0, 1, 2]]


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.lists(st.integers(min_value=-1, max_value=6), min_size=0, max_size=40))
def test_strips_to_triangles_matches_loop(s):
    np.testing.assert_array_equal(meshio.strips_to_triangles(np.array(s, dtype=np.int64)), _strip_reference(s))


@settings(max_examples=50, deadline=None, derandomize=True)
@given(st.integers(min_value=3, max_value=60), st.integers(min_value=0, max_value=2**31 - 1))
def test_zigzag_strip_has_one_winding(n, seed):
    """A zigzag of n points along x (alternating y = 0 / 1, random spacing) gives n - 2 triangles all facing
    the same side of the plane."""
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.uniform(0.1, 1.0, n))
    pts = np.stack([x, np.arange(n) % 2, np.zeros(n)], axis=1)
    tri = meshio.strips_to_triangles(np.arange(n))
    assert tri.shape == (n - 2, 3)
    v = pts[tri]
    nz = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])[:, 2]
    assert (nz > 0).all() or (nz < 0).all()


def _ply_bytes(fmt: str, verts, colors, strip, idx_type="int") -> bytes:
    """A tristrip PLY written here byte by byte (the layout of the classic scanned models)."""
    head = ["ply", f"format {fmt} 1.0", "comment hand-built tristrip test file", f"element vertex {len(verts)}",
            "property float x", "property float y", "property float z",
            "property uchar red", "property uchar green", "property uchar blue",
            "element tristrips 1", f"property list int {idx_type} vertex_indices", "end_header"]
    body = b""
    if fmt == "ascii":
        rows = [f"{x:g} {y:g} {z:g} {r} {g} {b}" for (x, y, z), (r, g, b) in zip(verts, colors)]
        rows.append(" ".join(str(i) for i in [len(strip), *strip]))
        body = ("\n".join(rows) + "\n").encode()
    else:
        o = "<" if fmt == "binary_little_endian" else ">"
        for (x, y, z), (r, g, b) in zip(verts, colors):
            body += struct.pack(o + "fffBBB", x, y, z, r, g, b)
        body += struct.pack(o + "i", len(strip)) + struct.pack(o + "i" * len(strip), *strip)
    return ("\n".join(head) + "\n").encode() + body


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_tristrip_ply_reads_known_triangles(tmp_path, fmt):
    p = tmp_path / f"strip-{fmt}.ply"
    p.write_bytes(_ply_bytes(fmt, STRIP_VERTS, STRIP_COLORS, STRIP))
    assert meshio.ply_has_tristrips(p)
    d = meshio.read_ply(p)
    np.testing.assert_allclose(d["vertices"], STRIP_VERTS)
    np.testing.assert_array_equal(d["faces"], STRIP_TRIS)
    np.testing.assert_allclose(d["colors"], STRIP_COLORS / 255.0)
    # through load_scene: the ground quad (4 vertices, 2 faces) comes first, then the strip's triangles
    s = fw.load_scene(str(p))
    assert s.num_triangles == 2 + len(STRIP_TRIS)
    np.testing.assert_array_equal(s.faces[2:], STRIP_TRIS + 4)
    expect_alb = (STRIP_COLORS / 255.0)[STRIP_TRIS].mean(axis=1)
    np.testing.assert_allclose(s.face_albedo[2:], expect_alb, atol=1e-6)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(st.sampled_from(["ascii", "binary_little_endian", "binary_big_endian"]),
       st.lists(st.integers(min_value=-1, max_value=7), min_size=3, max_size=30))
def test_tristrip_ply_random_strips_match_loop(tmp_path_factory, fmt, strip):
    """Random strips (restarts and repeated indices included) written to a file read back as the loop's
    triangles; a strip with no proper triangle is refused."""
    rng = np.random.default_rng(len(strip))
    verts = rng.uniform(-1, 1, (8, 3)).astype(np.float32).astype(np.float64)
    p = tmp_path_factory.mktemp("strips") / "s.ply"
    p.write_bytes(_ply_bytes(fmt, verts, np.zeros((8, 3), dtype=np.uint8), strip))
    expect = _strip_reference(strip)
    if len(expect) == 0:
        with pytest.raises(ValueError, match="holds no triangle mesh"):
            meshio.read_ply(p)
        return
    d = meshio.read_ply(p)
    np.testing.assert_array_equal(d["faces"], expect)
    np.testing.assert_allclose(d["vertices"], verts, rtol=0, atol=1e-5 if fmt == "ascii" else 0)  # ascii: %g


def test_tristrip_ply_renders(tmp_path):
    """A strip-only PLY (which trimesh alone reads as a point cloud) renders: primary rays hit it."""
    p = tmp_path / "strip.ply"
    p.write_bytes(_ply_bytes("binary_little_endian", STRIP_VERTS, STRIP_COLORS, STRIP))
    s = fw.load_scene(str(p))
    loop = fw.FrameLoop(s, 48, 32, device="cpu")
    f = loop.render_reference()
    hit = f.gbuffer.hit.numpy().astype(bool)
    alb = f.gbuffer.albedo.numpy()[hit]
    # some pixels see the red part of the strip (the ground is grey 0.5)
    assert (np.abs(alb - [1.0, 0.0, 0.0]).max(axis=1) < 1e-3).any()
    assert np.isfinite(f.numpy()).all()


def test_tristrip_ply_errors(tmp_path):
    p = tmp_path / "bad.ply"
    p.write_bytes(_ply_bytes("ascii", STRIP_VERTS, STRIP_COLORS, [0, 1, 2, 99]))
    with pytest.raises(ValueError, match=r"bad\.ply.*tristrips\[0\]\.vertex_indices must be in \[-1, 8\], got 99"):
        fw.load_scene(str(p))
    q = tmp_path / "short.ply"
    q.write_bytes(_ply_bytes("binary_little_endian", STRIP_VERTS, STRIP_COLORS, STRIP)[:-6])
    with pytest.raises(ValueError, match=r"short\.ply.*truncated"):
        fw.load_scene(str(q))


def _canonical_tris(f):
    """Triangles as a sorted set, each rotated to start at its smallest index (winding kept)."""
    f = np.asarray(f)
    r = np.argmin(f, axis=1)
    rot = np.stack([f[np.arange(len(f)), (r + k) % 3] for k in range(3)], axis=1)
    return rot[np.lexsort(rot.T[::-1])]


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_polygon_faces_match_trimesh(tmp_path, fmt):
    """read_ply's face path (quads and a pentagon, fan-triangulated) against trimesh reading the same file."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0], [3, 0.5, 0]], dtype=np.float64)
    polys = [[0, 1, 2, 3], [1, 4, 5, 2], [4, 6, 5, 2, 1]] if fmt == "ascii" else [[0, 1, 2, 3], [1, 4, 5, 2]]
    head = ["ply", f"format {fmt} 1.0", f"element vertex {len(v)}", "property float x", "property float y",
            "property float z", f"element face {len(polys)}", "property list uchar int vertex_indices", "end_header"]
    if fmt == "ascii":
        body = "".join(f"{a:g} {b:g} {c:g}\n" for a, b, c in v) + "".join(
            f"{len(q)} {' '.join(map(str, q))}\n" for q in polys)
        data = ("\n".join(head) + "\n" + body).encode()
    else:
        o = "<" if fmt == "binary_little_endian" else ">"
        data = ("\n".join(head) + "\n").encode() + b"".join(struct.pack(o + "fff", *p) for p in v) + b"".join(
            struct.pack(o + "B" + "i" * len(q), len(q), *q) for q in polys)
    p = tmp_path / f"poly-{fmt}.ply"
    p.write_bytes(data)
    ours = meshio.read_ply(p)
    ref = trimesh.load(str(p), force="mesh", process=False)
    assert ours["faces"].shape == (sum(len(q) - 2 for q in polys), 3)
    np.testing.assert_array_equal(_canonical_tris(ours["faces"]), _canonical_tris(ref.faces))
    np.testing.assert_allclose(ours["vertices"], ref.vertices)


# --------------------------------------------------------------------------------------------------------------
# multi-mesh glTF and OBJ


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    m = np.eye(4)
    m[1:3, 1:3] = [[c, -s], [s, c]]
    return m


def _two_mesh_scene():
    """A red box (PBR base colour factor) and a sphere with blue vertex colours, each placed by a node transform;
    a third mesh mirrored (det < 0) with a material factor times vertex colours."""
    box = trimesh.creation.box(extents=(1.0, 0.6, 0.8))
    box.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(baseColorFactor=[1.0, 0.0, 0.0, 1.0]))
    ball = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    ball.visual.vertex_colors = np.tile([0, 0, 255, 255], (len(ball.vertices), 1)).astype(np.uint8)
    cone = trimesh.creation.cone(radius=0.3, height=0.7, sections=12)
    cone.visual = trimesh.visual.TextureVisuals(
        material=trimesh.visual.material.PBRMaterial(baseColorFactor=[0.5, 1.0, 1.0, 1.0]))
    vc = np.zeros((len(cone.vertices), 4), dtype=np.uint8)
    vc[:, 1] = 255  # green vertex colours
    vc[:, 3] = 255
    cone.visual.vertex_attributes["color"] = vc
    m_box = trimesh.transformations.translation_matrix([1.5, 0.3, 0.0]) @ _rot_x(0.4)
    m_ball = trimesh.transformations.translation_matrix([-1.5, 0.5, 0.2]) @ np.diag([2.0, 1.0, 1.0, 1.0])
    m_cone = trimesh.transformations.translation_matrix([0.0, 0.4, -1.0]) @ np.diag([-1.0, 1.0, 1.0, 1.0])
    sc = trimesh.Scene()
    sc.add_geometry(box, node_name="a_box", geom_name="box", transform=m_box)
    sc.add_geometry(ball, node_name="b_ball", geom_name="ball", transform=m_ball)
    sc.add_geometry(cone, node_name="c_cone", geom_name="cone", transform=m_cone)
    return sc, {"a_box": (box, m_box), "b_ball": (ball, m_ball), "c_cone": (cone, m_cone)}


def _sorted_rows(a):
    a = np.round(np.asarray(a, dtype=np.float64), 5)
    return a[np.lexsort(a.T[::-1])]


@pytest.mark.parametrize("ext", ["glb", "gltf"])
def test_multi_mesh_gltf_placed_and_coloured(tmp_path, ext):
    sc, src = _two_mesh_scene()
    p = tmp_path / f"two.{ext}"
    sc.export(p)
    parts = meshio.load_mesh_parts(p)
    assert sorted(pt.name for pt in parts) == ["a_box", "b_ball", "c_cone"]
    expect_col = {"a_box": (1.0, 0.0, 0.0), "b_ball": (0.0, 0.0, 1.0), "c_cone": (0.0, 1.0, 0.0)}
    for pt in parts:
        mesh, m = src[pt.name]
        world = np.asarray(mesh.vertices) @ m[:3, :3].T + m[:3, 3]
        np.testing.assert_allclose(_sorted_rows(pt.vertices), _sorted_rows(world), atol=1e-5)
        assert pt.faces.shape == (len(mesh.faces), 3)
        np.testing.assert_allclose(pt.albedo, np.tile(expect_col[pt.name], (len(mesh.faces), 1)), atol=2e-3)
        # smooth normals: the source's vertex normals carried by M^-T (rows matched by position)
        n_src = np.asarray(mesh.vertex_normals) @ np.linalg.inv(m[:3, :3])
        n_src /= np.linalg.norm(n_src, axis=1, keepdims=True)
        o_loaded, o_src = np.lexsort(np.round(pt.vertices, 5).T[::-1]), np.lexsort(np.round(world, 5).T[::-1])
        np.testing.assert_allclose(pt.normals[o_loaded], n_src[o_src], atol=1e-5)
        # winding: a closed mesh's outward faces stay outward, the mirrored cone included
        v = pt.vertices[pt.faces]
        n_loaded = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        centroid_dir = v.mean(axis=1) - pt.vertices.mean(axis=0)
        assert (np.einsum("ij,ij->i", n_loaded, centroid_dir) > -1e-9).mean() > 0.9
    # a glTF file is a scene of its own: its meshes only (no ground), one object per placed mesh
    s = fw.load_scene(str(p))
    assert s.num_triangles == sum(len(m.faces) for m, _ in src.values())
    assert sorted(o.vertex_range[1] - o.vertex_range[0] for o in s.objects) == sorted(
        len(pt.vertices) for pt in parts)
    np.testing.assert_allclose(_sorted_rows(s.vertices), _sorted_rows(np.concatenate([pt.vertices for pt in parts])),
                               atol=1e-5)


def test_multi_mesh_gltf_renders_its_colours(tmp_path):
    sc, _ = _two_mesh_scene()
    p = tmp_path / "two.glb"
    sc.export(p)
    loop = fw.FrameLoop(str(p), 64, 40, device="cpu")
    frame = loop.render_reference()
    hit = frame.gbuffer.hit.numpy().astype(bool)
    alb = frame.gbuffer.albedo.numpy()[hit]
    for col in ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, 1.0, 0.0)):
        n = int((np.abs(alb - col).max(axis=1) < 1e-3).sum())
        assert n > 0, f"no G-buffer pixel has albedo {col}"
    img = frame.numpy()
    assert np.isfinite(img).all()
    # the shaded image shows the colours too: some red-dominant and some blue-dominant pixels
    px = img[hit]
    assert ((px[:, 0] > 2 * px[:, 1] + 0.02) & (px[:, 0] > 2 * px[:, 2] + 0.02)).any()
    assert ((px[:, 2] > 2 * px[:, 0] + 0.02) & (px[:, 2] > 2 * px[:, 1] + 0.02)).any()


def test_obj_with_two_objects_and_materials(tmp_path):
    (tmp_path / "two.mtl").write_text("newmtl warm\nKd 0.8 0.3 0.1\n\nnewmtl cool\nKd 0.1 0.4 0.7\n")
    lines = ["mtllib two.mtl", "o left", "v 0 0 0", "v 1 0 0", "v 0 1 0", "v 1 1 0", "usemtl warm",
             "f 1 2 3", "f 2 4 3", "o right", "v 3 0 0", "v 4 0 0", "v 3 1 0", "usemtl cool", "f 5 6 7"]
    p = tmp_path / "two.obj"
    p.write_text("\n".join(lines) + "\n")
    parts = meshio.load_mesh_parts(p)
    cols = np.array(sorted(tuple(pt.albedo[0]) for pt in parts))
    np.testing.assert_allclose(cols, [(0.1, 0.4, 0.7), (0.8, 0.3, 0.1)], atol=1 / 255)  # Kd kept as 8-bit
    for pt in parts:
        assert np.ptp(pt.albedo, axis=0).max() == 0  # one colour per part
    assert sum(len(pt.faces) for pt in parts) == 3
    v, f, alb, vn = meshio.load_mesh_arrays(p)
    assert f.shape == (3, 3) and alb.shape == (3, 3) and v.shape[1] == 3


def test_uncoloured_parts_get_the_default_albedo(tmp_path):
    a = trimesh.creation.box()
    b = trimesh.creation.box()
    b.visual.face_colors = np.tile([0, 255, 0, 255], (len(b.faces), 1)).astype(np.uint8)
    sc = trimesh.Scene()
    sc.add_geometry(a, node_name="plain", transform=trimesh.transformations.translation_matrix([2, 0, 0]))
    sc.add_geometry(b, node_name="green")
    p = tmp_path / "mixed.glb"
    sc.export(p)
    # glTF: albedo colours the triangles without material and vertex colours (a rough dielectric of that colour)
    s = fw.load_scene(str(p), albedo=(0.2, 0.3, 0.4))
    alb = s.face_albedo
    assert alb.shape == (24, 3)
    n_green = int((np.abs(alb - [0, 1, 0]).max(axis=1) < 1e-3).sum())
    n_plain = int((np.abs(alb - [0.2, 0.3, 0.4]).max(axis=1) < 1e-6).sum())
    assert n_green == 12 and n_plain == 12
    plain = s.materials.metallic_factor[s.face_material[np.abs(alb - [0.2, 0.3, 0.4]).max(axis=1) < 1e-6]]
    np.testing.assert_array_equal(plain, 0.0)
    # without albedo the file's own default material (white) stays
    d = fw.load_scene(str(p))
    assert int((np.abs(d.face_albedo - 1.0).max(axis=1) < 1e-6).sum()) == 12
    # the mesh loader (a ground plane under the parts) still takes albedo
    v, f, alb_m, _ = meshio.load_mesh_arrays(p)
    assert f.shape == (24, 3)
    g = fw.scenes.mesh_on_ground(p, albedo=(0.2, 0.3, 0.4))
    assert int((np.abs(g.face_albedo[2:] - [0.2, 0.3, 0.4]).max(axis=1) < 1e-6).sum()) == 12


# --------------------------------------------------------------------------------------------------------------
# named meshes from the package assets


def test_named_meshes_resolve_from_package_assets(monkeypatch, tmp_path):
    monkeypatch.delenv("FOVEAWARP_SCENES", raising=False)
    monkeypatch.chdir(tmp_path)
    # in this checkout the package's assets are the top-level assets/ folder (a wheel installs it as
    # foveawarp/assets, which tests/test_packaging.py checks)
    pkg_assets = Path(__file__).resolve().parent.parent / "assets"
    assert meshio.assets_dir() == pkg_assets
    for name, tris in (("bunny", 69451), ("spot", 5856), ("teapot", 6320)):
        p = meshio.find_named_mesh(name)
        assert p is not None and p.parent == pkg_assets and p.suffix == ".ply", p
        # the package's own PLY reader and trimesh's agree on the shipped file
        ours = meshio.read_ply(p)
        ref = trimesh.load(str(p), force="mesh", process=False)
        np.testing.assert_array_equal(ours["faces"], np.asarray(ref.faces))
        np.testing.assert_allclose(ours["vertices"], np.asarray(ref.vertices), rtol=0, atol=0)
        assert ours["faces"].shape[0] == tris
        s = fw.load_scene(name)
        assert s.num_triangles == tris + 2 and s.name == name
    assert fw.load_scene("bunny-in-box").num_triangles > 69451


def test_assets_are_small_and_documented():
    d = meshio.assets_dir()
    files = sorted(d.glob("*.ply"))
    assert [f.name for f in files] == sorted(meshio.ASSET_MESHES.values())
    total = sum(f.stat().st_size for f in d.iterdir() if f.is_file())
    assert total < 2_000_000, total
    readme = (d / "README.md").read_text()
    for f in files:
        assert f"`{f.name}`" in readme
    for word in ("CC0", "Stanford", "licence", "tools/make_assets.py"):
        assert word in readme


@pytest.mark.parametrize("name", sorted(meshio.ASSET_MESHES))
def test_shipped_assets_equal_the_original_objs(name):
    """Where the original OBJ files are in reach (a shared/scenes folder), the shipped PLY draws the OBJ's
    triangles, in file order and winding, at its vertices rounded to float32 (what tools/make_assets.py promises).
    Compared corner by corner: the order in which trimesh lists the vertices of an OBJ with texture coordinates
    (spot) differs between the environment that wrote the asset and trimesh 5.2.0 with NumPy 2.4.6; the triangles
    do not."""
    src = next((d / meshio.NAMED_MESHES[name] for d in meshio.scene_search_dirs()[1:]
                if (d / meshio.NAMED_MESHES[name]).is_file()), None)
    if src is None:
        pytest.skip(f"{meshio.NAMED_MESHES[name]} not in reach (no shared/scenes folder)")
    obj = trimesh.load(str(src), force="mesh", process=False)
    ply = meshio.read_ply(meshio.assets_dir() / meshio.ASSET_MESHES[name])
    assert ply["faces"].shape == np.asarray(obj.faces).shape and ply["vertices"].shape == obj.vertices.shape
    corners = np.asarray(obj.vertices).astype(np.float32)[np.asarray(obj.faces)]
    np.testing.assert_array_equal(ply["vertices"][ply["faces"]], corners)


def test_named_mesh_from_env_folder_and_clear_error_when_absent(monkeypatch, tmp_path):
    d = tmp_path / "scenes"
    d.mkdir()
    trimesh.creation.icosphere(subdivisions=1).export(d / "ogre.obj")
    monkeypatch.setenv("FOVEAWARP_SCENES", str(d))
    s = fw.load_scene("ogre")
    assert s.num_triangles == 80 + 2
    # with no folder holding it, the error names the file, the folders looked in and the variable to set
    monkeypatch.setattr(meshio, "scene_search_dirs", lambda: [meshio.assets_dir(), tmp_path / "nowhere"])
    with pytest.raises(ValueError) as ei:
        fw.load_scene("nefertiti")
    msg = str(ei.value)
    assert "'nefertiti.obj'" in msg and "nowhere" in msg and "FOVEAWARP_SCENES" in msg and "assets" in msg


# --------------------------------------------------------------------------------------------------------------
# import structure: scene.py never imports scenes.py; meshio imports neither


def _imports(path: Path) -> set:
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            mod = "." * node.level + (node.module or "")
            out.add(mod)
            out.update(f"{mod}.{a.name}" if mod.endswith(".") is False else f"{mod}{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_no_import_circle_between_scene_and_scenes():
    scene_imports = _imports(REPO / "foveawarp" / "scene.py")
    assert not any(i.split(".")[-1] == "scenes" or i.endswith("scenes") for i in scene_imports), scene_imports
    mio = _imports(REPO / "foveawarp" / "meshio.py")
    assert not any(i.rstrip(".").split(".")[-1] in ("scene", "scenes") for i in mio), mio
    from foveawarp import scene, scenes

    assert scene.load_scene is fw.load_scene
    assert scene._REGISTRY["builtin"] is scenes.BUILTIN and scene._REGISTRY["file"] is scenes.mesh_on_ground
    # the public names kept their homes
    for n in ("load_scene", "scene_search_dirs", "find_named_mesh", "load_mesh_arrays", "NAMED_MESHES"):
        assert hasattr(scene, n)
