"""Mesh files -> triangle arrays.

- Named meshes (``bunny``, ``spot``, ``teapot`` ship in the repository's ``assets/``, installed as
  ``foveawarp/assets/``; ``nefertiti`` and ``ogre`` are read from ``$FOVEAWARP_SCENES`` or a ``shared/scenes``
  folder): :func:`find_named_mesh`.
- PLY files whose faces are stored as triangle strips (``element tristrips`` with ``-1`` restarts and alternating
  winding), ASCII and binary: :func:`read_ply`, :func:`strips_to_triangles`.
- Scenes of several meshes with transforms (glTF / GLB, OBJ with several objects or materials, ...): each mesh is
  placed by its node transform and keeps its colour (glTF base colour factor times vertex colours, OBJ ``Kd``,
  PLY vertex or face colours), averaged per face: :func:`load_mesh_parts`. Textures are not read here; textured
  scene files go through the readers of ``foveawarp.io`` (:func:`scene_file_kind` says which files do).
- Named textured scenes (``suzanne``, ``wicker`` ship in ``assets/gltf-models/``; ``barrel``, ``milk-truck``,
  ``grey-white-room`` are read from the shared scenes folder, ``$FOVEAWARP_SCENES_DIR``): :func:`find_textured_scene`.

This module depends on NumPy, trimesh and ``config`` only (no scene classes), so ``scene`` and ``scenes`` can both
import it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Optional

import numpy as np

from .config import check_array, check_vec, show

__all__ = [
    "ASSET_MESHES",
    "NAMED_MESHES",
    "SCENE_FILE_EXTENSIONS",
    "TEXTURED_SCENES",
    "ASSET_TEXTURED_SCENES",
    "MeshPart",
    "assets_dir",
    "scene_search_dirs",
    "find_named_mesh",
    "named_mesh_help",
    "textured_scene_dirs",
    "find_textured_scene",
    "textured_scene_help",
    "obj_material_libraries",
    "scene_file_kind",
    "ply_has_tristrips",
    "read_ply",
    "strips_to_triangles",
    "load_mesh_parts",
    "load_mesh_arrays",
]

# named mesh -> file in the package's assets folder (small, redistributable; see assets/README.md)
ASSET_MESHES = {
    "bunny": "bunny.ply",
    "spot": "spot.ply",
    "teapot": "teapot.ply",
}

# named mesh -> file name in $FOVEAWARP_SCENES / shared/scenes (the original OBJ files)
NAMED_MESHES = {
    "bunny": "stanford-bunny.obj",
    "spot": "spot.obj",
    "nefertiti": "nefertiti.obj",
    "ogre": "ogre.obj",
    "teapot": "teapot.obj",
}

# the file extensions load_scene reads: .gltf / .glb (foveawarp.io.gltf), .obj (with an .mtl: foveawarp.io.obj),
# .xml (Mitsuba scenes: foveawarp.io.mitsuba), and .ply / .stl / .obj without materials as meshes on a ground
SCENE_FILE_EXTENSIONS = (".gltf", ".glb", ".obj", ".ply", ".stl", ".xml")

# named textured scene -> its file under the shared scenes folder's textured/ (see textured_scene_dirs)
TEXTURED_SCENES = {
    "suzanne": "Suzanne/Suzanne.gltf",
    "wicker": "ClearcoatWicker/ClearcoatWicker.glb",
    "barrel": "Barrel/barrel.glb",
    "milk-truck": "CesiumMilkTruck/CesiumMilkTruck.glb",
    "grey-white-room": "GreyWhiteRoom/scene.xml",
}

# the textured scenes whose licence (CC0) lets them ship: file in the package's assets folder
ASSET_TEXTURED_SCENES = {
    "suzanne": "gltf-models/Suzanne/Suzanne.gltf",
    "wicker": "gltf-models/ClearcoatWicker/ClearcoatWicker.glb",
}


def assets_dir() -> Path:
    """The folder of mesh files installed with the package: the ``foveawarp.assets`` package, which is the
    repository's top-level ``assets/`` in a source checkout (editable install or ``PYTHONPATH``) and
    ``foveawarp/assets`` in a wheel."""
    # a checkout beside this package comes first, so a checkout on PYTHONPATH reads its own assets, not those of
    # another editable install
    checkout = Path(__file__).resolve().parent.parent
    if (checkout / "assets" / "__init__.py").is_file() and (checkout / "pyproject.toml").is_file():
        return checkout / "assets"
    return Path(str(resources.files("foveawarp.assets")))


def scene_search_dirs() -> list:
    """Folders searched for named mesh files ("bunny", "spot", ...), in order: the package's assets folder,
    $FOVEAWARP_SCENES (os.pathsep separated), ./shared/scenes, ../shared/scenes, and the shared/scenes beside
    this checkout."""
    dirs = [assets_dir()]
    env = os.environ.get("FOVEAWARP_SCENES")
    if env:
        dirs += [Path(p) for p in env.split(os.pathsep) if p]
    here = Path(__file__).resolve().parent
    dirs += [Path("shared/scenes"), Path("../shared/scenes"), here.parent / "shared" / "scenes",
             here.parent.parent / "shared" / "scenes"]
    return dirs


def find_named_mesh(name: str) -> Optional[Path]:
    """The file of a named mesh: ``assets/<ASSET_MESHES[name]>`` when it ships, else the first of the search
    folders holding ``NAMED_MESHES[name]`` (an unknown name is looked up as a file name); None when absent."""
    if not isinstance(name, str):
        raise ValueError(f"name must be a named mesh {sorted(NAMED_MESHES)} or a file name, got {show(name)}")
    candidates = [f for f in (ASSET_MESHES.get(name), NAMED_MESHES.get(name, name)) if f]
    for d in scene_search_dirs():
        for fname in candidates:
            p = d / fname
            if p.is_file():
                return p
    return None


def named_mesh_help(name: str) -> str:
    """Where a named mesh was looked for, for error messages."""
    shipped = ", ".join(sorted(ASSET_MESHES))
    return (f"scene {name!r} needs {NAMED_MESHES.get(name, name)!r}, not found in the package assets "
            f"({shipped} ship there) nor in {[str(d) for d in scene_search_dirs()[1:]]}; set FOVEAWARP_SCENES to "
            f"the folder holding it")


def textured_scene_dirs() -> list:
    """Folders searched for the named textured scenes' files (:data:`TEXTURED_SCENES`), after the package's
    assets: with ``$FOVEAWARP_SCENES_DIR`` set, its ``textured/`` subfolder and the folder itself; otherwise
    ``shared/scenes/textured`` beside the checkout (``<repo>/../shared/scenes/textured``)."""
    env = os.environ.get("FOVEAWARP_SCENES_DIR")
    if env:
        return [Path(env) / "textured", Path(env)]
    return [Path(__file__).resolve().parent.parent.parent / "shared" / "scenes" / "textured"]


def find_textured_scene(name: str) -> Optional[Path]:
    """The file of a named textured scene: the shipped copy in the package's assets when there is one, else the
    first of :func:`textured_scene_dirs` holding ``TEXTURED_SCENES[name]``; None when absent."""
    if not isinstance(name, str) or name not in TEXTURED_SCENES:
        raise ValueError(f"name must be a named textured scene {sorted(TEXTURED_SCENES)}, got {show(name)}")
    if name in ASSET_TEXTURED_SCENES:
        p = assets_dir() / ASSET_TEXTURED_SCENES[name]
        if p.is_file():
            return p
    for d in textured_scene_dirs():
        p = d / TEXTURED_SCENES[name]
        if p.is_file():
            return p
    return None


def textured_scene_help(name: str) -> str:
    """Where a named textured scene was looked for and how to point at it, for error messages."""
    shipped = ", ".join(sorted(ASSET_TEXTURED_SCENES))
    return (f"scene {name!r} needs {TEXTURED_SCENES.get(name, name)!r}, not found in the package assets "
            f"({shipped} ship there) nor in {[str(d) for d in textured_scene_dirs()]}; set FOVEAWARP_SCENES_DIR "
            f"to the shared scenes folder (the one holding textured/{TEXTURED_SCENES.get(name, name)})")


def obj_material_libraries(path) -> list:
    """The material libraries (``mtllib``) an OBJ file names that exist beside it, as Paths (empty when none)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError:
        return []
    out = []
    for line in raw.splitlines():
        tok = line.strip()
        if not tok.startswith(b"mtllib"):
            continue
        name = tok[6:].strip().decode("utf-8", errors="replace")
        if name and (p.parent / name).is_file():
            out.append(p.parent / name)
    return out


