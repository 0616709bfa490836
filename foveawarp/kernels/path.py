"""The path integrator: unidirectional path tracing with next-event estimation and multiple importance sampling.

A path starts at the camera ray through its pixel (the pixel centre, or with ``PathParams.jitter`` a point drawn
uniformly over the pixel: a box filter), not at the G-buffer's stored hit: the G-buffer's hit is that same ray at
the pixel centre, and tracing it again costs one ray per path while keeping the integrator free of the G-buffer's
layout. At each surface vertex:

- emission seen along the ray is added: face emission (untextured scenes: two-sided, as the direct integrator
  adds it; a material's: two-sided when the material is double-sided, else from its front, ``front_emits``) and area
  lights (one-sided: the side ``cross(edge_u, edge_v)`` faces), weighted by the power heuristic against the light
  sampling of the previous vertex (weight 1 for a camera ray);
- next-event estimation: every point/spot light (one shadow ray each, no MIS: delta lights), one sample per area
  light (uniform over its area), one emissive triangle (chosen with probability proportional to area times summed
  RGB emission, then uniform over it) and, where the scene has a non-black environment, one environment sample
  (its importance distribution, kernels/envmap.py); each but the delta lights weighted by the power heuristic
  against the BSDF's pdf (Veach 1997, eq. 9.13 with beta = 2);
- the BSDF is sampled (kernels/bsdf.py: cosine-weighted Lambert and GGX visible normals) for the next ray;
- a glass vertex (a material's ``transmission`` part) instead samples no light: a smooth dielectric interface
  (roughness 0) reflects with the Fresnel probability of its index (``fresnel_dielectric``) or refracts; a rough
  one does so about a GGX microfacet normal (``rough_dielectric_sample``); the emission the next hit sees is
  weighted 1 (the previous pdf is PDF_MAX).

The material at a vertex is the per-face albedo as glTF base colour (``path_material``) in untextured scenes, or in
scenes with materials the hit's textured material (kernels/surface.py: ``eval_surface_at``), whose texture LOD
follows the path's ray cone (``bounce_spread_angle``; ``foveawarp.stages.path`` documents the model); the two
are separate kernels (``path_*_kernel``, ``path_*_textured_kernel``) of one body.

Depth follows Mitsuba 3's ``path`` integrator: vertex ``k`` (0 = the camera ray's hit) performs next-event
estimation and continues only when ``k + 1 < max_depth``, so ``max_depth`` 1 gives emitters seen directly, 2
direct light, 3 one indirect bounce. After ``k + 1 >= rr_depth`` bounces a path continues with probability
``q = min(max channel of its throughput, 0.95)`` and is divided by ``q`` (Russian roulette, Mitsuba's rule).

Area lights are opaque and black: a ray that meets one stops there (emitting only from its front), and shadow
rays are blocked by them, as a Mitsuba rectangle emitter with a black BSDF. A ray that leaves the scene sees the
environment (``PathParams.env_light``); without one, a camera ray sees ``PathParams.background`` (the direct
integrator's background) and a bounce ray sees nothing.

No NaN or Inf: every division is guarded (zero-area lights and triangles are skipped, a zero pdf ends the path,
a non-finite throughput ends it), and each path's radiance is clamped to ``[0, RADIANCE_MAX]`` per channel (NaN
to 0) before it is averaged; ``PathParams.clamp`` > 0 is the optional firefly clamp
(``ShadingConfig.radiance_clamp``).
"""

import warp as wp

from .bsdf import SurfaceMaterial, bsdf_eval, bsdf_pdf, bsdf_sample, frame_from_normal, fresnel_dielectric, \
    ggx_alpha, make_material, rough_dielectric_sample, to_local, to_world
from .camera import CameraParams, camera_ray_dir
from .envmap import EnvironmentMap, env_eval, env_pdf, env_sample
from .gbuffer import smooth_normal
from .gbuffer_textured import primary_spread_angle, sample_footprint_px
from .mis import PDF_MAX, nee_weight, power_heuristic
from .rng import pixel_rng
from .shade import AreaLightParams, LightParams, spot_factor
from .shade_textured import raised_wo
from .surface import SurfaceData, eval_surface_at, is_cut_out, segment_clear, surface_emission, trace_surface_cone
from .texture import SPREAD_ANGLE_MAX, cone_footprint_log2, cone_width

# lights and triangles of smaller area (world units squared) are never sampled
AREA_MIN = wp.constant(1.0e-30)
# the largest radiance a path may carry per channel: float32 max rounded down
RADIANCE_MAX = wp.constant(3.0e38)
# Russian roulette's highest survival probability (Mitsuba 3's)
RR_MAX = wp.constant(0.95)


