"""FrameLoop: owns every buffer of one (scene, width, height, device), sequences the stages (``stages/``),
decides what to skip, and collects stats; every launch lives in a stage."""

from __future__ import annotations

import contextlib
import functools
import math
import time
from typing import Optional

import numpy as np
import warp as wp

from . import parallel
from ._util import check_image_size, get_device
from .buffers import Frame, GBuffer
from .camera import Camera, _check_gaze
from .config import Config, check_bool, check_int_range, resolve_reorder_strategy, show
from .frame_context import FrameContextBuilder, FrameView
from .kernels.shade import ShadeParams
from .policy import CostPolicy
from .scene import DeviceScene, Scene, load_scene
from .stages.gbuffer import GBufferStage
from .stages.shade import ShadeStage
from .stages.tonemap import TonemapStage

__all__ = ["FrameLoop"]


# Sibson half window of the sparse G-buffer mode (when ReconstructionConfig.sibson_window is None)
SPARSE_SIBSON_WINDOW = 2


class _StageTimer:
    """The synchronized timing of one stage into ``loop._stats['ms_<name>']`` (nothing recorded when the stage
    raises)."""

    __slots__ = ("loop", "name", "t0")

    def __init__(self, loop, name: str):
        self.loop, self.name = loop, name

    def __enter__(self):
        wp.synchronize_device(self.loop.device)
        self.t0 = time.perf_counter()

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            wp.synchronize_device(self.loop.device)
            key = "ms_" + self.name
            st = self.loop._stats
            st[key] = st.get(key, 0.0) + (time.perf_counter() - self.t0) * 1e3
        return False


class _EventStageTimer:
    """The GPU time of one stage (``FrameLoop(timing="gpu")`` on CUDA): two CUDA timing events recorded on the loop's
    stream around the stage's launches, no synchronization; ``FrameLoop._stage_gpu_ms`` reads them after the
    frame's one synchronization. Nothing is recorded when the stage raises."""

    __slots__ = ("loop", "name", "ev")

    def __init__(self, loop, name: str):
        self.loop, self.name = loop, name

    def __enter__(self):
        self.ev = self.loop._stage_event_pair()
        self.loop.device.stream.record_event(self.ev[0])

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            self.loop.device.stream.record_event(self.ev[1])
            self.loop._stage_events.append((self.name, self.ev))
        return False


_NO_TIMING = contextlib.nullcontext()


def _cpu_threads(fn):
    """Run a launching method with this loop's ``cpu_threads`` for the band-parallel CPU launches."""

    @functools.wraps(fn)
    def wrapper(self, *args, **kwargs):
        if self._on_cuda:  # no CPU launches to split: skip the context (a few microseconds of every frame's head)
            return fn(self, *args, **kwargs)
        with parallel.cpu_threads(self.cpu_threads):
            return fn(self, *args, **kwargs)

    return wrapper


