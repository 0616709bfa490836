"""Shading of G-buffer points: direct light with shadow rays, Lambert + Blinn-Phong, ambient (with optional
ambient occlusion), emission. Launched over a full frame, a pixel list (compacted work) or a mask.

Every entry kernel writes the pixel's radiance to ``out`` and, when ``ShadeParams.split_stochastic`` is 1, its
stochastic part (the Monte Carlo terms, whose noise changes every frame: area-light samples and ambient
occlusion) to ``out_stoch``; ``out - out_stoch`` is then the deterministic part (point/spot lights, plain
ambient, emission). The temporal resolve accumulates only the stochastic part over frames."""

import warp as wp

from .context import FrameContext
from .gbuffer import surface_albedo
from .order import tile_order_pixel
from .rng import cosine_hemisphere, pixel_rng
from .tonemap import pow_inv22_row, tonemap_linear_rgb, tonemap_rgb


@wp.struct
class LightParams:
    kind: int  # 0 point, 1 spot
    position: wp.vec3
    direction: wp.vec3
    cos_outer: float
    cos_inner: float
    intensity: wp.vec3


@wp.struct
class AreaLightParams:
    corner: wp.vec3
    edge_u: wp.vec3
    edge_v: wp.vec3
    radiance: wp.vec3


@wp.struct
class ShadeParams:
    mesh: wp.uint64
    num_lights: int
    num_area_lights: int
    shadows: int
    ambient: wp.vec3
    specular: float
    shininess: float
    ao_samples: int
    ao_radius: float
    area_samples: int
    background: wp.vec3
    ray_eps: float
    seed: int
    frame: int
    width: int
    eye: wp.vec3
    split_stochastic: int  # 1: also write the stochastic part to out_stoch


@wp.func
def visible(mesh: wp.uint64, p: wp.vec3, n: wp.vec3, eps: float, to: wp.vec3, dist: float) -> float:
    """1 when nothing blocks the segment from p (offset along n) to p + to * dist, else 0. An any-hit query: the
    traversal stops at the first triangle met within the segment (Warp's closest-hit query, with the same triangle
    and box tests, answers the same yes or no after searching on for the nearest)."""
    o = p + n * eps
    if dist <= 2.0 * eps:
        return 1.0
    if wp.mesh_query_ray_anyhit(mesh, o, to, dist - 2.0 * eps):
        return 0.0
    return 1.0


@wp.func
def spot_factor(l: LightParams, to_point: wp.vec3) -> float:
    if l.kind == 0:
        return 1.0
    c = wp.dot(to_point, l.direction)
    return wp.smoothstep(l.cos_outer, wp.max(l.cos_inner, l.cos_outer + 1.0e-6), c)


@wp.func
def shade_direct_parts(
    sp: ShadeParams,
    pixel: int,
    p: wp.vec3,
    n: wp.vec3,
    albedo: wp.vec3,
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
):
    """The light sources' part at surface point p: (point/spot lights, area-light estimate, the pixel's random
    stream after the area-light draws). :func:`shade_finish` adds the ambient term (AO'd or plain) and emission."""
    v = wp.normalize(sp.eye - p)
    diffuse = albedo / wp.pi
    col = wp.vec3(0.0, 0.0, 0.0)
    norm_spec = (sp.shininess + 8.0) / (8.0 * wp.pi)
    for li in range(sp.num_lights):
        l = lights[li]
        dl = l.position - p
        dist2 = wp.dot(dl, dl)
        if dist2 > 1.0e-30:
            dist = wp.sqrt(dist2)
            wi = dl / dist
            cos_i = wp.dot(n, wi)
            if cos_i > 0.0:
                att = spot_factor(l, -wi)
                if att > 0.0:
                    vis = 1.0
                    if sp.shadows != 0:
                        vis = visible(sp.mesh, p, n, sp.ray_eps, wi, dist)
                    if vis > 0.0:
                        h = wp.normalize(wi + v)
                        spec = sp.specular * norm_spec * wp.pow(wp.max(wp.dot(n, h), 0.0), sp.shininess)
                        e = l.intensity * (att * cos_i / dist2)
                        col += wp.cw_mul(e, diffuse * (1.0 - sp.specular) + wp.vec3(spec, spec, spec))
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
                            vis = visible(sp.mesh, p, n, sp.ray_eps, wi, dist)
                        acc += a.radiance * (vis * cos_i * cos_l / dist2)
            stoch += wp.cw_mul(diffuse, acc * (area / float(sp.area_samples)))
    return col, stoch, rng


