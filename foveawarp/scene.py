"""Scene: triangle geometry + per-face material + lights + optional animation, and its device copy.

A :class:`Scene` is a host-side description (NumPy arrays). :class:`DeviceScene` owns the Warp arrays of one
device: the ``wp.Mesh`` (SAH BVH by default), the materials and the light arrays. Animated objects move
their vertices rigidly; the device copy refits its BVH only when something moved.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from .camera import Camera
from .config import check_choice, check_finite, check_range

__all__ = ["Light", "AreaLight", "SceneObject", "Scene", "DeviceScene", "load_scene", "scene_search_dirs"]

BVH_CONSTRUCTORS = ("sah", "median", "lbvh")


def _vec3(name, v):
    try:
        t = tuple(float(c) for c in v)
    except TypeError:
        raise ValueError(f"{name} must be 3 finite numbers, got {v!r}") from None
    if len(t) != 3:
        raise ValueError(f"{name} must be 3 finite numbers, got {v!r}")
    for i, c in enumerate(t):
        check_finite(f"{name}[{i}]", c)
    return t


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
        inten = _vec3("Light.intensity", self.intensity)
        for i, c in enumerate(inten):
            check_range(f"Light.intensity[{i}]", c, 0.0, None)
        object.__setattr__(self, "intensity", inten)
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
        for n in ("corner", "edge_u", "edge_v", "radiance"):
            object.__setattr__(self, n, _vec3(f"AreaLight.{n}", getattr(self, n)))
        if not np.linalg.norm(np.cross(self.edge_u, self.edge_v)) > 0:
            raise ValueError(f"AreaLight.edge_u {self.edge_u!r} and edge_v {self.edge_v!r} must span an area")
        for i, c in enumerate(self.radiance):
            check_range(f"AreaLight.radiance[{i}]", c, 0.0, None)


@dataclass
class SceneObject:
    """A rigid group of vertices (``vertex_range`` = [start, end)) with an optional motion ``t -> 4x4``."""

    name: str
    vertex_range: tuple
    motion: Optional[Callable[[float], np.ndarray]] = None


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
        bvh_constructor: "sah" (default; traces fastest), "median" or "lbvh" (builds fastest).
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
    bvh_constructor: str = "sah"

    def __post_init__(self):
        v = np.asarray(self.vertices)
        f = np.asarray(self.faces)
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] < 3:
            raise ValueError(f"Scene.vertices must have shape (V >= 3, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] < 1:
            raise ValueError(
                f"Scene.faces must have shape (F >= 1, 3) of triangle vertex indices, got {f.shape}"
                " (empty or non-triangle mesh)"
            )
        if not np.all(np.isfinite(v)):
            raise ValueError("Scene.vertices must be finite; found NaN or Inf")
        if not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"Scene.faces must be integers, got dtype {f.dtype}")
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise ValueError(f"Scene.faces indices must be in [0, {v.shape[0] - 1}], got [{f.min()}, {f.max()}]")
        self.vertices = np.ascontiguousarray(v, dtype=np.float32)
        self.faces = np.ascontiguousarray(f, dtype=np.int32)
        nf = self.faces.shape[0]
        self.face_albedo = self._per_face("face_albedo", self.face_albedo, nf, 0.0, 1.0)
        self.face_emission = self._per_face(
            "face_emission", np.zeros((nf, 3)) if self.face_emission is None else self.face_emission, nf, 0.0, None
        )
        if self.vertex_normals is not None:
            vn = np.asarray(self.vertex_normals, dtype=np.float32)
            if vn.shape != self.vertices.shape:
                raise ValueError(f"Scene.vertex_normals must have shape {self.vertices.shape}, got {vn.shape}")
            self.vertex_normals = np.nan_to_num(vn, nan=0.0, posinf=0.0, neginf=0.0)
        if self.face_smooth is None:
            self.face_smooth = np.zeros(nf, dtype=np.uint8)
        self.face_smooth = np.ascontiguousarray(self.face_smooth, dtype=np.uint8).reshape(nf)
        if self.vertex_normals is None and self.face_smooth.any():
            raise ValueError("Scene.face_smooth marks smooth faces but Scene.vertex_normals is None")
        check_choice("Scene.bvh_constructor", self.bvh_constructor, BVH_CONSTRUCTORS)
        for i, l in enumerate(self.lights):
            if not isinstance(l, Light):
                raise ValueError(f"Scene.lights[{i}] must be a Light, got {type(l).__name__}")
        for i, l in enumerate(self.area_lights):
            if not isinstance(l, AreaLight):
                raise ValueError(f"Scene.area_lights[{i}] must be an AreaLight, got {type(l).__name__}")

    @staticmethod
    def _per_face(name, a, nf, lo, hi):
        a = np.asarray(a, dtype=np.float32)
        if a.shape == (3,):
            a = np.broadcast_to(a, (nf, 3))
        if a.shape != (nf, 3):
            raise ValueError(f"Scene.{name} must have shape ({nf}, 3) or (3,), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"Scene.{name} must be finite")
        if a.min() < lo or (hi is not None and a.max() > hi):
            raise ValueError(
                f"Scene.{name} must be in [{lo}, {hi if hi is not None else 'inf'}], got [{a.min()}, {a.max()}]"
            )
        return np.ascontiguousarray(a)

    # -- derived ---------------------------------------------------------------------------------
    @property
    def num_triangles(self) -> int:
        return int(self.faces.shape[0])

    @property
    def bounds(self) -> tuple:
        """(min, max) corners of the rest-pose bounding box (computed once)."""
        key = (id(self.vertices), self.vertices.shape)
        if getattr(self, "_bounds_key", None) != key:
            self._bounds = (self.vertices.min(axis=0), self.vertices.max(axis=0))
            self._bounds_key = key
        return self._bounds

    @property
    def extent(self) -> float:
        """Bounding-box diagonal (world units), > 0."""
        lo, hi = self.bounds
        return max(float(np.linalg.norm(hi - lo)), 1e-30)

    @property
    def is_animated(self) -> bool:
        return any(o.motion is not None for o in self.objects)

    def camera_at(self, t: float) -> Camera:
        return self.camera if self.camera_path is None else self.camera_path(float(t))

    def vertices_at(self, t: float) -> np.ndarray:
        """World positions at time ``t`` (rest positions moved by each object's motion)."""
        out = self.vertices.copy()
        for o in self.objects:
            if o.motion is None:
                continue
            m = np.asarray(o.motion(float(t)), dtype=np.float64)
            a, b = o.vertex_range
            out[a:b] = (self.vertices[a:b].astype(np.float64) @ m[:3, :3].T + m[:3, 3]).astype(np.float32)
        return out

    def normals_at(self, t: float) -> Optional[np.ndarray]:
        if self.vertex_normals is None:
            return None
        out = self.vertex_normals.copy()
        for o in self.objects:
            if o.motion is None:
                continue
            m = np.asarray(o.motion(float(t)), dtype=np.float64)[:3, :3]
            a, b = o.vertex_range
            out[a:b] = (self.vertex_normals[a:b].astype(np.float64) @ m.T).astype(np.float32)
        return out

    def summary(self) -> str:
        return (
            f"{self.name}: {self.num_triangles} triangles, {len(self.lights)} lights, "
            f"{len(self.area_lights)} area lights, animated={self.is_animated}"
        )


class DeviceScene:
    """The Warp arrays of a :class:`Scene` on one device. Owned by a FrameLoop (or by ops)."""

    def __init__(self, scene: Scene, device=None, bvh_constructor: Optional[str] = None):
        import warp as wp

        from ._util import get_device
        from .kernels.shade import AreaLightParams, LightParams

        self.scene = scene
        self.device = get_device(device)
        ctor = bvh_constructor or scene.bvh_constructor
        check_choice("bvh_constructor", ctor, BVH_CONSTRUCTORS)
        dev = self.device
        self.points = wp.array(scene.vertices, dtype=wp.vec3, device=dev)
        self.points_prev = wp.array(scene.vertices, dtype=wp.vec3, device=dev)
        self.indices = wp.array(scene.faces.reshape(-1), dtype=wp.int32, device=dev)
        self.mesh = wp.Mesh(points=self.points, indices=self.indices, bvh_constructor=ctor)
        self.face_albedo = wp.array(scene.face_albedo, dtype=wp.vec3, device=dev)
        self.face_emission = wp.array(scene.face_emission, dtype=wp.vec3, device=dev)
        vn = scene.vertex_normals if scene.vertex_normals is not None else np.zeros_like(scene.vertices)
        self.vertex_normals = wp.array(vn, dtype=wp.vec3, device=dev)
        self.face_smooth = wp.array(scene.face_smooth, dtype=wp.uint8, device=dev)
        lights = []
        for l in scene.lights:
            p = LightParams()
            p.kind = 0 if l.kind == "point" else 1
            p.position = wp.vec3(*l.position)
            p.direction = wp.vec3(*l.direction)
            outer = math.radians(min(l.cone_deg, 180.0))
            inner = outer * (1.0 - l.penumbra)
            p.cos_outer = math.cos(outer)
            p.cos_inner = math.cos(inner)
            p.intensity = wp.vec3(*l.intensity)
            lights.append(p)
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

    def set_time(self, t: float) -> bool:
        """Move animated objects to time ``t``; previous positions go to ``points_prev``. Returns whether
        anything moved (the BVH is refit only then)."""
        import warp as wp

        t = float(t)
        if not self.scene.is_animated:
            self.moved_last_update = False
            if self.time is None:
                self.time = t
            return False
        wp.copy(self.points_prev, self.points)
        if self.time is not None and t == self.time:
            self.moved_last_update = False
            return False
        v = self.scene.vertices_at(t)
        self.points.assign(v)
        n = self.scene.normals_at(t)
        if n is not None:
            self.vertex_normals.assign(n)
        self.mesh.refit()
        first = self.time is None
        self.time = t
        if first:
            wp.copy(self.points_prev, self.points)
        self.moved_last_update = not first
        return self.moved_last_update

    def reset_history(self) -> None:
        """Make the previous positions equal to the current ones (after a cut)."""
        import warp as wp

        wp.copy(self.points_prev, self.points)


# ---------------------------------------------------------------------------------------------------
# loading


def scene_search_dirs() -> list:
    """Folders searched for named mesh files ("bunny", "spot", ...): $FOVEAWARP_SCENES (os.pathsep
    separated), ./shared/scenes, ../shared/scenes, and the shared/scenes beside this checkout."""
    dirs = []
    env = os.environ.get("FOVEAWARP_SCENES")
    if env:
        dirs += [Path(p) for p in env.split(os.pathsep) if p]
    here = Path(__file__).resolve().parent
    dirs += [Path("shared/scenes"), Path("../shared/scenes"), here.parent / "shared" / "scenes",
             here.parent.parent / "shared" / "scenes"]
    return dirs


NAMED_MESHES = {
    "bunny": "stanford-bunny.obj",
    "spot": "spot.obj",
    "nefertiti": "nefertiti.obj",
    "ogre": "ogre.obj",
    "teapot": "teapot.obj",
}


def find_named_mesh(name: str) -> Optional[Path]:
    fname = NAMED_MESHES.get(name, name)
    for d in scene_search_dirs():
        p = d / fname
        if p.is_file():
            return p
    return None


def load_mesh_arrays(path) -> tuple:
    """Read any mesh file trimesh reads -> (vertices, faces, face_albedo or None, vertex_normals)."""
    import trimesh

    p = Path(path)
    if not p.exists():
        raise ValueError(f"scene path {str(path)!r} does not exist")
    if not p.is_file():
        raise ValueError(f"scene path {str(path)!r} is not a file")
    try:
        loaded = trimesh.load(str(p), force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for unreadable input
        raise ValueError(f"scene file {str(path)!r} could not be read as a mesh: {e}") from None
    if isinstance(loaded, trimesh.Scene):  # older trimesh versions may still return a Scene
        geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        loaded = trimesh.util.concatenate(geoms) if geoms else None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0 or len(loaded.vertices) < 3:
        raise ValueError(f"scene file {str(path)!r} holds no triangle mesh (empty, points only, or not a mesh)")
    v = np.asarray(loaded.vertices, dtype=np.float64)
    f = np.asarray(loaded.faces, dtype=np.int64)
    if not np.all(np.isfinite(v)):
        raise ValueError(f"scene file {str(path)!r} has non-finite vertex coordinates")
    albedo = None
    try:
        vis = loaded.visual
        kind = getattr(vis, "kind", None)
        if kind == "face":
            albedo = np.asarray(vis.face_colors[:, :3], dtype=np.float32) / 255.0
        elif kind == "vertex":
            vc = np.asarray(vis.vertex_colors[:, :3], dtype=np.float32) / 255.0
            albedo = vc[f].mean(axis=1)
    except Exception:
        albedo = None
    try:
        vn = np.asarray(loaded.vertex_normals, dtype=np.float32)
    except Exception:
        vn = None
    return v, f, albedo, vn


def load_scene(name_or_path, **kwargs) -> Scene:
    """A built-in scene by name (``cornell``, ``city``, ``eyechart``, ``earth``, ``bunny-in-box``), a named
    mesh from the shared scene folder (``bunny``, ``spot``, ``nefertiti``, ``ogre``, ``teapot``), or any
    mesh file trimesh reads (.obj .ply .glb .gltf .stl ...), placed on a ground plane with a default spot
    light and camera. Keyword arguments go to the builder (e.g. ``seed``, ``motion``)."""
    from . import scenes

    if isinstance(name_or_path, Scene):
        return name_or_path
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise ValueError(f"name_or_path must be a scene name or a file path, got {name_or_path!r}")
    key = str(name_or_path)
    if key in scenes.BUILTIN:
        return scenes.BUILTIN[key](**kwargs)
    if key in NAMED_MESHES:
        p = find_named_mesh(key)
        if p is None:
            raise ValueError(
                f"scene {key!r} needs {NAMED_MESHES[key]!r}, not found in "
                f"{[str(d) for d in scene_search_dirs()]}; set FOVEAWARP_SCENES to its folder"
            )
        return scenes.mesh_on_ground(p, name=key, **kwargs)
    if not Path(key).exists():
        raise ValueError(
            f"scene {key!r} is neither a built-in name {sorted(scenes.BUILTIN) + sorted(NAMED_MESHES)} "
            "nor an existing file"
        )
    return scenes.mesh_on_ground(key, **kwargs)
