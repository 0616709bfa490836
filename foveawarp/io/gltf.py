"""glTF 2.0 files (``.gltf`` with ``.bin``/``data:`` buffers and image files, or ``.glb``) -> host arrays.

:func:`read_gltf` returns a :class:`~foveawarp.io.scenedata.SceneData` (alias ``GltfScene``): the triangles of
the chosen scene merged in world space (each mesh placed once per node that uses it), the materials
(:class:`foveawarp.materials.Material`), the images (:class:`foveawarp.materials.ImageSource`, not decoded), the
``KHR_lights_punctual`` lights (:class:`~foveawarp.io.scenedata.LightData`, alias ``GltfLight``) and the cameras
(:class:`~foveawarp.io.scenedata.CameraData`, alias ``GltfCamera``). Every warning issued is also kept in
``SceneData.warnings``.

Supported:
    - containers: JSON ``.gltf`` with external buffers (relative URIs) or ``data:`` base64 URIs; binary ``.glb``
      (header, JSON chunk, BIN chunk; lengths checked).
    - accessors: every component type, normalized integers, ``byteStride``, sparse accessors, accessors without
      a buffer view (zeros); min/max are ignored.
    - nodes: TRS or matrix transforms composed down the tree; a mesh used by several nodes is placed by each.
    - primitives: mode 4 (triangles), 5 (strip) and 6 (fan), indexed or not; modes 0-3 (points, lines) are
      skipped with one warning. Attributes POSITION, NORMAL, TANGENT, TEXCOORD_0, TEXCOORD_1, COLOR_0.
    - extensions: ``KHR_lights_punctual``, ``KHR_materials_emissive_strength``, ``KHR_materials_transmission``
      (its factor; ``transmissionTexture`` is not read), ``KHR_materials_ior``, ``KHR_texture_transform``
      (kept on each :class:`~foveawarp.materials.TextureRef`, not applied to the vertex UVs),
      ``KHR_mesh_quantization`` (integer attributes are read as floats), ``EXT_texture_webp`` (the image index).
      Other extensions named in ``extensionsUsed`` are listed in one warning and ignored; one named in
      ``extensionsRequired`` that is not supported raises ``ValueError``.
Not supported: skins (a skinned mesh is placed by its node, in its bind pose), morph targets, animations (the
rest pose is read), TEXCOORD_2 and above (a texture reading one falls back to TEXCOORD_0 with a warning), the
other material extensions.

Conventions:
    - UVs are kept as the file stores them: (0, 0) is the image's top-left corner, v grows downwards (the
      convention of ``foveawarp.textures``). trimesh flips v on load (``v' = 1 - v``); this reader does not.
    - Normals are transformed by the inverse-transpose of the node matrix and renormalized; tangents by the
      matrix, with ``w`` negated where the matrix's determinant is negative, where the winding of the
      triangles is reversed too so that the front faces stay front faces.
    - Tangent frame: ``T = dP/du``; the bitangent ``B = w * cross(N, T)`` points to the image's top
      (``-dP/dv`` with glTF's v down), the frame glTF's normal maps (+Y up) and MikkTSpace use.
    - Missing normals are computed per vertex as the area-weighted sum of the face normals of the triangles that
      share it (``computed_normals="smooth"``), or per face, the vertices split (``"flat"``, glTF's rule).
      Missing tangents are computed from the UVs the normal map reads: per-triangle tangents summed per vertex,
      made orthogonal to the normal (Gram-Schmidt), handedness from the sign of the summed bitangent.
    - A primitive without a material gets glTF's default material, appended to the list when needed.
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import struct
import urllib.parse
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..config import show
from ..materials import ImageSource, Material, TextureRef, default_material
from .geometry import any_perpendicular as _any_perpendicular
from .geometry import compute_normals, compute_tangents
from .geometry import normalize_rows as _normalize_rows
from .scenedata import CameraData, LightData, SceneData, ShapeData

__all__ = ["GltfLight", "GltfCamera", "GltfScene", "read_gltf", "SUPPORTED_EXTENSIONS"]

SUPPORTED_EXTENSIONS = (
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_transmission",
    "KHR_materials_ior",
    "KHR_texture_transform",
    "KHR_mesh_quantization",
    "EXT_texture_webp",
)

_GLB_MAGIC = 0x46546C67  # b"glTF"
_CHUNK_JSON = 0x4E4F534A  # b"JSON"
_CHUNK_BIN = 0x004E4942  # b"BIN\0"

_COMPONENT_DTYPES = {
    5120: np.dtype("<i1"),
    5121: np.dtype("<u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
_TYPE_SHAPES = {"SCALAR": (1, 1), "VEC2": (2, 1), "VEC3": (3, 1), "VEC4": (4, 1),
                "MAT2": (2, 2), "MAT3": (3, 3), "MAT4": (4, 4)}
_WRAP = {10497: "repeat", 33071: "clamp", 33648: "mirror"}
_MAG_FILTER = {9728: "nearest", 9729: "linear"}
_MIME_BY_SUFFIX = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp"}


def _known(value, table) -> bool:
    """True when ``value`` is a str or int (not bool) among ``table``'s keys (JSON may hold any type there)."""
    return isinstance(value, (str, int)) and not isinstance(value, bool) and value in table


# the glTF names of the format-independent description types
GltfScene = SceneData
GltfLight = LightData
GltfCamera = CameraData


# ---------------------------------------------------------------------------------------------------
# container and buffers


