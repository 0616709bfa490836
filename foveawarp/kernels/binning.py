"""Primary rays by screen bins: each triangle listed in the 8 x 8-pixel bins its projection can cover, and each
pixel's ray tested against its bin's list only (a screen-space grid as the primary rays' acceleration structure,
the ray-traced counterpart of the thesis's rasterized G-buffer).

The hits are those of ``wp.mesh_query_ray``'s triangle test (Warp's watertight ``intersect_ray_tri_woop``: the
same operations in the same order, its per-ray part computed once per ray), kept when ``0 <= t < max_t`` and
nearer than the nearest so far; among hits at the same distance the lowest face index is kept (the BVH keeps the
first its walk finds). A bin's list holds every triangle whose ray-hit region can reach one of the bin's pixel
centres (the projected triangle clipped to the half-space in front of the eye, widened by ``MARGIN_PX``), so the
nearest hit over the list is the nearest hit over the mesh. A bin with more triangles than its list holds
(``cap``) is traced by ``wp.mesh_query_ray`` instead, as is every pixel of a frame whose binning did not run.

Launches per frame (``stages.gbuffer``): a memset of the bin counts and of the large-triangle count, one thread
per triangle (small triangles list themselves; those covering more than ``SMALL_BINS`` bins are queued), the
queued triangles by blocks of threads, and the pixels.
"""

import warp as wp

from .camera import CameraParams

BIN_LOG2 = wp.constant(3)
BIN = 8  # bin edge in pixels (the "tiles" order's 8 x 4 warps lie inside one bin)
MARGIN_PX = wp.constant(1.0)  # the projected bounds are widened by this much (rounding of the projection)
SMALL_BINS = wp.constant(8)  # a triangle covering at most this many bins lists itself; larger ones are queued
BIG_THREADS = 128  # threads per queued triangle


@wp.func
def _extend_inf(lo: wp.vec2, hi: wp.vec2, x: float, y: float):
    """Bounds (pixels) widened towards the point at infinity in view direction (x, y) (a point of the triangle on
    the eye's plane): +x is screen right, +y is screen up (smaller rows)."""
    if x > 0.0:
        hi = wp.vec2(1.0e30, hi[1])
    elif x < 0.0:
        lo = wp.vec2(-1.0e30, lo[1])
    if y > 0.0:
        lo = wp.vec2(lo[0], -1.0e30)
    elif y < 0.0:
        hi = wp.vec2(hi[0], 1.0e30)
    return lo, hi