def _obj_reader_available() -> bool:
    try:
        from .io import obj
    except ImportError:
        return False
    return callable(getattr(obj, "read_obj", None))


def scene_file_kind(path) -> str:
    """How ``load_scene`` reads the file ``path``: "scene" (a scene file with materials: .gltf, .glb, .xml, and
    .obj with an existing .mtl once ``foveawarp.io.obj.read_obj`` is there) or "mesh" (.ply, .stl, .obj without
    materials: a mesh on a ground). ValueError naming the file and :data:`SCENE_FILE_EXTENSIONS` for any other
    extension."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"scene path must be a file path (str or os.PathLike), got {show(path)}")
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in SCENE_FILE_EXTENSIONS:
        raise ValueError(f"scene file {str(p)!r} could not be read: its extension {ext or '(none)'!r} is not one of "
                         f"{list(SCENE_FILE_EXTENSIONS)}")
    if ext in (".gltf", ".glb", ".xml"):
        return "scene"
    if ext == ".obj" and obj_material_libraries(p) and _obj_reader_available():
        return "scene"
    return "mesh"


# ---------------------------------------------------------------------------------------------------
# PLY with triangle strips

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def strips_to_triangles(strips) -> np.ndarray:
    """Triangles of triangle strips: ``strips`` is a 1-D integer index list where ``-1`` restarts a strip (or a
    list of such lists). Within each strip the k-th triangle is ``(s[k], s[k+1], s[k+2])`` for even k and
    ``(s[k+1], s[k], s[k+2])`` for odd k, so all triangles of a strip share one winding. Degenerate triangles
    (a repeated index, used to join strips) are dropped. Returns (F, 3) int64."""
    if isinstance(strips, (list, tuple)) and strips and all(np.ndim(s) == 1 for s in strips):
        parts = [check_array("strips", s) for s in strips]
        for s in parts:
            if s.size and s.dtype.kind not in "iu":
                raise ValueError(f"strips must be integer vertex indices (-1 = restart), got dtype {s.dtype}")
        s = np.concatenate([np.concatenate([p.astype(np.int64), [-1]]) for p in parts]) if parts else np.zeros(0)
    else:
        s = check_array("strips", strips)
        if s.ndim != 1:
            raise ValueError(f"strips must be a 1-D index list (-1 = restart) or a list of them, got shape {s.shape}")
    if s.size and s.dtype.kind not in "iu":
        raise ValueError(f"strips must be integer vertex indices (-1 = restart), got dtype {s.dtype}")
    s = s.astype(np.int64)
    if s.size and s.min() < -1:
        i = int(np.argmax(s < -1))
        raise ValueError(f"strips must hold vertex indices >= 0 or -1 (restart), got {int(s[i])} at index ({i},)")
    n = s.size
    if n < 3:
        return np.zeros((0, 3), dtype=np.int64)
    pos = np.arange(n)
    # start of the strip each position belongs to: one past the last -1 at or before it
    start = np.maximum.accumulate(np.where(s == -1, pos + 1, 0))
    k = pos[: n - 2]
    a, b, c = s[k], s[k + 1], s[k + 2]
    valid = (a >= 0) & (b >= 0) & (c >= 0)
    odd = ((k - start[k]) % 2) == 1
    tri = np.stack([np.where(odd, b, a), np.where(odd, a, b), c], axis=1)
    keep = valid & (a != b) & (b != c) & (a != c)
    return np.ascontiguousarray(tri[keep])


def _ply_header(raw: bytes, where: str):
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise ValueError(f"scene file {where!r} is not a PLY file (no 'ply' magic or no end_header)")
    nl = raw.find(b"\n", end)
    body_start = len(raw) if nl < 0 else nl + 1
    fmt = None
    elements = []  # [name, count, [(prop name, type, list count type or None)]]
    for line in raw[:end].decode("ascii", errors="replace").splitlines()[1:]:
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        try:
            if tok[0] == "format":
                fmt = tok[1]
            elif tok[0] == "element":
                elements.append([tok[1], int(tok[2]), []])
            elif tok[0] == "property":
                if not elements:
                    raise ValueError("property before any element")
                if tok[1] == "list":
                    elements[-1][2].append((tok[4], _PLY_TYPES[tok[3]], _PLY_TYPES[tok[2]]))
                else:
                    elements[-1][2].append((tok[2], _PLY_TYPES[tok[1]], None))
        except (IndexError, KeyError, ValueError) as e:
            raise ValueError(f"scene file {where!r} has an unreadable PLY header line {line!r} ({e})") from None
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ValueError(f"scene file {where!r} PLY format must be one of ['ascii', 'binary_little_endian', "
                         f"'binary_big_endian'], got {fmt!r}")
    for name, count, _ in elements:
        if count < 0:
            raise ValueError(f"scene file {where!r} PLY element {name!r} count must be >= 0, got {count}")
    return fmt, elements, body_start


def _read_binary(buf: memoryview, off: int, elements, order: str, where: str) -> dict:
    out = {}
    for name, count, props in elements:
        if all(p[2] is None for p in props):
            dt = np.dtype([(p[0], order + p[1]) for p in props])
            need = dt.itemsize * count
            if off + need > len(buf):
                raise ValueError(f"scene file {where!r} is truncated in PLY element {name!r}")
            arr = np.frombuffer(buf, dtype=dt, count=count, offset=off)
            out[name] = {p[0]: arr[p[0]] for p in props}
            off += need
            continue
        if len(props) == 1 and count > 0:  # one list property (faces, strips): try one count for all items
            pname, typ, ctyp = props[0]
            cdt = np.dtype(order + ctyp)
            if off + cdt.itemsize <= len(buf):
                n0 = int(np.frombuffer(buf, dtype=cdt, count=1, offset=off)[0])
                rec = np.dtype([("n", order + ctyp), ("v", order + typ, (max(n0, 0),))])
                if n0 >= 0 and off + rec.itemsize * count <= len(buf):
                    arr = np.frombuffer(buf, dtype=rec, count=count, offset=off)
                    if np.all(arr["n"] == n0):
                        out[name] = {pname: arr["v"].astype(np.int64)}
                        off += rec.itemsize * count
                        continue
        cols = {p[0]: [] for p in props}
        for _ in range(count):
            for pname, typ, ctyp in props:
                if ctyp is None:
                    dt = np.dtype(order + typ)
                    if off + dt.itemsize > len(buf):
                        raise ValueError(f"scene file {where!r} is truncated in PLY element {name!r}")
                    cols[pname].append(np.frombuffer(buf, dtype=dt, count=1, offset=off)[0])
                    off += dt.itemsize
                else:
                    cdt, vdt = np.dtype(order + ctyp), np.dtype(order + typ)
                    if off + cdt.itemsize > len(buf):
                        raise ValueError(f"scene file {where!r} is truncated in PLY element {name!r}")
                    n = int(np.frombuffer(buf, dtype=cdt, count=1, offset=off)[0])
                    off += cdt.itemsize
                    if n < 0 or off + n * vdt.itemsize > len(buf):
                        raise ValueError(f"scene file {where!r} is truncated in PLY element {name!r}")
                    cols[pname].append(np.frombuffer(buf, dtype=vdt, count=n, offset=off).astype(np.int64))
                    off += n * vdt.itemsize
        out[name] = {k: (v if any(p[0] == k and p[2] is not None for p in props) else np.asarray(v))
                     for k, v in cols.items()}
    return out


def _read_ascii(text: str, elements, where: str) -> dict:
    tok = text.split()
    i = 0
    out = {}
    for name, count, props in elements:
        if all(p[2] is None for p in props):
            k = len(props)
            if i + k * count > len(tok):
                raise ValueError(f"scene file {where!r} is truncated in PLY element {name!r}")
            try:
                block = np.asarray(tok[i:i + k * count], dtype=np.float64).reshape(count, k)
            except ValueError as e:
                raise ValueError(f"scene file {where!r} has a non-numeric value in PLY element {name!r} ({e})") \
                    from None
            out[name] = {p[0]: block[:, j] for j, p in enumerate(props)}
            i += k * count
            continue
        cols = {p[0]: [] for p in props}
        try:
            for _ in range(count):
                for pname, _typ, ctyp in props:
                    if ctyp is None:
                        cols[pname].append(float(tok[i]))
                        i += 1
                    else:
                        n = int(tok[i])
                        if n < 0 or i + 1 + n > len(tok):
                            raise IndexError
                        cols[pname].append(np.asarray([int(t) for t in tok[i + 1:i + 1 + n]], dtype=np.int64))
                        i += 1 + n
        except IndexError:
            raise ValueError(f"scene file {where!r} is truncated in PLY element {name!r}") from None
        except ValueError as e:
            raise ValueError(f"scene file {where!r} has a non-numeric value in PLY element {name!r} ({e})") from None
        out[name] = {k: (v if any(p[0] == k and p[2] is not None for p in props) else np.asarray(v))
                     for k, v in cols.items()}
    return out


def ply_has_tristrips(path) -> bool:
    """Whether the PLY header of ``path`` declares an ``element tristrips`` (False for other or unreadable
    files)."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"scene path must be a file path (str or os.PathLike), got {show(path)}")
    try:
        with open(path, "rb") as fh:
            head = fh.read(65536)
    except OSError:
        return False
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return False
    return any(line.split()[:2] == [b"element", b"tristrips"] for line in head[:end].splitlines())


