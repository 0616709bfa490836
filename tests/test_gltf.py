"""glTF 2.0 reader (foveawarp.io.gltf) and the material model (foveawarp.materials), checked on files built here
with json + struct + NumPy (expected world-space arrays computed independently) and on the textured sample files
in the shared scenes folder (trimesh's loader as the reference)."""

from __future__ import annotations

import base64
import json
import math
import os
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

from foveawarp.io.gltf import read_gltf
from foveawarp.materials import ImageSource, Material, MaterialTable, TextureRef, default_material

FLOAT, U8, U16, U32, I8, I16 = 5126, 5121, 5123, 5125, 5120, 5122
_NP = {FLOAT: "<f4", U8: "<u1", U16: "<u2", U32: "<u4", I8: "<i1", I16: "<i2"}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
PNG_1PX = bytes.fromhex(
    "89504e470d0a1a0a0000000d4948445200000001000000010806000000"
    "1f15c4890000000d49444154789c6360f8cfc0f01f0005000201e2a4b55f0000000049454e44ae426082")


# ---------------------------------------------------------------------------------------------------
# a small glTF writer


class Builder:
    """Accumulates a glTF document and one binary buffer; writes .glb, .gltf + .bin, or .gltf with a data URI."""

    def __init__(self):
        self.doc = {"asset": {"version": "2.0"}, "buffers": [], "bufferViews": [], "accessors": [],
                    "meshes": [], "nodes": [], "scenes": [{"nodes": []}], "scene": 0}
        self.bin = bytearray()

    def view(self, data: bytes, stride=None) -> int:
        while len(self.bin) % 4:
            self.bin.append(0)
        v = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if stride:
            v["byteStride"] = stride
        self.bin += data
        self.doc["bufferViews"].append(v)
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, values, ctype=FLOAT, atype=None, normalized=False, view=None, offset=0, count=None) -> int:
        a = np.asarray(values)
        if atype is None:
            atype = "SCALAR" if a.ndim == 1 else {2: "VEC2", 3: "VEC3", 4: "VEC4"}[a.shape[1]]
        if view is None:
            view = self.view(a.astype(_NP[ctype]).tobytes())
        acc = {"bufferView": view, "byteOffset": offset, "componentType": ctype, "type": atype,
               "count": int(a.shape[0]) if count is None else count}
        if normalized:
            acc["normalized"] = True
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def mesh(self, *prims) -> int:
        self.doc["meshes"].append({"primitives": list(prims)})
        return len(self.doc["meshes"]) - 1

    def node(self, root=True, **kw) -> int:
        self.doc["nodes"].append(kw)
        i = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(i)
        return i

    def _bin(self) -> bytes:
        b = bytes(self.bin)
        return b + b"\0" * (-len(b) % 4)

    def write_glb(self, path: Path) -> Path:
        doc = json.loads(json.dumps(self.doc))
        b = self._bin()
        doc["buffers"] = [{"byteLength": len(b)}]
        js = json.dumps(doc).encode()
        js += b" " * (-len(js) % 4)
        total = 12 + 8 + len(js) + 8 + len(b)
        path.write_bytes(struct.pack("<III", 0x46546C67, 2, total) + struct.pack("<II", len(js), 0x4E4F534A)
                         + js + struct.pack("<II", len(b), 0x004E4942) + b)
        return path

    def write_gltf(self, path: Path, data_uri: bool = False) -> Path:
        doc = json.loads(json.dumps(self.doc))
        b = self._bin()
        if data_uri:
            uri = "data:application/octet-stream;base64," + base64.b64encode(b).decode()
        else:
            uri = path.stem + " data.bin"  # a space: the URI is percent-encoded
            (path.parent / uri).write_bytes(b)
            uri = uri.replace(" ", "%20")
        doc["buffers"] = [{"byteLength": len(b), "uri": uri}]
        path.write_text(json.dumps(doc))
        return path

    def write(self, path: Path, kind: str) -> Path:
        if kind == "glb":
            return self.write_glb(path.with_suffix(".glb"))
        return self.write_gltf(path.with_suffix(".gltf"), data_uri=(kind == "datauri"))


CONTAINERS = ["glb", "gltf", "datauri"]


# ---------------------------------------------------------------------------------------------------
# independent references


def axis_angle_matrix(axis, angle) -> np.ndarray:
    """Rodrigues' rotation formula (4x4)."""
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    m = np.eye(4)
    m[:3, :3] = np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx
    return m


def quat_of(axis, angle) -> list:
    k = np.asarray(axis, dtype=np.float64)
    k = k / np.linalg.norm(k)
    return [*(k * math.sin(angle / 2)), math.cos(angle / 2)]


def translate(t) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = t
    return m


def scale(s) -> np.ndarray:
    return np.diag([*s, 1.0])


def apply(m, p) -> np.ndarray:
    return p @ m[:3, :3].T + m[:3, 3]


def world_triangles(s) -> np.ndarray:
    """(F, 9) world triangle corners, rows sorted, for comparing triangle sets regardless of order."""
    t = s.vertices[s.triangles].reshape(-1, 9).astype(np.float64)
    return t[np.lexsort(t.T[::-1])]


def sorted_rows(t) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64).reshape(len(t), -1)
    return t[np.lexsort(t.T[::-1])]


def read(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # files built here need no warning unless a test asks for one
        return read_gltf(path, **kw)


# a unit quad in z = 0 facing +z: two counter-clockwise triangles
QUAD_P = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float32)
QUAD_N = np.tile([0, 0, 1], (4, 1)).astype(np.float32)
QUAD_UV = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float32)  # glTF: v down, so y = 1 - v
QUAD_I = np.array([0, 1, 2, 0, 2, 3], dtype=np.uint16)


