"""Wavefront OBJ files with their MTL material libraries -> :class:`~foveawarp.io.scenedata.SceneData`.

:func:`parse_obj` reads the geometry (also used by the Mitsuba reader for its ``obj`` shapes);
:func:`read_obj` adds the materials of the ``mtllib`` files and completes normals and tangents.

Geometry (one parser of its own, vectorized with NumPy):
    - ``v x y z [w]`` (``w`` ignored; ``v x y z r g b`` gives vertex colours when every ``v`` line has them),
      ``vt u [v [w]]``, ``vn x y z``, ``f`` with ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn`` corners, 1-based or
      negative (relative to the elements defined so far) indices, and ``\\`` line continuations.
    - polygons are fanned from their first corner ((0, i, i + 1)); faces of fewer than 3 corners are dropped with
      a warning; ``l`` and ``p`` elements are skipped with a warning.
    - ``usemtl`` sets the material of the faces that follow, ``mtllib`` names the libraries; ``o``, ``g`` and
      ``s`` do not change the geometry (smoothing groups are ignored: computed normals are smooth everywhere).
    - a vertex of the result is one distinct (v, vt, vn) triple of the file.
    - UVs: OBJ's (0, 0) is the image's bottom-left corner; they are flipped to glTF's top-left origin,
      ``v' = 1 - v`` (``flip_v=False`` keeps them as stored). Corners without ``vt`` get UV (0, 0).
    - corners without ``vn`` get the area-weighted normal of the faces around their position
      (:func:`foveawarp.io.geometry.compute_normals`); tangents come from the UVs
      (:func:`foveawarp.io.geometry.compute_tangents`).

Materials (MTL -> :class:`foveawarp.materials.Material`, metallic-roughness):
    - ``Kd`` -> base colour (clamped to [0, 1]; 0.8 grey when absent); ``map_Kd`` -> the sRGB base colour
      texture, multiplied by ``Kd`` as the MTL format defines.
    - ``Ks``/``Ns`` -> roughness. A Blinn-Phong lobe of exponent ``Ns`` matches a microfacet lobe of alpha
      ``sqrt(2 / (Ns + 2))`` (Walter et al. 2007, eq. 33, Beckmann; GGX alike), and glTF's roughness is
      ``sqrt(alpha)``, so ``roughness = (2 / (Ns + 2)) ** 0.25``. Without a highlight (``Ks`` absent or black)
      the roughness is 1. The colour of ``Ks`` has no place in the model (its F0 is 0.04 for dielectrics) and
      is dropped. The PBR extension's ``Pr`` (roughness) and ``Pm`` (metallic) override; metallic is 0 otherwise.
    - ``Ke`` (with ``map_Ke`` as the sRGB emissive texture) -> emission: ``emissive_factor * emissive_strength``
      = ``Ke`` (radiance).
    - ``d`` (or ``1 - Tr``) -> base colour alpha; ``map_d`` -> alpha mode "MASK" (the base colour texture's
      alpha is the mask, so ``map_d`` must name the ``map_Kd`` image; another image is dropped with a warning).
      A constant ``d < 1`` without ``map_d`` gives "BLEND" (a constant mask would show all or nothing).
    - ``norm`` -> the tangent-space normal map. ``map_Bump``/``bump`` name a height map in the MTL format, but
      many exporters write a normal map there: the image is decoded and taken as a normal map when it looks
      like one (mean blue above 0.6 and ``|2 rgb - 1|`` within 0.25 of 1 for 90 % of its texels); a height map
      is dropped with a warning. ``-bm`` scales a normal map (``normal_scale``).
    - map options: ``-s`` and ``-o`` (the UV scale and offset, their omitted v 1 and 0, converted to glTF's
      v-down convention), ``-clamp on`` (clamp wrapping); the others are skipped.
    - every OBJ material is double-sided (the format has no culling); ``illum`` and ``Ni`` are ignored.

Missing pieces: a missing ``.mtl`` file, an image file that does not exist, or a material that no library
defines gives a warning (listed in ``SceneData.warnings``) and the material falls back (to a 0.8 grey diffuse
material) or the slot stays empty; with ``strict=True`` each raises ``ValueError`` instead. Malformed numbers,
indices outside the file's elements and a missing OBJ file raise ``ValueError`` naming the file and line.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..config import show
from ..materials import ImageSource, Material, TextureRef
from .geometry import compute_normals, compute_tangents, complete_tangents, normalize_rows
from .scenedata import SceneData, ShapeData, emission_material

__all__ = ["ObjMesh", "parse_obj", "read_mtl", "read_obj", "ns_to_roughness", "DEFAULT_OBJ_MATERIAL"]

DEFAULT_OBJ_MATERIAL = Material(name="default", base_color_factor=(0.8, 0.8, 0.8, 1.0), metallic_factor=0.0,
                                roughness_factor=1.0, double_sided=True)
_MIME_BY_SUFFIX = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp"}
# map statement options and how many arguments each takes (-o, -s, -t take 1 to 3 numbers)
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
                "-mm": 2, "-texres": 1, "-type": 1, "-o": 3, "-s": 3, "-t": 3}


# map statements (lower case) -> the keys read_mtl stores them under
_MAP_KEYS = {"map_kd": "map_Kd", "map_ke": "map_Ke", "map_d": "map_d", "map_bump": "bump", "map_pr": "map_Pr",
             "map_pm": "map_Pm", "map_ks": "map_Ks", "map_ns": "map_Ns"}


def ns_to_roughness(ns: float) -> float:
    """glTF roughness of a Blinn-Phong exponent: ``(2 / (Ns + 2)) ** 0.25`` (alpha = sqrt(2 / (Ns + 2)),
    roughness = sqrt(alpha)), in (0, 1] for Ns >= 0."""
    return float((2.0 / (max(float(ns), 0.0) + 2.0)) ** 0.25)


@dataclass
class ObjMesh:
    """The geometry of one OBJ file in its own coordinates.

    Attributes:
        positions: (V, 3) float64.
        normals: (V, 3) float64 unit normals (the file's, or computed where a corner has none).
        uvs: (V, 2) float64 in glTF's convention (unless parsed with ``flip_v=False``), or None without ``vt``.
        colors: (V, 4) float64 linear RGBA from ``v x y z r g b``, or None.
        triangles: (F, 3) int64, the file's winding.
        material_ids: (F,) int32 index into ``material_names``.
        material_names: the ``usemtl`` names in order of first use ("" for faces before any ``usemtl``).
        mtllibs: the ``mtllib`` file names, as written.
        warnings: what was skipped.
    """

    positions: np.ndarray
    normals: np.ndarray
    uvs: Optional[np.ndarray]
    colors: Optional[np.ndarray]
    triangles: np.ndarray
    material_ids: np.ndarray
    material_names: list
    mtllibs: list
    warnings: list


class _Lines:
    """The statements of one file: keyword -> list of argument strings (and their line numbers)."""

    def __init__(self, path: Path, text: str):
        self.path = path
        if "\\\n" in text or "\\\r\n" in text:
            text = text.replace("\\\r\n", " ").replace("\\\n", " ")
        self.lines = text.splitlines()

    def fail(self, line_no: Optional[int], what: str):
        where = f"{self.path}" if line_no is None else f"{self.path}:{line_no}"
        raise ValueError(f"{where}: {what}")


def _token_counts(joined: str, n: int) -> np.ndarray:
    """(n,) int64: the whitespace-separated tokens of each of the ``n`` newline-joined rows (vectorized)."""
    buf = np.frombuffer(joined.encode("utf-8", errors="replace"), dtype=np.uint8)
    if buf.size == 0:
        return np.zeros(n, dtype=np.int64)
    if (buf >= 128).any():  # non-ASCII text may hold other spaces: str.split decides
        return np.fromiter((len(r.split()) for r in joined.split("\n")), dtype=np.int64, count=n)
    space = (buf == 32) | ((buf >= 9) & (buf <= 13)) | ((buf >= 28) & (buf <= 31))  # str.split's ASCII spaces
    start = ~space
    start[1:] &= space[:-1]
    row = np.cumsum(buf == 10)
    return np.bincount(row[start], minlength=n).astype(np.int64)


def _floats(lp: _Lines, rows: list, line_nos: list, what: str, lo: int, hi: int) -> np.ndarray:
    """Rows of ``lo``..``hi`` numbers -> (N, hi) float64, missing trailing values 0 (NaN-free)."""
    n = len(rows)
    if n == 0:
        return np.zeros((0, hi), dtype=np.float64)
    joined = "\n".join(rows)
    lens = _token_counts(joined, n)
    bad = (lens < lo)
    if bad.any():
        i = int(np.argmax(bad))
        lp.fail(line_nos[i], f"'{what}' needs at least {lo} numbers, got {rows[i].strip()!r}")
    k = int(lens.max())
    try:
        if int(lens.min()) == k:
            a = np.array(joined.split(), dtype=np.float64).reshape(n, k)
        else:
            a = np.zeros((n, k), dtype=np.float64)
            for i, r in enumerate(rows):
                ts = r.split()
                a[i, :len(ts)] = np.array(ts, dtype=np.float64)
    except ValueError:
        for i, ts in enumerate(r.split() for r in rows):
            try:
                [float(t) for t in ts]
            except ValueError:
                lp.fail(line_nos[i], f"'{what}' must be followed by numbers, got {rows[i].strip()!r}")
        raise
    if not np.isfinite(a).all():
        i = int(np.argwhere(~np.isfinite(a))[0, 0])
        lp.fail(line_nos[i], f"'{what}' holds a non-finite number: {rows[i].strip()!r}")
    out = np.zeros((n, hi), dtype=np.float64)
    m = min(k, hi)
    out[:, :m] = a[:, :m]
    return out


def _corner_indices(lp: _Lines, faces: list, face_lines: list, lens: np.ndarray) -> np.ndarray:
    """(C, 3) int64 (v, vt, vn) of every corner as written (0 where a field is absent)."""
    flat = [t for f in faces for t in f]
    if not flat:
        return np.zeros((0, 3), dtype=np.int64)
    slashes = np.fromiter((t.count("/") for t in flat), dtype=np.int64, count=len(flat))
    if int(slashes.max()) > 2:
        i = int(np.argmax(slashes > 2))
        face = int(np.searchsorted(np.cumsum(lens), i, side="right"))
        lp.fail(face_lines[face], f"a face corner must be v, v/vt, v//vn or v/vt/vn, got {flat[i]!r}")
    k = int(slashes[0])
    if (slashes == k).all():
        parts = "/".join(flat).split("/")
        fields = np.array(parts, dtype=object).reshape(len(flat), k + 1)
    else:
        fields = np.empty((len(flat), 3), dtype=object)
        fields[:] = ""
        for i, t in enumerate(flat):
            p = t.split("/")
            fields[i, :len(p)] = p
        k = 2
    out = np.zeros((len(flat), 3), dtype=np.int64)
    for c in range(k + 1):
        col = fields[:, c]
        empty = col == ""
        if c == 0 and empty.any():
            i = int(np.argmax(empty))
            face = int(np.searchsorted(np.cumsum(lens), i, side="right"))
            lp.fail(face_lines[face], f"a face corner needs a vertex index, got {flat[i]!r}")
        try:
            vals = np.where(empty, "0", col).astype(np.int64)
        except (ValueError, OverflowError):
            for i, s in enumerate(col):
                try:
                    int(s or "0")
                except ValueError:
                    face = int(np.searchsorted(np.cumsum(lens), i, side="right"))
                    lp.fail(face_lines[face], f"face indices must be integers, got corner {flat[i]!r}")
            raise
        zero = (vals == 0) & ~empty
        if zero.any():
            i = int(np.argmax(zero))
            face = int(np.searchsorted(np.cumsum(lens), i, side="right"))
            lp.fail(face_lines[face], f"face indices are 1-based (or negative), got 0 in corner {flat[i]!r}")
        out[:, c] = vals
    return out


def parse_obj(path, *, flip_v: bool = True) -> ObjMesh:
    """The geometry of an OBJ file (see the module docstring). ``flip_v``: convert the UVs to glTF's top-left
    origin (``v' = 1 - v``)."""
    if not isinstance(path, (str, Path)):
        raise ValueError(f"path must be a str or Path, got {show(path)}")
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"OBJ file {str(path)!r} not found")
    lp = _Lines(path, path.read_bytes().decode("utf-8", errors="replace"))
    v, vt, vn, f = [], [], [], []
    v_no, vt_no, vn_no, f_no = [], [], [], []
    f_mat = []
    neg = []  # (face, len(v), len(vt), len(vn)) of faces written with a negative index
    mat_names, mat_index = [""], {"": 0}
    cur = 0
    mtllibs = []
    skipped: dict = {}
    unknown: dict = {}
    for no, line in enumerate(lp.lines, 1):
        if "#" in line:
            line = line[:line.index("#")]
        if not line:
            continue
        c = line[0]
        if c == " " or c == "\t":
            line = line.strip()
            if not line:
                continue
            c = line[0]
        c1 = line[1:2]
        if c == "v":
            if c1 == " " or c1 == "\t":
                v.append(line[2:])
                v_no.append(no)
                continue
            c2 = line[2:3]
            if c1 == "t" and (c2 == " " or c2 == "\t"):
                vt.append(line[3:])
                vt_no.append(no)
                continue
            if c1 == "n" and (c2 == " " or c2 == "\t"):
                vn.append(line[3:])
                vn_no.append(no)
                continue
        elif c == "f" and (c1 == " " or c1 == "\t"):
            rest = line[2:]
            if "-" in rest:
                neg.append((len(f), len(v), len(vt), len(vn)))
            f.append(rest)
            f_no.append(no)
            f_mat.append(cur)
            continue
        head, _, rest = line.partition(" ")
        if "\t" in head:
            head, _, more = head.partition("\t")
            rest = more + " " + rest
        rest = rest.strip()
        if head == "usemtl":
            if rest not in mat_index:
                mat_index[rest] = len(mat_names)
                mat_names.append(rest)
            cur = mat_index[rest]
        elif head == "mtllib":
            if rest:
                mtllibs.append(rest)
        elif head in ("o", "g", "s"):
            pass
        elif head in ("l", "p"):
            skipped[head] = skipped.get(head, 0) + 1
        else:
            unknown[head] = unknown.get(head, 0) + 1

    warn = []
    if skipped:
        warn.append(f"{path}: skipped line/point element(s): "
                    + ", ".join(f"{n} x '{k}'" for k, n in sorted(skipped.items())))
    if unknown:
        warn.append(f"{path}: ignored statement(s) " + ", ".join(f"'{k}' ({n})" for k, n in sorted(unknown.items())))

    pos6 = _floats(lp, v, v_no, "v", 3, 7)
    positions = pos6[:, :3]
    ntok = np.fromiter((len(s.split()) for s in v), dtype=np.int64, count=len(v)) if v else np.zeros(0, np.int64)
    colors = None
    if len(v) and (ntok == 6).all():
        colors = np.concatenate([np.clip(pos6[:, 3:6], 0.0, 1.0), np.ones((len(v), 1))], axis=1)
    texcoords = _floats(lp, vt, vt_no, "vt", 1, 2)
    vnormals = _floats(lp, vn, vn_no, "vn", 3, 3)

    toks = [s.split() for s in f]
    lens = np.fromiter(map(len, toks), dtype=np.int64, count=len(toks)) if toks else np.zeros(0, np.int64)
    short = lens < 3
    if short.any():
        warn.append(f"{path}: dropped {int(short.sum())} face(s) of fewer than 3 corners (first at line "
                    f"{f_no[int(np.argmax(short))]})")
    idx = _corner_indices(lp, toks, f_no, lens)
    # resolve negative indices against the counts at their face's line, then make all 0-based (-1: absent)
    if neg:
        nf = len(f)
        counts = np.zeros((nf, 3), dtype=np.int64)
        fi = np.array([n[0] for n in neg], dtype=np.int64)
        counts[fi] = np.array([n[1:] for n in neg], dtype=np.int64)
        per_corner = np.repeat(counts, lens, axis=0)
        idx = np.where(idx < 0, idx + per_corner + 1, idx)
    totals = (len(v), len(vt), len(vn))
    names = ("v", "vt", "vn")
    start = np.cumsum(lens) - lens
    for c in range(3):
        col = idx[:, c]
        bad = (col < 0) | (col > totals[c]) if c else (col < 1) | (col > totals[c])
        if c:
            bad &= col != 0
        if bad.any():
            i = int(np.argmax(bad))
            face = int(np.searchsorted(np.cumsum(lens), i, side="right"))
            lp.fail(f_no[face], f"face {names[c]} index must refer to one of the {totals[c]} '{names[c]}' "
                                f"lines written before it, got {toks[face][i - int(start[face])]!r}")
    idx = idx - 1

    # fan every polygon of >= 3 corners from its first corner
    ntri = np.maximum(lens - 2, 0)
    tri_face = np.repeat(np.arange(len(f), dtype=np.int64), ntri)
    j = np.arange(tri_face.shape[0], dtype=np.int64) - np.repeat(np.cumsum(ntri) - ntri, ntri) + 1
    a = start[tri_face]
    corner_tri = np.stack([a, a + j, a + j + 1], axis=1)
    material_ids = np.asarray(f_mat, dtype=np.int32)[tri_face] if len(f) else np.zeros(0, np.int32)

    used = np.unique(corner_tri.reshape(-1))
    triples = idx[used]
    if triples.shape[0]:
        span = np.array([totals[0] + 1, totals[1] + 1, totals[2] + 1], dtype=np.int64)
        if float(span[0]) * float(span[1]) * float(span[2]) < 2.0 ** 62:
            key = ((triples[:, 0] + 1) * span[1] + (triples[:, 1] + 1)) * span[2] + (triples[:, 2] + 1)
            _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
        else:
            _, first, inverse = np.unique(triples, axis=0, return_index=True, return_inverse=True)
        verts = triples[first]
        remap = np.full(idx.shape[0], -1, dtype=np.int64)
        remap[used] = inverse.reshape(-1)
        triangles = remap[corner_tri]
    else:
        verts = np.zeros((0, 3), dtype=np.int64)
        triangles = np.zeros((0, 3), dtype=np.int64)

    vi, ti, ni = verts[:, 0], verts[:, 1], verts[:, 2]
    out_pos = positions[vi]
    out_col = colors[vi] if colors is not None else None
    uvs = None
    if (ti >= 0).any():
        uvs = np.where((ti >= 0)[:, None], texcoords[np.maximum(ti, 0)] if len(vt) else 0.0, 0.0)
        if flip_v:
            uvs[:, 1] = np.where(ti >= 0, 1.0 - uvs[:, 1], 0.0)
    has_n = ni >= 0
    if has_n.all() and len(verts):
        normals = normalize_rows(vnormals[ni], (0.0, 0.0, 1.0))
    else:
        smooth = compute_normals(positions, vi[triangles]) if len(verts) else np.zeros((0, 3))
        normals = smooth[vi]
        if has_n.any():
            normals[has_n] = normalize_rows(vnormals[ni[has_n]], (0.0, 0.0, 1.0))
    return ObjMesh(positions=out_pos, normals=normals, uvs=uvs, colors=out_col, triangles=triangles,
                   material_ids=material_ids, material_names=mat_names, mtllibs=mtllibs, warnings=warn)


# ---------------------------------------------------------------------------------------------------
# MTL


@dataclass
class _MapSpec:
    path: Path
    options: dict


def _parse_map(args: str, base: Path):
    """A map statement's options and file -> _MapSpec (the file name may hold spaces)."""
    toks = args.split()
    opts = {}
    i = 0
    while i < len(toks) and toks[i].startswith("-") and toks[i].lower() in _MAP_OPTIONS:
        name = toks[i].lower()
        n = _MAP_OPTIONS[name]
        vals = []
        i += 1
        if name in ("-o", "-s", "-t"):
            while i < len(toks) and len(vals) < n:
                try:
                    vals.append(float(toks[i]))
                except ValueError:
                    break
                i += 1
        else:
            vals = toks[i:i + n]
            i += n
        opts[name] = vals
    name = " ".join(toks[i:]).replace("\\", "/")
    if not name:
        return None
    return _MapSpec(path=base / name, options=opts)


def _rgb(vals: list, default) -> tuple:
    if not vals:
        return default
    if len(vals) == 1:
        vals = vals * 3
    return tuple(float(x) for x in vals[:3])


def read_mtl(path, *, strict: bool = False, warn: Optional[list] = None) -> dict:
    """{material name: dict of the statements read} of one MTL file: "Kd", "Ks", "Ke" (RGB tuples), "Ns", "d",
    "Pr", "Pm" (floats), "map_Kd", "map_Ke", "map_d", "norm", "bump" (:class:`_MapSpec`). ValueError for a
    missing file or a malformed or non-finite number, naming the file and line."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"MTL file {str(path)!r} not found")
    lp = _Lines(path, path.read_bytes().decode("utf-8", errors="replace"))
    out: dict = {}
    cur = None
    for no, line in enumerate(lp.lines, 1):
        if "#" in line:
            line = line[:line.index("#")]
        line = line.strip()
        if not line:
            continue
        toks = line.split(None, 1)
        key = toks[0]
        rest = toks[1].strip() if len(toks) > 1 else ""
        lk = key.lower()
        if lk == "newmtl":
            cur = {}
            out[rest] = cur
            continue
        if cur is None:
            continue
        try:
            if lk in ("kd", "ks", "ke"):
                if rest.split()[:1] in (["spectral"], ["xyz"]):
                    (warn if warn is not None else []).append(f"{path}:{no}: {key} {rest.split()[0]} is not read")
                    continue
                vals = [float(x) for x in rest.split()]
                if len(vals) == 2 or not all(math.isfinite(v) for v in vals):  # r, or r g b
                    raise ValueError(key)
                cur[key[0].upper() + key[1].lower()] = _rgb(vals, None)
            elif lk in ("ns", "d", "tr", "pr", "pm", "ni"):
                v = float(rest.split()[0])
                if not math.isfinite(v):
                    raise ValueError(key)
                cur[{"ns": "Ns", "d": "d", "tr": "Tr", "pr": "Pr", "pm": "Pm", "ni": "Ni"}[lk]] = v
            elif lk in ("map_kd", "map_ke", "map_d", "norm", "map_bump", "bump", "map_pr", "map_pm", "map_ks",
                        "map_ns", "disp", "refl"):
                spec = _parse_map(rest, path.parent)
                if spec is not None and not all(math.isfinite(v) for k in ("-o", "-s", "-t")
                                                for v in spec.options.get(k, [])):
                    raise ValueError(key)
                if spec is not None:
                    cur[_MAP_KEYS.get(lk, lk)] = spec
        except (ValueError, IndexError):
            what = " (r, or r g b)" if lk in ("kd", "ks", "ke") else ""
            lp.fail(no, f"{key} must be followed by finite numbers{what}, got {rest!r}")
    return out


def _looks_like_normal_map(path: Path) -> bool:
    """Mean blue above 0.6 and |2 rgb - 1| within 0.25 of 1 for 90 % of the texels (a subsample)."""
    from .images import load_image

    img = load_image(path, srgb=False)
    step = max(1, int(math.sqrt(img.shape[0] * img.shape[1] / 4096)))
    rgb = img[::step, ::step, :3].reshape(-1, 3).astype(np.float64)
    if rgb.size == 0 or float(rgb[:, 2].mean()) <= 0.6:
        return False
    length = np.linalg.norm(rgb * 2.0 - 1.0, axis=1)
    return float(np.mean(np.abs(length - 1.0) < 0.25)) >= 0.9


class _Images:
    """The scene's image list: one ImageSource per distinct resolved file."""

    def __init__(self):
        self.images: list = []
        self.index: dict = {}

    def add(self, path: Path) -> int:
        key = path.resolve()
        if key not in self.index:
            self.index[key] = len(self.images)
            self.images.append(ImageSource(name=str(path), path=path,
                                           mime_type=_MIME_BY_SUFFIX.get(path.suffix.lower())))
        return self.index[key]


def _texture(spec: _MapSpec, images: _Images, color_space: str, note, strict: bool, where: str):
    if not spec.path.is_file():
        msg = f"{where}: texture file {str(spec.path)!r} not found; the slot is left empty"
        if strict:
            raise ValueError(msg)
        note(msg)
        return None
    s = spec.options.get("-s", [])
    o = spec.options.get("-o", [])
    su, sv = (s + [1.0, 1.0])[:2]  # the MTL format: v and w are optional, 1 by default
    ou, ov = (o + [0.0, 0.0])[:2] if o else (0.0, 0.0)
    clamp = [x.lower() for x in spec.options.get("-clamp", [])] == ["on"]
    wrap = "clamp" if clamp else "repeat"
    # OBJ's lookup v_obj' = sv * v_obj + ov with v = 1 - v_obj: v' = sv * v + (1 - sv - ov)
    return TextureRef(image=images.add(spec.path), wrap_s=wrap, wrap_t=wrap, color_space=color_space,
                      uv_offset=(ou, 1.0 - sv - ov), uv_scale=(su, sv))


def mtl_material(name: str, m: dict, images: _Images, note, strict: bool, where: str) -> Material:
    """One MTL material (the statements of :func:`read_mtl`) -> Material (see the module docstring)."""
    kd = m.get("Kd") or (0.8, 0.8, 0.8)
    ks = m.get("Ks")
    alpha = m["d"] if "d" in m else (1.0 - m["Tr"] if "Tr" in m else 1.0)
    alpha = min(1.0, max(0.0, alpha))
    if "Pr" in m:
        rough = min(1.0, max(0.0, m["Pr"]))
    elif ks is not None and max(ks) > 0.0:
        rough = ns_to_roughness(m.get("Ns", 0.0))
    else:
        rough = 1.0
    metal = min(1.0, max(0.0, m.get("Pm", 0.0)))
    w = f"{where} material {name!r}"
    base_tex = _texture(m["map_Kd"], images, "srgb", note, strict, w) if "map_Kd" in m else None
    alpha_mode = "BLEND" if alpha < 1.0 else "OPAQUE"
    if "map_d" in m:
        same = "map_Kd" in m and m["map_d"].path.resolve() == m["map_Kd"].path.resolve()
        if same and base_tex is not None:
            alpha_mode = "MASK"
        elif not same:
            note(f"{w}: map_d {str(m['map_d'].path)!r} is not the map_Kd image; the mask is dropped")
    normal_tex, normal_scale = None, 1.0
    spec = m.get("norm")
    from_bump = False
    if spec is None and "bump" in m:
        spec, from_bump = m["bump"], True
    if spec is not None:
        if from_bump and spec.path.is_file() and not _looks_like_normal_map(spec.path):
            note(f"{w}: bump map {str(spec.path)!r} is a height map; height maps are not supported, it is dropped")
        else:
            normal_tex = _texture(spec, images, "linear", note, strict, w)
            bm = spec.options.get("-bm")
            if bm:
                try:
                    normal_scale = float(bm[0])
                except ValueError:
                    pass
    for key in ("map_Pr", "map_Pm", "map_Ks", "map_Ns", "disp", "refl"):
        if key in m:
            note(f"{w}: {key} is not supported and is dropped")
    mat = Material(
        name=name,
        base_color_factor=tuple(min(1.0, max(0.0, c)) for c in kd) + (alpha,),
        base_color_texture=base_tex,
        metallic_factor=metal,
        roughness_factor=rough,
        normal_texture=normal_tex,
        normal_scale=normal_scale,
        alpha_mode=alpha_mode,
        double_sided=True,
    )
    ke = m.get("Ke")
    etex = _texture(m["map_Ke"], images, "srgb", note, strict, w) if "map_Ke" in m else None
    if etex is not None and ke is None:
        ke = (1.0, 1.0, 1.0)
    if ke is not None and max(ke) > 0.0:
        from dataclasses import replace

        mat = replace(emission_material(mat, tuple(max(0.0, c) for c in ke)), emissive_texture=etex)
    return mat


def read_obj(path, *, strict: bool = False) -> SceneData:
    """Read an OBJ file and its MTL libraries into a :class:`SceneData` (see the module docstring).

    Args:
        path: the ``.obj`` file.
        strict: raise ``ValueError`` for a missing MTL file, texture or material instead of warning.

    Raises:
        ValueError: the file is missing or malformed (a bad number, an index outside the file's elements), or,
            with ``strict``, a library, texture or material is missing; the message names the file and line.
    """
    mesh = parse_obj(path)
    path = Path(path)
    notes = list(mesh.warnings)
    note = notes.append

    libs: dict = {}
    for lib in mesh.mtllibs:
        names = [lib]
        lib_path = path.parent / lib.replace("\\", "/")
        if not lib_path.is_file() and " " in lib:
            names = lib.split()  # several libraries on one line
        for nm in names:
            p = path.parent / nm.replace("\\", "/")
            if not p.is_file():
                msg = f"{path}: material library {nm!r} not found (looked for {p})"
                if strict:
                    raise ValueError(msg)
                note(msg + "; its materials fall back to the default")
                continue
            for k, val in read_mtl(p, strict=strict, warn=notes).items():
                libs.setdefault(k, (val, p))
    images = _Images()
    materials = []
    for name in mesh.material_names:
        if name == "":
            materials.append(DEFAULT_OBJ_MATERIAL)
            continue
        if name not in libs:
            msg = f"{path}: material {name!r} is not defined by the material libraries {mesh.mtllibs}"
            if strict:
                raise ValueError(msg)
            note(msg + "; the default material is used")
            materials.append(Material(name=name, base_color_factor=DEFAULT_OBJ_MATERIAL.base_color_factor,
                                      metallic_factor=0.0, double_sided=True))
            continue
        m, lib_path = libs[name]
        materials.append(mtl_material(name, m, images, note, strict, str(lib_path)))

    # drop the materials no face uses (the default one when every face has a usemtl), keep the order
    used = np.unique(mesh.material_ids) if mesh.material_ids.size else np.zeros(0, np.int64)
    remap = np.full(len(materials), -1, dtype=np.int32)
    remap[used] = np.arange(used.shape[0], dtype=np.int32)
    materials = [materials[i] for i in used]
    material_ids = remap[mesh.material_ids] if mesh.material_ids.size else mesh.material_ids
    if not materials:
        materials = [DEFAULT_OBJ_MATERIAL]

    pos, nrm, tri = mesh.positions, mesh.normals, mesh.triangles
    tan = complete_tangents(pos, nrm, mesh.uvs, tri) if mesh.uvs is not None else complete_tangents(
        pos, nrm, None, tri)
    nv, nt = pos.shape[0], tri.shape[0]
    for msg in notes:
        warnings.warn(msg, stacklevel=2)
    return SceneData(
        path=path,
        vertices=pos.astype(np.float32),
        normals=nrm.astype(np.float32),
        tangents=tan.astype(np.float32),
        uvs=(mesh.uvs if mesh.uvs is not None else np.zeros((nv, 2))).astype(np.float32),
        uvs1=None,
        colors=mesh.colors.astype(np.float32) if mesh.colors is not None else None,
        triangles=tri.astype(np.int32),
        material_ids=material_ids.astype(np.int32),
        materials=materials,
        images=images.images,
        warnings=tuple(notes),
        shapes=[ShapeData(name=path.stem, kind="obj", vertex_range=(0, nv), triangle_range=(0, nt),
                          material=int(material_ids[0]) if nt else 0)],
    )
