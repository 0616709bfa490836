"""A scene's textures on a device: mip chains packed into one software atlas.

:class:`TextureSet` copies every texture of a scene to the device once: the linear RGBA images (colour data
already decoded from sRGB, so the mip chain averages linear values), all their mip levels in one flat
``wp.array(dtype=wp.vec4)``, and the tables of levels and textures, bundled as the
:class:`foveawarp.kernels.texture.TextureAtlas` struct that kernels take as one argument and sample with the
``@wp.func`` s of ``foveawarp.kernels.texture``.

Why an atlas of its own and not ``wp.Texture2D``: a kernel takes a fixed number of ``Texture2D`` arguments while a
scene has any number of textures; a ``Texture2D``'s wrap and filter are fixed at its creation; and the CUDA
texture unit interpolates with 8-bit fixed-point weights (a 1/256 step) where the CPU device computes in float32,
so the two devices would differ. The atlas gives the same values on CPU and CUDA at the cost of four loads per
bilinear tap instead of one hardware fetch.

Mip chain (:func:`build_mip_chain`): level k is ``max(1, w >> k) x max(1, h >> k)``, down to 1 x 1. Each texel of
a level is the mean of the parent texels under its footprint (an area-weighted box filter, so every level keeps
the mean of level 0): for an even axis the 2-texel average; for an odd axis of ``2m + 1`` texels halved to ``m``,
output texel ``j`` covers parent texels ``2j, 2j + 1, 2j + 2`` with weights ``(m - j, m, j + 1) / (2m + 1)``;
an axis of 1 texel stays 1.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Optional, Sequence

import numpy as np
import warp as wp

from .config import check_choice, check_int_range, check_range, show
from .kernels import texture as tk
from .materials import FILTERS, WRAP_MODES

__all__ = [
    "TEXTURE_LOD_MODES",
    "SAMPLE_FILTERS",
    "MAX_TEXTURE_SIZE",
    "MAX_ATLAS_TEXELS",
    "TextureSampler",
    "build_mip_chain",
    "mip_level_count",
    "pixel_spread_angle_rad",
    "footprint_spread_angle_rad",
    "TextureSet",
]

# ShadingConfig.texture_lod: "none" = level 0, bilinear; "ray_cone" = the ray-cone LOD, trilinear
TEXTURE_LOD_MODES = ("none", "ray_cone")
_LOD_CODE = {"none": 0, "ray_cone": 1}
# filter overrides of TextureSet.sample (None = each texture's own filter)
SAMPLE_FILTERS = ("nearest", "bilinear", "trilinear")
_SAMPLER_CODE = {None: -1, "nearest": 0, "bilinear": 1, "trilinear": 2}
_WRAP_CODE = {m: i for i, m in enumerate(WRAP_MODES)}
_FILTER_CODE = {m: i for i, m in enumerate(FILTERS)}
# largest width or height of an image: 16384 x 16384 RGBA float32 is 4 GiB, and indices stay within int32
MAX_TEXTURE_SIZE = 16384
# most texels of all levels of all textures of one atlas: the kernels index the atlas with int32
MAX_ATLAS_TEXELS = 2**31 - 1


@dataclasses.dataclass(frozen=True)
class TextureSampler:
    """How one texture reads its image.

    Attributes:
        image: index into the images given to :class:`TextureSet`, >= 0.
        wrap_s, wrap_t: wrap along u and v, one of ``foveawarp.materials.WRAP_MODES`` ("repeat", "clamp",
            "mirror").
        filter: "linear" (bilinear, trilinear between levels) or "nearest".
    """

    image: int
    wrap_s: str = "repeat"
    wrap_t: str = "repeat"
    filter: str = "linear"

    def __post_init__(self):
        object.__setattr__(self, "image", check_int_range("TextureSampler.image", self.image, 0))
        check_choice("TextureSampler.wrap_s", self.wrap_s, WRAP_MODES)
        check_choice("TextureSampler.wrap_t", self.wrap_t, WRAP_MODES)
        check_choice("TextureSampler.filter", self.filter, FILTERS)


def mip_level_count(width: int, height: int) -> int:
    """Number of levels of a full chain down to 1 x 1: ``floor(log2(max(w, h))) + 1``."""
    return int(max(int(width), int(height))).bit_length()


def _halve_axis(a: np.ndarray, axis: int) -> np.ndarray:
    """Area-weighted halving of one axis of a float64 array (see the module docstring)."""
    n = a.shape[axis]
    if n == 1:
        return a
    a = np.moveaxis(a, axis, 0)
    m = n // 2
    if n % 2 == 0:
        out = 0.5 * (a[0::2] + a[1::2])
    else:
        j = np.arange(m, dtype=np.float64).reshape((m,) + (1,) * (a.ndim - 1))
        out = ((m - j) * a[0:n - 1:2] + m * a[1:n:2] + (j + 1) * a[2:n:2]) / n
    return np.moveaxis(out, 0, axis)


def build_mip_chain(image: np.ndarray, num_levels: Optional[int] = None) -> list:
    """The mip chain of an ``(H, W, C)`` linear image: a list of float32 ``(h_k, w_k, C)`` arrays, level 0 the
    image itself; ``num_levels=None`` for the full chain to 1 x 1."""
    a = np.asarray(image)
    if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"image must be an (H, W, C) array with H, W >= 1, got shape {a.shape}")
    full = mip_level_count(a.shape[1], a.shape[0])
    if num_levels is None:
        num_levels = full
    num_levels = check_int_range("num_levels", num_levels, 1, full)
    cur = a.astype(np.float64)
    levels = [np.ascontiguousarray(a, dtype=np.float32)]
    for _ in range(1, num_levels):
        cur = _halve_axis(_halve_axis(cur, 0), 1)
        levels.append(cur.astype(np.float32))
    return levels


def pixel_spread_angle_rad(fov_y_deg: float, height_px: int) -> float:
    """A primary ray's cone spread angle in radians: ``atan(2 tan(fov_y / 2) / H)``."""
    fov = check_range("fov_y_deg", fov_y_deg, 0.0, 180.0, lo_open=True, hi_open=True)
    h = check_int_range("height_px", height_px, 1)
    return math.atan(2.0 * math.tan(math.radians(fov) / 2.0) / h)