class _Reader:
    """Parses one file: the JSON document, its buffers, views and accessors (decoded on demand, cached)."""

    def __init__(self, path: Path):
        self.path = path
        self.base = path.parent
        self.bin_chunk: Optional[bytes] = None
        raw = path.read_bytes()
        if raw[:4] == b"glTF" or path.suffix.lower() == ".glb":
            self.doc = self._parse_glb(raw)
        else:
            self.doc = self._parse_json(raw, "the file")
        if not isinstance(self.doc, dict):
            self.fail(f"the JSON document must be an object, got {type(self.doc).__name__}")
        self._buffers: dict = {}
        self._accessors: dict = {}

    def fail(self, what: str):
        raise ValueError(f"{self.path}: {what}")

    def _parse_json(self, raw: bytes, where: str):
        try:
            return json.loads(raw.decode("utf-8-sig"))
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            self.fail(f"{where} is not valid UTF-8 JSON ({e})")

    def _parse_glb(self, raw: bytes):
        n = len(raw)
        if n < 12:
            self.fail(f"GLB is truncated: {n} bytes, the header alone takes 12")
        magic, version, length = struct.unpack_from("<III", raw, 0)
        if magic != _GLB_MAGIC:
            self.fail(f"not a GLB file: the magic must be b'glTF', got {raw[:4]!r}")
        if version != 2:
            self.fail(f"GLB version must be 2, got {version}")
        if length > n:
            self.fail(f"GLB is truncated: the header gives a length of {length} bytes, the file has {n}")
        if length < n:
            self.fail(f"GLB length header ({length} bytes) does not match the file size ({n} bytes)")
        doc = None
        offset = 12
        index = 0
        while offset < length:
            if offset + 8 > length:
                self.fail(f"GLB is truncated: chunk {index} header at byte {offset} runs past the end ({length})")
            clen, ctype = struct.unpack_from("<II", raw, offset)
            start = offset + 8
            if start + clen > length:
                self.fail(f"GLB is truncated: chunk {index} (type 0x{ctype:08x}) of {clen} bytes at byte {start} "
                          f"runs past the end ({length})")
            data = raw[start:start + clen]
            if index == 0:
                if ctype != _CHUNK_JSON:
                    self.fail(f"GLB's first chunk must be JSON (0x{_CHUNK_JSON:08x}), got type 0x{ctype:08x}")
                doc = self._parse_json(data, "the GLB JSON chunk")
            elif ctype == _CHUNK_BIN and self.bin_chunk is None:
                self.bin_chunk = data
            offset = start + clen
            index += 1
        if doc is None:
            self.fail("GLB has no JSON chunk")
        return doc

    # -- JSON access with checks -----------------------------------------------------------------

    def items(self, key: str) -> list:
        v = self.doc.get(key, [])
        if not isinstance(v, list):
            self.fail(f"'{key}' must be an array, got {show(v)}")
        return v

    def item(self, key: str, index, where: str) -> dict:
        arr = self.items(key)
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(arr):
            self.fail(f"{where} must be an index into '{key}' in [0, {len(arr) - 1}], got {show(index)}")
        obj = arr[index]
        if not isinstance(obj, dict):
            self.fail(f"{key}[{index}] must be an object, got {show(obj)}")
        return obj

    def integer(self, obj: dict, key: str, where: str, default=None, lo: int = 0) -> int:
        v = obj.get(key, default)
        if v is None or isinstance(v, bool) or not isinstance(v, int) or v < lo:
            self.fail(f"{where}.{key} must be an integer >= {lo}, got {show(v)}")
        return v

    def number(self, obj: dict, key: str, where: str, default=None, lo=None, hi=None) -> float:
        v = obj.get(key, default)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        if ok and ((lo is not None and v < lo) or (hi is not None and v > hi)):
            ok = False
        if not ok:
            rng = f" in [{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
            self.fail(f"{where}.{key} must be a finite number{rng}, got {show(v)}")
        return float(v)

    def vector(self, obj: dict, key: str, where: str, default, n: int, lo=None, hi=None) -> tuple:
        v = obj.get(key, default)
        if not isinstance(v, list) or len(v) != n:
            self.fail(f"{where}.{key} must be an array of {n} numbers, got {show(v)}")
        return tuple(self.number({f"{key}[{i}]": c}, f"{key}[{i}]", where, lo=lo, hi=hi) for i, c in enumerate(v))

    # -- buffers, views, accessors --------------------------------------------------------------

    def _resolve_uri(self, uri: str, where: str):
        """(bytes, MIME type or None) of a ``data:`` URI, or the Path of a relative file URI."""
        if uri.startswith("data:"):
            head, sep, payload = uri.partition(",")
            if not sep or not head.endswith(";base64"):
                self.fail(f"{where}: a data URI must be base64 ('data:<mime>;base64,...'), got {show(uri[:40])}")
            try:
                data = base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError) as e:
                self.fail(f"{where}: the data URI's base64 does not decode ({e})")
            mime = head[5:-7] or None
            return data, mime
        parsed = urllib.parse.urlparse(uri)
        if parsed.scheme and len(parsed.scheme) > 1:  # one letter: a Windows drive
            self.fail(f"{where}: URI scheme {parsed.scheme!r} is not supported (allowed: relative paths, data:)")
        return self.base / urllib.parse.unquote(uri), None

    def buffer(self, index: int) -> bytes:
        if index in self._buffers:
            return self._buffers[index]
        where = f"buffers[{index}]"
        b = self.item("buffers", index, "bufferView.buffer")
        length = self.integer(b, "byteLength", where, lo=1)
        uri = b.get("uri")
        if uri is None:
            if self.bin_chunk is None:
                self.fail(f"{where} has no uri and the file has no GLB BIN chunk")
            data = self.bin_chunk
            name = "the GLB BIN chunk"
        else:
            if not isinstance(uri, str):
                self.fail(f"{where}.uri must be a string, got {show(uri)}")
            res, _ = self._resolve_uri(uri, where)
            if isinstance(res, Path):
                if not res.is_file():
                    self.fail(f"{where}: buffer file {uri!r} is missing (looked for {res})")
                data = res.read_bytes()
                name = f"buffer file {uri!r}"
            else:
                data = res
                name = "its data URI"
        if len(data) < length:
            self.fail(f"{where}: byteLength is {length} but {name} holds {len(data)} bytes")
        self._buffers[index] = data
        return data

    def view(self, index: int, where: str):
        """(bytes of the view, byte stride or None) of bufferViews[index]."""
        v = self.item("bufferViews", index, f"{where}.bufferView")
        w = f"bufferViews[{index}]"
        buf = self.integer(v, "buffer", w)
        offset = self.integer(v, "byteOffset", w, default=0)
        length = self.integer(v, "byteLength", w, lo=1)
        stride = v.get("byteStride")
        if stride is not None:
            stride = self.integer(v, "byteStride", w, lo=4)
            if stride > 252 or stride % 4:
                self.fail(f"{w}.byteStride must be a multiple of 4 in [4, 252], got {stride}")
        data = self.buffer(buf)
        blen = self.integer(self.item("buffers", buf, f"{w}.buffer"), "byteLength", f"buffers[{buf}]", lo=1)
        if offset + length > blen:
            self.fail(f"{w}: bytes [{offset}, {offset + length}) lie outside buffers[{buf}] "
                      f"(byteLength {blen})")
        return memoryview(data)[offset:offset + length], stride

    def _read_raw(self, view_index, byte_offset: int, count: int, dtype, rows: int, cols: int, where: str,
                  tight: bool = False) -> np.ndarray:
        """``count`` elements of ``rows x cols`` components as (count, rows * cols); matrix columns are stored
        one after another, each starting on a 4-byte boundary (glTF 2.0 spec 3.6.2.4)."""
        csize = dtype.itemsize
        col_bytes = rows * csize
        col_stride = col_bytes if cols == 1 else (col_bytes + 3) // 4 * 4
        elem = col_stride * (cols - 1) + col_bytes
        data, stride = self.view(view_index, where)
        if tight or stride is None:
            stride = elem
        need = byte_offset + stride * (count - 1) + elem if count else 0
        if need > len(data):
            self.fail(f"{where}: {count} elements of {elem} bytes (stride {stride}) from byte {byte_offset} need "
                      f"{need} bytes, bufferViews[{view_index}] holds {len(data)} (accessor out of bounds)")
        if count == 0:
            return np.zeros((0, rows * cols), dtype=dtype)
        if byte_offset % csize or stride % csize or col_stride % csize:
            self.fail(f"{where}: offsets must be multiples of the component size {csize}")
        arr = np.ndarray(shape=(count, cols, rows), dtype=dtype, buffer=data, offset=byte_offset,
                         strides=(stride, col_stride, csize))
        return np.array(arr).reshape(count, rows * cols)

    def accessor(self, index, where: str) -> np.ndarray:
        """The accessor's elements as (count, ncomp): float64 when float or normalized, else the integer type."""
        if isinstance(index, int) and not isinstance(index, bool) and index in self._accessors:
            return self._accessors[index]
        a = self.item("accessors", index, where)
        w = f"accessors[{index}]"
        ctype = a.get("componentType")
        if not _known(ctype, _COMPONENT_DTYPES):
            self.fail(f"{w}.componentType must be one of {sorted(_COMPONENT_DTYPES)}, got {show(ctype)}")
        dtype = _COMPONENT_DTYPES[ctype]
        atype = a.get("type")
        if not _known(atype, _TYPE_SHAPES):
            self.fail(f"{w}.type must be one of {list(_TYPE_SHAPES)}, got {show(atype)}")
        rows, cols = _TYPE_SHAPES[atype]
        count = self.integer(a, "count", w, lo=1)
        normalized = a.get("normalized", False)
        if not isinstance(normalized, bool):
            self.fail(f"{w}.normalized must be true or false, got {show(normalized)}")
        if normalized and ctype in (5125, 5126):
            self.fail(f"{w}.normalized is only allowed with 8- and 16-bit integer components, "
                      f"got componentType {ctype}")
        if "bufferView" in a:
            out = self._read_raw(a["bufferView"], self.integer(a, "byteOffset", w, default=0), count, dtype,
                                 rows, cols, w)
        else:
            out = np.zeros((count, rows * cols), dtype=dtype)
        sparse = a.get("sparse")
        if sparse is not None:
            out = self._apply_sparse(out, sparse, dtype, rows, cols, count, w)
        if normalized:
            # glTF 2.0 spec 3.11: signed c / (2^(b-1) - 1) clamped at -1, unsigned c / (2^b - 1)
            info = np.iinfo(dtype)
            out = out.astype(np.float64) / float(info.max)
            if info.min < 0:
                out = np.maximum(out, -1.0)
        elif dtype.kind == "f":
            out = out.astype(np.float64)
            if not np.isfinite(out).all():
                bad = tuple(int(i) for i in np.argwhere(~np.isfinite(out))[0])
                self.fail(f"{w} holds a non-finite value {out[bad]} at element {bad}")
        self._accessors[index] = out
        return out

    def _apply_sparse(self, out, sparse, dtype, rows, cols, count, w):
        ws = f"{w}.sparse"
        if not isinstance(sparse, dict):
            self.fail(f"{ws} must be an object, got {show(sparse)}")
        n = self.integer(sparse, "count", ws, lo=1)
        ind, val = sparse.get("indices"), sparse.get("values")
        if not isinstance(ind, dict) or not isinstance(val, dict):
            self.fail(f"{ws} must have 'indices' and 'values' objects")
        ictype = ind.get("componentType")
        if not _known(ictype, (5121, 5123, 5125)):
            self.fail(f"{ws}.indices.componentType must be 5121, 5123 or 5125, got {show(ictype)}")
        idx = self._read_raw(self.integer(ind, "bufferView", f"{ws}.indices"),
                             self.integer(ind, "byteOffset", f"{ws}.indices", default=0), n,
                             _COMPONENT_DTYPES[ictype], 1, 1, f"{ws}.indices", tight=True)[:, 0].astype(np.int64)
        if idx.size and idx.max() >= count:
            self.fail(f"{ws}.indices must be below the accessor's count {count}, got {int(idx.max())}")
        vals = self._read_raw(self.integer(val, "bufferView", f"{ws}.values"),
                              self.integer(val, "byteOffset", f"{ws}.values", default=0), n, dtype, rows, cols,
                              f"{ws}.values", tight=True)
        out = out.copy()
        out[idx] = vals
        return out