def read_ply(path) -> dict:
    """Read a PLY file (ASCII, binary little or big endian) with its own parser, for what trimesh does not read:
    ``element tristrips`` (triangle strips, ``-1`` restarts, alternating winding) as well as ``element face``
    (polygons, fan-triangulated). Returns ``{"vertices": (V, 3) float64, "faces": (F, 3) int64,
    "colors": (V, 3) float32 in [0, 1] or None, "normals": (V, 3) float64 or None}``.

    ValueError for a path that is not a readable file, a file that is not PLY, a truncated body, vertices that are
    not finite, indices outside [0, V - 1] (``-1`` allowed in strips), or no triangle at all."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"scene path must be a file path (str or os.PathLike), got {show(path)}")
    where = str(path)
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"scene path {where!r} " + ("is not a file" if p.exists() else "does not exist"))
    raw = p.read_bytes()
    fmt, elements, body = _ply_header(raw, where)
    if fmt == "ascii":
        data = _read_ascii(raw[body:].decode("ascii", errors="replace"), elements, where)
    else:
        data = _read_binary(memoryview(raw), body, elements, "<" if fmt == "binary_little_endian" else ">", where)
    vert = data.get("vertex")
    if vert is None or not all(k in vert for k in ("x", "y", "z")):
        raise ValueError(f"scene file {where!r} PLY has no 'vertex' element with x, y, z properties")
    v = np.stack([np.asarray(vert[k], dtype=np.float64) for k in ("x", "y", "z")], axis=1)
    nv = v.shape[0]
    if not np.all(np.isfinite(v)):
        raise ValueError(f"scene file {where!r} has non-finite vertex coordinates")
    tris = []
    strips = data.get("tristrips")
    if strips is not None:
        key = "vertex_indices" if "vertex_indices" in strips else next(iter(strips), None)
        if key is not None:
            for j, s in enumerate(strips[key]):
                s = np.asarray(s, dtype=np.int64)
                bad = (s < -1) | (s >= nv)
                if bad.any():
                    i = int(np.argmax(bad))
                    raise ValueError(f"scene file {where!r} tristrips[{j}].{key} must be in [-1, {nv - 1}], got "
                                     f"{int(s[i])} at index ({i},)")
                tris.append(strips_to_triangles(s))
    faces = data.get("face")
    if faces is not None:
        key = "vertex_indices" if "vertex_indices" in faces else "vertex_index" if "vertex_index" in faces else None
        polys = faces.get(key) if key is not None else None
        if isinstance(polys, np.ndarray) and polys.ndim == 2:  # all polygons of one size (binary fast path)
            bad = (polys < 0) | (polys >= nv)
            if bad.any():
                j, i = (int(x) for x in np.argwhere(bad)[0])
                raise ValueError(f"scene file {where!r} face[{j}].{key} must be in [0, {nv - 1}], got "
                                 f"{int(polys[j, i])} at index ({i},)")
            if polys.shape[1] >= 3:  # fan per polygon, in polygon order
                m = polys.shape[1] - 2
                fan = np.stack([np.repeat(polys[:, :1], m, axis=1), polys[:, 1:-1], polys[:, 2:]], axis=2)
                tris.append(fan.reshape(-1, 3))
        elif polys is not None:
            for j, poly in enumerate(polys):
                poly = np.asarray(poly, dtype=np.int64)
                if poly.size and (poly.min() < 0 or poly.max() >= nv):
                    i = int(np.argmax((poly < 0) | (poly >= nv)))
                    raise ValueError(f"scene file {where!r} face[{j}].{key} must be in [0, {nv - 1}], got "
                                     f"{int(poly[i])} at index ({i},)")
                if poly.size >= 3:
                    tris.append(np.stack([np.full(poly.size - 2, poly[0]), poly[1:-1], poly[2:]], axis=1))
    f = np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)
    if f.shape[0] == 0:
        raise ValueError(f"scene file {where!r} holds no triangle mesh (no non-degenerate triangle in its "
                         f"tristrips or faces)")
    colors = None
    if all(k in vert for k in ("red", "green", "blue")):
        c = np.stack([np.asarray(vert[k], dtype=np.float64) for k in ("red", "green", "blue")], axis=1)
        is_float = any(pp[0] == "red" and pp[1].startswith("f") for e in elements if e[0] == "vertex"
                       for pp in e[2])
        colors = np.clip(c if is_float else c / 255.0, 0.0, 1.0).astype(np.float32)
    normals = None
    if all(k in vert for k in ("nx", "ny", "nz")):
        normals = np.stack([np.asarray(vert[k], dtype=np.float64) for k in ("nx", "ny", "nz")], axis=1)
    return {"vertices": v, "faces": f, "colors": colors, "normals": normals}


# ---------------------------------------------------------------------------------------------------
# any mesh file: parts with transforms and colours


@dataclass
class MeshPart:
    """One mesh of a file, placed in the file's world frame.

    Attributes:
        name: the node (or geometry) name.
        vertices: (V, 3) float64, the node transform applied.
        faces: (F, 3) int64 indices into ``vertices``.
        albedo: (F, 3) float32 linear RGB in [0, 1] (per face; vertex colours are averaged per face), or None
            when the file gives this mesh no colour.
        normals: (V, 3) float64 smooth vertex normals (transformed), or None.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    albedo: Optional[np.ndarray]
    normals: Optional[np.ndarray]


