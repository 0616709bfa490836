"""Shading stage (ALGORITHMS.md A4): direct light with shadow rays, ambient or AO, emission, at G-buffer points;
launched over the full frame, a compacted work list, row CSR coordinates or a mask."""

from __future__ import annotations

from typing import Optional

import numpy as np
import warp as wp

from .. import parallel
from ..camera import Camera
from .._util import check_order_width, tile_order_threads
from ..kernels.shade import (
    ShadeParams,
    set_shade_params_kernel,
    set_shade_params_view_kernel,
    shade_ao_list_kernel,
    shade_full_kernel,
    shade_full_rows_kernel,
    shade_full_tiles_ao_kernel,
    shade_full_tiles_kernel,
    shade_list_direct_kernel,
    shade_list_finish_kernel,
    shade_list_kernel,
    shade_masked_kernel,
    shade_masked_rows_kernel,
    shade_rows_kernel,
)

from ..kernels.shade_textured import (
    TexturedShadeParams,
    shade_textured_full_kernel,
    shade_textured_list_kernel,
    shade_textured_masked_kernel,
    shade_textured_rows_kernel,
)
from ..surface import environment_map, is_textured, surface_data

__all__ = ["ShadeStage"]


class ShadeStage:
    """Shading of one :class:`DeviceScene` with a :class:`ShadingConfig` at ``width`` x ``height``.

    The per-frame parameters (eye, frame index for the Monte Carlo seeds, ...) live in a (1,) device array that
    ``upload`` writes with a one-thread kernel, so the launches read them on the device and a captured CUDA
    graph of the launches picks up each frame's values. Every launch writes the radiance to ``out`` and, when
    the shading has Monte Carlo terms (``stochastic``), their part to ``out_stoch``.
    """

    # CUDA: the full-frame shading runs each warp on a block of pixels this wide (kernels/order.py: 8 x 4, 16 x 2,
    # ...); 0: the (H, W) launch, 32 pixels of a row. The same values in every order
    order_width = 8

    # ``list`` with AO lanes: shade the light sources' part of the list apart from the AO pass (into two vec3 per
    # list entry, 24 bytes a pixel of the capacity, allocated on first use) and complete the pixels after both
    # (three launches instead of two; the same values). On CUDA the light-source shading then runs on a second
    # stream beside the AO pass, each filling the other's idle SM time. None (default): on CUDA at up to
    # SPLIT_MAX_PIXELS pixels; True: always (on the CPU one pass after the other: a test of the split); False:
    # never. FrameLoop keys its captured graphs by ``splits()``, so a change takes effect at the next frame.
    # Measured on the H100 (04c077a, whole frames with 8 AO rays, the two forms interleaved, three rounds,
    # ``split-ab-e11-04c077a-cuda.json``, the light part then kept in the output): at 1920x1080 nefertiti 1.46 ->
    # 1.31 ms, bunny 1.23 -> 1.21, spot and city within 1%, cornell 0.71 -> 0.73; at 3840x2160 nefertiti 1.3% faster,
    # and bunny, city, spot and cornell 1.5-4% slower (the extra pass over a long list costs more than the overlap
    # saves there). Again at 1920x1080 with the per-entry scratch (9045e11, ``split-ab-e11-9045e11-cuda.json``, two
    # rounds): nefertiti -9.8 / -10.7%, bunny +2.2 / +2.7%, spot -0.2 / +0.5%, city +0.7 / +0.8%, cornell +1.5 / +1.8%.
    split_direct = None
    SPLIT_MAX_PIXELS = 1920 * 1080

    # CUDA: the AO lanes launch of ``list`` in blocks of AO_BLOCK_DIM threads, at most AO_THREADS_PER_SM threads per SM
    # (a grid-stride launch: a thread takes an entry lane, then the one a grid later). The other list launches keep
    # 256-thread blocks and ``_list_blocks``. Measured on the H100 (the foveated list of frame 12 of each camera path,
    # 8 AO rays, three interleaved rounds, the outputs compared equal): against 256-thread blocks at 8192 threads per SM, the AO pass took 0.90-0.99x the time at
    # 3840x2160 on bunny, spot, teapot, nefertiti, ogre, city and cornell (at that size a 4-lane list of ~8% of the
    # pixels needs more than 8192 threads per SM, so some threads took two entries), and 0.97-1.02x at 1920x1080.
    # At 4K 128-thread blocks alone gave 0.97-0.99x, the larger grid with 256-thread blocks 0.93-1.00x
    # (``list-launch-shape-e26-ac1fa8a-cuda.log``). The other list kernels gained nothing consistent (0.93-1.06x).
    # Whole frames: 0.982-1.005x at 4K, 0.987-1.004x at 1080p (``ao-launch-ab-e28-ea4dba8-cuda.log``). The shape
    # changes no value, so FrameLoop does not key its captured graphs by it: a graph keeps the shape it was captured
    # with.
    AO_BLOCK_DIM = 128
    AO_THREADS_PER_SM = 16384

    # whether the scene is textured (set in __init__): its shading runs the kernels of kernels/shade_textured.py
    textured = False

    def __init__(self, dscene, config, width: int, height: int, device):
        self.dscene, self.config, self.width, self.height, self.device = dscene, config, width, height, device
        self.params_dev = wp.zeros(1, dtype=ShadeParams, device=device)
        self._upload_launch = parallel.Relaunch(set_shade_params_kernel, bands=False)  # recorded once on CUDA
        self._view_launch = parallel.Relaunch(set_shade_params_view_kernel, bands=False)
        self._dummy_display = wp.zeros((1, 1), dtype=wp.vec3, device=device)  # ``full`` without a display
        self._ao_samples = int(config.ao_samples)  # the last uploaded parameters' AO rays per pixel
        self._ao_part = None  # (list capacity, lanes) uint8: ``list``'s unoccluded AO counts per pixel and lane
        self._no_part = wp.zeros((1, 1), dtype=wp.uint8, device=device)  # ``list`` without AO lanes (not read)
        # CUDA: the second stream of ``list``'s split, made here, before any graph capture can begin
        self._side = wp.Stream(device) if wp.get_device(device).is_cuda else None
        self._light = None  # ``list``'s split: (capacity,) vec3 light part and its stochastic part per entry
        # a textured scene (foveawarp.surface): the glTF material model's kernels (kernels/shade_textured.py)
        self.textured = is_textured(dscene)
        self.textured_params = self._textured_params() if self.textured else None

    def _textured_params(self) -> TexturedShadeParams:
        """The textured shading's per-scene constants: surfaces at ``texture_lod``, the environment with
        ``area_light_samples`` samples per pixel (each a map and a BSDF direction with ``env_mis``), shadow rays
        to infinity as twice the scene's extent (every point lies inside its bounding box)."""
        ds = self.dscene
        tp = TexturedShadeParams()
        tp.sd = surface_data(ds, self.config.texture_lod)
        tp.env, has_env = environment_map(ds)
        tp.has_env = int(has_env)
        tp.env_samples = int(self.config.area_light_samples) if has_env else 0
        tp.env_mis = int(bool(self.config.env_mis))
        tp.far = float(2.0 * ds.extent)
        return tp

    def stochastic(self, ao_samples: Optional[int] = None) -> bool:
        """Whether the shading has Monte Carlo terms whose noise changes per frame (AO rays, area-light
        samples)."""
        return self.stochastic_samples(ao_samples) > 0

    def stochastic_samples(self, ao_samples: Optional[int] = None) -> int:
        """Monte Carlo samples per pixel per frame: the AO rays, ``area_light_samples`` per area light and the
        environment's draws (0: deterministic shading)."""
        sc = self.config
        ao = sc.ao_samples if ao_samples is None else ao_samples
        env = 0
        if self.textured:
            env = self.textured_params.env_samples * (2 if self.textured_params.env_mis else 1)
        return int(ao) + int(self.dscene.num_area_lights) * int(sc.area_light_samples) + int(env)

    def params(self, camera: Camera, frame_index: int, ao_samples: Optional[int] = None) -> ShadeParams:
        sc, ds = self.config, self.dscene
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
        sp.frame = int(frame_index)
        sp.width = self.width
        sp.eye = wp.vec3(*camera.eye)
        sp.split_stochastic = 1 if self.stochastic(sp.ao_samples) else 0
        return sp

    def upload_frame(self, camera: Camera, frame_index: int, ao_samples: Optional[int] = None) -> wp.array:
        """``upload(params(camera, frame_index, ao_samples))`` with one kept struct per ``ao_samples`` whose
        per-frame fields (eye, frame) are the only ones set again (the per-frame head: a Warp struct field costs
        ~1-2 us of Python to set)."""
        sp, kept = self._kept_params(camera, frame_index, ao_samples)
        if kept:
            sp.frame = int(frame_index)
            sp.eye = camera.eye
        return self.upload(sp)

    def _kept_params(self, camera: Camera, frame_index: int, ao_samples: Optional[int]) -> tuple:
        """(the kept ShadeParams of ``ao_samples``, whether it was kept from an earlier frame): made from
        ``camera`` and ``frame_index`` the first time."""
        cache = self.__dict__.setdefault("_frame_sp", {})
        sp = cache.get(ao_samples)
        if sp is not None:
            return sp, True
        sp = cache[ao_samples] = self.params(camera, frame_index, ao_samples)
        return sp, False

    def upload_view(self, frame, ao_samples: Optional[int] = None) -> wp.array:
        """``upload_frame`` for the frame context ``frame`` (``foveawarp.frame_context.FrameView``): the upload
        kernel takes the eye and the frame index from its struct, the other fields from the kept parameters."""
        sp, _ = self._kept_params(frame.camera, frame.frame_index, ao_samples)
        self._view_launch(1, inputs=[sp, frame.struct], outputs=[self.params_dev], device=self.device)
        self._ao_samples = int(sp.ao_samples)
        return self.params_dev

    def upload(self, sp: ShadeParams) -> wp.array:
        """Write ``sp`` to the device array the launches read; returns that array."""
        self._upload_launch(1, inputs=[sp], outputs=[self.params_dev], device=self.device)
        self._ao_samples = int(sp.ao_samples)
        return self.params_dev

    def inputs(self, gbuffer) -> list:
        """The scene and G-buffer arrays every shading launch reads, in kernel argument order: position, normal,
        the scene's per-face albedo (looked up by face: the G-buffer stores none), face, hit, lights, area
        lights, face emission."""
        g, ds = gbuffer, self.dscene
        return [g.position, g.normal, ds.face_albedo, g.face, g.hit, ds.lights, ds.area_lights, ds.face_emission]

    def textured_inputs(self, gbuffer) -> list:
        """The textured shading launches' scene and G-buffer arrays after the parameters: the per-scene constants,
        position, normal, albedo, material, emission, hit, lights, area lights."""
        g, ds = gbuffer, self.dscene
        return [self.textured_params, g.position, g.normal, g.albedo, g.material, g.emission, g.hit, ds.lights,
                ds.area_lights]

    def full(self, gbuffer, out, out_stoch, display=None) -> None:
        """Shade every pixel into ``out`` (and ``out_stoch``); ``display`` (an (H, W) vec3 array, or None): also
        the tone-mapped values, with the config's exposure and white point, in the same pass."""
        sc = self.config
        disp = self._dummy_display if display is None else display
        if self.textured:
            parallel.launch(shade_textured_full_kernel, dim=(self.height, self.width),
                            inputs=[self.params_dev, *self.textured_inputs(gbuffer), float(sc.exposure),
                                    float(sc.white_point), 0 if display is None else 1],
                            outputs=[out, out_stoch, disp], device=self.device)
            return
        wlog2 = check_order_width("ShadeStage.order_width", self.order_width)
        args = dict(inputs=[self.params_dev, *self.inputs(gbuffer), float(sc.exposure), float(sc.white_point),
                            0 if display is None else 1],
                    outputs=[out, out_stoch, disp, 0 if wlog2 is None else wlog2], device=self.device)
        if wlog2 is not None and not parallel.use_row_kernels(self.device):
            # CUDA: each warp on a block of pixels (kernels/order.py)
            # with AO rays the twin capped at 64 registers (kernels/shade.py: the caps as measured)
            kernel = shade_full_tiles_ao_kernel if self._ao_samples > 0 else shade_full_tiles_kernel
            parallel.launch(kernel, tile_order_threads(self.height, self.width, self.order_width), **args)
        else:
            parallel.launch_rows(shade_full_kernel, shade_full_rows_kernel, (self.height, self.width), **args)

    def masked(self, gbuffer, mask, out, out_stoch) -> None:
        """Every pixel launched, unsampled threads exit at once (the unreordered baseline)."""
        if self.textured:
            parallel.launch(shade_textured_masked_kernel, dim=(self.height, self.width),
                            inputs=[self.params_dev, mask, *self.textured_inputs(gbuffer)], outputs=[out, out_stoch],
                            device=self.device)
            return
        parallel.launch_rows(shade_masked_kernel, shade_masked_rows_kernel, (self.height, self.width),
                             inputs=[self.params_dev, mask, *self.inputs(gbuffer)], outputs=[out, out_stoch],
                             device=self.device)

    def rows(self, gbuffer, coords, counts, out, out_stoch) -> None:
        """Row-CSR launch (thesis strategies 1/2)."""
        if self.textured:
            parallel.launch(shade_textured_rows_kernel, dim=(self.height, self.width),
                            inputs=[self.params_dev, coords, counts, *self.textured_inputs(gbuffer)],
                            outputs=[out, out_stoch], device=self.device)
            return
        parallel.launch(shade_rows_kernel, dim=(self.height, self.width),
                        inputs=[self.params_dev, coords, counts, *self.inputs(gbuffer)], outputs=[out, out_stoch],
                        device=self.device)

    def ao_lanes(self) -> int:
        """Threads per pixel that ``list`` gives the AO rays of the last uploaded parameters: ``min(ao_lanes,
        ao_samples)``; below 2, one thread per pixel traces them with its shading (always for a textured scene:
        its list shading has no lanes)."""
        if self.textured:
            return 1
        return min(int(self.config.ao_lanes), self._ao_samples)

    def list(self, gbuffer, work, count, out, out_stoch) -> None:
        """The flat pixel indices ``work[0:count[0]]`` (count read on the device). With ``ao_lanes()`` >= 2 the
        AO rays are traced first, that many threads per pixel (``ShadingConfig.ao_lanes``), then the pixels
        shaded with their counts; where ``splits()`` (``split_direct``) the light sources' part is shaded apart
        (on CUDA beside the AO pass, on a second stream) and the pixels completed after both. The same values
        every way."""
        lanes = self.ao_lanes()
        blocks = self._list_blocks()
        n = int(work.shape[0])
        dev = self.device
        if n * lanes > 2**31 - 1:
            lanes = 1  # the lane launch's thread index is a 32-bit int: one thread per pixel (same values)
        if self.textured:
            parallel.launch(shade_textured_list_kernel, dim=n,
                            inputs=[self.params_dev, work, count, *self.textured_inputs(gbuffer)],
                            outputs=[out, out_stoch], device=dev, count=count, max_blocks=blocks)
            return
        if lanes < 2:
            parallel.launch(shade_list_kernel, dim=n, inputs=[self.params_dev, work, count, *self.inputs(gbuffer),
                                                              self._no_part, 0],
                            outputs=[out, out_stoch], device=dev, count=count, max_blocks=blocks)
            return
        if self._ao_part is None or tuple(self._ao_part.shape) != (n, lanes):
            self._ao_part = wp.zeros((n, lanes), dtype=wp.uint8, device=dev)
        part, g, ds = self._ao_part, gbuffer, self.dscene
        split = self.splits()  # lanes >= 2 here
        side = None
        if split:
            if self._light is None or self._light[0].shape[0] != n:
                self._light = (wp.zeros(n, dtype=wp.vec3, device=dev), wp.zeros(n, dtype=wp.vec3, device=dev))
            if dev.is_cuda:
                side = self._side
                side.wait_stream(dev.stream)  # fork: the list and G-buffer are ready
            parallel.launch(shade_list_direct_kernel, dim=n,
                            inputs=[self.params_dev, work, count, g.position, g.normal, ds.face_albedo, g.face, g.hit,
                                    ds.lights, ds.area_lights],
                            outputs=[*self._light], device=dev, count=count, max_blocks=blocks, stream=side)
        ao_blocks, ao_block_dim = self._ao_launch_shape()
        parallel.launch(shade_ao_list_kernel, dim=n * lanes,
                        inputs=[self.params_dev, work, count, g.position, g.normal, g.hit, ds.area_lights],
                        outputs=[part], device=dev, count=count, per_count=lanes, max_blocks=ao_blocks,
                        block_dim=ao_block_dim)
        if split:
            if side is not None:
                dev.stream.wait_stream(side)  # join
            parallel.launch(shade_list_finish_kernel, dim=n,
                            inputs=[self.params_dev, work, count, ds.face_albedo, g.face, g.hit, ds.face_emission, part,
                                    lanes, *self._light],
                            outputs=[out, out_stoch], device=dev, count=count, max_blocks=blocks)
        else:
            parallel.launch(shade_list_kernel, dim=n, inputs=[self.params_dev, work, count, *self.inputs(gbuffer),
                                                              part, lanes],
                            outputs=[out, out_stoch], device=dev, count=count, max_blocks=blocks)

    def splits(self) -> bool:
        """Whether ``list`` shades the light sources' part apart from the AO pass with the last uploaded
        parameters: ``split_direct`` (None: CUDA at up to ``SPLIT_MAX_PIXELS`` pixels), and only with AO lanes
        (``ao_lanes()`` >= 2; a list so long that its lanes would pass 2^31 threads runs unsplit too)."""
        s = self.split_direct
        if s is not None and not isinstance(s, (bool, np.bool_)):
            raise ValueError(f"ShadeStage.split_direct must be None (the default rule), True or False, got {s!r}")
        if s is None:
            s = self.device.is_cuda and self.width * self.height <= self.SPLIT_MAX_PIXELS
        return bool(s) and self.ao_lanes() >= 2

    def _ao_launch_shape(self) -> tuple:
        """(max_blocks, block_dim) of ``list``'s AO lanes launch: CUDA blocks of ``AO_BLOCK_DIM`` threads, at most
        ``AO_THREADS_PER_SM`` threads per SM; (0, 0) on the CPU (bands, no blocks)."""
        if not self.device.is_cuda:
            return 0, 0
        bd = int(self.AO_BLOCK_DIM)
        return max(1, int(self.AO_THREADS_PER_SM) // bd) * self._sm_count(), bd

    def _sm_count(self) -> int:
        """The CUDA device's SM count (1 where the device does not say), which the list launches' grids scale by."""
        return max(1, int(getattr(self.device, "sm_count", 0) or 1))

    def _list_blocks(self) -> int:
        """CUDA thread blocks of the list launches (``parallel.launch(max_blocks=...)``): 32 per SM, 1.08M threads
        on the H100, about a 4K frame's sampled pixels times 8 AO lanes at its ~11 % sampling rate, so a thread
        takes one item or a few and the threads past the count step over the rest of the capacity-sized launch
        cheaply. Measured on the H100 (b4f75a7, ``aolanes-e2-b4f75a7-cuda.json``, 8 AO lanes on the foveated
        list): city 1080p 1.16 ms, against 1.23 ms with a block per 256 threads of the capacity and 1.49 ms with
        a loop over the live items on a fixed grid (89 registers against 77: two blocks per SM, not three)."""
        if not self.device.is_cuda:
            return 0
        return 32 * self._sm_count()
