"""G-buffer: one primary ray per pixel against the scene BVH (thesis A1, traced instead of rasterized)."""

import warp as wp

from .camera import CameraParams, camera_project, camera_ray_dir
from .context import FrameContext, pixel_centre_ray_dir
from .load import (load1_i32, load1_u8, load1_vec3, load_f32, load_i32, load_vec2, load_vec3, store_f32, store_i32,
                   store_u8, store_vec2, store_vec3)
from .order import tile_order_pixel
from .packet import PACKET, trace_packet_row

# reprojection UV of pixels with no previous position (miss, or behind the previous eye)
NO_REPROJ = -1.0e4


@wp.func
def shading_normal(mesh: wp.uint64, face: int, u: float, v: float, face_n: wp.vec3,
                   vnormals: wp.array(dtype=wp.vec3), smooth: wp.array(dtype=wp.uint8),
                   indices: wp.array(dtype=wp.int32)) -> wp.vec3:
    """The shading normal at barycentrics (u, v) of a hit on ``face``: ``face_n`` (facing the viewer), or on a
    smooth face the interpolated vertex normals, kept on ``face_n``'s side."""
    n = face_n
    if smooth[face] != wp.uint8(0):
        n = smooth_normal(face_n, u, v, vnormals[indices[face * 3 + 0]], vnormals[indices[face * 3 + 1]],
                          vnormals[indices[face * 3 + 2]])
    return n


@wp.func
def smooth_normal(face_n: wp.vec3, u: float, v: float, n0: wp.vec3, n1: wp.vec3, n2: wp.vec3) -> wp.vec3:
    """:func:`shading_normal` of a smooth face with vertex normals n0, n1, n2."""
    n = face_n
    s = n0 * u + n1 * v + n2 * (1.0 - u - v)
    ls = wp.length(s)
    if ls > 1.0e-12:
        s = s / ls
        # keep the interpolated normal on the geometric normal's side
        if wp.dot(s, face_n) > 0.0:
            n = s
    return n


@wp.func
def cell_pixel(c: int, cell: int, n: int) -> int:
    """The pixel (column or row) whose centre the primary ray of G-buffer entry ``c`` passes through: the entry's
    own pixel at full resolution (``cell`` 1); in the sparse mode's coarse G-buffer the cell's middle pixel,
    clamped to the image for the partial cells at the right/bottom edges."""
    return wp.min(c * cell + cell / 2, n - 1)


@wp.func
def reproj_velocity(uv: wp.vec2, px: float, py: float) -> wp.vec2:
    """The screen velocity (pixels moved since the previous frame: current - previous position) of the primary
    hit traced through (px, py) whose reprojection is ``uv``: (px, py) - uv, or 0 where it has none
    (``NO_REPROJ``: a miss, or a point behind the previous eye). The same operations on the same float32 values
    as when the G-buffer stored the velocity, so the same bits, but for a point whose previous position is
    exactly (-1e4, -1e4) pixels, which reads as none."""
    if uv[0] == NO_REPROJ and uv[1] == NO_REPROJ:
        return wp.vec2(0.0, 0.0)
    return wp.vec2(px - uv[0], py - uv[1])


@wp.func
def surface_albedo(face_albedo: wp.array(dtype=wp.vec3), f: int) -> wp.vec3:
    """The albedo of the primary hit on face ``f`` (``GBuffer.face``): the scene's per-face albedo, 0 on a miss
    (f < 0)."""
    if f < 0:
        return wp.vec3(0.0, 0.0, 0.0)
    return face_albedo[f]


@wp.func
def pixel_albedo(textured: int, albedo: wp.array2d(dtype=wp.vec3), face_albedo: wp.array(dtype=wp.vec3),
                 face: wp.array2d(dtype=wp.int32), y: int, x: int) -> wp.vec3:
    """Pixel (y, x)'s albedo: a textured G-buffer's stored base colour (texture x factor; ``albedo``), else
    :func:`surface_albedo` of its face."""
    if textured != 0:
        return albedo[y, x]
    return surface_albedo(face_albedo, face[y, x])


@wp.func
def primary_normal(face_normal: wp.vec3, d: wp.vec3, face: int, u: float, v: float, i0: int, i1: int, i2: int,
                   vnormals: wp.array(dtype=wp.vec3), smooth: wp.array(dtype=wp.uint8)) -> wp.vec3:
    """The G-buffer normal of a primary hit along ``d`` at barycentrics (u, v) of ``face`` (vertices i0, i1, i2):
    the unit face normal turned to face the viewer, or on a smooth face the interpolated vertex normals, kept on its
    side (:func:`smooth_normal`). ``face`` and the vertices index the mesh: unchecked loads (kernels/load.py)."""
    fn = face_normal
    if wp.dot(fn, d) > 0.0:
        fn = -fn  # face the viewer
    n = fn
    if load1_u8(smooth, face) != wp.uint8(0):
        n = smooth_normal(fn, u, v, load1_vec3(vnormals, i0), load1_vec3(vnormals, i1), load1_vec3(vnormals, i2))
    return n