def _unit_colors(c) -> np.ndarray:
    """Colours as stored by trimesh (uint8 0-255, uint16 0-65535, or float 0-1) -> float RGB in [0, 1]."""
    c = np.asarray(c)
    if c.dtype.kind == "f":
        out = c.astype(np.float64)
    elif c.dtype == np.uint16:
        out = c.astype(np.float64) / 65535.0
    else:
        out = c.astype(np.float64) / 255.0
    return np.clip(np.nan_to_num(out[..., :3], nan=0.0), 0.0, 1.0)


def _part_albedo(g) -> Optional[np.ndarray]:
    """Per-face base colour of a trimesh.Trimesh, or None when it has none (see module docstring)."""
    import trimesh

    vis = g.visual
    faces = np.asarray(g.faces, dtype=np.int64)
    nf = faces.shape[0]
    kind = getattr(vis, "kind", None)
    if isinstance(vis, trimesh.visual.ColorVisuals):
        if kind == "face":
            return _unit_colors(vis.face_colors)
        if kind == "vertex":
            return _unit_colors(vis.vertex_colors)[faces].mean(axis=1)
        return None
    if isinstance(vis, trimesh.visual.TextureVisuals):
        mat = getattr(vis, "material", None)
        factor = None
        if isinstance(mat, trimesh.visual.material.PBRMaterial):
            if mat.baseColorFactor is not None:
                factor = _unit_colors(mat.baseColorFactor)
        elif isinstance(mat, trimesh.visual.material.SimpleMaterial):
            d = getattr(mat, "diffuse", None)
            default = trimesh.visual.material.SimpleMaterial().diffuse
            # trimesh gives an OBJ without a material library a default material (grey 102): that is no colour
            if d is not None and not np.array_equal(np.asarray(d), np.asarray(default)):
                factor = _unit_colors(d)
        vc = None
        attrs = getattr(vis, "vertex_attributes", None)
        if attrs is not None and "color" in attrs:
            c = np.asarray(attrs["color"])
            if c.ndim == 2 and c.shape[0] == len(g.vertices) and c.shape[1] >= 3:
                vc = _unit_colors(c)[faces].mean(axis=1)
        if factor is None and vc is None:
            return None
        col = np.ones((nf, 3)) if vc is None else vc
        return col * (np.ones(3) if factor is None else factor)
    return None


