"""Display composition for the live viewer: a tone-mapped frame (+ overlays) -> 8-bit RGB pixels.

Overlays (bits of ``flags``): 1 = sampling map tint, 2 = eccentricity rings every ``ring_deg`` degrees around the
gaze, 4 = error heat map against ``ref``, 8 = gaze marker. Eccentricity is the angle at the eye between the ray
through the gaze point and the ray through the pixel centre (pinhole camera, square pixels), as in
``ops.eccentricity_deg``.
"""

import warp as wp

FLAG_SAMPLING = 1
FLAG_RINGS = 2
FLAG_ERROR = 4
FLAG_GAZE = 8


@wp.func
def _cam_ray(px: float, py: float, w: float, h: float, tan_half_fov_y: float):
    # camera-space direction through the continuous pixel position (px, py); +z forward, +y up
    sx = (2.0 * px / w - 1.0) * tan_half_fov_y * (w / h)
    sy = (1.0 - 2.0 * py / h) * tan_half_fov_y
    return wp.normalize(wp.vec3(sx, sy, 1.0))


@wp.func
def _angle_deg(a: wp.vec3, b: wp.vec3):
    # atan2(|a x b|, a . b): accurate at small and large angles alike
    return wp.degrees(wp.atan2(wp.length(wp.cross(a, b)), wp.dot(a, b)))


@wp.func
def _clamp01(c: wp.vec3):
    r = c[0]
    g = c[1]
    b = c[2]
    # NaN fails every comparison and becomes 0
    if not (r >= 0.0):
        r = 0.0
    if not (g >= 0.0):
        g = 0.0
    if not (b >= 0.0):
        b = 0.0
    return wp.vec3(wp.min(r, 1.0), wp.min(g, 1.0), wp.min(b, 1.0))


@wp.kernel(enable_backward=False)
def compose_display_kernel(
    img: wp.array2d(dtype=wp.vec3),
    ref: wp.array2d(dtype=wp.vec3),
    smap: wp.array2d(dtype=wp.uint8),
    gaze: wp.vec2,
    tan_half_fov_y: float,
    ring_deg: float,
    err_gain: float,
    flags: int,
    x0: int,
    out: wp.array3d(dtype=wp.uint8),
    row0: int,
):
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    h = img.shape[0]
    w = img.shape[1]
    fw = float(w)
    fh = float(h)
    c = _clamp01(img[y, x])
    if (flags & 4) != 0:
        d = c - _clamp01(ref[y, x])
        e = wp.min((wp.abs(d[0]) + wp.abs(d[1]) + wp.abs(d[2])) * (err_gain / 3.0), 1.0)
        # black -> red -> yellow -> white
        heat = wp.vec3(wp.min(3.0 * e, 1.0), wp.clamp(3.0 * e - 1.0, 0.0, 1.0), wp.clamp(3.0 * e - 2.0, 0.0, 1.0))
        c = c * 0.25 + heat * 0.75
    if (flags & 1) != 0:
        if smap[y, x] != wp.uint8(0):
            c = c * 0.55 + wp.vec3(0.45, 0.05, 0.3)
        else:
            c = c * 0.7
    if (flags & 2) != 0 and ring_deg > 0.0:
        g = _cam_ray(gaze[0], gaze[1], fw, fh, tan_half_fov_y)
        fx = float(x) + 0.5
        fy = float(y) + 0.5
        e0 = wp.floor(_angle_deg(_cam_ray(fx, fy, fw, fh, tan_half_fov_y), g) / ring_deg)
        ex = wp.floor(_angle_deg(_cam_ray(fx + 1.0, fy, fw, fh, tan_half_fov_y), g) / ring_deg)
        ey = wp.floor(_angle_deg(_cam_ray(fx, fy + 1.0, fw, fh, tan_half_fov_y), g) / ring_deg)
        if e0 != ex or e0 != ey:
            c = c * 0.2 + wp.vec3(0.8, 0.8, 0.16)
    if (flags & 8) != 0:
        dx = float(x) + 0.5 - gaze[0]
        dy = float(y) + 0.5 - gaze[1]
        r = wp.sqrt(dx * dx + dy * dy)
        if r >= 5.0 and r < 7.0:
            c = wp.vec3(0.1, 1.0, 0.3)
    out[y, x0 + x, 0] = wp.uint8(int(c[0] * 255.0 + 0.5))
    out[y, x0 + x, 1] = wp.uint8(int(c[1] * 255.0 + 0.5))
    out[y, x0 + x, 2] = wp.uint8(int(c[2] * 255.0 + 0.5))
