"""Scene: triangle geometry + per-face material + lights + optional animation, and its device copy.

A :class:`Scene` is a host-side description (NumPy arrays). :class:`DeviceScene` owns the Warp arrays of one
device: the ``wp.Mesh`` (SAH BVH by default), the materials and the light arrays. Animated objects move
their vertices rigidly; the device copy refits its BVH only when something moved.

A scene may also carry textured surfaces: per-vertex UVs and tangents, a material per face
(``foveawarp.materials``: glTF metallic-roughness with textures), the images its textures read and an environment.
Such a scene still has a per-face albedo (each face's mean base colour, :func:`face_material_colors`) and
emission, so code that reads only those works on every scene.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np

from .camera import Camera
from .config import check_array, check_choice, check_finite, check_int_range, check_range, check_vec, show
from .materials import ImageSource, Material, MaterialTable
from .meshio import NAMED_MESHES, find_named_mesh, load_mesh_arrays, named_mesh_help, scene_search_dirs  # noqa: F401
from .meshio import scene_file_kind

__all__ = ["Light", "AreaLight", "SceneObject", "Scene", "DeviceScene", "load_scene", "scene_search_dirs",
           "face_material_colors"]

BVH_CONSTRUCTORS = ("auto", "sah", "median", "lbvh", "cubql")
BVH_MAX_LEAF = 64


def check_bvh(constructor, leaf_size, prefix: str = "") -> tuple:
    """``(constructor, leaf_size)`` checked: one of BVH_CONSTRUCTORS, and None or an int in [1, BVH_MAX_LEAF];
    ``prefix`` goes before the names in the ValueError ("Scene." for the Scene's fields)."""
    constructor = check_choice(prefix + "bvh_constructor", constructor, BVH_CONSTRUCTORS)
    if leaf_size is not None:
        leaf_size = check_int_range(prefix + "bvh_leaf_size", leaf_size, 1, BVH_MAX_LEAF)
    return constructor, leaf_size


def resolve_bvh(constructor: str, leaf_size, device) -> tuple:
    """The (constructor, leaf size) a :class:`DeviceScene` builds its ``wp.Mesh`` with on ``device``.

    "auto" is "cubql" on CUDA (Warp's cuBQL builder: on the H100 and H200 it traced every built-in scene and mesh
    faster than "sah" with 4 per leaf, and built the meshes of 69k triangles and more 1.9-8.4x faster; small ones
    take a few ms more) and "sah" on the CPU device (where the cuBQL tree traced slower). "lbvh" on the CPU is
    "sah" (Warp's own fallback). A leaf size of None is 2 for "sah", "median" and "lbvh" on CUDA (against Warp's 4:
    cornell's shading with 8 AO rays at 4K 4.79 -> 2.61 ms on the H100), Warp's default otherwise (4 for the CPU
    trees, cuBQL's own for "cubql"). ``benchmarks/bvh.py`` measures every choice."""
    from ._util import get_device

    constructor, leaf_size = check_bvh(constructor, leaf_size)
    cuda = get_device(device).is_cuda
    if constructor == "auto":
        constructor = "cubql" if cuda else "sah"
    elif constructor == "lbvh" and not cuda:
        constructor = "sah"  # Warp has no CPU "lbvh" builder (it falls back to "sah" with a warning)
    if leaf_size is None and cuda and constructor != "cubql":
        leaf_size = 2
    return constructor, leaf_size


def _vec3(name, v, lo=None):
    return check_vec(name, v, 3, lo)


@dataclass(frozen=True)
class Light:
    """A point or spot light.

    Attributes:
        kind: "point" or "spot".
        position: world position.
        direction: spot axis (normalized on construction; ignored for point lights).
        cone_deg: spot half angle in degrees, in (0, 180]; light falls off smoothly over the outer
            ``penumbra`` fraction of the cone.
        intensity: radiant intensity, linear RGB per steradian (irradiance = intensity * cos / r^2).
        penumbra: fraction of the cone angle used for the smooth edge, in [0, 1].
    """

    kind: str = "point"
    position: tuple = (0.0, 2.0, 0.0)
    direction: tuple = (0.0, -1.0, 0.0)
    cone_deg: float = 45.0
    intensity: tuple = (5.0, 5.0, 5.0)
    penumbra: float = 0.2

    def __post_init__(self):
        check_choice("Light.kind", self.kind, ("point", "spot"))
        object.__setattr__(self, "position", _vec3("Light.position", self.position))
        d = np.asarray(_vec3("Light.direction", self.direction))
        n = float(np.linalg.norm(d))
        if not n > 0:
            raise ValueError(f"Light.direction must be a non-zero vector, got {self.direction!r}")
        object.__setattr__(self, "direction", tuple(float(c) for c in d / n))
        check_range("Light.cone_deg", self.cone_deg, 0.0, 180.0, lo_open=True)
        object.__setattr__(self, "intensity", _vec3("Light.intensity", self.intensity, 0.0))
        check_range("Light.penumbra", self.penumbra, 0.0, 1.0)


@dataclass(frozen=True)
class AreaLight:
    """An emissive parallelogram ``corner + s * edge_u + t * edge_v`` (s, t in [0, 1]) emitting ``radiance``
    from the side its normal ``cross(edge_u, edge_v)`` faces."""

    corner: tuple = (-0.25, 1.98, -0.25)
    edge_u: tuple = (0.5, 0.0, 0.0)
    edge_v: tuple = (0.0, 0.0, 0.5)
    radiance: tuple = (10.0, 10.0, 10.0)

    def __post_init__(self):
        for n in ("corner", "edge_u", "edge_v"):
            object.__setattr__(self, n, _vec3(f"AreaLight.{n}", getattr(self, n)))
        object.__setattr__(self, "radiance", _vec3("AreaLight.radiance", self.radiance, 0.0))
        area = float(np.linalg.norm(np.cross(self.edge_u, self.edge_v)))
        if not (area > 0 and math.isfinite(area)):
            raise ValueError(f"AreaLight.edge_u {self.edge_u!r} and edge_v {self.edge_v!r} must span an area in "
                             f"(0, inf), got {area!r}")


@dataclass
class SceneObject:
    """A rigid group of vertices (``vertex_range`` = [start, end)) with an optional motion ``t -> 4x4``."""

    name: str
    vertex_range: tuple
    motion: Optional[Callable[[float], np.ndarray]] = None

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise ValueError(f"SceneObject.name must be a str, got {show(self.name)}")
        try:
            vr = None if isinstance(self.vertex_range, (str, bytes)) else tuple(self.vertex_range)
        except TypeError:
            vr = None
        if vr is None or len(vr) != 2:
            raise ValueError(f"SceneObject.vertex_range must be (start, end) integers with 0 <= start <= end, "
                             f"got {show(self.vertex_range)}")
        a = check_int_range("SceneObject.vertex_range[0]", vr[0], 0, None)
        b = check_int_range("SceneObject.vertex_range[1]", vr[1], a, None)
        self.vertex_range = (a, b)
        if self.motion is not None and not callable(self.motion):
            raise ValueError(f"SceneObject.motion must be None or a callable t -> 4x4 matrix, got {show(self.motion)}")

    def transform_at(self, t: float) -> np.ndarray:
        """The object's 4x4 rigid transform at time ``t`` (identity without motion); ValueError unless the motion
        returns a finite 4x4 matrix."""
        if self.motion is None:
            return np.eye(4)
        m = check_array(f"SceneObject {self.name!r} motion({float(t)!r})", self.motion(float(t))).astype(np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"SceneObject {self.name!r} motion({float(t)!r}) must return a 4x4 matrix, got shape "
                             f"{m.shape}")
        return m


@dataclass
class Scene:
    """Host-side scene.

    Attributes:
        vertices: (V, 3) float32 rest positions, world units.
        faces: (F, 3) int32 vertex indices.
        face_albedo: (F, 3) float32 linear RGB albedo in [0, 1].
        face_emission: (F, 3) float32 emitted radiance, >= 0.
        vertex_normals: (V, 3) float32 smooth normals (used where ``face_smooth``); None = flat everywhere.
        face_smooth: (F,) uint8, 1 where the shading normal interpolates ``vertex_normals``.
        lights: point and spot lights.
        area_lights: emissive parallelograms sampled with shadow rays.
        camera: the default camera.
        camera_path: optional ``t (s) -> Camera`` for animation.
        objects: rigid groups with optional motion.
        name: a label for reports.
        bvh_constructor: "auto" (default: "cubql" on CUDA, "sah" on the CPU; :func:`resolve_bvh`), "sah", "median",
            "lbvh" (builds fastest) or "cubql" (Warp's cuBQL builder).
        bvh_leaf_size: triangles per BVH leaf in [1, 64]; None = the tuned default of :func:`resolve_bvh`.

    Textured surfaces (all optional; a scene without them is shaded from ``face_albedo`` alone):
        uvs: (V, 2) float32 TEXCOORD_0 per vertex, glTF's convention: (0, 0) is the image's top-left corner, u to
            the right, v down; values outside [0, 1] repeat, clamp or mirror as each texture's wrap mode says.
        uvs1: (V, 2) float32 TEXCOORD_1, for textures whose ``texcoord`` is 1; None when none reads it.
        tangents: (V, 4) float32: xyz the tangent (``dP/du``), w = +1 or -1 the handedness: the bitangent
            ``w * cross(normal, tangent)`` points to the image's top (``-dP/dv``), the frame of glTF normal maps.
        face_material: (F,) int32 index into ``materials``; given exactly when ``materials`` is.
        materials: a :class:`foveawarp.materials.MaterialTable`, or a list of
            :class:`foveawarp.materials.Material` (packed into one on construction).
        images: what the materials' textures read (``TextureRef.image`` indexes this list): linear images as
            (H, W) or (H, W, 1..4) float arrays (colour already linear: a texture's ``color_space`` is ignored for
            them), or :class:`foveawarp.materials.ImageSource` s (encoded files, decoded with the slot's colour
            space when needed).
        environment: None, or the light from infinitely far away: an (H, W, 3) float32 equirectangular image of
            linear radiance (row 0 the zenith +y, row H - 1 the nadir; column ``W * (atan2(d.x, -d.z) / 2 pi mod
            1)`` for direction d), a path to an ``.hdr`` / ``.exr`` file, or an environment object (kept as given).

    ``face_albedo`` may be None when ``materials`` is given: it is then each face's mean base colour
    (:func:`face_material_colors`), and a ``face_emission`` of None each face's mean emission.
    """

    vertices: np.ndarray
    faces: np.ndarray
    face_albedo: np.ndarray
    face_emission: Optional[np.ndarray] = None
    vertex_normals: Optional[np.ndarray] = None
    face_smooth: Optional[np.ndarray] = None
    lights: list = field(default_factory=list)
    area_lights: list = field(default_factory=list)
    camera: Camera = field(default_factory=Camera)
    camera_path: Optional[Callable[[float], Camera]] = None
    objects: list = field(default_factory=list)
    name: str = "scene"
    bvh_constructor: str = "auto"
    bvh_leaf_size: Optional[int] = None
    uvs: Optional[np.ndarray] = None
    uvs1: Optional[np.ndarray] = None
    tangents: Optional[np.ndarray] = None
    face_material: Optional[np.ndarray] = None
    materials: Optional[object] = None
    images: list = field(default_factory=list)
    environment: Optional[object] = None

    def __post_init__(self):
        v = check_array("Scene.vertices", self.vertices)
        f = check_array("Scene.faces", self.faces)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 3:
            raise ValueError(f"Scene.vertices must have shape (V >= 3, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] < 1:
            raise ValueError(
                f"Scene.faces must have shape (F >= 1, 3) of triangle vertex indices, got {f.shape}"
                " (empty or non-triangle mesh)"
            )
        if not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"Scene.faces must be integers in [0, {v.shape[0] - 1}], got dtype {f.dtype}")
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError(f"Scene.faces indices must be in [0, {v.shape[0] - 1}], got [{f.min()}, {f.max()}]")
        self.vertices = np.ascontiguousarray(v, dtype=np.float32)
        self.faces = np.ascontiguousarray(f, dtype=np.int32)
        nf = self.faces.shape[0]
        self._check_textured(v.shape[0], nf)
        if self.face_albedo is None:
            if self.materials is None:
                raise ValueError("Scene.face_albedo must be an (F, 3) or (3,) array of linear RGB in [0, 1], got None "
                                 "(None is allowed only with Scene.materials, which give each face its base colour)")
            self.face_albedo = face_material_colors(self.faces, self.face_material, self.materials, self.images,
                                                    self.uvs, self.uvs1, slot="base_color")
        self.face_albedo = self._per_face("face_albedo", self.face_albedo, nf, 0.0, 1.0)
        if self.face_emission is None:
            self.face_emission = (np.zeros((nf, 3)) if self.materials is None else face_material_colors(
                self.faces, self.face_material, self.materials, self.images, self.uvs, self.uvs1, slot="emissive"))
        self.face_emission = self._per_face("face_emission", self.face_emission, nf, 0.0, None)
        if self.vertex_normals is not None:
            # non-finite normals (trimesh gives NaN at degenerate faces) become 0: the kernels then use the
            # face normal; the kernels never see NaN
            vn = np.asarray(self.vertex_normals)
            if vn.dtype.kind not in "biuf":
                raise ValueError(f"Scene.vertex_normals must be an array of real numbers, got dtype {vn.dtype}")
            if vn.shape != self.vertices.shape:
                raise ValueError(f"Scene.vertex_normals must have shape {self.vertices.shape}, got {vn.shape}")
            vn = vn.astype(np.float32)
            self.vertex_normals = np.nan_to_num(vn, nan=0.0, posinf=0.0, neginf=0.0)
        if self.face_smooth is None:
            self.face_smooth = np.zeros(nf, dtype=np.uint8)
        fs = check_array("Scene.face_smooth", self.face_smooth, lo=0, hi=1)
        if fs.shape not in ((nf,), (nf, 1)):
            raise ValueError(f"Scene.face_smooth must have shape ({nf},), got {fs.shape}")
        self.face_smooth = np.ascontiguousarray(fs != 0, dtype=np.uint8).reshape(nf)
        if self.vertex_normals is None and self.face_smooth.any():
            raise ValueError("Scene.face_smooth marks smooth faces but Scene.vertex_normals is None")
        self.bvh_constructor, self.bvh_leaf_size = check_bvh(self.bvh_constructor, self.bvh_leaf_size, "Scene.")
        for attr, typ in (("lights", Light), ("area_lights", AreaLight), ("objects", SceneObject)):
            items = getattr(self, attr)
            if not isinstance(items, (list, tuple)):
                raise ValueError(f"Scene.{attr} must be a list of {typ.__name__}, got {show(items)}")
            for i, l in enumerate(items):
                if not isinstance(l, typ):
                    raise ValueError(f"Scene.{attr}[{i}] must be a {typ.__name__}, got {show(l)} "
                                     f"({type(l).__name__})")
            setattr(self, attr, list(items))
        for o in self.objects:
            if o.vertex_range[1] > v.shape[0]:
                raise ValueError(f"SceneObject {o.name!r} vertex_range must lie in [0, {v.shape[0]}], "
                                 f"got {o.vertex_range}")
        if not isinstance(self.camera, Camera):
            raise ValueError(f"Scene.camera must be a foveawarp.Camera, got {show(self.camera)} "
                             f"({type(self.camera).__name__})")
        if self.camera_path is not None and not callable(self.camera_path):
            raise ValueError(f"Scene.camera_path must be None or a callable t -> Camera, got {show(self.camera_path)}")
        if not isinstance(self.name, str):
            raise ValueError(f"Scene.name must be a str, got {show(self.name)}")

    def _check_textured(self, nv: int, nf: int) -> None:
        """Validate and normalize the textured-surface fields (shapes, finite values, indices in range)."""
        for name, k in (("uvs", 2), ("uvs1", 2), ("tangents", 4)):
            a = getattr(self, name)
            if a is None:
                continue
            a = check_array(f"Scene.{name}", a)
            if a.shape != (nv, k):
                raise ValueError(f"Scene.{name} must have shape ({nv}, {k}) (one row per vertex), got {a.shape}")
            a = np.ascontiguousarray(a, dtype=np.float32)
            if name == "tangents":
                a[:, 3] = np.where(a[:, 3] < 0, -1.0, 1.0)  # the handedness is a sign
            setattr(self, name, a)
        if isinstance(self.images, (str, bytes, np.ndarray)) or not isinstance(self.images, (list, tuple)):
            raise ValueError(f"Scene.images must be a list of arrays or ImageSources, got {show(self.images)}")
        images = []
        for i, im in enumerate(self.images):
            if isinstance(im, ImageSource):
                images.append(im)
                continue
            a = check_array(f"Scene.images[{i}]", im)
            if a.ndim == 2:
                a = a[:, :, None]
            if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1 or a.shape[2] not in (1, 2, 3, 4):
                raise ValueError(f"Scene.images[{i}] must be an ImageSource or an (H, W) or (H, W, 1..4) array with "
                                 f"H, W >= 1, got shape {np.shape(im)}")
            images.append(np.ascontiguousarray(a, dtype=np.float32))
        self.images = images
        mats = self.materials
        if mats is not None and not isinstance(mats, MaterialTable):
            if isinstance(mats, Material) or not isinstance(mats, (list, tuple)):
                raise ValueError(f"Scene.materials must be None, a MaterialTable or a list of Material, got "
                                 f"{show(mats)}")
            mats = MaterialTable.build(mats, len(images))
        if mats is not None and len(mats.textures) and int(mats.tex_image.max()) >= len(images):
            k = int(np.argmax(mats.tex_image >= len(images)))
            raise ValueError(f"Scene.materials texture {k} reads image {int(mats.tex_image[k])}; the image index must "
                             f"be in [0, {len(images) - 1}] (Scene.images holds {len(images)})")
        self.materials = mats
        if (self.face_material is None) != (mats is None):
            raise ValueError("Scene.face_material and Scene.materials must be given together, got "
                             f"face_material={'None' if self.face_material is None else 'an array'} and "
                             f"materials={'None' if mats is None else 'a table'}")
        if mats is not None:
            fm = check_array("Scene.face_material", self.face_material)
            if fm.shape not in ((nf,), (nf, 1)) or (fm.size and fm.dtype.kind not in "iu"):
                raise ValueError(f"Scene.face_material must be ({nf},) integers (one material index per face), got "
                                 f"shape {fm.shape} of {fm.dtype}")
            fm = fm.reshape(nf)
            if fm.min() < 0 or fm.max() >= len(mats):
                i = int(np.argmax((fm < 0) | (fm >= len(mats))))
                raise ValueError(f"Scene.face_material must be in [0, {len(mats) - 1}] ({len(mats)} materials), got "
                                 f"{int(fm[i])} at face {i}")
            self.face_material = np.ascontiguousarray(fm, dtype=np.int32)
            used = np.unique(self.face_material)
            tex = mats.texture[used]
            if (tex >= 0).any():
                if self.uvs is None:
                    raise ValueError("Scene.uvs must be given: the materials of the faces have textures")
                if self.uvs1 is None and (mats.tex_texcoord[tex[tex >= 0]] == 1).any():
                    raise ValueError("Scene.uvs1 must be given: a texture of the faces' materials reads TEXCOORD_1")
        env = self.environment
        if isinstance(env, (str, os.PathLike)):
            ep = Path(env)
            if ep.suffix.lower() not in (".hdr", ".exr") or not ep.is_file():
                raise ValueError(f"Scene.environment must be an existing .hdr or .exr file, got {str(env)!r}")
            self.environment = ep
        elif isinstance(env, (np.ndarray, list, tuple)):
            e = check_array("Scene.environment", env, lo=0.0)
            if e.ndim != 3 or e.shape[2] != 3 or e.shape[0] < 1 or e.shape[1] < 1:
                raise ValueError(f"Scene.environment must be an (H, W, 3) equirectangular radiance image, got shape "
                                 f"{e.shape}")
            self.environment = np.ascontiguousarray(e, dtype=np.float32)

    @property
    def is_textured(self) -> bool:
        """Whether the scene has materials (and so, possibly, textures)."""
        return self.materials is not None

    def linear_image(self, index: int, srgb: bool) -> np.ndarray:
        """``images[index]`` as linear float32 values: an array as it is, an ImageSource decoded (sRGB EOTF on its
        RGB when ``srgb``) to (H, W, 4)."""
        index = check_int_range("index", index, 0, len(self.images) - 1)
        return _linear_image(self.images[index], srgb)

    @staticmethod
    def _per_face(name, a, nf, lo, hi):
        a = check_array(f"Scene.{name}", a, lo=lo, hi=hi).astype(np.float32)
        if a.shape == (3,):
            a = np.broadcast_to(a, (nf, 3))
        if a.shape != (nf, 3):
            raise ValueError(f"Scene.{name} must have shape ({nf}, 3) or (3,), got {a.shape}")
        return np.ascontiguousarray(a)

    # -- derived ---------------------------------------------------------------------------------
    @property
    def num_triangles(self) -> int:
        return int(self.faces.shape[0])

    def _derived(self) -> tuple:
        """(bounds, extent, centre) of the rest pose, computed once per vertex array."""
        key = (id(self.vertices), self.vertices.shape)
        if getattr(self, "_derived_key", None) != key:
            lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
            extent = max(float(np.linalg.norm(hi - lo)), 1e-30)
            self._derived_vals = ((lo, hi), extent, tuple(float(v) for v in (lo + hi) * 0.5))
            self._derived_key = key
        return self._derived_vals

    @property
    def bounds(self) -> tuple:
        """(min, max) corners of the rest-pose bounding box (computed once)."""
        return self._derived()[0]

    @property
    def extent(self) -> float:
        """Bounding-box diagonal (world units), > 0."""
        return self._derived()[1]

    @property
    def centre(self) -> tuple:
        """Centre of the rest-pose bounding box, as floats."""
        return self._derived()[2]

    @property
    def is_animated(self) -> bool:
        return any(o.motion is not None for o in self.objects)

    def camera_at(self, t: float) -> Camera:
        t = check_finite("time", t)
        if self.camera_path is None:
            return self.camera
        cam = self.camera_path(t)
        if not isinstance(cam, Camera):
            raise ValueError(f"Scene.camera_path({t!r}) must return a foveawarp.Camera, got {show(cam)}")
        return cam

    def vertices_at(self, t: float) -> np.ndarray:
        """World positions at time ``t`` (seconds, finite; rest positions moved by each object's motion)."""
        t = check_finite("time", t)
        out = self.vertices.copy()
        for o in self.objects:
            if o.motion is None:
                continue
            m = o.transform_at(t)
            a, b = o.vertex_range
            out[a:b] = (self.vertices[a:b].astype(np.float64) @ m[:3, :3].T + m[:3, 3]).astype(np.float32)
        return out

    def normals_at(self, t: float) -> Optional[np.ndarray]:
        t = check_finite("time", t)
        if self.vertex_normals is None:
            return None
        out = self.vertex_normals.copy()
        for o in self.objects:
            if o.motion is None:
                continue
            m = o.transform_at(t)[:3, :3]
            a, b = o.vertex_range
            out[a:b] = (self.vertex_normals[a:b].astype(np.float64) @ m.T).astype(np.float32)
        return out

    def summary(self) -> str:
        if self.materials is None:
            tex = "untextured"
        else:
            tex = (f"{len(self.materials)} materials, {len(self.materials.textures)} textures over "
                   f"{len(self.images)} images")
        env = "" if self.environment is None else ", environment"
        return (
            f"{self.name}: {self.num_triangles} triangles, {len(self.lights)} lights, "
            f"{len(self.area_lights)} area lights, animated={self.is_animated}, {tex}{env}"
        )


def _linear_image(im, srgb: bool) -> np.ndarray:
    if isinstance(im, ImageSource):
        from .io.images import load_image

        return load_image(im.source, srgb=bool(srgb), name=im.name, mime_type=im.mime_type)
    return im


def _wrap_index(i: np.ndarray, n: int, mode: str) -> np.ndarray:
    if mode == "clamp":
        return np.clip(i, 0, n - 1)
    if mode == "mirror":
        j = np.mod(i, 2 * n)
        return np.where(j >= n, 2 * n - 1 - j, j)
    return np.mod(i, n)


def _bilinear(level: np.ndarray, uv: np.ndarray, wrap_s: str, wrap_t: str) -> np.ndarray:
    """Bilinear lookup of an (h, w, C) level at (N, 2) UVs (texel centres at (i + 0.5) / w, row 0 at v = 0)."""
    h, w = level.shape[:2]
    x = uv[:, 0] * w - 0.5
    y = uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    xa, xb = _wrap_index(x0, w, wrap_s), _wrap_index(x0 + 1, w, wrap_s)
    ya, yb = _wrap_index(y0, h, wrap_t), _wrap_index(y0 + 1, h, wrap_t)
    top = level[ya, xa] * (1.0 - fx) + level[ya, xb] * fx
    bot = level[yb, xa] * (1.0 - fx) + level[yb, xb] * fx
    return top * (1.0 - fy) + bot * fy


def _triangle_means(chain: list, uv: np.ndarray, wrap_s: str, wrap_t: str) -> np.ndarray:
    """The mean texel value over each UV triangle (N, 3, 2): the mean of trilinear lookups at the centroids of the
    four triangles of its midpoint subdivision, each at the mip level whose texel covers the area of such a
    triangle (``0.5 log2(area in level-0 texels / 4)``, clamped to the chain)."""
    h0, w0 = chain[0].shape[:2]
    a, b, c = uv[:, 0], uv[:, 1], uv[:, 2]
    e1, e2 = (b - a) * (w0, h0), (c - a) * (w0, h0)
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    lod = np.clip(0.5 * np.log2(np.maximum(area / 4.0, 1e-30)), 0.0, len(chain) - 1)
    l0 = np.floor(lod).astype(np.int64)
    frac = (lod - l0)[:, None]
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    points = ((a + ab + ca) / 3, (ab + b + bc) / 3, (ca + bc + c) / 3, (ab + bc + ca) / 3)
    out = np.zeros((uv.shape[0], chain[0].shape[2]))
    for lev in np.unique(l0):
        sel = l0 == lev
        hi = min(lev + 1, len(chain) - 1)
        for p in points:
            lo_s = _bilinear(chain[lev], p[sel], wrap_s, wrap_t)
            hi_s = _bilinear(chain[hi], p[sel], wrap_s, wrap_t)
            out[sel] += (lo_s * (1.0 - frac[sel]) + hi_s * frac[sel]) / len(points)
    return out


def face_material_colors(faces, face_material, materials, images, uvs, uvs1=None, *, slot: str = "base_color",
                         vertex_colors=None) -> np.ndarray:
    """Each face's mean base colour (``slot="base_color"``) or emitted radiance (``slot="emissive"``), (F, 3)
    float32, from its material: the factor (``base_color_factor`` RGB, or ``emissive_factor *
    emissive_strength``) times the mean of the slot's texture over the face's UV triangle (after the slot's UV
    transform; sRGB texels decoded to linear; see :func:`_triangle_means`) times, for the base colour, the mean
    of the face's ``vertex_colors`` ((V, 3 or 4) linear, optional: glTF's COLOR_0). Base colours are clipped to
    [0, 1], emission to >= 0.

    ``materials``: a MaterialTable; ``images``: the scene's images (arrays or ImageSources, decoded once per call);
    ``uvs`` / ``uvs1``: (V, 2) or None where no texture reads them."""
    from .materials import TEXTURE_SLOTS
    from .textures import build_mip_chain

    if slot not in ("base_color", "emissive"):
        raise ValueError(f"slot must be one of ['base_color', 'emissive'], got {show(slot)}")
    table = materials if isinstance(materials, MaterialTable) else MaterialTable.build(materials, len(images))
    faces = np.asarray(faces, dtype=np.int64)
    fm = np.asarray(face_material, dtype=np.int64).reshape(-1)
    factor = table.base_color_factor[:, :3] if slot == "base_color" else table.emission
    out = factor.astype(np.float64)[fm]
    column = TEXTURE_SLOTS.index(slot)
    chains: dict = {}
    for m in range(len(table)):
        k = int(table.texture[m, column])
        if k < 0:
            continue
        sel = np.nonzero(fm == m)[0]
        if not sel.size or not out[sel].any():
            continue
        t = table.textures[k]
        uv_set = uvs1 if t.texcoord == 1 else uvs
        if uv_set is None:
            raise ValueError(f"face_material_colors: materials[{m}] {slot}_texture reads TEXCOORD_{t.texcoord}, got "
                             f"no uvs{'1' if t.texcoord == 1 else ''}")
        key = (t.image, t.srgb)
        if key not in chains:
            chains[key] = [lev.astype(np.float64) for lev in build_mip_chain(_as_rgba(_linear_image(images[t.image],
                                                                                                   t.srgb)))]
        tri_uv = t.transform_uv(np.asarray(uv_set, dtype=np.float64)[faces[sel]].reshape(-1, 2)).reshape(-1, 3, 2)
        out[sel] *= _triangle_means(chains[key], tri_uv, t.wrap_s, t.wrap_t)[:, :3]
    if slot == "base_color" and vertex_colors is not None:
        vc = np.asarray(vertex_colors, dtype=np.float64)
        out *= vc[faces][:, :, :3].mean(axis=1)
    out = np.nan_to_num(out, nan=0.0, posinf=0.0, neginf=0.0)
    return (np.clip(out, 0.0, 1.0) if slot == "base_color" else np.maximum(out, 0.0)).astype(np.float32)


def _as_rgba(a: np.ndarray) -> np.ndarray:
    """An (H, W[, C]) image as (H, W, 4): grey to R, G, B, a missing alpha 1 (as ``load_image`` expands)."""
    a = np.asarray(a)
    if a.ndim == 2:
        a = a[:, :, None]
    c = a.shape[2]
    if c == 4:
        return a
    out = np.ones(a.shape[:2] + (4,), dtype=np.float32)
    out[:, :, :3] = a[:, :, :1] if c in (1, 2) else a[:, :, :3]
    if c == 2:
        out[:, :, 3] = a[:, :, 1]
    return out


def light_params(light: Light) -> LightParams:
    """The shading kernels' struct for a host :class:`Light` (spot cone as cosines of the outer and inner
    angles)."""
    import warp as wp

    from .kernels.shade import LightParams

    p = LightParams()
    p.kind = 0 if light.kind == "point" else 1
    p.position = wp.vec3(*light.position)
    p.direction = wp.vec3(*light.direction)
    outer = math.radians(min(light.cone_deg, 180.0))
    p.cos_outer = math.cos(outer)
    p.cos_inner = math.cos(outer * (1.0 - light.penumbra))
    p.intensity = wp.vec3(*light.intensity)
    return p


class DeviceScene:
    """The Warp arrays of a :class:`Scene` on one device. Owned by a FrameLoop (or by ops)."""

    def __init__(self, scene: Scene, device=None, bvh_constructor: Optional[str] = None,
                 bvh_leaf_size: Optional[int] = None):
        import warp as wp

        from ._util import get_device
        from .kernels.shade import AreaLightParams, LightParams

        if not isinstance(scene, Scene):
            raise ValueError(f"scene must be a foveawarp.Scene, got {show(scene)} ({type(scene).__name__})")
        self.scene = scene
        self.device = get_device(device)
        self.animated = bool(scene.is_animated)  # read every frame by set_time
        requested = scene.bvh_constructor if bvh_constructor is None else bvh_constructor
        requested_leaf = scene.bvh_leaf_size if bvh_leaf_size is None else bvh_leaf_size
        dev = self.device
        ctor, leaf = resolve_bvh(requested, requested_leaf, dev)  # checks both before any allocation
        self.points = wp.array(scene.vertices, dtype=wp.vec3, device=dev)
        self.points_prev = wp.array(scene.vertices, dtype=wp.vec3, device=dev)
        self.indices = wp.array(scene.faces.reshape(-1), dtype=wp.int32, device=dev)
        try:
            self.mesh = wp.Mesh(points=self.points, indices=self.indices, bvh_constructor=ctor, bvh_leaf_size=leaf)
        except (RuntimeError, ValueError) as e:
            if requested != "auto" or ctor != "cubql":  # an explicit choice fails loudly
                raise
            # "auto" on a Warp without cuBQL: SAH (the fastest of the others on CUDA, with 2 per leaf)
            import warnings

            warnings.warn(f"DeviceScene: the cuBQL BVH could not be built ({e}); using 'sah'", RuntimeWarning,
                          stacklevel=2)
            ctor, leaf = resolve_bvh("sah", requested_leaf, dev)
            self.mesh = wp.Mesh(points=self.points, indices=self.indices, bvh_constructor=ctor, bvh_leaf_size=leaf)
        # what the BVH was built with (leaf size None: Warp's default for that constructor)
        self.bvh_constructor, self.bvh_leaf_size = ctor, leaf
        self.face_albedo = wp.array(scene.face_albedo, dtype=wp.vec3, device=dev)
        self.face_emission = wp.array(scene.face_emission, dtype=wp.vec3, device=dev)
        vn = scene.vertex_normals if scene.vertex_normals is not None else np.zeros_like(scene.vertices)
        self.vertex_normals = wp.array(vn, dtype=wp.vec3, device=dev)
        # rest positions and normals of the animated scene: set_time moves them on the device (kernels/motion.py)
        self._rest_points = wp.array(scene.vertices, dtype=wp.vec3, device=dev) if self.animated else None
        self._rest_normals = (wp.array(vn, dtype=wp.vec3, device=dev)
                              if self.animated and scene.vertex_normals is not None else None)
        # the moving objects' 4x4 transforms of the frame, written on the host and copied to the device in one copy
        # (on the CPU device the same array); on CUDA the rest of the update (previous positions, motion kernels,
        # BVH refit) is captured once as a CUDA graph and replayed (see ``_move_objects``)
        self._mats = self._mats_host = None
        self._update_graphs: dict = {}  # vertex ranges of the moving objects -> captured graph
        self._update_warm: set = set()
        self.update_graph_error: Optional[str] = None  # why the update runs eagerly on CUDA, if a capture failed
        self.face_smooth = wp.array(scene.face_smooth, dtype=wp.uint8, device=dev)
        lights = [light_params(l) for l in scene.lights]
        self.num_lights = len(lights)
        self.lights = wp.array(lights if lights else [LightParams()], dtype=LightParams, device=dev)
        areas = []
        for a in scene.area_lights:
            p = AreaLightParams()
            p.corner = wp.vec3(*a.corner)
            p.edge_u = wp.vec3(*a.edge_u)
            p.edge_v = wp.vec3(*a.edge_v)
            p.radiance = wp.vec3(*a.radiance)
            areas.append(p)
        self.num_area_lights = len(areas)
        self.area_lights = wp.array(areas if areas else [AreaLightParams()], dtype=AreaLightParams, device=dev)
        self.extent = scene.extent
        self.ray_eps = 1.0e-4 * self.extent
        self.time = None
        self.moved_last_update = False
        # (F + 1,) vec3: the CIE-Lab of each face's albedo, then of the miss albedo (black); the sampling map reads
        # its Lab albedo from it by the G-buffer's face index (kernels.saliency.face_lab_kernel)
        from .kernels.saliency import face_lab_kernel

        n = self.face_albedo.shape[0] + 1
        self.face_lab = wp.empty(n, dtype=wp.vec3, device=dev)
        wp.launch(face_lab_kernel, dim=n, inputs=[self.face_albedo], outputs=[self.face_lab], device=dev)
        self._upload_textured(scene)
        if scene.materials is not None:
            # a textured scene's albedo varies within its faces: no per-face Lab, the sampling map converts the
            # G-buffer's per-pixel albedo (FrameLoop passes face_lab=None)
            self.face_lab = None

    def _upload_textured(self, scene: Scene) -> None:
        """The textured-surface data, copied once, each only when the scene has it (None otherwise):

        - ``uvs``, ``uvs1``: (V,) vec2 per vertex (glTF convention, v down); ``tangents``: (V,) vec4 (xyz tangent,
          w handedness); ``face_material``: (F,) int32.
        - the material table, one row per material (``num_materials`` rows): ``mat_base_color`` vec4 (linear
          RGBA factor), ``mat_metallic``, ``mat_roughness``, ``mat_normal_scale``, ``mat_occlusion_strength``,
          ``mat_alpha_cutoff`` float32, ``mat_emission`` vec3 (factor * strength), ``mat_alpha_mode`` int32
          (index into ``materials.ALPHA_MODES``), ``mat_double_sided`` int32 (0/1), ``mat_transmission`` and
          ``mat_ior`` float32 (the glass part and its index of refraction), ``mat_texture`` (M, 5) int32:
          per slot of ``materials.TEXTURE_SLOTS`` the texture index, -1 for none.
        - per texture (``num_textures`` of them; the arrays keep one unused row when there are none):
          ``tex_texcoord`` int32 (which UV set), ``tex_uv_linear`` mat22 and ``tex_uv_offset`` vec2 (the slot's
          ``KHR_texture_transform``: ``uv' = tex_uv_linear * uv + tex_uv_offset``), and ``textures``, the
          :class:`foveawarp.textures.TextureSet` whose texture ``k`` is the table's texture ``k`` (its ``atlas``
          is what the kernels sample; ``mat_texture`` indexes it directly).
        """
        import warp as wp

        dev = self.device
        self.uvs = wp.array(scene.uvs, dtype=wp.vec2, device=dev) if scene.uvs is not None else None
        self.uvs1 = wp.array(scene.uvs1, dtype=wp.vec2, device=dev) if scene.uvs1 is not None else None
        self.tangents = wp.array(scene.tangents, dtype=wp.vec4, device=dev) if scene.tangents is not None else None
        self.face_material = None
        self.num_materials = self.num_textures = 0
        for n in ("mat_base_color", "mat_metallic", "mat_roughness", "mat_normal_scale", "mat_occlusion_strength",
                  "mat_alpha_cutoff", "mat_emission", "mat_alpha_mode", "mat_double_sided", "mat_transmission",
                  "mat_ior", "mat_texture",
                  "tex_texcoord", "tex_uv_linear", "tex_uv_offset", "textures"):
            setattr(self, n, None)
        t = scene.materials
        if t is None:
            return
        from .textures import TextureSampler, TextureSet

        self.face_material = wp.array(scene.face_material, dtype=wp.int32, device=dev)
        self.num_materials = len(t)
        self.mat_base_color = wp.array(t.base_color_factor, dtype=wp.vec4, device=dev)
        for n, a in (("mat_metallic", t.metallic_factor), ("mat_roughness", t.roughness_factor),
                     ("mat_normal_scale", t.normal_scale), ("mat_occlusion_strength", t.occlusion_strength),
                     ("mat_alpha_cutoff", t.alpha_cutoff), ("mat_transmission", t.transmission_factor),
                     ("mat_ior", t.ior)):
            setattr(self, n, wp.array(a, dtype=wp.float32, device=dev))
        self.mat_emission = wp.array(t.emission, dtype=wp.vec3, device=dev)
        self.mat_alpha_mode = wp.array(t.alpha_mode, dtype=wp.int32, device=dev)
        self.mat_double_sided = wp.array(t.double_sided, dtype=wp.int32, device=dev)
        self.mat_texture = wp.array(t.texture, dtype=wp.int32, device=dev)
        nt = len(t.textures)
        self.num_textures = nt
        uvm = t.tex_uv_transform if nt else np.array([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]], dtype=np.float32)
        self.tex_texcoord = wp.array(t.tex_texcoord if nt else np.zeros(1, np.int32), dtype=wp.int32, device=dev)
        self.tex_uv_linear = wp.array(np.ascontiguousarray(uvm[:, :, :2]), dtype=wp.mat22, device=dev)
        self.tex_uv_offset = wp.array(np.ascontiguousarray(uvm[:, :, 2]), dtype=wp.vec2, device=dev)
        # each (image, colour space) decoded once; texture k of the atlas is the table's texture k
        decoded, key_index, samplers = [], {}, []
        for ref in t.textures:
            im = scene.images[ref.image]
            key = (ref.image, ref.srgb if isinstance(im, ImageSource) else None)
            if key not in key_index:
                key_index[key] = len(decoded)
                decoded.append(_linear_image(im, ref.srgb))
            samplers.append(TextureSampler(key_index[key], ref.wrap_s, ref.wrap_t, ref.filter))
        self.textures = TextureSet(decoded, samplers, device=dev)

    def set_time(self, t: float) -> bool:
        """Move animated objects to time ``t``; previous positions go to ``points_prev``. Returns whether
        anything moved (the BVH is refit only then)."""
        import warp as wp

        t = check_finite("time", t)
        if not self.animated:
            self.moved_last_update = False
            if self.time is None:
                self.time = t
            return False
        if self.time is not None and t == self.time:
            wp.copy(self.points_prev, self.points)
            self.moved_last_update = False
            return False
        self._move_objects(t)  # points_prev = the positions before; the BVH refit
        first = self.time is None
        self.time = t
        if first:
            wp.copy(self.points_prev, self.points)
        self.moved_last_update = not first
        return self.moved_last_update

    def _move_objects(self, t: float) -> None:
        """The current positions to ``points_prev``, then each moving object's vertices (and vertex normals) to
        time ``t`` on the device, then the BVH refit: the values of ``Scene.vertices_at`` / ``normals_at`` (the
        same float64 products rounded to float32, summed in the kernel's order: within one float32 ulp of the
        host's, or, where a coordinate cancels to near zero, within 1e-14 of its terms; tests compare), with one
        4x4 matrix per moving object as the only data from the host.
        Every motion is evaluated (and checked) before anything is written; objects are moved in their order, so
        a vertex in two moving objects' ranges takes the later one's motion, as on the host.

        On CUDA the launches after the matrices' copy are the same every frame: from the second update of a set of
        moving objects on they replay a CUDA graph captured from them (the host's part of a frame's update of the
        earth went from 0.18 ms to the matrices' evaluation and copy); ``update_graph_error`` says why they run
        eagerly instead if the capture failed, and an update made while the device is capturing runs eagerly into
        that capture."""
        import warp as wp

        moves = []
        for o in self.scene.objects:
            if o.motion is not None:
                moves.append((tuple(o.vertex_range), o.transform_at(t)))  # a finite 4x4 (checked there)
        ranges = tuple(r for r, _ in moves)
        dev = self.device
        if self._mats is None or self._mats.shape[0] < max(len(moves), 1):
            k = max(len(moves), 1)
            self._mats = wp.zeros(k, dtype=wp.mat44d, device=dev)
            self._mats_host = self._mats if dev.is_cpu else wp.zeros(k, dtype=wp.mat44d, device="cpu")
            self._update_graphs.clear()  # they read the old array
            self._update_warm.clear()
        host = self._mats_host.numpy()
        for j, (_, m) in enumerate(moves):
            host[j] = m
        if dev.is_cuda:
            wp.copy(self._mats, self._mats_host, count=len(moves))
            if not dev.is_capturing and self.update_graph_error is None:
                g = self._update_graphs.get(ranges)
                if g is None and ranges in self._update_warm:
                    try:
                        with wp.ScopedCapture(device=dev) as cap:
                            self._launch_update(ranges)
                    except Exception as e:  # noqa: BLE001 (any capture failure: run eagerly from now on)
                        self.update_graph_error = f"{type(e).__name__}: {e}"
                    else:
                        g = self._update_graphs[ranges] = cap.graph
                if g is not None:
                    wp.capture_launch(g)
                    return
                self._update_warm.add(ranges)
        self._launch_update(ranges)

    def _launch_update(self, ranges: tuple) -> None:
        """Previous positions, the motion kernels of ``ranges`` (the moving objects' vertex ranges, transforms in
        ``self._mats`` in that order) and the BVH refit."""
        import warp as wp

        from .kernels.motion import rigid_motion_kernel
        from .parallel import launch

        wp.copy(self.points_prev, self.points)
        normals = self._rest_normals is not None
        for j, (a, b) in enumerate(ranges):
            launch(rigid_motion_kernel, b - a,
                   inputs=[self._mats, j, a, self._rest_points, self._rest_normals if normals else self._rest_points,
                           int(normals), self.points, self.vertex_normals], device=self.device)
        self.mesh.refit()

    def reset_history(self) -> None:
        """Make the previous positions equal to the current ones (after a cut)."""
        import warp as wp

        wp.copy(self.points_prev, self.points)


