"""Path-tracing stage (``ShadingConfig.integrator = "path"``): the kernels of ``foveawarp.kernels.path`` on one
:class:`DeviceScene`, over a full frame or a work list of flat pixel indices.

How a frame calls it: the stage is built once per (scene, config, size, device) next to the ``ShadeStage``; each
frame calls ``run(camera, frame_index, out, work, count)`` with the reorder's work list (flat indices
``y * width + x`` in ``work[0:count[0]]``, the count read on the device) and the frame's shading buffer ``out``
((H, W) vec3), and gets the linear radiance of every listed pixel written at its (x, y), the other pixels left as
they were; ``run(camera, frame_index, out)`` traces every pixel (the full-resolution reference). The path budget
per pixel is ``ShadingConfig.spp`` (``spp=`` overrides it per call). The frame index seeds the per-pixel random
streams, so successive frames are independent estimates for the temporal resolve to accumulate.

The material is the glTF metallic-roughness BSDF of ``kernels/bsdf.py`` in both kinds of scene:

- untextured scenes carry a per-face albedo and the direct integrator's Blinn-Phong lobe (``ShadingConfig.specular``,
  ``shininess``): the albedo is the base colour, metallic 0, and the Blinn-Phong lobe is mapped by
  :func:`material_from_blinn_phong`; ``specular = 0`` gives exactly Lambert;
- scenes with materials (``Scene.materials``) are shaded with each hit's textured material (kernels/surface.py, as
  the textured direct integrator: base colour, metallic, roughness, normal map, emission, cut-outs; single-sided
  materials' back faces culled on camera rays only, so that bounces and shadow rays see the same surfaces). The
  texture LOD (``ShadingConfig.texture_lod`` "ray_cone") follows a ray cone along the path: the camera ray's spans
  one pixel, or on a foveated frame's list the sample's spacing; at each hit the cone's width grows by
  ``2 t tan(spread / 2)`` and a bounce widens its spread by the apex angle of the cone of solid angle
  ``1 / pdf`` of the sampled direction (``kernels.path.bounce_spread_angle``; rough glass by its microfacet
  sample's pdf, smooth glass not at all). The occlusion map is not used: the paths compute the occlusion.

Ambient, AO and the light-tree indirect term of the direct integrator have no part in it: the path tracer computes
the indirect light itself.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
import warp as wp

from .. import parallel
from ..camera import Camera
from ..config import ShadingConfig, check_choice, check_int_range
from ..kernels.path import (PathParams, budget_sum_kernel, path_full_kernel, path_full_textured_kernel,
                            path_list_kernel, path_list_textured_kernel, set_path_params_kernel)
from ..kernels.surface import SurfaceData
from ..surface import is_textured, surface_data

__all__ = ["PathStage", "material_from_blinn_phong", "emitter_tables"]

# the glTF dielectric's specular reflectance at normal incidence (kernels/bsdf.py DIELECTRIC_F0)
_GLTF_F0 = 0.04


def material_from_blinn_phong(specular: float, shininess: float) -> tuple:
    """(glTF roughness, specularFactor) that stand in for the direct integrator's normalized Blinn-Phong lobe of
    weight ``specular`` and exponent ``shininess``.

    - roughness: Blinn-Phong exponent n -> Beckmann alpha = sqrt(2 / (n + 2)) (Walter et al. 2007, sec. 5.2), used
      as the GGX alpha, and glTF's roughness = sqrt(alpha): n = 48 gives alpha 0.2, roughness 0.447.
    - specularFactor: the GGX lobe's normal-incidence reflectance is 0.04 s, so s = min(1, specular / 0.04): the
      Blinn-Phong weight up to the glTF dielectric's largest specular (0.15 gives 1), and 0 gives a pure Lambert
      surface, the direct integrator's diffuse term exactly.
    """
    alpha = math.sqrt(2.0 / (float(shininess) + 2.0))
    return math.sqrt(alpha), min(1.0, float(specular) / _GLTF_F0)


def emitter_tables(vertices: np.ndarray, faces: np.ndarray, face_emission: np.ndarray) -> tuple:
    """The emissive-triangle sampling tables of a mesh: (face index per emitter (K,) int32, CDF (K + 1,) float32
    with 0 first and 1 last, selection probability per face (F,) float32: 0 for faces never sampled). A face's
    weight is its area times its summed RGB emission; the probabilities are the float32 CDF's steps, so the pdf
    the kernels evaluate is exactly that of the sampler."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    e = np.asarray(face_emission, dtype=np.float64)
    area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    w = area * e.sum(axis=1)
    w = np.where(np.isfinite(w) & (w > 0.0), w, 0.0)
    idx = np.nonzero(w > 0.0)[0]
    prob = np.zeros(len(f), dtype=np.float32)
    if len(idx) == 0:
        return np.zeros(1, np.int32), np.array([0.0, 1.0], np.float32), prob
    c = np.concatenate([[0.0], np.cumsum(w[idx])])
    cdf = (c / c[-1]).astype(np.float32)
    cdf[-1] = 1.0
    prob[idx] = np.diff(cdf.astype(np.float64)).astype(np.float32)
    return idx.astype(np.int32), cdf, prob


