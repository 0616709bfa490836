"""Shading of textured scenes' G-buffer points in the glTF metallic-roughness model (kernels/bsdf.py).

Separate kernels from kernels/shade.py, so that untextured scenes keep theirs. The G-buffer of a textured scene
holds each hit's base colour, shading normal, packed (roughness, metallic, occlusion, specular) and emission
(kernels/gbuffer_textured.py). At a hit p with shading normal n, towards the viewer wo:

- point and spot lights: ``f(wo, wi) I att cos_i / r^2`` with a shadow ray; directional lights (``LightParams``
  kind 2: ``direction`` the way the light travels, ``intensity`` the irradiance facing it): ``f E cos_i``;
- area lights: ``area_light_samples`` uniform points per light, ``f L cos_i cos_l A / (N r^2)``;
- the environment: ``env_samples`` directions drawn from its luminance distribution (kernels/envmap.py),
  ``f L cos_i w / (N pdf)`` with a shadow ray to ``far``; with ``env_mis`` each also draws one direction from the
  BSDF (kernels/bsdf.py ``bsdf_sample``), ``f L cos_i w / (N pdf_bsdf)`` where its shadow ray escapes, the two
  weighted by the power heuristic (kernels/mis.py), as Mitsuba 3's ``direct`` integrator does; without it
  ``w = 1`` and only the map is sampled (a glossy lobe narrower than the map's bright cells is then noisy);
- ambient: ``base_colour x ambient x occlusion`` (the occlusion map), times the AO rays' unoccluded fraction with
  ``ao_samples``; then the emission.

``f`` is :func:`kernels.bsdf.bsdf_eval` in the shading frame: GGX with height-correlated Smith masking, Schlick
Fresnel, and the Lambert lobe weighted by ``(1 - metallic) (1 - Fd)``. Shadow and AO rays pass cut-out texels
(kernels/surface.py: ``surface_visible``). A shading normal turned away from the viewer (a normal map or smooth
normals at a silhouette) is evaluated with ``wo`` raised to just above its horizon. A primary miss is the
environment seen along the ray (the G-buffer's ``emission`` of a miss) or, without one, the background.
The stochastic part (area lights, environment, AO) goes to ``out_stoch`` as in kernels/shade.py.
"""

import warp as wp

from .bsdf import bsdf_eval, bsdf_pdf, bsdf_sample, frame_from_normal, make_material, to_local, to_world
from .envmap import EnvironmentMap, env_eval, env_pdf, env_sample
from .mis import nee_weight
from .rng import cosine_hemisphere, pixel_rng
from .shade import AreaLightParams, LightParams, ShadeParams, list_pixel, spot_factor
from .surface import SurfaceData, surface_visible
from .tonemap import tonemap_rgb

# LightParams.kind of a directional light (0 point, 1 spot: kernels/shade.py)
LIGHT_DIRECTIONAL = wp.constant(2)
# the smallest wo.z the BSDF is evaluated with when the shading normal faces away from the viewer
WO_Z_MIN = wp.constant(1.0e-4)


@wp.struct
class TexturedShadeParams:
    """The textured shading's per-scene constants: the surfaces (for cut-outs in shadow rays), the environment
    (``has_env`` 0: none), its samples per pixel, whether each also draws a BSDF direction (``env_mis`` 1) and
    the shadow rays' length towards it and directional lights."""

    sd: SurfaceData
    env: EnvironmentMap
    has_env: int
    env_samples: int
    env_mis: int
    far: float


@wp.func
def unpack_material(albedo: wp.vec3, m: wp.vec4h):
    """(``SurfaceMaterial``, occlusion) of a G-buffer entry's base colour and packed material."""
    return make_material(albedo, float(m[1]), float(m[0]), float(m[3])), float(m[2])


@wp.func
def raised_wo(wo: wp.vec3) -> wp.vec3:
    """The unit local direction to the viewer ``wo``, raised to ``z >= WO_Z_MIN`` (its slope capped) where the
    shading normal faces away from the viewer; unchanged above."""
    if wo[2] < WO_Z_MIN:
        return wp.normalize(wp.vec3(wo[0], wo[1], WO_Z_MIN * wp.sqrt(wo[0] * wo[0] + wo[1] * wo[1]) + 1.0e-12))
    return wo