@wp.func
def tri_bin_rect(cam: CameraParams, a: wp.vec3, b: wp.vec3, c: wp.vec3, tiles_x: int, tiles_y: int) -> wp.vec4i:
    """The bins (tx0, ty0, tx1, ty1), inclusive, whose pixel centres the primary rays of ``cam`` can hit triangle
    (a, b, c) through; tx1 < tx0 when none. The triangle's part in front of the eye (view z >= 0) projects into the
    convex hull of its projected vertices with z > 0 and, for its points on the eye's plane (z = 0), rays to
    infinity in their view directions; the bounds are that hull's, widened by ``MARGIN_PX`` and clipped to the
    screen. A triangle with a non-finite view coordinate, or one touching the eye's plane with no vertex in front,
    gets the whole screen (conservative)."""
    w = float(cam.width)
    h = float(cam.height)
    kx = 0.5 * w / (cam.tan_half_fov_y * cam.aspect)
    ky = 0.5 * h / cam.tan_half_fov_y
    da = a - cam.eye
    db = b - cam.eye
    dc = c - cam.eye
    xa = wp.dot(da, cam.right)
    ya = wp.dot(da, cam.up)
    za = wp.dot(da, cam.forward)
    xb = wp.dot(db, cam.right)
    yb = wp.dot(db, cam.up)
    zb = wp.dot(db, cam.forward)
    xc = wp.dot(dc, cam.right)
    yc = wp.dot(dc, cam.up)
    zc = wp.dot(dc, cam.forward)
    full = wp.vec4i(0, 0, tiles_x - 1, tiles_y - 1)
    s = xa + ya + za + xb + yb + zb + xc + yc + zc
    if not wp.isfinite(s):
        return full
    zmax = wp.max(za, wp.max(zb, zc))
    if zmax < 0.0:
        return wp.vec4i(0, 0, -1, -1)  # behind the eye: no ray reaches it at t >= 0
    if zmax == 0.0:
        return full  # on the eye's plane: only a hit at the eye itself (t = 0) is possible
    lo = wp.vec2(1.0e30, 1.0e30)
    hi = wp.vec2(-1.0e30, -1.0e30)
    # the vertices in front of the eye
    if za > 0.0:
        p = wp.vec2(wp.clamp(xa / za, -1.0e7, 1.0e7) * kx + 0.5 * w, 0.5 * h - wp.clamp(ya / za, -1.0e7, 1.0e7) * ky)
        lo = wp.min(lo, p)
        hi = wp.max(hi, p)
    if zb > 0.0:
        p = wp.vec2(wp.clamp(xb / zb, -1.0e7, 1.0e7) * kx + 0.5 * w, 0.5 * h - wp.clamp(yb / zb, -1.0e7, 1.0e7) * ky)
        lo = wp.min(lo, p)
        hi = wp.max(hi, p)
    if zc > 0.0:
        p = wp.vec2(wp.clamp(xc / zc, -1.0e7, 1.0e7) * kx + 0.5 * w, 0.5 * h - wp.clamp(yc / zc, -1.0e7, 1.0e7) * ky)
        lo = wp.min(lo, p)
        hi = wp.max(hi, p)
    # edges from a vertex in front to one not in front cross the eye's plane: a point at infinity
    eye_hit = False
    if (za > 0.0) != (zb > 0.0):
        t = za / (za - zb)
        ex = xa + (xb - xa) * t
        ey = ya + (yb - ya) * t
        eye_hit = eye_hit or (ex == 0.0 and ey == 0.0)
        lo, hi = _extend_inf(lo, hi, ex, ey)
    if (zb > 0.0) != (zc > 0.0):
        t = zb / (zb - zc)
        ex = xb + (xc - xb) * t
        ey = yb + (yc - yb) * t
        eye_hit = eye_hit or (ex == 0.0 and ey == 0.0)
        lo, hi = _extend_inf(lo, hi, ex, ey)
    if (zc > 0.0) != (za > 0.0):
        t = zc / (zc - za)
        ex = xc + (xa - xc) * t
        ey = yc + (ya - yc) * t
        eye_hit = eye_hit or (ex == 0.0 and ey == 0.0)
        lo, hi = _extend_inf(lo, hi, ex, ey)
    if eye_hit:
        return full  # the triangle passes through the eye
    # pixels whose centre (x + 0.5) lies in [lo - margin, hi + margin]
    x0f = wp.clamp(lo[0] - MARGIN_PX - 0.5, -1.0, w)
    x1f = wp.clamp(hi[0] + MARGIN_PX - 0.5, -1.0, w)
    y0f = wp.clamp(lo[1] - MARGIN_PX - 0.5, -1.0, h)
    y1f = wp.clamp(hi[1] + MARGIN_PX - 0.5, -1.0, h)
    x0 = wp.max(int(wp.ceil(x0f)), 0)
    x1 = wp.min(int(wp.floor(x1f)), cam.width - 1)
    y0 = wp.max(int(wp.ceil(y0f)), 0)
    y1 = wp.min(int(wp.floor(y1f)), cam.height - 1)
    if x0 > x1 or y0 > y1:
        return wp.vec4i(0, 0, -1, -1)
    return wp.vec4i(x0 >> BIN_LOG2, y0 >> BIN_LOG2, x1 >> BIN_LOG2, y1 >> BIN_LOG2)


@wp.func
def face_rect(points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), f: int, cam: CameraParams,
              tiles_x: int, tiles_y: int) -> wp.vec4i:
    return tri_bin_rect(cam, points[indices[f * 3 + 0]], points[indices[f * 3 + 1]], points[indices[f * 3 + 2]],
                        tiles_x, tiles_y)


@wp.func
def list_in_bin(t: int, f: int, cap: int, bin_count: wp.array(dtype=wp.int32), bin_faces: wp.array(dtype=wp.int32)):
    s = wp.atomic_add(bin_count, t, 1)
    if s < cap:
        bin_faces[t * cap + s] = f


@wp.kernel(enable_backward=False)
def bin_triangles_kernel(points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), cam: CameraParams,
                         tiles_x: int, tiles_y: int, cap: int, bin_count: wp.array(dtype=wp.int32),
                         bin_faces: wp.array(dtype=wp.int32), big_count: wp.array(dtype=wp.int32),
                         big_faces: wp.array(dtype=wp.int32)):
    """Thread f: triangle f listed in each bin of its rectangle (at most ``SMALL_BINS`` bins), or queued in
    ``big_faces`` (``big_count[0]`` of them)."""
    f = wp.tid()
    r = face_rect(points, indices, f, cam, tiles_x, tiles_y)
    if r[2] < r[0]:
        return
    nx = r[2] - r[0] + 1
    n = nx * (r[3] - r[1] + 1)
    if n > SMALL_BINS:
        big_faces[wp.atomic_add(big_count, 0, 1)] = f
        return
    for k in range(n):
        list_in_bin((r[1] + k / nx) * tiles_x + r[0] + k % nx, f, cap, bin_count, bin_faces)


