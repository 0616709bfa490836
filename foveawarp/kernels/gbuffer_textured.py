"""G-buffer of textured scenes (foveawarp.surface): the primary hit's material is stored per pixel.

Separate kernels from kernels/gbuffer.py, so that the untextured scenes' kernels stay as they are. The entry's
common fields are :func:`kernels.gbuffer.write_primary`'s; the normal is then the shading normal of
kernels/surface.py (normal map applied), and three fields are added: ``albedo`` (linear base colour: texture x
factor), ``material`` (roughness, metallic, occlusion, specular scale as half floats: 8 bytes) and ``emission``.

Kernels: the full-resolution G-buffer (a one-pixel cone; a thread per pixel, on CUDA warps on 8 x 4 blocks), the
sparse mode's coarse G-buffer (a cone over the cell) and its saliency from the entries' Lab albedo, and its sampled
pixels traced and shaded in one thread (a cone over the sample's spacing).
"""

import warp as wp

from .camera import CameraParams, camera_ray_dir
from .context import FrameContext
from .envmap import EnvironmentMap, env_eval
from .gbuffer import cell_pixel, write_primary
from .load import store_vec3
from .order import tile_order_pixel
from .saliency import sobel_vec3
from .sampling import FrameParams, SamplingParams, saliency_velocity
from .shade import AreaLightParams, LightParams, ShadeParams, list_pixel
from .shade_textured import TexturedShadeParams, shade_textured_pixel
from .surface import SurfaceData, eval_surface, trace_surface
from .texture import footprint_spread_angle


@wp.func
def pack_material(roughness: float, metallic: float, occlusion: float, specular: float) -> wp.vec4h:
    """``GBuffer.material``: the four factors (each in [0, 1]) as half floats."""
    return wp.vec4h(wp.float16(roughness), wp.float16(metallic), wp.float16(occlusion), wp.float16(specular))


@wp.func
def primary_spread_angle(cam: CameraParams, footprint_px: float) -> float:
    """The ray cone's spread angle of a primary ray standing for ``footprint_px`` pixels: ``footprint_px`` times
    one pixel's angle ``atan(2 tan(fov_y / 2) / H)`` (kernels/texture.py)."""
    return footprint_spread_angle(wp.atan(2.0 * cam.tan_half_fov_y / float(wp.max(cam.height, 1))), footprint_px)


@wp.func
def store_material(y: int, x: int, albedo: wp.vec3, material: wp.vec4h, emission: wp.vec3,
                   out_albedo: wp.array2d(dtype=wp.vec3), out_material: wp.array2d(dtype=wp.vec4h),
                   out_emission: wp.array2d(dtype=wp.vec3)):
    """The material fields of textured G-buffer entry [y, x]."""
    store_vec3(out_albedo, y, x, albedo)
    out_material[y, x] = material
    store_vec3(out_emission, y, x, emission)


@wp.func
def trace_primary_textured(
    mesh: wp.uint64,
    sd: SurfaceData,
    env: EnvironmentMap,
    has_env: int,
    points_prev: wp.array(dtype=wp.vec3),
    cam: CameraParams,
    cam_prev: CameraParams,
    max_t: float,
    px: float,
    py: float,
    footprint_px: float,
    y: int,
    x: int,
    out_pos: wp.array2d(dtype=wp.vec3),
    out_normal: wp.array2d(dtype=wp.vec3),
    out_depth: wp.array2d(dtype=float),
    out_face: wp.array2d(dtype=wp.int32),
    out_hit: wp.array2d(dtype=wp.uint8),
    out_reproj: wp.array2d(dtype=wp.vec2),
    out_prev_dist: wp.array2d(dtype=float),
    out_moved: wp.array2d(dtype=wp.uint8),
    out_albedo: wp.array2d(dtype=wp.vec3),
    out_material: wp.array2d(dtype=wp.vec4h),
    out_emission: wp.array2d(dtype=wp.vec3),
):
    """:func:`trace_primary` of a textured scene: the ray passes cut-outs and culled back faces
    (kernels/surface.py), and the entry also holds the hit's base colour (``out_albedo``), (roughness, metallic,
    occlusion, specular) in half precision (``out_material``) and emission (on a miss the environment's radiance
    along the ray when ``has_env``, else 0); the normal is the shading normal (normal map applied). The texture
    LOD is that of a cone spread over ``footprint_px`` pixels."""
    d = camera_ray_dir(cam, px, py)
    spread = primary_spread_angle(cam, footprint_px)
    h = trace_surface(mesh, sd, cam.eye, d, max_t, spread, 1)
    write_primary(mesh, sd.indices, points_prev, sd.vnormals, sd.smooth, cam, cam_prev, max_t, d, h.result,
                  h.t, h.face, h.u, h.v, h.normal, y, x, out_pos, out_normal, out_depth, out_face, out_hit, out_reproj,
                  out_prev_dist, out_moved)
    if h.result:
        s = eval_surface(sd, h.face, h.u, h.v, d, h.t, h.normal, spread)
        store_vec3(out_normal, y, x, s.normal)
        store_material(y, x, s.base_color, pack_material(s.roughness, s.metallic, s.occlusion, s.specular),
                       s.emission, out_albedo, out_material, out_emission)
    else:
        z = wp.vec3(0.0, 0.0, 0.0)
        e = z
        if has_env != 0:
            e = env_eval(env, d)  # the environment seen along the ray
        # a miss: roughness 1, metallic 0, occlusion 1, specular 1
        store_material(y, x, z, pack_material(1.0, 0.0, 1.0, 1.0), e, out_albedo, out_material, out_emission)


