"""G-buffer: one primary ray per pixel against the scene BVH (thesis A1, traced instead of rasterized)."""

import warp as wp

from .camera import CameraParams, camera_project, camera_ray_dir
from .order import tile_order_pixel

# reprojection UV of pixels with no previous position (miss, or behind the previous eye)
NO_REPROJ = -1.0e4


@wp.func
def shading_normal(mesh: wp.uint64, face: int, u: float, v: float, face_n: wp.vec3,
                   vnormals: wp.array(dtype=wp.vec3), smooth: wp.array(dtype=wp.uint8),
                   indices: wp.array(dtype=wp.int32)) -> wp.vec3:
    n = face_n
    if smooth[face] != wp.uint8(0):
        i0 = indices[face * 3 + 0]
        i1 = indices[face * 3 + 1]
        i2 = indices[face * 3 + 2]
        s = vnormals[i0] * u + vnormals[i1] * v + vnormals[i2] * (1.0 - u - v)
        ls = wp.length(s)
        if ls > 1.0e-12:
            s = s / ls
            # keep the interpolated normal on the geometric normal's side
            if wp.dot(s, face_n) > 0.0:
                n = s
    return n


@wp.func
def trace_primary(
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    points_prev: wp.array(dtype=wp.vec3),
    vnormals: wp.array(dtype=wp.vec3),
    smooth: wp.array(dtype=wp.uint8),
    face_albedo: wp.array(dtype=wp.vec3),
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
    out_albedo: wp.array2d(dtype=wp.vec3),
    out_face: wp.array2d(dtype=wp.int32),
    out_hit: wp.array2d(dtype=wp.uint8),
    out_velocity: wp.array2d(dtype=wp.vec2),
    out_reproj: wp.array2d(dtype=wp.vec2),
    out_prev_dist: wp.array2d(dtype=float),
    out_moved: wp.array2d(dtype=wp.uint8),
):
    """Trace the primary ray through the continuous pixel position (px, py) and write its G-buffer entry at
    [y, x] of the output arrays (the full-resolution G-buffer writes pixel (x, y) through its own centre; the
    coarse one of the sparse mode writes one entry per cell)."""
    d = camera_ray_dir(cam, px, py)
    q = wp.mesh_query_ray(mesh, cam.eye, d, max_t)
    if q.result:
        p = cam.eye + d * q.t
        fn = q.normal
        if wp.dot(fn, d) > 0.0:
            fn = -fn  # face the viewer
        n = shading_normal(mesh, q.face, q.u, q.v, fn, vnormals, smooth, indices)
        i0 = indices[q.face * 3 + 0]
        i1 = indices[q.face * 3 + 1]
        i2 = indices[q.face * 3 + 2]
        # the same surface point at the previous frame's vertex positions (object motion)
        pp = points_prev[i0] * q.u + points_prev[i1] * q.v + points_prev[i2] * (1.0 - q.u - q.v)
        pr = camera_project(cam_prev, pp)
        out_prev_dist[y, x] = wp.length(pp - cam_prev.eye)
        # the surface point itself moved (object motion): its lighting may have changed too
        moved = wp.uint8(0)
        if wp.length(pp - p) > 1.0e-6 * q.t + 1.0e-7:
            moved = wp.uint8(1)
        out_moved[y, x] = moved
        uv = wp.vec2(NO_REPROJ, NO_REPROJ)
        vel = wp.vec2(0.0, 0.0)
        if pr[2] > 0.0:
            uv = wp.vec2(pr[0], pr[1])
            vel = wp.vec2(px - pr[0], py - pr[1])
        out_pos[y, x] = p
        out_normal[y, x] = n
        out_depth[y, x] = q.t
        out_albedo[y, x] = face_albedo[q.face]
        out_face[y, x] = q.face
        out_hit[y, x] = wp.uint8(1)
        out_velocity[y, x] = vel
        out_reproj[y, x] = uv
    else:
        out_pos[y, x] = wp.vec3(0.0, 0.0, 0.0)
        out_normal[y, x] = wp.vec3(0.0, 0.0, 0.0)
        out_depth[y, x] = max_t
        out_albedo[y, x] = wp.vec3(0.0, 0.0, 0.0)
        out_face[y, x] = -1
        out_hit[y, x] = wp.uint8(0)
        out_velocity[y, x] = wp.vec2(0.0, 0.0)
        out_reproj[y, x] = wp.vec2(NO_REPROJ, NO_REPROJ)
        out_prev_dist[y, x] = 0.0
        out_moved[y, x] = wp.uint8(0)


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
        face_albedo: wp.array(dtype=wp.vec3),
        cam: CameraParams,
        cam_prev: CameraParams,
        max_t: float,
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
        wlog2: int,
        row0: int,
    ):
        """``wlog2``: the "tiles" launch's block width, log2 (``kernels/order.py``); the other modes ignore it."""
        if wp.static(rows):
            y = wp.tid() + row0  # band offset (foveawarp.parallel)
            for x in range(out_depth.shape[1]):
                trace_primary(mesh, indices, points_prev, vnormals, smooth, face_albedo, cam, cam_prev, max_t,
                              float(x) + 0.5, float(y) + 0.5, y, x, out_pos, out_normal, out_depth, out_albedo,
                              out_face, out_hit, out_velocity, out_reproj, out_prev_dist, out_moved)
        elif wp.static(tiles):
            p = tile_order_pixel(wp.tid() + row0, out_depth.shape[1], wlog2)  # band offset: a range of threads
            x = p[0]
            y = p[1]
            if x < out_depth.shape[1] and y < out_depth.shape[0]:
                trace_primary(mesh, indices, points_prev, vnormals, smooth, face_albedo, cam, cam_prev, max_t,
                              float(x) + 0.5, float(y) + 0.5, y, x, out_pos, out_normal, out_depth, out_albedo,
                              out_face, out_hit, out_velocity, out_reproj, out_prev_dist, out_moved)
        else:
            y, x = wp.tid()
            y += row0  # band offset (foveawarp.parallel)
            trace_primary(mesh, indices, points_prev, vnormals, smooth, face_albedo, cam, cam_prev, max_t,
                          float(x) + 0.5, float(y) + 0.5, y, x, out_pos, out_normal, out_depth, out_albedo, out_face,
                          out_hit, out_velocity, out_reproj, out_prev_dist, out_moved)

    return gbuffer


gbuffer_kernel = _make_gbuffer("pixels")
gbuffer_rows_kernel = _make_gbuffer("rows")
gbuffer_tiles_kernel = _make_gbuffer("tiles")