# ---------------------------------------------------------------------------------------------------
# loading
#
# Mesh files are read by foveawarp.meshio (re-exported here). The built-in scene builders live in
# foveawarp.scenes, which imports this module; it registers its builders here when it is imported (the package's
# __init__ imports it), so this module never imports foveawarp.scenes and the two do not import each other.

_REGISTRY: dict = {"builtin": None, "file": None, "scene_file": None}


def register_builtin_scenes(builtin: dict, file_builder: Callable, scene_file_builder: Optional[Callable] = None) -> None:
    """Called once by :mod:`foveawarp.scenes`: ``builtin`` maps a scene name to its builder (the dict itself is
    kept, so later additions to it are seen), ``file_builder(path, name=None, **kw)`` builds a scene around a mesh
    file, ``scene_file_builder(path, name=None, **kw)`` (optional) builds one from a scene file with materials
    (:func:`foveawarp.meshio.scene_file_kind` "scene")."""
    if not isinstance(builtin, dict) or not all(isinstance(k, str) and callable(b) for k, b in builtin.items()):
        raise ValueError(f"builtin must be a dict of scene name -> builder, got {show(builtin)}")
    if not callable(file_builder):
        raise ValueError(f"file_builder must be a callable (path, name=None, **kw) -> Scene, got {show(file_builder)}")
    if scene_file_builder is not None and not callable(scene_file_builder):
        raise ValueError(f"scene_file_builder must be None or a callable (path, name=None, **kw) -> Scene, got "
                         f"{show(scene_file_builder)}")
    _REGISTRY["builtin"] = builtin
    _REGISTRY["file"] = file_builder
    _REGISTRY["scene_file"] = scene_file_builder


