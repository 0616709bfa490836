"""Frozen configuration dataclasses, one per stage.

Every field states its unit and allowed range; ``__post_init__`` validates and raises ``ValueError``
naming the field, the value and the allowed range.
"""

from __future__ import annotations

import math
import reprlib
from dataclasses import dataclass, field, fields, replace
from typing import Optional, Sequence

import numpy as np

__all__ = [
    "FoveationConfig",
    "SaliencyConfig",
    "ReorderConfig",
    "ShadingConfig",
    "ReconstructionConfig",
    "DofConfig",
    "IndirectConfig",
    "TemporalConfig",
    "Config",
    "check_finite",
    "check_range",
    "check_int_range",
    "check_choice",
    "check_bool",
    "check_vec",
    "check_array",
    "interval",
    "show",
]


# ---------------------------------------------------------------------------------------------------
# validation helpers (shared by configs, Camera, Scene, ops, stages and FrameLoop)
#
# Every message names the parameter, the offending value and the allowed range, e.g.
#   "FoveationConfig.mar_slope must be a finite number in (0.0, 1.0], got nan"
#   "width must be an integer in [1, 16384], got 0"
#   "colors must hold finite real numbers, got nan at index (2, 3, 0)"

_REPR = reprlib.Repr()
# the largest finite float32: the bound of the values the kernels hold in float32 where larger ones would overflow
FLOAT32_MAX = float(np.finfo(np.float32).max)
_REPR.maxstring = 60
_REPR.maxother = 60


def show(value) -> str:
    """A short repr of an offending value (NumPy scalars as Python numbers; long values abbreviated)."""
    if isinstance(value, np.generic):
        value = value.item()
    return _REPR.repr(value)


def _num(v) -> str:
    if isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_)):
        return str(int(v))
    return repr(float(v))


def interval(lo=None, hi=None, *, lo_open=False, hi_open=False) -> str:
    """``[lo, hi]`` with open ends as asked and -inf / inf for missing bounds."""
    left = "(" if lo_open else "["
    right = ")" if hi_open else "]"
    lo_s = "-inf" if lo is None else _num(lo)
    hi_s = "inf" if hi is None else _num(hi)
    return f"{left}{lo_s}, {hi_s}{right}"


def _is_real_scalar(value) -> bool:
    if isinstance(value, (bool, np.bool_, str, bytes)):
        return False
    return isinstance(value, (int, float, np.integer, np.floating)) or (
        hasattr(value, "__float__") and not hasattr(value, "__len__")
    )


def check_finite(name: str, value) -> float:
    """Return ``value`` as a float, or raise ``ValueError`` when it is not a finite real number (strings and
    bools are rejected)."""
    if type(value) is float and math.isfinite(value):  # the common case, checked per frame: no more to do
        return value
    if not _is_real_scalar(value):
        raise ValueError(f"{name} must be a finite real number, got {show(value)}")
    try:
        v = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be a finite real number, got {show(value)}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be a finite real number, got {show(value)}")
    return v


def check_range(name: str, value, lo=None, hi=None, *, lo_open=False, hi_open=False) -> float:
    """Finite float in [lo, hi] (open ends when asked); the error names the interval, also for NaN, Inf and
    values that are not real numbers."""
    rng = interval(lo, hi, lo_open=lo_open, hi_open=hi_open)
    try:
        v = check_finite(name, value)
    except ValueError:
        raise ValueError(f"{name} must be a finite number in {rng}, got {show(value)}") from None
    if (lo is not None and (v < lo or (lo_open and v == lo))) or (hi is not None and (v > hi or (hi_open and v == hi))):
        raise ValueError(f"{name} must be in {rng}, got {show(value)}")
    return v


def check_int_range(name: str, value, lo=None, hi=None) -> int:
    """An integer (Python or NumPy; not bool, not float) in [lo, hi]."""
    rng = f"[{'-inf' if lo is None else int(lo)}, {hi if hi is not None else 'inf'}]"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) and not (
        hasattr(value, "__index__") and not isinstance(value, (float, np.floating))
    ):
        raise ValueError(f"{name} must be an integer in {rng}, got {show(value)}")
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise ValueError(f"{name} must be an integer in {rng}, got {show(value)}")
    return v


def check_choice(name: str, value, choices: Sequence):
    try:
        ok = isinstance(value, (str, int, float, type(None))) and value in choices
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"{name} must be one of {list(choices)}, got {show(value)}")
    return value