# ---------------------------------------------------------------------------------------------------
# transforms and geometry


def _quat_matrix(q) -> np.ndarray:
    x, y, z, w = q
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if n == 0.0:
        return np.eye(3)
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _strip_triangles(idx: np.ndarray) -> np.ndarray:
    """Triangle strip -> list (glTF 2.0 spec 3.7.2.1: triangle i is (i, i+1+i%2, i+2-i%2)); index-degenerate
    triangles (the strip's stitches) are dropped."""
    n = idx.shape[0] - 2
    if n <= 0:
        return np.zeros((0, 3), dtype=idx.dtype)
    i = np.arange(n)
    tri = np.stack([idx[i], idx[i + 1 + i % 2], idx[i + 2 - i % 2]], axis=1)
    keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
    return tri[keep]


def _fan_triangles(idx: np.ndarray) -> np.ndarray:
    """Triangle fan -> list (triangle i is (i+1, i+2, 0))."""
    n = idx.shape[0] - 2
    if n <= 0:
        return np.zeros((0, 3), dtype=idx.dtype)
    i = np.arange(n)
    return np.stack([idx[i + 1], idx[i + 2], np.full(n, idx[0])], axis=1)


@dataclass
class _LocalMesh:
    """One primitive group of a mesh in its object space, with normals and tangents complete."""

    positions: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    uvs: Optional[np.ndarray]
    uvs1: Optional[np.ndarray]
    colors: Optional[np.ndarray]
    triangles: np.ndarray
    material: int


