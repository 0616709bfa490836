"""The scene description every file reader returns: :class:`SceneData`, with :class:`LightData`,
:class:`CameraData`, :class:`EnvironmentData` and :class:`ShapeData`.

A reader (``read_gltf``, ``read_obj``, ``read_mitsuba``) merges all triangles in world space into one set of
vertex arrays and says, per triangle, which material it uses. Nothing here is rendered or uploaded; turning a
:class:`SceneData` into a renderable ``foveawarp.Scene`` is ``foveawarp.scene``'s job.

Units (the renderer's): lengths in the file's world units; colours linear RGB; radiance in W/(m^2 sr),
radiant intensity in W/sr, irradiance in W/m^2, each per unit of the RGB channel.

- Area emitters are no lights here: they are the ``Material`` emission of the emitting triangles,
  ``emissive_factor * emissive_strength`` = the radiance they emit (see :func:`emission_material`).
- Punctual lights (:class:`LightData`): ``color * intensity`` is the radiant intensity in W/sr of a point or
  spot light along its axis, or the irradiance in W/m^2 a directional light gives a surface facing it.
  glTF's ``KHR_lights_punctual`` gives candela (point, spot) and lux (directional); they are read as W/sr and
  W/m^2 unchanged (one photometric unit = one radiometric unit per channel, no 683 lm/W factor).
  Mitsuba gives point ``intensity`` (W/sr), spot ``intensity`` with ``cutoff_angle`` / ``beam_width`` and
  directional ``irradiance`` (W/m^2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional, Union

import numpy as np

from ..config import check_choice, check_range, check_vec, show
from ..materials import Material

__all__ = [
    "LIGHT_KINDS",
    "CAMERA_KINDS",
    "SPOT_FALLOFFS",
    "LightData",
    "CameraData",
    "EnvironmentData",
    "ShapeData",
    "SceneData",
    "emission_material",
]

LIGHT_KINDS = ("point", "spot", "directional")
CAMERA_KINDS = ("perspective", "orthographic")
# how a spot light's intensity falls from the inner to the outer cone angle
SPOT_FALLOFFS = ("linear_cos", "linear_angle")


def _unit(name: str, v) -> tuple:
    d = np.asarray(check_vec(name, v, 3), dtype=np.float64)
    n = float(np.linalg.norm(d))
    if not n > 1e-30:
        raise ValueError(f"{name} must be a non-zero vector, got {show(v)}")
    return tuple(float(c) for c in d / n)


@dataclass(frozen=True)
class LightData:
    """A punctual light in world space.

    Attributes:
        name: the light's name (may be empty).
        kind: one of :data:`LIGHT_KINDS`: "point", "spot" or "directional".
        color: linear RGB, each >= 0 (a reader puts the spectrum's shape here and its scale in ``intensity``).
        intensity: >= 0. ``color * intensity`` is the radiant intensity in W/sr (point; spot along its axis) or
            the irradiance in W/m^2 on a surface facing a directional light. glTF's candela and lux are read as
            W/sr and W/m^2; Mitsuba's point/spot ``intensity`` and directional ``irradiance`` are these units.
        range_m: distance where the light's influence ends, world units (glTF's ``range``); None = infinite.
        position: world position (a directional light keeps its node's origin; it is not used).
        direction: unit world direction the light shines along (spot axis, directional light's travel).
        inner_cone_rad: spot: angle from the axis within which the full intensity is emitted, radians (0 otherwise).
        outer_cone_rad: spot: angle from the axis beyond which nothing is emitted, radians, >= inner (0 otherwise).
        spot_falloff: one of :data:`SPOT_FALLOFFS`, the profile between the two angles: "linear_cos" (glTF: a
            linear ramp in cos(angle)) or "linear_angle" (Mitsuba's spot: a linear ramp in the angle).
        node: the glTF node that places the light; None for other formats.
    """

    name: str
    kind: str
    color: tuple
    intensity: float
    range_m: Optional[float] = None
    position: tuple = (0.0, 0.0, 0.0)
    direction: tuple = (0.0, 0.0, -1.0)
    inner_cone_rad: float = 0.0
    outer_cone_rad: float = 0.0
    spot_falloff: str = "linear_cos"
    node: Optional[int] = None

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise ValueError(f"LightData.name must be a str, got {show(self.name)}")
        p = f"LightData {self.name!r}" if self.name else "LightData"
        check_choice(f"{p} kind", self.kind, LIGHT_KINDS)
        set_ = object.__setattr__
        set_(self, "color", check_vec(f"{p} color", self.color, 3, 0.0))
        set_(self, "intensity", check_range(f"{p} intensity", self.intensity, 0.0))
        if self.range_m is not None:
            set_(self, "range_m", check_range(f"{p} range_m", self.range_m, 0.0, lo_open=True))
        set_(self, "position", check_vec(f"{p} position", self.position, 3))
        set_(self, "direction", _unit(f"{p} direction", self.direction))
        set_(self, "outer_cone_rad", check_range(f"{p} outer_cone_rad", self.outer_cone_rad, 0.0, math.pi))
        set_(self, "inner_cone_rad", check_range(f"{p} inner_cone_rad", self.inner_cone_rad, 0.0,
                                                 self.outer_cone_rad))
        check_choice(f"{p} spot_falloff", self.spot_falloff, SPOT_FALLOFFS)

    @property
    def radiant(self) -> tuple:
        """``color * intensity``: W/sr (point, spot axis) or W/m^2 (directional), RGB."""
        return tuple(c * self.intensity for c in self.color)


@dataclass(frozen=True)
class CameraData:
    """A camera in world space: eye, unit view direction and unit up (orthogonal to it).

    Attributes:
        name: the camera's name (may be empty).
        kind: one of :data:`CAMERA_KINDS`.
        eye: world position.
        forward: unit world view direction.
        up: unit world up, orthogonal to ``forward`` (the image's upward direction).
        yfov_rad: vertical field of view, radians, in (0, pi) (perspective; 0 for orthographic).
        aspect: width / height the file asks for, or None (then the viewport's).
        znear: near plane distance, world units (>= 0; 0 when the file gives none or it is ignored).
        zfar: far plane distance, or None (infinite).
        xmag, ymag: half width and half height of an orthographic view (0 for perspective).
        camera: glTF: index into the file's ``cameras``; None for other formats.
        node: glTF: the node that places the camera; None for other formats.
    """

    name: str
    kind: str
    eye: tuple
    forward: tuple
    up: tuple
    yfov_rad: float
    aspect: Optional[float] = None
    znear: float = 0.0
    zfar: Optional[float] = None
    xmag: float = 0.0
    ymag: float = 0.0
    camera: Optional[int] = None
    node: Optional[int] = None

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise ValueError(f"CameraData.name must be a str, got {show(self.name)}")
        check_choice("CameraData.kind", self.kind, CAMERA_KINDS)
        if self.kind == "perspective":
            check_range("CameraData.yfov_rad", self.yfov_rad, 0.0, math.pi, lo_open=True, hi_open=True)
        if self.aspect is not None:
            check_range("CameraData.aspect", self.aspect, 0.0, lo_open=True)

    @property
    def fov_y_deg(self) -> float:
        """Vertical field of view in degrees (perspective)."""
        return math.degrees(self.yfov_rad)

    def fov_x_rad(self, aspect: Optional[float] = None) -> float:
        """Horizontal field of view in radians for ``aspect`` (width / height; None = the camera's own)."""
        a = self.aspect if aspect is None else aspect
        if a is None:
            raise ValueError("aspect must be given: the camera has no aspect ratio of its own")
        return 2.0 * math.atan(math.tan(0.5 * self.yfov_rad) * float(a))

    def camera_kwargs(self, distance: float = 1.0) -> dict:
        """Keyword arguments for ``foveawarp.Camera``: eye, a target ``distance`` along ``forward``, up, fov."""
        target = tuple(e + distance * f for e, f in zip(self.eye, self.forward))
        return {"eye": self.eye, "target": target, "up": self.up, "fov_y_deg": self.fov_y_deg}


@dataclass(frozen=True)
class EnvironmentData:
    """Light from infinitely far away, seen in the directions no geometry covers.

    Attributes:
        image: an equirectangular (latitude-longitude) radiance map: the path of an ``.hdr``/``.exr`` file
            (``foveawarp.io.images.load_environment`` decodes it), or an (H, W, 3) float32 array of linear
            radiance (a constant environment is (1, 1, 3)).
        scale: multiplies the image's radiance, >= 0.
        to_world: (3, 3) float64 rotation from the map's local frame to world space.
        name: a label for messages.

    The map's local frame is Mitsuba's ``envmap``: a local direction ``d`` looks up
    ``u = 0.5 + atan2(d.x, -d.z) / (2 pi)``, ``v = acos(d.y) / pi`` (u right, v down from the image's top row),
    so the local +Y is the top row.
    """

    image: Union[Path, np.ndarray]
    scale: float = 1.0
    to_world: np.ndarray = field(default_factory=lambda: np.eye(3))
    name: str = ""

    def __post_init__(self):
        if isinstance(self.image, (str, Path)):
            object.__setattr__(self, "image", Path(self.image))
        elif isinstance(self.image, np.ndarray):
            a = self.image
            if a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
                raise ValueError(f"EnvironmentData.image must be a path or an (H, W, 3) array, got shape {a.shape}")
            a = a.astype(np.float32)
            if not np.isfinite(a).all() or (a < 0).any():
                raise ValueError("EnvironmentData.image must hold finite radiance values >= 0")
            object.__setattr__(self, "image", a)
        else:
            raise ValueError(f"EnvironmentData.image must be a path or an (H, W, 3) array, got {show(self.image)}")
        object.__setattr__(self, "scale", check_range("EnvironmentData.scale", self.scale, 0.0))
        m = np.asarray(self.to_world, dtype=np.float64)
        if m.shape != (3, 3) or not np.isfinite(m).all():
            raise ValueError(f"EnvironmentData.to_world must be a finite 3x3 matrix, got {show(self.to_world)}")
        object.__setattr__(self, "to_world", m)

    @property
    def is_constant(self) -> bool:
        """True for a (1, 1, 3) array: the same radiance from every direction."""
        return isinstance(self.image, np.ndarray) and self.image.shape[:2] == (1, 1)


@dataclass(frozen=True)
class ShapeData:
    """Where one shape of the file lies in the merged arrays.

    Attributes:
        name: the shape's name or id (may be empty).
        kind: what it was in the file ("gltf", "obj", "ply", "rectangle", "cube", "sphere", "disk", ...).
        vertex_range: (start, end) into ``SceneData.vertices``.
        triangle_range: (start, end) into ``SceneData.triangles``.
        material: index into ``SceneData.materials`` (the shape's first triangle's for a multi-material shape).
    """

    name: str
    kind: str
    vertex_range: tuple
    triangle_range: tuple
    material: int

    @property
    def num_triangles(self) -> int:
        return int(self.triangle_range[1] - self.triangle_range[0])


@dataclass
class SceneData:
    """The host-side content of a scene file, in world space.

    Attributes:
        path: the file read.
        vertices: (V, 3) float32 world positions.
        normals: (V, 3) float32 unit world normals.
        tangents: (V, 4) float32: unit world tangent (xyz, orthogonal to the normal) and handedness w = +-1;
            the bitangent ``w * cross(N, T)`` points to the image's top.
        uvs: (V, 2) float32 texture coordinates in glTF's convention: (0, 0) is the image's top-left corner, v
            grows downwards; 0 where a shape has none.
        uvs1: (V, 2) float32 a second UV set, or None when no shape has one.
        colors: (V, 4) float32 linear RGBA vertex colours, or None when no shape has any.
        triangles: (F, 3) int32 vertex indices, counter-clockwise seen from the front.
        material_ids: (F,) int32 index into ``materials``.
        materials: the :class:`foveawarp.materials.Material` list; emitting surfaces carry their radiance as
            ``emissive_factor * emissive_strength``.
        images: the :class:`foveawarp.materials.ImageSource` list the materials' textures index.
        lights: the punctual lights (:class:`LightData`).
        cameras: every camera of the file (:class:`CameraData`).
        camera: the chosen camera, or None when the file has none.
        extensions_ignored: glTF: the names of the extensions used by the file that were ignored.
        environment: the environment light (:class:`EnvironmentData`), or None.
        film_size: (width, height) in pixels the file asks for, or None.
        warnings: what the reader left out or changed, one message each.
        shapes: where each shape lies in the arrays (:class:`ShapeData`), in file order.
    """

    path: Path
    vertices: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    uvs: np.ndarray
    uvs1: Optional[np.ndarray]
    colors: Optional[np.ndarray]
    triangles: np.ndarray
    material_ids: np.ndarray
    materials: list
    images: list
    lights: list = field(default_factory=list)
    cameras: list = field(default_factory=list)
    camera: Optional[CameraData] = None
    extensions_ignored: tuple = ()
    environment: Optional[EnvironmentData] = None
    film_size: Optional[tuple] = None
    warnings: tuple = ()
    shapes: list = field(default_factory=list)

    @property
    def num_triangles(self) -> int:
        return int(self.triangles.shape[0])

    @property
    def emissive_triangles(self) -> np.ndarray:
        """(K,) int64 indices of the triangles whose material emits (radiance > 0)."""
        emitting = np.array([max(m.emission) > 0.0 for m in self.materials], dtype=bool)
        if not emitting.any():
            return np.zeros(0, dtype=np.int64)
        return np.nonzero(emitting[self.material_ids])[0]


def emission_material(base: Material, radiance, name: Optional[str] = None) -> Material:
    """``base`` emitting ``radiance`` (linear RGB, W/(m^2 sr), each >= 0): ``emissive_strength`` = the largest
    channel and ``emissive_factor`` = ``radiance / emissive_strength`` (so each factor stays in [0, 1])."""
    r = check_vec("radiance", radiance, 3, 0.0)
    s = max(r)
    factor = tuple(c / s for c in r) if s > 0.0 else (0.0, 0.0, 0.0)
    factor = tuple(min(1.0, max(0.0, c)) for c in factor)
    return replace(base, name=base.name if name is None else name, emissive_factor=factor,
                   emissive_strength=s if s > 0.0 else 1.0, emissive_texture=None)