def check_bool(name: str, value) -> bool:
    """True or False (Python or NumPy bool); anything else (strings, numbers, None) is a ValueError."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {show(value)}")
    return bool(value)


def check_vec(name: str, value, n: int = 3, lo=None, hi=None) -> tuple:
    """``n`` finite numbers (each in [lo, hi] when bounds are given) as a tuple of floats."""
    what = f"{n} finite numbers" + ("" if lo is None and hi is None else f" each in {interval(lo, hi)}")
    try:
        t = None if isinstance(value, (str, bytes)) else tuple(value)
    except TypeError:
        t = None
    if t is None or len(t) != n:
        raise ValueError(f"{name} must be {what}, got {show(value)}")
    out = []
    for i, c in enumerate(t):
        if lo is None and hi is None:
            out.append(check_finite(f"{name}[{i}]", c))
        else:
            out.append(check_range(f"{name}[{i}]", c, lo, hi))
    return tuple(out)


def check_array(name: str, a, *, lo=None, hi=None, lo_open=False, hi_open=False, allow_posinf=False) -> np.ndarray:
    """``a`` (NumPy, Warp or nested sequences) as a host NumPy array of real numbers that are all finite and in
    [lo, hi] (``allow_posinf``: +inf allowed too). The error names the first offending value and its index."""
    if hasattr(a, "numpy") and not isinstance(a, np.ndarray):
        a = a.numpy()
    try:
        arr = np.asarray(a)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be an array of real numbers, got {show(a)} ({e})") from None
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{name} must be an array of real numbers, got dtype {arr.dtype} ({show(a)})")
    if arr.dtype.kind == "f":
        finite = np.isfinite(arr)
        if allow_posinf:
            finite |= np.isposinf(arr)
    else:
        finite = np.ones(arr.shape, dtype=bool)
    bad = ~finite
    if lo is not None or hi is not None:
        with np.errstate(invalid="ignore"):
            if lo is not None:
                bad |= (arr < lo) | ((arr == lo) if lo_open else False)
            if hi is not None:
                bad |= (arr > hi) | ((arr == hi) if hi_open else False)
    if bad.any():
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        what = "finite real numbers" if lo is None and hi is None else (
            f"finite numbers in {interval(lo, hi, lo_open=lo_open, hi_open=hi_open)}")
        if allow_posinf:
            what += " or +inf"
        raise ValueError(f"{name} must hold {what}, got {show(arr[idx])} at index {idx}")
    return arr


def _check_color(name: str, value, lo=0.0, hi=None) -> tuple:
    return check_vec(name, value, 3, lo, hi)


# ---------------------------------------------------------------------------------------------------
# stage configs


@dataclass(frozen=True)
class FoveationConfig:
    """Eccentricity / MAR foveation probability (thesis eq. 2) and the jitter-block guarantee.

    Attributes:
        mar_slope: MAR slope ``m`` in degrees of MAR per degree of eccentricity, in (0, 1].
            Guenter et al. 2012 measured 0.022-0.034; default 0.028.
        mar_fovea_deg: MAR at the fovea ``b`` in degrees, in (0, 1]; default 1/48.
        min_probability: minimum sampling probability ``xi`` in [0, 1]. It is raised to ``1 / block**2``
            when lower, so that the expected count of a block is at least one (see ``effective_min_probability``).
        block: jitter block size ``k`` in pixels, in [1, 64]: every k x k tile holds at least one sample,
            which bounds the distance from any pixel to its nearest sample by ``k * sqrt(2)``.
        enabled: False traces every pixel (sampling rate 1).
        fovea_deg: the probability is 1 within this eccentricity in degrees, in [0, 180]: the fovea is traced at
            full rate (ALGORITHMS.md A: "the fovea is ray traced at full rate"); 0 leaves eq. 2 alone. Default 5
            (the foveal region of the quality metrics).
        falloff_deg: None normalizes eq. 2 by ``w_far`` = MAR at the largest eccentricity on screen, as the
            thesis does; a number in (0, 180] normalizes by the MAR at this eccentricity instead (the smaller of
            the two), so the probability falls to about ``xi`` there. A foveawarp extension: with the thesis
            normalizer the mean probability is about 1/2 whatever the MAR slope (44-59% measured at 1080p and
            4K). Default 12: 12-30% sampled at 1920x1080 on the built-in scenes and meshes (H100).
        gbuffer: "full" (default) traces one primary ray per pixel for the G-buffer; "sparse" traces one per
            ``coarse_cell`` x ``coarse_cell`` cell for the saliency terms plus one per sampled pixel (traced with
            its shading), so the frame's primary rays scale with the sampling rate. The sparse mode has no
            per-pixel history (no cache test, no temporal resolve: the unsampled pixels come from the
            reconstruction alone) and no depth of field (``DofConfig.aperture_m`` must be 0). Its Sibson half
            window is 2 pixels unless ``ReconstructionConfig.sibson_window`` says otherwise.
        coarse_cell: cell edge in pixels of the sparse mode's coarse G-buffer, in [1, 64]; default 4.
    """

    mar_slope: float = 0.028
    mar_fovea_deg: float = 1.0 / 48.0
    min_probability: float = 0.05
    block: int = 4
    enabled: bool = True
    falloff_deg: Optional[float] = 12.0
    fovea_deg: float = 5.0
    gbuffer: str = "full"
    coarse_cell: int = 4

    def __post_init__(self):
        check_range("FoveationConfig.mar_slope", self.mar_slope, 0.0, 1.0, lo_open=True)
        check_range("FoveationConfig.mar_fovea_deg", self.mar_fovea_deg, 0.0, 1.0, lo_open=True)
        check_range("FoveationConfig.min_probability", self.min_probability, 0.0, 1.0)
        check_int_range("FoveationConfig.block", self.block, 1, 64)
        check_bool("FoveationConfig.enabled", self.enabled)
        check_range("FoveationConfig.fovea_deg", self.fovea_deg, 0.0, 180.0)
        if self.falloff_deg is not None:
            check_range("FoveationConfig.falloff_deg", self.falloff_deg, 0.0, 180.0, lo_open=True)
        check_choice("FoveationConfig.gbuffer", self.gbuffer, GBUFFER_MODES)
        check_int_range("FoveationConfig.coarse_cell", self.coarse_cell, 1, 64)

    @property
    def effective_min_probability(self) -> float:
        """``max(min_probability, 1 / block**2)``: the xi used by the sampling map."""
        return max(float(self.min_probability), 1.0 / float(self.block * self.block))


@dataclass(frozen=True)
class SaliencyConfig:
    """Saliency terms of thesis eq. 3: ``clip(max(dA, dN, V, p) * F_DoF, xi, 1)``.

    Attributes:
        use_albedo: include the CIE-Lab albedo gradient term ``dA``.
        use_normal: include the normal-buffer gradient term ``dN``.
        use_velocity: include the normalized screen velocity ``V`` (skipped when nothing moved).
        use_dof: multiply by the depth-of-field factor (skipped for a pinhole camera).
        albedo_scale: gain applied to the normalized Lab gradient before clipping, >= 0.
        normal_scale: gain applied to the normalized normal gradient, >= 0.
        velocity_scale_px: velocity in pixels per frame that maps to V = 1, > 0; default 32 (8 sampled a spinning
            globe at 30-33% at 1080p and 4K, 32 at about 16% at 1080p, with its PSNR still above 68 dB).
        sigma1_m: half width of the in-focus depth range around the focus depth, metres, >= 0.
        sigma2_m: depth range over which F_DoF falls linearly from 1 to 0 beyond sigma1, metres, > 0.
        dof_floor: the smallest value F_DoF takes (so defocused regions keep some rays), in [0, 1].
    """

    use_albedo: bool = True
    use_normal: bool = True
    use_velocity: bool = True
    use_dof: bool = True
    albedo_scale: float = 1.0
    normal_scale: float = 1.0
    velocity_scale_px: float = 32.0
    sigma1_m: float = 0.5
    sigma2_m: float = 2.0
    dof_floor: float = 0.0

    def __post_init__(self):
        check_range("SaliencyConfig.albedo_scale", self.albedo_scale, 0.0, None)
        check_range("SaliencyConfig.normal_scale", self.normal_scale, 0.0, None)
        check_range("SaliencyConfig.velocity_scale_px", self.velocity_scale_px, 0.0, None, lo_open=True)
        check_range("SaliencyConfig.sigma1_m", self.sigma1_m, 0.0, None)
        check_range("SaliencyConfig.sigma2_m", self.sigma2_m, 0.0, None, lo_open=True)
        check_range("SaliencyConfig.dof_floor", self.dof_floor, 0.0, 1.0)
        for n in ("use_albedo", "use_normal", "use_velocity", "use_dof"):
            check_bool(f"SaliencyConfig.{n}", getattr(self, n))

    @property
    def any_enabled(self) -> bool:
        return self.use_albedo or self.use_normal or self.use_velocity or self.use_dof


REORDER_STRATEGIES = ("auto", "none", "rows", "rows+balance", "scan", "tile")


def resolve_reorder_strategy(strategy: str, device) -> str:
    """The strategy a frame runs: "auto" is "tile" on CUDA (coherent warps) and "none" on the CPU, where a
    thread traces one pixel at a time, so a compacted list saves nothing and its compaction (single-threaded
    prefix-sum tile kernels) costs more than the masked launch's idle pixels; any other value unchanged."""
    check_choice("ReorderConfig.strategy", strategy, REORDER_STRATEGIES)
    if strategy != "auto":
        return strategy
    import warp as wp

    return "tile" if wp.get_device(device).is_cuda else "none"