# ---------------------------------------------------------------------------------------------------
# the reader


def read_gltf(path, *, camera_index: Optional[int] = None, scene_index: Optional[int] = None,
              computed_normals: str = "smooth") -> SceneData:
    """Read a ``.gltf`` or ``.glb`` file into world-space host arrays (see the module docstring).

    Args:
        path: the file.
        camera_index: which placed camera becomes ``GltfScene.camera``: an index into ``GltfScene.cameras``
            (the camera nodes in the scene's depth-first order); None = the first one (or no camera).
        scene_index: which of the file's scenes to read; None = the file's ``scene``, else the first.
        computed_normals: "smooth" (area-weighted vertex normals) or "flat" (face normals) for primitives
            without NORMAL.

    Raises:
        ValueError: the file is missing, malformed (truncated GLB, wrong magic, a missing buffer file, an
            accessor out of bounds, a bad index, ...) or requires an unsupported extension; the message names
            the file and what is wrong.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = _read_gltf(path, camera_index, scene_index, computed_normals)
    for w in caught:
        warnings.warn(w.message, w.category, stacklevel=2)
    scene.warnings = tuple(str(w.message) for w in caught)
    return scene


def _read_gltf(path, camera_index, scene_index, computed_normals) -> SceneData:
    if not isinstance(path, (str, Path)):
        raise ValueError(f"path must be a str or Path, got {show(path)}")
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"path must be an existing .gltf or .glb file, got {str(path)!r} (not found)")
    if computed_normals not in ("smooth", "flat"):
        raise ValueError(f"computed_normals must be one of ['smooth', 'flat'], got {show(computed_normals)}")
    r = _Reader(path)
    doc = r.doc

    asset = doc.get("asset")
    version = asset.get("version") if isinstance(asset, dict) else None
    if not isinstance(version, str) or not version.startswith("2."):
        r.fail(f"asset.version must be '2.x' (glTF 2.0), got {show(version)}")

    used = doc.get("extensionsUsed", [])
    required = doc.get("extensionsRequired", [])
    if not isinstance(used, list) or not isinstance(required, list):
        r.fail("extensionsUsed and extensionsRequired must be arrays of names")
    unsupported_required = [e for e in required if e not in SUPPORTED_EXTENSIONS]
    if unsupported_required:
        r.fail(f"requires unsupported extension(s) {unsupported_required} (supported: {list(SUPPORTED_EXTENSIONS)})")
    ignored = tuple(sorted({str(e) for e in used if e not in SUPPORTED_EXTENSIONS}))
    if ignored:
        warnings.warn(f"{path}: ignoring glTF extension(s) {list(ignored)}")

    images = _read_images(r)
    materials = _read_materials(r, len(images))
    light_defs = _read_light_defs(r)

    # -- the node tree ----------------------------------------------------------------------------
    scenes = r.items("scenes")
    nodes = r.items("nodes")
    if scene_index is None:
        scene_index = doc.get("scene", 0 if scenes else None)
    if scenes:
        sc = r.item("scenes", scene_index, "scene")
        roots = sc.get("nodes", [])
    elif scene_index is not None:
        r.fail(f"scene must be an index into 'scenes', got {show(scene_index)} (the file has no scenes)")
    else:
        # no scenes: every node that is no node's child is a root
        children = {c for nd in nodes if isinstance(nd, dict) for c in nd.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    if not isinstance(roots, list):
        r.fail(f"scenes[{scene_index}].nodes must be an array, got {show(roots)}")

    instances = []  # (mesh index, world matrix, node index)
    lights, cameras = [], []
    stack = [(n, np.eye(4), ()) for n in reversed(roots)]
    while stack:
        ni, parent, ancestors = stack.pop()
        node = r.item("nodes", ni, "node")
        if ni in ancestors:
            r.fail(f"nodes[{ni}] is its own ancestor (the node graph has a cycle)")
        world = parent @ _node_matrix(r, node, ni)
        if "mesh" in node:
            r.item("meshes", node["mesh"], f"nodes[{ni}].mesh")
            instances.append((node["mesh"], world, ni))
        if "camera" in node:
            cameras.append(_place_camera(r, node["camera"], world, ni))
        ext = node.get("extensions", {})
        if isinstance(ext, dict) and "KHR_lights_punctual" in ext:
            li = ext["KHR_lights_punctual"].get("light") if isinstance(ext["KHR_lights_punctual"], dict) else None
            if isinstance(li, bool) or not isinstance(li, int) or not 0 <= li < len(light_defs):
                r.fail(f"nodes[{ni}].extensions.KHR_lights_punctual.light must be an index in "
                       f"[0, {len(light_defs) - 1}], got {show(li)}")
            lights.append(_place_light(light_defs[li], world, ni))
        kids = node.get("children", [])
        if not isinstance(kids, list):
            r.fail(f"nodes[{ni}].children must be an array, got {show(kids)}")
        for c in reversed(kids):
            stack.append((c, world, ancestors + (ni,)))

    # -- meshes -------------------------------------------------------------------------------------
    skipped: dict = {}
    local_cache: dict = {}
    default_index = [None]

    def material_of(prim, where):
        if "material" in prim:
            r.item("materials", prim["material"], f"{where}.material")
            return prim["material"]
        if default_index[0] is None:
            default_index[0] = len(materials)
            materials.append(default_material())
        return default_index[0]

    parts, part_names = [], []
    for mesh_i, world, node_i in instances:
        if mesh_i not in local_cache:
            local_cache[mesh_i] = _read_mesh(r, mesh_i, material_of, skipped, computed_normals)
        mesh_name = r.items("meshes")[mesh_i].get("name")
        label = mesh_name if isinstance(mesh_name, str) and mesh_name else f"meshes[{mesh_i}]"
        for lm in local_cache[mesh_i]:
            parts.append(_to_world(lm, world))
            part_names.append(f"{label}@nodes[{node_i}]")
    if skipped:
        warnings.warn(f"{path}: skipped primitive(s) that are not triangles: "
                      + ", ".join(f"{n} x {k}" for k, n in sorted(skipped.items())), stacklevel=2)

    vert, nrm, tan, uv0, uv1, col, tri, mat = [], [], [], [], [], [], [], []
    any_uv1 = any(p.uvs1 is not None for p in parts)
    any_col = any(p.colors is not None for p in parts)
    base = 0
    tri_base = 0
    shapes = []
    for p, pname in zip(parts, part_names):
        nv = p.positions.shape[0]
        nt = p.triangles.shape[0]
        shapes.append(ShapeData(name=pname, kind="gltf", vertex_range=(base, base + nv),
                                triangle_range=(tri_base, tri_base + nt), material=int(p.material)))
        tri_base += nt
        vert.append(p.positions)
        nrm.append(p.normals)
        tan.append(p.tangents)
        uv0.append(p.uvs if p.uvs is not None else np.zeros((nv, 2)))
        if any_uv1:
            uv1.append(p.uvs1 if p.uvs1 is not None else np.zeros((nv, 2)))
        if any_col:
            col.append(p.colors if p.colors is not None else np.ones((nv, 4)))
        tri.append(p.triangles + base)
        mat.append(np.full(p.triangles.shape[0], p.material, dtype=np.int32))
        base += nv

    def cat(lst, width, dtype=np.float32):
        return np.concatenate(lst).astype(dtype) if lst else np.zeros((0, width), dtype=dtype)

    if base > np.iinfo(np.int32).max:
        r.fail(f"the scene has {base} vertices, more than int32 indices can address")
    if camera_index is not None:
        if isinstance(camera_index, bool) or not isinstance(camera_index, (int, np.integer)) \
                or not 0 <= camera_index < len(cameras):
            raise ValueError(f"camera_index must be an integer in [0, {len(cameras) - 1}] ({path} places "
                             f"{len(cameras)} camera(s)), got {show(camera_index)}")
    chosen = cameras[int(camera_index)] if camera_index is not None else (cameras[0] if cameras else None)
    return SceneData(
        path=path,
        vertices=cat(vert, 3),
        normals=cat(nrm, 3),
        tangents=cat(tan, 4),
        uvs=cat(uv0, 2),
        uvs1=cat(uv1, 2) if any_uv1 else None,
        colors=cat(col, 4) if any_col else None,
        triangles=np.concatenate(tri).astype(np.int32) if tri else np.zeros((0, 3), dtype=np.int32),
        material_ids=np.concatenate(mat) if mat else np.zeros(0, dtype=np.int32),
        materials=materials,
        images=images,
        lights=lights,
        cameras=cameras,
        camera=chosen,
        extensions_ignored=ignored,
        shapes=shapes,
    )


def _node_matrix(r: _Reader, node: dict, ni: int) -> np.ndarray:
    w = f"nodes[{ni}]"
    if "matrix" in node:
        m = r.vector(node, "matrix", w, None, 16)
        return np.array(m, dtype=np.float64).reshape(4, 4).T  # glTF stores column-major
    t = r.vector(node, "translation", w, [0.0, 0.0, 0.0], 3)
    q = r.vector(node, "rotation", w, [0.0, 0.0, 0.0, 1.0], 4)
    s = r.vector(node, "scale", w, [1.0, 1.0, 1.0], 3)
    m = np.eye(4)
    m[:3, :3] = _quat_matrix(q) * np.array(s)[None, :]  # T * R * S
    m[:3, 3] = t
    return m


def _read_mesh(r: _Reader, mesh_i: int, material_of, skipped: dict, computed_normals: str) -> list:
    mesh = r.item("meshes", mesh_i, "node.mesh")
    prims = mesh.get("primitives")
    if not isinstance(prims, list) or not prims:
        r.fail(f"meshes[{mesh_i}].primitives must be a non-empty array, got {show(prims)}")
    out = []
    for pi, prim in enumerate(prims):
        where = f"meshes[{mesh_i}].primitives[{pi}]"
        if not isinstance(prim, dict):
            r.fail(f"{where} must be an object, got {show(prim)}")
        mode = prim.get("mode", 4)
        if not _known(mode, (0, 1, 2, 3, 4, 5, 6)):
            r.fail(f"{where}.mode must be an integer in [0, 6], got {show(mode)}")
        attrs = prim.get("attributes")
        if not isinstance(attrs, dict):
            r.fail(f"{where}.attributes must be an object, got {show(attrs)}")
        if mode < 4:
            name = {0: "points", 1: "lines", 2: "line loop", 3: "line strip"}[mode]
            skipped[name] = skipped.get(name, 0) + 1
            continue
        if "POSITION" not in attrs:
            skipped["no POSITION"] = skipped.get("no POSITION", 0) + 1
            continue
        pos = r.accessor(attrs["POSITION"], f"{where}.attributes.POSITION")
        if pos.shape[1] != 3:
            r.fail(f"{where}.attributes.POSITION must be VEC3, got {pos.shape[1]} components")
        pos = pos.astype(np.float64)
        nv = pos.shape[0]

        def attr(name, ncomp):
            if name not in attrs:
                return None
            a = r.accessor(attrs[name], f"{where}.attributes.{name}")
            if a.shape[1] not in ncomp:
                r.fail(f"{where}.attributes.{name} must have {' or '.join(map(str, ncomp))} components, "
                       f"got {a.shape[1]}")
            if a.shape[0] != nv:
                r.fail(f"{where}.attributes.{name} has {a.shape[0]} elements, POSITION has {nv}")
            return a.astype(np.float64)

        nrm = attr("NORMAL", (3,))
        tan = attr("TANGENT", (4,))
        uv0 = attr("TEXCOORD_0", (2,))
        uv1 = attr("TEXCOORD_1", (2,))
        col = attr("COLOR_0", (3, 4))
        if col is not None and col.shape[1] == 3:
            col = np.concatenate([col, np.ones((nv, 1))], axis=1)

        if "indices" in prim:
            idx = r.accessor(prim["indices"], f"{where}.indices")
            if idx.shape[1] != 1 or idx.dtype.kind not in "u":
                r.fail(f"{where}.indices must be a SCALAR accessor of unsigned integers")
            idx = idx[:, 0].astype(np.int64)
            if idx.size and idx.max() >= nv:
                r.fail(f"{where}.indices must be below the vertex count {nv}, got {int(idx.max())}")
        else:
            idx = np.arange(nv, dtype=np.int64)
        if mode == 4:
            if idx.shape[0] % 3:
                r.fail(f"{where}: a triangle list needs a multiple of 3 indices, got {idx.shape[0]}")
            tri = idx.reshape(-1, 3)
        elif mode == 5:
            tri = _strip_triangles(idx)
        else:
            tri = _fan_triangles(idx)
        mat = material_of(prim, where)

        if nrm is None and computed_normals == "flat":
            # split the vertices so that each triangle has its own three
            flat = tri.reshape(-1)
            pos = pos[flat]
            uv0 = uv0[flat] if uv0 is not None else None
            uv1 = uv1[flat] if uv1 is not None else None
            col = col[flat] if col is not None else None
            tan = None  # glTF: provided tangents are ignored when normals are not given
            tri = np.arange(flat.shape[0], dtype=np.int64).reshape(-1, 3)
            nv = pos.shape[0]
        if nrm is None:
            nrm = compute_normals(pos, tri)
        else:
            nrm = _normalize_rows(nrm, (0.0, 0.0, 1.0))
        if tan is None:
            uv_for_tangents = _normal_map_uvs(r, mat, uv0, uv1)
            if uv_for_tangents is not None:
                tan = compute_tangents(pos, nrm, uv_for_tangents, tri)
            else:
                tan = np.concatenate([_any_perpendicular(nrm), np.ones((nv, 1))], axis=1)
        else:
            t = tan[:, :3] - nrm * np.sum(tan[:, :3] * nrm, axis=1, keepdims=True)
            t = np.where(np.linalg.norm(t, axis=1, keepdims=True) > 1e-12, t, _any_perpendicular(nrm))
            tan = np.concatenate([_normalize_rows(t, (1.0, 0.0, 0.0)),
                                  np.where(tan[:, 3:] < 0, -1.0, 1.0)], axis=1)
        for name, a in (("TEXCOORD_0", uv0), ("TEXCOORD_1", uv1), ("COLOR_0", col)):
            if a is not None and not np.isfinite(a).all():
                r.fail(f"{where}.attributes.{name} holds non-finite values")
        out.append(_LocalMesh(pos, nrm, tan, uv0, uv1, col, tri, mat))
    return out


def _normal_map_uvs(r: _Reader, mat_index: int, uv0, uv1):
    """The UV set the material's normal map reads (TEXCOORD_0 when it has none), or None without UVs."""
    mats = r.items("materials")
    texcoord = 0
    if mat_index < len(mats):
        nt = mats[mat_index].get("normalTexture")
        if isinstance(nt, dict):
            texcoord = nt.get("texCoord", 0)
    uv = uv1 if texcoord == 1 else uv0
    return uv if uv is not None else uv0