@wp.func
def shade_finish(
    sp: ShadeParams,
    rng: wp.uint32,
    p: wp.vec3,
    n: wp.vec3,
    albedo: wp.vec3,
    face: int,
    face_emission: wp.array(dtype=wp.vec3),
    col: wp.vec3,
    stoch: wp.vec3,
    ao_unocc: float,
):
    """(radiance, stochastic part) from the light sources' part ``col`` / ``stoch`` (:func:`shade_direct_parts`):
    the ambient term, occluded by ``sp.ao_samples`` AO rays when there are any (traced here from ``rng`` when
    ``ao_unocc`` < 0, else ``ao_unocc`` of them were unoccluded: p, n and rng are then not read), and the face's
    emission."""
    amb = wp.cw_mul(albedo, sp.ambient)
    if sp.ao_samples > 0:
        unocc = float(0.0)
        if ao_unocc < 0.0:
            for s in range(sp.ao_samples):
                d = cosine_hemisphere(n, wp.randf(rng), wp.randf(rng))
                unocc += visible(sp.mesh, p, n, sp.ray_eps, d, sp.ao_radius)
        else:
            unocc = ao_unocc
        stoch += amb * (unocc / float(sp.ao_samples))
    else:
        col += amb
    return col + stoch + face_emission[face], stoch


@wp.func
def shade_point_parts(
    sp: ShadeParams,
    pixel: int,
    p: wp.vec3,
    n: wp.vec3,
    albedo: wp.vec3,
    face: int,
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
    ao_unocc: float = -1.0,
):
    """(radiance, stochastic part) at surface point p: the stochastic part holds the area-light estimate and,
    with AO rays, the occluded ambient term. ``ao_unocc`` < 0 (the default): the AO rays are traced here; else it
    is how many of the ``sp.ao_samples`` rays were unoccluded, traced beforehand (``shade_ao_list_kernel``: the
    same rays)."""
    col, stoch, rng = shade_direct_parts(sp, pixel, p, n, albedo, lights, area_lights)
    return shade_finish(sp, rng, p, n, albedo, face, face_emission, col, stoch, ao_unocc)


@wp.func
def area_light_draws(sp: ShadeParams, area_lights: wp.array(dtype=AreaLightParams)) -> int:
    """How many random numbers :func:`shade_point_parts` draws from the pixel's stream before its AO rays: two per
    sample of each area light of non-zero area (the same test as there, on the same values)."""
    k = int(0)
    for ai in range(sp.num_area_lights):
        a = area_lights[ai]
        if wp.length(wp.cross(a.edge_u, a.edge_v)) > 1.0e-30:
            k += 2 * sp.area_samples
    return k


@wp.func
def shade_point(
    sp: ShadeParams,
    pixel: int,
    p: wp.vec3,
    n: wp.vec3,
    albedo: wp.vec3,
    face: int,
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
) -> wp.vec3:
    """Radiance at surface point p (direct light, ambient or AO, emission)."""
    c, st = shade_point_parts(sp, pixel, p, n, albedo, face, lights, area_lights, face_emission)
    return c


@wp.func
def shade_miss(sp: ShadeParams, x: int, y: int, out: wp.array2d(dtype=wp.vec3), out_stoch: wp.array2d(dtype=wp.vec3)):
    """A primary-ray miss at (x, y): the background to ``out`` and, with ``sp.split_stochastic``, 0 to
    ``out_stoch``."""
    out[y, x] = sp.background
    if sp.split_stochastic != 0:
        out_stoch[y, x] = wp.vec3(0.0, 0.0, 0.0)