@wp.struct
class PathParams:
    """The path integrator's per-frame parameters (``foveawarp.stages.path.PathStage.params``)."""

    mesh: wp.uint64
    cam: CameraParams
    num_lights: int
    num_area_lights: int
    num_emitters: int  # emissive triangles with a non-zero sampling weight
    env_light: int  # 1: a ray that misses sees the environment; 0: no environment
    env_nee: int  # 1: the environment is sampled at every vertex (a non-black map)
    max_depth: int
    rr_depth: int
    spp: int
    budget: float  # > 0: the list launch shares this many paths by sampling probability (path_budget "frame")
    max_spp: int  # the most paths of one pixel under the budget
    jitter: int  # 1: a path's camera ray through a uniform point of its pixel; 0: through the pixel centre
    clamp: float  # > 0: a path's largest channel is scaled down to at most this; 0: off
    roughness: float  # glTF roughness of every surface (today's material; see path_material)
    specular: float  # glTF specularFactor of every surface; 0: pure Lambert
    background: wp.vec3  # what a camera ray that misses sees when there is no environment
    ray_eps: float  # secondary-ray origin offset along the geometric normal, world units
    far: float  # the longest ray, world units
    seed: int
    frame: int
    width: int


@wp.func
def max3(c: wp.vec3) -> float:
    return wp.max(c[0], wp.max(c[1], c[2]))


@wp.func
def finite_radiance(c: wp.vec3) -> wp.vec3:
    """c with every channel in [0, RADIANCE_MAX] (NaN to 0)."""
    out = wp.vec3(0.0, 0.0, 0.0)
    for k in range(3):
        x = c[k]
        if x > RADIANCE_MAX:
            out[k] = RADIANCE_MAX
        elif x > 0.0:
            out[k] = x
    return out


@wp.func
def finite3(c: wp.vec3) -> bool:
    return wp.isfinite(c[0]) and wp.isfinite(c[1]) and wp.isfinite(c[2])


@wp.func
def path_material(pp: PathParams, face_albedo: wp.array(dtype=wp.vec3), face: int) -> SurfaceMaterial:
    """The material of a path vertex on ``face``: today's per-face albedo as the glTF base colour, metallic 0, and
    the frame's roughness and specularFactor standing in for the direct integrator's Blinn-Phong lobe
    (``foveawarp.stages.path.material_from_blinn_phong``); untextured scenes only."""
    return make_material(face_albedo[face], 0.0, pp.roughness, pp.specular)


@wp.func
def bounce_spread_angle(pdf: float) -> float:
    """The angle a path's ray cone widens by at a bounce whose direction was drawn with solid-angle density
    ``pdf``: the apex angle ``2 theta`` of the cone of solid angle ``1 / pdf``, ``2 pi (1 - cos theta) = 1 / pdf``,
    so ``2 acos(1 - 1 / (2 pi pdf))``, evaluated as ``4 asin(sqrt(1 / (4 pi pdf)))`` (no cancellation for narrow
    lobes); at most SPREAD_ANGLE_MAX (also for a pdf of 0 or NaN); 0 for an infinite pdf (a mirror)."""
    if not (pdf > 0.0):
        return SPREAD_ANGLE_MAX
    x = 1.0 / (4.0 * wp.pi * pdf)  # sin^2(theta / 2)
    if x >= 1.0:
        return SPREAD_ANGLE_MAX
    return wp.min(4.0 * wp.asin(wp.sqrt(x)), SPREAD_ANGLE_MAX)


@wp.func
def parallelogram_t(a: AreaLightParams, o: wp.vec3, d: wp.vec3, tmax: float) -> float:
    """Distance along the unit ray (o, d) to area light ``a`` when it meets the parallelogram in (0, tmax), from
    either side; -1 otherwise (and for a light of area below AREA_MIN or a ray parallel to its plane)."""
    n = wp.cross(a.edge_u, a.edge_v)
    area = wp.length(n)
    if not (area > AREA_MIN):
        return -1.0
    nu = n / area
    den = wp.dot(d, nu)
    if not (wp.abs(den) > 1.0e-12):
        return -1.0
    t = wp.dot(a.corner - o, nu) / den
    if not (t > 0.0 and t < tmax):
        return -1.0
    r = o + d * t - a.corner
    # r = s edge_u + w edge_v: s = (r x edge_v) . n / |n|^2, w = (edge_u x r) . n / |n|^2
    s = wp.dot(wp.cross(r, a.edge_v), nu) / area
    w = wp.dot(wp.cross(a.edge_u, r), nu) / area
    if s < 0.0 or s > 1.0 or w < 0.0 or w > 1.0:
        return -1.0
    return t