@dataclass(frozen=True)
class ReorderConfig:
    """How the sampled pixels become a work list for the tracing kernel.

    Attributes:
        strategy: one of "auto" (the default: "tile" on CUDA, "none" on the CPU device), "none" (every pixel
            launched, unsampled threads exit), "rows" (thesis strategy 1, row CSR), "rows+balance" (strategies
            1 + 2), "scan" (prefix-sum compaction, raster order), "tile" (prefix-sum compaction over screen
            tiles in Morton order).
        balance_rows: rows per balancing block for "rows+balance", in [1, 1024].
        tile: tile edge in pixels for "tile", a power of two in [2, 64] (8 x 8 = 64 rays: two warps).
        skip_misses: list only the sampled pixels whose primary ray hit a surface (the compacting strategies;
            with the full G-buffer). A miss shows the background, which the temporal resolve writes without
            reading the shading, so the shading launch need not spend a lane on it: in a warp of the list, a
            miss's lane idles while its neighbours trace. False: every sampled pixel is listed (and shaded to the
            background), as before this option; the image is the same either way.
    """

    strategy: str = "auto"
    balance_rows: int = 8
    tile: int = 8
    skip_misses: bool = True

    def __post_init__(self):
        check_choice("ReorderConfig.strategy", self.strategy, REORDER_STRATEGIES)
        check_int_range("ReorderConfig.balance_rows", self.balance_rows, 1, 1024)
        check_int_range("ReorderConfig.tile", self.tile, 2, 64)
        check_bool("ReorderConfig.skip_misses", self.skip_misses)
        if self.tile & (self.tile - 1):
            raise ValueError(f"ReorderConfig.tile must be a power of two in [2, 64], got {self.tile!r}")


