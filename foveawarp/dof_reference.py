"""Thin-lens ray-traced depth-of-field reference, and the pixel-scatter vs reference comparison.

Lens model (how the reference matches the scatter's circle of confusion)
----------------------------------------------------------------------
The scatter blurs a point at view depth Z over a disc of diameter (ALGORITHMS.md B)

    C(Z) = E F |Z - Z_f| / (Z (Z_f - F)) * px_per_m        pixels.

The tracer puts a lens disc of world diameter A centred on the eye in the camera's (right, up) plane and aims
every ray from a lens point a at the point of the focal plane (view depth Z_f) seen through the pixel centre.
By similar triangles a scene point at view depth Z is then seen from lens point a displaced by
``f_px a (Z - Z_f) / (Z Z_f)`` pixels, at every pixel of the screen, where ``f_px = (H / 2) / tan(fov_y / 2)``
is the pinhole focal length in pixels. Its on-screen blur is a disc of diameter ``f_px A |Z - Z_f| / (Z Z_f)``.
Equating both diameters gives the world aperture the tracer uses:

    A = E F px_per_m Z_f / (f_px (Z_f - F))                 metres  (:func:`thin_lens_aperture_m`).

Depths here are view depths (along the view axis), as in the thin-lens model; the G-buffer's distances are
converted with the camera's field of view. The reference is not clamped to ``max_coc_px``.
Rays start at pixel centres (no pixel jitter, as the G-buffer), so with A = 0 it is the pinhole render.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Optional

import numpy as np
import warp as wp

from . import parallel
from .camera import Camera
from .config import Config, DofConfig, check_int_range
from .kernels.dof import FOCUS_FAR_M, FOCUS_MIN_REL, thin_lens_kernel
from .kernels.tonemap import tonemap_kernel

__all__ = ["thin_lens_aperture_m", "render_thin_lens", "render_dof_comparison", "resolve_focus_m",
           "COMPARISON_VARIANTS", "DEFAULT_COMPARISON_DOF"]

# the lens of render_dof_comparison / render_thin_lens when none is given: focus at the gaze depth; a point
# 2 m nearer or farther than a 4 m focus gets a CoC of about 10 px (clamped at 16 px in the scatter)
DEFAULT_COMPARISON_DOF = DofConfig(aperture_m=0.05, focal_length_m=0.05, focus_depth_m=None, px_per_m=20000.0,
                                   max_coc_px=16.0)

# image name -> (foreground_fix, background_fix) of the scatter variants in render_dof_comparison
COMPARISON_VARIANTS = {
    "scatter": (False, False),
    "scatter_fg_fix": (True, False),
    "scatter_bg_fix": (False, True),
    "corrected": (True, True),
}


def thin_lens_aperture_m(dof_config: DofConfig, focus_depth_m: float, fov_y_deg: float, height: int) -> float:
    """World-space lens diameter (metres) whose ray-traced blur matches the scatter's CoC in pixels
    (module docstring): ``E F px_per_m Z_f / (f_px (Z_f - F))``, ``f_px = (height / 2) / tan(fov_y / 2)``.
    ``focus_depth_m`` is clamped into (F, 1e30] as on the device."""
    c = dof_config
    f = float(c.focal_length_m)
    zf = min(max(float(focus_depth_m), f * (1.0 + float(FOCUS_MIN_REL))), float(FOCUS_FAR_M))
    f_px = 0.5 * float(height) / math.tan(math.radians(float(fov_y_deg)) * 0.5)
    return float(c.aperture_m) * f * float(c.px_per_m) * (zf / (zf - f)) / f_px


def _as_loop(loop_or_scene, width: int, height: int, device):
    from .frame_loop import FrameLoop

    if isinstance(loop_or_scene, FrameLoop):
        loop = loop_or_scene
        if (loop.width, loop.height) != (int(width), int(height)):
            raise ValueError(f"width, height ({width}, {height}) must match the FrameLoop's "
                             f"({loop.width}, {loop.height})")
        if device is not None and wp.get_device(device) != loop.device:
            raise ValueError(f"device {device!r} must be the FrameLoop's device {loop.device}")
        return loop
    return FrameLoop(loop_or_scene, width, height, config=Config(), device=device, timing=False)


def _max_t(loop, camera: Camera) -> float:
    lo, hi = loop.scene.bounds
    far = float(np.linalg.norm(np.asarray(camera.eye) - (lo + hi) * 0.5)) + loop.scene.extent
    return float(min(max(2.0 * far, 1.0), 1.0e30))


def resolve_focus_m(loop_or_scene, camera: Camera, dof_config: DofConfig, *, gaze_px=None, width=None,
                    height=None, device=None) -> float:
    """The focus view depth in metres: ``dof_config.focus_depth_m``, or the view depth at the gaze pixel
    (screen centre when None) of a pinhole G-buffer render (1e30 m where that pixel misses)."""
    if dof_config.focus_depth_m is not None:
        return float(dof_config.focus_depth_m)
    from .stages.dof import DofStage

    w = width if width is not None else getattr(loop_or_scene, "width", None)
    h = height if height is not None else getattr(loop_or_scene, "height", None)
    if w is None or h is None:
        raise ValueError("width and height are needed when loop_or_scene is not a FrameLoop")
    loop = _as_loop(loop_or_scene, w, h, device)
    loop.render_reference(camera, dof=False)
    stage = DofStage(loop.width, loop.height, dof_config, loop.device)
    gaze = (loop.width * 0.5, loop.height * 0.5) if gaze_px is None else gaze_px
    stage.focus_at_pixel(loop.gbuffer.depth, loop.gbuffer.hit, gaze, fov_y_deg=camera.fov_y_deg)
    return float(stage.focus_m.numpy()[0])


def render_thin_lens(loop_or_scene, camera: Camera, width: int, height: int,
                     dof_config: Optional[DofConfig] = None, samples: int = 64, device=None, *, gaze_px=None,
                     return_hdr: bool = False):
    """Distributed ray tracing through a thin lens (module docstring) with ``samples`` lens rays per pixel,
    shaded with the FrameLoop's ``shade_point`` (direct light, shadows, ambient, AO when configured) and tone
    mapped. The light quad-tree's indirect term (``ShadingConfig.indirect="lighttree"``) is not traced.

    Args:
        loop_or_scene: a FrameLoop of size (width, height) (its scene, shading config and device are used),
            or a Scene / scene name (a FrameLoop with the default Config is built).
        camera: the pinhole camera whose eye is the lens centre.
        width, height: image size in pixels.
        dof_config: aperture, focal length, px_per_m and focus (focus None: the view depth at ``gaze_px``);
            None uses :data:`DEFAULT_COMPARISON_DOF`.
        samples: lens samples per pixel, in [1, 4096]; ``samples * width * height`` must stay below 2^31.
        return_hdr: also return the linear radiance.

    Returns:
        (H, W, 3) float32 display-referred image in [0, 1] (and the (H, W, 3) linear radiance with
        ``return_hdr``).
    """
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a foveawarp.Camera, got {type(camera).__name__}")
    if dof_config is None:
        dof_config = DEFAULT_COMPARISON_DOF
    if not isinstance(dof_config, DofConfig):
        raise ValueError(f"dof_config must be a foveawarp.DofConfig, got {type(dof_config).__name__}")
    samples = check_int_range("samples", samples, 1, 4096)
    loop = _as_loop(loop_or_scene, width, height, device)
    from .surface import is_textured

    if is_textured(loop.dscene):
        raise ValueError(f"render_thin_lens shades with per-face colours and point / area lights only: scene "
                         f"{loop.dscene.scene.name!r} has materials (textures, glTF BSDF); use an untextured scene")
    w, h = loop.width, loop.height
    if samples * w * h >= 2**31:
        raise ValueError(f"samples * width * height must be below 2^31, got {samples} * {w} * {h}")
    focus = resolve_focus_m(loop, camera, dof_config, gaze_px=gaze_px)
    focus = min(max(focus, dof_config.focal_length_m * (1.0 + float(FOCUS_MIN_REL))), float(FOCUS_FAR_M))
    lens_radius = 0.5 * thin_lens_aperture_m(dof_config, focus, camera.fov_y_deg, h)
    ds, sc, dev = loop.dscene, loop.config.shading, loop.device
    hdr = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    disp = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    parallel.launch(thin_lens_kernel, dim=(h, w),
                    inputs=[loop.shade_params(camera), camera.params(w, h), float(lens_radius), float(focus), samples,
                            _max_t(loop, camera), ds.mesh.id, ds.indices, ds.vertex_normals, ds.face_smooth,
                            ds.face_albedo, ds.lights, ds.area_lights, ds.face_emission, float(sc.exposure),
                            float(sc.white_point)],
                    outputs=[hdr, disp], device=dev)
    img = disp.numpy().reshape(h, w, 3)
    if return_hdr:
        return img, hdr.numpy().reshape(h, w, 3)
    return img


def render_dof_comparison(loop_or_scene, camera: Camera, width: int, height: int,
                          dof_config: Optional[DofConfig] = None, samples: int = 64, device=None, *, gaze_px=None,
                          method: str = "gather") -> dict:
    """Display-referred (H, W, 3) float32 images of one view, keyed by name:

    - ``pinhole``: the FrameLoop's reference render (no depth of field);
    - ``scatter``: the pixel scatter with no correction; ``scatter_fg_fix``: foreground fix only;
      ``scatter_bg_fix``: background fix only; ``corrected``: both fixes;
    - ``thin_lens``: the ray-traced reference (:func:`render_thin_lens`) with ``samples`` lens rays.

    The scatter runs on the linear radiance with the G-buffer's depth (converted to view depth) and is then
    tone mapped, as the reference averages radiance before its tone map. Focus: ``dof_config.focus_depth_m``
    or the view depth at ``gaze_px`` (screen centre when None). ``dof_config`` None uses
    :data:`DEFAULT_COMPARISON_DOF`. The loop's own DoF setting is not used (``render_reference(dof=False)``):
    the comparison applies ``dof_config`` itself.
    """
    from .stages.dof import DofStage

    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a foveawarp.Camera, got {type(camera).__name__}")
    if dof_config is None:
        dof_config = DEFAULT_COMPARISON_DOF
    if not isinstance(dof_config, DofConfig):
        raise ValueError(f"dof_config must be a foveawarp.DofConfig, got {type(dof_config).__name__}")
    loop = _as_loop(loop_or_scene, width, height, device)
    w, h, dev = loop.width, loop.height, loop.device
    focus = resolve_focus_m(loop, camera, dof_config, gaze_px=gaze_px)
    cfg = replace(dof_config, focus_depth_m=focus)
    frame = loop.render_reference(camera, dof=False)
    images = {"pinhole": frame.numpy().copy()}
    sc = loop.config.shading
    out_hdr = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    out_disp = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    g = loop.gbuffer
    for name, (fg, bg) in COMPARISON_VARIANTS.items():
        stage = DofStage(w, h, replace(cfg, foreground_fix=fg, background_fix=bg), dev, method=method)
        stage.run(loop.radiance, g.depth, g.hit, None, out_hdr, fov_y_deg=camera.fov_y_deg)
        parallel.launch(tonemap_kernel, dim=(h, w), inputs=[out_hdr, float(sc.exposure), float(sc.white_point)],
                        outputs=[out_disp], device=dev)
        images[name] = out_disp.numpy().reshape(h, w, 3).copy()
    images["thin_lens"] = render_thin_lens(loop, camera, w, h, cfg, samples)
    return images
