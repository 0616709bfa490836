"""Texture sampling from a software atlas, and the ray-cone level of detail.

The atlas (:class:`TextureAtlas`, built by ``foveawarp.textures.TextureSet``) holds every mip level of every image
of a scene in one flat ``wp.array(dtype=wp.vec4)`` of linear RGBA texels, with a table of the levels (first texel,
width, height) and one of the textures (first level, level count, wrap S/T, filter). Every lookup is done here in
software, so the CPU and CUDA devices return the same values.

Conventions:
- UV as in glTF: (0, 0) is the image's top-left corner, u grows to the right, v downwards; texel ``(i, j)`` of a
  ``w x h`` level (column i, row j from the top) covers ``[i/w, (i+1)/w) x [j/h, (j+1)/h)`` and its centre is at
  ``((i + 0.5) / w, (j + 0.5) / h)``. Nearest picks the texel that covers the UV; bilinear weights the four texels
  around it by their centres.
- Wrap per axis (codes in the order of ``foveawarp.materials.WRAP_MODES``): :data:`WRAP_REPEAT` (glTF 10497),
  :data:`WRAP_CLAMP` (CLAMP_TO_EDGE, 33071), :data:`WRAP_MIRROR` (MIRRORED_REPEAT, 33648: period 2, the odd
  copies flipped). They apply to texel indices, so a bilinear tap beyond the edge reads the wrapped texel.
- Filter per texture (codes in the order of ``foveawarp.materials.FILTERS``): :data:`FILTER_LINEAR` = bilinear
  within a level and linear between the two levels around the LOD (trilinear); :data:`FILTER_NEAREST` = the
  nearest texel of the level nearest the LOD.
- LOD modes (``ShadingConfig.texture_lod``): :data:`LOD_NONE` ("none": level 0, the texture's filter) and
  :data:`LOD_RAY_CONE` ("ray_cone": the LOD from a ray cone, clamped to ``[0, levels - 1]``).

Ray cones (Akenine-Moller et al., "Texture Level of Detail Strategies for Real-Time Ray Tracing", Ray Tracing
Gems, 2019, section on ray cones; the isotropic form, not the anisotropic one of Akenine-Moller et al. 2021,
"Improved Shader and Texture Level of Detail Using Ray Cones", JCGT 10(1)):

    Delta  = 0.5 * log2(t_a / p_a),  t_a = w h |(t1 - t0) x (t2 - t0)|,  p_a = |(p1 - p0) x (p2 - p0)|
    lambda = Delta + log2(W / |n . d|),  W = 2 t tan(alpha / 2)

with ``t_i`` the vertices' UVs, ``p_i`` their positions, ``w x h`` the texture's level-0 size, ``t`` the hit
distance and ``alpha`` the cone's spread angle. The exact width ``2 t tan(alpha / 2)`` is used where the chapter
writes its small-angle form ``alpha t``. A primary ray's spread is the angle of one pixel,
``alpha = atan(2 tan(fov_y / 2) / H)``; a sparse foveated sample standing for ``s`` pixels widens it to
``s * alpha`` (:func:`footprint_spread_angle`). ``Delta`` splits into a part of the triangle alone
(:func:`triangle_uv_lod_delta`, ``w = h = 1``) and ``0.5 log2(w h)`` of the texture, so one hit serves every
texture slot. Guards: areas below :data:`AREA_MIN`, widths below :data:`WIDTH_MIN` and ``|n . d|`` below
:data:`COS_MIN` are raised to them, NaN terms count as 0, and the LOD is clamped, so no input gives NaN or Inf.
"""

import warp as wp

__all__ = [
    "WRAP_REPEAT",
    "WRAP_CLAMP",
    "WRAP_MIRROR",
    "FILTER_LINEAR",
    "FILTER_NEAREST",
    "LOD_NONE",
    "LOD_RAY_CONE",
    "SAMPLER_TEXTURE",
    "SAMPLER_NEAREST",
    "SAMPLER_BILINEAR",
    "SAMPLER_TRILINEAR",
    "AREA_MIN",
    "WIDTH_MIN",
    "COS_MIN",
    "SPREAD_ANGLE_MAX",
    "TextureAtlas",
    "wrap_texel",
    "texture_num_levels",
    "texture_size",
    "sample_nearest",
    "sample_bilinear",
    "sample_trilinear",
    "sample_texture_at_lod",
    "sample_texture",
    "triangle_uv_lod_delta",
    "triangle_lod_delta",
    "pixel_spread_angle",
    "footprint_spread_angle",
    "cone_width",
    "cone_footprint_log2",
    "ray_cone_lod",
    "texture_ray_cone_lod",
    "sample_atlas_kernel",
    "ray_cone_lod_kernel",
]