@dataclass(frozen=True)
class ShadingConfig:
    """Direct lighting, ambient occlusion and tone mapping.

    Attributes:
        shadows: trace one shadow ray per light (offset origin).
        ambient: ambient radiance (linear RGB), each channel >= 0.
        specular: Blinn-Phong specular weight in [0, 1].
        shininess: Blinn-Phong exponent in [1, 4096].
        ao_samples: ambient-occlusion rays per shaded pixel, in [0, 256]; 0 disables AO.
        ao_radius_rel: AO ray length as a fraction of the scene's bounding-box diagonal, in (0, 10].
        ao_lanes: threads per pixel for the AO rays of a compacted work list (the foveated frame's "scan" /
            "tile" strategies), in [1, 16]. A first launch traces them, ``min(ao_lanes, ao_samples)`` threads per
            pixel, a second shades the pixels with their counts: a list of a tenth of the pixels, one thread each
            tracing all its pixel's rays in turn, is too short to fill a GPU (its time is one thread's chain of
            rays, not the rays' throughput). 1: one thread per pixel traces them. The image is the same for every
            value (the same rays, counted in another order). Default 4: with 8 AO rays on the H100 it beat 8 and 1
            on 13 of 18 scene-size pairs (b44a619); 1 was faster only on the cheap 4K scenes (cornell, eyechart:
            0.09 ms).
        area_light_samples: shadow rays per area light, in [1, 256]; also the direct integrator's environment
            samples per pixel on scenes with an environment.
        env_mis: the direct integrator's environment: True (default) draws each of its samples once from the map's
            luminance and once from the BSDF, weighted by the power heuristic (two shadow rays: a glossy lobe
            sees the map's detail); False draws from the map only (one shadow ray).
        indirect: "none" or "lighttree" (one-bounce indirect from the light quad-tree, see IndirectConfig).
        integrator: "direct" (default: the fields above: lights with shadow rays, ambient or AO, optional
            light-tree indirect) or "path" (unidirectional path tracing with next-event estimation and multiple
            importance sampling, ``foveawarp.stages.path``; ambient, AO and ``indirect`` do not apply to it;
            ``FrameLoop`` traces it at the sampled pixels with the full G-buffer; scenes with materials are shaded
            with their textured materials).
        max_depth: longest path of the "path" integrator, in [1, 4096], Mitsuba 3's convention: 1 = emitters seen
            directly, 2 = direct light, 3 = one indirect bounce, ...
        spp: paths per traced pixel per frame of the "path" integrator, in [1, 65536].
        path_budget: how a foveated frame of the "path" integrator spends its paths: "pixel" (default: ``spp`` at
            every traced pixel) or "frame" (a full-resolution frame's ``spp * width * height`` paths shared among
            the traced pixels in proportion to their sampling probability, so the fovea gets more than the
            periphery: each traced pixel at least 1 path and at most ``max_spp``, rounded stochastically; a cap that
            binds leaves part of the budget unspent). The full-resolution frame traces ``spp`` everywhere.
        max_spp: the most paths one pixel gets under ``path_budget = "frame"``, in [1, 65536].
        rr_depth: path depth from which the "path" integrator applies Russian roulette, in [1, 4096] (Mitsuba 3's
            ``rr_depth``: a path that has made ``rr_depth`` bounces continues with probability min(max channel of
            its throughput, 0.95)).
        radiance_clamp: None (default: unbiased) or the largest channel value, linear radiance in
            (0, float32 max], that one path of the "path" integrator may contribute: a path above it is scaled
            down to it (hue kept). It trades bias for fewer fireflies; leave it off for references.
        path_filter: "atrous" (default) or "none": a foveated frame of the "path" integrator filters its
            reconstructed periphery with edge-avoiding a-trous iterations guided by the G-buffer
            (``foveawarp.stages.path_filter``), leaving the fovea as traced. On by default: at 1920x1080 on an
            H200 it raised the foveated frame's FovVideoVDP at equal time from 6.83 to 7.60 JOD on cornell and,
            with the demodulated reconstruction, from 6.83 to 7.42 on the textured room, for 1.2-1.9 ms a frame.
        path_filter_iterations: a-trous iterations (steps 1, 2, 4, ... pixels), in [1, 5]; default 3: five raised
            FovVideoVDP on the room (7.37 to 8.17 JOD, 1080p) and cornell (8.10 to 8.82, 4K) but lowered bunny
            (9.21 to 8.67) and city (9.00 to 8.41) at 1080p (H200, max_depth 5).
        path_filter_fovea_deg: eccentricity in degrees within which the frame is not filtered, in [0, 90]; the
            filter reaches full strength at twice it.
        path_filter_guide: the filter's luminance stop: "relative" (the default; a tap's weight falls with its
            luminance difference relative to the pixel's) or "variance" (SVGF's: relative to the standard
            deviation of the pixel's luminance over the last frames, reprojected and depth-validated: noise is
            still averaged, and a clean edge of light, such as a sharp shadow, is kept at any step; the relative
            stop until a pixel has 4 frames of history). See kernels/atrous.py.
        path_history: the weight of the previous frame in a foveated path-traced frame's periphery, in [0, 0.95];
            0 (the default) turns it off. After the filter, each surface pixel beyond ``path_filter_fovea_deg`` is
            blended with the previous frame's output reprojected there (bilinear, depth-validated), the weight
            growing to ``path_history`` at twice that eccentricity (kernels/atrous.py): the periphery, rebuilt
            from new sparse paths every frame, then changes less from frame to frame. The fovea stays as traced.
            Off by default: at 0.75 FovVideoVDP rose 7.37 -> 7.46 JOD on the room and moved <= 0.02 on bunny and
            city (1920x1080, max_depth 5, H200), short of the room's full-resolution 7.85.
        background: linear RGB radiance of rays that miss, each channel >= 0.
        exposure: linear scale before tone mapping, in (0, float32 max].
        white_point: Uncharted 2 linear white point, in (0, float32 max]; radiance beyond ~1e18 after the exposure
            maps to the curve's limit (white for any white point up to 1e18).
        seed: base seed of the per-pixel random streams (AO and area-light samples).
        texture_lod: texture level of detail of textured scenes (``Scene.materials``): "ray_cone" (default: the
            ray-cone LOD of Akenine-Moller et al. 2019/2021, trilinear; a primary ray's cone spreads over one
            pixel, a sparse sample's over its spacing) or "none" (level 0, bilinear: for parity with renderers
            without MIP maps, such as Mitsuba 3's bitmap). Untextured scenes ignore it.
    """

    shadows: bool = True
    ambient: tuple = (0.03, 0.03, 0.035)
    specular: float = 0.15
    shininess: float = 48.0
    ao_samples: int = 0
    ao_radius_rel: float = 0.1
    ao_lanes: int = 4
    area_light_samples: int = 4
    env_mis: bool = True
    indirect: str = "none"
    integrator: str = "direct"
    max_depth: int = 5
    spp: int = 1
    path_budget: str = "pixel"
    max_spp: int = 64
    rr_depth: int = 5
    radiance_clamp: Optional[float] = None
    path_filter: str = "atrous"
    path_filter_iterations: int = 3
    path_filter_fovea_deg: float = 5.0
    path_filter_guide: str = "relative"
    path_history: float = 0.0
    background: tuple = (0.02, 0.02, 0.03)
    exposure: float = 2.0
    white_point: float = 11.2
    seed: int = 1
    texture_lod: str = "ray_cone"

    def __post_init__(self):
        object.__setattr__(self, "ambient", _check_color("ShadingConfig.ambient", self.ambient))
        object.__setattr__(self, "background", _check_color("ShadingConfig.background", self.background))
        check_range("ShadingConfig.specular", self.specular, 0.0, 1.0)
        check_range("ShadingConfig.shininess", self.shininess, 1.0, 4096.0)
        check_int_range("ShadingConfig.ao_samples", self.ao_samples, 0, 256)
        check_range("ShadingConfig.ao_radius_rel", self.ao_radius_rel, 0.0, 10.0, lo_open=True)
        check_int_range("ShadingConfig.ao_lanes", self.ao_lanes, 1, 16)
        check_int_range("ShadingConfig.area_light_samples", self.area_light_samples, 1, 256)
        check_choice("ShadingConfig.indirect", self.indirect, ("none", "lighttree"))
        check_choice("ShadingConfig.integrator", self.integrator, ("direct", "path"))
        if self.integrator == "path" and self.indirect != "none":
            raise ValueError(f"ShadingConfig.integrator 'path' computes indirect light itself: ShadingConfig.indirect "
                             f"must be 'none', got {self.indirect!r}")
        check_int_range("ShadingConfig.max_depth", self.max_depth, 1, 4096)
        check_int_range("ShadingConfig.spp", self.spp, 1, 65536)
        check_choice("ShadingConfig.path_budget", self.path_budget, ("pixel", "frame"))
        check_int_range("ShadingConfig.max_spp", self.max_spp, 1, 65536)
        check_int_range("ShadingConfig.rr_depth", self.rr_depth, 1, 4096)
        if self.radiance_clamp is not None:
            check_range("ShadingConfig.radiance_clamp", self.radiance_clamp, 0.0, FLOAT32_MAX, lo_open=True)
        check_choice("ShadingConfig.path_filter", self.path_filter, ("none", "atrous"))
        check_int_range("ShadingConfig.path_filter_iterations", self.path_filter_iterations, 1, 5)
        check_range("ShadingConfig.path_filter_fovea_deg", self.path_filter_fovea_deg, 0.0, 90.0)
        check_choice("ShadingConfig.path_filter_guide", self.path_filter_guide, ("relative", "variance"))
        check_range("ShadingConfig.path_history", self.path_history, 0.0, 0.95)
        # at most float32's largest value: the kernels hold them in float32 (an exposure that became inf there made
        # every black pixel inf * 0 = NaN)
        check_range("ShadingConfig.exposure", self.exposure, 0.0, FLOAT32_MAX, lo_open=True)
        check_range("ShadingConfig.white_point", self.white_point, 0.0, FLOAT32_MAX, lo_open=True)
        check_int_range("ShadingConfig.seed", self.seed, 0, 2**31 - 1)
        check_bool("ShadingConfig.shadows", self.shadows)
        check_bool("ShadingConfig.env_mis", self.env_mis)
        check_choice("ShadingConfig.texture_lod", self.texture_lod, ("ray_cone", "none"))