@wp.func
def ao_lanes_count(ao_part: wp.array2d(dtype=wp.uint8), i: int, lanes: int) -> float:
    """The unoccluded AO rays of list entry i: the sum of its ``lanes`` counts from :func:`shade_ao_list_kernel`
    (a sum of ones in any order: the count one thread tracing every ray would reach)."""
    c = int(0)
    for g in range(lanes):
        c += int(ao_part[i, g])
    return float(c)


@wp.func
def shade_pixel(
    sp: ShadeParams,
    x: int,
    y: int,
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    ao_unocc: float = -1.0,
):
    """Write the shaded radiance of G-buffer pixel (x, y) to out[y, x] (the background on a miss) and, with
    ``sp.split_stochastic``, its stochastic part to out_stoch[y, x] (0 on a miss). ``ao_unocc``: as in
    :func:`shade_point_parts`."""
    if hit[y, x] == wp.uint8(0):
        shade_miss(sp, x, y, out, out_stoch)
    else:
        f = face[y, x]
        c, st = shade_point_parts(sp, y * sp.width + x, pos[y, x], normal[y, x], surface_albedo(face_albedo, f), f,
                                  lights, area_lights, face_emission, ao_unocc)
        out[y, x] = c
        if sp.split_stochastic != 0:
            out_stoch[y, x] = st


def _make_shade_full(mode: str, max_registers=None, suffix: str = ""):
    """``shade_full_kernel`` (mode "pixels": a thread per pixel), ``shade_full_rows_kernel`` ("rows": a thread per
    image row looping over its pixels, the CPU: ``parallel.launch_rows``) or ``shade_full_tiles_kernel`` ("tiles":
    a thread per pixel, each warp on a block of pixels, CUDA: ``kernels/order.py``): one signature, one body.
    ``max_registers``: the CUDA register cap (``cuda_max_registers``; None: the compiler's choice); ``suffix``
    goes into the kernel's name (``shade_full_tiles_ao_kernel``: the capped twin for AO shading, see below)."""
    rows = mode == "rows"
    tiles = mode == "tiles"

    @wp.kernel(enable_backward=False, cuda_max_registers=max_registers,
               name=f"shade_full_{mode}{suffix}_kernel" if mode != "pixels" else "shade_full_kernel")
    def shade_full(
        spa: wp.array(dtype=ShadeParams),
        pos: wp.array2d(dtype=wp.vec3),
        normal: wp.array2d(dtype=wp.vec3),
        face_albedo: wp.array(dtype=wp.vec3),
        face: wp.array2d(dtype=wp.int32),
        hit: wp.array2d(dtype=wp.uint8),
        lights: wp.array(dtype=LightParams),
        area_lights: wp.array(dtype=AreaLightParams),
        face_emission: wp.array(dtype=wp.vec3),
        exposure: float,
        white: float,
        to_display: int,
        out: wp.array2d(dtype=wp.vec3),
        out_stoch: wp.array2d(dtype=wp.vec3),
        display: wp.array2d(dtype=wp.vec3),
        wlog2: int,
        row0: int,
    ):
        """Shade every pixel; ``to_display`` != 0: also write its tone-mapped value to ``display`` (the frame's
        last pass when no indirect light or depth of field follows: no separate tone-map pass). ``wlog2``: the
        "tiles" launch's block width, log2 (``kernels/order.py``); the other modes ignore it."""
        if wp.static(rows):
            y = wp.tid() + row0  # band offset (foveawarp.parallel)
            sp = spa[0]
            for x in range(out.shape[1]):
                shade_pixel(sp, x, y, pos, normal, face_albedo, face, hit, lights, area_lights, face_emission, out,
                            out_stoch)
                if to_display != 0:
                    display[y, x] = tonemap_linear_rgb(out[y, x], exposure, white)
            if to_display != 0:
                pow_inv22_row(display, y)  # the row's display gamma, one vectorized loop (the same values)
        elif wp.static(tiles):
            p = tile_order_pixel(wp.tid() + row0, out.shape[1], wlog2)  # band offset: a range of threads
            x = p[0]
            y = p[1]
            if x < out.shape[1] and y < out.shape[0]:
                sp = spa[0]
                shade_pixel(sp, x, y, pos, normal, face_albedo, face, hit, lights, area_lights, face_emission, out,
                            out_stoch)
                if to_display != 0:
                    display[y, x] = tonemap_rgb(out[y, x], exposure, white)
        else:
            y, x = wp.tid()
            y += row0  # band offset (foveawarp.parallel)
            sp = spa[0]
            shade_pixel(sp, x, y, pos, normal, face_albedo, face, hit, lights, area_lights, face_emission, out,
                        out_stoch)
            if to_display != 0:
                display[y, x] = tonemap_rgb(out[y, x], exposure, white)

    return shade_full