def quad_primitive(b: Builder, *, normals=True, uvs=QUAD_UV, material=None) -> dict:
    attrs = {"POSITION": b.accessor(QUAD_P)}
    if normals:
        attrs["NORMAL"] = b.accessor(QUAD_N)
    if uvs is not None:
        attrs["TEXCOORD_0"] = b.accessor(uvs)
    prim = {"attributes": attrs, "indices": b.accessor(QUAD_I, U16)}
    if material is not None:
        prim["material"] = material
    return prim


# ---------------------------------------------------------------------------------------------------
# node hierarchy, instancing, containers


@pytest.mark.parametrize("kind", CONTAINERS)
def test_hierarchy_trs_matrix_and_instancing(tmp_path, kind):
    b = Builder()
    quad = b.mesh(quad_primitive(b))
    # parent: TRS; child: matrix (column-major in the file); a second root places the same mesh again
    t, ax, ang, s = (1.0, 2.0, -3.0), (0.3, 1.0, 0.2), 0.7, (2.0, 0.5, 1.5)
    parent_m = translate(t) @ axis_angle_matrix(ax, ang) @ scale(s)
    child_m = translate((0.0, 0.0, 4.0)) @ axis_angle_matrix((1, 0, 0), -0.4) @ scale((1.0, 3.0, 1.0))
    child = b.node(root=False, mesh=quad, matrix=child_m.T.reshape(-1).tolist())
    b.node(mesh=quad, translation=list(t), rotation=quat_of(ax, ang), scale=list(s), children=[child])
    other_m = translate((-5.0, 0.0, 0.0))
    b.node(mesh=quad, translation=[-5.0, 0.0, 0.0])
    scene = read(b.write(tmp_path / "h", kind))

    worlds = [parent_m, parent_m @ child_m, other_m]
    assert scene.num_triangles == 6 and scene.vertices.shape == (12, 3)
    expected = np.concatenate([apply(m, QUAD_P.astype(np.float64))[QUAD_I.reshape(-1, 3)].reshape(-1, 9)
                               for m in worlds])
    np.testing.assert_allclose(world_triangles(scene), sorted_rows(expected), atol=1e-5)
    # depth-first order: parent, child, then the second root
    for k, m in enumerate(worlds):
        sl = slice(4 * k, 4 * k + 4)
        np.testing.assert_allclose(scene.vertices[sl], apply(m, QUAD_P.astype(np.float64)), atol=1e-5)
        n = QUAD_N @ np.linalg.inv(m[:3, :3])  # rows times M^-1 = (M^-T n) as rows
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        np.testing.assert_allclose(scene.normals[sl], n, atol=1e-5)
        tx = m[:3, :3] @ np.array([1.0, 0.0, 0.0])
        tx -= n[0] * (tx @ n[0])
        np.testing.assert_allclose(scene.tangents[sl, :3], np.tile(tx / np.linalg.norm(tx), (4, 1)), atol=1e-5)
        np.testing.assert_array_equal(scene.tangents[sl, 3], 1.0)
    np.testing.assert_array_equal(scene.uvs, np.tile(QUAD_UV, (3, 1)))  # UVs kept as stored (v not flipped)
    assert scene.uvs1 is None and scene.colors is None
    # no material in the file: glTF's default one
    assert scene.materials == [default_material()]
    np.testing.assert_array_equal(scene.material_ids, 0)
    for a in (scene.vertices, scene.normals, scene.tangents, scene.uvs):
        assert a.dtype == np.float32 and np.isfinite(a).all()
    assert scene.triangles.dtype == np.int32 and scene.material_ids.dtype == np.int32


def test_negative_scale_node_flips_winding_and_handedness(tmp_path):
    b = Builder()
    quad = b.mesh(quad_primitive(b))
    b.node(mesh=quad, scale=[-1.0, 1.0, 1.0], translation=[0.0, 0.0, 2.0])
    scene = read(b.write_glb(tmp_path / "neg.glb"))
    m = translate((0, 0, 2)) @ scale((-1, 1, 1))
    np.testing.assert_allclose(scene.vertices, apply(m, QUAD_P.astype(np.float64)), atol=1e-6)
    # mirrored triangles with the winding reversed: their geometric normal agrees with the transformed normal +z
    np.testing.assert_array_equal(scene.triangles, QUAD_I.reshape(-1, 3)[:, [0, 2, 1]])
    p = scene.vertices[scene.triangles]
    gn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    np.testing.assert_allclose(scene.normals, np.tile([0, 0, 1], (4, 1)), atol=1e-6)
    assert (gn @ np.array([0, 0, 1.0]) > 0).all()
    # the tangent follows the mirror (-x) and the frame's handedness flips
    np.testing.assert_allclose(scene.tangents[:, :3], np.tile([-1, 0, 0], (4, 1)), atol=1e-6)
    np.testing.assert_array_equal(scene.tangents[:, 3], -1.0)