JFA_VARIANTS = ("jfa", "jfa+1", "jfa+2", "1+jfa")
# the reconstruction's Voronoi step: a JFA schedule, or "disc": the exact nearest seed by a distance-ordered scan
# of the disc that the jitter-block guarantee bounds (one pass)
VORONOI_VARIANTS = JFA_VARIANTS + ("disc", "auto")


def resolve_voronoi_variant(variant: str, guaranteed: bool) -> str:
    """The Voronoi step a reconstruction runs: "auto" is "disc" when the seed masks carry the jitter-block
    guarantee (``guaranteed``: a FrameLoop's always do), else "1+jfa". The disc scan is one launch where 1+JFA
    takes a pass per step: on the CPU (cornell 640x360, 16 threads) 23.2 against 28.4 ms per frame, on the H100
    0.19-0.22 ms less GPU time per 4K frame (cornell, bunny, city), at equal quality (it is exact). Any other
    value unchanged."""
    check_choice("ReconstructionConfig.jfa_variant", variant, VORONOI_VARIANTS)
    if variant != "auto":
        return variant
    return "disc" if guaranteed else "1+jfa"


GBUFFER_MODES = ("full", "sparse")


@dataclass(frozen=True)
class ReconstructionConfig:
    """Voronoi (JFA) + bounded Sibson reconstruction of the sparse shading buffer.

    Attributes:
        jfa_variant: one of "jfa", "jfa+1", "jfa+2", "1+jfa" (Rong & Tan 2006 variants), "disc": no jump
            flooding; one pass finds each pixel's exact nearest seed by scanning the offsets of the disc of
            radius ``(block - 1) sqrt(2)`` (the bound of the jitter-block guarantee) in order of distance. Valid
            only for masks with the guarantee (the frame loop's always have it); a pixel with no seed in its disc
            gets none (counted in ``ReconstructStage.unreached``). Or "auto" (the default): "disc" in a
            FrameLoop, "1+jfa" in a ReconstructStage used on its own, whose masks may lack the guarantee
            (``resolve_voronoi_variant``).
        sibson: interpolate with discrete Sibson (False: plain Voronoi / nearest-seed color).
        sibson_window: half window J in pixels of the bounded gather, in [1, 256]; None derives it from the
            foveation block size so that it covers the largest nearest-seed radius the block guarantee allows.
        bounded_jfa_start: start JFA at the step implied by the block guarantee instead of half the image.
        demodulate: reconstruct the light each sample reflects, ``(L - E) / albedo``, and multiply it back by
            every pixel's own G-buffer albedo (plus its emission): the texture and the colour edges stay at full
            resolution wherever the samples are sparse (kernels/demodulate.py). None (the default): on with the
            path integrator, off with the direct one. Not with the sparse G-buffer, which has no per-pixel albedo.
    """

    jfa_variant: str = "auto"
    sibson: bool = True
    sibson_window: Optional[int] = None
    bounded_jfa_start: bool = True
    demodulate: Optional[bool] = None

    def __post_init__(self):
        check_choice("ReconstructionConfig.jfa_variant", self.jfa_variant, VORONOI_VARIANTS)
        if self.sibson_window is not None:
            check_int_range("ReconstructionConfig.sibson_window", self.sibson_window, 1, 256)
        check_bool("ReconstructionConfig.sibson", self.sibson)
        check_bool("ReconstructionConfig.bounded_jfa_start", self.bounded_jfa_start)
        if self.demodulate is not None and not isinstance(self.demodulate, (bool, np.bool_)):
            raise ValueError(f"ReconstructionConfig.demodulate must be True, False or None (on with the path "
                             f"integrator), got {show(self.demodulate)}")


