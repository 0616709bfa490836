"""Sampling-map ops (ALGORITHMS.md A2): NumPy (or Warp) arrays in, NumPy arrays out, running the kernels the
SamplingStage runs. Not for per-frame use: each call allocates and synchronizes."""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .. import parallel
from .._util import as_wp, check_image_size, get_device
from ..camera import _check_gaze
from ..config import Config, FoveationConfig, check_array, check_int_range, check_range, check_vec
from ..kernels.camera import CameraParams
from ..kernels.context import FrameContext
from ..kernels.reproject import cache_test_kernel
from ..kernels.sampling import (
    FrameParams,
    eccentricity_kernel,
    frame_setup_kernel,
    probability_kernel,
    threshold_kernel,
)
from ..kernels.saliency import dof_factor_kernel, gradient_kernel, lab_kernel
from ..stages.sampling import (
    NO_FALLOFF,
    clamp_gaze,
    dither_ranks,
    frame_rotation,
    launch_tile_pass,
    sampling_params,
)

__all__ = [
    "eccentricity_deg",
    "foveation_probability",
    "sample_map",
    "albedo_to_lab",
    "albedo_gradient",
    "normal_gradient",
    "dof_sampling_factor",
    "cache_test",
    "dither_ranks",
]


def _frame(width, height, gaze_px, fov_y_deg, dev, *, mar_slope=1.0, mar_fovea_deg=1.0, frame_index=0, block=1,
           falloff_deg=NO_FALLOFF):
    w, h = check_image_size(width, height)
    gaze = _check_gaze(gaze_px)
    fov = check_range("fov_y_deg", fov_y_deg, 0.0, 180.0, lo_open=True, hi_open=True)
    gx, gy = clamp_gaze(gaze, w, h)
    rot, phase = frame_rotation(frame_index, block)
    out = wp.zeros(1, dtype=FrameParams, device=dev)
    dummy_d = wp.zeros((1, 1), dtype=float, device=dev)
    dummy_h = wp.zeros((1, 1), dtype=wp.uint8, device=dev)
    ctx = FrameContext()  # the gaze and the field of view; no previous camera (no velocity, no cache test)
    cam = CameraParams()
    cam.tan_half_fov_y = math.tan(math.radians(fov) * 0.5)
    cam.aspect = float(w) / float(h)
    cam.width, cam.height = w, h
    ctx.cam = cam
    ctx.gaze = wp.vec2(gx, gy)
    wp.launch(frame_setup_kernel, dim=1,
              inputs=[ctx, w, h, float(mar_slope), float(mar_fovea_deg), float(falloff_deg), 0, 0.0, dummy_d, dummy_h,
                      0, 0, 0, rot, phase, 0.0, 0.0],
              outputs=[out], device=dev)
    return out, w, h


def eccentricity_deg(width, height, gaze_px, fov_y_deg, device=None) -> np.ndarray:
    """(H, W) float32: angle in degrees at the eye between the ray through the gaze point (pixels; off screen
    is valid) and the ray through each pixel centre, for a pinhole camera with vertical field of view
    ``fov_y_deg`` in (0, 180) and square pixels."""
    dev = get_device(device)
    frame, w, h = _frame(width, height, gaze_px, fov_y_deg, dev)
    out = wp.zeros((h, w), dtype=float, device=dev)
    parallel.launch(eccentricity_kernel, dim=(h, w), inputs=[frame], outputs=[out], device=dev)
    return out.numpy()