class FrameLoop:
    """Render foveated frames of ``scene`` at ``width`` x ``height`` on ``device``.

    Every buffer is allocated here, once; ``render`` and ``render_reference`` only launch kernels.

    Args:
        scene: a :class:`Scene` or a name/path for :func:`load_scene`.
        width, height: image size in pixels, each in [1, 16384].
        config: a :class:`Config` (defaults if None).
        device: Warp device ("cpu", "cuda:0", ...) or None for Warp's default.
        timing: True: synchronize after each stage and report ``ms_<stage>`` in ``stats`` (slower; off for
            benchmarks of whole frames, which use CUDA graphs on CUDA): each stage's wall time, its host work
            and launch latency included. "gpu": the same launches, but on CUDA each ``ms_<stage>`` is the GPU
            time between two CUDA timing events recorded around the stage, with one synchronization at the end
            of the frame (a stage's time then leaves out the host work that overlaps earlier stages' kernels,
            and small stages are not inflated by a synchronization each; where the host launches a stage's
            kernels more slowly than the GPU runs them, as in small frames, its span includes the GPU's wait for
            them); on the CPU, whose launches are synchronous, "gpu" is the same as True. False: no per-stage
            times.
        graph: capture the steady-state frame body and replay it: on CUDA as a CUDA graph, on the CPU as a
            recording of its launches (``parallel.record``: the bands run again without the stages' Python).
            None (default): when ``timing`` is False. Ignored (eager launches) when ``timing`` is True.
        policy: "foveated" always renders the foveated frame (research use); "full" always traces every pixel;
            "auto" measures both paths (synchronized wall time of whole ``render`` calls, a few frames each,
            every ``POLICY_PERIOD`` frames, and sooner when a check of the chosen path's frames says the choice
            was wrong: wall times on the CPU device or with ``timing=True``, CUDA event spans otherwise) and
            renders the cheaper one (the rule: :class:`foveawarp.policy.CostPolicy`, ``self.cost_policy``),
            reporting the choice, the reason and both estimates in ``stats["skipped"]["foveation"]`` and
            ``stats["policy"]``; the first foveated frame after a full one takes it as its history
            (``stats["history_seeded"]``). None (default): "auto", on every device and with or without
            ``timing``: where the foveated frame costs more than full resolution (cheap shading, small scenes,
            the CPU with default shading, docs/cpu.md), the user gets the exact full frame at the lower cost.
            With ``timing=True`` the policy compares the two paths as this loop runs them (per-stage
            synchronization, no CUDA graphs), which costs the foveated path's many launches more than the full
            path's few, so it picks full resolution more often than a loop without timing would. Stage-by-stage
            study of the foveated frame passes ``policy="foveated"``.
        cpu_threads: threads of the band-parallel CPU launches (``foveawarp.parallel``), in [1, 1024]; None
            (default): the environment variable ``FOVEAWARP_CPU_THREADS``, else the usable cores. 1 = one
            thread per launch. The output does not depend on it (bit-identical). Ignored on CUDA.
    """

    # the cost policy's constants (``CostPolicy``), under their FrameLoop names
    POLICY_PERIOD = CostPolicy.PERIOD
    POLICY_WARM = CostPolicy.WARM
    POLICY_TIMED = CostPolicy.TIMED
    POLICY_MARGIN = CostPolicy.MARGIN
    POLICY_WARM_AGAIN = CostPolicy.WARM_AGAIN
    POLICY_TIMED_CLEAR = CostPolicy.TIMED_CLEAR
    POLICY_CLEAR = CostPolicy.CLEAR
    POLICY_WATCH = CostPolicy.WATCH
    POLICY_WATCH_EVERY = CostPolicy.WATCH_EVERY
    POLICY_RECHECK_MIN = CostPolicy.RECHECK_MIN

    @classmethod
    def policy_measurement_frames(cls) -> int:
        """The most frames the first measurement of the "auto" policy renders (with its confirmation)."""
        return CostPolicy.measurement_frames()

    def __init__(self, scene, width: int, height: int, config: Optional[Config] = None, device=None,
                 timing: bool = True, graph: Optional[bool] = None, policy: Optional[str] = None,
                 cpu_threads: Optional[int] = None):
        self.width, self.height = check_image_size(width, height)
        self.cpu_threads = parallel.resolve_cpu_threads(cpu_threads)
        if config is None:
            config = Config()
        if not isinstance(config, Config):
            raise ValueError(f"config must be a foveawarp.Config, got {type(config).__name__}")
        self.config = config
        self.device = get_device(device)
        self.scene = scene if isinstance(scene, Scene) else load_scene(scene)
        self._on_cuda = bool(self.device.is_cuda)
        self._animated = bool(self.scene.is_animated)  # read every frame (a property over the scene's objects)
        gpu_timing = isinstance(timing, str) and timing == "gpu"
        if not (gpu_timing or isinstance(timing, (bool, np.bool_))):
            raise ValueError(f"timing must be True, False or 'gpu', got {show(timing)}")
        self.timing = True if gpu_timing else bool(timing)
        # timing="gpu" on CUDA: per-stage CUDA events, read after the frame's one synchronization
        self._timing_gpu = gpu_timing and self._on_cuda
        self._stage_events: list = []  # (stage name, (start, end) events) of this frame, in order
        self._stage_ev_pool: list = []  # reused event pairs (no allocation per frame once warm)
        self.dscene = DeviceScene(self.scene, self.device)
        w, h, dev = self.width, self.height, self.device
        self.gbuffer = GBuffer(w, h, dev)
        self.gbuffer.bind_albedo(self.dscene.face_albedo)  # GBuffer.albedo: the face looked up (none stored)
        self.radiance = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        # the stochastic part of ``radiance`` (AO, area-light samples), written when the shading has one
        self.radiance_stoch = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        self.image = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        self.full_map = wp.ones((h, w), dtype=wp.uint8, device=dev)
        from .stages.dof import DofStage
        from .stages.indirect import IndirectStage

        cfg = self.config
        self.sparse_gbuffer = cfg.foveation.enabled and cfg.foveation.gbuffer == "sparse"
        if self.sparse_gbuffer and cfg.dof.enabled:
            raise ValueError(f"FoveationConfig.gbuffer 'sparse' needs a pinhole camera: DofConfig.aperture_m must be "
                             f"0, got {cfg.dof.aperture_m} (the DoF pass reads every pixel's depth)")
        self.dof = DofStage(w, h, cfg.dof, dev) if cfg.dof.enabled else None
        self.dof_out = wp.zeros((h, w), dtype=wp.vec3, device=dev) if cfg.dof.enabled else None
        self.indirect = (IndirectStage(self.dscene, cfg.indirect, dev) if cfg.shading.indirect == "lighttree"
                         else None)
        self.sampling = self.reorder = self.temporal = self.reconstruct = self.recon = self.sparse = None
        self.frame_index = 0
        self.prev_camera: Optional[Camera] = None
        self._ref_prev_camera: Optional[Camera] = None
        self._stats: dict = {}
        self.gbuffer_stage = GBufferStage(self.dscene, w, h, dev)
        self.gbuffer_stage.texture_lod = cfg.shading.texture_lod  # a textured scene's texture LOD
        self._contexts = FrameContextBuilder(w, h)  # the per-frame view constants (frame context), one struct
        self.shade = ShadeStage(self.dscene, cfg.shading, w, h, dev)
        # a scene with an environment: its misses show the environment the G-buffer saw, not one background colour
        self._env_misses = bool(self.shade.textured and self.shade.textured_params.has_env)
        self.path = self._path_stage() if cfg.shading.integrator == "path" else None
        # the fresh stochastic part the temporal resolve accumulates: the whole path radiance, else the shading's
        self._fresh_stoch = self.radiance if self.path is not None else self.radiance_stoch
        # the foveated path-traced frame's periphery filter (ShadingConfig.path_filter)
        self.path_filter = self.filtered = None
        if self.path is not None and cfg.shading.path_filter == "atrous" and cfg.foveation.enabled:
            from .stages.path_filter import PathFilterStage

            self.path_filter = PathFilterStage(w, h, dev, cfg.shading.path_filter_iterations,
                                               cfg.shading.path_filter_fovea_deg, cfg.shading.path_filter_guide,
                                               cfg.temporal.depth_eps_rel)
            self.filtered = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        # and its history blend (ShadingConfig.path_history)
        self.path_history = self.held = None
        if self.path is not None and cfg.shading.path_history > 0.0 and cfg.foveation.enabled:
            from .stages.path_filter import PeripheryHistoryStage

            self.path_history = PeripheryHistoryStage(w, h, dev, cfg.shading.path_history,
                                                      cfg.shading.path_filter_fovea_deg, cfg.temporal.depth_eps_rel)
            self.held = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        # albedo demodulation around the reconstruction (ReconstructionConfig.demodulate; None: with the path
        # integrator, whose periphery filter it keeps off the texture: the room's equal-time FovVideoVDP at 1080p on
        # an H200, 6.83 JOD with the filter alone, 7.42 with both)
        self.demodulation = self._hdr_out = None
        demod = cfg.reconstruction.demodulate
        if demod is None:
            demod = self.path is not None
        if demod and cfg.foveation.enabled and not self.sparse_gbuffer:
            from .stages.demodulate import DemodulateStage

            self.demodulation = DemodulateStage(self.dscene, w, h, dev)
            self.remod = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        self.tonemap = TonemapStage(cfg.shading, w, h, dev)
        self._sp_dev = self.shade.params_dev
        if graph is not None and not isinstance(graph, bool):
            raise ValueError(f"graph must be True, False or None, got {graph!r}")
        # CUDA: graphs of the frame body; the CPU: recordings of its launches (parallel.record), replayed the same way
        self._graphs_on = bool(not self.timing and graph is not False)
        self._graphs: dict = {}
        self._warm_keys: set = set()
        self._graph_error: Optional[str] = None
        self._static_frames = 0
        if policy is None:
            policy = "auto"
        # the cost policy's state machine; CUDA without timing: the watch reads the GPU span of a frame from two
        # timing events (recorded around its launches, read at the next frame when done: no synchronization), and
        # the measurement records the timed frames' spans too, so that the watch compares spans with spans
        self.cost_policy = CostPolicy(policy, by_events=self._on_cuda and not self.timing)
        self._pol_events: Optional[list] = None
        self._pol_ev_i = 0
        self._pol_ev_pending = None
        self._last_full = False

    @property
    def hdr(self) -> wp.array:
        """The last frame's HDR radiance ((H, W) vec3) before depth of field and the tone map: the full-resolution
        shading, or the foveated frame's reconstruction after its periphery filter and remodulation (``recon`` holds
        the reconstruction itself, demodulated where ``ReconstructionConfig.demodulate`` is on; ``filtered`` the
        filter's output, in the same terms)."""
        return self._hdr_out if self._hdr_out is not None else self.radiance

    @property
    def policy(self) -> str:
        """The cost policy: "auto", "foveated" or "full" (settable; see ``CostPolicy``)."""
        return self.cost_policy.mode

    @policy.setter
    def policy(self, value) -> None:
        self.cost_policy.mode = value

    @property
    def _pol_choice(self) -> str:
        """The policy's current choice (read by benchmarks/frame.py)."""
        return self.cost_policy.choice

    @property
    def _pol_est(self) -> dict:
        """The policy's last decision (read by benchmarks/frame.py)."""
        return self.cost_policy.estimates

    def _ensure_foveated_stages(self) -> None:
        """Allocate the foveated stages' buffers (once, on the first ``render``)."""
        if self.sampling is not None:
            return
        from .stages.reconstruct import ReconstructStage
        from .stages.reorder import ReorderStage
        from .stages.sampling import SamplingStage
        from .stages.temporal import TemporalStage

        w, h, dev, cfg = self.width, self.height, self.device, self.config
        self.sampling = SamplingStage(w, h, cfg, dev)
        self.reorder = ReorderStage(w, h, cfg.reorder, dev)
        self.temporal = TemporalStage(w, h, cfg.temporal, dev)
        # the sparse mode fills ~85-90% of the pixels from samples alone, where the bounded Sibson gather's window
        # sets the cost: J = 2 matched the block-exact window's PSNR (320x180, cornell and bunny in motion: 37.45 vs
        # 37.41 dB, 38.99 vs 38.96 dB) with 25 instead of up to 81 taps; an explicit sibson_window wins
        window = SPARSE_SIBSON_WINDOW if (self.sparse_gbuffer and cfg.reconstruction.sibson_window is None) else None
        self.reconstruct = ReconstructStage(w, h, cfg.reconstruction, block=cfg.foveation.block, device=dev,
                                            window=window, guaranteed=True,  # the sample maps hold the guarantee
                                            # deterministic shading leaves few holes (history fills all but the
                                            # disocclusions; with stochastic shading young history is left as
                                            # holes: 16-26% of the pixels in motion)
                                            few_holes=not self._stochastic_shading())
        self.recon = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        if self.sparse_gbuffer:
            from .stages.sparse import SparseGBufferStage

            self.sparse = SparseGBufferStage(self.dscene, w, h, cfg.foveation.coarse_cell, dev)
            self.sparse.texture_lod = cfg.shading.texture_lod

    # -- helpers ---------------------------------------------------------------------------------------
    def _stage(self, name: str, active: bool = True):
        """Time a stage into ``stats['ms_<name>']`` (synchronized) when timing is on and the stage has work this
        frame (``active``): a stage that launches nothing costs no synchronization and reports no time (the
        frame's ``skipped`` says why), so a full-resolution frame through ``render`` synchronizes as often as
        ``render_reference``. Otherwise a shared do-nothing context (no per-stage Python object: a frame enters
        up to 14 stages, and a generator context manager costs a few microseconds each)."""
        if not (self.timing and active):
            return _NO_TIMING
        if self._timing_gpu:
            return _EventStageTimer(self, name)
        return _StageTimer(self, name)

    def _stage_event_pair(self) -> tuple:
        """The next unused (start, end) pair of CUDA timing events of this frame (made on first use, then reused)."""
        i = len(self._stage_events)
        while len(self._stage_ev_pool) <= i:
            self._stage_ev_pool.append((wp.Event(self.device, enable_timing=True),
                                        wp.Event(self.device, enable_timing=True)))
        return self._stage_ev_pool[i]

    def _stage_gpu_ms(self) -> dict:
        """``ms_<stage>`` of this frame from its stage events (the device synchronized by the caller), summed per
        name: a stage entered twice in a frame (the head's and the body's part) reports both."""
        out: dict = {}
        for name, (e0, e1) in self._stage_events:
            key = "ms_" + name
            out[key] = out.get(key, 0.0) + float(wp.get_event_elapsed_time(e0, e1, synchronize=False))
        self._stage_events = []
        return out

    def _max_t(self, camera: Camera) -> float:
        return self.gbuffer_stage.max_t(camera)

    def shade_params(self, camera: Camera, *, ao_samples: Optional[int] = None) -> ShadeParams:
        """The shading kernels' parameters for ``camera`` (required) and this frame; ``ao_samples`` in [0, 256]
        overrides ``ShadingConfig.ao_samples``."""
        camera, ao_samples = self._shade_args(camera, ao_samples)
        return self.shade.params(camera, self.frame_index, ao_samples)

    def _shade_args(self, camera, ao_samples) -> tuple:
        if ao_samples is not None:
            ao_samples = check_int_range("ao_samples", ao_samples, 0, 256)
        return self._require_camera(camera), ao_samples

    def _path_stage(self):
        """The path integrator's stage (``ShadingConfig.integrator = "path"``), after the checks of what it
        cannot combine with."""
        from .stages.path import PathStage

        cfg = self.config
        if self.sparse_gbuffer:
            raise ValueError("ShadingConfig.integrator 'path' needs the full G-buffer (FoveationConfig.gbuffer "
                             "'full'), got 'sparse'")
        return PathStage(self.dscene, cfg.shading, self.width, self.height, self.device)

    def _stochastic_shading(self, ao_samples: Optional[int] = None) -> bool:
        """Whether the shading has Monte Carlo terms whose noise changes per frame (AO rays, area-light
        samples, every term of the path integrator): the temporal resolve then accumulates them
        (``TemporalStage``)."""
        return self.path is not None or self.shade.stochastic(ao_samples)

    def _resolve_kind(self) -> dict:
        """The temporal resolve's shading-kind arguments: ``stochastic`` and its Monte Carlo ``samples`` per pixel
        per frame (1 for deterministic shading, where the resolve does not use it), from one count (the path
        integrator: its paths per pixel)."""
        n = int(self.config.shading.spp) if self.path is not None else self.shade.stochastic_samples()
        return {"stochastic": n > 0, "samples": max(n, 1)}

    @staticmethod
    def _require_camera(camera) -> Camera:
        if not isinstance(camera, Camera):
            raise ValueError(f"camera must be a foveawarp.Camera, got {show(camera)} ({type(camera).__name__})")
        return camera

    def _check_image_array(self, name: str, a, dtype) -> None:
        """``a`` must be an (H, W) wp.array of ``dtype`` on this loop's device (kernels index it per pixel)."""
        ok = (isinstance(a, wp.array) and a.dtype == dtype and tuple(a.shape) == (self.height, self.width)
              and a.device == self.device)
        if not ok:
            raise ValueError(f"{name} must be a ({self.height}, {self.width}) wp.array of {dtype.__name__} on "
                             f"{self.device}, got {_describe(a)}")

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

    def _gbuffer(self, frame: FrameView) -> None:
        self.gbuffer_stage.run_frame(self.gbuffer, frame)

    @_cpu_threads
    def upload_shade_params(self, camera: Camera, *, ao_samples: Optional[int] = None) -> wp.array:
        """Write ``shade_params(camera)`` to the (1,) device array the shading kernels read, and return it."""
        camera, ao_samples = self._shade_args(camera, ao_samples)
        return self.shade.upload_frame(camera, self.frame_index, ao_samples)

    @_cpu_threads
    def shade_full(self, camera: Camera, out=None, *, ao_samples: Optional[int] = None) -> None:
        """Shade every pixel of the current G-buffer into ``out`` ((H, W) vec3 wp.array; default
        ``self.radiance``)."""
        if out is not None:
            self._check_image_array("out", out, wp.vec3)
        self.upload_shade_params(camera, ao_samples=ao_samples)
        self.shade.full(self.gbuffer, out if out is not None else self.radiance, self.radiance_stoch)

    @_cpu_threads
    def shade_list(self, camera: Camera, work, count, out=None, *, ao_samples: Optional[int] = None) -> None:
        """Shade the flat pixel indices ``work[0:count[0]]`` (count stays on the device): ``work`` a 1-D int32
        wp.array of at most H * W indices in [0, H * W), ``count`` a (1,) int32 wp.array, both on this device."""
        if out is not None:
            self._check_image_array("out", out, wp.vec3)
        if not (isinstance(work, wp.array) and work.dtype == wp.int32 and work.ndim == 1
                and work.shape[0] <= self.width * self.height and work.device == self.device):
            raise ValueError(f"work must be a 1-D int32 wp.array of at most {self.width * self.height} pixel indices "
                             f"on {self.device}, got {_describe(work)}")
        if not (isinstance(count, wp.array) and count.dtype == wp.int32 and tuple(count.shape) == (1,)
                and count.device == self.device):
            raise ValueError(f"count must be a (1,) int32 wp.array on {self.device}, got {_describe(count)}")
        self.upload_shade_params(camera, ao_samples=ao_samples)
        self.shade.list(self.gbuffer, work, count, out if out is not None else self.radiance, self.radiance_stoch)

    @_cpu_threads
    def shade_masked(self, camera: Camera, mask, out=None, *, ao_samples: Optional[int] = None) -> None:
        """Shade the pixels where ``mask`` ((H, W) uint8 wp.array) is nonzero, launching every pixel."""
        self._check_image_array("mask", mask, wp.uint8)
        if out is not None:
            self._check_image_array("out", out, wp.vec3)
        self.upload_shade_params(camera, ao_samples=ao_samples)
        self.shade.masked(self.gbuffer, mask, out if out is not None else self.radiance, self.radiance_stoch)

    def _tonemap(self, hdr, out) -> None:
        self.tonemap.run(hdr, out)

    # -- public ------------------------------------------------------------------------------------------
    @_cpu_threads
    def render_reference(self, camera: Optional[Camera] = None, *, time: Optional[float] = None,
                         gaze_px=None, dof: bool = True) -> Frame:
        """G-buffer + shading (+ indirect, + depth of field when configured, focused at ``gaze_px``) at every
        pixel, full resolution, no reuse: the error reference. It does not disturb the foveated history."""
        camera = self._check_camera(camera)
        gaze = None if gaze_px is None else _check_gaze(gaze_px)
        dof = check_bool("dof", dof)
        self._stats = {}
        self._stage_events = []
        t0 = _now()
        with self._stage("scene", self._animated):
            self._advance_scene(time)
        frame = self._contexts.build(camera, self._ref_prev_camera or camera,
                                     (self.width * 0.5, self.height * 0.5) if gaze is None else gaze,
                                     self.frame_index, self._max_t(camera))
        with self._stage("gbuffer"):
            self._gbuffer(frame)
        # the shading writes the display image itself when nothing follows it (as in render's full path)
        fused = self.indirect is None and self.path is None and not (self.config.dof.enabled and dof)
        with self._stage("shade"):
            self.shade.upload_view(frame)
            if self.path is not None:
                self.path.upload(frame.camera, frame.frame_index)
                self.path.launch(self.radiance)
            else:
                self.shade.full(self.gbuffer, self.radiance, self.radiance_stoch, self.image if fused else None)
        with self._stage("indirect", self.indirect is not None):
            if self.indirect is not None:
                self.indirect.update()
                self.indirect.run_full(self.gbuffer, self.radiance)
        hdr = self.radiance
        self._hdr_out = None
        with self._stage("dof", self.config.dof.enabled and dof):
            if self.config.dof.enabled and dof:
                cfgd = self.config.dof
                focus = (cfgd.focus_depth_m if cfgd.focus_depth_m is not None else
                         self.dof.focus_at_pixel(self.gbuffer.depth, self.gbuffer.hit,
                                                 (self.width * 0.5, self.height * 0.5) if gaze is None else gaze,
                                                 fov_y_deg=camera.fov_y_deg))
                self.dof.run(hdr, self.gbuffer.depth, self.gbuffer.hit, focus, self.dof_out,
                             fov_y_deg=camera.fov_y_deg)
                hdr = self.dof_out
        with self._stage("tonemap", not fused):
            if not fused:
                self._tonemap(hdr, self.image)
        wp.synchronize_device(self.device)
        n = self.width * self.height
        stats = dict(self._stats)
        if self._timing_gpu:
            stats.update(self._stage_gpu_ms())
        stats.update(sampling_rate=1.0, cache_hit_rate=0.0, rays_traced=n, frame_index=self.frame_index,
                     ms_frame=(_now() - t0) * 1e3, skipped={})
        self._ref_prev_camera = camera
        return Frame(self.image, self.full_map, self.gbuffer, stats)

    @_cpu_threads
    def render(self, camera: Optional[Camera] = None, gaze_px=None, *, time: Optional[float] = None,
               cut: bool = False) -> Frame:
        """Render one foveated frame for ``camera`` with the gaze at ``gaze_px`` (pixels; None = screen centre;
        off screen is valid). ``time`` (seconds) moves animated objects; ``cut=True`` forces a camera cut (no
        reprojection from the previous frame).

        The frame runs in two parts. The head launches everything that takes this frame's values (scene
        refit, G-buffer, the sampling stage's per-frame setup, DoF focus, shading parameters, the indirect
        light's rebuild when needed). The body (sampling map, refresh thinning, reorder, trace, indirect
        gather, temporal resolve, reconstruction, DoF, tone map) has fixed arguments: on CUDA, with
        ``timing=False``, it runs eagerly once per configuration, is then captured as a CUDA graph and replayed
        (``stats['graph']`` says which; a failed capture falls back to eager launches and says why)."""
        camera = self._check_camera(camera)
        gaze = (self.width * 0.5, self.height * 0.5) if gaze_px is None else _check_gaze(gaze_px)
        cut = check_bool("cut", cut)
        self._ensure_foveated_stages()
        cfg = self.config
        self._stats = {}
        self._stage_events = []
        skipped: dict = {}
        t0 = _now()
        # -- head: per-frame values ---------------------------------------------------------------------
        with self._stage("scene", self._animated):
            geometry_moved = self._advance_scene(time)
        first = self.prev_camera is None
        if not first and not cut and self.prev_camera.rotation_deg_to(camera) > cfg.temporal.cut_threshold_deg:
            cut = True
        pol = self.cost_policy
        mode, pol_timed, pol_watch = pol.next_frame(self.frame_index, cfg.foveation.enabled)
        seeded = False
        # (a full-resolution frame's skipped["foveation"] is written after the launches: host work they need not
        # wait for)
        if not (mode == "full" and cfg.foveation.enabled) and self._last_full and not (first or cut):
            if cfg.foveation.enabled:
                # a foveated frame after one that traced every pixel: that frame becomes its history (no cut)
                with self._stage("temporal"):
                    seeded = self._seed_history()
            if not seeded:
                cut = True
                skipped["reprojection"] = "previous frame rendered at full resolution"
        if pol_timed:
            wp.synchronize_device(self.device)
        t_pol = _now()
        ev = self._frame_events() if (pol_timed or pol_watch) and pol.by_events else None
        if ev is not None:
            self.device.stream.record_event(ev[0])
        if first or cut:
            skipped.setdefault("reprojection", "first frame" if first else "camera cut")
            self.temporal.reset()
            self.dscene.reset_history()
        history = not (first or cut)
        prev_cam = self.prev_camera if history else camera
        # the frame context: this frame's view constants, packed once for every stage
        frame = self._contexts.build(camera, prev_cam, gaze, self.frame_index, self._max_t(camera))
        camera_moved = prev_cam != camera
        moving = bool(geometry_moved or camera_moved)
        # a still view: the history reprojects exactly, so the resolve clips it with the wider still box
        still = history and not moving
        if not self._animated:
            skipped["bvh_refit"] = "static scene"
        foveated = cfg.foveation.enabled and mode == "foveated"
        sparse = foveated and self.sparse_gbuffer
        with self._stage("gbuffer"):
            if sparse:
                self.sparse.trace_coarse_frame(frame)
            else:
                self._gbuffer(frame)
        if sparse:
            skipped["gbuffer"] = (f"sparse G-buffer: one primary ray per {cfg.foveation.coarse_cell} x "
                                  f"{cfg.foveation.coarse_cell} cell, plus the sampled pixels (traced with their shading)")
            skipped["temporal"] = "sparse G-buffer: no per-pixel history (the reconstruction fills every gap)"
        strategy = resolve_reorder_strategy(cfg.reorder.strategy, self.device) if foveated else "full"
        tc = cfg.temporal
        still_boost = (foveated and not sparse and history and not moving and tc.enabled and tc.still_min_probability > 0.0
                       and self._stochastic_shading() and self._static_frames < tc.max_history_frames)
        if still_boost:
            skipped["foveation.min_probability"] = (f"raised to TemporalConfig.still_min_probability "
                                                    f"({tc.still_min_probability:g}): still view, stochastic "
                                                    f"shading still converging")
        dof_focus = cfg.dof.enabled and cfg.dof.focus_depth_m is None
        with self._stage("sampling", foveated or dof_focus):
            if foveated:
                self.sampling.set_frame_view(self.gbuffer, frame, moving=moving, history=history,
                                             min_probability=tc.still_min_probability if still_boost else None)
                if sparse:
                    skipped["cache_test"] = "sparse G-buffer: no per-pixel history"
                skipped.update(self.sampling.skipped)
            else:
                skipped["sampling"] = "foveation disabled: sampling rate 1"
            if dof_focus:
                self.dof.focus_at_pixel(self.gbuffer.depth, self.gbuffer.hit, gaze, fov_y_deg=camera.fov_y_deg)
            self.shade.upload_view(frame)
            if self.path is not None:
                self.path.upload(frame.camera, frame.frame_index)
        rebuilt = False
        with self._stage("indirect_build", self.indirect is not None):
            if self.indirect is not None:
                rebuilt = self.indirect.update()
                skipped.update(self.indirect.skipped)
            else:
                skipped["indirect"] = "ShadingConfig.indirect is 'none'"
        # static view: same camera, nothing moved, indirect light unchanged, history kept
        static = history and not moving and not rebuilt
        self._static_frames = self._static_frames + 1 if static else 0
        refresh = self._refresh_due(foveated and not sparse)
        if refresh:
            skipped["trace"] = (f"static view, converged history: only the refresh budget "
                                f"({cfg.temporal.refresh_fraction:g} of the samples with history) traced")
        if not foveated:
            skipped["reorder"] = "sampling rate 1: every pixel traced"
            skipped["reconstruct"] = "sampling rate 1: nothing to fill"
        if not cfg.dof.enabled:
            skipped["dof"] = "pinhole camera (aperture 0)"
        if self._tonemap_fused(strategy):
            skipped["tonemap"] = ("no separate pass: the " + ("full-resolution shading" if strategy == "full" else
                                  "Sibson gather") + " writes the tone-mapped image")
        # -- body: fixed arguments (captured as a CUDA graph in steady state) -----------------------------
        if sparse:  # no history: one graph per strategy and field of view
            key = (strategy, "sparse", float(camera.fov_y_deg))
        else:
            key = (strategy, history, refresh, self.temporal._cur if foveated else 0, float(camera.fov_y_deg),
                   self.shade.splits(), still)  # the list's launches differ with the split (ShadeStage.split_direct)
        graph_state = self._run_body(key, lambda: self._body(camera, strategy, history, refresh, still))
        if graph_state == "replayed" and foveated and not sparse:
            self.temporal.swap()  # the body's host-side state: the history ping-pong ...
            self.reconstruct.set_seed_mask(self.temporal.filled)  # ... and the seed mask run_interpolate reads
        # what the body's last pass before depth of field wrote (the same buffers on a replay)
        self._hdr_out = None
        if foveated:
            self._hdr_out = (self.recon if sparse else self.remod if self.demodulation is not None else
                             self.held if self.path_history is not None else
                             self.filtered if self.path_filter is not None else self.recon)
        if ev is not None:
            self.device.stream.record_event(ev[1])
        # the policy's host work that this frame's launches do not depend on, after them: the last watched frame's
        # GPU span (read when done), and why foveation was skipped
        self._harvest_watch()
        if mode == "full" and cfg.foveation.enabled:
            skipped["foveation"] = pol.skip_reason()
        n = self.width * self.height
        stats = _LazyStats(dict(self._stats))
        stats["skipped"] = skipped
        stats["gaze_px"] = gaze
        stats["frame_index"] = self.frame_index
        stats["strategy"] = strategy
        stats["graph"] = graph_state
        stats["static_frames"] = self._static_frames
        stats["policy"] = {"policy": pol.mode, "path": mode, **pol.estimates}
        stats["history_seeded"] = seeded
        if foveated:
            ns, nh = self.sampling.num_samples, self.sampling.num_cache_hits
            stats.defer("sampling_rate", lambda: float(ns.numpy()[0]) / n)
            stats.defer("cache_hit_rate", lambda: float(nh.numpy()[0]) / n)
            if self.path is not None:
                # a path's rays vary (bounces, Russian roulette): the paths are counted, not the rays
                # (the traced pixels' list: sampled hits, the misses take the background without a path)
                bands = functools.lru_cache(maxsize=1)(functools.partial(self._paths_by_band, gaze,
                                                                          float(camera.fov_y_deg)))
                stats.defer("paths_traced", lambda: sum(b["paths"] for b in bands().values()))
                stats.defer("paths_by_band", bands)
            elif sparse:
                nc = self.sparse.num_coarse_rays
                stats.defer("rays_traced", lambda: nc + int(ns.numpy()[0]) * (1 + self._rays_per_sample()))
            else:
                stats.defer("rays_traced", lambda: n + int(ns.numpy()[0]) * self._rays_per_sample())
        elif self.path is not None:
            stats.update(sampling_rate=1.0, cache_hit_rate=0.0, paths_traced=n * int(self.config.shading.spp))
        else:
            stats.update(sampling_rate=1.0, cache_hit_rate=0.0, rays_traced=n + n * self._rays_per_sample())
        if self.timing:
            wp.synchronize_device(self.device)
            stats["ms_frame"] = (_now() - t0) * 1e3
            if self._timing_gpu:
                stats.update(self._stage_gpu_ms())
        if pol_timed:
            wp.synchronize_device(self.device)
            pol.record(mode, (_now() - t_pol) * 1e3, None if ev is None else
                       float(wp.get_event_elapsed_time(ev[0], ev[1], synchronize=False)))
        elif pol_watch:
            if ev is not None:  # read at the next frame, if the GPU is done with this one by then
                self._pol_ev_pending = ev
            else:  # the frame's work is done: CPU launches are synchronous, and timing synchronized above
                pol.watch((_now() - t_pol) * 1e3)
        self._last_full = not foveated
        self.prev_camera = camera
        self.frame_index += 1
        if sparse:
            # the G-buffer holds this frame's values only at the sampled pixels
            extras = {"sparse": self.radiance, "filled": self.sampling.sample_map,
                      "coarse_gbuffer": self.sparse.coarse}
        elif foveated:
            extras = {"sparse": self.temporal.color, "filled": self.temporal.filled}
        else:
            extras = {}
        return Frame(self.image, self.sampling.sample_map if foveated else self.full_map, self.gbuffer, stats,
                     extras)

    def _frame_events(self) -> tuple:
        """The next of two (start, end) pairs of CUDA timing events (made on first use)."""
        if self._pol_events is None:
            self._pol_events = [(wp.Event(self.device, enable_timing=True), wp.Event(self.device, enable_timing=True))
                                for _ in range(2)]
        self._pol_ev_i ^= 1
        return self._pol_events[self._pol_ev_i]

    def _harvest_watch(self) -> None:
        """Add the GPU span of the last watched frame to the watch when the GPU is done with it (never waits: a
        frame still running is left out)."""
        p, self._pol_ev_pending = self._pol_ev_pending, None
        if p is not None and p[1].is_complete:
            self.cost_policy.watch(float(wp.get_event_elapsed_time(p[0], p[1], synchronize=False)))

    def _seed_history(self) -> bool:
        """After a full-resolution frame (the cost policy's), make that frame the history of the foveated frame
        that follows, instead of a camera cut that would start it with no history at all: the temporal resolve
        of the previous frame, still in the G-buffer and ``radiance``, with every pixel traced and no older
        history (each pixel's history is then its exact full-resolution value, one frame old). Returns False
        where the foveated frame keeps no per-pixel history (sparse G-buffer, TemporalConfig.enabled False)."""
        if self.sparse_gbuffer or not self.config.temporal.enabled:
            return False
        self.temporal.run(self.full_map, self.gbuffer, self.radiance, self._fresh_stoch, use_history=False,
                          background=self.config.shading.background, **self._resolve_kind())
        return True

    def _refresh_due(self, foveated: bool) -> bool:
        """Whether this frame traces only the refresh budget: foveation and history on, a refresh fraction
        below 1, and a view static for long enough that every pixel was sampled (one full rotation of the
        block^2 threshold ranks) and the running means filled (``max_history_frames``)."""
        tc = self.config.temporal
        if not (foveated and tc.enabled and tc.refresh_fraction < 1.0):
            return False
        block = self.config.foveation.block
        return self._static_frames >= max(block * block, tc.max_history_frames)

    def _body(self, camera: Camera, strategy: str, history: bool, refresh: bool, still: bool = False) -> None:
        """The launches of one frame after the head: no host reads, no allocation, the same arguments for the
        same (strategy, history, refresh, temporal parity, field of view, still view). Its one host-side effect, the
        temporal ping-pong swap, is repeated by ``render`` after a graph replay."""
        cfg = self.config
        foveated = strategy != "full"
        sparse = foveated and self.sparse_gbuffer
        smap = self.sampling.sample_map if foveated else self.full_map
        if sparse:
            self._sparse_body(smap, strategy)
            return
        # the CPU's rows kernels with deterministic shading: the sampling pass runs in the launch that shades and
        # resolves (each tile row sampled just before its rows are shaded), unless timing wants the two apart
        sample_in_resolve = (foveated and not refresh and not self.timing and self._shade_in_resolve(strategy)
                             and parallel.use_row_kernels(self.device))
        # the cache test's previous depth and valid mask: the temporal history's, as last resolved; the Lab albedo by
        # face (no cube roots)
        pass_inputs = dict(depth_prev=self.temporal.depth, valid_prev=self.temporal.filled,
                           face_lab=self.dscene.face_lab)
        with self._stage("sampling", foveated):
            if foveated and not sample_in_resolve:
                self.sampling.launch(self.gbuffer, **pass_inputs)
                if refresh:
                    s = self.sampling
                    self.temporal.refresh(smap, s.cache_hit, s.prev_index, s.frame_params, s.num_samples,
                                          cfg.temporal.refresh_fraction, stochastic=self._stochastic_shading())
        reorders = strategy in ("scan", "tile", "rows", "rows+balance")
        with self._stage("reorder", reorders):
            if reorders:
                self.reorder.run(smap, keep=self._list_keep())
        fused = self._tonemap_fused(strategy)
        # the CPU's masked shading and deterministic resolve run as one launch (the "temporal" stage's time)
        shade_in_resolve = self._shade_in_resolve(strategy)
        with self._stage("shade", not shade_in_resolve):
            if not shade_in_resolve:
                self._trace(smap, strategy, display=self.image if fused and not foveated else None)
        with self._stage("indirect", self.indirect is not None):
            self._indirect(smap, strategy)
        with self._stage("temporal", foveated):
            if foveated:
                listed = strategy in ("scan", "tile")  # the traced pixels' flat list (clip boxes by list)
                srows = None
                if sample_in_resolve:
                    srows = self.sampling.rows_pass_args(self.gbuffer, **pass_inputs)
                self.temporal.run(smap, self.gbuffer, self.radiance, self._fresh_stoch, use_history=history,
                                  background=cfg.shading.background, **self._resolve_kind(), still=still,
                                  shade=self.shade if shade_in_resolve else None,
                                  work=self.reorder.work if listed else None,
                                  count=self.reorder.count if listed else None, sampling=srows)
                if sample_in_resolve:
                    self.sampling.sum_row_counts()
                if self._env_misses:
                    self.temporal.show_misses(self.gbuffer.hit, self.gbuffer.emission)
        with self._stage("reconstruct", foveated):
            if foveated:
                sc = cfg.shading
                seeds = self.temporal.color
                if self.demodulation is not None:
                    seeds = self.demodulation.demodulate(seeds, self.gbuffer)
                self.reconstruct.run(seeds, self.temporal.filled, self.recon,
                                     display=self.image if fused else None, exposure=float(sc.exposure),
                                     white_point=float(sc.white_point))
                hdr = self.recon
            else:
                hdr = self.radiance
        with self._stage("path_filter", foveated and self.path_filter is not None):
            if foveated and self.path_filter is not None:
                self.path_filter.run(hdr, self.gbuffer, self.sampling.frame_params, self.filtered, history)
                hdr = self.filtered
            elif self.path_filter is not None:
                self.path_filter.reset()  # a full-resolution frame: the next foveated one starts afresh
        with self._stage("path_history", foveated and self.path_history is not None):
            if foveated and self.path_history is not None:
                self.path_history.run(hdr, self.gbuffer, self.sampling.frame_params, self.held, history)
                hdr = self.held
            elif self.path_history is not None:
                self.path_history.reset()  # a full-resolution frame: the next foveated one starts afresh
        with self._stage("remodulate", foveated and self.demodulation is not None):
            if foveated and self.demodulation is not None:
                self.demodulation.remodulate(hdr, self.gbuffer, self.remod)
                hdr = self.remod
        with self._stage("dof", cfg.dof.enabled):
            if cfg.dof.enabled:
                self.dof.run(hdr, self.gbuffer.depth, self.gbuffer.hit, cfg.dof.focus_depth_m, self.dof_out,
                             fov_y_deg=camera.fov_y_deg)
                hdr = self.dof_out
        with self._stage("tonemap", not fused):
            if not fused:
                self._tonemap(hdr, self.image)

    def _shade_in_resolve(self, strategy: str) -> bool:
        """Whether the temporal resolve shades the sampled pixels in its own launch (TemporalStage.can_shade: the
        CPU's rows kernels, deterministic shading) instead of a separate masked shading pass: the masked
        strategy, with nothing (indirect light) added to the shading between the two."""
        return (strategy == "none" and self.indirect is None and not self.shade.textured and self.path is None
                and self.temporal.can_shade(self._stochastic_shading()))

    def _tonemap_fused(self, strategy: str) -> bool:
        """Whether the frame's last pass writes the display image itself (no separate tone-map pass): nothing
        may follow it (no depth of field), and it must be the full-resolution shading (with no indirect light
        added after it) or the bounded Sibson gather."""
        if self.config.dof.enabled:
            return False
        if strategy == "full":
            return self.indirect is None and self.path is None
        if self.path_filter is not None or self.path_history is not None or self.demodulation is not None:
            return False  # the filter, the history blend or the remodulation follows the reconstruction
        rc = self.reconstruct
        return bool(rc.config.sibson and not rc.exact_sibson)

    def _sparse_body(self, smap, strategy: str) -> None:
        """The body of a sparse-G-buffer frame: sampling map from the coarse G-buffer, compaction, primary rays
        and shading of the sampled pixels, indirect light, reconstruction from the samples alone, tone map."""
        with self._stage("sampling"):
            self.sparse.sample(self.sampling)
        # the sampled pixels' primary rays need a flat list: the row and masked strategies compact one too
        list_strategy = strategy if strategy in ("scan", "tile") else "scan"
        with self._stage("reorder"):
            self.reorder.run(smap, strategy=list_strategy)
        with self._stage("shade"):
            self.sparse.trace_shade(self.gbuffer, self.shade, self.reorder.work, self.reorder.count, self.radiance,
                                    self.radiance_stoch)
        with self._stage("indirect", self.indirect is not None):
            self._indirect(smap, list_strategy)
        fused = self._tonemap_fused(strategy)
        with self._stage("reconstruct"):
            sc = self.config.shading
            self.reconstruct.run(self.radiance, smap, self.recon, display=self.image if fused else None,
                                 exposure=float(sc.exposure), white_point=float(sc.white_point))
        with self._stage("tonemap", not fused):
            if not fused:
                self._tonemap(self.recon, self.image)

    def _run_body(self, key, body) -> str:
        """Run ``body`` eagerly, or (CUDA, graphs on) replay its captured graph for ``key``: the first frame of
        a key runs eagerly (kernels compile and load), the second is captured and launched, later ones replay.
        Returns what happened: "eager", "warm-up", "captured", "replayed" or "eager (capture failed: ...)"."""
        if not self._graphs_on:
            body()
            return "eager"
        if not self._on_cuda:
            return self._run_body_cpu(key, body)
        g = self._graphs.get(key)
        if g is not None:
            wp.capture_launch(g)
            return "replayed"
        if key not in self._warm_keys:
            body()
            self._warm_keys.add(key)
            return "warm-up"
        try:
            with wp.ScopedCapture(device=self.device) as cap:
                body()
        except Exception as e:  # capture impossible on this setup: fall back to eager launches for good
            self._graphs_on = False
            self._graph_error = f"{type(e).__name__}: {e}"
            body()
            return f"eager (capture failed: {self._graph_error})"
        self._graphs[key] = cap.graph
        wp.capture_launch(cap.graph)
        return "captured"

    def _run_body_cpu(self, key, body) -> str:
        """``_run_body`` on the CPU: the first frame of a key runs eagerly, the second runs while its CPU work is
        recorded (``parallel.record``), later ones replay the recording (for the thread count it was made with;
        another count records anew). A recording that cannot be replayed (a host read in the body) turns
        replays off for this loop and says why. Inside the caller's own ``parallel.record`` block the body runs
        eagerly (the caller's recording takes its work)."""
        if parallel.recording_active():  # inside the caller's own recording: eager, so that it sees the work
            body()
            return "eager (inside a parallel.record block)"
        prog = self._graphs.get(key)
        if prog is not None and prog.threads == parallel.current_cpu_threads():
            prog.replay()
            return "replayed"
        if key not in self._warm_keys:
            body()
            self._warm_keys.add(key)
            return "warm-up"
        with parallel.record() as prog:
            body()
        if prog.problem is not None:
            self._graphs_on = False
            self._graph_error = prog.problem
            return f"eager (recording not replayable: {prog.problem})"
        self._graphs[key] = prog
        return "captured"

    def _list_keep(self):
        """The second mask of the full-G-buffer frame's compaction (``ReorderStage.run(keep=...)``): the G-buffer's
        hits with ``ReorderConfig.skip_misses``, else None (every sampled pixel). A miss's colour is the
        background, written by the temporal resolve, and the indirect gather skips it too."""
        return self.gbuffer.hit if self.config.reorder.skip_misses else None

    def _rays_per_sample(self) -> int:
        """Secondary rays per shaded pixel (shadow rays, area-light samples, AO rays)."""
        sc = self.config.shading
        r = self.dscene.num_lights * (1 if sc.shadows else 0)
        r += self.dscene.num_area_lights * sc.area_light_samples * (1 if sc.shadows else 0)
        return r + sc.ao_samples

    def _trace(self, smap, strategy: str, display=None) -> None:
        """Shade the sampled pixels with the shading parameters last uploaded by ``upload_shade_params``
        (``display``: the full-resolution shading also writes the tone-mapped image)."""
        g, out, st = self.gbuffer, self.radiance, self.radiance_stoch
        if self.path is not None:
            self._trace_paths(smap, strategy)
        elif strategy == "full":
            self.shade.full(g, out, st, display)
        elif strategy == "none":
            self.shade.masked(g, smap, out, st)
        elif strategy in ("rows", "rows+balance"):
            self.shade.rows(g, self.reorder.coords, self.reorder.counts, out, st)
        else:
            self.shade.list(g, self.reorder.work, self.reorder.count, out, st)

    def _paths_by_band(self, gaze, fov_y_deg: float) -> dict:
        """Paths of the last foveated frame by eccentricity band around ``gaze`` (degrees: "0-5", "5-20",
        "20+"): the band's pixels, its traced pixels, their paths and the paths per pixel of the band (host reads
        of the list and of the paths per pixel)."""
        from .ops.sampling import eccentricity_deg

        n = int(self.reorder.count.numpy()[0])
        idx = self.reorder.work.numpy()[:n]
        paths = self.path.spp_used.numpy().ravel()[idx].astype(np.int64)
        # on the loop's device (a CPU kernel would need Warp's CPU compiler on a CUDA machine)
        ecc = eccentricity_deg(self.width, self.height, gaze, fov_y_deg, device=self.device).ravel()
        e = ecc[idx]
        out = {}
        for name, lo, hi in (("0-5", -1.0, 5.0), ("5-20", 5.0, 20.0), ("20+", 20.0, math.inf)):
            pix = int(np.count_nonzero((ecc > lo) & (ecc <= hi)))
            sel = (e > lo) & (e <= hi)
            p = int(paths[sel].sum())
            out[name] = {"pixels": pix, "traced": int(np.count_nonzero(sel)), "paths": p,
                         "paths_per_pixel": p / pix if pix else 0.0}
        return out

    def _trace_paths(self, smap, strategy: str) -> None:
        """The path integrator's ``_trace``: ``ShadingConfig.spp`` paths per sampled pixel (every pixel with the
        "full" strategy) from the parameters uploaded in the head, over the traced pixels' flat list (compacted
        here for the row and masked strategies). Every term of a path estimate is Monte Carlo: the resolve reads
        the radiance as its stochastic part too (``_fresh_stoch``)."""
        if strategy == "full":
            self.path.launch(self.radiance)
        else:
            if strategy not in ("scan", "tile"):
                self.reorder.run(smap, strategy="scan", keep=self._list_keep())
            self.path.launch(self.radiance, self.reorder.work, self.reorder.count, self.sampling.probability)

    def _indirect(self, smap, strategy: str) -> None:
        """Add the light-tree indirect light at the sampled pixels (the structures were updated in the head)."""
        if self.indirect is None:
            return
        if strategy == "full":
            self.indirect.run_full(self.gbuffer, self.radiance)
            return
        if strategy not in ("scan", "tile"):
            # the row and masked launches have no flat list: compact one for the gather
            self.reorder.run(smap, strategy="scan", keep=self._list_keep())
        self.indirect.run_list(self.gbuffer, self.reorder.work, self.reorder.count, self.radiance, self.width)