@dataclass(frozen=True)
class DofConfig:
    """Thin-lens depth of field by pixel-intensity scatter (Lee, Kim, Choi).

    Attributes:
        aperture_m: lens diameter E in metres, >= 0; 0 is a pinhole camera (the pass is skipped).
        focal_length_m: focal length F in metres, > 0.
        focus_depth_m: focus distance Z_f in metres (> focal_length_m); None focuses at the gaze point's depth.
        px_per_m: screen pixels per metre of circle of confusion on the sensor, > 0 (the C_r -> C factor).
        gamma: foreground amplification exponent of K = (Z_f / Z_p)^gamma, >= 0.
        eps_px: loose in-focus range in pixels of the background-leak correction, > 0.
        max_coc_px: largest circle-of-confusion diameter in pixels, in [1, 128].
        foreground_fix: apply the foreground (virtual visibility) correction.
        background_fix: apply the background-leak correction.
    """

    aperture_m: float = 0.0
    focal_length_m: float = 0.05
    focus_depth_m: Optional[float] = None
    px_per_m: float = 20000.0
    gamma: float = 2.0
    eps_px: float = 1.0
    max_coc_px: float = 16.0
    foreground_fix: bool = True
    background_fix: bool = True

    def __post_init__(self):
        check_range("DofConfig.aperture_m", self.aperture_m, 0.0, 10.0)
        check_range("DofConfig.focal_length_m", self.focal_length_m, 0.0, 10.0, lo_open=True)
        if self.focus_depth_m is not None:
            check_range("DofConfig.focus_depth_m", self.focus_depth_m, self.focal_length_m, None, lo_open=True)
        check_range("DofConfig.px_per_m", self.px_per_m, 0.0, None, lo_open=True)
        check_range("DofConfig.gamma", self.gamma, 0.0, 16.0)
        check_range("DofConfig.eps_px", self.eps_px, 0.0, None, lo_open=True)
        check_range("DofConfig.max_coc_px", self.max_coc_px, 1.0, 128.0)
        check_bool("DofConfig.foreground_fix", self.foreground_fix)
        check_bool("DofConfig.background_fix", self.background_fix)

    @property
    def enabled(self) -> bool:
        return self.aperture_m > 0.0