def test_sparse_accessor_and_accessor_without_view(tmp_path):
    b = Builder()
    base_p = QUAD_P.copy()
    pos = b.accessor(base_p)
    idx = b.view(np.array([1, 3], dtype=np.uint16).tobytes())
    val = b.view(np.array([[2, 0, 0], [0, 5, 0]], dtype=np.float32).tobytes())
    b.doc["accessors"][pos]["sparse"] = {"count": 2, "indices": {"bufferView": idx, "componentType": U16},
                                         "values": {"bufferView": val}}
    # a sparse accessor without a bufferView: zeros, then the sparse values
    tri_p = np.zeros((3, 3), dtype=np.float32)
    b.doc["accessors"].append({"componentType": FLOAT, "type": "VEC3", "count": 3,
                               "sparse": {"count": 2,
                                          "indices": {"bufferView": b.view(np.array([1, 2], np.uint8).tobytes()),
                                                      "componentType": U8},
                                          "values": {"bufferView": b.view(np.array([[1, 0, 0], [0, 1, 0]],
                                                                                   np.float32).tobytes())}}})
    zero_based = len(b.doc["accessors"]) - 1
    mesh = b.mesh({"attributes": {"POSITION": pos}, "indices": b.accessor(QUAD_I, U16)},
                  {"attributes": {"POSITION": zero_based}})
    b.node(mesh=mesh)
    scene = read(b.write_glb(tmp_path / "sparse.glb"))
    exp = base_p.copy()
    exp[1], exp[3] = (2, 0, 0), (0, 5, 0)
    tri_p[1], tri_p[2] = (1, 0, 0), (0, 1, 0)
    np.testing.assert_allclose(scene.vertices, np.concatenate([exp, tri_p]))
    np.testing.assert_array_equal(scene.triangles, np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]]))


def test_normalized_and_quantized_attributes_interleaved_view(tmp_path):
    b = Builder()
    # interleaved POSITION (float32 x3) + NORMAL (int8 normalized x3, padded to 4) in one view, stride 16
    n_i8 = np.array([[0, 0, 127], [0, 0, 127], [0, 0, 127], [0, -128, 0]], dtype=np.int8)
    rec = b"".join(QUAD_P[i].tobytes() + n_i8[i].tobytes() + b"\0" for i in range(4))
    v = b.view(rec, stride=16)
    pos = b.accessor(QUAD_P, view=v, offset=0)
    nrm = b.accessor(n_i8, I8, normalized=True, view=v, offset=12)
    uv_u8 = np.array([[0, 255], [255, 255], [255, 0], [51, 0]], dtype=np.uint8)
    col_u16 = np.array([[65535, 0, 0], [0, 65535, 0], [0, 0, 65535], [32768, 32768, 32768]], dtype=np.uint16)
    uv1_u16 = np.array([[0, 0], [65535, 0], [65535, 65535], [0, 65535]], dtype=np.uint16)
    prim = {"attributes": {"POSITION": pos, "NORMAL": nrm,
                           "TEXCOORD_0": b.accessor(uv_u8, U8, normalized=True),
                           "TEXCOORD_1": b.accessor(uv1_u16, U16, normalized=True),
                           "COLOR_0": b.accessor(col_u16, U16, normalized=True)},
            "indices": b.accessor(QUAD_I.astype(np.uint8), U8)}
    b.node(mesh=b.mesh(prim))
    scene = read(b.write_glb(tmp_path / "q.glb"))
    np.testing.assert_allclose(scene.vertices, QUAD_P)
    np.testing.assert_allclose(scene.normals, [[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, -1, 0]], atol=1e-6)
    np.testing.assert_allclose(scene.uvs, uv_u8 / 255.0, atol=1e-7)
    np.testing.assert_allclose(scene.uvs1, uv1_u16 / 65535.0, atol=1e-7)
    exp_col = np.concatenate([col_u16 / 65535.0, np.ones((4, 1))], axis=1)
    np.testing.assert_allclose(scene.colors, exp_col, atol=1e-7)


def test_non_indexed_strips_fans_and_skipped_lines(tmp_path):
    b = Builder()
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 2, 0], [1, 2, 0]], dtype=np.float32)
    p_acc = b.accessor(pts)
    fan_p = np.array([[0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1], [-1, 1, 1]], dtype=np.float32)
    mesh = b.mesh(
        {"attributes": {"POSITION": p_acc}},  # non-indexed triangle list: (0 1 2) (3 4 5)
        {"attributes": {"POSITION": p_acc}, "mode": 5},  # strip
        {"attributes": {"POSITION": b.accessor(fan_p)}, "mode": 6},  # fan
        {"attributes": {"POSITION": p_acc}, "mode": 1},  # lines: skipped
        {"attributes": {"POSITION": p_acc}, "mode": 0},  # points: skipped
    )
    b.node(mesh=mesh)
    with pytest.warns(UserWarning, match=r"not triangles: .*1 x lines, 1 x points") as rec:
        scene = read_gltf(b.write_glb(tmp_path / "modes.glb"))
    assert len([w for w in rec if "not triangles" in str(w.message)]) == 1
    tris = scene.vertices[scene.triangles]
    exp = np.concatenate([
        pts[[[0, 1, 2], [3, 4, 5]]],
        pts[[[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4]]],  # strip: odd triangles swap their last two
        fan_p[[[1, 2, 0], [2, 3, 0], [3, 4, 0]]],
    ])
    np.testing.assert_allclose(tris, exp)
    # the strip's and the fan's triangles all counter-clockwise seen from +z, as their first triangle
    gn = np.cross(tris[2:, 1] - tris[2:, 0], tris[2:, 2] - tris[2:, 0])
    assert (gn[:, 2] > 0).all()


def test_computed_normals_area_weighted_and_flat(tmp_path):
    # a tent: two triangles of different area sharing an edge
    p = np.array([[0, 0, 0], [0, 0, 1], [1, 1, 0], [-3, 0, 0.5]], dtype=np.float32)
    tri = np.array([[0, 1, 2], [1, 0, 3]], dtype=np.uint16)
    b = Builder()
    b.node(mesh=b.mesh({"attributes": {"POSITION": b.accessor(p)}, "indices": b.accessor(tri.reshape(-1), U16)}))
    path = b.write_glb(tmp_path / "tent.glb")
    scene = read(path)
    fn = [np.cross(p[t[1]] - p[t[0]], p[t[2]] - p[t[0]]).astype(np.float64) for t in tri]
    exp = np.zeros((4, 3))
    for f, t in zip(fn, tri):
        for v in t:
            exp[v] += f  # the cross product's length is twice the area: area weighting
    exp /= np.linalg.norm(exp, axis=1, keepdims=True)
    np.testing.assert_allclose(scene.normals, exp, atol=1e-6)
    flat = read_gltf(path, computed_normals="flat")
    assert flat.vertices.shape == (6, 3)
    np.testing.assert_allclose(flat.normals, np.repeat([f / np.linalg.norm(f) for f in fn], 3, axis=0), atol=1e-6)
    with pytest.raises(ValueError, match="computed_normals must be one of"):
        read_gltf(path, computed_normals="round")


