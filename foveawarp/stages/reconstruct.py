"""Reconstruction stage: Jump Flooding Voronoi over the filled pixels, then bounded Sibson interpolation
(ALGORITHMS.md A5-A6). Allocates every buffer in ``__init__``; ``run`` only launches kernels.

Launches of one ``run`` (n = number of JFA steps of the schedule, 5 for the default 1+JFA at block 4):
pass 1 (init fused with the first step; writes the seeds' entries of the result and zeroes the statistics),
passes 2..n-1, pass n (tiled: also the nearest-seed radius, the Voronoi color of the non-seed pixels, per-tile
maxima and statistics; or the Voronoi fill of every pixel when Sibson is off), then the Sibson gather (seeds:
one mask read, their color copied). n + 1 full-image launches in all (n with Sibson off) and no memset when
n >= 2 (the plain form took n + 3 launches and 3 memsets); with n <= 1, three 1-element memsets zero the
statistics. The work at a seed pixel is a 1-byte mask read per pass, one 8-byte write, and its color copy.
On CUDA the last pass is a per-pixel launch that folds the radii into the tile maxima (after a memset of them):
with ``few_holes`` (a FrameLoop with deterministic shading) by an atomic maximum per pixel, else by one per warp
and tile after a reduction across the warp's lanes (``kernels/lanes.py``); ``last_pass`` picks a form, the tiled
kernel with per-block reductions included. On the CPU the last pass runs in bands (``cpu_bands``).
"""

from __future__ import annotations

import math
from typing import Optional

import warp as wp

from .. import parallel
from .._util import check_image_size, get_device
import numpy as np

from ..config import (VORONOI_VARIANTS, ReconstructionConfig, check_bool, check_choice, check_int_range,
                      resolve_voronoi_variant)
from ..kernels.jfa import (
    RTILE,
    jfa_last_pass_bands_kernel,
    jfa_last_pass_atomic_kernel,
    jfa_last_pass_lanes_kernel,
    jfa_last_pass_kernel,
    jfa_tile_stats_kernel,
    jfa_pass_kernel,
    voronoi_color_kernel,
    voronoi_fill_kernel,
    voronoi_from_nearest_kernel,
)
from ..kernels.sibson import (
    sibson_gather_kernel,
    sibson_gather_rows_kernel,
    sibson_resolve_kernel,
    sibson_scatter_kernel,
)

__all__ = [
    "ReconstructStage",
    "jfa_steps",
    "jfa_start_step_for_block",
    "disc_offsets_for_block",
    "max_seed_distance_for_block",
    "sibson_window_for_block",
]

_LAST_PASS_FORMS = (None, "tiled", "atomic", "lanes")  # ReconstructStage.last_pass
_RTILE = int(RTILE)  # screen tile edge of the radius reduction (kernels/jfa.py)
_CUDA_BLOCK = _RTILE * _RTILE  # threads per block of the tiled last pass on CUDA (the CPU runs blocks of 1)


def max_seed_distance_for_block(block: int) -> float:
    """Largest possible distance in pixels from a pixel to its nearest seed when every ``block`` x ``block``
    tile (aligned at multiples of ``block``; partial tiles at the right/bottom edges included) holds a seed.

    A pixel and a seed of its own tile differ by at most ``block - 1`` in x and in y, so the bound is
    ``(block - 1) * sqrt(2)``; it is reached (a pixel in one corner, the only seeds of the neighbouring
    tiles farther away). ``block`` in [1, 64]."""
    b = check_int_range("block", block, 1, 64)
    return (b - 1) * math.sqrt(2.0)


def jfa_start_step_for_block(block: int) -> int:
    """First JFA step (pixels) for masks with the block guarantee: the smallest power of two >= the
    nearest-seed distance bound ``(block - 1) * sqrt(2)`` (1 for block 1). Steps k, k/2, ..., 1 can carry a
    seed up to ``2k - 1`` pixels per axis, about twice the bound, which leaves room for JFA's propagation
    errors. ``block`` in [1, 64]."""
    d = max_seed_distance_for_block(block)
    k = 1
    while k < d:
        k *= 2
    return k