# Register caps of the CUDA full-frame shading (H100, 01a17ff, ``regcaps-e3-01a17ff-cuda.json``: the kernels alone
# on frames of bunny, spot, city and cornell at 1080p and 4K). Uncapped the compiler gave it 128 registers: two
# 256-thread blocks per SM, too few warps to hide the BVH traversals' memory latency. With 8 AO rays a 64-register
# cap (4 blocks) took 15-28% off every scene (bunny 4K 11.65 -> 8.46 ms, city 4K 18.10 -> 13.02, cornell 4K 2.67
# -> 2.23); with default shading 80 registers (3 blocks) took 5-18% off bunny, spot and city (bunny 4K 0.85 ->
# 0.74 ms, city 4K 1.52 -> 1.26) and added 3-4% on cornell, while 64 added 20-23% there. So the AO shading
# launches its own twin, capped at 64, and the other shading the kernel capped at 80.
shade_full_kernel = _make_shade_full("pixels")
shade_full_rows_kernel = _make_shade_full("rows")
shade_full_tiles_kernel = _make_shade_full("tiles", max_registers=80)
shade_full_tiles_ao_kernel = _make_shade_full("tiles", max_registers=64, suffix="_ao")


@wp.func
def list_pixel(idx: int, width: int):
    """(x, y) of the flat pixel index ``idx`` = y * width + x of a work list (the reorder's lists)."""
    y = idx // width
    return idx - y * width, y