def _to_world(lm: _LocalMesh, world: np.ndarray) -> _LocalMesh:
    m3 = world[:3, :3]
    det = float(np.linalg.det(m3))
    pos = lm.positions @ m3.T + world[:3, 3]
    if abs(det) > 1e-300:
        nrm_m = np.linalg.inv(m3).T
    else:
        # a singular node matrix: its cofactor matrix (det * inverse-transpose) still maps normals
        nrm_m = np.stack([np.cross(m3[:, 1], m3[:, 2]), np.cross(m3[:, 2], m3[:, 0]),
                          np.cross(m3[:, 0], m3[:, 1])], axis=1)
    nrm = _normalize_rows(lm.normals @ nrm_m.T, (0.0, 0.0, 1.0))
    t = lm.tangents[:, :3] @ m3.T
    t = t - nrm * np.sum(t * nrm, axis=1, keepdims=True)
    t = np.where(np.linalg.norm(t, axis=1, keepdims=True) > 1e-12, t, _any_perpendicular(nrm))
    w = lm.tangents[:, 3:] * (-1.0 if det < 0 else 1.0)
    tan = np.concatenate([_normalize_rows(t, (1.0, 0.0, 0.0)), w], axis=1)
    tri = lm.triangles[:, [0, 2, 1]] if det < 0 else lm.triangles
    return _LocalMesh(pos, nrm, tan, lm.uvs, lm.uvs1, lm.colors, tri, lm.material)