def _check_part(where, v, f):
    if not np.all(np.isfinite(v)):
        raise ValueError(f"scene file {where!r} has non-finite vertex coordinates")


def load_mesh_parts(path) -> list:
    """Read a mesh file into :class:`MeshPart` s: every triangle mesh of the file placed by its node transform
    (glTF / GLB node hierarchy; OBJ objects and materials become separate parts), with its base colour.
    PLY files with triangle strips go through :func:`read_ply`; everything else through trimesh.

    ValueError naming the path for a missing or unreadable file, a file without triangles, or non-finite
    vertices."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"scene path must be a file path (str or os.PathLike), got {show(path)}")
    where = str(path)
    p = Path(path)
    if not p.exists():
        raise ValueError(f"scene path {where!r} does not exist")
    if not p.is_file():
        raise ValueError(f"scene path {where!r} is not a file")
    if p.suffix.lower() == ".ply" and ply_has_tristrips(p):
        d = read_ply(p)
        alb = None if d["colors"] is None else d["colors"][d["faces"]].mean(axis=1)
        nrm = d["normals"]
        if nrm is None:
            nrm = _smooth_normals(d["vertices"], d["faces"])
        return [MeshPart(p.stem, d["vertices"], d["faces"], alb, nrm)]
    import trimesh

    try:
        loaded = trimesh.load(str(p), force="scene", process=False)
    except Exception as e:  # trimesh raises many types for unreadable input
        raise ValueError(f"scene file {where!r} could not be read as a mesh: {e}") from None
    if isinstance(loaded, trimesh.Trimesh):  # some trimesh versions may return a mesh
        loaded = trimesh.Scene(loaded)
    parts = []
    if isinstance(loaded, trimesh.Scene):
        nodes = sorted(loaded.graph.nodes_geometry, key=str)
        for node in nodes:
            transform, gname = loaded.graph[node]
            g = loaded.geometry.get(gname)
            if not isinstance(g, trimesh.Trimesh) or len(g.faces) == 0 or len(g.vertices) < 3:
                continue
            v0 = np.asarray(g.vertices, dtype=np.float64)
            _check_part(where, v0, g.faces)
            albedo = _part_albedo(g)
            m = np.asarray(transform, dtype=np.float64)
            f = np.asarray(g.faces, dtype=np.int64)
            try:
                n0 = np.asarray(g.vertex_normals, dtype=np.float64)
            except Exception:
                n0 = None
            v = v0 @ m[:3, :3].T + m[:3, 3]
            lin = m[:3, :3]
            if n0 is not None and n0.shape == v0.shape:
                try:
                    nrm = n0 @ np.linalg.inv(lin)  # (M^-T n) for row vectors
                except np.linalg.LinAlgError:
                    nrm = None
                if nrm is not None:
                    with np.errstate(invalid="ignore", divide="ignore"):
                        nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
            else:
                nrm = None
            if np.linalg.det(lin) < 0:  # a mirroring transform: keep the faces' winding outward
                f = f[:, ::-1].copy()
            parts.append(MeshPart(str(node), v, f, albedo, nrm))
    if not parts:
        raise ValueError(f"scene file {where!r} holds no triangle mesh (empty, points only, or not a mesh)")
    for part in parts:
        _check_part(where, part.vertices, part.faces)
    return parts


def _smooth_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (0 at vertices of only degenerate faces)."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    vn = np.zeros_like(v)
    for j in range(3):
        np.add.at(vn, f[:, j], fn)
    ln = np.linalg.norm(vn, axis=1, keepdims=True)
    return np.divide(vn, ln, out=np.zeros_like(vn), where=ln > 0)


def load_mesh_arrays(path, default_albedo=(0.75, 0.72, 0.68)) -> tuple:
    """Read any mesh file -> (vertices, faces, face_albedo or None, vertex_normals or None): the parts of
    :func:`load_mesh_parts` concatenated. ``face_albedo`` is None when no part has a colour; otherwise parts
    without one get ``default_albedo`` (3 numbers in [0, 1])."""
    default_albedo = check_vec("default_albedo", default_albedo, 3, 0.0, 1.0)
    parts = load_mesh_parts(path)
    vs, fs, als, ns = [], [], [], []
    off = 0
    any_col = any(pt.albedo is not None for pt in parts)
    all_n = all(pt.normals is not None for pt in parts)
    for pt in parts:
        vs.append(pt.vertices)
        fs.append(pt.faces + off)
        off += pt.vertices.shape[0]
        if any_col:
            als.append(pt.albedo if pt.albedo is not None else np.tile(default_albedo, (pt.faces.shape[0], 1)))
        if all_n:
            ns.append(pt.normals)
    v = np.concatenate(vs)
    f = np.concatenate(fs)
    alb = np.concatenate(als).astype(np.float32) if any_col else None
    vn = np.concatenate(ns).astype(np.float32) if all_n else None
    return v, f, alb, vn