# ---------------------------------------------------------------------------------------------------
# tangent frames


def _dp_du(p, uv):
    """dP/du of a triangle (the plane's gradient solve), independent of the reader's formula."""
    e = np.stack([p[1] - p[0], p[2] - p[0]])  # (2, 3)
    d = np.stack([uv[1] - uv[0], uv[2] - uv[0]])  # (2, 2): rows (du, dv)
    # e = d @ [dP/du; dP/dv]
    g = np.linalg.solve(d, e)
    return g[0], g[1]


@pytest.mark.parametrize("mirror,w_expected", [("none", 1.0), ("u", -1.0), ("v", -1.0), ("uv", 1.0)])
def test_tangents_from_uvs_on_mirrored_uvs(tmp_path, mirror, w_expected):
    uv = QUAD_UV.copy()
    if "u" in mirror:
        uv[:, 0] = 1.0 - uv[:, 0]
    if "v" in mirror:
        uv[:, 1] = 1.0 - uv[:, 1]
    b = Builder()
    b.node(mesh=b.mesh(quad_primitive(b, uvs=uv)))
    scene = read(b.write_glb(tmp_path / f"m_{mirror}.glb"))
    t, n = scene.tangents[:, :3].astype(np.float64), scene.normals.astype(np.float64)
    np.testing.assert_allclose(np.sum(t * n, axis=1), 0.0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-6)
    dpdu, dpdv = _dp_du(QUAD_P[:3].astype(np.float64), uv[:3].astype(np.float64))
    np.testing.assert_allclose(t, np.tile(dpdu / np.linalg.norm(dpdu), (4, 1)), atol=1e-6)
    np.testing.assert_array_equal(scene.tangents[:, 3], w_expected)
    # B = w * cross(N, T) points to the image's top: against dP/dv (glTF's v grows downwards)
    bt = scene.tangents[:, 3:] * np.cross(n, t)
    assert (bt @ dpdv < 0).all()


def test_tangents_random_triangles(tmp_path, rng):
    # separate random triangles with random UVs: T along dP/du (projected off N), handedness from dP/dv
    k = 20
    p = rng.normal(size=(k, 3, 3)).astype(np.float32)
    uv = rng.uniform(0, 1, size=(k, 3, 2)).astype(np.float32)
    b = Builder()
    b.node(mesh=b.mesh({"attributes": {"POSITION": b.accessor(p.reshape(-1, 3)),
                                       "TEXCOORD_0": b.accessor(uv.reshape(-1, 2))}}))
    scene = read(b.write_glb(tmp_path / "rand.glb"))
    t = scene.tangents[:, :3].reshape(k, 3, 3)
    w = scene.tangents[:, 3].reshape(k, 3)
    for i in range(k):
        pp, uu = p[i].astype(np.float64), uv[i].astype(np.float64)
        n = np.cross(pp[1] - pp[0], pp[2] - pp[0])
        n /= np.linalg.norm(n)
        dpdu, dpdv = _dp_du(pp, uu)
        tu = dpdu - n * (dpdu @ n)
        tu /= np.linalg.norm(tu)
        np.testing.assert_allclose(t[i], np.tile(tu, (3, 1)), atol=2e-4)
        assert (w[i] == np.sign(np.cross(n, tu) @ -dpdv)).all()