# ---------------------------------------------------------------------------------------------------
# images, materials, lights, cameras


def _read_images(r: _Reader) -> list:
    out = []
    for i, im in enumerate(r.items("images")):
        w = f"images[{i}]"
        if not isinstance(im, dict):
            r.fail(f"{w} must be an object, got {show(im)}")
        label = im.get("name") or (im["uri"][:60] if isinstance(im.get("uri"), str) and
                                   not im["uri"].startswith("data:") else "")
        name = f"{r.path.name}#{w}" + (f" ({label})" if label else "")
        mime = im.get("mimeType")
        if "uri" in im:
            uri = im["uri"]
            if not isinstance(uri, str):
                r.fail(f"{w}.uri must be a string, got {show(uri)}")
            res, data_mime = r._resolve_uri(uri, w)
            if isinstance(res, Path):
                if not res.is_file():
                    r.fail(f"{w}: image file {uri!r} is missing (looked for {res})")
                out.append(ImageSource(name=name, path=res,
                                       mime_type=mime or _MIME_BY_SUFFIX.get(res.suffix.lower())))
            else:
                out.append(ImageSource(name=name, data=res, mime_type=_image_mime(r, w, mime or data_mime)))
        elif "bufferView" in im:
            data, _ = r.view(im["bufferView"], w)
            out.append(ImageSource(name=name, data=bytes(data), mime_type=_image_mime(r, w, mime)))
        else:
            r.fail(f"{w} must have a uri or a bufferView")
    return out