def _make_gbuffer_textured(tiles: bool):
    """``gbuffer_textured_kernel`` (a thread per pixel over (H, W)) or ``gbuffer_textured_tiles_kernel`` (each
    warp on a block of ``2**wlog2`` x ``32 / 2**wlog2`` pixels, kernels/order.py; CUDA: neighbouring lanes hit
    nearby texels and BVH nodes). The same entries in both."""

    @wp.kernel(enable_backward=False, name="gbuffer_textured_tiles_kernel" if tiles else "gbuffer_textured_kernel")
    def gbuffer_textured(
        mesh: wp.uint64,
        sd: SurfaceData,
        env: EnvironmentMap,
        has_env: int,
        points_prev: wp.array(dtype=wp.vec3),
        ctx: FrameContext,
        out_pos: wp.array2d(dtype=wp.vec3),
        out_normal: wp.array2d(dtype=wp.vec3),
        out_depth: wp.array2d(dtype=float),
        out_face: wp.array2d(dtype=wp.int32),
        out_hit: wp.array2d(dtype=wp.uint8),
        out_reproj: wp.array2d(dtype=wp.vec2),
        out_prev_dist: wp.array2d(dtype=float),
        out_moved: wp.array2d(dtype=wp.uint8),
        out_albedo: wp.array2d(dtype=wp.vec3),
        out_material: wp.array2d(dtype=wp.vec4h),
        out_emission: wp.array2d(dtype=wp.vec3),
        wlog2: int,
        row0: int,
    ):
        """The full-resolution G-buffer of a textured scene: pixel (x, y) through its centre, a one-pixel cone;
        ``wlog2`` the tiles launch's block width, log2 (the per-pixel launch ignores it)."""
        x = int(0)
        y = int(0)
        if wp.static(tiles):
            p = tile_order_pixel(wp.tid() + row0, out_depth.shape[1], wlog2)  # band offset: a range of threads
            x = p[0]
            y = p[1]
            if x >= out_depth.shape[1] or y >= out_depth.shape[0]:
                return
        else:
            y, x = wp.tid()
            y += row0  # band offset (foveawarp.parallel)
        trace_primary_textured(mesh, sd, env, has_env, points_prev, ctx.cam, ctx.cam_prev, ctx.max_t,
                               float(x) + 0.5, float(y) + 0.5, 1.0, y, x, out_pos, out_normal, out_depth, out_face,
                               out_hit, out_reproj, out_prev_dist, out_moved, out_albedo, out_material,
                               out_emission)

    return gbuffer_textured


gbuffer_textured_kernel = _make_gbuffer_textured(False)
gbuffer_textured_tiles_kernel = _make_gbuffer_textured(True)


@wp.kernel(enable_backward=False)
def split_material_kernel(material: wp.array2d(dtype=wp.vec4h), out_roughness: wp.array2d(dtype=float),
                          out_metallic: wp.array2d(dtype=float)):
    """``GBuffer.roughness`` and ``GBuffer.metallic`` from the packed ``GBuffer.material``."""
    y, x = wp.tid()
    m = material[y, x]
    out_roughness[y, x] = float(m[0])
    out_metallic[y, x] = float(m[1])