WRAP_REPEAT = wp.constant(0)
WRAP_CLAMP = wp.constant(1)
WRAP_MIRROR = wp.constant(2)
FILTER_LINEAR = wp.constant(0)
FILTER_NEAREST = wp.constant(1)
LOD_NONE = wp.constant(0)
LOD_RAY_CONE = wp.constant(1)
# filter overrides of sample_atlas_kernel: the texture's own filter, or a fixed one
SAMPLER_TEXTURE = wp.constant(-1)
SAMPLER_NEAREST = wp.constant(0)
SAMPLER_BILINEAR = wp.constant(1)
SAMPLER_TRILINEAR = wp.constant(2)
# floors of the ray-cone terms: log2 of each stays within [-100, 128], so lambda is finite before its clamp
AREA_MIN = wp.constant(1.0e-30)
WIDTH_MIN = wp.constant(1.0e-30)
COS_MIN = wp.constant(1.0e-6)
# largest cone spread angle in radians: below pi, so tan(alpha / 2) stays finite
SPREAD_ANGLE_MAX = wp.constant(3.0)


@wp.struct
class TextureAtlas:
    """All mip levels of all textures of a scene in one array, with their tables.

    A lookup reads one row of each table, not six scalar tables (the room's textured G-buffer kernel at
    1920x1080 on the H200: 0.55 to 0.52 ms).

    Attributes:
        texels: linear RGBA texels, level after level, each level row-major with row 0 at the image's top.
        levels: per level (of all textures), (index of its first texel in ``texels``, width, height), sizes >= 1.
        textures: per texture, (index of its level 0 in ``levels``, number of levels >= 1, wrap mode along u,
            wrap mode along v) with the wrap modes ``WRAP_*``; level k is ``max(1, w >> k) x max(1, h >> k)``.
        filters: per texture, ``FILTER_LINEAR`` or ``FILTER_NEAREST``.
        num_textures: the number of textures (rows of ``textures``).
    """

    texels: wp.array(dtype=wp.vec4)
    levels: wp.array(dtype=wp.vec3i)
    textures: wp.array(dtype=wp.vec4i)
    filters: wp.array(dtype=wp.int32)
    num_textures: int


@wp.func
def wrap_texel(i: int, n: int, mode: int) -> int:
    """Texel index ``i`` (any integer) of an axis of ``n`` texels wrapped into ``[0, n - 1]``."""
    if mode == WRAP_CLAMP:
        return wp.clamp(i, 0, n - 1)
    if mode == WRAP_MIRROR:
        p = 2 * n
        m = ((i % p) + p) % p
        if m >= n:
            m = p - 1 - m
        return m
    return ((i % n) + n) % n


@wp.func
def _reduce_coord(u: float, mode: int) -> float:
    """``u`` moved into one period of its wrap mode (the sample does not change), so that texel indices stay
    small integers; NaN and Inf count as 0."""
    if not wp.isfinite(u):
        return 0.0
    if mode == WRAP_CLAMP:
        return wp.clamp(u, -1.0, 2.0)
    if mode == WRAP_MIRROR:
        return u - 2.0 * wp.floor(0.5 * u)
    return u - wp.floor(u)


@wp.func
def texture_num_levels(atlas: TextureAtlas, tex: int) -> int:
    """Number of mip levels of texture ``tex``."""
    return atlas.textures[tex][1]


@wp.func
def texture_size(atlas: TextureAtlas, tex: int, level: int) -> wp.vec2i:
    """(width, height) of level ``level`` of texture ``tex``."""
    lv = atlas.levels[atlas.textures[tex][0] + level]
    return wp.vec2i(lv[1], lv[2])


@wp.func
def sample_nearest(atlas: TextureAtlas, tex: int, level: int, uv: wp.vec2) -> wp.vec4:
    """The texel of level ``level`` (in ``[0, levels - 1]``) of texture ``tex`` that covers ``uv``."""
    return _nearest(atlas, atlas.textures[tex], level, uv)


@wp.func
def _nearest(atlas: TextureAtlas, td: wp.vec4i, level: int, uv: wp.vec2) -> wp.vec4:
    """:func:`sample_nearest` of the texture whose ``textures`` row is ``td``."""
    lv = atlas.levels[td[0] + level]
    w = lv[1]
    h = lv[2]
    x = _reduce_coord(uv[0], td[2]) * float(w)
    y = _reduce_coord(uv[1], td[3]) * float(h)
    ix = wrap_texel(int(wp.floor(x)), w, td[2])
    iy = wrap_texel(int(wp.floor(y)), h, td[3])
    return atlas.texels[lv[0] + iy * w + ix]