def _image_mime(r: _Reader, where: str, mime) -> str:
    allowed = ("image/png", "image/jpeg", "image/webp")
    if mime not in allowed:
        r.fail(f"{where}.mimeType must be one of {list(allowed)}, got {show(mime)}")
    return mime


def _texture_ref(r: _Reader, info, where: str, color_space: str, num_images: int) -> Optional[TextureRef]:
    if info is None:
        return None
    if not isinstance(info, dict):
        r.fail(f"{where} must be an object, got {show(info)}")
    tex = r.item("textures", info.get("index"), f"{where}.index")
    ti = info["index"]
    source = tex.get("source")
    ext = tex.get("extensions", {})
    if source is None and isinstance(ext, dict) and isinstance(ext.get("EXT_texture_webp"), dict):
        source = ext["EXT_texture_webp"].get("source")
    if source is None:
        warnings.warn(f"{r.path}: textures[{ti}] has no image source this reader can use; {where} is ignored",
                      stacklevel=2)
        return None
    if isinstance(source, bool) or not isinstance(source, int) or not 0 <= source < num_images:
        r.fail(f"textures[{ti}].source must be an index into 'images' in [0, {num_images - 1}], got {show(source)}")
    texcoord = info.get("texCoord", 0)
    if isinstance(texcoord, bool) or not isinstance(texcoord, int) or texcoord < 0:
        r.fail(f"{where}.texCoord must be an integer >= 0, got {show(texcoord)}")
    wrap_s = wrap_t = "repeat"
    filt = "linear"
    if "sampler" in tex:
        s = r.item("samplers", tex["sampler"], f"textures[{ti}].sampler")
        ws, wt = s.get("wrapS", 10497), s.get("wrapT", 10497)
        if not _known(ws, _WRAP) or not _known(wt, _WRAP):
            r.fail(f"samplers[{tex['sampler']}] wrapS/wrapT must be in {sorted(_WRAP)}, got {show(ws)}/{show(wt)}")
        wrap_s, wrap_t = _WRAP[ws], _WRAP[wt]
        mag = s.get("magFilter")
        filt = _MAG_FILTER[mag] if _known(mag, _MAG_FILTER) else "linear"
    offset, rotation, scale = (0.0, 0.0), 0.0, (1.0, 1.0)
    iext = info.get("extensions", {})
    tt = iext.get("KHR_texture_transform") if isinstance(iext, dict) else None
    if isinstance(tt, dict):
        wt_ = f"{where}.extensions.KHR_texture_transform"
        offset = r.vector(tt, "offset", wt_, [0.0, 0.0], 2)
        rotation = r.number(tt, "rotation", wt_, default=0.0)
        scale = r.vector(tt, "scale", wt_, [1.0, 1.0], 2)
        if "texCoord" in tt:
            texcoord = r.integer(tt, "texCoord", wt_)
    if texcoord > 1:
        # only TEXCOORD_0 and TEXCOORD_1 are read
        warnings.warn(f"{r.path}: {where} reads TEXCOORD_{texcoord}; TEXCOORD_0 is used instead", stacklevel=2)
        texcoord = 0
    return TextureRef(image=source, texcoord=texcoord, wrap_s=wrap_s, wrap_t=wrap_t, filter=filt,
                      color_space=color_space, uv_offset=offset, uv_rotation_rad=rotation, uv_scale=scale)


def _read_materials(r: _Reader, num_images: int) -> list:
    out = []
    for i, m in enumerate(r.items("materials")):
        w = f"materials[{i}]"
        if not isinstance(m, dict):
            r.fail(f"{w} must be an object, got {show(m)}")
        pbr = m.get("pbrMetallicRoughness", {})
        if not isinstance(pbr, dict):
            r.fail(f"{w}.pbrMetallicRoughness must be an object, got {show(pbr)}")
        wp_ = f"{w}.pbrMetallicRoughness"
        nt = m.get("normalTexture")
        ot = m.get("occlusionTexture")
        ext = m.get("extensions", {})
        es = ext.get("KHR_materials_emissive_strength") if isinstance(ext, dict) else None
        strength = 1.0
        if isinstance(es, dict):
            strength = r.number(es, "emissiveStrength", f"{w}.extensions.KHR_materials_emissive_strength",
                                default=1.0, lo=0.0)
        transmission, ior = 0.0, 1.5
        tr = ext.get("KHR_materials_transmission") if isinstance(ext, dict) else None
        if isinstance(tr, dict):
            transmission = r.number(tr, "transmissionFactor", f"{w}.extensions.KHR_materials_transmission",
                                    default=0.0, lo=0.0, hi=1.0)
        io_ = ext.get("KHR_materials_ior") if isinstance(ext, dict) else None
        if isinstance(io_, dict):
            ior = r.number(io_, "ior", f"{w}.extensions.KHR_materials_ior", default=1.5, lo=1.0, hi=5.0)
        alpha_mode = m.get("alphaMode", "OPAQUE")
        if alpha_mode not in ("OPAQUE", "MASK", "BLEND"):
            r.fail(f"{w}.alphaMode must be one of ['OPAQUE', 'MASK', 'BLEND'], got {show(alpha_mode)}")
        double_sided = m.get("doubleSided", False)
        if not isinstance(double_sided, bool):
            r.fail(f"{w}.doubleSided must be true or false, got {show(double_sided)}")
        name = m.get("name", "")
        out.append(Material(
            name=name if isinstance(name, str) else str(name),
            base_color_factor=r.vector(pbr, "baseColorFactor", wp_, [1.0, 1.0, 1.0, 1.0], 4, 0.0, 1.0),
            base_color_texture=_texture_ref(r, pbr.get("baseColorTexture"), f"{wp_}.baseColorTexture", "srgb",
                                            num_images),
            metallic_factor=r.number(pbr, "metallicFactor", wp_, default=1.0, lo=0.0, hi=1.0),
            roughness_factor=r.number(pbr, "roughnessFactor", wp_, default=1.0, lo=0.0, hi=1.0),
            metallic_roughness_texture=_texture_ref(r, pbr.get("metallicRoughnessTexture"),
                                                    f"{wp_}.metallicRoughnessTexture", "linear", num_images),
            normal_texture=_texture_ref(r, nt, f"{w}.normalTexture", "linear", num_images),
            normal_scale=r.number(nt, "scale", f"{w}.normalTexture", default=1.0) if isinstance(nt, dict) else 1.0,
            occlusion_texture=_texture_ref(r, ot, f"{w}.occlusionTexture", "linear", num_images),
            occlusion_strength=(r.number(ot, "strength", f"{w}.occlusionTexture", default=1.0, lo=0.0, hi=1.0)
                                if isinstance(ot, dict) else 1.0),
            emissive_factor=r.vector(m, "emissiveFactor", w, [0.0, 0.0, 0.0], 3, 0.0, 1.0),
            emissive_strength=strength,
            emissive_texture=_texture_ref(r, m.get("emissiveTexture"), f"{w}.emissiveTexture", "srgb", num_images),
            alpha_mode=alpha_mode,
            alpha_cutoff=r.number(m, "alphaCutoff", w, default=0.5, lo=0.0),
            double_sided=double_sided,
            transmission_factor=transmission,
            ior=ior,
        ))
    return out