def sibson_window_for_block(block: int) -> int:
    """Half window J (pixels) of the bounded Sibson gather that is exact under the block guarantee.

    q reaches p only when ``|p - q| <= r_q <= (block - 1) sqrt(2)``, so integer offsets satisfy
    ``max(|dx|, |dy|) <= floor((block - 1) sqrt(2)) = isqrt(2 (block - 1)^2)``. Returns at least 1 (the
    smallest ``ReconstructionConfig.sibson_window``). ``block`` in [1, 64]."""
    b = check_int_range("block", block, 1, 64)
    return max(1, math.isqrt(2 * (b - 1) * (b - 1)))


def disc_offsets_for_block(block: int) -> np.ndarray:
    """(N, 2) int32 (dx, dy) offsets of the "disc" variant's scan: every nonzero offset with
    ``dx^2 + dy^2 <= 2 (block - 1)^2`` (the squared nearest-seed bound of the block guarantee), sorted by squared
    length, then dy, then dx. Empty for block 1 (every pixel is a seed). ``block`` in [1, 64]."""
    b = check_int_range("block", block, 1, 64)
    r2 = 2 * (b - 1) * (b - 1)
    r = b - 1
    offs = [(dx, dy) for dy in range(-2 * r, 2 * r + 1) for dx in range(-2 * r, 2 * r + 1)
            if 0 < dx * dx + dy * dy <= r2]
    offs.sort(key=lambda o: (o[0] * o[0] + o[1] * o[1], o[1], o[0]))
    return np.asarray(offs, dtype=np.int32).reshape(-1, 2)


def jfa_steps(width: int, height: int, variant: str = "1+jfa", start_step: Optional[int] = None) -> list:
    """The step lengths (pixels) of the JFA passes, in launch order.

    Full JFA: N/2, N/4, ..., 1 with N = max(width, height) rounded up to a power of two (no pass when N = 1).
    ``start_step`` (>= 1) replaces N/2 when smaller; each next step is ``ceil(k / 2)``, down to 1.
    Variants (Rong & Tan 2006): "jfa+1" appends a step-1 pass, "jfa+2" appends steps 2 and 1,
    "1+jfa" prepends a step-1 pass; "auto" is "1+jfa"; "disc" has none."""
    w, h = check_image_size(width, height)
    check_choice("variant", variant, VORONOI_VARIANTS)
    variant = resolve_voronoi_variant(variant, False)  # no guarantee known here: "auto" is "1+jfa"
    if variant == "disc":
        return []  # no jump flooding: the last pass scans the disc
    n = 1
    while n < max(w, h):
        n *= 2
    k = n // 2
    if start_step is not None:
        k = min(k, check_int_range("start_step", start_step, 1, 16384))
    steps = []
    while k >= 1:
        steps.append(k)
        k = (k + 1) // 2 if k > 1 else 0
    if variant == "jfa+1":
        steps = steps + [1]
    elif variant == "jfa+2":
        steps = steps + [2, 1]
    elif variant == "1+jfa":
        steps = [1] + steps
    return steps


