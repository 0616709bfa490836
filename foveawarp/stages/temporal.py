"""TemporalStage: the ping-pong history of shaded radiance (thesis A4) under a rule that never makes a traced
pixel worse than tracing it alone."""

from __future__ import annotations

import warp as wp

from .. import parallel
from ..config import TemporalConfig, check_int_range
from ..kernels.temporal import (
    META_SHIFT,
    TemporalParams,
    misses_seen_kernel,
    refresh_thin_kernel,
    resolve_kernel,
    resolve_rows_kernel,
    resolve_stoch_boxed_kernel,
    resolve_stoch_kernel,
    resolve_stoch_rows_kernel,
    sample_shade_resolve_rows_kernel,
    shade_resolve_rows_kernel,
    stoch_box_list_kernel,
)

__all__ = ["TemporalStage", "stochastic_min_age"]

# With stochastic shading an unsampled pixel that moved on screen (more than half a pixel) reuses history only
# once it has accumulated frames worth ``TemporalConfig.stochastic_min_samples`` Monte Carlo samples at this
# frame's samples per pixel (``stochastic_min_age``; under motion the blend weights the fresh samples more, so the
# history holds fewer effective samples than that count):
# a younger history is a noisy sample or two, and the reconstruction from this frame's neighbouring samples (a
# spatial average) is closer. The rule counts samples, not frames: the noise of a history falls with the samples
# it holds, the reconstruction's error (edges blurred) does not. Measured on the H100 (30 frames of each scene's
# camera path with a moving gaze, against 256-ray frames; ``benchmarks/results/stoch-*``) against the rule before
# (4 frames at any sample count, and moving history dropped after max_history_frames // 2 reprojections): with 4
# samples (1 frame at 4 and 8 AO rays, 2 at 2, 4 at 1) the foveated frame's mean PSNR rose by 0.0-0.7 dB at 1 AO
# ray, 0.7-1.8 at 2, 1.2-2.6 at 4 and 1.3-2.6 at 8 on every scene but the earth (unchanged); the worst frame of
# a path (just after its first frame) stayed or rose, but on cornell, where it fell by 0.9-1.5 dB at 4 rays,
# 0.04-0.3 dB at 8 and 0.08 dB at 2. With 8 samples, 1 AO ray lost 0.2-1.3 dB. On a still view any age is kept:
# there each pixel's own past samples beat an interpolation of this frame's sparse ones.


