"""The path integrator's converged reference: many independent path-traced passes accumulated, NumPy out."""

from __future__ import annotations

import dataclasses
from typing import Optional

import numpy as np
import warp as wp

from .. import parallel
from .._util import check_image_size, get_device
from ..camera import Camera
from ..config import ShadingConfig, check_choice, check_int_range
from ..kernels.path import accumulate_kernel
from ..stages.path import PathStage

__all__ = ["render_converged"]


def render_converged(scene, camera: Optional[Camera], width: int, height: int, spp_total: int, *, max_depth: int = 5,
                     seed: int = 0, device=None, rr_depth: int = 5, spp_per_pass: int = 64,
                     pixel_filter: str = "box", shading: Optional[ShadingConfig] = None) -> np.ndarray:
    """Path-traced linear radiance of every pixel, (H, W, 3) float32: the spp-weighted mean of
    ``ceil(spp_total / spp_per_pass)`` independent passes of :class:`foveawarp.stages.path.PathStage`, pass ``k``
    seeded by (``seed``, frame index ``k``), each of ``spp_per_pass`` paths per pixel (the last one the rest).

    Args:
        scene: a :class:`foveawarp.Scene` (uploaded here) or a :class:`foveawarp.scene.DeviceScene` on ``device``.
        camera: the camera; None: ``scene.camera``.
        width, height: the image size in pixels, in [1, 16384].
        spp_total: paths per pixel in all, in [1, 2^31 - 1].
        max_depth: Mitsuba 3's convention (1 emitters seen directly, 2 direct light, ...), in [1, 4096].
        seed: base seed of the random streams, in [0, 2^31 - 1].
        device: the Warp device (None: Warp's default).
        rr_depth: Russian roulette from this many bounces, in [1, 4096].
        spp_per_pass: paths per pixel of one launch, in [1, 65536].
        pixel_filter: "box" (each path through a uniform point of its pixel: the pixel's mean radiance) or
            "centre" (every path through the pixel centre).
        shading: the material and background fields (``specular``, ``shininess``, ``background``) come from it
            (None: ``ShadingConfig()``); its depth, seed and clamp fields are replaced by the arguments here, and
            the radiance clamp is off: the reference is unbiased.
    """
    width, height = check_image_size(width, height)
    spp_total = check_int_range("spp_total", spp_total, 1, 2**31 - 1)
    per_pass = check_int_range("spp_per_pass", spp_per_pass, 1, 65536)
    check_choice("pixel_filter", pixel_filter, ("box", "centre"))
    if shading is None:
        shading = ShadingConfig()
    elif not isinstance(shading, ShadingConfig):
        raise ValueError(f"shading must be a ShadingConfig or None, got {type(shading).__name__}")
    sc = dataclasses.replace(shading, integrator="path", max_depth=max_depth, rr_depth=rr_depth, seed=seed,
                             spp=per_pass, radiance_clamp=None)
    dev = get_device(device)
    from ..scene import DeviceScene, Scene

    if isinstance(scene, Scene):
        ds = DeviceScene(scene, device=dev)
    elif isinstance(scene, DeviceScene):
        if scene.device != dev:
            raise ValueError(f"scene is a DeviceScene on {scene.device}, not on device {dev}")
        ds = scene
    else:
        raise ValueError(f"scene must be a foveawarp.Scene or DeviceScene, got {type(scene).__name__}")
    if camera is None:
        camera = ds.scene.camera
    if not isinstance(camera, Camera):
        raise ValueError(f"camera must be a foveawarp.Camera or None, got {type(camera).__name__}")
    stage = PathStage(ds, sc, width, height, dev, pixel_filter=pixel_filter)
    acc = wp.zeros((height, width), dtype=wp.vec3, device=dev)
    one = wp.zeros((height, width), dtype=wp.vec3, device=dev)
    done, k = 0, 0
    while done < spp_total:
        n = min(per_pass, spp_total - done)
        stage.run(camera, k, one, spp=n)
        parallel.launch(accumulate_kernel, dim=(height, width), inputs=[acc, one, float(n) / float(spp_total)],
                        device=dev)
        done += n
        k += 1
    return acc.numpy().astype(np.float32)