def _builders():
    if _REGISTRY["builtin"] is None:  # only when foveawarp.scene is used without the package's __init__
        raise RuntimeError("no scene builders registered: import foveawarp (or foveawarp.scenes) first")
    return _REGISTRY["builtin"], _REGISTRY["file"], _REGISTRY["scene_file"]


def load_scene(name_or_path, **kwargs) -> Scene:
    """A scene by name or from a file.

    Names: the procedural built-ins (``cornell``, ``city``, ``eyechart``, ``earth``, ``bunny-in-box``, ``room``:
    textured), the named textured models (``suzanne``, ``wicker`` ship with the package; ``barrel``,
    ``milk-truck`` and the Mitsuba scene ``grey-white-room`` are read from ``$FOVEAWARP_SCENES_DIR``, the shared
    scenes folder), and the named meshes (``bunny``, ``spot``, ``teapot`` ship with the package; ``nefertiti``,
    ``ogre`` are read from ``$FOVEAWARP_SCENES`` or a ``shared/scenes`` folder).

    Files, by extension (:data:`foveawarp.meshio.SCENE_FILE_EXTENSIONS`): ``.gltf`` / ``.glb``, ``.obj`` with an
    ``.mtl`` (once ``foveawarp.io.obj`` is there) and Mitsuba ``.xml`` are scene files with materials and
    textures, taken as they are (``foveawarp.scenes.file_scene``: the file's camera, lights and emission, default
    lights when it has none); ``.ply``, ``.stl`` and ``.obj`` without materials are meshes placed on a ground
    plane with a default spot light and camera (``foveawarp.scenes.mesh_on_ground``; PLY triangle strips
    included). A scene file keeps its own placement and gets no ground plane; ``albedo=`` (3 numbers in [0, 1])
    colours what it leaves without material and vertex colours, as it colours an uncoloured mesh on the ground.
    Keyword arguments go to the builder (e.g. ``seed``, ``motion``, ``camera_index``, ``albedo``)."""
    if isinstance(name_or_path, Scene):
        return name_or_path
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise ValueError(f"name_or_path must be a scene name or a file path, got {name_or_path!r}")
    builtin, on_ground, scene_file = _builders()
    key = str(name_or_path)
    if key in builtin:
        _check_kwargs(builtin[key], kwargs, ())
        return builtin[key](**kwargs)
    if key in NAMED_MESHES:
        _check_kwargs(on_ground, kwargs, ("path", "name"))
        p = find_named_mesh(key)
        if p is None:
            raise ValueError(named_mesh_help(key))
        return on_ground(p, name=key, **kwargs)
    p = Path(key)
    if not p.exists():
        _check_kwargs(on_ground, kwargs, ("path",))
        raise ValueError(
            f"scene {key!r} is neither a built-in name {sorted(builtin) + sorted(NAMED_MESHES)} "
            "nor an existing file"
        )
    if not p.is_file():
        raise ValueError(f"scene path {key!r} is not a file")
    kind = scene_file_kind(p)  # ValueError for an extension no reader takes
    builder = scene_file if kind == "scene" and scene_file is not None else on_ground
    _check_kwargs(builder, kwargs, ("path",))
    return builder(key, **kwargs)


def _check_kwargs(builder, kwargs: dict, exclude: tuple) -> None:
    """ValueError naming the keyword and the builder's keywords for a keyword the builder does not take."""
    import inspect

    allowed = [p for p in inspect.signature(builder).parameters if p not in exclude]
    for k in kwargs:
        if k not in allowed:
            raise ValueError(f"load_scene keyword for {builder.__name__} must be one of {allowed}, got {k!r}")