@dataclass(frozen=True)
class IndirectConfig:
    """One-bounce indirect light from a light quad-tree over a reflective shadow map (Ki & Oh).

    Attributes:
        rsm_size: RSM edge in texels (N x N VPLs), a power of two in [8, 2048].
        depth_threshold: relative depth difference (fraction of the scene's bounding-box diagonal) below
            which children join a cluster, in (0, 1]; paper 0.05.
        normal_threshold: minimum dot(n_child, n_avg) for a valid cluster, in [-1, 1]; paper 0.9.
        start_level: quad-tree level where traversal starts (level L has 2^L x 2^L nodes; no cluster is coarser),
            >= 0. Default 4 (16 x 16 nodes); the paper's 8 x 8 nodes is 3.
        limit_level: level whose nodes count as valid, in [start_level, log2(rsm_size)]. Default 7 (128 x 128
            nodes, 1,490-2,010 clusters in the cut of the benchmark scenes; the paper's fastest setting is 4, its
            "limit level 6" counting from the 512^2 leaves up). The level is absolute: the same cut of the
            surfaces at every ``rsm_size`` >= 128 (a smaller RSM needs a lower limit). The default (start 4,
            limit 7, extended emitters of scale 1.0, refinement at threshold 0.32, minimum angular size 0.25 and
            minimum radius 0.5 d_min, at most 512 splits) is the Pareto choice of ``benchmarks/indirect.py``
            (docs/pipeline.md, "Indirect light").
        d_min_rel: distance clamp of the irradiance form, fraction of the bounding-box diagonal, > 0.
        strength: scale of the indirect term, >= 0.
        cluster_radius_scale: a cluster of the tree methods is an extended emitter of radius
            ``a = cluster_radius_scale x`` its flux-weighted RMS extent (``kernels.lighttree.cluster_term``); 0
            gives the point form of the paper, in [0, 16]. A uniform disk has ``a^2 = 2 rms^2``.
        refine_threshold: per-receiver refinement (Lightcuts-style): a cut cluster seen under radius / distance
            above ``refine_min_ratio`` is split when its estimated error exceeds this fraction of the receiver's
            coarse estimate (``kernels.lighttree.gather_list``), in (0, 1e6].
        refine_budget: the most splits per receiver (each replaces a cluster by its four children); 0 turns
            refinement off, in [0, 65536]. A safety cap: the cut is refined in list order (coarse clusters
            first), so a receiver that runs out leaves its later (often nearer) clusters unsplit; the default
            is rarely reached (by fewer than 0.5% of cornell's receivers at RSM 256^2 and 512^2) and the cost
            is set by the threshold, angular size and minimum radius.
        refine_min_ratio: clusters seen under radius / distance at or below this are never split (their
            estimated error is at most ``ratio / (1 - ratio)`` of their bound; the test needs no square root),
            in [0, 1]; 0 lets every cluster be tested.
        refine_min_radius: clusters whose bounding radius is at or below this many distance clamps
            (``d_min_rel`` x the extent) are never split: below the clamp the irradiance form varies little
            across them, and it keeps the refinement's depth independent of ``rsm_size``, in [0, 1000]; 0 lets
            every cluster be split.
    """

    rsm_size: int = 256
    depth_threshold: float = 0.05
    normal_threshold: float = 0.9
    start_level: int = 4
    limit_level: int = 7
    d_min_rel: float = 0.02
    strength: float = 1.0
    cluster_radius_scale: float = 1.0
    refine_threshold: float = 0.32
    refine_budget: int = 512
    refine_min_ratio: float = 0.25
    refine_min_radius: float = 0.5

    def __post_init__(self):
        check_int_range("IndirectConfig.rsm_size", self.rsm_size, 8, 2048)
        if self.rsm_size & (self.rsm_size - 1):
            raise ValueError(f"IndirectConfig.rsm_size must be a power of two in [8, 2048], got {self.rsm_size!r}")
        check_range("IndirectConfig.depth_threshold", self.depth_threshold, 0.0, 1.0, lo_open=True)
        check_range("IndirectConfig.normal_threshold", self.normal_threshold, -1.0, 1.0)
        max_level = int(self.rsm_size).bit_length() - 1
        check_int_range("IndirectConfig.start_level", self.start_level, 0, max_level)
        check_int_range("IndirectConfig.limit_level", self.limit_level, self.start_level, max_level)
        check_range("IndirectConfig.d_min_rel", self.d_min_rel, 0.0, 1.0, lo_open=True)
        check_range("IndirectConfig.strength", self.strength, 0.0, None)
        check_range("IndirectConfig.cluster_radius_scale", self.cluster_radius_scale, 0.0, 16.0)
        check_range("IndirectConfig.refine_threshold", self.refine_threshold, 0.0, 1.0e6, lo_open=True)
        check_int_range("IndirectConfig.refine_budget", self.refine_budget, 0, 65536)
        check_range("IndirectConfig.refine_min_ratio", self.refine_min_ratio, 0.0, 1.0)
        check_range("IndirectConfig.refine_min_radius", self.refine_min_radius, 0.0, 1.0e3)