@wp.kernel(enable_backward=False)
def shade_list_kernel(
    spa: wp.array(dtype=ShadeParams),
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
    ao_part: wp.array2d(dtype=wp.uint8),
    lanes: int,
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Shade the flat pixel indices work[0:count[0]]; each result lands at its own (x, y). ``lanes`` > 0: the AO
    rays were traced by :func:`shade_ao_list_kernel`, and the unoccluded count is the sum of ``ao_part[i, :lanes]``
    (a sum of ones in any order: the same value as tracing them here); 0: they are traced here (``ao_part`` is
    not read)."""
    i = wp.tid()
    i += row0  # band offset (foveawarp.parallel)
    if i >= count[0]:
        return
    sp = spa[0]
    x, y = list_pixel(work[i], sp.width)
    ao = float(-1.0)
    if lanes > 0:
        ao = ao_lanes_count(ao_part, i, lanes)
    shade_pixel(sp, x, y, pos, normal, face_albedo, face, hit, lights, area_lights, face_emission, out, out_stoch, ao)


@wp.func
def ao_list_lane(sp: ShadeParams, work: wp.array(dtype=wp.int32), pos: wp.array2d(dtype=wp.vec3),
                 normal: wp.array2d(dtype=wp.vec3), hit: wp.array2d(dtype=wp.uint8),
                 area_lights: wp.array(dtype=AreaLightParams), ao_part: wp.array2d(dtype=wp.uint8), k: int):
    """Lane k of the list's AO pass (k below ``count[0] * G``, ``G = ao_part.shape[1]``): k = i G + g traces rays
    [g S / G, (g + 1) S / G) of pixel ``work[i]`` (S = ``sp.ao_samples``) and writes how many were unoccluded to
    ``ao_part[i, g]`` (0 on a miss). Each ray is the one :func:`shade_point_parts` would trace there: the pixel's
    random stream is advanced past the draws before it (the area-light samples', then two per earlier ray)."""
    groups = ao_part.shape[1]
    i = k // groups
    g = k - i * groups
    x, y = list_pixel(work[i], sp.width)
    c = int(0)
    if hit[y, x] != wp.uint8(0):
        s0 = (g * sp.ao_samples) // groups
        s1 = ((g + 1) * sp.ao_samples) // groups
        if s1 > s0:
            rng = pixel_rng(sp.seed, sp.frame, y * sp.width + x)
            for j in range(area_light_draws(sp, area_lights) + 2 * s0):
                wp.randf(rng)
            p = pos[y, x]
            n = normal[y, x]
            for s in range(s0, s1):
                d = cosine_hemisphere(n, wp.randf(rng), wp.randf(rng))
                if visible(sp.mesh, p, n, sp.ray_eps, d, sp.ao_radius) > 0.0:
                    c += 1
    ao_part[i, g] = wp.uint8(c)


# 64 registers (4 blocks per SM) instead of the compiler's 77 (3): 3-12% faster on bunny, spot and city at 1080p
# and 4K (city 1080p 1.12 -> 0.98 ms), equal on cornell (regcaps-e3-01a17ff-cuda.json); on the eyechart, earth and
# teapot -9% to +1% (regcaps-e5-c06862d-cuda.json). The list shading after it stays uncapped: every cap tried (80,
# 64, 48) slowed it on bunny, spot and cornell.
@wp.kernel(enable_backward=False, cuda_max_registers=64)
def shade_ao_list_kernel(
    spa: wp.array(dtype=ShadeParams),
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    area_lights: wp.array(dtype=AreaLightParams),
    ao_part: wp.array2d(dtype=wp.uint8),
    row0: int,
):
    """The AO rays of the list's pixels, ``G = ao_part.shape[1]`` threads per pixel: thread k is
    :func:`ao_list_lane` k, for k below ``count[0] * G``."""
    k = wp.tid() + row0  # band offset (foveawarp.parallel)
    if k >= count[0] * ao_part.shape[1]:
        return
    ao_list_lane(spa[0], work, pos, normal, hit, area_lights, ao_part, k)


@wp.kernel(enable_backward=False)
def shade_list_direct_kernel(
    spa: wp.array(dtype=ShadeParams),
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    light_col: wp.array(dtype=wp.vec3),
    light_stoch: wp.array(dtype=wp.vec3),
    row0: int,
):
    """The light sources' part (:func:`shade_direct_parts`) of list entry i (pixel ``work[i]``, i < ``count[0]``),
    written to ``light_col[i]`` / ``light_stoch[i]`` for :func:`shade_list_finish_kernel` to complete with the AO
    counts of :func:`shade_ao_list_kernel`, which reads none of it (the two may run at once: ``ShadeStage.list``).
    Misses are left to the finish. Per entry, so a pixel listed twice gets the same values twice."""
    i = wp.tid() + row0  # band offset (foveawarp.parallel)
    if i >= count[0]:
        return
    sp = spa[0]
    x, y = list_pixel(work[i], sp.width)
    if hit[y, x] == wp.uint8(0):
        return
    col, st, rng = shade_direct_parts(sp, y * sp.width + x, pos[y, x], normal[y, x],
                                      surface_albedo(face_albedo, face[y, x]), lights, area_lights)
    light_col[i] = col
    light_stoch[i] = st


@wp.kernel(enable_backward=False)
def shade_list_finish_kernel(
    spa: wp.array(dtype=ShadeParams),
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    hit: wp.array2d(dtype=wp.uint8),
    face_emission: wp.array(dtype=wp.vec3),
    ao_part: wp.array2d(dtype=wp.uint8),
    lanes: int,
    light_col: wp.array(dtype=wp.vec3),
    light_stoch: wp.array(dtype=wp.vec3),
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Complete list entry i from its light sources' part (``light_col[i]`` / ``light_stoch[i]``, written by
    :func:`shade_list_direct_kernel`) and its unoccluded AO count, the sum of ``ao_part[i, :lanes]``
    (:func:`shade_finish`), into ``out`` / ``out_stoch`` at its pixel: the values :func:`shade_list_kernel`
    writes, operation for operation (a miss: the background, stochastic part 0 with ``sp.split_stochastic``)."""
    i = wp.tid() + row0  # band offset (foveawarp.parallel)
    if i >= count[0]:
        return
    sp = spa[0]
    x, y = list_pixel(work[i], sp.width)
    if hit[y, x] == wp.uint8(0):
        shade_miss(sp, x, y, out, out_stoch)
        return
    zero = wp.vec3(0.0, 0.0, 0.0)
    f = face[y, x]
    col, st = shade_finish(sp, wp.uint32(0), zero, zero, surface_albedo(face_albedo, f), f, face_emission,
                           light_col[i], light_stoch[i], ao_lanes_count(ao_part, i, lanes))
    out[y, x] = col
    if sp.split_stochastic != 0:
        out_stoch[y, x] = st


def _make_shade_masked(rows: bool):
    """``shade_masked_kernel`` (a thread per pixel) or ``shade_masked_rows_kernel`` (a thread per row, the CPU)."""

    @wp.kernel(enable_backward=False, name="shade_masked_rows_kernel" if rows else "shade_masked_kernel")
    def shade_masked(
        spa: wp.array(dtype=ShadeParams),
        mask: wp.array2d(dtype=wp.uint8),
        pos: wp.array2d(dtype=wp.vec3),
        normal: wp.array2d(dtype=wp.vec3),
        face_albedo: wp.array(dtype=wp.vec3),
        face: wp.array2d(dtype=wp.int32),
        hit: wp.array2d(dtype=wp.uint8),
        lights: wp.array(dtype=LightParams),
        area_lights: wp.array(dtype=AreaLightParams),
        face_emission: wp.array(dtype=wp.vec3),
        out: wp.array2d(dtype=wp.vec3),
        out_stoch: wp.array2d(dtype=wp.vec3),
        row0: int,
    ):
        """The unreordered baseline: every pixel launched, unsampled threads exit at once."""
        if wp.static(rows):
            y = wp.tid() + row0  # band offset (foveawarp.parallel)
            sp = spa[0]
            for x in range(mask.shape[1]):
                if mask[y, x] != wp.uint8(0):
                    shade_pixel(sp, x, y, pos, normal, face_albedo, face, hit, lights, area_lights, face_emission, out,
                                out_stoch)
        else:
            y, x = wp.tid()
            y += row0  # band offset (foveawarp.parallel)
            if mask[y, x] == wp.uint8(0):
                return
            sp = spa[0]
            shade_pixel(sp, x, y, pos, normal, face_albedo, face, hit, lights, area_lights, face_emission, out,
                        out_stoch)

    return shade_masked


shade_masked_kernel = _make_shade_masked(False)
shade_masked_rows_kernel = _make_shade_masked(True)


@wp.kernel(enable_backward=False)
def shade_rows_kernel(
    spa: wp.array(dtype=ShadeParams),
    coords: wp.array2d(dtype=wp.vec2i),
    counts: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    face_albedo: wp.array(dtype=wp.vec3),
    face: wp.array2d(dtype=wp.int32),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """Row-CSR launch (thesis strategies 1/2): thread (v, u) shades coords[v, u] when u < counts[v]."""
    v, u = wp.tid()
    v += row0  # band offset (foveawarp.parallel)
    if u >= counts[v]:
        return
    sp = spa[0]
    c = coords[v, u]
    x = c[0]
    y = c[1]
    shade_pixel(sp, x, y, pos, normal, face_albedo, face, hit, lights, area_lights, face_emission, out, out_stoch)


@wp.kernel(enable_backward=False)
def set_shade_params_kernel(sp: ShadeParams, out: wp.array(dtype=ShadeParams)):
    """Write the frame's shading parameters to the device (the entry kernels read them from there, so a
    captured CUDA graph picks up each frame's eye and frame index)."""
    out[0] = sp


@wp.kernel(enable_backward=False)
def set_shade_params_view_kernel(sp: ShadeParams, ctx: FrameContext, out: wp.array(dtype=ShadeParams)):
    """``set_shade_params_kernel`` with the frame's eye and frame index taken from the frame context."""
    p = sp
    p.eye = ctx.cam.eye
    p.frame = ctx.frame
    out[0] = p