@wp.func
def store_surface(y: int, x: int, p: wp.vec3, n: wp.vec3, t: float, face: int, hit: wp.uint8,
                  out_pos: wp.array2d(dtype=wp.vec3), out_normal: wp.array2d(dtype=wp.vec3),
                  out_depth: wp.array2d(dtype=float), out_face: wp.array2d(dtype=wp.int32),
                  out_hit: wp.array2d(dtype=wp.uint8)):
    """The surface fields of G-buffer entry [y, x] (an entry of the outputs: unchecked stores): position, normal,
    depth, face and hit."""
    store_vec3(out_pos, y, x, p)
    store_vec3(out_normal, y, x, n)
    store_f32(out_depth, y, x, t)
    store_i32(out_face, y, x, face)
    store_u8(out_hit, y, x, hit)


@wp.func
def trace_primary(
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    points_prev: wp.array(dtype=wp.vec3),
    vnormals: wp.array(dtype=wp.vec3),
    smooth: wp.array(dtype=wp.uint8),
    cam: CameraParams,
    cam_prev: CameraParams,
    max_t: float,
    px: float,
    py: float,
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
):
    """Trace the primary ray through the continuous pixel position (px, py) and write its G-buffer entry at
    [y, x] of the output arrays (the full-resolution G-buffer writes pixel (x, y) through its own centre; the
    coarse one of the sparse mode writes one entry per cell). The albedo and the screen velocity are not stored:
    they follow from the face (:func:`surface_albedo`) and the reprojection (:func:`reproj_velocity`), exactly."""
    d = camera_ray_dir(cam, px, py)
    q = wp.mesh_query_ray(mesh, cam.eye, d, max_t)
    write_primary(mesh, indices, points_prev, vnormals, smooth, cam, cam_prev, max_t, d, q.result, q.t, q.face,
                  q.u, q.v, q.normal, y, x, out_pos, out_normal, out_depth, out_face, out_hit, out_reproj,
                  out_prev_dist, out_moved)


@wp.func
def write_primary(
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    points_prev: wp.array(dtype=wp.vec3),
    vnormals: wp.array(dtype=wp.vec3),
    smooth: wp.array(dtype=wp.uint8),
    cam: CameraParams,
    cam_prev: CameraParams,
    max_t: float,
    d: wp.vec3,
    result: bool,
    t: float,
    face: int,
    u: float,
    v: float,
    face_normal: wp.vec3,
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
):
    """The G-buffer entry at [y, x] of the primary ray ``d`` from the eye with the closest hit (``result``, ``t``,
    ``face``, ``u``, ``v``, unit ``face_normal``) of ``wp.mesh_query_ray`` (or the packet walk of
    kernels/packet.py, which gives the same)."""
    if result:
        # face is a face of the mesh and (y, x) an entry of the outputs: the unchecked loads and stores of
        # kernels/load.py (the same values; the kernel is instruction bound)
        p = cam.eye + d * t
        i0 = load1_i32(indices, face * 3 + 0)
        i1 = load1_i32(indices, face * 3 + 1)
        i2 = load1_i32(indices, face * 3 + 2)
        n = primary_normal(face_normal, d, face, u, v, i0, i1, i2, vnormals, smooth)
        # the same surface point at the previous frame's vertex positions (object motion)
        pp = load1_vec3(points_prev, i0) * u + load1_vec3(points_prev, i1) * v + load1_vec3(points_prev, i2) * (
            1.0 - u - v)
        pr = camera_project(cam_prev, pp)
        store_f32(out_prev_dist, y, x, wp.length(pp - cam_prev.eye))
        # the surface point itself moved (object motion): its lighting may have changed too
        moved = wp.uint8(0)
        if wp.length(pp - p) > 1.0e-6 * t + 1.0e-7:
            moved = wp.uint8(1)
        store_u8(out_moved, y, x, moved)
        uv = wp.vec2(NO_REPROJ, NO_REPROJ)
        if pr[2] > 0.0:
            uv = wp.vec2(pr[0], pr[1])
        store_surface(y, x, p, n, t, face, wp.uint8(1), out_pos, out_normal, out_depth, out_face, out_hit)
        store_vec2(out_reproj, y, x, uv)
    else:
        store_surface(y, x, wp.vec3(0.0, 0.0, 0.0), wp.vec3(0.0, 0.0, 0.0), max_t, -1, wp.uint8(0), out_pos,
                      out_normal, out_depth, out_face, out_hit)
        store_vec2(out_reproj, y, x, wp.vec2(NO_REPROJ, NO_REPROJ))
        store_f32(out_prev_dist, y, x, 0.0)
        store_u8(out_moved, y, x, wp.uint8(0))