@wp.func
def area_light_pdf(a: AreaLightParams, d: wp.vec3, t: float) -> float:
    """Solid-angle density of sampling light ``a`` uniformly by area, at the point a unit ray ``d`` meets at
    distance ``t``: t^2 / (cos_l area); 0 from behind or for a zero area."""
    n = wp.cross(a.edge_u, a.edge_v)
    area = wp.length(n)
    if not (area > AREA_MIN):
        return 0.0
    cos_l = -wp.dot(n / area, d)
    if not (cos_l > 0.0):
        return 0.0
    return wp.min(t * t / (cos_l * area), PDF_MAX)


@wp.func
def triangle_corners(points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), f: int):
    return points[indices[3 * f + 0]], points[indices[3 * f + 1]], points[indices[3 * f + 2]]


@wp.func
def emitter_pdf(points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32),
                face_emit_prob: wp.array(dtype=float), f: int, d: wp.vec3, t: float) -> float:
    """Solid-angle density of the emissive-triangle sampling at the point of face ``f`` a unit ray ``d`` meets at
    distance ``t``: prob(f) t^2 / (|cos_l| area(f)); 0 for a face that is never sampled."""
    prob = face_emit_prob[f]
    if not (prob > 0.0):
        return 0.0
    p0, p1, p2 = triangle_corners(points, indices, f)
    n = wp.cross(p1 - p0, p2 - p0)
    len_n = wp.length(n)
    area = 0.5 * len_n
    if not (area > AREA_MIN):
        return 0.0
    cos_l = wp.abs(wp.dot(n / len_n, d))
    if not (cos_l > 0.0):
        return 0.0
    return wp.min(prob * t * t / (cos_l * area), PDF_MAX)


@wp.func
def cdf_search(cdf: wp.array(dtype=float), n: int, x: float) -> int:
    """The largest k in [0, n - 1] with cdf[k] <= x (cdf holds n + 1 values, 0 first, 1 last)."""
    lo = int(0)
    hi = n - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if cdf[mid] <= x:
            lo = mid
        else:
            hi = mid - 1
    return lo


@wp.func
def front_emits(sd: SurfaceData, face: int, face_normal: wp.vec3, d: wp.vec3) -> bool:
    """Whether a ray along ``d`` meeting ``face`` (winding normal ``face_normal``) sees its emission: a
    double-sided material emits from both sides, a single-sided one from its front only (as a Mitsuba area
    emitter, and as glTF's back-face culling shows it)."""
    if sd.double_sided[sd.face_material[face]] != 0:
        return True
    return wp.dot(face_normal, d) < 0.0