class _LazyStats(dict):
    """A dict whose device-counter entries are read (one small host copy) only when first accessed."""

    def __init__(self, *a, **kw):
        super().__init__(*a, **kw)
        self._pending = {}

    def defer(self, key, fn) -> None:
        self._pending[key] = fn

    def _resolve(self) -> None:
        if self._pending:
            pending, self._pending = self._pending, {}
            for k, fn in pending.items():
                dict.__setitem__(self, k, fn())

    def __getitem__(self, k):
        self._resolve()
        return dict.__getitem__(self, k)

    def __contains__(self, k):
        return k in self._pending or dict.__contains__(self, k)

    def __iter__(self):
        self._resolve()
        return dict.__iter__(self)

    def __len__(self):
        self._resolve()
        return dict.__len__(self)

    def __repr__(self):
        self._resolve()
        return dict.__repr__(self)

    def get(self, k, default=None):
        self._resolve()
        return dict.get(self, k, default)

    def keys(self):
        self._resolve()
        return dict.keys(self)

    def items(self):
        self._resolve()
        return dict.items(self)

    def values(self):
        self._resolve()
        return dict.values(self)

    def copy(self):
        self._resolve()
        return dict(self)


def _describe(a) -> str:
    """What an array argument is, for error messages: type, dtype, shape and device."""
    if isinstance(a, wp.array):
        return f"wp.array of {getattr(a.dtype, '__name__', a.dtype)} with shape {tuple(a.shape)} on {a.device}"
    if isinstance(a, np.ndarray):
        return f"ndarray of {a.dtype} with shape {a.shape}"
    return f"{show(a)} ({type(a).__name__})"


def _now() -> float:
    return time.perf_counter()