def test_tangents_without_uvs_are_still_a_frame(tmp_path):
    b = Builder()
    b.node(mesh=b.mesh(quad_primitive(b, uvs=None)))
    scene = read(b.write_glb(tmp_path / "nouv.glb"))
    t, n = scene.tangents[:, :3], scene.normals
    np.testing.assert_allclose(np.sum(t * n, axis=1), 0.0, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(scene.uvs, 0.0)


# ---------------------------------------------------------------------------------------------------
# materials, images, lights, cameras, extensions


def test_materials_textures_and_images(tmp_path):
    b = Builder()
    png_file = tmp_path / "tex image.png"
    png_file.write_bytes(PNG_1PX)
    b.doc["images"] = [
        {"uri": "tex%20image.png"},
        {"uri": "data:image/png;base64," + base64.b64encode(PNG_1PX).decode()},
        {"bufferView": b.view(PNG_1PX), "mimeType": "image/png"},
    ]
    b.doc["samplers"] = [{"wrapS": 33071, "wrapT": 33648, "magFilter": 9728}]
    b.doc["textures"] = [{"source": 0, "sampler": 0}, {"source": 1}, {"source": 2}]
    b.doc["extensionsUsed"] = ["KHR_materials_emissive_strength", "KHR_texture_transform",
                               "KHR_materials_transmission", "KHR_materials_ior"]
    b.doc["materials"] = [
        {"name": "painted",
         "pbrMetallicRoughness": {
             "baseColorFactor": [0.5, 0.25, 1.0, 0.75],
             "baseColorTexture": {"index": 0,
                                  "extensions": {"KHR_texture_transform": {
                                      "offset": [0.5, 0.0], "rotation": 0.3, "scale": [2.0, 3.0]}}},
             "metallicFactor": 0.2, "roughnessFactor": 0.6,
             "metallicRoughnessTexture": {"index": 1, "texCoord": 1}},
         "normalTexture": {"index": 2, "scale": 0.5},
         "occlusionTexture": {"index": 1, "strength": 0.25},
         "emissiveFactor": [1.0, 0.5, 0.0],
         "emissiveTexture": {"index": 2},
         "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}},
         "alphaMode": "MASK", "alphaCutoff": 0.3, "doubleSided": True},
        {"name": "plain"},
        {"name": "glass", "extensions": {"KHR_materials_transmission": {"transmissionFactor": 0.75},
                                         "KHR_materials_ior": {"ior": 1.33}}},
    ]
    b.node(mesh=b.mesh(quad_primitive(b, material=1), quad_primitive(b, material=0), quad_primitive(b),
                       quad_primitive(b, material=2)))
    scene = read(b.write_gltf(tmp_path / "mat.gltf"))

    assert [im.path for im in scene.images] == [png_file, None, None]
    assert scene.images[1].data == PNG_1PX and scene.images[2].data == PNG_1PX
    assert all(im.mime_type == "image/png" for im in scene.images)
    assert "images[0]" in scene.images[0].name
    m, plain, glass, dflt = scene.materials
    assert plain == Material(name="plain") and dflt == default_material()
    assert (glass.transmission_factor, glass.ior) == (0.75, 1.33) and (m.transmission_factor, m.ior) == (0.0, 1.5)
    np.testing.assert_array_equal(scene.material_ids, [1, 1, 0, 0, 3, 3, 2, 2])
    assert m.base_color_factor == (0.5, 0.25, 1.0, 0.75)
    assert (m.metallic_factor, m.roughness_factor) == (0.2, 0.6)
    bc = m.base_color_texture
    assert (bc.image, bc.wrap_s, bc.wrap_t, bc.filter, bc.color_space) == (0, "clamp", "mirror", "nearest", "srgb")
    assert (bc.uv_offset, bc.uv_rotation_rad, bc.uv_scale) == ((0.5, 0.0), 0.3, (2.0, 3.0))
    # KHR_texture_transform: T * R * S applied to a UV, written out here term by term
    c, s_ = math.cos(0.3), math.sin(0.3)
    u, v = 0.2, 0.7
    exp = (c * 2.0 * u + s_ * 3.0 * v + 0.5, -s_ * 2.0 * u + c * 3.0 * v)
    np.testing.assert_allclose(bc.transform_uv([[u, v]])[0], exp, atol=1e-12)
    mr = m.metallic_roughness_texture
    assert (mr.image, mr.texcoord, mr.wrap_s, mr.color_space) == (1, 1, "repeat", "linear")
    assert m.normal_texture.image == 2 and m.normal_scale == 0.5 and m.normal_texture.color_space == "linear"
    assert m.occlusion_texture.image == 1 and m.occlusion_strength == 0.25
    assert m.emissive_texture.color_space == "srgb" and m.emission == (4.0, 2.0, 0.0)
    assert (m.alpha_mode, m.alpha_cutoff, m.double_sided) == ("MASK", 0.3, True)

    table = MaterialTable.build(scene.materials, len(scene.images))
    assert len(table) == 4 and table.texture.shape == (4, 5)
    np.testing.assert_allclose(table.transmission_factor, [0.0, 0.0, 0.75, 0.0])
    np.testing.assert_allclose(table.ior, [1.5, 1.5, 1.33, 1.5])
    # base colour, metallic-roughness, normal, occlusion, emissive; the occlusion and metallic-roughness slots
    # read the same image with different UV sets, so they are two texture rows
    np.testing.assert_array_equal(table.texture[0], [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(table.texture[1:], -1)
    np.testing.assert_array_equal(table.tex_image, [0, 1, 2, 1, 2])
    np.testing.assert_array_equal(table.tex_srgb, [1, 0, 0, 0, 1])
    np.testing.assert_array_equal(table.tex_wrap[0], [1, 2])
    np.testing.assert_allclose(table.emission[0], [4.0, 2.0, 0.0])
    np.testing.assert_array_equal(table.alpha_mode, [1, 0, 0, 0])
    np.testing.assert_allclose(table.tex_uv_transform[1], [[1, 0, 0], [0, 1, 0]])


def test_lights_and_cameras(tmp_path):
    b = Builder()
    b.doc["extensionsUsed"] = ["KHR_lights_punctual"]
    b.doc["extensions"] = {"KHR_lights_punctual": {"lights": [
        {"type": "point", "color": [1.0, 0.5, 0.25], "intensity": 40.0, "range": 10.0, "name": "bulb"},
        {"type": "spot", "intensity": 100.0, "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.5}},
        {"type": "directional", "intensity": 3.0},
    ]}}
    b.doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "aspectRatio": 1.5, "znear": 0.1}},
                        {"type": "orthographic", "orthographic": {"xmag": 2, "ymag": 1, "znear": 0.01, "zfar": 50}}]
    rot = quat_of((0, 1, 0), math.pi / 2)  # -z becomes -x, +y stays
    r_m = axis_angle_matrix((0, 1, 0), math.pi / 2)
    pitch = axis_angle_matrix((1, 0, 0), -0.5)
    spot_node = b.node(root=False, translation=[0, 3, 0], rotation=quat_of((1, 0, 0), -0.5),
                       extensions={"KHR_lights_punctual": {"light": 1}})
    cam1 = b.node(root=False, camera=1, translation=[0, 0, 5])
    b.node(translation=[1, 2, 3], rotation=rot, extensions={"KHR_lights_punctual": {"light": 0}},
           children=[spot_node, cam1])
    b.node(rotation=quat_of((1, 0, 0), -math.pi / 2), extensions={"KHR_lights_punctual": {"light": 2}})
    b.node(camera=0, translation=[0, 1, 4], rotation=quat_of((1, 0, 0), -0.5))
    path = b.write_glb(tmp_path / "lc.glb")
    scene = read(path)

    parent = translate((1, 2, 3)) @ r_m
    point, spot, sun = scene.lights
    assert point.kind == "point" and point.name == "bulb" and point.color == (1.0, 0.5, 0.25)
    assert (point.intensity, point.range_m) == (40.0, 10.0)
    np.testing.assert_allclose(point.position, (1, 2, 3))
    np.testing.assert_allclose(point.direction, (-1, 0, 0), atol=1e-12)
    spot_m = parent @ translate((0, 3, 0)) @ pitch
    np.testing.assert_allclose(spot.position, spot_m[:3, 3], atol=1e-12)
    np.testing.assert_allclose(spot.direction, spot_m[:3, :3] @ (0, 0, -1), atol=1e-12)
    assert (spot.inner_cone_rad, spot.outer_cone_rad, spot.range_m) == (0.2, 0.5, None)
    assert sun.kind == "directional" and sun.intensity == 3.0
    np.testing.assert_allclose(sun.direction, (0, -1, 0), atol=1e-12)  # pointing straight down

    # cameras in depth-first order: the child of the first root, then the last root
    ortho, persp = scene.cameras
    assert scene.camera is ortho and ortho.kind == "orthographic" and (ortho.xmag, ortho.ymag) == (2.0, 1.0)
    np.testing.assert_allclose(ortho.eye, apply(parent, np.array([[0.0, 0, 5]]))[0], atol=1e-12)
    np.testing.assert_allclose(ortho.forward, (-1, 0, 0), atol=1e-12)
    cam_m = translate((0, 1, 4)) @ pitch
    second = read(path, camera_index=1).camera
    assert second.kind == "perspective" and second.camera == 0
    assert (second.yfov_rad, second.aspect, second.znear, second.zfar) == (0.8, 1.5, 0.1, None)
    np.testing.assert_allclose(second.eye, (0, 1, 4), atol=1e-12)
    np.testing.assert_allclose(second.forward, cam_m[:3, :3] @ (0, 0, -1), atol=1e-12)
    np.testing.assert_allclose(second.up, cam_m[:3, :3] @ (0, 1, 0), atol=1e-12)
    kw = second.camera_kwargs()
    assert kw["fov_y_deg"] == pytest.approx(math.degrees(0.8))
    np.testing.assert_allclose(np.subtract(kw["target"], kw["eye"]), second.forward, atol=1e-12)
    with pytest.raises(ValueError, match=r"camera_index must be an integer in \[0, 1\]"):
        read_gltf(path, camera_index=2)
    assert scene.num_triangles == 0 and scene.vertices.shape == (0, 3)


def test_extensions_used_one_warning_and_required_unsupported(tmp_path):
    b = Builder()
    b.node(mesh=b.mesh(quad_primitive(b)))
    b.doc["extensionsUsed"] = ["KHR_materials_clearcoat", "EXT_foo", "KHR_lights_punctual"]
    with pytest.warns(UserWarning) as rec:
        scene = read_gltf(b.write_glb(tmp_path / "ext.glb"))
    msgs = [str(w.message) for w in rec]
    assert len(msgs) == 1 and "EXT_foo" in msgs[0] and "KHR_materials_clearcoat" in msgs[0]
    assert "KHR_lights_punctual" not in msgs[0]
    assert scene.extensions_ignored == ("EXT_foo", "KHR_materials_clearcoat")
    b.doc["extensionsRequired"] = ["EXT_foo"]
    path = b.write_glb(tmp_path / "req.glb")
    with pytest.raises(ValueError, match=r"req\.glb.*requires unsupported extension.*EXT_foo"):
        read_gltf(path)


def test_file_without_scenes_and_texcoord_fallback(tmp_path):
    b = Builder()
    b.doc["images"] = [{"bufferView": b.view(PNG_1PX), "mimeType": "image/png"}]
    b.doc["textures"] = [{"source": 0}]
    b.doc["materials"] = [{"emissiveTexture": {"index": 0, "texCoord": 2}}]
    quad = b.mesh(quad_primitive(b, material=0))
    child = b.node(root=False, mesh=quad, translation=[0, 0, 1])
    b.node(mesh=quad, children=[child])
    del b.doc["scenes"], b.doc["scene"]
    with pytest.warns(UserWarning, match=r"emissiveTexture reads TEXCOORD_2; TEXCOORD_0 is used instead"):
        scene = read_gltf(b.write_glb(tmp_path / "noscene.glb"))
    # without scenes, every node that is nobody's child is a root: the child is placed once, under its parent
    assert scene.num_triangles == 4
    np.testing.assert_allclose(scene.vertices[4:], QUAD_P + [0, 0, 1])
    assert scene.materials[0].emissive_texture.texcoord == 0


# ---------------------------------------------------------------------------------------------------
# bad input


def _simple_glb(tmp_path, name="ok.glb") -> Path:
    b = Builder()
    b.node(mesh=b.mesh(quad_primitive(b)))
    return b.write_glb(tmp_path / name)


def test_bad_glb_containers(tmp_path):
    raw = _simple_glb(tmp_path).read_bytes()
    cases = {
        "trunc.glb": (raw[:-10], r"trunc\.glb: GLB is truncated"),
        "short.glb": (raw[:7], r"short\.glb: GLB is truncated"),
        "magic.glb": (b"glTX" + raw[4:], r"magic\.glb: not a GLB file: the magic"),
        "ver.glb": (raw[:4] + struct.pack("<I", 1) + raw[8:], r"ver\.glb: GLB version must be 2, got 1"),
        "chunk.glb": (raw[:12] + struct.pack("<I", 10 ** 6) + raw[16:], r"chunk\.glb: GLB is truncated: chunk 0"),
        "json.glb": (raw[:20] + b"x" + raw[21:], r"json\.glb: the GLB JSON chunk is not valid"),
    }
    for name, (data, pattern) in cases.items():
        p = tmp_path / name
        p.write_bytes(data)
        with pytest.raises(ValueError, match=pattern):
            read_gltf(p)


def test_bad_gltf_files(tmp_path):
    b = Builder()
    b.node(mesh=b.mesh(quad_primitive(b)))
    path = b.write_gltf(tmp_path / "nobin.gltf")
    (tmp_path / "nobin data.bin").unlink()
    with pytest.raises(ValueError, match=r"nobin\.gltf: buffers\[0\]: buffer file 'nobin%20data\.bin' is missing"):
        read_gltf(path)

    b.doc["accessors"][0]["count"] = 40
    with pytest.raises(ValueError, match=r"oob\.glb: accessors\[0\].*out of bounds"):
        read_gltf(b.write_glb(tmp_path / "oob.glb"))
    b.doc["accessors"][0]["count"] = 4

    b.doc["meshes"][0]["primitives"][0]["material"] = 3
    with pytest.raises(ValueError, match=r"mat\.glb: .*material must be an index into 'materials'"):
        read_gltf(b.write_glb(tmp_path / "mat.glb"))
    del b.doc["meshes"][0]["primitives"][0]["material"]

    idx = b.doc["meshes"][0]["primitives"][0]["indices"]
    view = b.doc["accessors"][idx]["bufferView"]
    off = b.doc["bufferViews"][view]["byteOffset"]
    b.bin[off:off + 2] = struct.pack("<H", 9)
    with pytest.raises(ValueError, match=r"idx\.glb: .*indices must be below the vertex count 4, got 9"):
        read_gltf(b.write_glb(tmp_path / "idx.glb"))

    b.doc["materials"] = [{"extensions": {"KHR_materials_ior": {"ior": 0.5}}}]
    b.doc["meshes"][0]["primitives"][0]["material"] = 0
    with pytest.raises(ValueError, match=r"ior\.glb: .*KHR_materials_ior\.ior must be a finite number in \[1\.0, 5\.0\]"):
        read_gltf(b.write_glb(tmp_path / "ior.glb"))
    b.doc["materials"] = [{"extensions": {"KHR_materials_transmission": {"transmissionFactor": "all"}}}]
    with pytest.raises(ValueError, match=r"KHR_materials_transmission\.transmissionFactor must be a finite number"):
        read_gltf(b.write_glb(tmp_path / "tr.glb"))
    del b.doc["meshes"][0]["primitives"][0]["material"]
    del b.doc["materials"]

    bad = tmp_path / "bad.gltf"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match=r"bad\.gltf: the file is not valid UTF-8 JSON"):
        read_gltf(bad)
    v1 = tmp_path / "v1.gltf"
    v1.write_text(json.dumps({"asset": {"version": "1.0"}}))
    with pytest.raises(ValueError, match=r"v1\.gltf: asset\.version must be '2\.x'"):
        read_gltf(v1)
    with pytest.raises(ValueError, match="path must be an existing .gltf or .glb file"):
        read_gltf(tmp_path / "absent.glb")