def _make_path(textured: bool):
    """The path integrator's entry kernels for untextured scenes (per-face albedo and emission: ``path_material``)
    or, with ``textured``, for scenes with materials (kernels/surface.py: the hit's textured glTF material,
    cut-outs, culled back faces of single-sided materials on camera rays, texture LOD from the path's ray cone):
    one body, the textured parts selected at code generation."""

    @wp.func
    def blocked(pp: PathParams, sd: SurfaceData, area_lights: wp.array(dtype=AreaLightParams), o: wp.vec3,
                d: wp.vec3, dist: float, skip: int) -> bool:
        """Whether a surface (textured: an opaque texel, cut-outs let the ray through) or an area light other than
        ``skip`` (-1: none) lies on the unit ray (o, d) within (0, dist)."""
        hit = False
        if dist > 0.0:
            if wp.static(textured):
                hit = not segment_clear(pp.mesh, sd, o, d, dist)
            else:
                hit = wp.mesh_query_ray_anyhit(pp.mesh, o, d, dist)
            if not hit:
                for li in range(pp.num_area_lights):
                    if li != skip and parallelogram_t(area_lights[li], o, d, dist) > 0.0:
                        hit = True
        return hit

    @wp.func
    def clear_to(pp: PathParams, sd: SurfaceData, area_lights: wp.array(dtype=AreaLightParams), o: wp.vec3,
                 q: wp.vec3, skip: int) -> bool:
        """Whether the segment from the offset origin o to the light point q is free, but for its last 2 ray_eps
        (so the light's own surface at q never blocks it) and area light ``skip``."""
        dq = q - o
        dist = wp.length(dq)
        if not (dist > 2.0 * pp.ray_eps):
            return True
        return not blocked(pp, sd, area_lights, o, dq / dist, dist - 2.0 * pp.ray_eps, skip)

    @wp.func
    def trace_path(
        pp: PathParams,
        env: EnvironmentMap,
        sd: SurfaceData,
        face_albedo: wp.array(dtype=wp.vec3),
        face_emission: wp.array(dtype=wp.vec3),
        vnormals: wp.array(dtype=wp.vec3),
        face_smooth: wp.array(dtype=wp.uint8),
        points: wp.array(dtype=wp.vec3),
        indices: wp.array(dtype=wp.int32),
        lights: wp.array(dtype=LightParams),
        area_lights: wp.array(dtype=AreaLightParams),
        emit_face: wp.array(dtype=wp.int32),
        emit_cdf: wp.array(dtype=float),
        face_emit_prob: wp.array(dtype=float),
        o_cam: wp.vec3,
        d_cam: wp.vec3,
        spread0: float,
        rng: wp.uint32,
    ):
        """The radiance one path carries along the camera ray (o_cam, d_cam) (before the clamps), and the stream;
        ``spread0``: the camera ray cone's spread angle (textured scenes' texture LOD)."""
        L = wp.vec3(0.0, 0.0, 0.0)
        thr = wp.vec3(1.0, 1.0, 1.0)
        o = o_cam
        d = d_cam
        prev_pdf = float(0.0)  # the BSDF pdf of the ray being traced; 0 for the camera ray
        eps = pp.ray_eps
        cone_w = float(0.0)  # the ray cone's width at o and its spread angle (textured scenes)
        cone_a = spread0
        for depth in range(pp.max_depth):
            hit = False
            t = pp.far
            f = int(-1)
            bu = float(0.0)
            bv = float(0.0)
            gn = wp.vec3(0.0, 0.0, 1.0)
            if wp.static(textured):
                cull = int(0)
                if depth == 0:
                    cull = 1  # single-sided materials' back faces are culled on camera rays, as the G-buffer does
                h = trace_surface_cone(pp.mesh, sd, o, d, pp.far, cone_w, cone_a, cull)
                if h.result:
                    hit = True
                    t = h.t
                    f = h.face
                    bu = h.u
                    bv = h.v
                    gn = h.normal
            else:
                q = wp.mesh_query_ray(pp.mesh, o, d, pp.far)
                if q.result:
                    hit = True
                    t = q.t
                    f = q.face
                    bu = q.u
                    bv = q.v
                    gn = q.normal
            light = int(-1)
            for li in range(pp.num_area_lights):
                tl = parallelogram_t(area_lights[li], o, d, t)
                if tl > 0.0:
                    t = tl
                    light = li
            if light >= 0:
                a = area_lights[light]
                if wp.dot(wp.cross(a.edge_u, a.edge_v), d) < 0.0:
                    w = float(1.0)
                    if depth > 0:
                        w = power_heuristic(prev_pdf, area_light_pdf(a, d, t))
                    L += wp.cw_mul(thr, a.radiance) * w
                break
            if not hit:
                if pp.env_light != 0:
                    w = float(1.0)
                    if depth > 0 and pp.env_nee != 0:
                        w = power_heuristic(prev_pdf, env_pdf(env, d))
                    L += wp.cw_mul(thr, env_eval(env, d)) * w
                elif depth == 0:
                    L += pp.background
                break
            p = o + d * t
            # the geometric normal facing the arriving ray
            ng = gn
            if wp.dot(ng, d) > 0.0:
                ng = -ng
            ns = ng
            m = SurfaceMaterial()
            le = wp.vec3(0.0, 0.0, 0.0)
            tr = float(0.0)  # the glass part, its index of refraction and tint (textured scenes)
            ior = float(1.5)
            tint = wp.vec3(1.0, 1.0, 1.0)
            cone_hit = cone_w
            if wp.static(textured):
                cone_hit = cone_w + cone_width(t, cone_a)
                fp = cone_footprint_log2(cone_hit, gn, d)
                sp = eval_surface_at(sd, f, bu, bv, d, gn, fp)
                if front_emits(sd, f, gn, d):
                    le = sp.emission
                ns = sp.normal
                m = make_material(sp.base_color, sp.metallic, sp.roughness, sp.specular)
                tr = sp.transmission
                ior = sp.ior
                tint = sp.base_color
            else:
                le = face_emission[f]
            if max3(le) > 0.0:
                w = float(1.0)
                if depth > 0 and pp.num_emitters > 0:
                    w = power_heuristic(prev_pdf, emitter_pdf(points, indices, face_emit_prob, f, d, t))
                L += wp.cw_mul(thr, le) * w
            if depth + 1 >= pp.max_depth:
                break
            if wp.static(not textured):
                if face_smooth[f] != wp.uint8(0):
                    ns = smooth_normal(ng, bu, bv, vnormals[indices[3 * f + 0]], vnormals[indices[3 * f + 1]],
                                       vnormals[indices[3 * f + 2]])
                m = path_material(pp, face_albedo, f)
            fr = frame_from_normal(ns)
            wo = to_local(fr, -d)
            if wp.static(textured):
                wo = raised_wo(wo)  # as the textured direct integrator: a map normal turned from the viewer
            # every ray leaving this vertex starts here; light samples are placed and weighted from p itself
            po = p + ng * eps
            # a glass vertex (textured scenes: the material's transmission part, chosen with that probability) is a
            # smooth dielectric interface, a delta lobe: no light samples; Fresnel reflection with probability F,
            # else refraction
            glass = False
            if tr > 0.0:
                glass = True
                if tr < 1.0:
                    glass = wp.randf(rng) < tr
            wi = wp.vec3(0.0, 0.0, 0.0)
            spread_pdf = float(PDF_MAX)  # the next ray's density, which widens its cone: a smooth interface's delta
            if glass:
                eta = ior
                if wp.dot(gn, d) > 0.0:
                    eta = 1.0 / ior  # leaving through the back of the winding normal: glass to outside
                nn = ns
                cos_i = -wp.dot(d, nn)
                if not (cos_i > 1.0e-6):  # a shading normal turned from the ray
                    nn = ng
                    cos_i = -wp.dot(d, ng)
                inv = 1.0 / eta
                transmitted = False
                weight = float(1.0)  # f |cos| / pdf of the chosen direction: 1 for the smooth interface
                if m.roughness > 0.0:
                    # a rough interface (GGX microfacets): still no light samples, so the emission the next hit
                    # sees keeps weight 1, as behind a smooth one
                    gf = frame_from_normal(nn)
                    ds = rough_dielectric_sample(to_local(gf, -d), ggx_alpha(m.roughness), eta, wp.randf(rng),
                                                 wp.randf(rng), wp.randf(rng))
                    if not (ds.weight > 0.0):
                        break
                    wi = to_world(gf, ds.wi)
                    spread_pdf = ds.pdf
                    transmitted = ds.transmitted != 0
                    weight = ds.weight
                else:
                    fres, cos_t = fresnel_dielectric(cos_i, eta)
                    if wp.randf(rng) < fres:
                        wi = wp.normalize(d + nn * (2.0 * cos_i))
                    else:
                        wi = wp.normalize(d * inv + nn * (inv * cos_i - cos_t))
                        transmitted = True
                if transmitted:
                    if not (wp.dot(wi, ng) < 0.0):
                        break
                    po = p - ng * eps
                    # radiance entering a medium of relative index eta scales by 1 / eta^2 (as in Mitsuba 3)
                    thr = wp.cw_mul(thr, tint) * (inv * inv * weight)
                else:
                    if not (wp.dot(wi, ng) > 0.0):
                        break
                    thr = thr * weight
                prev_pdf = PDF_MAX  # what the next hit's emission is weighted against: no light sample, weight 1
            else:
                # point and spot lights
                for li in range(pp.num_lights):
                    lt = lights[li]
                    dl = lt.position - p
                    dist2 = wp.dot(dl, dl)
                    if dist2 > 1.0e-30:
                        dist = wp.sqrt(dist2)
                        wi = dl / dist
                        if wp.dot(wi, ng) > 0.0:
                            att = spot_factor(lt, -wi)
                            wil = to_local(fr, wi)
                            if att > 0.0 and wil[2] > 0.0:
                                if clear_to(pp, sd, area_lights, po, lt.position, -1):
                                    fv = bsdf_eval(m, wo, wil)
                                    L += wp.cw_mul(thr, wp.cw_mul(fv, lt.intensity)) * (att * wil[2] / dist2)
                # area lights, one sample each
                for li in range(pp.num_area_lights):
                    a = area_lights[li]
                    u1 = wp.randf(rng)
                    u2 = wp.randf(rng)
                    an = wp.cross(a.edge_u, a.edge_v)
                    area = wp.length(an)
                    if area > AREA_MIN:
                        ql = a.corner + a.edge_u * u1 + a.edge_v * u2
                        dl = ql - p
                        dist2 = wp.dot(dl, dl)
                        if dist2 > 1.0e-30:
                            dist = wp.sqrt(dist2)
                            wi = dl / dist
                            cos_l = -wp.dot(an / area, wi)
                            wil = to_local(fr, wi)
                            if cos_l > 0.0 and wp.dot(wi, ng) > 0.0 and wil[2] > 0.0:
                                if clear_to(pp, sd, area_lights, po, ql, li):
                                    pl = wp.min(dist2 / (cos_l * area), PDF_MAX)
                                    L += wp.cw_mul(thr, nee_weight(bsdf_eval(m, wo, wil), wil[2], a.radiance, pl,
                                                                   bsdf_pdf(m, wo, wil)))
                # one emissive triangle
                if pp.num_emitters > 0:
                    ue = wp.randf(rng)
                    u1 = wp.randf(rng)
                    u2 = wp.randf(rng)
                    fe = emit_face[cdf_search(emit_cdf, pp.num_emitters, ue)]
                    p0, p1, p2 = triangle_corners(points, indices, fe)
                    su = wp.sqrt(u1)
                    ql = p0 * (1.0 - su) + p1 * (u2 * su) + p2 * (su * (1.0 - u2))
                    dl = ql - p
                    dist2 = wp.dot(dl, dl)
                    if dist2 > 1.0e-30:
                        dist = wp.sqrt(dist2)
                        wi = dl / dist
                        wil = to_local(fr, wi)
                        if wp.dot(wi, ng) > 0.0 and wil[2] > 0.0:
                            pl = emitter_pdf(points, indices, face_emit_prob, fe, wi, dist)
                            if pl > 0.0:
                                lq = wp.vec3(0.0, 0.0, 0.0)
                                if wp.static(textured):
                                    # the point's barycentrics in Warp's convention: p0 u + p1 v + p2 (1 - u - v)
                                    eu = 1.0 - su
                                    ev = u2 * su
                                    visible = front_emits(sd, fe, wp.cross(p1 - p0, p2 - p0), wi)
                                    if visible and sd.has_cutouts != 0:
                                        visible = not is_cut_out(sd, fe, eu, ev, -128.0)
                                    if visible:
                                        lq = surface_emission(sd, fe, eu, ev, -128.0)
                                else:
                                    lq = face_emission[fe]
                                if max3(lq) > 0.0:
                                    if clear_to(pp, sd, area_lights, po, ql, -1):
                                        L += wp.cw_mul(thr, nee_weight(bsdf_eval(m, wo, wil), wil[2], lq, pl,
                                                                       bsdf_pdf(m, wo, wil)))
                # the environment
                if pp.env_nee != 0:
                    u1 = wp.randf(rng)
                    u2 = wp.randf(rng)
                    wi, le_env, pl = env_sample(env, u1, u2)
                    wil = to_local(fr, wi)
                    if pl > 0.0 and wp.dot(wi, ng) > 0.0 and wil[2] > 0.0:
                        if not blocked(pp, sd, area_lights, po, wi, pp.far, -1):
                            L += wp.cw_mul(thr, nee_weight(bsdf_eval(m, wo, wil), wil[2], le_env, pl,
                                                           bsdf_pdf(m, wo, wil)))
                # the next ray
                u1 = wp.randf(rng)
                u2 = wp.randf(rng)
                u3 = wp.randf(rng)
                s = bsdf_sample(m, wo, u1, u2, u3)
                if not (s.pdf > 0.0):
                    break
                wi = to_world(fr, s.wi)
                if not (wp.dot(wi, ng) > 0.0):
                    break
                thr = wp.cw_mul(thr, s.f) * (s.wi[2] / s.pdf)
                prev_pdf = s.pdf
                spread_pdf = s.pdf
            if not finite3(thr):
                break
            if depth + 1 >= pp.rr_depth:
                qs = wp.min(max3(thr), RR_MAX)
                if not (wp.randf(rng) < qs):
                    break
                thr = thr / qs
            if not (max3(thr) > 0.0):
                break
            if wp.static(textured):
                cone_w = cone_hit
                cone_a = wp.min(cone_a + bounce_spread_angle(spread_pdf), SPREAD_ANGLE_MAX)
            o = po
            d = wi
        return L, rng

    @wp.func
    def pixel_radiance(
        pp: PathParams,
        env: EnvironmentMap,
        sd: SurfaceData,
        face_albedo: wp.array(dtype=wp.vec3),
        face_emission: wp.array(dtype=wp.vec3),
        vnormals: wp.array(dtype=wp.vec3),
        face_smooth: wp.array(dtype=wp.uint8),
        points: wp.array(dtype=wp.vec3),
        indices: wp.array(dtype=wp.int32),
        lights: wp.array(dtype=LightParams),
        area_lights: wp.array(dtype=AreaLightParams),
        emit_face: wp.array(dtype=wp.int32),
        emit_cdf: wp.array(dtype=float),
        face_emit_prob: wp.array(dtype=float),
        x: int,
        y: int,
        spp: int,
        footprint_px: float,
    ) -> wp.vec3:
        """The mean of ``spp`` paths through pixel (x, y), each clamped (module docstring), from the pixel's
        random stream of the frame (``pixel_rng(seed, frame, y * width + x)``); ``footprint_px``: the pixels the
        camera ray cone spans (textured scenes' texture LOD)."""
        rng = pixel_rng(pp.seed, pp.frame, y * pp.width + x)
        spread0 = primary_spread_angle(pp.cam, footprint_px)
        acc = wp.vec3(0.0, 0.0, 0.0)
        for s in range(spp):
            jx = float(0.5)
            jy = float(0.5)
            if pp.jitter != 0:
                jx = wp.randf(rng)
                jy = wp.randf(rng)
            d = camera_ray_dir(pp.cam, float(x) + jx, float(y) + jy)
            c, rng = trace_path(pp, env, sd, face_albedo, face_emission, vnormals, face_smooth, points, indices,
                                lights, area_lights, emit_face, emit_cdf, face_emit_prob, pp.cam.eye, d, spread0,
                                rng)
            c = finite_radiance(c)
            if pp.clamp > 0.0:
                mc = max3(c)
                if mc > pp.clamp:
                    c = c * (pp.clamp / mc)
            acc += c
        return finite_radiance(acc / float(wp.max(spp, 1)))

    suffix = "_textured" if textured else ""

    @wp.kernel(enable_backward=False, name=f"path_full{suffix}_kernel")
    def path_full_kernel(
        ppa: wp.array(dtype=PathParams),
        env: EnvironmentMap,
        sd: SurfaceData,
        face_albedo: wp.array(dtype=wp.vec3),
        face_emission: wp.array(dtype=wp.vec3),
        vnormals: wp.array(dtype=wp.vec3),
        face_smooth: wp.array(dtype=wp.uint8),
        points: wp.array(dtype=wp.vec3),
        indices: wp.array(dtype=wp.int32),
        lights: wp.array(dtype=LightParams),
        area_lights: wp.array(dtype=AreaLightParams),
        emit_face: wp.array(dtype=wp.int32),
        emit_cdf: wp.array(dtype=float),
        face_emit_prob: wp.array(dtype=float),
        out: wp.array2d(dtype=wp.vec3),
        row0: int,
    ):
        """Every pixel's path-traced radiance into out[y, x] (camera ray cones of one pixel)."""
        y, x = wp.tid()
        y += row0  # band offset (foveawarp.parallel)
        pp = ppa[0]
        out[y, x] = pixel_radiance(pp, env, sd, face_albedo, face_emission, vnormals, face_smooth, points, indices,
                                   lights, area_lights, emit_face, emit_cdf, face_emit_prob, x, y, pp.spp, 1.0)

    @wp.kernel(enable_backward=False, name=f"path_list{suffix}_kernel")
    def path_list_kernel(
        ppa: wp.array(dtype=PathParams),
        env: EnvironmentMap,
        sd: SurfaceData,
        face_albedo: wp.array(dtype=wp.vec3),
        face_emission: wp.array(dtype=wp.vec3),
        vnormals: wp.array(dtype=wp.vec3),
        face_smooth: wp.array(dtype=wp.uint8),
        points: wp.array(dtype=wp.vec3),
        indices: wp.array(dtype=wp.int32),
        lights: wp.array(dtype=LightParams),
        area_lights: wp.array(dtype=AreaLightParams),
        emit_face: wp.array(dtype=wp.int32),
        emit_cdf: wp.array(dtype=float),
        face_emit_prob: wp.array(dtype=float),
        work: wp.array(dtype=wp.int32),
        count: wp.array(dtype=wp.int32),
        probability: wp.array2d(dtype=float),
        prob_sum: wp.array(dtype=float),
        out: wp.array2d(dtype=wp.vec3),
        spp_out: wp.array2d(dtype=wp.int32),
        row0: int,
    ):
        """The radiance of the flat pixel indices work[0:count[0]] (y * width + x), each into out[y, x], and the
        paths it took into spp_out[y, x]: ``pp.spp``, or with a budget (``pp.budget`` > 0) its share
        ``budget * p / sum p`` of the listed pixels' sampling probabilities ``p`` (``prob_sum[0]``, from
        ``budget_sum_kernel``), rounded stochastically and clamped to [1, ``pp.max_spp``]. A ``probability`` of
        the frame's size also widens a textured scene's camera ray cone to the sample's spacing
        (``sample_footprint_px``), as the sparse G-buffer does; a (1, 1) one leaves it at one pixel."""
        i = wp.tid() + row0  # band offset (foveawarp.parallel)
        if i >= count[0]:
            return
        pp = ppa[0]
        idx = work[i]
        y = idx // pp.width
        x = idx - y * pp.width
        if y < 0 or y >= out.shape[0] or x < 0 or x >= out.shape[1]:
            return
        n = pp.spp
        if pp.budget > 0.0 and prob_sum[0] > 0.0:
            share = pp.budget * probability[y, x] / prob_sum[0]
            # a stream of its own (the paths' stream is the pixel's, as with a fixed count)
            rr = pixel_rng(pp.seed ^ 0x5BD1E995, pp.frame, idx)
            share = wp.min(share, float(pp.max_spp))
            n = wp.clamp(int(wp.floor(share + wp.randf(rr))), 1, pp.max_spp)
        spp_out[y, x] = n
        footprint = float(1.0)
        if wp.static(textured):
            if probability.shape[0] == out.shape[0] and probability.shape[1] == out.shape[1]:
                footprint = sample_footprint_px(probability[y, x])
        out[y, x] = pixel_radiance(pp, env, sd, face_albedo, face_emission, vnormals, face_smooth, points, indices,
                                   lights, area_lights, emit_face, emit_cdf, face_emit_prob, x, y, n, footprint)

    return path_full_kernel, path_list_kernel


