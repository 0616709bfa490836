"""The host side of the frame context (kernels/context.py): the per-frame view constants, packed once per frame.

:class:`FrameContextBuilder` keeps one :class:`~foveawarp.kernels.context.FrameContext` struct per loop and
re-packs it for each frame from the cameras, the gaze, the frame index and the primary rays' length;
:meth:`FrameContextBuilder.build` returns a :class:`FrameView`: the struct that the stages' launches take, with
the same values on the host (the cameras, the clamped gaze) for the stages whose launches take them one by one.
"""

from __future__ import annotations

from typing import NamedTuple

import warp as wp

from ._util import check_image_size
from .camera import Camera, _check_gaze
from .config import check_int_range, check_range, show
from .kernels.context import FrameContext
from .stages.sampling import clamp_gaze

__all__ = ["FrameContextBuilder", "FrameView"]

class FrameView(NamedTuple):
    """One frame's context: ``struct`` (the FrameContext the launches take; the builder re-packs it for the next
    frame) and the same values on the host."""

    struct: FrameContext
    camera: Camera  # this frame's camera
    prev_camera: Camera  # the previous frame's (reprojection); ``camera`` on the first frame or after a cut
    gaze: tuple  # (x, y) pixels, clamped (``stages.sampling.clamp_gaze``)
    frame_index: int
    max_t: float  # primary ray length


class FrameContextBuilder:
    """Packs the frame context of ``width`` x ``height`` frames; :meth:`build` once per frame."""

    def __init__(self, width: int, height: int):
        self.width, self.height = check_image_size(width, height)
        self.struct = FrameContext()

    def build(self, camera: Camera, prev_camera: Camera, gaze_px, frame_index: int, max_t: float) -> FrameView:
        """The context of the frame of ``camera`` (reprojection against ``prev_camera``), with the gaze at
        ``gaze_px`` ((x, y) pixels, finite; clamped), ``frame_index`` >= 0 and primary rays ``max_t`` long (> 0)."""
        for name, c in (("camera", camera), ("prev_camera", prev_camera)):
            if not isinstance(c, Camera):
                raise ValueError(f"{name} must be a foveawarp.Camera, got {show(c)} ({type(c).__name__})")
        if type(frame_index) is not int:
            frame_index = check_int_range("frame_index", frame_index, 0, None)
        elif frame_index < 0:
            raise ValueError(f"frame_index must be an integer >= 0, got {frame_index}")
        if type(max_t) is not float or not 0.0 < max_t < float("inf"):
            max_t = check_range("max_t", max_t, 0.0, None, lo_open=True)
        w, h = self.width, self.height
        gaze = clamp_gaze(_check_gaze(gaze_px), w, h)
        s = self.struct
        s.cam = camera.params(w, h)
        s.cam_prev = prev_camera.params(w, h)
        s.max_t = max_t
        s.gaze = wp.vec2(gaze[0], gaze[1])
        s.frame = frame_index
        return FrameView(s, camera, prev_camera, gaze, frame_index, max_t)