@wp.func
def shade_textured_parts(sp: ShadeParams, tp: TexturedShadeParams, pixel: int, p: wp.vec3, n: wp.vec3,
                         albedo: wp.vec3, mat: wp.vec4h, lights: wp.array(dtype=LightParams),
                         area_lights: wp.array(dtype=AreaLightParams)):
    """(deterministic light part, stochastic light part, the pixel's random stream after the draws) at p."""
    m, occ = unpack_material(albedo, mat)
    fr = frame_from_normal(n)
    wo = raised_wo(to_local(fr, wp.normalize(sp.eye - p)))
    col = wp.vec3(0.0, 0.0, 0.0)
    for li in range(sp.num_lights):
        l = lights[li]
        wi = wp.vec3(0.0, 0.0, 0.0)
        dist = float(0.0)
        e = wp.vec3(0.0, 0.0, 0.0)
        if l.kind == LIGHT_DIRECTIONAL:
            wi = -l.direction
            dist = tp.far
            e = l.intensity
        else:
            dl = l.position - p
            dist2 = wp.dot(dl, dl)
            if dist2 > 1.0e-30:
                dist = wp.sqrt(dist2)
                wi = dl / dist
                e = l.intensity * (spot_factor(l, -wi) / dist2)
        cos_i = wp.dot(n, wi)
        if dist > 0.0 and cos_i > 0.0 and wp.max(e) > 0.0:
            vis = 1.0
            if sp.shadows != 0:
                vis = surface_visible(sp.mesh, tp.sd, p, n, sp.ray_eps, wi, dist)
            if vis > 0.0:
                col += wp.cw_mul(e * cos_i, bsdf_eval(m, wo, to_local(fr, wi)))
    rng = pixel_rng(sp.seed, sp.frame, pixel)
    stoch = wp.vec3(0.0, 0.0, 0.0)
    for ai in range(sp.num_area_lights):
        a = area_lights[ai]
        an = wp.cross(a.edge_u, a.edge_v)
        area = wp.length(an)
        if area > 1.0e-30:
            an = an / area
            acc = wp.vec3(0.0, 0.0, 0.0)
            for s in range(sp.area_samples):
                q = a.corner + a.edge_u * wp.randf(rng) + a.edge_v * wp.randf(rng)
                dl = q - p
                dist2 = wp.dot(dl, dl)
                if dist2 > 1.0e-30:
                    dist = wp.sqrt(dist2)
                    wi = dl / dist
                    cos_i = wp.dot(n, wi)
                    cos_l = -wp.dot(an, wi)
                    if cos_i > 0.0 and cos_l > 0.0:
                        vis = 1.0
                        if sp.shadows != 0:
                            vis = surface_visible(sp.mesh, tp.sd, p, n, sp.ray_eps, wi, dist)
                        if vis > 0.0:
                            acc += wp.cw_mul(a.radiance * (cos_i * cos_l / dist2), bsdf_eval(m, wo, to_local(fr, wi)))
            stoch += acc * (area / float(sp.area_samples))
    if tp.has_env != 0 and tp.env_samples > 0:
        acc = wp.vec3(0.0, 0.0, 0.0)
        for s in range(tp.env_samples):
            # a direction from the map's luminance distribution
            u1 = wp.randf(rng)
            u2 = wp.randf(rng)
            wi, radiance, pdf = env_sample(tp.env, u1, u2)
            cos_i = wp.dot(n, wi)
            if cos_i > 0.0 and pdf > 0.0:
                wil = to_local(fr, wi)
                f = bsdf_eval(m, wo, wil)
                if wp.max(f) > 0.0:
                    vis = 1.0
                    if sp.shadows != 0:
                        vis = surface_visible(sp.mesh, tp.sd, p, n, sp.ray_eps, wi, tp.far)
                    if vis > 0.0:
                        pb = float(0.0)
                        if tp.env_mis != 0:
                            pb = bsdf_pdf(m, wo, wil)
                        acc += nee_weight(f, cos_i, radiance, pdf, pb)
            if tp.env_mis != 0:
                # a direction from the BSDF, seeing the map where it leaves the scene
                bs = bsdf_sample(m, wo, wp.randf(rng), wp.randf(rng), wp.randf(rng))
                if bs.pdf > 0.0 and bs.wi[2] > 0.0:
                    wb = to_world(fr, bs.wi)
                    vis = 1.0
                    if sp.shadows != 0:
                        vis = surface_visible(sp.mesh, tp.sd, p, n, sp.ray_eps, wb, tp.far)
                    if vis > 0.0:
                        acc += nee_weight(bs.f, bs.wi[2], env_eval(tp.env, wb), bs.pdf, env_pdf(tp.env, wb))
        stoch += acc / float(tp.env_samples)
    return col, stoch, rng