@wp.func
def sample_bilinear(atlas: TextureAtlas, tex: int, level: int, uv: wp.vec2) -> wp.vec4:
    """Bilinear interpolation of level ``level`` of texture ``tex`` at ``uv`` between the four texel centres
    around it."""
    return _bilinear(atlas, atlas.textures[tex], level, uv)


@wp.func
def _bilinear(atlas: TextureAtlas, td: wp.vec4i, level: int, uv: wp.vec2) -> wp.vec4:
    """:func:`sample_bilinear` of the texture whose ``textures`` row is ``td``."""
    lv = atlas.levels[td[0] + level]
    w = lv[1]
    h = lv[2]
    ws = td[2]
    wt = td[3]
    x = _reduce_coord(uv[0], ws) * float(w) - 0.5
    y = _reduce_coord(uv[1], wt) * float(h) - 0.5
    fx = wp.floor(x)
    fy = wp.floor(y)
    ax = x - fx
    ay = y - fy
    x0 = int(fx)
    y0 = int(fy)
    i0 = wrap_texel(x0, w, ws)
    i1 = wrap_texel(x0 + 1, w, ws)
    base = lv[0]
    r0 = base + wrap_texel(y0, h, wt) * w
    r1 = base + wrap_texel(y0 + 1, h, wt) * w
    top = (1.0 - ax) * atlas.texels[r0 + i0] + ax * atlas.texels[r0 + i1]
    bottom = (1.0 - ax) * atlas.texels[r1 + i0] + ax * atlas.texels[r1 + i1]
    return (1.0 - ay) * top + ay * bottom


@wp.func
def _clamp_lod(lod: float, num_levels: int) -> float:
    if not (lod >= 0.0):  # negative or NaN
        return 0.0
    return wp.min(lod, float(num_levels - 1))


@wp.func
def sample_trilinear(atlas: TextureAtlas, tex: int, uv: wp.vec2, lod: float) -> wp.vec4:
    """Bilinear in the two levels around ``lod`` (clamped to ``[0, levels - 1]``), linear between them."""
    return _trilinear(atlas, atlas.textures[tex], uv, lod)


@wp.func
def _trilinear(atlas: TextureAtlas, td: wp.vec4i, uv: wp.vec2, lod: float) -> wp.vec4:
    """:func:`sample_trilinear` of the texture whose ``textures`` row is ``td``."""
    n = td[1]
    lam = _clamp_lod(lod, n)
    l0 = int(wp.floor(lam))
    t = lam - float(l0)
    c0 = _bilinear(atlas, td, l0, uv)
    if t <= 0.0 or l0 + 1 >= n:
        return c0
    c1 = _bilinear(atlas, td, l0 + 1, uv)
    return (1.0 - t) * c0 + t * c1


@wp.func
def sample_texture_at_lod(atlas: TextureAtlas, tex: int, uv: wp.vec2, lod_mode: int, lod: float) -> wp.vec4:
    """Texture ``tex`` at ``uv`` with its own filter; white (1, 1, 1, 1) for ``tex`` outside
    ``[0, num_textures - 1]`` (no texture in that slot).

    ``lod_mode == LOD_NONE``: level 0 (bilinear, or nearest for a nearest texture), ``lod`` ignored.
    ``LOD_RAY_CONE``: trilinear at ``lod`` (nearest: the nearest texel of the level nearest ``lod``).
    """
    if tex < 0 or tex >= atlas.num_textures:
        return wp.vec4(1.0, 1.0, 1.0, 1.0)
    return _at_lod(atlas, tex, atlas.textures[tex], uv, lod_mode, lod)


@wp.func
def _at_lod(atlas: TextureAtlas, tex: int, td: wp.vec4i, uv: wp.vec2, lod_mode: int, lod: float) -> wp.vec4:
    """:func:`sample_texture_at_lod` of texture ``tex`` (in range) whose ``textures`` row is ``td``."""
    lam = float(0.0)
    if lod_mode == LOD_RAY_CONE:
        lam = _clamp_lod(lod, td[1])
    if atlas.filters[tex] == FILTER_NEAREST:
        return _nearest(atlas, td, int(wp.floor(lam + 0.5)), uv)
    if lam <= 0.0:
        return _bilinear(atlas, td, 0, uv)
    return _trilinear(atlas, td, uv, lam)


# ---------------------------------------------------------------------------------------------------------------
# ray cones