@wp.kernel(enable_backward=False)
def bin_big_triangles_kernel(points: wp.array(dtype=wp.vec3), indices: wp.array(dtype=wp.int32), cam: CameraParams,
                             tiles_x: int, tiles_y: int, cap: int, groups: int, big_count: wp.array(dtype=wp.int32),
                             big_faces: wp.array(dtype=wp.int32), bin_count: wp.array(dtype=wp.int32),
                             bin_faces: wp.array(dtype=wp.int32)):
    """``groups`` groups of ``BIG_THREADS`` threads: group g lists queued triangles g, g + groups, ... in their
    bins, its threads taking the bins in turn."""
    i = wp.tid()
    g = i / BIG_THREADS
    lane = i - g * BIG_THREADS
    nb = big_count[0]
    for b in range(g, nb, groups):
        f = big_faces[b]
        r = face_rect(points, indices, f, cam, tiles_x, tiles_y)
        nx = r[2] - r[0] + 1
        n = nx * (r[3] - r[1] + 1)
        for k in range(lane, n, BIG_THREADS):
            list_in_bin((r[1] + k / nx) * tiles_x + r[0] + k % nx, f, cap, bin_count, bin_faces)


# the nearest hit of ray (eye, d) over faces list[begin : begin + n], as (t, u, v, face bits): Warp's
# intersect_ray_tri_woop with its per-ray part (axes, shear) once per ray; face -1 (its bits) on a miss
_BIN_HIT = """
    wp::Mesh mesh = wp::mesh_get(mesh_id);
    int kz = wp::max_dim(d);
    int kx = kz + 1;
    if (kx == 3) kx = 0;
    int ky = kx + 1;
    if (ky == 3) ky = 0;
    if (d[kz] < 0.0f) { const int tmp = kx; kx = ky; ky = tmp; }
    const float Sx = d[kx] / d[kz];
    const float Sy = d[ky] / d[kz];
    const float Sz = 1.0f / d[kz];
    float best = max_t;
    int bf = -1;
    float bu = 0.0f, bv = 0.0f;
    const int* lst = (const int*)faces.data + begin;
    for (int j = 0; j < n; ++j) {
        const int f = lst[j];
        const wp::vec3 A = mesh.points[mesh.indices[f * 3 + 0]] - eye;
        const wp::vec3 B = mesh.points[mesh.indices[f * 3 + 1]] - eye;
        const wp::vec3 C = mesh.points[mesh.indices[f * 3 + 2]] - eye;
        const float Ax = A[kx] - Sx * A[kz];
        const float Ay = A[ky] - Sy * A[kz];
        const float Bx = B[kx] - Sx * B[kz];
        const float By = B[ky] - Sy * B[kz];
        const float Cx = C[kx] - Sx * C[kz];
        const float Cy = C[ky] - Sy * C[kz];
        float U = wp::diff_product(Cx, By, Cy, Bx);
        float V = wp::diff_product(Ax, Cy, Ay, Cx);
        float W = wp::diff_product(Bx, Ay, By, Ax);
        if (U == 0.0f || V == 0.0f || W == 0.0f) {
            U = (float)((double)Cx * (double)By - (double)Cy * (double)Bx);
            V = (float)((double)Ax * (double)Cy - (double)Ay * (double)Cx);
            W = (float)((double)Bx * (double)Ay - (double)By * (double)Ax);
        }
        if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f)) continue;
        const float det = U + V + W;
        if (det == 0.0f) continue;
        const float Az = Sz * A[kz];
        const float Bz = Sz * B[kz];
        const float Cz = Sz * C[kz];
        const float T = U * Az + V * Bz + W * Cz;
        if (wp::xorf(T, wp::sign_mask(det)) < 0.0f) continue;
        const float rcp = 1.0f / det;
        const float tt = T * rcp;
        if (tt >= 0.0f && (tt < best || (tt == best && bf >= 0 && f < bf))) {
            best = tt;
            bf = f;
            bu = U * rcp;
            bv = V * rcp;
        }
    }
    union { int i; float f; } fb;
    fb.i = bf;
    return wp::vec4(best, bu, bv, fb.f);
"""


@wp.func_native(_BIN_HIT)
def bin_nearest_hit(mesh_id: wp.uint64, eye: wp.vec3, d: wp.vec3, max_t: float, faces: wp.array(dtype=wp.int32),
                    begin: int, n: int) -> wp.vec4:
    """(t, u, v, face bits) of the nearest hit of ray (eye, d) among faces ``faces[begin : begin + n]``
    (``face_of`` decodes the face: -1 on a miss, t is then ``max_t``)."""
    ...


@wp.func_native("""
    union { float f; int i; } b;
    b.f = v;
    return b.i;
""")
def face_of(v: float) -> int:
    """The face index stored in the last component of :func:`bin_nearest_hit`'s result."""
    ...


@wp.func_native("""
    wp::Mesh mesh = wp::mesh_get(mesh_id);
    const wp::vec3 a = mesh.points[mesh.indices[f * 3 + 0]];
    const wp::vec3 b = mesh.points[mesh.indices[f * 3 + 1]];
    const wp::vec3 c = mesh.points[mesh.indices[f * 3 + 2]];
    return wp::normalize(wp::cross(b - a, c - a));
""")
def face_unit_normal(mesh_id: wp.uint64, f: int) -> wp.vec3:
    """The unit normal ``wp.mesh_query_ray`` gives a hit on face ``f`` (its operations)."""
    ...
