"""Sparse G-buffer mode: primary rays only where they are needed.

A coarse G-buffer (one primary ray through the centre pixel of every ``cell`` x ``cell`` cell) feeds the saliency
terms of thesis eq. 3 at coarse resolution; the per-pixel sampling map combines them with the per-pixel
eccentricity probability (eq. 2) and binarizes with the same stratified threshold as the full mode; the sampled
pixels then trace their own primary ray and are shaded in the same thread. So the frame's primary rays scale
with the sampling rate (coarse cells + samples) instead of costing one per pixel.

Coarse saliency: the Sobel terms are taken over neighbouring *cells* (a unit step between two cells gives the
same response as between two pixels of the full mode), so an edge raises the probability of the cells on both
sides of it, a band of about ``2 cell`` pixels; velocity and the background rule are the full mode's, at the
cell's centre point.
"""

import warp as wp

from .context import FrameContext
from .fpbits import nan_f32
from .gbuffer import cell_pixel, trace_primary
from .saliency import sobel_lab_by_face, sobel_vec3
from .sampling import FrameParams, SamplingParams, dither_sample, pixel_probability, saliency_velocity
from .shade import AreaLightParams, LightParams, ShadeParams, list_pixel, shade_pixel


@wp.kernel(enable_backward=False)
def coarse_gbuffer_kernel(
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    points_prev: wp.array(dtype=wp.vec3),
    vnormals: wp.array(dtype=wp.vec3),
    smooth: wp.array(dtype=wp.uint8),
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
    row0: int,
):
    """One primary ray per cell (through its middle pixel's centre), written at the cell's entry."""
    cy, cx = wp.tid()
    cy += row0  # band offset (foveawarp.parallel)
    px = float(cell_pixel(cx, cell, ctx.cam.width)) + 0.5
    py = float(cell_pixel(cy, cell, ctx.cam.height)) + 0.5
    trace_primary(mesh, indices, points_prev, vnormals, smooth, ctx.cam, ctx.cam_prev, ctx.max_t, px, py, cy,
                  cx, out_pos, out_normal, out_depth, out_face, out_hit, out_reproj, out_prev_dist, out_moved)


@wp.kernel(enable_backward=False)
def coarse_saliency_kernel(
    sp: SamplingParams,
    frame: wp.array(dtype=FrameParams),
    face: wp.array2d(dtype=wp.int32),
    face_lab: wp.array(dtype=wp.vec3),
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
    """max(dA, dN, V) of thesis eq. 3 per cell (each term clipped to [0, 1]; 0 when all are off); ``cell``,
    ``width``, ``height``: the cell edge and the image size (the V term's ray passed through the cell's middle
    pixel, ``cell_pixel``)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    fp = frame[0]
    s = float(0.0)
    if sp.use_albedo != 0:
        s = wp.max(s, wp.min(sp.albedo_gain * sobel_lab_by_face(face, face_lab, x, y), 1.0))
    if sp.use_normal != 0 and s < 1.0:
        s = wp.max(s, wp.min(sp.normal_gain * sobel_vec3(normal, x, y), 1.0))
    if hit[y, x] != wp.uint8(0) and fp.use_velocity != 0 and s < 1.0:
        v = saliency_velocity(fp, position, y, x, reproj_uv[y, x], float(cell_pixel(x, cell, width)) + 0.5,
                              float(cell_pixel(y, cell, height)) + 0.5)
        s = wp.max(s, wp.min(wp.length(v) * sp.inv_velocity_px, 1.0))
    out[y, x] = s


@wp.kernel(enable_backward=False)
def sparse_sampling_kernel(
    sp: SamplingParams,
    frame: wp.array(dtype=FrameParams),
    ranks: wp.array2d(dtype=wp.int32),
    coarse_saliency: wp.array2d(dtype=float),
    cell: int,
    out_probability: wp.array2d(dtype=float),
    out_saliency: wp.array2d(dtype=float),
    out_sample: wp.array2d(dtype=wp.uint8),
    row0: int,
):
    """Per pixel: eq. 2 probability at the pixel, raised to its cell's saliency, clipped to [xi, 1], binarized
    with the full mode's stratified threshold (same block guarantee)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    fp = frame[0]
    w = out_sample.shape[1]
    h = out_sample.shape[0]
    p = float(1.0)
    s = float(1.0)
    if sp.foveation != 0:
        p = pixel_probability(x, y, w, h, sp, fp)
        s = p
        if s < 1.0:
            cy = wp.min(y / cell, coarse_saliency.shape[0] - 1)
            cx = wp.min(x / cell, coarse_saliency.shape[1] - 1)
            s = wp.max(s, coarse_saliency[cy, cx])
        s = wp.clamp(s, fp.xi, 1.0)
        if nan_f32(s):  # a bit test (kernels/fpbits.py)
            s = 1.0
    out_probability[y, x] = p
    out_saliency[y, x] = s
    out_sample[y, x] = dither_sample(s, x, y, w, h, ranks, sp, fp.rot, fp.phase)


@wp.kernel(enable_backward=False)
def trace_shade_list_kernel(
    ctxa: wp.array(dtype=FrameContext),
    spa: wp.array(dtype=ShadeParams),
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    points_prev: wp.array(dtype=wp.vec3),
    vnormals: wp.array(dtype=wp.vec3),
    smooth: wp.array(dtype=wp.uint8),
    face_albedo: wp.array(dtype=wp.vec3),
    lights: wp.array(dtype=LightParams),
    area_lights: wp.array(dtype=AreaLightParams),
    face_emission: wp.array(dtype=wp.vec3),
    g_pos: wp.array2d(dtype=wp.vec3),
    g_normal: wp.array2d(dtype=wp.vec3),
    g_depth: wp.array2d(dtype=float),
    g_face: wp.array2d(dtype=wp.int32),
    g_hit: wp.array2d(dtype=wp.uint8),
    g_reproj: wp.array2d(dtype=wp.vec2),
    g_prev_dist: wp.array2d(dtype=float),
    g_moved: wp.array2d(dtype=wp.uint8),
    out: wp.array2d(dtype=wp.vec3),
    out_stoch: wp.array2d(dtype=wp.vec3),
    row0: int,
):
    """For the flat pixel indices work[0:count[0]]: trace the pixel's primary ray into the full-resolution
    G-buffer (exactly the full mode's entry) and shade it, in one thread."""
    i = wp.tid()
    i += row0  # band offset (foveawarp.parallel)
    if i >= count[0]:
        return
    ctx = ctxa[0]
    sp = spa[0]
    x, y = list_pixel(work[i], sp.width)
    trace_primary(mesh, indices, points_prev, vnormals, smooth, ctx.cam, ctx.cam_prev, ctx.max_t,
                  float(x) + 0.5, float(y) + 0.5, y, x, g_pos, g_normal, g_depth, g_face, g_hit, g_reproj,
                  g_prev_dist, g_moved)
    shade_pixel(sp, x, y, g_pos, g_normal, face_albedo, g_face, g_hit, lights, area_lights, face_emission, out,
                out_stoch)