class ReconstructStage:
    """Fill the unsampled pixels of a sparse shading buffer from its seeds (the nonzero ``seed_mask`` pixels).

    Args:
        width, height: image size in pixels, each in [1, 16384].
        config: a :class:`ReconstructionConfig` (JFA variant, Sibson on/off, window J, bounded JFA start).
        block: the sampling map's jitter block ``k`` in [1, 64] (``FoveationConfig.block``): it sets the bounded
            JFA start step and, when ``config.sibson_window`` is None, the window J. Both rely on the mask
            holding a seed in every aligned ``block`` x ``block`` tile.
        device: Warp device.
        exact_sibson: use Park et al.'s exact scatter (atomics; cost grows with the empty area) instead of
            the bounded gather. For references and benchmarks.
        window: overrides the half window J in pixels, in [1, 256] (default: config / block).
        start_step: overrides the first JFA step in pixels, in [1, 16384] (default: config / block).
        guaranteed: the masks hold the block guarantee (``"auto"`` may then pick the "disc" step).
        few_holes: the masks have few non-seed pixels (a FrameLoop with deterministic shading): off the CPU's
            bands the last pass then folds each pixel's radius by its own atomic (H100, 4K: 0.071 against 0.086 ms
            for the warp-folded form and 0.157 for the tiled kernel); without it, one atomic per warp and tile.

    Buffers (all on ``device``, overwritten by each ``run``):
        nearest: (H, W) ``wp.vec2i``, (x, y) of the nearest seed found, (-1, -1) where none was found (a seed
            pixel holds itself).
        voronoi_color: (H, W) ``wp.vec3``, finite color of the nearest seed at the NON-seed pixels (0 where
            none was found), written when Sibson is on. Seed entries are not written (a seed's color is its own).
        radius_sq: (H, W) int32, squared distance r_q^2 to the nearest seed in pixels^2 at the NON-seed pixels
            (-1 where none was found), and -1 at the seeds (a seed reaches no other pixel; the mask says which
            pixels are seeds), so the Sibson gather's taps read this array alone.
        tile_radius_sq: (ceil(H / 16), ceil(W / 16)) int32, the largest ``radius_sq`` of each 16 x 16 screen
            tile (0 when the tile has no reached non-seed pixel): the gather's local window bound.
        max_radius: (1,) float32, the largest nearest-seed distance r_q in pixels (0 without seeds).
        max_radius_sq: (1,) int32, its square (exact), pixels^2.
        unreached: (1,) int32, pixels for which no seed was found (all of them without seeds; nonzero with a
            bounded JFA start also flags a mask that broke the block guarantee).
    """

    # on the CPU, the last JFA pass runs as band-parallel tiles without atomics (False: the tiled kernel, as on
    # CUDA; the tests compare the two)
    cpu_bands = True
    # the last pass's form off the CPU's bands: None (by ``few_holes``: "atomic" when set, else "lanes"), or one
    # of "tiled" (per-block reductions), "atomic" (an atomic per pixel), "lanes" (an atomic per warp and tile);
    # all three write the same values (tests compare them), at different costs
    last_pass = None

    def __init__(self, width: int, height: int, config: Optional[ReconstructionConfig] = None, block: int = 4,
                 device=None, *, exact_sibson: bool = False, window: Optional[int] = None,
                 start_step: Optional[int] = None, guaranteed: bool = False, few_holes: bool = False):
        self.width, self.height = check_image_size(width, height)
        if config is None:
            config = ReconstructionConfig()
        if not isinstance(config, ReconstructionConfig):
            raise ValueError(f"config must be a ReconstructionConfig, got {type(config).__name__}")
        self.config = config
        self.block = check_int_range("block", block, 1, 64)
        self.device = get_device(device)
        self.exact_sibson = bool(exact_sibson)
        # the caller expects few non-seed pixels: elsewhere than the CPU's bands the last pass is then a per-pixel
        # launch with atomic tile maxima instead of the tiled kernel's per-block reductions
        self.few_holes = check_bool("few_holes", few_holes)
        self._checked_last_pass()
        if window is not None:
            self.window = check_int_range("window", window, 1, 256)
        elif config.sibson_window is not None:
            self.window = int(config.sibson_window)
        else:
            self.window = sibson_window_for_block(self.block)
        if start_step is not None:
            self.start_step = check_int_range("start_step", start_step, 1, 16384)
        else:
            self.start_step = jfa_start_step_for_block(self.block) if config.bounded_jfa_start else None
        # the Voronoi step run ("auto" resolved: "disc" needs the block guarantee, which ``guaranteed`` promises)
        self.variant = resolve_voronoi_variant(config.jfa_variant, bool(guaranteed))
        self.steps = jfa_steps(self.width, self.height, self.variant, self.start_step)

        shape = (self.height, self.width)
        dev = self.device
        self.nearest = wp.empty(shape, dtype=wp.vec2i, device=dev)
        self._pong = wp.empty(shape, dtype=wp.vec2i, device=dev) if len(self.steps) > 1 else None
        self.voronoi_color = wp.zeros(shape, dtype=wp.vec3, device=dev)
        self.radius_sq = wp.full(shape, -1, dtype=wp.int32, device=dev)
        tiles = ((self.height + _RTILE - 1) // _RTILE, (self.width + _RTILE - 1) // _RTILE)
        self.tile_radius_sq = wp.zeros(tiles, dtype=wp.int32, device=dev)
        self.max_radius = wp.zeros(1, dtype=wp.float32, device=dev)
        self.max_radius_sq = wp.zeros(1, dtype=wp.int32, device=dev)
        self.unreached = wp.zeros(1, dtype=wp.int32, device=dev)
        self._accum = wp.zeros(shape, dtype=wp.vec4, device=dev) if self.exact_sibson else None
        self._block_dim = _CUDA_BLOCK if dev.is_cuda else 1
        self._num_tiles = tiles[0] * tiles[1]
        # the CPU runs the last pass as bands of tiles (no tiles, no atomics: foveawarp.parallel); per-tile
        # counts of pixels without a seed, folded into ``unreached`` by a one-thread kernel
        self._tile_miss = None if dev.is_cuda else wp.zeros(tiles, dtype=wp.int32, device=dev)
        self._stats_launch = parallel.Relaunch(jfa_tile_stats_kernel, bands=False)  # recorded once
        self._mask = None  # the seed mask of the last run_jfa (a reference, for run_interpolate)
        self._dummy3 = wp.zeros((1, 1), dtype=wp.vec3, device=dev)  # color placeholder of run_jfa
        self._seeds = None  # seed mask derived from a given nearest map (ops path; allocated on first use)
        self.disc = self.variant == "disc"
        offs = disc_offsets_for_block(self.block) if self.disc else np.zeros((1, 2), np.int32)
        self._disc_offsets = wp.array(offs if len(offs) else np.zeros((0, 2), np.int32), dtype=wp.vec2i, device=dev)

    # -- checks (host-side attribute reads only: no sync, no allocation) --------------------------------------
    def _checked_last_pass(self):
        """``last_pass`` (checked at construction and at each run: it may be set on the instance)."""
        if not (self.last_pass is None or (isinstance(self.last_pass, str) and self.last_pass in _LAST_PASS_FORMS)):
            raise ValueError(f"ReconstructStage.last_pass must be one of {_LAST_PASS_FORMS}, got {self.last_pass!r}")
        return self.last_pass

    def _check(self, name, arr, dtype):
        if not isinstance(arr, wp.array) or arr.dtype != dtype or tuple(arr.shape) != (self.height, self.width):
            got = type(arr).__name__
            if isinstance(arr, wp.array):
                got = f"a {tuple(arr.shape)} wp.array of {getattr(arr.dtype, '__name__', arr.dtype)}"
            raise ValueError(f"{name} must be a ({self.height}, {self.width}) wp.array of {dtype.__name__}, "
                             f"got {got}")
        if arr.device != self.device:
            raise ValueError(f"{name} must be on {self.device}, got {arr.device}")

    # -- passes ------------------------------------------------------------------------------------------------
    def _stats_args(self):
        return [self.max_radius_sq, self.max_radius, self.unreached]

    def set_seed_mask(self, seed_mask) -> None:
        """Make ``seed_mask`` the mask ``run_interpolate`` reads (what ``run_jfa`` sets): ``FrameLoop`` calls it
        after a replayed frame body (a CUDA graph or a CPU recording runs no Python), whose last seed mask is
        the temporal history's current one."""
        self._check("seed_mask", seed_mask, wp.uint8)
        self._mask = seed_mask

    def run_jfa(self, seed_mask, *, color_in=None, color_out=None) -> None:
        """Jump flooding: ``nearest`` <- nearest seed of every pixel, plus ``radius_sq``, ``tile_radius_sq`` and
        the statistics. ``seed_mask``: (H, W) uint8, nonzero = seed. With ``color_in`` ((H, W) vec3, read at
        seeds) the last pass also writes ``voronoi_color`` (for the Sibson gather), or, when ``color_out`` is
        given too, the Voronoi fill of every pixel to ``color_out``."""
        self._check("seed_mask", seed_mask, wp.uint8)
        last_pass = self._checked_last_pass()
        mode = 0
        cin, cout = self._dummy3, self._dummy3  # placeholders, never touched in mode 0
        if color_out is not None and color_in is None:
            raise ValueError(f"color_in must be given with color_out (a ({self.height}, {self.width}) wp.array of "
                             f"vec3), got None")
        if color_in is not None:
            self._check("color_in", color_in, wp.vec3)
            cin, cout, mode = color_in, self.voronoi_color, 1
            if color_out is not None:
                self._check("color_out", color_out, wp.vec3)
                cout, mode = color_out, 2
        dev = self.device
        dim = (self.height, self.width)
        steps = self.steps
        n = len(steps)
        # ping-pong so that the last pass writes self.nearest: pass i writes nearest when n - 1 - i is even
        bufs = [self.nearest, self._pong]
        if n <= 1:  # no pass before the last one to zero the statistics
            self.max_radius_sq.zero_()
            self.max_radius.zero_()
            self.unreached.zero_()
        src = self.nearest
        # squared distance at which a pixel is final before pass i: 2 once a step-1 pass has run, else 1
        settled = [2 if 1 in steps[:i] else 1 for i in range(n)]
        for i in range(n - 1):
            dst = bufs[(n - 1 - i) % 2]
            parallel.launch(jfa_pass_kernel, dim=dim,
                            inputs=[seed_mask, src, int(steps[i]), 1 if i == 0 else 0, settled[i]],
                            outputs=[self.nearest, dst, *self._stats_args()], device=dev)
            src = dst
        step_last = -1 if self.disc else (int(steps[-1]) if n else 0)
        last = [seed_mask, src, step_last, 1 if n <= 1 else 0, settled[-1] if n else 1, cin, mode,
                self._disc_offsets]
        if self._tile_miss is not None and self.cpu_bands:
            parallel.launch(jfa_last_pass_bands_kernel, dim=self.tile_radius_sq.size, inputs=last,
                            outputs=[self.nearest, self.radius_sq, self.tile_radius_sq, cout, self._tile_miss],
                            device=dev, min_band_items=8)
            self._stats_launch(1, inputs=[self.tile_radius_sq, self._tile_miss], outputs=self._stats_args(),
                               device=dev)
        elif last_pass != "tiled":
            self.tile_radius_sq.zero_()
            form = last_pass or ("atomic" if self.few_holes else "lanes")
            kern = jfa_last_pass_atomic_kernel if form == "atomic" else jfa_last_pass_lanes_kernel
            wp.launch(kern, dim=(self.height, self.width), inputs=last,
                      outputs=[self.nearest, self.radius_sq, self.tile_radius_sq, cout, *self._stats_args()],
                      device=dev)
        else:
            wp.launch_tiled(
                jfa_last_pass_kernel, dim=[self._num_tiles], inputs=last,
                outputs=[self.nearest, self.radius_sq, self.tile_radius_sq, cout, *self._stats_args()],
                block_dim=self._block_dim, device=dev,
            )
        self._mask = seed_mask

    def run_interpolate(self, color_in, color_out, nearest=None) -> None:
        """Sibson (or the plain Voronoi color when ``config.sibson`` is False) into ``color_out``, from the
        last ``run_jfa`` (its mask, ``nearest``, radii and statistics) or, when given, from ``nearest`` ((H, W)
        vec2i; its seeds are the pixels that map to themselves). ``color_in`` is read at seeds only."""
        self._check("color_in", color_in, wp.vec3)
        self._check("color_out", color_out, wp.vec3)
        self._interpolate(color_in, color_out, nearest, vor_ready=False)

    def _interpolate(self, color_in, color_out, nearest, vor_ready: bool, display=None, tone=(1.0, 1.0)) -> bool:
        """``vor_ready``: the last pass of the JFA just run wrote ``voronoi_color`` for ``color_in``. ``display``:
        also write the tone-mapped result there (``tone`` = exposure, white point) when the path allows it (the
        bounded Sibson gather); returns whether it did."""
        dev = self.device
        dim = (self.height, self.width)
        if nearest is not None:
            self._check("nearest", nearest, wp.vec2i)
            if self._seeds is None:
                self._seeds = wp.zeros(dim, dtype=wp.uint8, device=dev)
            self.max_radius_sq.zero_()
            self.max_radius.zero_()
            self.unreached.zero_()
            wp.launch_tiled(voronoi_from_nearest_kernel, dim=[self._num_tiles], inputs=[nearest, color_in],
                            outputs=[self._seeds, self.nearest, self.radius_sq, self.voronoi_color,
                                     self.tile_radius_sq, *self._stats_args()],
                            block_dim=self._block_dim, device=dev)
            mask = self._seeds
            vor_ready = True
        else:
            if self._mask is None:
                raise ValueError("nearest must be given (a (H, W) wp.array of vec2i) before run_jfa has run")
            mask = self._mask
        sibson = self.config.sibson or self.exact_sibson
        if not sibson:
            parallel.launch(voronoi_fill_kernel, dim=dim, inputs=[mask, self.nearest, color_in], outputs=[color_out],
                            device=dev)
            return False
        if not vor_ready:
            parallel.launch(voronoi_color_kernel, dim=dim, inputs=[mask, self.nearest, color_in],
                            outputs=[self.voronoi_color], device=dev)
        near = [mask, self.voronoi_color, self.radius_sq]
        if self.exact_sibson:
            self._accum.zero_()
            wp.launch(sibson_scatter_kernel, dim=dim, inputs=near, outputs=[self._accum], device=dev)
            parallel.launch(sibson_resolve_kernel, dim=dim, inputs=[*near, color_in, self._accum, self.max_radius_sq],
                            outputs=[color_out], device=dev)
            return False
        parallel.launch_rows(sibson_gather_kernel, sibson_gather_rows_kernel, dim,
                             inputs=[*near, self.tile_radius_sq, color_in, int(self.window), self.max_radius_sq,
                                     float(tone[0]), float(tone[1]), 0 if display is None else 1],
                             outputs=[color_out, self._dummy3 if display is None else display], device=dev)
        return display is not None

    def run(self, color_in, seed_mask, color_out, *, display=None, exposure: float = 1.0,
            white_point: float = 1.0) -> bool:
        """One frame: JFA over ``seed_mask`` ((H, W) uint8), then interpolation of ``color_in`` ((H, W) vec3,
        read at seeds only) into ``color_out`` ((H, W) vec3; may not alias ``color_in``). Seeds keep their
        color. Launches only: no allocation, no host synchronization (CUDA-graph capturable).

        ``display`` ((H, W) vec3, or None): the bounded Sibson gather also writes the tone-mapped result there
        (``exposure``, ``white_point`` as in ShadingConfig), saving the separate tone-map pass. Returns whether
        it did (False on the other paths: plain Voronoi, exact Sibson; the caller tone-maps ``color_out``)."""
        if color_in is color_out:
            raise ValueError("color_out must be a different array from color_in")
        self._check("color_in", color_in, wp.vec3)
        self._check("color_out", color_out, wp.vec3)
        if display is not None:
            self._check("display", display, wp.vec3)
        if self.config.sibson or self.exact_sibson:
            self.run_jfa(seed_mask, color_in=color_in)
            return self._interpolate(color_in, color_out, None, vor_ready=True, display=display,
                                     tone=(exposure, white_point))
        # the last JFA pass writes the Voronoi colors
        self.run_jfa(seed_mask, color_in=color_in, color_out=color_out)
        return False
