"""Sparse G-buffer stage: a coarse G-buffer for the saliency terms, the sampling map from it, and
the primary rays of the sampled pixels traced together with their shading (kernels/sparse.py)."""

from __future__ import annotations

import warp as wp

from .. import parallel
from ..buffers import GBuffer
from ..camera import Camera
from ..config import check_int_range
from ..frame_context import FrameContextBuilder, FrameView
from ..kernels.context import FrameContext, set_frame_context_kernel
from ..kernels.sparse import (
    coarse_gbuffer_kernel,
    coarse_saliency_kernel,
    sparse_sampling_kernel,
    trace_shade_list_kernel,
)
from ..kernels.gbuffer_textured import (
    coarse_gbuffer_textured_kernel,
    coarse_saliency_lab_kernel,
    trace_shade_textured_list_kernel,
)
from ..kernels.saliency import lab_kernel
from ..surface import environment_map, is_textured, surface_data
from .sampling import launch_tile_pass

__all__ = ["SparseGBufferStage"]


class SparseGBufferStage:
    """Primary rays only where needed, for one :class:`DeviceScene` at ``width`` x ``height``.

    ``coarse`` is a :class:`GBuffer` of ``ceil(W / cell)`` x ``ceil(H / cell)`` entries, one primary ray through
    the middle pixel of each cell; ``coarse_saliency`` holds eq. 3's ``max(dA, dN, V)`` per cell. Per frame:
    ``trace_coarse`` (head: this frame's cameras), then ``sample`` (the sampling map into a
    :class:`SamplingStage`'s buffers, no cache test) and ``trace_shade`` (the sampled pixels' primary rays into
    the full-resolution G-buffer and their shading). Nothing is allocated per frame; ``sample`` and
    ``trace_shade`` have fixed arguments (capturable in a CUDA graph).

    Args:
        dscene: the :class:`DeviceScene`.
        width, height: image size in pixels.
        cell: coarse cell edge in pixels, in [1, 64].
        device: Warp device.
    """

    # a textured scene's texture LOD (ShadingConfig.texture_lod); FrameLoop sets it
    texture_lod = "ray_cone"

    def __init__(self, dscene, width: int, height: int, cell: int, device):
        self.dscene, self.width, self.height, self.device = dscene, width, height, device
        self.cell = check_int_range("cell", cell, 1, 64)
        self.coarse_width = (width + self.cell - 1) // self.cell
        self.coarse_height = (height + self.cell - 1) // self.cell
        self.coarse = GBuffer(self.coarse_width, self.coarse_height, device, cell=self.cell, image_size=(width, height))
        self.textured = is_textured(dscene)
        self._sample_probability = None
        if self.textured:
            # the coarse entries store their base colour and material; the saliency reads their Lab
            self.coarse.store_surface()
            self.coarse_lab = wp.zeros((self.coarse_height, self.coarse_width), dtype=wp.vec3, device=device)
        else:
            self.coarse.bind_albedo(dscene.face_albedo)
        self.coarse_saliency = wp.zeros((self.coarse_height, self.coarse_width), dtype=float, device=device)
        self.primary = wp.zeros(1, dtype=FrameContext, device=device)  # the frame context, for trace_shade
        self._contexts = None  # trace_coarse's frame contexts (made on first use)

    def _probability(self) -> wp.array:
        """(H, W) float32: the sampling probability of the last ``sample`` (1 everywhere before one: a one-pixel
        cone)."""
        if self._sample_probability is None:
            self._sample_probability = wp.full((self.height, self.width), 1.0, dtype=float, device=self.device)
        return self._sample_probability

    @property
    def num_coarse_rays(self) -> int:
        return self.coarse_width * self.coarse_height

    def trace_coarse(self, camera: Camera, prev_camera: Camera, max_t: float) -> None:
        """The coarse G-buffer for ``camera`` (reprojection fields against ``prev_camera``), and this frame's
        primary-ray parameters for ``trace_shade`` (written on the device): ``trace_coarse_frame`` with a context
        of these cameras."""
        if self._contexts is None:
            self._contexts = FrameContextBuilder(self.width, self.height)
        self.trace_coarse_frame(self._contexts.build(camera, prev_camera, (0.0, 0.0), 0, float(max_t)))

    def trace_coarse_frame(self, frame: FrameView) -> None:
        """``trace_coarse`` for the frame context ``frame`` (its cameras and ray length), which ``trace_shade``
        reads from the device."""
        ds, c = self.dscene, self.coarse
        if self.textured:
            env, has_env = environment_map(ds)
            parallel.launch(coarse_gbuffer_textured_kernel, dim=(self.coarse_height, self.coarse_width),
                            inputs=[ds.mesh.id, surface_data(ds, self.texture_lod), env, int(has_env), ds.points_prev,
                                    frame.struct, self.cell],
                            outputs=[c.position, c.normal, c.depth, c.face, c.hit, c.reproj_uv, c.prev_dist, c.moved,
                                     c.albedo, c.material, c.emission], device=self.device)
            wp.launch(set_frame_context_kernel, dim=1, inputs=[frame.struct], outputs=[self.primary],
                      device=self.device)
            return
        parallel.launch(
            coarse_gbuffer_kernel,
            dim=(self.coarse_height, self.coarse_width),
            inputs=[ds.mesh.id, ds.indices, ds.points_prev, ds.vertex_normals, ds.face_smooth, frame.struct,
                    self.cell],
            outputs=[c.position, c.normal, c.depth, c.face, c.hit, c.reproj_uv, c.prev_dist, c.moved],
            device=self.device,
        )
        wp.launch(set_frame_context_kernel, dim=1, inputs=[frame.struct], outputs=[self.primary], device=self.device)

    def sample(self, sampling) -> None:
        """Fill ``sampling``'s probability, saliency and sample_map (and its sample counter; no cache hits) for
        the frame set by ``sampling.set_frame``: coarse saliency, per-pixel map, tile guarantee."""
        dev, c = self.device, self.coarse
        sampling.num_samples.zero_()
        sampling.num_cache_hits.zero_()
        if self.textured:
            parallel.launch(lab_kernel, dim=(self.coarse_height, self.coarse_width), inputs=[c.albedo],
                            outputs=[self.coarse_lab], device=dev)
            parallel.launch(coarse_saliency_lab_kernel, dim=(self.coarse_height, self.coarse_width),
                            inputs=[sampling.params, sampling.frame_params, self.coarse_lab, c.normal, c.hit,
                                    c.position, c.reproj_uv, self.cell, self.width, self.height],
                            outputs=[self.coarse_saliency], device=dev)
        else:
            parallel.launch(coarse_saliency_kernel, dim=(self.coarse_height, self.coarse_width),
                            inputs=[sampling.params, sampling.frame_params, c.face, self.dscene.face_lab, c.normal,
                                    c.hit, c.position, c.reproj_uv, self.cell, self.width, self.height],
                            outputs=[self.coarse_saliency], device=dev)
        maps = sampling.map_buffers()
        self._sample_probability = maps[1]  # the probability each pixel's sample was drawn with (trace_shade)
        parallel.launch(sparse_sampling_kernel, dim=(self.height, self.width),
                        inputs=[sampling.params, sampling.frame_params, sampling.ranks, self.coarse_saliency,
                                self.cell],
                        outputs=[*maps, sampling.sample_map], device=dev)
        launch_tile_pass(sampling.ranks, sampling.params, sampling.frame_params, sampling.tiles, sampling.sample_map,
                         sampling.cache_hit, sampling.num_samples, sampling.num_cache_hits, dev,
                         sampling.tile_counts)

    def trace_shade(self, gbuffer: GBuffer, shade, work, count, out, out_stoch) -> None:
        """Trace and shade the flat pixel indices ``work[0:count[0]]`` (``shade``: a :class:`ShadeStage` whose
        parameters were uploaded this frame). Writes ``gbuffer`` at those pixels only."""
        ds, g = self.dscene, gbuffer
        if self.textured:
            # the cone of each sample spreads over its spacing at the sampling map's probability
            g.store_surface()
            parallel.launch(trace_shade_textured_list_kernel, dim=work.shape[0],
                            inputs=[self.primary, shade.params_dev, shade.textured_params, work, count, ds.mesh.id,
                                    ds.points_prev, self._probability(), ds.lights, ds.area_lights],
                            outputs=[g.position, g.normal, g.depth, g.face, g.hit, g.reproj_uv, g.prev_dist, g.moved,
                                     g._albedo, g.material, g.emission, out, out_stoch],
                            device=self.device, count=count)
            return
        parallel.launch(
            trace_shade_list_kernel,
            dim=work.shape[0],
            inputs=[self.primary, shade.params_dev, work, count, ds.mesh.id, ds.indices, ds.points_prev,
                    ds.vertex_normals, ds.face_smooth, ds.face_albedo, ds.lights, ds.area_lights, ds.face_emission],
            outputs=[g.position, g.normal, g.depth, g.face, g.hit, g.reproj_uv, g.prev_dist, g.moved, out, out_stoch],
            device=self.device,
            count=count,
        )