def _make_gbuffer(mode: str):
    """``gbuffer_kernel`` (mode "pixels": a thread per pixel), ``gbuffer_rows_kernel`` ("rows": a thread per row,
    the CPU: ``parallel.launch_rows``) or ``gbuffer_tiles_kernel`` ("tiles": a thread per pixel, warps on 8 x 4
    blocks, CUDA: ``kernels/order.py``)."""
    rows = mode == "rows"
    tiles = mode == "tiles"

    @wp.kernel(enable_backward=False, name=f"gbuffer_{mode}_kernel" if mode != "pixels" else "gbuffer_kernel")
    def gbuffer(
        mesh: wp.uint64,
        indices: wp.array(dtype=wp.int32),
        points_prev: wp.array(dtype=wp.vec3),
        vnormals: wp.array(dtype=wp.vec3),
        smooth: wp.array(dtype=wp.uint8),
        ctx: FrameContext,
        out_pos: wp.array2d(dtype=wp.vec3),
        out_normal: wp.array2d(dtype=wp.vec3),
        out_depth: wp.array2d(dtype=float),
        out_face: wp.array2d(dtype=wp.int32),
        out_hit: wp.array2d(dtype=wp.uint8),
        out_reproj: wp.array2d(dtype=wp.vec2),
        out_prev_dist: wp.array2d(dtype=float),
        out_moved: wp.array2d(dtype=wp.uint8),
        wlog2: int,
        row0: int,
    ):
        """``ctx``: the frame context (cameras, ray length); ``wlog2``: the "tiles" launch's block width, log2
        (``kernels/order.py``); the other modes ignore it."""
        cam = ctx.cam
        cam_prev = ctx.cam_prev
        max_t = ctx.max_t
        if wp.static(rows):
            # the row's rays in packets of 8 (kernels/packet.py: the same hits as wp.mesh_query_ray). The row of
            # out_pos holds the directions, and the packets' hits go to out_depth, out_face, out_reproj (u, v)
            # and out_normal (the unit face normal) until write_primary replaces them with the entries
            y = wp.tid() + row0  # band offset (foveawarp.parallel)
            w = out_depth.shape[1]
            for x in range(w):
                store_vec3(out_pos, y, x, pixel_centre_ray_dir(ctx, x, y))
            for x0 in range(0, w, PACKET):
                trace_packet_row(mesh, cam.eye, max_t, out_pos, y, x0, w - x0, out_depth, out_face, out_reproj,
                                 out_normal)
            for x in range(w):
                f = load_i32(out_face, y, x)
                uv = load_vec2(out_reproj, y, x)
                write_primary(mesh, indices, points_prev, vnormals, smooth, cam, cam_prev, max_t,
                              load_vec3(out_pos, y, x), f >= 0, load_f32(out_depth, y, x), f, uv[0], uv[1],
                              load_vec3(out_normal, y, x), y, x, out_pos, out_normal, out_depth, out_face, out_hit,
                              out_reproj, out_prev_dist, out_moved)
        elif wp.static(tiles):
            p = tile_order_pixel(wp.tid() + row0, out_depth.shape[1], wlog2)  # band offset: a range of threads
            x = p[0]
            y = p[1]
            if x < out_depth.shape[1] and y < out_depth.shape[0]:
                trace_primary(mesh, indices, points_prev, vnormals, smooth, cam, cam_prev, max_t,
                              float(x) + 0.5, float(y) + 0.5, y, x, out_pos, out_normal, out_depth,
                              out_face, out_hit, out_reproj, out_prev_dist, out_moved)
        else:
            y, x = wp.tid()
            y += row0  # band offset (foveawarp.parallel)
            trace_primary(mesh, indices, points_prev, vnormals, smooth, cam, cam_prev, max_t,
                          float(x) + 0.5, float(y) + 0.5, y, x, out_pos, out_normal, out_depth, out_face,
                          out_hit, out_reproj, out_prev_dist, out_moved)

    return gbuffer


gbuffer_kernel = _make_gbuffer("pixels")
gbuffer_rows_kernel = _make_gbuffer("rows")
gbuffer_tiles_kernel = _make_gbuffer("tiles")


@wp.kernel(enable_backward=False)
def derive_velocity_kernel(reproj_uv: wp.array2d(dtype=wp.vec2), cell: int, width: int, height: int,
                           out: wp.array2d(dtype=wp.vec2)):
    """``GBuffer.velocity``: :func:`reproj_velocity` of each entry, traced through the centre of pixel
    (``cell_pixel(x, cell, width)``, ``cell_pixel(y, cell, height)``)."""
    y, x = wp.tid()
    out[y, x] = reproj_velocity(reproj_uv[y, x], float(cell_pixel(x, cell, width)) + 0.5,
                                float(cell_pixel(y, cell, height)) + 0.5)


@wp.kernel(enable_backward=False)
def derive_albedo_kernel(face: wp.array2d(dtype=wp.int32), face_albedo: wp.array(dtype=wp.vec3),
                         out: wp.array2d(dtype=wp.vec3)):
    """``GBuffer.albedo``: :func:`surface_albedo` of each entry."""
    y, x = wp.tid()
    out[y, x] = surface_albedo(face_albedo, face[y, x])
