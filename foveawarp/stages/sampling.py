"""Sampling stage (ALGORITHMS.md A2): foveation probability, saliency, binarized sampling map and the
reprojection cache test, as one fused pass plus a tile pass, with every buffer allocated once."""

from __future__ import annotations

import functools
import math
from typing import NamedTuple, Optional

import numpy as np
import warp as wp

from .. import parallel
from .._util import check_image_size, get_device
from ..camera import Camera, _check_gaze
from ..config import Config, check_bool, check_int_range, check_range, check_vec, show
from ..kernels.camera import CameraParams
from ..kernels.context import FrameContext
from ..kernels.saliency import LAB_STEP_FULL, NORMAL_STEP_FULL, SOBEL_GAIN, lab_kernel
from ..kernels.sampling import (
    FrameParams,
    SamplingParams,
    frame_setup_kernel,
    sampling_map_kernel,
    sampling_rows_kernel,
    tile_counts_sum_kernel,
    tile_pass_bands_kernel,
    tile_pass_kernel,
)

__all__ = ["SamplingStage", "dither_ranks", "rank_step", "frame_rotation", "launch_tile_pass", "GAZE_LIMIT_PX"]

GOLDEN = 0.6180339887498949
# Gaze coordinates farther than this from the screen are clamped to it: every angle is then within
# ~1e-3 deg of its limit, and float32 plane directions stay far from overflow.
GAZE_LIMIT_PX = 1.0e6
# FoveationConfig.falloff_deg None: the normalizer's eccentricity is the screen's largest (thesis eq. 2)
NO_FALLOFF = 1.0e9
# threads per block of the tile pass on CUDA (the CPU runs blocks of one thread)
TILE_PASS_THREADS = 256


# -- threshold ranks -------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=None)
def _dither_ranks_cached(block: int) -> np.ndarray:
    k = block
    n = k * k
    if k == 1:
        return np.zeros((1, 1), dtype=np.int32)
    # Void-and-cluster style progressive ordering on the k x k torus (Ulichney 1993): each next rank goes to
    # the free pixel with the least Gaussian "energy" from the ranks already placed (sigma 1.5 px; periodic
    # images summed so the tile tiles seamlessly). Ties resolve to the first pixel in raster order.
    sigma = 1.5
    d = np.arange(k, dtype=np.float64)
    reps = np.arange(-3, 4)[:, None] * k
    g1 = np.exp(-((d[None, :] + reps) ** 2) / (2.0 * sigma * sigma)).sum(axis=0)  # periodic 1D Gaussian
    kernel = np.outer(g1, g1)  # energy at offset (dy, dx)
    energy = np.zeros((k, k))
    ranks = np.full((k, k), -1, dtype=np.int32)
    for r in range(n):
        masked = np.where(ranks < 0, energy, np.inf)
        i = int(np.argmin(masked))
        y, x = divmod(i, k)
        ranks[y, x] = r
        energy += np.roll(np.roll(kernel, y, axis=0), x, axis=1)
    return ranks


def dither_ranks(block: int) -> np.ndarray:
    """(block, block) int32 permutation of 0 .. block^2 - 1 with blue-noise spacing: for every m the pixels of
    rank < m are spread evenly over the tile (deterministic; cached)."""
    k = check_int_range("block", block, 1, 64)
    return _dither_ranks_cached(k).copy()


def rank_step(num_ranks: int) -> int:
    """Per-frame rank rotation: the integer nearest 0.618 K (golden ratio) that is coprime with K, so that K
    consecutive frames give each pixel every rank once, and consecutive frames are far apart in rank."""
    if num_ranks <= 1:
        return 0
    s0 = int(round(num_ranks * GOLDEN))
    for d in range(num_ranks):
        for s in (s0 - d, s0 + d):
            if 0 < s < num_ranks and math.gcd(s, num_ranks) == 1:
                return s
    return 1