def stochastic_min_age(min_samples: int, samples_per_pixel: int) -> int:
    """Accumulated frames a moving unsampled pixel's stochastic history needs before it is reused:
    ``ceil(min_samples / samples_per_pixel)`` (frames of ``samples_per_pixel`` Monte Carlo samples each, at least 1).
    Both are integers >= 1 (``min_samples`` <= 4096, ``samples_per_pixel`` < 2^31)."""
    need = check_int_range("min_samples", min_samples, 1, 4096)
    spp = check_int_range("samples_per_pixel", samples_per_pixel, 1, 2**31 - 1)
    return -(-need // spp)


# the variance clipping box of stochastic shading is over the 5 x 5 neighbourhood
CLIP_BOX_RADIUS = 2


class TemporalStage:
    """History buffers for one image size, and the per-frame resolve.

    The rule (per pixel, ``run``):

    * **Background** (the G-buffer's primary ray missed): the background radiance. Exact, nothing to trace.
    * **Traced this frame, deterministic shading** (no AO rays, no area-light samples): the fresh value, as
      is. History is never blended in, so a traced pixel equals full-resolution tracing (the fovea is then
      identical to the reference) and history cannot accumulate error under motion.
    * **Traced this frame, stochastic shading**: the fresh deterministic part (``fresh - fresh_stoch``) plus an
      accumulated stochastic part: the reprojected stochastic history, clipped to the box mean +- ``clamp_gamma``
      standard deviations of the fresh stochastic values traced in the 5 x 5 neighbourhood (variance
      clipping; skipped when fewer than 3 were traced there), blended with the fresh stochastic value at weight
      ``alpha = max(1 / (n + 1), motion_alpha_per_px * |velocity|, 1 - w)`` (``n`` frames of history, at most
      ``max_history_frames - 1``; ``w`` the validated part of the bilinear footprint). So the weight of history
      falls with screen motion and with disocclusion, and a static view converges to the mean of
      ``max_history_frames`` frames.
    * **Not traced, valid history**: the history colour, fetched with bilinear reprojection at the G-buffer's
      ``reproj_uv``; each of the 4 taps counts only when it was filled last frame, its depth matches the depth
      this surface point had in the previous frame (G-buffer ``prev_dist``; moving objects included) within
      ``depth_eps_rel * depth``, and its normal is within ``normal_cos_min``; the weights are renormalised over
      the valid taps (with stochastic shading and more than half a pixel of screen motion, only history of at
      least ``stochastic_min_age(TemporalConfig.stochastic_min_samples, samples)`` accumulated frames: 1 with
      4 or more AO rays per pixel, 2 with 2, 4 with 1). A value reprojected ``max_history_frames - 1`` times without being traced is dropped, and
      so is the history of a surface point that moved since the last frame (object motion, G-buffer ``moved``):
      its lighting changed with it (a spinning globe turns its day side), so the reconstruction from this
      frame's samples is closer than any reprojected colour.
    * **Otherwise**: empty (not a seed); the reconstruction fills it.

    Outputs of each ``run`` (then the current slot of the ping-pong history; each ``run`` writes the other slot
    and swaps): ``color`` (H, W) vec3, the linear radiance, which is also the colour history; ``filled``
    (H, W) uint8, the reconstruction's seeds; ``depth`` (H, W) float, the G-buffer depth of the frame. The
    next frame's cache test reads ``filled`` and ``depth`` as its previous valid mask and depth
    (``SamplingStage.launch``), so they need no copy. Hold no reference to them across frames: the next
    ``run`` but one overwrites them.

    The shading kind (``stochastic``) picks a compile-time specialisation of the resolve: the deterministic
    one keeps no stochastic history. A ``run`` or ``refresh`` whose ``stochastic`` differs from the previous
    one forgets the history first (``reset``): history written without a stochastic part is never used as
    if it had one.
    """

    # the clip boxes by list (``run(work=...)``) on the CPU too: False, the rows resolve gathers them without the
    # divergence that the list avoids on CUDA; the tests set it to check the CUDA path's kernels on the CPU
    list_boxes_on_cpu = False

    def __init__(self, width: int, height: int, config: TemporalConfig, device):
        self.width, self.height, self.config, self.device = width, height, config, device
        n = width * height
        shape = (height, width)
        # the colour history is (H, W) (the stage's output) and is handed to the kernels as a flat view
        self._color = [wp.zeros(shape, dtype=wp.vec3, device=device) for _ in range(2)]
        self._color_flat = [a.flatten() for a in self._color]
        self._filled = [wp.zeros(shape, dtype=wp.uint8, device=device) for _ in range(2)]
        self._depth = [wp.zeros(shape, dtype=float, device=device) for _ in range(2)]
        self._normal = [wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(2)]
        self._stoch = [wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(2)]
        self._meta = [wp.zeros(n, dtype=wp.int32, device=device) for _ in range(2)]  # age | stale << 16
        self._cur = 0
        self._stochastic = None  # shading kind of the last run/refresh (None: none yet)
        self._box = None  # the list-gathered clip boxes (lo, hi), allocated on the first run that uses them
        self._no_box = wp.zeros((1, 1), dtype=wp.vec3, device=device)  # box placeholder of the other kernels

    @property
    def color(self) -> wp.array:
        """(H, W) vec3: the last resolved frame's radiance (the current colour history)."""
        return self._color[self._cur]

    @property
    def filled(self) -> wp.array:
        """(H, W) uint8: 1 where the last resolved frame has a colour (the reconstruction's seeds)."""
        return self._filled[self._cur]

    @property
    def depth(self) -> wp.array:
        """(H, W) float: the G-buffer depth of the last resolved frame (the next frame's previous depth)."""
        return self._depth[self._cur]

    def show_misses(self, hit: wp.array, seen: wp.array) -> None:
        """Overwrite the last resolved colour at the G-buffer's misses with ``seen`` (H, W) vec3, what each
        miss's primary ray saw: the environment of a scene that has one, where the resolve wrote the constant
        background. Read by the reconstruction like any filled pixel; the next frame's hits never take a miss's
        history (its depth test fails)."""
        parallel.launch(misses_seen_kernel, dim=(self.height, self.width), inputs=[hit, seen, self.color],
                        device=self.device)

    def reset(self) -> None:
        """Forget all history (camera cut, resize of the content, change of the shading kind)."""
        for a in self._meta:
            a.zero_()

    def _check_kind(self, stochastic: bool) -> None:
        if self._stochastic is not None and self._stochastic != stochastic:
            self.reset()
        self._stochastic = stochastic

    def history(self) -> dict:
        """Host copies of the current history (debugging and tests; reads the device): color (H, W, 3),
        filled (H, W), depth (H, W), and flat (H*W, ...) normal, stoch, age, stale. ``normal`` and ``stoch``
        are meaningful only where age > 0."""
        c = self._cur
        meta = self._meta[c].numpy()
        return {"color": self._color[c].numpy(), "filled": self._filled[c].numpy(), "depth": self._depth[c].numpy(),
                "normal": self._normal[c].numpy(), "stoch": self._stoch[c].numpy(),
                "age": meta & ((1 << META_SHIFT) - 1), "stale": meta >> META_SHIFT}

    def set_history(self, *, color, stoch, normal, age, stale, depth, filled) -> None:
        """Load the current history from host arrays (tests): shapes as ``history()`` returns them. ``age > 0``
        must imply ``filled`` (as every ``run`` leaves it; the resolve relies on it)."""
        import numpy as np

        age = np.asarray(age, np.int32)
        stale = np.asarray(stale, np.int32)
        filled = np.asarray(filled, np.uint8)
        if ((age.reshape(-1) > 0) & (filled.reshape(-1) == 0)).any():
            raise ValueError("set_history: age > 0 must imply filled (the resolve reads no filled mask)")
        c = self._cur
        self._color[c].assign(np.asarray(color, np.float32).reshape(self.height, self.width, 3))
        self._stoch[c].assign(np.asarray(stoch, np.float32).reshape(-1, 3))
        self._normal[c].assign(np.asarray(normal, np.float32).reshape(-1, 3))
        self._meta[c].assign((age | (stale << META_SHIFT)).reshape(-1))
        self._depth[c].assign(np.asarray(depth, np.float32).reshape(self.height, self.width))
        self._filled[c].assign(filled.reshape(self.height, self.width))

    def params(self, *, use_history: bool, stochastic: bool, background=(0.0, 0.0, 0.0),
               samples: int = 1, still: bool = False) -> TemporalParams:
        """The resolve's constants; ``samples``: Monte Carlo samples per pixel per frame of the stochastic
        shading (the minimum age of reused moving history, ``stochastic_min_age``); ``still``: a still view, whose
        clip box is ``still_clamp_gamma`` wide."""
        c = self.config
        tp = TemporalParams()
        tp.max_frames = int(c.max_history_frames)
        tp.use_history = 1 if (use_history and c.enabled) else 0
        tp.depth_eps_rel = float(c.depth_eps_rel)
        tp.normal_cos_min = float(c.normal_cos_min)
        tp.clamp_gamma = float(c.still_clamp_gamma if still else c.clamp_gamma)
        tp.box_radius = CLIP_BOX_RADIUS
        tp.motion_alpha_per_px = float(c.motion_alpha_per_px)
        tp.min_age_reuse = stochastic_min_age(c.stochastic_min_samples, samples) if stochastic else 1
        tp.background = wp.vec3(*(float(v) for v in background))
        return tp

    def can_shade(self, stochastic: bool) -> bool:
        """Whether ``run(..., shade=...)`` may shade the sampled pixels in its own launch: the CPU's rows kernels
        with deterministic shading (the stochastic resolve reads its neighbours' fresh values)."""
        return not stochastic and parallel.use_row_kernels(self.device)

    def run(self, sample_map, gbuffer, fresh, fresh_stoch, *, use_history: bool = True, stochastic: bool = False,
            background=(0.0, 0.0, 0.0), shade=None, work=None, count=None, samples: int = 1,
            sampling=None, still: bool = False) -> None:
        """Resolve one frame (the rule in the class docstring) against the history of the previous ``run``.

        Args:
            sample_map: (H, W) uint8, 1 where ``fresh`` was traced this frame.
            gbuffer: this frame's :class:`GBuffer` (hit, normal, depth, reproj_uv, prev_dist, moved).
            fresh: (H, W) vec3 radiance at the traced pixels.
            fresh_stoch: (H, W) vec3, the stochastic part of ``fresh`` (read only when ``stochastic``).
            use_history: False on the first frame and after a cut.
            stochastic: whether the shading has Monte Carlo terms.
            samples: their Monte Carlo samples per pixel per frame (AO rays plus area-light samples; an integer
                >= 1): moving unsampled pixels reuse stochastic history of at least
                ``stochastic_min_age(config.stochastic_min_samples, samples)`` frames. Unused without
                ``stochastic``; the default 1 is the most cautious (``stochastic_min_samples`` frames), so a caller
                with stochastic shading should pass its count (``ShadeStage.stochastic_samples``).
            background: radiance of rays that miss (linear RGB).
            still: the camera and the scene stand still (the history reprojects exactly): the stochastic
                history is clipped with ``TemporalConfig.still_clamp_gamma`` instead of ``clamp_gamma``.
            shade: a :class:`ShadeStage` (only where :meth:`can_shade`): the sampled pixels are shaded into
                ``fresh`` / ``fresh_stoch`` in the same launch, each just before its resolve, with the values of
                ``shade.masked`` (its parameters as last uploaded); one pass over the image instead of two.
            sampling: with ``shade``: None, or the ``RowsPass`` of ``SamplingStage.rows_pass_args(...)`` of the
                stage whose ``sample_map`` this is: its frame pass then runs in the same launch too, each tile row's just
                before the row's shading and resolve (``sample_shade_resolve_rows_kernel``; the caller then calls
                ``SamplingStage.sum_row_counts``). The G-buffer must be the one the sampling pass was set up with.
            work, count: the flat list of the traced pixels (``ReorderStage.work`` / ``count``: indices y * W + x
                of every nonzero ``sample_map`` pixel, ``count[0]`` of them) or None. With stochastic shading on
                CUDA the clip boxes are then gathered by a launch over the list (a thread per traced pixel),
                not inside the per-pixel resolve, where the few traced threads of each warp held all of it; the
                same values. Two (H, W) vec3 box buffers are allocated on the first such run.
        """
        stochastic = bool(stochastic)
        samples = check_int_range("samples", samples, 1, 2**31 - 1)
        if shade is not None and not self.can_shade(stochastic):
            raise ValueError("shade must be None unless can_shade(stochastic) (the CPU's rows kernels with "
                             f"deterministic shading), got a {type(shade).__name__} with stochastic={stochastic} "
                             f"on {self.device}")
        self._check_kind(stochastic)
        prev, cur = self._cur, 1 - self._cur
        g = gbuffer
        if (work is None) != (count is None):
            raise ValueError(f"work and count must be given together (ReorderStage.work and .count), got "
                             f"{type(work).__name__} and {type(count).__name__}")
        if sampling is not None and shade is None:
            raise ValueError("sampling (SamplingStage.rows_pass_args) needs shade: the fused launch shades and "
                             "resolves the rows it samples, got shade=None")
        if shade is not None:
            pos, _, face_albedo, face, _, lights, area_lights, face_emission = shade.inputs(gbuffer)
            args = [shade.params_dev, pos, face_albedo, face, lights, area_lights, face_emission,
                    self.params(use_history=use_history, stochastic=False, background=background), sample_map,
                    g.hit, g.normal, g.depth, g.reproj_uv, g.prev_dist, g.moved, fresh, fresh_stoch,
                    self._depth[prev], self._normal[prev], self._meta[prev], self._color_flat[prev], self._stoch[prev]]
            outs = [self._color_flat[cur], self._filled[cur], self._depth[cur], self._normal[cur], self._meta[cur],
                    self._stoch[cur]]
            if sampling is not None:
                # the pass must write the map the resolve reads, and must read a history this launch does not write
                if sampling.sample_map is not sample_map:
                    raise ValueError("sampling: the SamplingStage's sample_map must be the sample_map given here "
                                     "(the fused launch writes it and resolves from it)")
                if sampling.depth_prev is self._depth[cur] or sampling.valid_prev is self._filled[cur]:
                    raise ValueError("sampling: the cache test's depth_prev / valid_prev must not be the history "
                                     "this resolve writes (TemporalStage.depth / .filled before the run are right)")
                parallel.launch(sample_shade_resolve_rows_kernel, sampling.tile_rows, inputs=[*sampling.args, *args],
                                outputs=outs, device=self.device, min_band_items=1)
            else:
                parallel.launch(shade_resolve_rows_kernel, self.height, inputs=args, outputs=outs, device=self.device,
                                min_band_items=max(1, -(-parallel.MIN_ITEMS_PER_BAND // self.width)))
            self.swap()
            return
        tp = self.params(use_history=use_history, stochastic=stochastic, background=background, samples=samples,
                         still=still)
        inputs = [tp, sample_map, g.hit, g.normal, g.depth, g.reproj_uv, g.prev_dist, g.moved, fresh,
                  fresh_stoch, self._depth[prev], self._normal[prev], self._meta[prev], self._color_flat[prev],
                  self._stoch[prev]]
        outputs = [self._color_flat[cur], self._filled[cur], self._depth[cur], self._normal[cur], self._meta[cur],
                   self._stoch[cur]]
        if stochastic and work is not None and (self.device.is_cuda or self.list_boxes_on_cpu):
            box_lo, box_hi = self._boxes()
            wp.launch(stoch_box_list_kernel, dim=work.shape[0],
                      inputs=[tp, work, count, self.width, sample_map, g.hit, fresh_stoch],
                      outputs=[box_lo, box_hi], device=self.device)
            wp.launch(resolve_stoch_boxed_kernel, dim=(self.height, self.width), inputs=inputs,
                      outputs=[*outputs, box_lo, box_hi, 0], device=self.device)
        else:
            parallel.launch_rows(
                resolve_stoch_kernel if stochastic else resolve_kernel,
                resolve_stoch_rows_kernel if stochastic else resolve_rows_kernel,
                (self.height, self.width), inputs=inputs, outputs=[*outputs, self._no_box, self._no_box],
                device=self.device,
            )
        self.swap()

    def _boxes(self):
        """The (H, W) vec3 clip-box buffers of the list-gathered boxes (allocated on first use)."""
        if self._box is None:
            shape = (self.height, self.width)
            self._box = (wp.zeros(shape, dtype=wp.vec3, device=self.device),
                         wp.zeros(shape, dtype=wp.vec3, device=self.device))
        return self._box

    def swap(self) -> None:
        """Make the history just written the current one (``run`` does it; a replayed CUDA graph of ``run``
        does not run Python, so its caller swaps)."""
        self._cur = 1 - self._cur

    def refresh(self, sample_map, cache_hit, prev_index, frame_params, num_samples, fraction: float, *,
                stochastic: bool = False) -> None:
        """Thin ``sample_map`` (in place; ``num_samples`` decremented on the device) to the refresh budget of a
        static, converged view: samples with usable history are kept with probability ``fraction``; those
        without history, or unrefreshed for half of ``max_history_frames`` or more, and (``stochastic``) those
        whose accumulation is not yet full, are always kept. Call before ``run`` of the same frame."""
        self._check_kind(bool(stochastic))
        prev = self._cur
        keep_stale = max(1, int(self.config.max_history_frames) // 2)
        keep_young = int(self.config.max_history_frames) if stochastic else 0
        wp.launch(refresh_thin_kernel, dim=(self.height, self.width),
                  inputs=[cache_hit, prev_index, self._meta[prev], frame_params, float(fraction),
                          keep_stale, keep_young],
                  outputs=[sample_map, num_samples], device=self.device)
