"""The material model on the host (glTF 2.0 metallic-roughness) and its flat tables for the device.

- :class:`ImageSource`: where an image's encoded bytes live (a file, or bytes with a MIME type). Decoding is done
  by ``foveawarp.io.images.load_image(source.source, srgb=...)``; this module never decodes pixels.
- :class:`TextureRef`: one texture slot of a material: the image, the UV set, the sampler (wrap modes S/T, filter),
  the colour space of the texels (``"srgb"`` for base colour and emissive, ``"linear"`` for the others) and the
  ``KHR_texture_transform`` of its UVs.
- :class:`Material`: glTF's ``pbrMetallicRoughness`` with normal, occlusion and emissive textures,
  ``KHR_materials_emissive_strength``, the alpha mode and ``doubleSided``.
- :class:`MaterialTable`: the materials packed as structure-of-arrays (one row per material) plus a table of the
  distinct texture slots, ready to be copied to a device.

UVs follow glTF: (0, 0) is the top-left corner of the image, u to the right, v down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from .config import check_bool, check_choice, check_finite, check_int_range, check_range, check_vec, show

__all__ = [
    "WRAP_MODES",
    "FILTERS",
    "COLOR_SPACES",
    "ALPHA_MODES",
    "IMAGE_MIME_TYPES",
    "TEXTURE_SLOTS",
    "ImageSource",
    "TextureRef",
    "Material",
    "MaterialTable",
    "default_material",
]

WRAP_MODES = ("repeat", "clamp", "mirror")
FILTERS = ("linear", "nearest")
COLOR_SPACES = ("srgb", "linear")
ALPHA_MODES = ("OPAQUE", "MASK", "BLEND")
IMAGE_MIME_TYPES = ("image/png", "image/jpeg", "image/webp")
# the texture slots of a material, in the column order of MaterialTable.texture, with the colour space each holds
TEXTURE_SLOTS = ("base_color", "metallic_roughness", "normal", "occlusion", "emissive")
SLOT_COLOR_SPACE = {
    "base_color": "srgb",
    "metallic_roughness": "linear",
    "normal": "linear",
    "occlusion": "linear",
    "emissive": "srgb",
}


@dataclass(frozen=True)
class ImageSource:
    """An encoded image (PNG, JPEG, WebP) that a material's textures refer to.

    Exactly one of ``path`` and ``data`` is set.

    Attributes:
        name: a name for messages (the glTF image's name or URI, or "<file>#image<i>").
        path: the image file (absolute, or relative to the working directory).
        data: the encoded bytes (a GLB buffer view or a ``data:`` URI).
        mime_type: one of :data:`IMAGE_MIME_TYPES`; required with ``data``, optional with ``path``.
    """

    name: str
    path: Optional[Path] = None
    data: Optional[bytes] = None
    mime_type: Optional[str] = None

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise ValueError(f"ImageSource.name must be a str, got {show(self.name)}")
        if (self.path is None) == (self.data is None):
            raise ValueError(
                f"ImageSource {self.name!r}: exactly one of path and data must be set, got "
                f"path={show(self.path)} and data of {'no' if self.data is None else len(self.data)} bytes")
        if self.path is not None:
            if not isinstance(self.path, (str, Path)):
                raise ValueError(f"ImageSource.path must be a str or Path, got {show(self.path)}")
            object.__setattr__(self, "path", Path(self.path))
        else:
            if isinstance(self.data, (bytearray, memoryview)):
                object.__setattr__(self, "data", bytes(self.data))
            if not isinstance(self.data, bytes):
                raise ValueError(f"ImageSource.data must be bytes, got {show(self.data)}")
            if self.mime_type is None:
                raise ValueError(
                    f"ImageSource {self.name!r}: mime_type must be one of {list(IMAGE_MIME_TYPES)} with data, got None")
        if self.mime_type is not None:
            check_choice(f"ImageSource {self.name!r} mime_type", self.mime_type, IMAGE_MIME_TYPES)

    @property
    def source(self) -> Union[Path, bytes]:
        """What the image decoder takes: the file path, or the encoded bytes."""
        return self.path if self.path is not None else self.data


@dataclass(frozen=True)
class TextureRef:
    """One texture slot of a material.

    Attributes:
        image: index into the scene's list of :class:`ImageSource`, >= 0.
        texcoord: which UV set the slot reads (0: TEXCOORD_0, 1: TEXCOORD_1).
        wrap_s, wrap_t: wrap mode along u and v, one of :data:`WRAP_MODES`.
        filter: magnification filter, one of :data:`FILTERS`.
        color_space: ``"srgb"`` (base colour, emissive: texels are sRGB-encoded) or ``"linear"`` (the others).
        uv_offset, uv_rotation_rad, uv_scale: ``KHR_texture_transform`` of the UVs before lookup,
            ``uv' = T(offset) R(rotation) S(scale) uv``; the identity by default.
    """

    image: int
    texcoord: int = 0
    wrap_s: str = "repeat"
    wrap_t: str = "repeat"
    filter: str = "linear"
    color_space: str = "linear"
    uv_offset: tuple = (0.0, 0.0)
    uv_rotation_rad: float = 0.0
    uv_scale: tuple = (1.0, 1.0)

    def __post_init__(self):
        object.__setattr__(self, "image", check_int_range("TextureRef.image", self.image, 0))
        object.__setattr__(self, "texcoord", check_int_range("TextureRef.texcoord", self.texcoord, 0, 1))
        check_choice("TextureRef.wrap_s", self.wrap_s, WRAP_MODES)
        check_choice("TextureRef.wrap_t", self.wrap_t, WRAP_MODES)
        check_choice("TextureRef.filter", self.filter, FILTERS)
        check_choice("TextureRef.color_space", self.color_space, COLOR_SPACES)
        object.__setattr__(self, "uv_offset", check_vec("TextureRef.uv_offset", self.uv_offset, 2))
        object.__setattr__(self, "uv_rotation_rad", check_finite("TextureRef.uv_rotation_rad", self.uv_rotation_rad))
        object.__setattr__(self, "uv_scale", check_vec("TextureRef.uv_scale", self.uv_scale, 2))

    @property
    def srgb(self) -> bool:
        """True when the texels are sRGB-encoded (decode them to linear before use)."""
        return self.color_space == "srgb"

    def uv_matrix(self) -> np.ndarray:
        """The (2, 3) float64 affine map of ``KHR_texture_transform``: ``uv' = M[:, :2] @ uv + M[:, 2]``."""
        c, s = math.cos(self.uv_rotation_rad), math.sin(self.uv_rotation_rad)
        sx, sy = self.uv_scale
        ox, oy = self.uv_offset
        # the extension's matrix T * R * S, with R = [[cos, sin], [-sin, cos]]
        return np.array([[c * sx, s * sy, ox], [-s * sx, c * sy, oy]], dtype=np.float64)

    def transform_uv(self, uv) -> np.ndarray:
        """Apply the slot's UV transform to an (N, 2) array of UVs (float64 out)."""
        uv = np.asarray(uv, dtype=np.float64)
        m = self.uv_matrix()
        return uv @ m[:, :2].T + m[:, 2]


def _check_texture(field: str, value, color_space: str):
    if value is None:
        return
    if not isinstance(value, TextureRef):
        raise ValueError(f"Material.{field} must be a TextureRef or None, got {show(value)}")
    if value.color_space != color_space:
        raise ValueError(
            f"Material.{field}.color_space must be {color_space!r} (the colour space glTF defines for this slot), "
            f"got {value.color_space!r}")


@dataclass(frozen=True)
class Material:
    """A glTF 2.0 metallic-roughness material (all factors linear).

    Attributes:
        name: the material's name (may be empty).
        base_color_factor: RGBA, each in [0, 1]; multiplies the base colour texture (decoded to linear) and the
            vertex colour.
        base_color_texture: sRGB texture slot, or None.
        metallic_factor: in [0, 1]; multiplies the texture's B channel.
        roughness_factor: perceptual roughness in [0, 1]; multiplies the texture's G channel.
        metallic_roughness_texture: linear texture slot (B = metallic, G = roughness), or None.
        normal_texture: linear tangent-space normal map (+X right = tangent, +Y up = bitangent), or None.
        normal_scale: scale of the map's X and Y, a finite number.
        occlusion_texture: linear texture slot (R = occlusion), or None.
        occlusion_strength: in [0, 1]; 0 = no occlusion.
        emissive_factor: RGB, each in [0, 1].
        emissive_strength: ``KHR_materials_emissive_strength``, >= 0; the emitted radiance is
            ``emissive_factor * emissive_strength * emissive texture`` (1 = the core glTF range).
        emissive_texture: sRGB texture slot, or None.
        alpha_mode: one of :data:`ALPHA_MODES`.
        alpha_cutoff: >= 0; with "MASK", texels with alpha below it are not there.
        double_sided: False = back faces are culled and lit as seen from the front.
        transmission_factor: ``KHR_materials_transmission``, in [0, 1]: the fraction of the dielectric that is a
            glass interface (Fresnel reflection and refraction, smooth at roughness 0, GGX microfacets of the
            material's roughness above; the transmitted light tinted by the base colour). Only the path
            integrator refracts; the direct integrator shows the opaque material.
        ior: ``KHR_materials_ior``, the index of refraction of the glass, in [1, 5] (default 1.5).
    """

    name: str = ""
    base_color_factor: tuple = (1.0, 1.0, 1.0, 1.0)
    base_color_texture: Optional[TextureRef] = None
    metallic_factor: float = 1.0
    roughness_factor: float = 1.0
    metallic_roughness_texture: Optional[TextureRef] = None
    normal_texture: Optional[TextureRef] = None
    normal_scale: float = 1.0
    occlusion_texture: Optional[TextureRef] = None
    occlusion_strength: float = 1.0
    emissive_factor: tuple = (0.0, 0.0, 0.0)
    emissive_strength: float = 1.0
    emissive_texture: Optional[TextureRef] = None
    alpha_mode: str = "OPAQUE"
    alpha_cutoff: float = 0.5
    double_sided: bool = False
    transmission_factor: float = 0.0
    ior: float = 1.5

    def __post_init__(self):
        if not isinstance(self.name, str):
            raise ValueError(f"Material.name must be a str, got {show(self.name)}")
        p = f"Material {self.name!r}" if self.name else "Material"
        set_ = object.__setattr__
        set_(self, "base_color_factor", check_vec(f"{p} base_color_factor", self.base_color_factor, 4, 0.0, 1.0))
        set_(self, "metallic_factor", check_range(f"{p} metallic_factor", self.metallic_factor, 0.0, 1.0))
        set_(self, "roughness_factor", check_range(f"{p} roughness_factor", self.roughness_factor, 0.0, 1.0))
        set_(self, "normal_scale", check_finite(f"{p} normal_scale", self.normal_scale))
        set_(self, "occlusion_strength", check_range(f"{p} occlusion_strength", self.occlusion_strength, 0.0, 1.0))
        set_(self, "emissive_factor", check_vec(f"{p} emissive_factor", self.emissive_factor, 3, 0.0, 1.0))
        set_(self, "emissive_strength", check_range(f"{p} emissive_strength", self.emissive_strength, 0.0))
        check_choice(f"{p} alpha_mode", self.alpha_mode, ALPHA_MODES)
        set_(self, "alpha_cutoff", check_range(f"{p} alpha_cutoff", self.alpha_cutoff, 0.0))
        set_(self, "double_sided", check_bool(f"{p} double_sided", self.double_sided))
        set_(self, "transmission_factor", check_range(f"{p} transmission_factor", self.transmission_factor, 0.0,
                                                      1.0))
        set_(self, "ior", check_range(f"{p} ior", self.ior, 1.0, 5.0))
        for slot in TEXTURE_SLOTS:
            _check_texture(f"{slot}_texture", getattr(self, f"{slot}_texture"), SLOT_COLOR_SPACE[slot])

    def textures(self) -> dict:
        """{slot name: TextureRef} of the slots that hold a texture, in :data:`TEXTURE_SLOTS` order."""
        out = {}
        for slot in TEXTURE_SLOTS:
            t = getattr(self, f"{slot}_texture")
            if t is not None:
                out[slot] = t
        return out

    @property
    def emission(self) -> tuple:
        """The emitted radiance scale, ``emissive_factor * emissive_strength`` (RGB)."""
        return tuple(c * self.emissive_strength for c in self.emissive_factor)


def default_material() -> Material:
    """glTF's default material, for primitives without one: white, metallic 1, roughness 1, single-sided."""
    return Material(name="default")


_ALPHA_CODE = {m: i for i, m in enumerate(ALPHA_MODES)}
_WRAP_CODE = {m: i for i, m in enumerate(WRAP_MODES)}
_FILTER_CODE = {m: i for i, m in enumerate(FILTERS)}


@dataclass(frozen=True)
class MaterialTable:
    """Materials as flat arrays (row ``m`` = material ``m``) and the distinct texture slots they use.

    Material arrays (M rows):
        base_color_factor (M, 4) float32; metallic_factor, roughness_factor, normal_scale, occlusion_strength,
        alpha_cutoff (M,) float32; emission (M, 3) float32 (``emissive_factor * emissive_strength``);
        alpha_mode (M,) int32 (index into :data:`ALPHA_MODES`); double_sided (M,) int32 (0/1);
        transmission_factor, ior (M,) float32;
        texture (M, 5) int32: per slot of :data:`TEXTURE_SLOTS`, an index into ``textures`` or -1 for none.
    Texture arrays (T rows, one per distinct :class:`TextureRef`):
        tex_image (T,) int32 (index into the scene's images); tex_texcoord (T,) int32; tex_wrap (T, 2) int32
        (S, T as indices into :data:`WRAP_MODES`); tex_filter (T,) int32 (index into :data:`FILTERS`);
        tex_srgb (T,) int32 (0/1); tex_uv_transform (T, 2, 3) float32 (:meth:`TextureRef.uv_matrix`).
    """

    materials: tuple
    textures: tuple
    base_color_factor: np.ndarray
    metallic_factor: np.ndarray
    roughness_factor: np.ndarray
    normal_scale: np.ndarray
    occlusion_strength: np.ndarray
    emission: np.ndarray
    alpha_mode: np.ndarray
    alpha_cutoff: np.ndarray
    double_sided: np.ndarray
    transmission_factor: np.ndarray
    ior: np.ndarray
    texture: np.ndarray
    tex_image: np.ndarray
    tex_texcoord: np.ndarray
    tex_wrap: np.ndarray
    tex_filter: np.ndarray
    tex_srgb: np.ndarray
    tex_uv_transform: np.ndarray

    @classmethod
    def build(cls, materials: Sequence[Material], num_images: Optional[int] = None) -> "MaterialTable":
        """Pack ``materials`` (at least one). With ``num_images``, every texture's image index must be below it."""
        mats = tuple(materials)
        if not mats:
            raise ValueError("materials must hold at least one Material, got none")
        for i, m in enumerate(mats):
            if not isinstance(m, Material):
                raise ValueError(f"materials[{i}] must be a Material, got {show(m)}")
        if num_images is not None:
            num_images = check_int_range("num_images", num_images, 0)
        tex_index = {}
        textures = []
        slots = np.full((len(mats), len(TEXTURE_SLOTS)), -1, dtype=np.int32)
        for i, m in enumerate(mats):
            for j, slot in enumerate(TEXTURE_SLOTS):
                t = getattr(m, f"{slot}_texture")
                if t is None:
                    continue
                if num_images is not None and t.image >= num_images:
                    raise ValueError(
                        f"materials[{i}] ({m.name!r}) {slot}_texture.image must be in [0, {num_images - 1}] "
                        f"(the scene has {num_images} images), got {t.image}")
                if t not in tex_index:
                    tex_index[t] = len(textures)
                    textures.append(t)
                slots[i, j] = tex_index[t]
        n_t = len(textures)
        f32 = np.float32
        return cls(
            materials=mats,
            textures=tuple(textures),
            base_color_factor=np.array([m.base_color_factor for m in mats], dtype=f32).reshape(-1, 4),
            metallic_factor=np.array([m.metallic_factor for m in mats], dtype=f32),
            roughness_factor=np.array([m.roughness_factor for m in mats], dtype=f32),
            normal_scale=np.array([m.normal_scale for m in mats], dtype=f32),
            occlusion_strength=np.array([m.occlusion_strength for m in mats], dtype=f32),
            emission=np.array([m.emission for m in mats], dtype=f32).reshape(-1, 3),
            alpha_mode=np.array([_ALPHA_CODE[m.alpha_mode] for m in mats], dtype=np.int32),
            alpha_cutoff=np.array([m.alpha_cutoff for m in mats], dtype=f32),
            double_sided=np.array([int(m.double_sided) for m in mats], dtype=np.int32),
            transmission_factor=np.array([m.transmission_factor for m in mats], dtype=f32),
            ior=np.array([m.ior for m in mats], dtype=f32),
            texture=slots,
            tex_image=np.array([t.image for t in textures], dtype=np.int32).reshape(n_t),
            tex_texcoord=np.array([t.texcoord for t in textures], dtype=np.int32).reshape(n_t),
            tex_wrap=np.array([(_WRAP_CODE[t.wrap_s], _WRAP_CODE[t.wrap_t]) for t in textures],
                              dtype=np.int32).reshape(n_t, 2),
            tex_filter=np.array([_FILTER_CODE[t.filter] for t in textures], dtype=np.int32).reshape(n_t),
            tex_srgb=np.array([int(t.srgb) for t in textures], dtype=np.int32).reshape(n_t),
            tex_uv_transform=np.array([t.uv_matrix() for t in textures], dtype=f32).reshape(n_t, 2, 3),
        )

    def __len__(self) -> int:
        return len(self.materials)
