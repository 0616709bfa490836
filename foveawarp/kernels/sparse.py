"""Sparse G-buffer mode (issue 14): primary rays only where they are needed.

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

from .camera import CameraParams, camera_ray_dir
from .gbuffer import trace_primary, write_miss, write_surface
from .saliency import sobel_lab_by_face, sobel_vec3
from .sampling import FrameParams, SamplingParams, dither_sample, pixel_probability, saliency_velocity
from .shade import AreaLightParams, LightParams, ShadeParams, shade_pixel


@wp.struct
class PrimaryParams:
    """Per-frame primary-ray constants of the sampled pixels, read on the device (a captured graph sees each
    frame's camera)."""

    cam: CameraParams
    cam_prev: CameraParams
    max_t: float


@wp.func
def cell_pixel(c: int, cell: int, n: int) -> int:
    """The pixel (column or row) whose centre the primary ray of cell ``c`` passes through: the cell's middle
    pixel, clamped to the image for the partial cells at the right/bottom edges."""
    return wp.min(c * cell + cell / 2, n - 1)


@wp.kernel(enable_backward=False)
def set_primary_params_kernel(pp: PrimaryParams, out: wp.array(dtype=PrimaryParams)):
    out[0] = pp


@wp.kernel(enable_backward=False)
def coarse_gbuffer_kernel(
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    points_prev: wp.array(dtype=wp.vec3),
    vnormals: wp.array(dtype=wp.vec3),
    smooth: wp.array(dtype=wp.uint8),
    face_albedo: wp.array(dtype=wp.vec3),
    cam: CameraParams,
    cam_prev: CameraParams,
    max_t: float,
    cell: int,
    out_pos: wp.array2d(dtype=wp.vec3),
    out_normal: wp.array2d(dtype=wp.vec3),
    out_depth: wp.array2d(dtype=float),
    out_albedo: wp.array2d(dtype=wp.vec3),
    out_face: wp.array2d(dtype=wp.int32),
    out_hit: wp.array2d(dtype=wp.uint8),
    out_velocity: wp.array2d(dtype=wp.vec2),
    out_reproj: wp.array2d(dtype=wp.vec2),
    out_prev_dist: wp.array2d(dtype=float),
    out_moved: wp.array2d(dtype=wp.uint8),
    row0: int,
):
    """One primary ray per cell (through its middle pixel's centre), written at the cell's entry."""
    cy, cx = wp.tid()
    cy += row0  # band offset (foveawarp.parallel)
    px = float(cell_pixel(cx, cell, cam.width)) + 0.5
    py = float(cell_pixel(cy, cell, cam.height)) + 0.5
    trace_primary(mesh, indices, points_prev, vnormals, smooth, face_albedo, cam, cam_prev, max_t, px, py, cy, cx,
                  out_pos, out_normal, out_depth, out_albedo, out_face, out_hit, out_velocity, out_reproj,
                  out_prev_dist, out_moved)


@wp.kernel(enable_backward=False)
def coarse_saliency_kernel(
    sp: SamplingParams,
    frame: wp.array(dtype=FrameParams),
    face: wp.array2d(dtype=wp.int32),
    face_lab: wp.array(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    velocity: wp.array2d(dtype=wp.vec2),
    position: wp.array2d(dtype=wp.vec3),
    reproj_uv: wp.array2d(dtype=wp.vec2),
    out: wp.array2d(dtype=float),
    row0: int,
):
    """max(dA, dN, V) of thesis eq. 3 per cell (each term clipped to [0, 1]; 0 when all are off)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    fp = frame[0]
    s = float(0.0)
    if sp.use_albedo != 0:
        s = wp.max(s, wp.min(sp.albedo_gain * sobel_lab_by_face(face, face_lab, x, y), 1.0))
    if sp.use_normal != 0 and s < 1.0:
        s = wp.max(s, wp.min(sp.normal_gain * sobel_vec3(normal, x, y), 1.0))
    if hit[y, x] != wp.uint8(0) and fp.use_velocity != 0 and s < 1.0:
        v = saliency_velocity(fp, velocity[y, x], position[y, x], reproj_uv[y, x])
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
        if wp.isnan(s):
            s = 1.0
    out_probability[y, x] = p
    out_saliency[y, x] = s
    out_sample[y, x] = dither_sample(s, x, y, w, h, ranks, sp, fp.rot, fp.phase)


@wp.kernel(enable_backward=False)
def trace_shade_list_kernel(
    ppa: wp.array(dtype=PrimaryParams),
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
    g_albedo: wp.array2d(dtype=wp.vec3),
    g_face: wp.array2d(dtype=wp.int32),
    g_hit: wp.array2d(dtype=wp.uint8),
    g_velocity: wp.array2d(dtype=wp.vec2),
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
    pp = ppa[0]
    sp = spa[0]
    idx = work[i]
    y = idx // sp.width
    x = idx - y * sp.width
    trace_primary(mesh, indices, points_prev, vnormals, smooth, face_albedo, pp.cam, pp.cam_prev, pp.max_t,
                  float(x) + 0.5, float(y) + 0.5, y, x, g_pos, g_normal, g_depth, g_albedo, g_face, g_hit,
                  g_velocity, g_reproj, g_prev_dist, g_moved)
    shade_pixel(sp, x, y, g_pos, g_normal, g_albedo, g_face, g_hit, lights, area_lights, face_emission, out,
                out_stoch)


# the refined mode's smooth-surface test (upsample_gbuffer_kernel): a coarse corner agrees with the reference plane
# when its traced depth is within this fraction of the depth its ray has on that plane ...
REFINE_DEPTH_TOL = 0.005
# ... its normal is within this cosine of the reference normal, its albedo within this of the reference albedo in
# every channel (the sampling map's albedo term must see edges of colour: an eye chart's letters lie on one plane) ...
REFINE_NORMAL_COS = 0.95
REFINE_ALBEDO_TOL = 0.02
# ... and no ray (the pixel's or a corner's) meets the plane at a grazing angle: |cos| of ray and normal above this
REFINE_GRAZE_COS = 0.02


@wp.func
def quad_lo(p: int, cell: int, n_cells: int, n: int) -> int:
    """The lower of the two coarse cells whose rays bracket pixel ``p`` (column or row): the cell of the last
    coarse ray at or before the pixel's centre, 0 before the first."""
    c = p / cell
    if c > n_cells - 1:
        c = n_cells - 1
    if cell_pixel(c, cell, n) > p and c > 0:
        c = c - 1
    return c


@wp.func
def corner_agrees(eye: wp.vec3, k0: float, n0: wp.vec3, a0: wp.vec3, pos: wp.vec3, normal: wp.vec3, albedo: wp.vec3,
                  hit: wp.uint8, moved: wp.uint8, depth_tol: float, normal_cos: float, albedo_tol: float) -> int:
    """1 when a coarse corner lies on the reference plane {X : dot(X - eye, n0) = k0} with the reference albedo
    ``a0``: a static hit whose normal is within ``normal_cos`` of ``n0``, whose albedo is within ``albedo_tol`` of
    ``a0`` in every channel, and whose ray, met with the plane, lands within ``depth_tol`` of its depth."""
    if hit == wp.uint8(0) or moved != wp.uint8(0):
        return 0
    if wp.dot(normal, n0) < normal_cos:
        return 0
    da = albedo - a0
    if wp.max(wp.max(wp.abs(da[0]), wp.abs(da[1])), wp.abs(da[2])) > albedo_tol:
        return 0
    di = pos - eye
    ti = wp.length(di)
    den = wp.dot(di, n0)  # ti * cos(ray, n0)
    if not (den < -REFINE_GRAZE_COS * ti):
        return 0
    # the plane meets this corner's ray at k0 / cos = ti * k0 / den: within depth_tol * ti of ti
    if not (wp.abs(k0 / den - 1.0) <= depth_tol):
        return 0
    return 1


@wp.kernel(enable_backward=False)
def upsample_gbuffer_kernel(
    cam: CameraParams,
    cam_prev: CameraParams,
    max_t: float,
    cell: int,
    depth_tol: float,
    normal_cos: float,
    albedo_tol: float,
    c_pos: wp.array2d(dtype=wp.vec3),
    c_normal: wp.array2d(dtype=wp.vec3),
    c_albedo: wp.array2d(dtype=wp.vec3),
    c_face: wp.array2d(dtype=wp.int32),
    c_hit: wp.array2d(dtype=wp.uint8),
    c_moved: wp.array2d(dtype=wp.uint8),
    out_pos: wp.array2d(dtype=wp.vec3),
    out_normal: wp.array2d(dtype=wp.vec3),
    out_depth: wp.array2d(dtype=float),
    out_albedo: wp.array2d(dtype=wp.vec3),
    out_face: wp.array2d(dtype=wp.int32),
    out_hit: wp.array2d(dtype=wp.uint8),
    out_velocity: wp.array2d(dtype=wp.vec2),
    out_reproj: wp.array2d(dtype=wp.vec2),
    out_prev_dist: wp.array2d(dtype=float),
    out_moved: wp.array2d(dtype=wp.uint8),
    out_traced: wp.array2d(dtype=wp.uint8),
    row0: int,
):
    """The full-resolution G-buffer of the refined mode from the coarse one (``coarse_gbuffer_kernel``).

    Pixel (x, y) looks at the four coarse rays that bracket its centre. When all four missed, the pixel is a
    miss. When all four hit one smooth static surface of one colour (every corner agrees, ``corner_agrees``, with the plane
    through the pixel's own cell's hit and normal) and the pixel's ray meets that plane at a non-grazing angle,
    the entry is the plane's: position and depth where the pixel's ray meets it, the corners' normals blended
    bilinearly, albedo and face of the own cell's hit, reprojection of that position (static: it is its own
    previous position). Anywhere else (an edge, a crease, object motion, a hit next to a miss) ``out_traced`` is
    set to 1 and the entry is left for ``gbuffer_list_kernel``, which traces the pixel's own primary ray: exactly
    the full mode's entry."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    cw = c_hit.shape[1]
    ch = c_hit.shape[0]
    cx0 = quad_lo(x, cell, cw, cam.width)
    cy0 = quad_lo(y, cell, ch, cam.height)
    cx1 = wp.min(cx0 + 1, cw - 1)
    cy1 = wp.min(cy0 + 1, ch - 1)
    px = float(x) + 0.5
    py = float(y) + 0.5
    h00 = c_hit[cy0, cx0]
    h01 = c_hit[cy0, cx1]
    h10 = c_hit[cy1, cx0]
    h11 = c_hit[cy1, cx1]
    nhit = int(h00) + int(h01) + int(h10) + int(h11)
    if nhit == 0:
        write_miss(max_t, y, x, out_pos, out_normal, out_depth, out_albedo, out_face, out_hit, out_velocity,
                   out_reproj, out_prev_dist, out_moved)
        out_traced[y, x] = wp.uint8(0)
        return
    ok = int(0)
    d = camera_ray_dir(cam, px, py)
    # the reference plane: the own cell's hit and normal
    ox = wp.min(x / cell, cw - 1)
    oy = wp.min(y / cell, ch - 1)
    t = float(0.0)
    n0 = c_normal[oy, ox]
    if nhit == 4:
        p0 = c_pos[oy, ox]
        a0 = c_albedo[oy, ox]
        k0 = wp.dot(p0 - cam.eye, n0)
        c = wp.dot(d, n0)
        if c < -REFINE_GRAZE_COS:
            t = k0 / c
            if t > 0.0 and t < max_t:
                ok = (corner_agrees(cam.eye, k0, n0, a0, c_pos[cy0, cx0], c_normal[cy0, cx0], c_albedo[cy0, cx0],
                                    h00, c_moved[cy0, cx0], depth_tol, normal_cos, albedo_tol)
                      * corner_agrees(cam.eye, k0, n0, a0, c_pos[cy0, cx1], c_normal[cy0, cx1], c_albedo[cy0, cx1],
                                      h01, c_moved[cy0, cx1], depth_tol, normal_cos, albedo_tol)
                      * corner_agrees(cam.eye, k0, n0, a0, c_pos[cy1, cx0], c_normal[cy1, cx0], c_albedo[cy1, cx0],
                                      h10, c_moved[cy1, cx0], depth_tol, normal_cos, albedo_tol)
                      * corner_agrees(cam.eye, k0, n0, a0, c_pos[cy1, cx1], c_normal[cy1, cx1], c_albedo[cy1, cx1],
                                      h11, c_moved[cy1, cx1], depth_tol, normal_cos, albedo_tol))
    if ok == 0:
        out_traced[y, x] = wp.uint8(1)  # gbuffer_list_kernel traces it (a thread per listed pixel: no divergence)
        return
    # bilinear weights between the bracketing rays' pixel centres (clamped: one ray at the image's edges)
    ax0 = float(cell_pixel(cx0, cell, cam.width)) + 0.5
    ax1 = float(cell_pixel(cx1, cell, cam.width)) + 0.5
    ay0 = float(cell_pixel(cy0, cell, cam.height)) + 0.5
    ay1 = float(cell_pixel(cy1, cell, cam.height)) + 0.5
    wx = float(0.0)
    if ax1 > ax0:
        wx = wp.clamp((px - ax0) / (ax1 - ax0), 0.0, 1.0)
    wy = float(0.0)
    if ay1 > ay0:
        wy = wp.clamp((py - ay0) / (ay1 - ay0), 0.0, 1.0)
    nb = (c_normal[cy0, cx0] * ((1.0 - wx) * (1.0 - wy)) + c_normal[cy0, cx1] * (wx * (1.0 - wy))
          + c_normal[cy1, cx0] * ((1.0 - wx) * wy) + c_normal[cy1, cx1] * (wx * wy))
    ln = wp.length(nb)
    n = n0
    if ln > 1.0e-6:
        n = nb / ln
        if wp.dot(n, d) >= 0.0:
            n = n0
    p = cam.eye + d * t
    write_surface(cam_prev, px, py, y, x, p, p, n, t, c_face[oy, ox], c_albedo[oy, ox], out_pos, out_normal,
                  out_depth, out_albedo, out_face, out_hit, out_velocity, out_reproj, out_prev_dist, out_moved)
    out_traced[y, x] = wp.uint8(0)


@wp.kernel(enable_backward=False)
def gbuffer_list_kernel(
    ppa: wp.array(dtype=PrimaryParams),
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    skip: wp.array2d(dtype=wp.uint8),
    use_skip: int,
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    points_prev: wp.array(dtype=wp.vec3),
    vnormals: wp.array(dtype=wp.vec3),
    smooth: wp.array(dtype=wp.uint8),
    face_albedo: wp.array(dtype=wp.vec3),
    out_pos: wp.array2d(dtype=wp.vec3),
    out_normal: wp.array2d(dtype=wp.vec3),
    out_depth: wp.array2d(dtype=float),
    out_albedo: wp.array2d(dtype=wp.vec3),
    out_face: wp.array2d(dtype=wp.int32),
    out_hit: wp.array2d(dtype=wp.uint8),
    out_velocity: wp.array2d(dtype=wp.vec2),
    out_reproj: wp.array2d(dtype=wp.vec2),
    out_prev_dist: wp.array2d(dtype=float),
    out_moved: wp.array2d(dtype=wp.uint8),
    row0: int,
):
    """The full mode's G-buffer entry (``trace_primary`` through the pixel centre, cameras from ``ppa[0]``) of
    the flat pixel indices work[0:count[0]], except (``use_skip`` != 0) those where ``skip`` is nonzero."""
    i = wp.tid()
    i += row0  # band offset (foveawarp.parallel)
    if i >= count[0]:
        return
    w = out_depth.shape[1]
    idx = work[i]
    y = idx // w
    x = idx - y * w
    if use_skip != 0:
        if skip[y, x] != wp.uint8(0):
            return
    pp = ppa[0]
    trace_primary(mesh, indices, points_prev, vnormals, smooth, face_albedo, pp.cam, pp.cam_prev, pp.max_t,
                  float(x) + 0.5,
                  float(y) + 0.5, y, x, out_pos, out_normal, out_depth, out_albedo, out_face, out_hit, out_velocity,
                  out_reproj, out_prev_dist, out_moved)