@wp.kernel(enable_backward=False)
def coarse_gbuffer_textured_kernel(
    mesh: wp.uint64,
    sd: SurfaceData,
    env: EnvironmentMap,
    has_env: int,
    points_prev: wp.array(dtype=wp.vec3),
    ctx: FrameContext,
    cell: int,
    out_pos: wp.array2d(dtype=wp.vec3),
    out_normal: wp.array2d(dtype=wp.vec3),
    out_depth: wp.array2d(dtype=float),
    out_face: wp.array2d(dtype=wp.int32),
    out_hit: wp.array2d(dtype=wp.uint8),
    out_reproj: wp.array2d(dtype=wp.vec2),
    out_prev_dist: wp.array2d(dtype=float),
    out_moved: wp.array2d(dtype=wp.uint8),
    out_albedo: wp.array2d(dtype=wp.vec3),
    out_material: wp.array2d(dtype=wp.vec4h),
    out_emission: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """The sparse mode's coarse G-buffer of a textured scene: one ray per cell through its middle pixel, its cone
    spread over the cell (``cell`` pixels: the texture pre-filtered at the cells' spacing)."""
    cy, cx = wp.tid()
    cy += row0  # band offset (foveawarp.parallel)
    px = float(cell_pixel(cx, cell, ctx.cam.width)) + 0.5
    py = float(cell_pixel(cy, cell, ctx.cam.height)) + 0.5
    trace_primary_textured(mesh, sd, env, has_env, points_prev, ctx.cam, ctx.cam_prev, ctx.max_t, px, py,
                           float(cell), cy, cx, out_pos, out_normal, out_depth, out_face, out_hit, out_reproj,
                           out_prev_dist, out_moved, out_albedo, out_material, out_emission)


@wp.func
def sample_footprint_px(probability: float) -> float:
    """The pixels a sample stands for at sampling probability ``probability``: its spacing ``1 / sqrt(p)`` (1 at
    p = 1; p raised to 1e-6, 1000 pixels)."""
    return 1.0 / wp.sqrt(wp.clamp(probability, 1.0e-6, 1.0))


@wp.kernel(enable_backward=False)
def trace_shade_textured_list_kernel(
    ctxa: wp.array(dtype=FrameContext),
    spa: wp.array(dtype=ShadeParams),
    tp: TexturedShadeParams,
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    mesh: wp.uint64,
    points_prev: wp.array(dtype=wp.vec3),
    probability: wp.array2d(dtype=float),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    g_pos: wp.array2d(dtype=wp.vec3),
    g_normal: wp.array2d(dtype=wp.vec3),
    g_depth: wp.array2d(dtype=float),
    g_face: wp.array2d(dtype=wp.int32),
    g_hit: wp.array2d(dtype=wp.uint8),
    g_reproj: wp.array2d(dtype=wp.vec2),
    g_prev_dist: wp.array2d(dtype=float),
    g_moved: wp.array2d(dtype=wp.uint8),
    g_albedo: wp.array2d(dtype=wp.vec3),
    g_material: wp.array2d(dtype=wp.vec4h),
    g_emission: wp.array2d(dtype=wp.vec3),
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """The sparse mode's sampled pixels of a textured scene (work[0:count[0]]): the primary ray into the
    full-resolution G-buffer, its cone spread over the sample's footprint (:func:`sample_footprint_px` of the
    pixel's sampling probability), then its shading, in one thread."""
    i = wp.tid() + row0  # band offset (foveawarp.parallel)
    if i >= count[0]:
        return
    sp = spa[0]
    pp = ctxa[0]
    x, y = list_pixel(work[i], sp.width)
    trace_primary_textured(mesh, tp.sd, tp.env, tp.has_env, points_prev, pp.cam, pp.cam_prev, pp.max_t,
                           float(x) + 0.5, float(y) + 0.5, sample_footprint_px(probability[y, x]), y, x, g_pos,
                           g_normal, g_depth, g_face, g_hit, g_reproj, g_prev_dist, g_moved, g_albedo, g_material,
                           g_emission)
    shade_textured_pixel(sp, tp, x, y, g_pos, g_normal, g_albedo, g_material, g_emission, g_hit, lights,
                         area_lights, out, out_stoch)


@wp.kernel(enable_backward=False)
def coarse_saliency_lab_kernel(
    sp: SamplingParams,
    frame: wp.array(dtype=FrameParams),
    lab: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    position: wp.array2d(dtype=wp.vec3),
    reproj_uv: wp.array2d(dtype=wp.vec2),
    cell: int,
    width: int,
    height: int,
    out: wp.array2d(dtype=float),
    row0: int,
):
    """``kernels.sparse.coarse_saliency_kernel`` of a textured scene: the dA term's Sobel taps read the coarse
    G-buffer's per-entry CIE-Lab albedo (``lab``, the textured base colour converted by ``saliency.lab_kernel``)
    instead of a per-face table."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    fp = frame[0]
    s = float(0.0)
    if sp.use_albedo != 0:
        s = wp.max(s, wp.min(sp.albedo_gain * sobel_vec3(lab, x, y), 1.0))
    if sp.use_normal != 0 and s < 1.0:
        s = wp.max(s, wp.min(sp.normal_gain * sobel_vec3(normal, x, y), 1.0))
    if hit[y, x] != wp.uint8(0) and fp.use_velocity != 0 and s < 1.0:
        v = saliency_velocity(fp, position, y, x, reproj_uv[y, x], float(cell_pixel(x, cell, width)) + 0.5,
                              float(cell_pixel(y, cell, height)) + 0.5)
        s = wp.max(s, wp.min(wp.length(v) * sp.inv_velocity_px, 1.0))
    out[y, x] = s