def frame_rotation(frame_index: int, block: int) -> tuple:
    """(rot, phase) of frame ``frame_index``: the rank rotation in [0, K) and the jitter phase in [0, 1)."""
    n = block * block
    rot = ((frame_index % n) * rank_step(n)) % n
    phase = math.fmod((frame_index // n) * GOLDEN, 1.0)
    return int(rot), float(phase)


def sampling_params(config: Config, width: int, height: int, seed: int = 0) -> SamplingParams:
    """The kernels' constant struct for ``config`` at ``width`` x ``height``."""
    fc, sc, tc = config.foveation, config.saliency, config.temporal
    sp = SamplingParams()
    sp.mar_slope = float(fc.mar_slope)
    sp.mar_fovea_deg = float(fc.mar_fovea_deg)
    sp.fovea_deg = float(fc.fovea_deg)
    sp.xi = float(fc.effective_min_probability)
    sp.foveation = 1 if fc.enabled else 0
    sp.use_albedo = 1 if sc.use_albedo else 0
    sp.use_normal = 1 if sc.use_normal else 0
    sp.albedo_gain = float(sc.albedo_scale) / (SOBEL_GAIN * LAB_STEP_FULL)
    sp.normal_gain = float(sc.normal_scale) / (SOBEL_GAIN * NORMAL_STEP_FULL)
    sp.inv_velocity_px = 1.0 / float(sc.velocity_scale_px)
    sp.sigma1_m = float(sc.sigma1_m)
    sp.sigma2_m = float(sc.sigma2_m)
    sp.dof_floor = float(sc.dof_floor)
    sp.depth_eps_rel = float(tc.depth_eps_rel)
    sp.block = int(fc.block)
    sp.tiles_x = (width + fc.block - 1) // fc.block
    sp.num_ranks = int(fc.block * fc.block)
    sp.block_shift = int(fc.block).bit_length() - 1 if (fc.block & (fc.block - 1)) == 0 else -1
    sp.seed = int(seed)
    return sp


def launch_tile_pass(ranks, params: SamplingParams, frame_params, tiles: tuple, sample_map, cache_hit, num_samples,
                     num_cache_hits, device, tile_counts=None) -> None:
    """The tile guarantee + counters pass over ``tiles`` = (tiles_y, tiles_x) aligned tiles. On the CPU with
    more than one thread: band-parallel per-tile counts into ``tile_counts`` ((tiles_y, tiles_x) vec2i scratch;
    allocated here when None), then a one-thread sum (the same counts as the tiled kernel's atomics)."""
    if device.is_cpu and parallel.current_cpu_threads() > 1:
        if tile_counts is None:
            tile_counts = wp.empty(tiles, dtype=wp.vec2i, device=device)
        parallel.launch(tile_pass_bands_kernel, dim=tiles, inputs=[ranks, params, frame_params, sample_map, cache_hit],
                        outputs=[tile_counts], device=device, min_band_items=128)  # a tile item = block^2 pixels
        wp.launch(tile_counts_sum_kernel, dim=1, inputs=[tile_counts, 1], outputs=[num_samples, num_cache_hits],
                  device=device)
        return
    threads = TILE_PASS_THREADS if device.is_cuda else 1
    n = tiles[0] * tiles[1]
    wp.launch_tiled(tile_pass_kernel, dim=[(n + threads - 1) // threads],
                    inputs=[ranks, params, frame_params, tiles[0]],
                    outputs=[sample_map, cache_hit, num_samples, num_cache_hits], block_dim=TILE_PASS_THREADS,
                    device=device)


def clamp_gaze(gaze, width: int, height: int) -> tuple:
    gx = min(max(float(gaze[0]), -GAZE_LIMIT_PX), width + GAZE_LIMIT_PX)
    gy = min(max(float(gaze[1]), -GAZE_LIMIT_PX), height + GAZE_LIMIT_PX)
    return gx, gy


def _eye(name: str, v) -> wp.vec3:
    return wp.vec3(*check_vec(name, v, 3))


# -- stage -----------------------------------------------------------------------------------------------------


class RowsPass(NamedTuple):
    """``SamplingStage.rows_pass_args``: the frame pass for a kernel that runs it over rows of tiles itself."""

    tile_rows: int
    args: list  # the sample_shade_resolve_rows_kernel's s_* arguments
    sample_map: wp.array  # what the pass writes
    depth_prev: wp.array  # the history its cache test reads
    valid_prev: wp.array


class SamplingStage:
    """Foveated sampling map + reprojection cache test for one image size and config.

    Buffers (all (H, W) wp.arrays on ``device``, overwritten by each ``run``):
        probability: float32, thesis eq. 2 foveation probability p(w) in [xi, 1] (1 when foveation is off).
        saliency: float32, thesis eq. 3 ``clip(max(dA, dN, V, p) * F_DoF, xi, 1)``: the per-pixel sampling
            probability that ``sample_map`` follows (long-run rate exactly ``saliency`` in full tiles).
            These two are computed on request (nothing in a frame reads them): reading either property
            launches one pass that writes both, from the frame values of the last ``set_frame`` and the
            G-buffer given to it as it is at the time of reading (in ``FrameLoop``, read them before the next
            ``render`` or ``render_reference``). The values are those the frame's ``sample_map`` thresholds.
        sample_map: uint8, 1 where a ray is traced this frame; every aligned block x block tile holds >= 1.
        cache_hit: uint8, 1 where the reprojected history passes the cache test (0 everywhere when skipped).
        prev_index: int32, flat index ``y * W + x`` of the previous-frame pixel on a cache hit, else -1.
        depth_prev, valid_prev: the previous frame's depth (metres) and valid-color mask, set by ``end_frame``.
        lab: vec3, the CIE-Lab albedo (a prepass, so each pixel is converted once; (1, 1) when unused).
    Counters (1-element int32 wp.arrays, updated on the device with atomics; read them only for stats):
        num_samples, num_cache_hits.
    ``skipped``: dict of what this frame did not compute and why (keys "foveation", "saliency.albedo",
    "saliency.normal", "saliency.velocity", "saliency.dof", "cache_test").

    Policies: background pixels (G-buffer hit 0: albedo 0, normal 0) enter the gradient terms as they are, so
    silhouettes get samples on both sides, but get no velocity term and no DoF factor. The DoF focus is
    ``DofConfig.focus_depth_m`` or else the G-buffer depth at the gaze pixel (gaze clamped to the screen, read
    on the device); when that pixel is background the DoF factor is 1 for the frame.

    Args:
        width, height: image size in pixels.
        config: the full :class:`foveawarp.Config` (foveation, saliency, dof and temporal sections are used).
        device: Warp device.
        seed: seed of the threshold pattern, in [0, 2^31 - 1].
    """

    def __init__(self, width: int, height: int, config: Optional[Config] = None, device=None, *, seed: int = 0):
        self.width, self.height = check_image_size(width, height)
        if config is None:
            config = Config()
        if not isinstance(config, Config):
            raise ValueError(f"config must be a foveawarp.Config, got {type(config).__name__}")
        self.config = config
        self.seed = check_int_range("seed", seed, 0, 2**31 - 1)
        self.device = get_device(device)
        w, h, dev = self.width, self.height, self.device
        k = config.foveation.block
        self.block = k
        self.tiles = ((h + k - 1) // k, (w + k - 1) // k)
        self.params = sampling_params(config, w, h, self.seed)
        self.ranks = wp.array(dither_ranks(k), dtype=wp.int32, device=dev)
        self.frame_params = wp.zeros(1, dtype=FrameParams, device=dev)
        self._lab_on = bool(config.foveation.enabled and config.saliency.use_albedo)
        # the Lab prepass's output, allocated on first use (a FrameLoop reads the scene's per-face table instead)
        self.lab = wp.zeros((1, 1), dtype=wp.vec3, device=dev)
        self._no_face_lab = wp.zeros(1, dtype=wp.vec3, device=dev)
        self._probability = None  # allocated on the first request (see ``probability``)
        self._saliency = None
        self._maps_gbuffer = None  # the G-buffer of the last set_frame, and whether the maps are of that frame
        self._maps_current = False
        self._maps_external = False  # True: another pass writes the maps (``map_buffers``)
        self.sample_map = wp.zeros((h, w), dtype=wp.uint8, device=dev)
        self.cache_hit = wp.zeros((h, w), dtype=wp.uint8, device=dev)
        self.prev_index = wp.full((h, w), -1, dtype=wp.int32, device=dev)
        self.depth_prev = wp.zeros((h, w), dtype=float, device=dev)
        self.valid_prev = wp.zeros((h, w), dtype=wp.uint8, device=dev)
        self._dummy_map = wp.zeros((1, 1), dtype=float, device=dev)  # the frame pass writes no maps
        self.num_samples = wp.zeros(1, dtype=wp.int32, device=dev)
        self.num_cache_hits = wp.zeros(1, dtype=wp.int32, device=dev)
        # per-tile (samples, cache hits) of the CPU's band-parallel tile pass (see ``launch_tile_pass``)
        self.tile_counts = wp.zeros(self.tiles if dev.is_cpu else (1, 1), dtype=wp.vec2i, device=dev)
        # per-tile-row sums of the CPU's rows pass (sampling_rows_kernel), and its one-thread count sum, recorded
        self._row_counts = wp.zeros((self.tiles[0] if dev.is_cpu else 1, 1), dtype=wp.vec2i, device=dev)
        self._sum_launch = parallel.Relaunch(tile_counts_sum_kernel, bands=False)
        self._setup_launch = parallel.Relaunch(frame_setup_kernel, bands=False)  # recorded once on CUDA
        self.skipped: dict = {}

    # -- per frame ---------------------------------------------------------------------------------------------
    def run(self, gbuffer, camera: Camera, gaze_px, frame_index: int, *, moving: bool, first_frame: bool,
            eye_prev=None, camera_prev: Optional[Camera] = None) -> None:
        """Fill probability, saliency, sample_map, cache_hit, prev_index and the counters for this frame:
        ``set_frame(...)`` then ``launch(gbuffer)`` (same arguments as ``set_frame``)."""
        self.set_frame(gbuffer, camera, gaze_px, frame_index, moving=moving, first_frame=first_frame,
                       eye_prev=eye_prev, camera_prev=camera_prev)
        self.launch(gbuffer)

    def set_frame_view(self, gbuffer, frame, *, moving: bool, history: bool,
                       min_probability: Optional[float] = None) -> None:
        """``set_frame`` for the frame context ``frame`` (``foveawarp.frame_context.FrameView``), whose struct the
        setup kernel reads: its gaze, camera and frame index, and with ``history`` its previous camera (the cache
        test's previous eye, and the velocity term's camera motion); without, the frame is a first frame or follows
        a cut."""
        self._setup(gbuffer, frame.struct, frame.frame_index, moving=moving, first_frame=not history,
                    object_prev=history, min_probability=min_probability)

    def set_frame(self, gbuffer, camera: Camera, gaze_px, frame_index: int, *, moving: bool, first_frame: bool,
                  eye_prev=None, camera_prev: Optional[Camera] = None, min_probability: Optional[float] = None) -> None:
        """Validate this frame's inputs, decide what to skip (``self.skipped``) and launch the one-thread setup
        kernel that writes every per-frame value (gaze, w_min, w_far, focus depth read from the G-buffer at the
        gaze pixel, threshold rotation, flags) to ``self.frame_params`` on the device, from a frame context
        packed of these arguments (``set_frame_view`` takes one already packed).

        Args:
            gbuffer: the current :class:`GBuffer` (same size and device).
            camera: the current camera (its field of view drives the eccentricity).
            gaze_px: gaze (x, y) in pixels; off screen is valid (the fovea may lie off screen; beyond
                ``GAZE_LIMIT_PX`` it is clamped); NaN raises ValueError.
            frame_index: frame counter >= 0; selects the threshold rotation (K = block^2 frames per cycle).
            moving: whether anything in the scene moved since the previous frame; False skips the velocity term.
            first_frame: True on the first frame or after a camera cut: the cache test is skipped (no hits).
            eye_prev: previous eye position (world units); required unless ``first_frame``.
            camera_prev: optional previous camera; given, the velocity term uses object motion only
                (camera motion removed), otherwise the G-buffer velocity (which includes camera motion).
            min_probability: this frame's minimum probability xi in [0, 1]; None: the config's
                (``FoveationConfig.effective_min_probability``); a smaller value is raised to it.
        """
        w, h = self.width, self.height
        gaze = _check_gaze(gaze_px)
        fi = check_int_range("frame_index", frame_index, 0, None)
        if not isinstance(camera, Camera):
            raise ValueError(f"camera must be a foveawarp.Camera, got {type(camera).__name__}")
        first = check_bool("first_frame", first_frame)
        if camera_prev is not None and not isinstance(camera_prev, Camera):
            raise ValueError(f"camera_prev must be a foveawarp.Camera or None, got {type(camera_prev).__name__}")
        if not first and self.config.temporal.enabled and eye_prev is None:
            raise ValueError("eye_prev must be 3 finite numbers (the previous eye position) unless first_frame "
                             "is True, got None")
        ctx = FrameContext()
        ctx.cam = camera.params(w, h)
        gx, gy = clamp_gaze(gaze, w, h)
        ctx.gaze = wp.vec2(gx, gy)
        ctx.frame = fi
        ctx.max_t = 1.0  # unused by the setup kernel
        # the previous camera's parameters with the previous eye (a copy: params are cached per camera)
        src = (camera_prev if camera_prev is not None else camera).params(w, h)
        prev = CameraParams()
        for k in ("right", "up", "forward", "tan_half_fov_y", "aspect", "width", "height"):
            setattr(prev, k, getattr(src, k))
        prev.eye = _eye("eye_prev", eye_prev) if eye_prev is not None else src.eye
        ctx.cam_prev = prev
        self._setup(gbuffer, ctx, fi, moving=moving, first_frame=first, object_prev=camera_prev is not None,
                    min_probability=min_probability)

    def _setup(self, gbuffer, ctx, frame_index: int, *, moving: bool, first_frame: bool, object_prev: bool,
               min_probability: Optional[float]) -> None:
        """The setup launch of ``set_frame`` / ``set_frame_view`` for the frame context struct ``ctx``: the skip
        decisions, then the kernel. ``object_prev``: ``ctx.cam_prev`` is the previous frame's camera (the velocity
        term removes camera motion with it)."""
        w, h = self.width, self.height
        self._check_gbuffer(gbuffer)
        moving = check_bool("moving", moving)
        first_frame = check_bool("first_frame", first_frame)
        cfg = self.config
        fc, sc = cfg.foveation, cfg.saliency
        skipped = {}
        do_cache = 1
        if not cfg.temporal.enabled:
            do_cache = 0
            skipped["cache_test"] = "TemporalConfig.enabled is False"
        elif first_frame:
            do_cache = 0
            skipped["cache_test"] = "first frame or camera cut: no history"
        use_vel = 0
        focus_mode, focus = 0, 0.0
        if not fc.enabled:
            skipped["foveation"] = "FoveationConfig.enabled is False: every pixel traced"
            for term in ("albedo", "normal", "velocity", "dof"):
                skipped[f"saliency.{term}"] = "foveation disabled"
        else:
            if not sc.use_albedo:
                skipped["saliency.albedo"] = "SaliencyConfig.use_albedo is False"
            if not sc.use_normal:
                skipped["saliency.normal"] = "SaliencyConfig.use_normal is False"
            if not sc.use_velocity:
                skipped["saliency.velocity"] = "SaliencyConfig.use_velocity is False"
            elif not moving:
                skipped["saliency.velocity"] = "nothing moved"
            else:
                use_vel = 1
            if not sc.use_dof:
                skipped["saliency.dof"] = "SaliencyConfig.use_dof is False"
            elif not cfg.dof.enabled:
                skipped["saliency.dof"] = "pinhole camera (DofConfig.aperture_m == 0)"
            elif cfg.dof.focus_depth_m is not None:
                focus_mode, focus = 1, float(cfg.dof.focus_depth_m)
            else:
                focus_mode = 2  # the G-buffer depth at the gaze pixel, read on the device
        obj_vel = 1 if use_vel and object_prev else 0
        xi = float(self.params.xi)
        if min_probability is not None:
            xi = max(xi, check_range("min_probability", min_probability, 0.0, 1.0))
        rot, phase = frame_rotation(frame_index, self.block)
        self.skipped = skipped
        self._maps_gbuffer, self._maps_current = gbuffer, False
        self._setup_launch(1,
                           inputs=[ctx, w, h, self.params.mar_slope, self.params.mar_fovea_deg,
                                   NO_FALLOFF if fc.falloff_deg is None else float(fc.falloff_deg), focus_mode, focus,
                                   gbuffer.depth, gbuffer.hit, use_vel, obj_vel, do_cache, rot, phase, xi,
                                   float(fc.fovea_deg)],
                           outputs=[self.frame_params], device=self.device)

    def launch(self, gbuffer, *, depth_prev=None, valid_prev=None, face_lab=None) -> None:
        """The per-pixel work of the frame set by ``set_frame``: Lab prepass, fused pass, tile pass, counters.

        Every argument is fixed (buffers and constants; the per-frame values are read from
        ``self.frame_params``), so on CUDA this can be captured once in a graph and replayed after each
        ``set_frame`` as long as the G-buffer arrays stay the same objects.

        Args:
            gbuffer: the current :class:`GBuffer` (the one given to ``set_frame``).
            depth_prev, valid_prev: the previous frame's depth (float) and valid-colour mask (uint8), (H, W)
                wp.arrays on this device, for the cache test; None (default): this stage's own ``depth_prev``
                and ``valid_prev`` (kept by ``end_frame``). ``FrameLoop`` passes the temporal history's
                ``depth`` and ``filled``, which the resolve already holds, instead of copying them.
        """
        w, h = self.width, self.height
        g, dev = self._check_gbuffer(gbuffer), self.device
        rows = parallel.use_row_kernels(dev)
        if not rows:  # the rows path's count sum writes the counters
            self.num_samples.zero_()
            self.num_cache_hits.zero_()
        dp, vp, table, by_face = self._frame_inputs(g, depth_prev, valid_prev, face_lab)
        args = [self.params, self.frame_params, self.ranks, self.lab, g.normal, g.depth, g.hit, g.position,
                g.reproj_uv, g.prev_dist, dp, vp, 0, g.face, table, by_face]
        outs = [self._dummy_map, self._dummy_map, self.sample_map, self.cache_hit, self.prev_index]
        if rows:
            # the map and the tile pass in one launch over rows of tiles, then the one-thread count sum over the
            # tile rows' sums
            parallel.launch(sampling_rows_kernel, dim=self.tiles[0], inputs=args, outputs=[*outs, self._row_counts],
                            device=dev, min_band_items=1)
            self.sum_row_counts()
            return
        outs.append(self.tile_counts)
        parallel.launch(sampling_map_kernel, dim=(h, w), inputs=args, outputs=outs, device=dev)
        launch_tile_pass(self.ranks, self.params, self.frame_params, self.tiles, self.sample_map, self.cache_hit,
                         self.num_samples, self.num_cache_hits, dev, self.tile_counts)

    def rows_pass_args(self, gbuffer, depth_prev=None, valid_prev=None, face_lab=None) -> "RowsPass":
        """``launch``'s frame pass, for a CPU kernel that runs it over rows of tiles itself
        (``sample_shade_resolve_rows_kernel``: the pass and the masked shading and resolve in one launch;
        ``TemporalStage.run(sampling=...)``), after the checks and the Lab prepass ``launch`` makes: a
        :class:`RowsPass` with the tile rows, the arguments that kernel takes before its shading ones (its ``s_*``
        parameters), the map the pass must write and the history its cache test reads. The caller launches it, then
        calls :meth:`sum_row_counts`. CPU rows kernels only (``parallel.use_row_kernels``)."""
        if not parallel.use_row_kernels(self.device):
            raise ValueError(f"rows_pass_args needs the CPU's rows kernels (parallel.use_row_kernels), got device "
                             f"{self.device}")
        dp, vp, table, by_face = self._frame_inputs(self._check_gbuffer(gbuffer), depth_prev, valid_prev, face_lab)
        # the pass's arguments that the shading does not share (it passes the G-buffer's itself)
        args = [self.params, self.frame_params, self.ranks, self.lab, gbuffer.position, dp, vp, table, by_face,
                self._dummy_map, self.cache_hit, self.prev_index, self._row_counts]
        return RowsPass(self.tiles[0], args, self.sample_map, dp, vp)

    def sum_row_counts(self) -> None:
        """The one-thread sum of the rows pass's tile-row counts into ``num_samples`` and ``num_cache_hits``."""
        self._sum_launch(1, inputs=[self._row_counts, 0], outputs=[self.num_samples, self.num_cache_hits],
                         device=self.device)

    def _frame_inputs(self, g, depth_prev, valid_prev, face_lab) -> tuple:
        """(depth_prev, valid_prev, Lab table, lab_by_face) of the frame pass, checked (the Lab prepass launched
        when needed)."""
        w, h, dev = self.width, self.height, self.device
        dp = self.depth_prev if depth_prev is None else self._check_prev("depth_prev", depth_prev, wp.float32)
        vp = self.valid_prev if valid_prev is None else self._check_prev("valid_prev", valid_prev, wp.uint8)
        by_face = 0
        table = self._no_face_lab
        if face_lab is not None:
            if not (isinstance(face_lab, wp.array) and face_lab.dtype == wp.vec3 and face_lab.ndim == 1
                    and face_lab.device == dev):
                got = (f"a {type(face_lab).__name__} of shape {getattr(face_lab, 'shape', None)}, dtype "
                       f"{getattr(getattr(face_lab, 'dtype', None), '__name__', getattr(face_lab, 'dtype', None))}")
                raise ValueError(f"face_lab must be a 1-D vec3 wp.array on {dev} (DeviceScene.face_lab), got {got}")
            by_face, table = 1, face_lab
        elif self._lab_on:
            parallel.launch(lab_kernel, dim=(h, w), inputs=[g.albedo], outputs=[self._lab_array()], device=dev)
        return dp, vp, table, by_face

    def _lab_array(self) -> wp.array:
        if tuple(self.lab.shape) != (self.height, self.width):
            self.lab = wp.zeros((self.height, self.width), dtype=wp.vec3, device=self.device)
        return self.lab

    # -- probability and saliency maps, on request ---------------------------------------------------------------
    @property
    def probability(self) -> wp.array:
        """(H, W) float32: the eq. 2 foveation probability of the last ``set_frame`` (computed on request)."""
        return self._maps()[0]

    @property
    def saliency(self) -> wp.array:
        """(H, W) float32: the eq. 3 saliency (the sampling probability) of the last ``set_frame`` (computed
        on request)."""
        return self._maps()[1]

    def map_buffers(self) -> tuple:
        """(probability, saliency) (H, W) float32 arrays for a pass that computes the sampling map itself and
        writes both maps every frame (the sparse G-buffer's): from this call on, ``probability`` and
        ``saliency`` return them as that pass wrote them and compute nothing."""
        self._maps_external = True
        return self._maps()

    def _maps(self) -> tuple:
        """Compute (once per ``set_frame``) and return (probability, saliency): the fused kernel's own code in
        its maps-only mode, so the values are exactly those ``sample_map`` was thresholded with."""
        w, h, dev = self.width, self.height, self.device
        if self._probability is None:
            self._probability = wp.zeros((h, w), dtype=float, device=dev)
            self._saliency = wp.zeros((h, w), dtype=float, device=dev)
        g = self._maps_gbuffer
        if g is not None and not self._maps_current and not self._maps_external:
            if self._lab_on:
                parallel.launch(lab_kernel, dim=(h, w), inputs=[g.albedo], outputs=[self._lab_array()], device=dev)
            parallel.launch(sampling_map_kernel, dim=(h, w),
                            inputs=[self.params, self.frame_params, self.ranks, self.lab, g.normal, g.depth, g.hit,
                                    g.position, g.reproj_uv, g.prev_dist, self.depth_prev,
                                    self.valid_prev, 1, g.face, self._no_face_lab, 0],
                            outputs=[self._probability, self._saliency, self.sample_map, self.cache_hit,
                                     self.prev_index, self.tile_counts],
                            device=dev)
            self._maps_current = True
        return self._probability, self._saliency

    def _check_prev(self, name: str, a, dtype):
        ok = (isinstance(a, wp.array) and a.dtype == dtype and tuple(a.shape) == (self.height, self.width)
              and a.device == self.device)
        if not ok:
            raise ValueError(f"{name} must be a ({self.height}, {self.width}) {dtype.__name__} wp.array on "
                             f"{self.device}, got {type(a).__name__} {tuple(getattr(a, 'shape', ()))} "
                             f"{getattr(getattr(a, 'dtype', None), '__name__', '')}")
        return a

    def end_frame(self, gbuffer, valid_mask=None) -> None:
        """Keep this frame's depth and valid-color mask (uint8 (H, W) wp.array; None: the G-buffer hit mask)
        for the next frame's cache test."""
        self._check_gbuffer(gbuffer)
        src = gbuffer.hit if valid_mask is None else valid_mask
        if not isinstance(src, wp.array) or tuple(src.shape) != (self.height, self.width) or src.dtype != wp.uint8:
            kind = "wp.array" if isinstance(src, wp.array) else type(src).__name__
            raise ValueError(f"valid_mask must be a ({self.height}, {self.width}) uint8 wp.array, got {kind} "
                             f"{getattr(src, 'shape', None)} {getattr(src, 'dtype', '')}")
        wp.copy(self.depth_prev, gbuffer.depth)
        wp.copy(self.valid_prev, src)

    def _check_gbuffer(self, gbuffer):
        from ..buffers import GBuffer

        if not isinstance(gbuffer, GBuffer):
            raise ValueError(f"gbuffer must be a foveawarp GBuffer of {self.width} x {self.height}, got "
                             f"{show(gbuffer)} ({type(gbuffer).__name__})")
        if gbuffer.width != self.width or gbuffer.height != self.height:
            raise ValueError(f"gbuffer must be {self.width} x {self.height}, got {gbuffer.width} x {gbuffer.height}")
        return gbuffer

    # -- stats (host reads: call only when wanted) ---------------------------------------------------------------
    def stats(self) -> dict:
        n = float(self.width * self.height)
        s = int(self.num_samples.numpy()[0])
        c = int(self.num_cache_hits.numpy()[0])
        return {"num_samples": s, "num_cache_hits": c, "sampling_rate": s / n, "cache_hit_rate": c / n,
                "skipped": dict(self.skipped)}