@dataclass(frozen=True)
class TemporalConfig:
    """Temporal reprojection (thesis A2.6 cache test and A4 history).

    Attributes:
        enabled: reuse reprojected history in unsampled pixels.
        max_history_frames: history values older than this many frames are dropped, in [1, 1024].
        depth_eps_rel: cache-test tolerance as a fraction of the current depth, in (0, 1]: a hit needs
            ``|depth_prev(uv_prev) - |pos_prev - eye_prev|| < depth_eps_rel * depth`` with ``pos_prev`` the
            surface point at the previous frame's object transforms (thesis eq. 4, extended to moving objects);
            the temporal resolve checks each bilinear history tap the same way.
        cut_threshold_deg: a camera rotation above this many degrees between frames is a cut, in (0, 180].
        refresh_fraction: fraction of the normal samples still traced when the view and scene are static and
            history has converged, in [0, 1].
        normal_cos_min: a history tap is reused only when its normal and the current one have at least this
            cosine, in [-1, 1]; default 0.9 (about 26 degrees).
        clamp_gamma: half-width, in standard deviations, of the variance-clipping box that bounds the
            accumulated stochastic history of a traced pixel (5 x 5 neighbourhood of fresh values), in [0, 100].
        still_clamp_gamma: the clip box's half-width while the camera and the scene stand still, in [0, 100]: the
            history then reprojects exactly and needs no guard against ghosting, while clipping heavy-tailed Monte
            Carlo estimates towards their neighbours biases the accumulation low (path traced cornell, depth 3,
            64x36, CPU, 24 still frames: 0.917 of the converged mean at 1.25, 0.997 at 100, the default).
        motion_alpha_per_px: weight of a traced pixel's fresh stochastic value per pixel of screen motion
            (the history weight falls with motion), per pixel, in [0, 1]; 0.05 gives fresh-only at 20 px/frame.
        still_min_probability: with stochastic shading (AO rays, area-light samples), while the camera and scene
            stand still and the accumulation is not yet full (fewer than ``max_history_frames`` still frames),
            the sampling map's minimum probability is raised to this, in [0, 1], so that the periphery
            converges too (progressive refinement); then the refresh budget takes over. 0 disables it.
        stochastic_min_samples: with stochastic shading, an unsampled pixel that moved on screen (more than half
            a pixel) reuses history only once it has accumulated ``ceil(stochastic_min_samples / samples per
            pixel per frame)`` frames (the samples per pixel: ``ao_samples`` plus ``area_light_samples`` per area
            light); younger, noisier history is left to the reconstruction. In [1, 4096]; the default 4 reuses
            any history with 4 or more AO rays per pixel, history of 2 frames with 2 and of 4 frames with 1.
            Accumulation stops at ``max_history_frames``, so a value above ``max_history_frames`` times the
            samples per pixel never reuses moving stochastic history.
    """

    enabled: bool = True
    max_history_frames: int = 16
    depth_eps_rel: float = 0.01
    cut_threshold_deg: float = 30.0
    refresh_fraction: float = 0.25
    normal_cos_min: float = 0.9
    clamp_gamma: float = 1.25
    still_clamp_gamma: float = 100.0
    motion_alpha_per_px: float = 0.05
    still_min_probability: float = 0.25
    stochastic_min_samples: int = 4

    def __post_init__(self):
        check_int_range("TemporalConfig.max_history_frames", self.max_history_frames, 1, 1024)
        check_range("TemporalConfig.depth_eps_rel", self.depth_eps_rel, 0.0, 1.0, lo_open=True)
        check_range("TemporalConfig.cut_threshold_deg", self.cut_threshold_deg, 0.0, 180.0, lo_open=True)
        check_range("TemporalConfig.refresh_fraction", self.refresh_fraction, 0.0, 1.0)
        check_range("TemporalConfig.normal_cos_min", self.normal_cos_min, -1.0, 1.0)
        check_range("TemporalConfig.clamp_gamma", self.clamp_gamma, 0.0, 100.0)
        check_range("TemporalConfig.still_clamp_gamma", self.still_clamp_gamma, 0.0, 100.0)
        check_range("TemporalConfig.motion_alpha_per_px", self.motion_alpha_per_px, 0.0, 1.0)
        check_range("TemporalConfig.still_min_probability", self.still_min_probability, 0.0, 1.0)
        check_int_range("TemporalConfig.stochastic_min_samples", self.stochastic_min_samples, 1, 4096)
        check_bool("TemporalConfig.enabled", self.enabled)


@dataclass(frozen=True)
class Config:
    """All stage configs. Build variants with ``dataclasses.replace`` or ``Config.with_(...)``."""

    foveation: FoveationConfig = field(default_factory=FoveationConfig)
    saliency: SaliencyConfig = field(default_factory=SaliencyConfig)
    reorder: ReorderConfig = field(default_factory=ReorderConfig)
    shading: ShadingConfig = field(default_factory=ShadingConfig)
    reconstruction: ReconstructionConfig = field(default_factory=ReconstructionConfig)
    dof: DofConfig = field(default_factory=DofConfig)
    indirect: IndirectConfig = field(default_factory=IndirectConfig)
    temporal: TemporalConfig = field(default_factory=TemporalConfig)

    def __post_init__(self):
        expected = {
            "foveation": FoveationConfig,
            "saliency": SaliencyConfig,
            "reorder": ReorderConfig,
            "shading": ShadingConfig,
            "reconstruction": ReconstructionConfig,
            "dof": DofConfig,
            "indirect": IndirectConfig,
            "temporal": TemporalConfig,
        }
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, expected[f.name]):
                raise ValueError(f"Config.{f.name} must be a {expected[f.name].__name__}, got {show(v)} "
                                 f"({type(v).__name__})")

    def with_(self, **stage_overrides) -> "Config":
        """Copy with some fields of some stages replaced: ``cfg.with_(foveation={"block": 8})``."""
        changes = {}
        for stage, over in stage_overrides.items():
            if stage not in [f.name for f in fields(self)]:
                raise ValueError(f"Config.with_ stage must be one of {[f.name for f in fields(self)]}, got {stage!r}")
            cur = getattr(self, stage)
            if isinstance(over, dict):
                names = [f.name for f in fields(cur)]
                for k in over:
                    if k not in names:
                        raise ValueError(f"Config.with_({stage}=...) key must be one of {names}, got {show(k)}")
                over = replace(cur, **over)
            changes[stage] = over
        return replace(self, **changes)