@wp.func
def triangle_uv_lod_delta(p0: wp.vec3, p1: wp.vec3, p2: wp.vec3, t0: wp.vec2, t1: wp.vec2, t2: wp.vec2) -> float:
    """``0.5 * log2(t_a / p_a)`` of a triangle for a 1 x 1 texture: ``t_a = |(t1 - t0) x (t2 - t0)|`` (UV),
    ``p_a = |(p1 - p0) x (p2 - p0)|`` (world). Areas are raised to :data:`AREA_MIN`; NaN gives 0."""
    e1 = t1 - t0
    e2 = t2 - t0
    t_a = wp.abs(e1[0] * e2[1] - e1[1] * e2[0])
    p_a = wp.length(wp.cross(p1 - p0, p2 - p0))
    d = 0.5 * (wp.log2(wp.max(t_a, AREA_MIN)) - wp.log2(wp.max(p_a, AREA_MIN)))
    if not wp.isfinite(d):  # NaN (or Inf) vertices
        return 0.0
    return d


@wp.func
def triangle_lod_delta(p0: wp.vec3, p1: wp.vec3, p2: wp.vec3, t0: wp.vec2, t1: wp.vec2, t2: wp.vec2,
                       width: int, height: int) -> float:
    """``Delta = 0.5 * log2(t_a / p_a)`` with ``t_a = w h |(t1 - t0) x (t2 - t0)|`` for a ``width x height``
    texture."""
    wh = float(wp.max(width, 1)) * float(wp.max(height, 1))
    return triangle_uv_lod_delta(p0, p1, p2, t0, t1, t2) + 0.5 * wp.log2(wh)


@wp.func
def pixel_spread_angle(fov_y_rad: float, height_px: int) -> float:
    """A primary ray's cone spread angle: the angle of one pixel, ``atan(2 tan(fov_y / 2) / H)``."""
    f = wp.clamp(fov_y_rad, 0.0, 3.14159)
    return wp.atan(2.0 * wp.tan(0.5 * f) / float(wp.max(height_px, 1)))


@wp.func
def footprint_spread_angle(pixel_angle: float, footprint_px: float) -> float:
    """The spread angle of a ray standing for ``footprint_px`` pixels (a sparse sample's spacing):
    ``footprint_px * pixel_angle``, in ``[0, SPREAD_ANGLE_MAX]``."""
    a = pixel_angle * footprint_px
    if not (a >= 0.0):
        return 0.0
    return wp.min(a, SPREAD_ANGLE_MAX)


@wp.func
def cone_width(t: float, spread_angle: float) -> float:
    """Width of a cone of spread angle ``spread_angle`` (radians) at distance ``t`` from its apex:
    ``2 t tan(alpha / 2)``; 0 for negative or NaN inputs."""
    a = spread_angle
    if not (a >= 0.0):
        a = 0.0
    d = t
    if not (d >= 0.0):
        d = 0.0
    return 2.0 * d * wp.tan(0.5 * wp.min(a, SPREAD_ANGLE_MAX))


@wp.func
def cone_footprint_log2(width: float, normal: wp.vec3, direction: wp.vec3) -> float:
    """``log2(W / |n . d|)`` with ``n``, ``d`` normalized here; ``W`` raised to :data:`WIDTH_MIN` and ``|n . d|``
    to :data:`COS_MIN`; a zero-length normal or direction counts as ``|n . d| = 1``."""
    ln = wp.length(normal) * wp.length(direction)
    c = float(1.0)
    if ln > 0.0 and wp.isfinite(ln):
        c = wp.abs(wp.dot(normal, direction)) / ln
    if not (c >= COS_MIN):  # grazing or NaN
        c = COS_MIN
    w = width
    if not (w >= WIDTH_MIN):
        w = WIDTH_MIN
    r = wp.log2(w) - wp.log2(wp.min(c, 1.0))
    if not wp.isfinite(r):  # an infinite width
        return 128.0
    return r


@wp.func
def ray_cone_lod(delta: float, footprint_log2: float, num_levels: int) -> float:
    """``lambda = Delta + log2(W / |n . d|)`` clamped to ``[0, num_levels - 1]`` (NaN gives 0)."""
    return _clamp_lod(delta + footprint_log2, wp.max(num_levels, 1))


@wp.func
def texture_ray_cone_lod(atlas: TextureAtlas, tex: int, uv_lod_delta: float, footprint_log2: float) -> float:
    """The ray-cone LOD of texture ``tex``: :func:`triangle_uv_lod_delta` of the hit triangle plus
    ``0.5 log2(w h)`` of the texture's level 0 plus :func:`cone_footprint_log2`, clamped to its levels."""
    return _cone_lod(atlas, atlas.textures[tex], uv_lod_delta, footprint_log2)