def test_material_model_validation():
    with pytest.raises(ValueError, match=r"metallic_factor must be in \[0\.0, 1\.0\], got 1\.5"):
        Material(metallic_factor=1.5)
    with pytest.raises(ValueError, match=r"base_color_factor must be 4 finite numbers"):
        Material(base_color_factor=(1, 1, 1))
    with pytest.raises(ValueError, match="alpha_mode must be one of"):
        Material(alpha_mode="opaque")
    with pytest.raises(ValueError, match="emissive_strength must be"):
        Material(emissive_strength=-1.0)
    with pytest.raises(ValueError, match=r"base_color_texture\.color_space must be 'srgb'"):
        Material(base_color_texture=TextureRef(0))
    with pytest.raises(ValueError, match=r"normal_texture\.color_space must be 'linear'"):
        Material(normal_texture=TextureRef(0, color_space="srgb"))
    with pytest.raises(ValueError, match="double_sided must be True or False"):
        Material(double_sided=1)
    with pytest.raises(ValueError, match=r"transmission_factor must be in \[0\.0, 1\.0\]"):
        Material(transmission_factor=1.5)
    with pytest.raises(ValueError, match=r"ior must be in \[1\.0, 5\.0\]"):
        Material(ior=0.5)
    with pytest.raises(ValueError, match="TextureRef.wrap_s must be one of"):
        TextureRef(0, wrap_s="wrap")
    with pytest.raises(ValueError, match=r"TextureRef.texcoord must be an integer in \[0, 1\]"):
        TextureRef(0, texcoord=2)
    with pytest.raises(ValueError, match=r"TextureRef.image must be an integer"):
        TextureRef(-1)
    with pytest.raises(ValueError, match="uv_rotation_rad must be a finite"):
        TextureRef(0, uv_rotation_rad=float("nan"))
    with pytest.raises(ValueError, match="exactly one of path and data"):
        ImageSource("x")
    with pytest.raises(ValueError, match="mime_type must be one of"):
        ImageSource("x", data=b"abc")
    assert ImageSource("x", data=b"abc", mime_type="image/jpeg").source == b"abc"
    with pytest.raises(ValueError, match=r"materials\[0\] \('m'\) base_color_texture\.image must be in \[0, 0\]"):
        MaterialTable.build([Material("m", base_color_texture=TextureRef(1, color_space="srgb"))], 1)
    with pytest.raises(ValueError, match="at least one Material"):
        MaterialTable.build([])