path_full_kernel, path_list_kernel = _make_path(False)
path_full_textured_kernel, path_list_textured_kernel = _make_path(True)


@wp.kernel(enable_backward=False)
def budget_sum_kernel(work: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32), width: int,
                      probability: wp.array2d(dtype=float), out: wp.array(dtype=float), row0: int):
    """The sum of the sampling probabilities of the listed pixels work[0:count[0]] into out[0] (zeroed first)."""
    i = wp.tid() + row0  # band offset (foveawarp.parallel)
    if i >= count[0]:
        return
    idx = work[i]
    y = idx // width
    x = idx - y * width
    wp.atomic_add(out, 0, probability[y, x])


@wp.kernel(enable_backward=False)
def set_path_params_kernel(pp: PathParams, out: wp.array(dtype=PathParams)):
    """Write the frame's path parameters to the device (the entry kernels read them from there)."""
    out[0] = pp


@wp.kernel(enable_backward=False)
def accumulate_kernel(acc: wp.array2d(dtype=wp.vec3), value: wp.array2d(dtype=wp.vec3), weight: float, row0: int):
    """acc += weight * value (the converged reference's running sum of passes)."""
    y, x = wp.tid()
    y += row0
    acc[y, x] = acc[y, x] + value[y, x] * weight


@wp.kernel(enable_backward=False)
def sample_directions_kernel(
    base_color: wp.vec3,
    roughness: float,
    specular: float,
    normal: wp.vec3,
    wo_world: wp.vec3,
    seed: int,
    wi_out: wp.array(dtype=wp.vec3),
    pdf_out: wp.array(dtype=float),
    pdf_eval: wp.array(dtype=float),
):
    """Test hook: the next-ray draw of a path vertex (frame from ``normal``, the path's material with this base
    colour, roughness and specular, metallic 0), world direction and its sampled pdf, and bsdf_pdf re-evaluated at
    it; a failed sample writes pdf 0."""
    i = wp.tid()
    rng = wp.rand_init(seed, i)
    fr = frame_from_normal(normal)
    m = make_material(base_color, 0.0, roughness, specular)
    wo = to_local(fr, wo_world)
    s = bsdf_sample(m, wo, wp.randf(rng), wp.randf(rng), wp.randf(rng))
    wi_out[i] = to_world(fr, s.wi)
    pdf_out[i] = s.pdf
    pdf_eval[i] = bsdf_pdf(m, wo, s.wi)


@wp.kernel(enable_backward=False)
def fresnel_dielectric_kernel(cos_i: wp.array(dtype=float), eta: wp.array(dtype=float), f_out: wp.array(dtype=float),
                              cos_t_out: wp.array(dtype=float)):
    """Test hook: fresnel_dielectric(cos_i[i], eta[i])."""
    i = wp.tid()
    f, ct = fresnel_dielectric(cos_i[i], eta[i])
    f_out[i] = f
    cos_t_out[i] = ct


@wp.kernel(enable_backward=False)
def bounce_spread_kernel(pdf: wp.array(dtype=float), out: wp.array(dtype=float)):
    """Test hook: bounce_spread_angle(pdf[i])."""
    i = wp.tid()
    out[i] = bounce_spread_angle(pdf[i])


@wp.kernel(enable_backward=False)
def power_heuristic_kernel(pa: wp.array(dtype=float), pb: wp.array(dtype=float), out: wp.array(dtype=float)):
    """Test hook: power_heuristic(pa[i], pb[i])."""
    i = wp.tid()
    out[i] = power_heuristic(pa[i], pb[i])
