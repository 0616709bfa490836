"""Pinhole camera as a Warp struct, with primary-ray generation and world -> pixel projection."""

import warp as wp


@wp.struct
class CameraParams:
    eye: wp.vec3
    right: wp.vec3  # unit, screen +x
    up: wp.vec3  # unit, screen -y (row 0 is the top)
    forward: wp.vec3  # unit, view direction
    tan_half_fov_y: float
    aspect: float  # width / height
    width: int
    height: int


@wp.func
def camera_ray_dir(cam: CameraParams, px: float, py: float) -> wp.vec3:
    """Unit direction through the continuous pixel position (px, py); pixel centres are at (x + 0.5, y + 0.5)."""
    sx = (2.0 * px / float(cam.width) - 1.0) * cam.tan_half_fov_y * cam.aspect
    sy = (1.0 - 2.0 * py / float(cam.height)) * cam.tan_half_fov_y
    return wp.normalize(cam.forward + sx * cam.right + sy * cam.up)


@wp.func
def camera_project(cam: CameraParams, p: wp.vec3) -> wp.vec3:
    """World point -> (px, py, z_view). z_view <= 0 means behind the eye (px, py are then 0)."""
    d = p - cam.eye
    z = wp.dot(d, cam.forward)
    if z <= 1.0e-20:
        return wp.vec3(0.0, 0.0, z)
    sx = wp.dot(d, cam.right) / (z * cam.tan_half_fov_y * cam.aspect)
    sy = wp.dot(d, cam.up) / (z * cam.tan_half_fov_y)
    px = (sx + 1.0) * 0.5 * float(cam.width)
    py = (1.0 - sy) * 0.5 * float(cam.height)
    return wp.vec3(px, py, z)