# ---------------------------------------------------------------------------------------------------
# the textured sample files


def _scenes_dir() -> Path:
    env = os.environ.get("FOVEAWARP_SCENES_DIR")
    return Path(env) if env else Path(__file__).resolve().parent.parent.parent / "shared" / "scenes"


REAL_FILES = {
    "Suzanne/Suzanne.gltf": 3936,
    "ClearcoatWicker/ClearcoatWicker.glb": 3072,
    "Barrel/barrel.glb": 1148,
    "CesiumMilkTruck/CesiumMilkTruck.glb": 3624,  # the wheels instanced twice (2,856 unique)
}


def _real(rel: str) -> Path:
    p = _scenes_dir() / "textured" / rel
    if not p.is_file():
        pytest.skip(f"sample file {rel} not found under {_scenes_dir()}")
    return p


@pytest.mark.parametrize("rel", list(REAL_FILES))
def test_real_files_against_trimesh(rel):
    trimesh = pytest.importorskip("trimesh")
    from scipy.spatial import cKDTree

    path = _real(rel)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ClearcoatWicker uses KHR_materials_clearcoat
        scene = read_gltf(path)
        ref = trimesh.load(path, force="scene")
    assert scene.num_triangles == REAL_FILES[rel]
    for a in (scene.vertices, scene.normals, scene.tangents, scene.uvs):
        assert np.isfinite(a).all()
    np.testing.assert_allclose(np.linalg.norm(scene.normals, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.sum(scene.normals * scene.tangents[:, :3], axis=1), 0.0, atol=1e-5)
    assert set(np.unique(scene.tangents[:, 3])) <= {-1.0, 1.0}
    assert scene.triangles.min() >= 0 and scene.triangles.max() < scene.vertices.shape[0]
    assert scene.material_ids.min() >= 0 and scene.material_ids.max() < len(scene.materials)
    MaterialTable.build(scene.materials, len(scene.images))  # every texture names an existing image
    assert any(m.base_color_texture is not None for m in scene.materials)
    for im in scene.images:
        head = im.path.read_bytes()[:4] if im.path is not None else im.data[:4]
        assert head in (b"\x89PNG", b"\xff\xd8\xff\xe0", b"\xff\xd8\xff\xe1", b"\xff\xd8\xff\xdb")

    # trimesh (world space, v flipped on load) as the reference: the same triangles and the same (position, uv)
    geoms = ref.dump()
    ref_tris = sum(len(g.faces) for g in geoms)
    assert ref_tris == scene.num_triangles
    ref_v = np.concatenate([g.vertices for g in geoms])
    ours = scene.vertices.astype(np.float64)
    size = float(np.ptp(ours, axis=0).max())
    d1, _ = cKDTree(ref_v).query(ours)
    d2, _ = cKDTree(ours).query(ref_v)
    assert d1.max() < 1e-5 * size and d2.max() < 1e-5 * size
    ref_c = np.concatenate([g.triangles_center for g in geoms])
    our_c = ours[scene.triangles].mean(axis=1)
    dc, _ = cKDTree(ref_c).query(our_c)
    assert dc.max() < 1e-5 * size
    with_uv = [g for g in geoms if getattr(g.visual, "uv", None) is not None]
    if with_uv:
        ref_pu = np.concatenate([np.concatenate([g.vertices, g.visual.uv * [1, -1] + [0, 1]], axis=1)
                                 for g in with_uv])
        our_pu = np.concatenate([ours, scene.uvs.astype(np.float64)], axis=1)
        ref_pu[:, :3] /= size
        our_pu[:, :3] /= size
        du, _ = cKDTree(our_pu).query(ref_pu)
        assert du.max() < 1e-5


def test_real_file_tangents_match_the_files_own(tmp_path):
    # Barrel ships tangents: drop them from its JSON chunk and compare the computed ones with the file's
    path = _real("Barrel/barrel.glb")
    raw = path.read_bytes()
    jlen = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + jlen])
    rest = raw[20 + jlen:]
    assert all("TANGENT" in p["attributes"] for m in doc["meshes"] for p in m["primitives"])
    for m in doc["meshes"]:
        for p in m["primitives"]:
            del p["attributes"]["TANGENT"]
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    out = tmp_path / "barrel_no_tangents.glb"
    out.write_bytes(struct.pack("<III", 0x46546C67, 2, 20 + len(js) + len(rest))
                    + struct.pack("<II", len(js), 0x4E4F534A) + js + rest)
    given, computed = read_gltf(path), read_gltf(out)
    np.testing.assert_array_equal(computed.tangents[:, 3], given.tangents[:, 3])
    cos = np.sum(computed.tangents[:, :3] * given.tangents[:, :3], axis=1)
    assert np.median(cos) > 0.999 and cos.min() > 0.9


def test_real_truck_instancing():
    path = _real("CesiumMilkTruck/CesiumMilkTruck.glb")
    scene = read_gltf(path)
    doc_tris = 0
    raw = path.read_bytes()
    doc = json.loads(raw[20:20 + struct.unpack_from("<I", raw, 12)[0]])
    for m in doc["meshes"]:
        for p in m["primitives"]:
            doc_tris += doc["accessors"][p["indices"]]["count"] // 3
    assert doc_tris == 2856 and scene.num_triangles == 3624
    wheels = [i for i, m in enumerate(scene.materials) if m.name == "wheels"]
    assert len(wheels) == 1
    assert int(np.sum(scene.material_ids == wheels[0])) == 2 * (3624 - 2856)