def footprint_spread_angle_rad(pixel_angle_rad: float, footprint_px: float) -> float:
    """The spread angle of a sample standing for ``footprint_px`` pixels (the sparse foveated sample spacing):
    ``footprint_px * pixel_angle_rad``, capped at ``kernels.texture.SPREAD_ANGLE_MAX``."""
    a = check_range("pixel_angle_rad", pixel_angle_rad, 0.0)
    s = check_range("footprint_px", footprint_px, 0.0)
    return min(a * s, float(tk.SPREAD_ANGLE_MAX))


def _check_image(i: int, im) -> np.ndarray:
    if hasattr(im, "numpy") and not isinstance(im, np.ndarray):
        im = im.numpy()
    a = np.asarray(im)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 2, 3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"images[{i}] must be an (H, W) or (H, W, 1..4) array with H, W >= 1, got shape "
                         f"{np.shape(im)}")
    if max(a.shape[0], a.shape[1]) > MAX_TEXTURE_SIZE:
        raise ValueError(f"images[{i}] must be at most {MAX_TEXTURE_SIZE} texels wide and high, got "
                         f"{a.shape[1]} x {a.shape[0]}")
    if a.dtype.kind != "f":
        raise ValueError(f"images[{i}] must hold linear floating-point values, got dtype {a.dtype}")
    bad = ~np.isfinite(a)
    if bad.any():
        idx = tuple(int(k) for k in np.argwhere(bad)[0])
        raise ValueError(f"images[{i}] must hold finite values, got {show(a[idx])} at index {idx}")
    # expand to RGBA as load_image does: grey to R, G, B; missing alpha = 1
    h, w, c = a.shape
    out = np.ones((h, w, 4), dtype=np.float32)
    if c in (1, 2):
        out[:, :, :3] = a[:, :, :1]
    else:
        out[:, :, :3] = a[:, :, :3]
    if c in (2, 4):
        out[:, :, 3] = a[:, :, c - 1]
    return out