def foveation_probability(width, height, gaze_px, fov_y_deg, *, mar_slope, mar_fovea_deg, min_probability,
                          falloff_deg=None, fovea_deg=0.0, device=None) -> np.ndarray:
    """(H, W) float32 thesis eq. 2: ``clip(1 - (w - w_min) / w_far, min_probability, 1)``.

    ``w = mar_slope * e + mar_fovea_deg`` (degrees; e = ``eccentricity_deg``); ``w_min`` = angle between the
    rays through the gaze point and through the point one pixel to its right; ``w_far`` =
    ``mar_slope * e_max + mar_fovea_deg`` with ``e_max`` the largest eccentricity over the screen rectangle
    [0, W] x [0, H] (its corners, or an edge point for gazes far off screen).
    ``mar_slope`` in (0, 1] deg/deg, ``mar_fovea_deg`` in (0, 1], ``min_probability`` in [0, 1] (used as is;
    the SamplingStage raises it to 1 / block^2). ``falloff_deg`` (None or in (0, 180]): when given, ``w_far``
    uses ``min(e_max, falloff_deg)`` instead of ``e_max`` (``FoveationConfig.falloff_deg``). ``fovea_deg`` in
    [0, 180]: the probability is 1 where ``e <= fovea_deg`` (``FoveationConfig.fovea_deg``; 0 = eq. 2 alone).
    """
    m = check_range("mar_slope", mar_slope, 0.0, 1.0, lo_open=True)
    b = check_range("mar_fovea_deg", mar_fovea_deg, 0.0, 1.0, lo_open=True)
    xi = check_range("min_probability", min_probability, 0.0, 1.0)
    dev = get_device(device)
    fo = NO_FALLOFF if falloff_deg is None else check_range("falloff_deg", falloff_deg, 0.0, 180.0, lo_open=True)
    fd = check_range("fovea_deg", fovea_deg, 0.0, 180.0)
    frame, w, h = _frame(width, height, gaze_px, fov_y_deg, dev, mar_slope=m, mar_fovea_deg=b, falloff_deg=fo)
    cfg = Config(foveation=FoveationConfig(mar_slope=m, mar_fovea_deg=b, min_probability=xi, block=1))
    sp = sampling_params(cfg, w, h)
    sp.xi = xi  # exactly as given (block 1 would raise it to 1)
    sp.fovea_deg = fd
    out = wp.zeros((h, w), dtype=float, device=dev)
    parallel.launch(probability_kernel, dim=(h, w), inputs=[sp, frame], outputs=[out], device=dev)
    return out.numpy()


