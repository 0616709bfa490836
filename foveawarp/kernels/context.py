"""The frame context: one struct of the per-frame view constants that every stage reads, and its wp.funcs.

A frame's context holds this frame's camera, the previous frame's (the one reprojection refers to; this frame's
own on the first frame or after a cut), the primary rays' length, the gaze and the frame index. It is packed once
per frame on the host (``foveawarp/frame_context.py``) and passed by value to the head's launches, or copied to a
(1,) device array (``set_frame_context_kernel``) for launches that keep fixed arguments (a captured graph).
"""

import warp as wp

from .camera import CameraParams, camera_project, camera_ray_dir


@wp.struct
class FrameContext:
    cam: CameraParams  # this frame's camera at the frame's width and height
    cam_prev: CameraParams  # the previous frame's camera (reprojection); this frame's after a cut
    max_t: float  # primary ray length, past the whole scene from this frame's eye
    gaze: wp.vec2  # gaze in pixels, clamped to the screen's surroundings (sampling.clamp_gaze)
    frame: int  # the loop's frame index, >= 0


@wp.func
def context_ray_dir(ctx: FrameContext, px: float, py: float) -> wp.vec3:
    """Unit direction of this frame's ray through the continuous pixel position (px, py)."""
    return camera_ray_dir(ctx.cam, px, py)


@wp.func
def pixel_centre_ray_dir(ctx: FrameContext, x: int, y: int) -> wp.vec3:
    """Unit direction of this frame's ray through the centre of pixel (x, y)."""
    return camera_ray_dir(ctx.cam, float(x) + 0.5, float(y) + 0.5)


@wp.func
def project_prev(ctx: FrameContext, p: wp.vec3) -> wp.vec3:
    """World point -> (px, py, z_view) in the previous frame's camera (``camera_project``)."""
    return camera_project(ctx.cam_prev, p)


@wp.kernel(enable_backward=False)
def set_frame_context_kernel(ctx: FrameContext, out: wp.array(dtype=FrameContext)):
    out[0] = ctx