class TextureSet:
    """Textures of a scene on one device, in one atlas (:class:`foveawarp.kernels.texture.TextureAtlas`).

    Args:
        images: linear images, each ``(H, W)`` or ``(H, W, C)`` with C in 1..4 (expanded to RGBA like
            ``load_image``), finite floats. Decode sRGB colour data before (``load_image(..., srgb=True)``).
        textures: one :class:`TextureSampler` (or any object with ``image``, ``wrap_s``, ``wrap_t``, ``filter``,
            e.g. a ``TextureRef`` whose ``image`` indexes ``images``) per texture; texture ``k`` of the kernels is
            ``textures[k]``. None: one repeat/linear texture per image.
        device: a Warp device (None: the default one).

    Attributes:
        atlas: the struct the kernels take.
        num_textures, num_levels (per texture), sizes (per texture, level 0 (width, height)), nbytes (texel bytes).
    """

    def __init__(self, images: Sequence, textures: Optional[Sequence] = None, *, device=None):
        if isinstance(images, np.ndarray) or not isinstance(images, (list, tuple)):
            raise ValueError(f"images must be a list or tuple of arrays, got {show(images)}")
        rgba = [_check_image(i, im) for i, im in enumerate(images)]
        if textures is None:
            textures = [TextureSampler(i) for i in range(len(rgba))]
        samplers = []
        for k, t in enumerate(textures):
            try:
                s = t if isinstance(t, TextureSampler) else TextureSampler(t.image, t.wrap_s, t.wrap_t, t.filter)
            except AttributeError:
                raise ValueError(f"textures[{k}] must be a TextureSampler (image, wrap_s, wrap_t, filter), got "
                                 f"{show(t)}") from None
            if s.image >= len(rgba):
                raise ValueError(f"textures[{k}].image must be in [0, {len(rgba) - 1}] (there are {len(rgba)} "
                                 f"images), got {s.image}")
            samplers.append(s)
        self.device = wp.get_device(device)
        self.samplers = tuple(samplers)

        # the levels of each image used by a texture, once per image
        used = sorted({s.image for s in samplers})
        chunks, offsets, widths, heights = [], [], [], []
        first_level_of_image = {}
        levels_of_image = {}
        total = 0
        for i in used:
            first_level_of_image[i] = len(offsets)
            chain = build_mip_chain(rgba[i])
            levels_of_image[i] = len(chain)
            for lev in chain:
                offsets.append(total)
                heights.append(lev.shape[0])
                widths.append(lev.shape[1])
                chunks.append(lev.reshape(-1, 4))
                total += lev.shape[0] * lev.shape[1]
            if total > MAX_ATLAS_TEXELS:
                raise ValueError(f"the textures' mip levels must hold at most {MAX_ATLAS_TEXELS} texels in all "
                                 f"(the atlas is indexed with int32), got {total} by images[{i}]")
        if not chunks:  # no texture: one white texel keeps every array non-empty
            chunks = [np.ones((1, 4), dtype=np.float32)]
            offsets, widths, heights = [0], [1], [1]
        texels = np.concatenate(chunks, axis=0)
        i32 = np.int32
        first = np.array([first_level_of_image[s.image] for s in samplers] or [0], dtype=i32)
        nlev = np.array([levels_of_image[s.image] for s in samplers] or [1], dtype=i32)
        wrap_s = np.array([_WRAP_CODE[s.wrap_s] for s in samplers] or [0], dtype=i32)
        wrap_t = np.array([_WRAP_CODE[s.wrap_t] for s in samplers] or [0], dtype=i32)
        filt = np.array([_FILTER_CODE[s.filter] for s in samplers] or [0], dtype=i32)

        d = self.device
        a = tk.TextureAtlas()
        a.texels = wp.array(texels, dtype=wp.vec4, device=d)
        a.levels = wp.array(np.stack([offsets, widths, heights], axis=1).astype(i32), dtype=wp.vec3i, device=d)
        a.textures = wp.array(np.stack([first, nlev, wrap_s, wrap_t], axis=1).astype(i32), dtype=wp.vec4i, device=d)
        a.filters = wp.array(filt, dtype=wp.int32, device=d)
        a.num_textures = len(samplers)
        self.atlas = a
        self.num_textures = len(samplers)
        self.num_levels = tuple(int(n) for n in nlev[: len(samplers)])
        self.sizes = tuple((int(rgba[s.image].shape[1]), int(rgba[s.image].shape[0])) for s in samplers)
        self.nbytes = int(texels.nbytes)
        self._texels = texels
        self._offsets = offsets
        self._widths = widths
        self._heights = heights
        self._first = first

    @classmethod
    def from_materials(cls, table, images: Sequence, *, device=None) -> "TextureSet":
        """The textures of a ``foveawarp.materials.MaterialTable``: texture ``k`` is ``table.textures[k]`` (so
        ``table.texture[m, slot]`` indexes the atlas directly). ``images`` are the scene's
        ``foveawarp.materials.ImageSource`` s; each (image, colour space) pair is decoded once with
        ``foveawarp.io.images.load_image``."""
        from .io.images import load_image

        decoded = []
        key_index = {}
        samplers = []
        for k, t in enumerate(table.textures):
            if not 0 <= t.image < len(images):
                raise ValueError(f"table.textures[{k}].image must be in [0, {len(images) - 1}] (there are "
                                 f"{len(images)} images), got {t.image}")
            key = (t.image, bool(t.srgb))
            if key not in key_index:
                src = images[t.image]
                key_index[key] = len(decoded)
                decoded.append(load_image(src.source, srgb=t.srgb, name=src.name, mime_type=src.mime_type))
            samplers.append(TextureSampler(key_index[key], t.wrap_s, t.wrap_t, t.filter))
        return cls(decoded, samplers, device=device)

    def level(self, texture: int, level: int) -> np.ndarray:
        """A host copy of level ``level`` of texture ``texture``, ``(h, w, 4)`` float32 (from the packed atlas)."""
        t = check_int_range("texture", texture, 0, self.num_textures - 1)
        lv = check_int_range("level", level, 0, self.num_levels[t] - 1)
        g = int(self._first[t]) + lv
        o, w, h = self._offsets[g], self._widths[g], self._heights[g]
        return self._texels[o:o + w * h].reshape(h, w, 4).copy()

    def sample(self, texture, uv, lod=None, *, filter: Optional[str] = None) -> np.ndarray:
        """Sample on the device: ``(N, 4)`` float32 of texture(s) ``texture`` (an int or ``(N,)`` ints, -1 = no
        texture = white) at ``uv`` ``(N, 2)``.

        ``lod=None``: level 0 ("none" mode); a number or ``(N,)`` array: that LOD (the "ray_cone" mode's
        trilinear lookup), clamped to the texture's levels. ``filter``: None (each texture's own filter) or one
        of :data:`SAMPLE_FILTERS` (nearest / bilinear at the level nearest the LOD, trilinear).
        """
        if filter is not None:
            check_choice("filter", filter, SAMPLE_FILTERS)
        uv = np.asarray(uv, dtype=np.float32)
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise ValueError(f"uv must be an (N, 2) array, got shape {uv.shape}")
        n = uv.shape[0]
        tex = np.broadcast_to(np.asarray(texture, dtype=np.int64), (n,))
        if tex.size and (tex.min() < -1 or tex.max() >= self.num_textures):
            raise ValueError(f"texture must be in [-1, {self.num_textures - 1}], got "
                             f"{show(tex[(tex < -1) | (tex >= self.num_textures)][0])}")
        lod_mode = 0 if lod is None else 1
        lods = np.broadcast_to(np.asarray(0.0 if lod is None else lod, dtype=np.float32), (n,))
        if n == 0:
            return np.zeros((0, 4), dtype=np.float32)
        d = self.device
        out = wp.empty(n, dtype=wp.vec4, device=d)
        wp.launch(tk.sample_atlas_kernel, dim=n, device=d,
                  inputs=[self.atlas, wp.array(tex.astype(np.int32), dtype=wp.int32, device=d),
                          wp.array(uv, dtype=wp.vec2, device=d),
                          wp.array(np.ascontiguousarray(lods), dtype=float, device=d), lod_mode,
                          _SAMPLER_CODE[filter], out])
        return out.numpy()