@wp.func
def _cone_lod(atlas: TextureAtlas, td: wp.vec4i, uv_lod_delta: float, footprint_log2: float) -> float:
    """:func:`texture_ray_cone_lod` of the texture whose ``textures`` row is ``td``."""
    lv = atlas.levels[td[0]]
    wh = float(lv[1]) * float(lv[2])
    return ray_cone_lod(uv_lod_delta + 0.5 * wp.log2(wh), footprint_log2, td[1])


@wp.func
def sample_texture(atlas: TextureAtlas, tex: int, uv: wp.vec2, lod_mode: int, uv_lod_delta: float,
                   footprint_log2: float) -> wp.vec4:
    """Texture ``tex`` at ``uv`` with the LOD of a hit: ``LOD_NONE`` (level 0) or ``LOD_RAY_CONE`` (the LOD of
    :func:`texture_ray_cone_lod`). White for a slot without texture (``tex < 0``)."""
    if tex < 0 or tex >= atlas.num_textures:
        return wp.vec4(1.0, 1.0, 1.0, 1.0)
    td = atlas.textures[tex]
    lod = float(0.0)
    if lod_mode == LOD_RAY_CONE:
        lod = _cone_lod(atlas, td, uv_lod_delta, footprint_log2)
    return _at_lod(atlas, tex, td, uv, lod_mode, lod)


# ---------------------------------------------------------------------------------------------------------------
# kernels for host-side lookups (foveawarp.textures.TextureSet.sample / ray_cone_lod) and tests


@wp.kernel(enable_backward=False)
def sample_atlas_kernel(atlas: TextureAtlas, tex: wp.array(dtype=wp.int32), uv: wp.array(dtype=wp.vec2),
                        lod: wp.array(dtype=float), lod_mode: int, sampler: int, out: wp.array(dtype=wp.vec4)):
    """``out[i]`` = texture ``tex[i]`` at ``uv[i]`` and ``lod[i]``. ``sampler``: ``SAMPLER_TEXTURE`` (the
    texture's filter through :func:`sample_texture_at_lod` with ``lod_mode``), or a fixed filter:
    ``SAMPLER_NEAREST`` / ``SAMPLER_BILINEAR`` at the level nearest the LOD, ``SAMPLER_TRILINEAR``."""
    i = wp.tid()
    t = tex[i]
    if sampler == SAMPLER_TEXTURE or t < 0 or t >= atlas.num_textures:
        out[i] = sample_texture_at_lod(atlas, t, uv[i], lod_mode, lod[i])
        return
    lam = float(0.0)
    if lod_mode == LOD_RAY_CONE:
        lam = _clamp_lod(lod[i], atlas.textures[t][1])
    if sampler == SAMPLER_TRILINEAR:
        out[i] = sample_trilinear(atlas, t, uv[i], lam)
    elif sampler == SAMPLER_NEAREST:
        out[i] = sample_nearest(atlas, t, int(wp.floor(lam + 0.5)), uv[i])
    else:
        out[i] = sample_bilinear(atlas, t, int(wp.floor(lam + 0.5)), uv[i])


@wp.kernel(enable_backward=False)
def ray_cone_lod_kernel(p: wp.array2d(dtype=wp.vec3), t: wp.array2d(dtype=wp.vec2), width: wp.array(dtype=int),
                        height: wp.array(dtype=int), hit_t: wp.array(dtype=float),
                        spread_angle: wp.array(dtype=float), normal: wp.array(dtype=wp.vec3),
                        direction: wp.array(dtype=wp.vec3), num_levels: wp.array(dtype=int),
                        delta_out: wp.array(dtype=float), lod_out: wp.array(dtype=float)):
    """Per row ``i``: the triangle ``p[i, 0..2]`` with UVs ``t[i, 0..2]``, a ``width[i] x height[i]`` texture and
    a cone of spread ``spread_angle[i]`` hitting at distance ``hit_t[i]`` along ``direction[i]`` on a surface of
    normal ``normal[i]`` -> ``Delta`` and the clamped LOD."""
    i = wp.tid()
    d = triangle_lod_delta(p[i, 0], p[i, 1], p[i, 2], t[i, 0], t[i, 1], t[i, 2], width[i], height[i])
    fp = cone_footprint_log2(cone_width(hit_t[i], spread_angle[i]), normal[i], direction[i])
    delta_out[i] = d
    lod_out[i] = ray_cone_lod(d, fp, num_levels[i])
