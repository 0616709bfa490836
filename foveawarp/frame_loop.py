"""FrameLoop: owns every buffer of one (scene, width, height, device), runs the stages, decides what to skip,
and times them."""

from __future__ import annotations

import contextlib
import math
import time
from typing import Optional

import numpy as np
import warp as wp

from ._util import check_image_size, get_device
from .buffers import Frame, GBuffer
from .camera import Camera, _check_gaze
from .config import Config
from .kernels.gbuffer import gbuffer_kernel
from .kernels.shade import ShadeParams, shade_full_kernel, shade_list_kernel, shade_masked_kernel
from .kernels.tonemap import tonemap_kernel
from .scene import DeviceScene, Scene, load_scene

__all__ = ["FrameLoop"]


class FrameLoop:
    """Render foveated frames of ``scene`` at ``width`` x ``height`` on ``device``.

    Every buffer is allocated here, once; ``render`` and ``render_reference`` only launch kernels.

    Args:
        scene: a :class:`Scene` or a name/path for :func:`load_scene`.
        width, height: image size in pixels, each in [1, 16384].
        config: a :class:`Config` (defaults if None).
        device: Warp device ("cpu", "cuda:0", ...) or None for Warp's default.
        timing: synchronize after each stage and report ``ms_<stage>`` in ``stats`` (slower; off for
            benchmarks of whole frames, which use CUDA graphs on CUDA).
    """

    def __init__(self, scene, width: int, height: int, config: Optional[Config] = None, device=None,
                 timing: bool = True):
        self.width, self.height = check_image_size(width, height)
        if config is None:
            config = Config()
        if not isinstance(config, Config):
            raise ValueError(f"config must be a foveawarp.Config, got {type(config).__name__}")
        self.config = config
        self.device = get_device(device)
        self.scene = scene if isinstance(scene, Scene) else load_scene(scene)
        self.timing = bool(timing)
        self.dscene = DeviceScene(self.scene, self.device)
        w, h, dev = self.width, self.height, self.device
        self.gbuffer = GBuffer(w, h, dev)
        self.radiance = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        self.image = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        self.full_map = wp.ones((h, w), dtype=wp.uint8, device=dev)
        self.frame_index = 0
        self.prev_camera: Optional[Camera] = None
        self._stats: dict = {}

    # -- helpers ---------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def _stage(self, name: str):
        """Time a stage into ``stats['ms_<name>']`` (synchronized) when timing is on."""
        if not self.timing:
            yield
            return
        wp.synchronize_device(self.device)
        t0 = time.perf_counter()
        yield
        wp.synchronize_device(self.device)
        self._stats[f"ms_{name}"] = self._stats.get(f"ms_{name}", 0.0) + (time.perf_counter() - t0) * 1e3

    def _max_t(self, camera: Camera) -> float:
        lo, hi = self.scene.bounds
        far = float(np.linalg.norm(np.asarray(camera.eye) - (lo + hi) * 0.5)) + self.scene.extent
        return float(min(max(2.0 * far, 1.0), 1.0e30))

    def shade_params(self, camera: Camera, *, ao_samples: Optional[int] = None) -> ShadeParams:
        sc = self.config.shading
        ds = self.dscene
        sp = ShadeParams()
        sp.mesh = ds.mesh.id
        sp.num_lights = ds.num_lights
        sp.num_area_lights = ds.num_area_lights
        sp.shadows = 1 if sc.shadows else 0
        sp.ambient = wp.vec3(*sc.ambient)
        sp.specular = float(sc.specular)
        sp.shininess = float(sc.shininess)
        sp.ao_samples = int(sc.ao_samples if ao_samples is None else ao_samples)
        sp.ao_radius = float(sc.ao_radius_rel * ds.extent)
        sp.area_samples = int(sc.area_light_samples)
        sp.background = wp.vec3(*sc.background)
        sp.ray_eps = float(ds.ray_eps)
        sp.seed = int(sc.seed)
        sp.frame = int(self.frame_index)
        sp.width = self.width
        sp.eye = wp.vec3(*camera.eye)
        return sp

    def _check_camera(self, camera) -> Camera:
        if camera is None:
            return self.scene.camera
        if not isinstance(camera, Camera):
            raise ValueError(f"camera must be a foveawarp.Camera, got {type(camera).__name__}")
        return camera

    # -- stages ------------------------------------------------------------------------------------------
    def _advance_scene(self, t: Optional[float]) -> bool:
        if t is None:
            t = self.dscene.time if self.dscene.time is not None else 0.0
        return self.dscene.set_time(t)

    def _gbuffer(self, camera: Camera, prev_camera: Camera) -> None:
        g, ds = self.gbuffer, self.dscene
        wp.launch(
            gbuffer_kernel,
            dim=(self.height, self.width),
            inputs=[ds.mesh.id, ds.indices, ds.points_prev, ds.vertex_normals, ds.face_smooth, ds.face_albedo,
                    camera.params(self.width, self.height), prev_camera.params(self.width, self.height),
                    self._max_t(camera)],
            outputs=[g.position, g.normal, g.depth, g.albedo, g.face, g.hit, g.velocity, g.reproj_uv],
            device=self.device,
        )

    def _shade_inputs(self):
        g, ds = self.gbuffer, self.dscene
        return [g.position, g.normal, g.albedo, g.face, g.hit, ds.lights, ds.area_lights, ds.face_emission]

    def shade_full(self, camera: Camera, out=None, *, ao_samples: Optional[int] = None) -> None:
        wp.launch(shade_full_kernel, dim=(self.height, self.width),
                  inputs=[self.shade_params(camera, ao_samples=ao_samples), *self._shade_inputs()],
                  outputs=[out if out is not None else self.radiance], device=self.device)

    def shade_list(self, camera: Camera, work, count, out=None, *, ao_samples: Optional[int] = None) -> None:
        """Shade the flat pixel indices ``work[0:count[0]]`` (count stays on the device)."""
        wp.launch(shade_list_kernel, dim=work.shape[0],
                  inputs=[self.shade_params(camera, ao_samples=ao_samples), work, count, *self._shade_inputs()],
                  outputs=[out if out is not None else self.radiance], device=self.device)

    def shade_masked(self, camera: Camera, mask, out=None, *, ao_samples: Optional[int] = None) -> None:
        wp.launch(shade_masked_kernel, dim=(self.height, self.width),
                  inputs=[self.shade_params(camera, ao_samples=ao_samples), mask, *self._shade_inputs()],
                  outputs=[out if out is not None else self.radiance], device=self.device)

    def _tonemap(self, hdr, out) -> None:
        sc = self.config.shading
        wp.launch(tonemap_kernel, dim=(self.height, self.width), inputs=[hdr, float(sc.exposure),
                  float(sc.white_point)], outputs=[out], device=self.device)

    # -- public ------------------------------------------------------------------------------------------
    def render_reference(self, camera: Optional[Camera] = None, *, time: Optional[float] = None) -> Frame:
        """G-buffer + shading at every pixel, full resolution, no reuse (the error reference)."""
        camera = self._check_camera(camera)
        self._stats = {}
        t0 = _now()
        with self._stage("scene"):
            self._advance_scene(time)
        with self._stage("gbuffer"):
            self._gbuffer(camera, self.prev_camera or camera)
        with self._stage("shade"):
            self.shade_full(camera)
        with self._stage("tonemap"):
            self._tonemap(self.radiance, self.image)
        wp.synchronize_device(self.device)
        n = self.width * self.height
        stats = dict(self._stats)
        stats.update(sampling_rate=1.0, cache_hit_rate=0.0, rays_traced=n, frame_index=self.frame_index,
                     ms_frame=(_now() - t0) * 1e3, skipped={})
        self.prev_camera = camera
        self.frame_index += 1
        return Frame(self.image, self.full_map, self.gbuffer, stats)

    def render(self, camera: Optional[Camera] = None, gaze_px=None, *, time: Optional[float] = None) -> Frame:
        """Render one foveated frame for ``camera`` with the gaze at ``gaze_px`` (pixels; None = centre;
        off screen is valid). ``time`` (seconds) moves animated objects."""
        camera = self._check_camera(camera)
        gaze = (self.width * 0.5, self.height * 0.5) if gaze_px is None else _check_gaze(gaze_px)
        frame = self.render_reference(camera, time=time)
        frame.stats["gaze_px"] = gaze
        frame.stats["skipped"] = {
            "foveation": "foveated stages not built yet: reference path",
        }
        return frame


def _now() -> float:
    return time.perf_counter()