class PathStage:
    """The path integrator of one :class:`DeviceScene` with a :class:`ShadingConfig` at ``width`` x ``height``.

    Args:
        dscene: the scene on the device (its current vertex positions are traced and sampled).
        config: the shading config: ``max_depth``, ``spp``, ``rr_depth``, ``radiance_clamp``, ``seed``,
            ``background``, ``specular`` and ``shininess`` are read (whatever its ``integrator``).
        width, height: the frame size in pixels.
        device: the Warp device.
        pixel_filter: "box" (default: each path's camera ray through a uniform point of its pixel, so the estimate
            converges to the pixel's mean radiance) or "centre" (through the pixel centre, the G-buffer's ray).

    The per-frame parameters live in a (1,) device array written by a one-thread kernel (``upload``), as in
    ``ShadeStage``, so a captured CUDA graph of the launches picks up each frame's camera and frame index.
    """

    def __init__(self, dscene, config: ShadingConfig, width: int, height: int, device, *,
                 pixel_filter: str = "box"):
        if not isinstance(config, ShadingConfig):
            raise ValueError(f"config must be a ShadingConfig, got {type(config).__name__}")
        check_choice("pixel_filter", pixel_filter, ("box", "centre"))
        self.dscene, self.config, self.device = dscene, config, wp.get_device(device)
        self.width = check_int_range("width", width, 1, 16384)
        self.height = check_int_range("height", height, 1, 16384)
        self.pixel_filter = pixel_filter
        dev = self.device
        sc = dscene.scene
        from ..envmap import Environment

        self.environment = Environment.of(sc.environment)

        env = self.environment if self.environment is not None else Environment.constant((0.0, 0.0, 0.0))
        self.env = env.to_device(dev)
        self.textured = is_textured(dscene)
        if self.textured:
            # the surfaces with their textures; the emitters are weighted by their materials' emission factor, the
            # bound of the textured emission (texels <= 1), so every emitting texel has a non-zero pdf
            self.surface = surface_data(dscene, config.texture_lod)
            emission = dscene.mat_emission.numpy()[dscene.face_material.numpy()]
            self._kernels = (path_full_textured_kernel, path_list_textured_kernel)
        else:
            self.surface = SurfaceData()  # not read by the untextured kernels
            emission = sc.face_emission
            self._kernels = (path_full_kernel, path_list_kernel)
        face, cdf, prob = emitter_tables(sc.vertices, sc.faces, emission)
        self.num_emitters = int(np.count_nonzero(prob > 0.0))
        self.emit_face = wp.array(face, dtype=wp.int32, device=dev)
        self.emit_cdf = wp.array(cdf, dtype=float, device=dev)
        self.face_emit_prob = wp.array(prob, dtype=float, device=dev)
        # the bounds the rays must cross: the mesh and the area lights
        pts = [np.asarray(sc.vertices, np.float64)]
        for a in sc.area_lights:
            c, u, v = (np.asarray(x, np.float64) for x in (a.corner, a.edge_u, a.edge_v))
            pts.append(np.stack([c, c + u, c + v, c + u + v]))
        allp = np.concatenate(pts)
        self._lo, self._hi = allp.min(axis=0), allp.max(axis=0)
        self.params_dev = wp.zeros(1, dtype=PathParams, device=dev)
        self._count = wp.zeros(1, dtype=wp.int32, device=dev)  # ``run``'s count of a whole work list
        self._upload_launch = parallel.Relaunch(set_path_params_kernel, bands=False)
        # the list launch's budget inputs (the sum of the listed pixels' probabilities) and the paths per pixel
        self._prob_sum = wp.zeros(1, dtype=float, device=dev)
        self._no_prob = wp.zeros((1, 1), dtype=float, device=dev)
        self.spp_used = wp.zeros((self.height, self.width), dtype=wp.int32, device=dev)
        self._roughness, self._specular = material_from_blinn_phong(config.specular, config.shininess)

    def _far(self, camera: Camera) -> float:
        """A ray length that crosses the scene from any point in it or from the eye (finite, >= 1)."""
        e = np.asarray(camera.eye, np.float64)
        c = 0.5 * (self._lo + self._hi)
        ext = float(np.linalg.norm(self._hi - self._lo))
        far = float(np.linalg.norm(e - c)) + ext
        return float(min(max(2.0 * far, 1.0), 1.0e30))

    def params(self, camera: Camera, frame_index: int, spp: Optional[int] = None) -> PathParams:
        """The frame's :class:`PathParams` (``spp`` None: the config's)."""
        sc, ds = self.config, self.dscene
        pp = PathParams()
        pp.mesh = ds.mesh.id
        pp.cam = camera.params(self.width, self.height)
        pp.num_lights = int(ds.num_lights)
        pp.num_area_lights = int(ds.num_area_lights)
        pp.num_emitters = self.num_emitters
        pp.env_light = 0 if self.environment is None else 1
        pp.env_nee = 0 if self.environment is None or self.environment.is_black else 1
        pp.max_depth = int(sc.max_depth)
        pp.rr_depth = int(sc.rr_depth)
        pp.spp = int(sc.spp) if spp is None else check_int_range("spp", spp, 1, 65536)
        # the "frame" budget: a full-resolution frame's paths, shared by the list launch
        pp.budget = float(pp.spp) * self.width * self.height if sc.path_budget == "frame" else 0.0
        pp.max_spp = int(sc.max_spp)
        pp.jitter = 1 if self.pixel_filter == "box" else 0
        pp.clamp = 0.0 if sc.radiance_clamp is None else float(sc.radiance_clamp)
        pp.roughness = float(self._roughness)
        pp.specular = float(self._specular)
        pp.background = wp.vec3(*sc.background)
        pp.ray_eps = float(ds.ray_eps)
        pp.far = self._far(camera)
        pp.seed = int(sc.seed)
        pp.frame = int(frame_index)
        pp.width = self.width
        return pp

    def upload(self, camera: Camera, frame_index: int, spp: Optional[int] = None) -> wp.array:
        """Write the frame's parameters to the device array the launches read; returns that array."""
        self._upload_launch(1, inputs=[self.params(camera, frame_index, spp)], outputs=[self.params_dev],
                            device=self.device)
        return self.params_dev

    def inputs(self) -> list:
        """The scene arrays every launch reads, in kernel argument order (after the parameters)."""
        ds = self.dscene
        return [self.env, self.surface, ds.face_albedo, ds.face_emission, ds.vertex_normals, ds.face_smooth, ds.points,
                ds.indices, ds.lights, ds.area_lights, self.emit_face, self.emit_cdf, self.face_emit_prob]

    def _check_out(self, out) -> None:
        if not isinstance(out, wp.array) or out.dtype != wp.vec3 or tuple(out.shape) != (self.height, self.width):
            raise ValueError(f"out must be a ({self.height}, {self.width}) wp.array of vec3, got "
                             f"{getattr(out, 'shape', type(out).__name__)}")

    def run(self, camera: Camera, frame_index: int, out, work=None, count=None, spp: Optional[int] = None) -> None:
        """Trace ``spp`` paths (None: ``ShadingConfig.spp``) per pixel of frame ``frame_index`` seen by ``camera``
        and write each pixel's mean linear radiance to ``out[y, x]``: every pixel when ``work`` is None, else the
        flat indices ``work[0:count[0]]`` (int32 arrays on the device; ``count`` None: all of ``work``)."""
        self._check_out(out)
        self.upload(camera, frame_index, spp)
        self.launch(out, work, count)

    def launch(self, out, work=None, count=None, probability=None) -> None:
        """``run``'s launches with the parameters last uploaded (``upload``): fixed arguments, so a captured CUDA
        graph of them replays each frame with the frame's uploaded camera and index. ``probability``: the (H, W)
        float sampling probability of a foveated frame's list, which ``ShadingConfig.path_budget = "frame"``
        shares the paths by (None, or the "pixel" budget: ``spp`` at every listed pixel) and which seeds a textured
        scene's camera ray cones with the samples' spacing (None: one pixel); the paths each listed
        pixel took are in ``spp_used``."""
        self._check_out(out)
        dev = self.device
        full_kernel, list_kernel = self._kernels
        if work is None:
            parallel.launch(full_kernel, dim=(self.height, self.width),
                            inputs=[self.params_dev, *self.inputs()], outputs=[out], device=dev)
            return
        if not isinstance(work, wp.array) or work.dtype != wp.int32 or work.ndim != 1:
            raise ValueError(f"work must be a 1-D wp.array of int32 flat pixel indices, got "
                             f"{getattr(work, 'dtype', type(work).__name__)}")
        if count is None:
            count = self._count
            count.fill_(int(work.shape[0]))
        elif not isinstance(count, wp.array) or count.dtype != wp.int32 or count.size < 1:
            raise ValueError("count must be a wp.array of int32 holding the number of live work entries")
        n = int(work.shape[0])
        if n == 0:
            return
        self._prob_sum.zero_()
        prob = self._no_prob
        if probability is not None:
            if (not isinstance(probability, wp.array) or probability.dtype != wp.float32
                    or tuple(probability.shape) != (self.height, self.width)):
                raise ValueError(f"probability must be a ({self.height}, {self.width}) float32 wp.array, got "
                                 f"{getattr(probability, 'shape', type(probability).__name__)}")
            prob = probability
        if probability is not None and self.config.path_budget == "frame":
            # one thread on the CPU: its atomic adds are not shared between the bands' threads
            parallel.launch(budget_sum_kernel, dim=n, inputs=[work, count, self.width, prob],
                            outputs=[self._prob_sum], device=dev, count=count, threads=1 if dev.is_cpu else None)
        parallel.launch(list_kernel, dim=n, inputs=[self.params_dev, *self.inputs(), work, count, prob,
                                                         self._prob_sum],
                        outputs=[out, self.spp_used], device=dev, count=count)