def sample_map(probability, *, block, frame_index=0, seed=0, device=None) -> np.ndarray:
    """(H, W) uint8 stratified binarization of ``probability`` ((H, W) finite floats; values outside [0, 1]
    act as 0 / 1).

    In every full aligned ``block`` x ``block`` tile each pixel's long-run rate over frames is exactly
    ``max(p, 1 / block^2)`` (exact over every block^2 consecutive frames up to the jitter of the fractional
    part); partial tiles at the right/bottom edges may get one extra sample. Every aligned tile, partial ones
    included, holds at least one sample. ``frame_index`` >= 0 rotates the pattern; ``seed`` in [0, 2^31 - 1]
    picks it.
    """
    k = check_int_range("block", block, 1, 64)
    fi = check_int_range("frame_index", frame_index, 0, None)
    sd = check_int_range("seed", seed, 0, 2**31 - 1)
    dev = get_device(device)
    p = check_array("probability", probability)
    if p.ndim != 2 or p.size == 0:
        raise ValueError(f"probability must be a non-empty (H, W) array, got shape {p.shape}")
    h, w = check_image_size(p.shape[1], p.shape[0])[::-1]
    cfg = Config(foveation=FoveationConfig(block=k))
    sp = sampling_params(cfg, w, h, sd)
    frame, _, _ = _frame(w, h, (0.0, 0.0), 60.0, dev, frame_index=fi, block=k)
    prob = as_wp(p, wp.float32, dev, name="probability")
    ranks = wp.array(dither_ranks(k), dtype=wp.int32, device=dev)
    out = wp.zeros((h, w), dtype=wp.uint8, device=dev)
    no_cache = wp.zeros((h, w), dtype=wp.uint8, device=dev)
    counts = wp.zeros(1, dtype=wp.int32, device=dev)
    counts_c = wp.zeros(1, dtype=wp.int32, device=dev)
    parallel.launch(threshold_kernel, dim=(h, w), inputs=[prob, ranks, sp, frame], outputs=[out], device=dev)
    launch_tile_pass(ranks, sp, frame, ((h + k - 1) // k, (w + k - 1) // k), out, no_cache, counts, counts_c, dev)
    return out.numpy()


def _image3(a, name, dev):
    arr = check_array(name, a)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{name} must be a non-empty (H, W, 3) array, got shape {arr.shape}")
    check_image_size(arr.shape[1], arr.shape[0])
    return as_wp(arr, wp.vec3, dev, name=name), arr.shape[:2]


def _image2(a, name, dev, shape=None, *, mask=False, **bounds):
    """A checked (H, W) array as a Warp array (float32, or uint8 0/1 with ``mask``: nonzero = set)."""
    arr = check_array(name, a, **bounds)
    if shape is not None and tuple(arr.shape) != tuple(shape):
        raise ValueError(f"{name} must have shape {tuple(shape)}, got {tuple(arr.shape)}")
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(f"{name} must be a non-empty (H, W) array, got shape {arr.shape}")
    check_image_size(arr.shape[1], arr.shape[0])
    if mask:
        return as_wp((arr != 0).astype(np.uint8), wp.uint8, dev, name=name)
    return as_wp(arr, wp.float32, dev, name=name)


def albedo_to_lab(albedo, device=None) -> np.ndarray:
    """(H, W, 3) float32 CIE-Lab (D65, 2 deg) of *linear* RGB ``albedo`` (H, W, 3), finite; equals
    ``skimage.color.rgb2lab`` of the sRGB-encoded albedo."""
    dev = get_device(device)
    a, (h, w) = _image3(albedo, "albedo", dev)
    out = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    parallel.launch(lab_kernel, dim=(h, w), inputs=[a], outputs=[out], device=dev)
    return out.numpy()


def albedo_gradient(albedo, device=None) -> np.ndarray:
    """(H, W) float32 3x3 Sobel gradient magnitude of the Lab albedo, max over L, a, b (raw: Lab units times
    the Sobel gain 4; the saliency term divides by 4 * LAB_STEP_FULL). Borders replicate the edge pixel."""
    dev = get_device(device)
    a, (h, w) = _image3(albedo, "albedo", dev)
    lab = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    out = wp.zeros((h, w), dtype=float, device=dev)
    parallel.launch(lab_kernel, dim=(h, w), inputs=[a], outputs=[lab], device=dev)
    parallel.launch(gradient_kernel, dim=(h, w), inputs=[lab], outputs=[out], device=dev)
    return out.numpy()


def normal_gradient(normal, device=None) -> np.ndarray:
    """(H, W) float32 3x3 Sobel gradient magnitude of the normal buffer (H, W, 3), max over x, y, z (raw)."""
    dev = get_device(device)
    n, (h, w) = _image3(normal, "normal", dev)
    out = wp.zeros((h, w), dtype=float, device=dev)
    parallel.launch(gradient_kernel, dim=(h, w), inputs=[n], outputs=[out], device=dev)
    return out.numpy()


def dof_sampling_factor(depth_m, *, focus_depth_m, sigma1_m, sigma2_m, dof_floor, device=None) -> np.ndarray:
    """(H, W) float32 F_DoF of the sampling map: 1 within ``sigma1_m`` of ``focus_depth_m``, falling linearly
    to ``dof_floor`` (in [0, 1]) over a further ``sigma2_m`` (> 0), ``dof_floor`` beyond. Metres."""
    f = check_range("focus_depth_m", focus_depth_m, 0.0, None, lo_open=True)
    s1 = check_range("sigma1_m", sigma1_m, 0.0, None)
    s2 = check_range("sigma2_m", sigma2_m, 0.0, None, lo_open=True)
    fl = check_range("dof_floor", dof_floor, 0.0, 1.0)
    dev = get_device(device)
    dw = _image2(depth_m, "depth_m", dev)
    out = wp.zeros(dw.shape, dtype=float, device=dev)
    parallel.launch(dof_factor_kernel, dim=dw.shape, inputs=[dw, f, s1, s2, fl], outputs=[out], device=dev)
    return out.numpy()


def cache_test(reproj_uv, position, hit, depth, depth_prev, valid_prev, eye_prev, *, depth_eps_rel,
               device=None) -> tuple:
    """Thesis eq. 4 cache test. Inputs (H, W[, C]): reproj_uv (2, previous-frame pixel position, centres at
    +0.5), position (3, world), hit (uint8), depth (metres from the current eye), depth_prev and valid_prev
    (previous frame's depth and valid-color mask), eye_prev (3,). A hit needs ``hit``, ``uv`` on screen,
    ``valid_prev`` at the nearest pixel ``floor(uv)`` and
    ``|depth_prev(floor(uv)) - |position - eye_prev|| < depth_eps_rel * depth``.

    Returns (hit_map (H, W) uint8, prev_index (H, W) int32 = y_prev * W + x_prev on a hit, else -1).
    """
    eps = check_range("depth_eps_rel", depth_eps_rel, 0.0, 1.0, lo_open=True)
    dev = get_device(device)
    dc = _image2(depth, "depth", dev, lo=0.0)
    h, w = dc.shape
    uv = as_wp(check_array("reproj_uv", reproj_uv), wp.vec2, dev, name="reproj_uv", shape=(h, w, 2))
    pos = as_wp(check_array("position", position), wp.vec3, dev, name="position", shape=(h, w, 3))
    ht = _image2(hit, "hit", dev, (h, w), mask=True)
    dp = _image2(depth_prev, "depth_prev", dev, (h, w), lo=0.0)
    vp = _image2(valid_prev, "valid_prev", dev, (h, w), mask=True)
    e = check_vec("eye_prev", eye_prev, 3)
    out_hit = wp.zeros((h, w), dtype=wp.uint8, device=dev)
    out_idx = wp.zeros((h, w), dtype=wp.int32, device=dev)
    parallel.launch(cache_test_kernel, dim=(h, w), inputs=[uv, pos, ht, dc, dp, vp, wp.vec3(*e), eps],
                    outputs=[out_hit, out_idx], device=dev)
    return out_hit.numpy(), out_idx.numpy()