def _read_light_defs(r: _Reader) -> list:
    ext = r.doc.get("extensions", {})
    lp = ext.get("KHR_lights_punctual") if isinstance(ext, dict) else None
    if lp is None:
        return []
    lights = lp.get("lights", []) if isinstance(lp, dict) else None
    if not isinstance(lights, list):
        r.fail(f"extensions.KHR_lights_punctual.lights must be an array, got {show(lights)}")
    out = []
    for i, li in enumerate(lights):
        w = f"extensions.KHR_lights_punctual.lights[{i}]"
        if not isinstance(li, dict):
            r.fail(f"{w} must be an object, got {show(li)}")
        kind = li.get("type")
        if kind not in ("point", "spot", "directional"):
            r.fail(f"{w}.type must be one of ['point', 'spot', 'directional'], got {show(kind)}")
        rng = li.get("range")
        if rng is not None:
            rng = r.number(li, "range", w, lo=0.0)
            if rng <= 0.0:
                r.fail(f"{w}.range must be > 0, got {rng}")
        inner = outer = 0.0
        if kind == "spot":
            spot = li.get("spot", {})
            if not isinstance(spot, dict):
                r.fail(f"{w}.spot must be an object, got {show(spot)}")
            outer = r.number(spot, "outerConeAngle", f"{w}.spot", default=math.pi / 4, lo=0.0, hi=math.pi / 2)
            inner = r.number(spot, "innerConeAngle", f"{w}.spot", default=0.0, lo=0.0, hi=outer)
        name = li.get("name", "")
        out.append(dict(name=name if isinstance(name, str) else str(name), kind=kind,
                        color=r.vector(li, "color", w, [1.0, 1.0, 1.0], 3, 0.0),
                        intensity=r.number(li, "intensity", w, default=1.0, lo=0.0),
                        range_m=rng, inner_cone_rad=inner, outer_cone_rad=outer))
    return out


def _axis(m: np.ndarray, v, fallback) -> tuple:
    d = m[:3, :3] @ np.asarray(v, dtype=np.float64)
    n = float(np.linalg.norm(d))
    return tuple(float(c) for c in d / n) if n > 1e-30 else tuple(fallback)


def _place_light(d: dict, world: np.ndarray, ni: int) -> GltfLight:
    return GltfLight(position=tuple(float(c) for c in world[:3, 3]),
                     direction=_axis(world, (0.0, 0.0, -1.0), (0.0, 0.0, -1.0)), node=ni, **d)


def _place_camera(r: _Reader, ci, world: np.ndarray, ni: int) -> GltfCamera:
    c = r.item("cameras", ci, f"nodes[{ni}].camera")
    w = f"cameras[{ci}]"
    kind = c.get("type")
    if kind not in ("perspective", "orthographic"):
        r.fail(f"{w}.type must be 'perspective' or 'orthographic', got {show(kind)}")
    p = c.get(kind)
    if not isinstance(p, dict):
        r.fail(f"{w}.{kind} must be an object, got {show(p)}")
    wk = f"{w}.{kind}"
    fwd = _axis(world, (0.0, 0.0, -1.0), (0.0, 0.0, -1.0))
    up = np.array(_axis(world, (0.0, 1.0, 0.0), (0.0, 1.0, 0.0)))
    f = np.array(fwd)
    up = up - f * float(up @ f)
    n = float(np.linalg.norm(up))
    up = up / n if n > 1e-12 else _any_perpendicular(f[None])[0]
    zfar = p.get("zfar")
    if kind == "perspective":
        yfov = r.number(p, "yfov", wk, lo=0.0, hi=math.pi)
        if not 0.0 < yfov < math.pi:
            r.fail(f"{wk}.yfov must be in (0, pi) radians, got {yfov}")
        aspect = r.number(p, "aspectRatio", wk, lo=0.0) if "aspectRatio" in p else None
        znear = r.number(p, "znear", wk, lo=0.0)
        xmag = ymag = 0.0
        zfar = r.number(p, "zfar", wk, lo=0.0) if zfar is not None else None
    else:
        yfov, aspect = 0.0, None
        xmag = r.number(p, "xmag", wk)
        ymag = r.number(p, "ymag", wk)
        znear = r.number(p, "znear", wk, lo=0.0)
        zfar = r.number(p, "zfar", wk, lo=0.0)
    name = c.get("name", "")
    return GltfCamera(name=name if isinstance(name, str) else str(name), kind=kind,
                      eye=tuple(float(v) for v in world[:3, 3]), forward=fwd, up=tuple(float(v) for v in up),
                      yfov_rad=yfov, aspect=aspect, znear=znear, zfar=zfar, xmag=xmag, ymag=ymag, camera=ci,
                      node=ni)