@wp.func
def shade_textured_point(sp: ShadeParams, tp: TexturedShadeParams, pixel: int, p: wp.vec3, n: wp.vec3,
                         albedo: wp.vec3, mat: wp.vec4h, emission: wp.vec3, lights: wp.array(dtype=LightParams),
                         area_lights: wp.array(dtype=AreaLightParams)):
    """(radiance, stochastic part) at p: the light sources, the ambient term (occlusion map; AO rays with
    ``sp.ao_samples``) and the emission."""
    col, stoch, rng = shade_textured_parts(sp, tp, pixel, p, n, albedo, mat, lights, area_lights)
    amb = albedo * float(mat[2])
    amb = wp.cw_mul(amb, sp.ambient)
    if sp.ao_samples > 0:
        unocc = float(0.0)
        for s in range(sp.ao_samples):
            d = cosine_hemisphere(n, wp.randf(rng), wp.randf(rng))
            unocc += surface_visible(sp.mesh, tp.sd, p, n, sp.ray_eps, d, sp.ao_radius)
        stoch += amb * (unocc / float(sp.ao_samples))
    else:
        col += amb
    return col + stoch + emission, stoch


@wp.func
def shade_textured_pixel(
    sp: ShadeParams,
    tp: TexturedShadeParams,
    x: int,
    y: int,
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    albedo: wp.array2d(dtype=wp.vec3),
    material: wp.array2d(dtype=wp.vec4h),
    emission: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
):
    """Shade G-buffer pixel (x, y) of a textured scene into out[y, x] (and its stochastic part into
    out_stoch[y, x] with ``sp.split_stochastic``); a miss: the environment along the ray, else the background."""
    if hit[y, x] == wp.uint8(0):
        if tp.has_env != 0:
            out[y, x] = emission[y, x]
        else:
            out[y, x] = sp.background
        if sp.split_stochastic != 0:
            out_stoch[y, x] = wp.vec3(0.0, 0.0, 0.0)
        return
    c, st = shade_textured_point(sp, tp, y * sp.width + x, pos[y, x], normal[y, x], albedo[y, x], material[y, x],
                                 emission[y, x], lights, area_lights)
    out[y, x] = c
    if sp.split_stochastic != 0:
        out_stoch[y, x] = st


@wp.kernel(enable_backward=False)
def shade_textured_full_kernel(
    spa: wp.array(dtype=ShadeParams),
    tp: TexturedShadeParams,
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    albedo: wp.array2d(dtype=wp.vec3),
    material: wp.array2d(dtype=wp.vec4h),
    emission: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    exposure: float,
    white: float,
    to_display: int,
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    display: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Shade every pixel; ``to_display`` != 0: also its tone-mapped value to ``display``."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    shade_textured_pixel(spa[0], tp, x, y, pos, normal, albedo, material, emission, hit, lights, area_lights, out,
                         out_stoch)
    if to_display != 0:
        display[y, x] = tonemap_rgb(out[y, x], exposure, white)


@wp.kernel(enable_backward=False)
def shade_textured_list_kernel(
    spa: wp.array(dtype=ShadeParams),
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    tp: TexturedShadeParams,
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    albedo: wp.array2d(dtype=wp.vec3),
    material: wp.array2d(dtype=wp.vec4h),
    emission: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Shade the flat pixel indices work[0:count[0]], each result at its own (x, y)."""
    i = wp.tid() + row0  # band offset (foveawarp.parallel)
    if i >= count[0]:
        return
    sp = spa[0]
    x, y = list_pixel(work[i], sp.width)
    shade_textured_pixel(sp, tp, x, y, pos, normal, albedo, material, emission, hit, lights, area_lights, out,
                         out_stoch)


@wp.kernel(enable_backward=False)
def shade_textured_masked_kernel(
    spa: wp.array(dtype=ShadeParams),
    mask: wp.array2d(dtype=wp.uint8),
    tp: TexturedShadeParams,
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    albedo: wp.array2d(dtype=wp.vec3),
    material: wp.array2d(dtype=wp.vec4h),
    emission: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """The unreordered baseline: every pixel launched, unsampled ones exit at once."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    if mask[y, x] == wp.uint8(0):
        return
    shade_textured_pixel(spa[0], tp, x, y, pos, normal, albedo, material, emission, hit, lights, area_lights, out,
                         out_stoch)


@wp.kernel(enable_backward=False)
def shade_textured_rows_kernel(
    spa: wp.array(dtype=ShadeParams),
    coords: wp.array2d(dtype=wp.vec2i),
    counts: wp.array(dtype=wp.int32),
    tp: TexturedShadeParams,
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    albedo: wp.array2d(dtype=wp.vec3),
    material: wp.array2d(dtype=wp.vec4h),
    emission: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Row-CSR launch (thesis strategies 1/2): thread (v, u) shades coords[v, u] when u < counts[v]."""
    v, u = wp.tid()
    v += row0  # band offset (foveawarp.parallel)
    if u >= counts[v]:
        return
    c = coords[v, u]
    shade_textured_pixel(spa[0], tp, c[0], c[1], pos, normal, albedo, material, emission, hit, lights, area_lights,
                         out, out_stoch)
