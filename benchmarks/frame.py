"""The frame benchmark: foveated against full-resolution tracing, timed the same way in one run, and the
foveated frame's error in motion.

Per scene x resolution:
* quality: along the scene's own camera path with a moving gaze, ``--frames`` frames; per-frame PSNR, SSIM and
  foveal PSNR (eccentricity <= 5 deg) against ``render_reference`` of the same frame, with history on (the
  configuration under test) and off (``TemporalConfig.enabled=False``), and the sampling rate per frame;
* timing, per shading ("default"; "ao8" = 8 AO rays per pixel): the reference is ``FrameLoop(policy="full")``
  (every pixel traced, the same frame path and CUDA graph replay), the foveated frame ``policy="foveated"`` and
  the default policy ("auto"); each the median of ``--timing-frames`` synchronized frames along the camera path
  after warm-up, the three loops taking turns frame by frame in a new (seeded) order every frame (so clock and
  load drift hit them alike, and no loop always follows the same other one); with ``--turns blocks`` they take
  turns in blocks of consecutive frames instead (``_timed_blocks``: each loop's frames follow its own, as in an
  application), and ``--turns frames,blocks`` records both (each record's ``turns``); per-stage ms from a
  ``timing=True`` run;
  ``overhead_ms`` = foveated frame - (G-buffer + traced shading + indirect) stage times; on CUDA also
  ``stage_gpu_ms`` and ``overhead_gpu_ms``, the same from a ``timing="gpu"`` run (CUDA-event stage times);
* stochastic (``--stochastic``): with ``ao_samples=4``, a static view's frame 0 and frame 29 against a converged
  reference (256 AO rays), and a moving path with history on and off against the converged reference.
* ao quality (part ``aoquality``): the heavy shading's error in motion. Along the same camera path and moving
  gaze, the full-resolution frame with ``--ao-samples`` AO rays per pixel (``policy="full"``, the timing's
  reference) and the foveated frame with as many are both compared with a converged frame (``--converged-ao``
  rays per pixel, ``render_reference``); per-frame PSNR, SSIM and foveal PSNR of both; the full-resolution
  frame with fewer AO rays (``--ao-sweep``) against the same converged frames, and all of them timed with the
  foveated frame as the timing part times (``--timing-frames``; 0: none): brute force with fewer rays at its
  error. The timing
  records of "ao8" then carry the foveated frame's quality (``psnr``) and the reference's (``ref_psnr``).

python benchmarks/frame.py --device cuda:0 [--scenes ...] [--sizes 1920x1080,3840x2160] [--frames 60]
"""

from __future__ import annotations

import ast
import math
import os
import sys
import textwrap
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, git_commit, md_table, write_results  # noqa: E402

ALL_SCENES = "cornell,city,eyechart,earth,bunny,spot,teapot,nefertiti,ogre"


def gaze_path(i, n, w, h):
    """A moving gaze: a Lissajous figure over the central 60 % x 40 % of the screen."""
    t = i / max(n, 1)
    return (w * (0.5 + 0.3 * math.sin(2 * math.pi * t)), h * (0.5 + 0.2 * math.sin(4 * math.pi * t + 0.5)))


def render_path_frame(loop, scene, i: int, n: int, w: int, h: int):
    """``loop`` renders frame ``i`` of the scene's camera path (time i / 30 s) with the gaze of ``gaze_path(i, n)``;
    returns the frame."""
    t = i / 30.0
    return loop.render(scene.camera_at(t), gaze_px=gaze_path(i, n, w, h), time=t)


def _psnr_only(img, ref, g, fov):
    """PSNR of the whole frame and of the fovea (<= 5 deg) on the host, SSIM left out (fast sweeps)."""
    from foveawarp.metrics import psnr, region_masks

    a, b = img.numpy(), ref.numpy()
    h, w = a.shape[:2]
    masks = region_masks(w, h, g, fov)
    out = {"psnr": psnr(a, b), "ssim": float("nan")}
    for k, mk in masks.items():
        out[f"psnr_{k}"] = psnr(a, b, mask=mk) if mk.any() else float("nan")
    return out


def _metric_fn(fast=False):
    import foveawarp.metrics as m

    if fast:
        return _psnr_only, "host-psnr-only"

    dev_fn = getattr(m, "region_metrics_device", None)
    if dev_fn is not None:
        return dev_fn, "device"
    return (lambda img, ref, g, fov: m.region_metrics(img.numpy(), ref.numpy(), g, fov)), "host"


def _fovea_key(d):
    for k in ("psnr_fovea", "fovea_psnr"):
        if k in d:
            return d[k]
    return float("nan")


def _summ(v):
    a = np.asarray(v, float)
    f = a[np.isfinite(a)]
    cap = np.minimum(a, 100.0)  # identical frames (inf dB) count as 100 dB in means
    return {"mean": float(np.mean(cap)), "min": float(np.min(a)) if a.size else float("nan"),
            "finite_min": float(np.min(f)) if f.size else float("inf")}


def quality(fw, scene, w, h, dev, cfg, frames, metrics):
    fov = scene.camera.fov_y_deg
    ref_loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
    on = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
    off = fw.FrameLoop(scene, w, h, config=cfg.with_(temporal={"enabled": False}), device=dev, timing=False,
                       policy="foveated")
    ref_img = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    rec = {"psnr": [], "ssim": [], "fovea_psnr": [], "psnr_off": [], "ssim_off": [], "fovea_psnr_off": [],
           "sampling_rate": [], "cache_hit_rate": []}
    for i in range(frames):
        t = i / 30.0
        cam = scene.camera_at(t)
        g = gaze_path(i, frames, w, h)
        wp.copy(ref_img, ref_loop.render_reference(cam, time=t, gaze_px=g).image)
        f = on.render(cam, gaze_px=g, time=t)
        m = metrics(f.image, ref_img, g, fov)
        rec["psnr"].append(m["psnr"])
        rec["ssim"].append(m["ssim"])
        rec["fovea_psnr"].append(_fovea_key(m))
        rec["sampling_rate"].append(f.stats["sampling_rate"])
        rec["cache_hit_rate"].append(f.stats["cache_hit_rate"])
        f = off.render(cam, gaze_px=g, time=t)
        m = metrics(f.image, ref_img, g, fov)
        rec["psnr_off"].append(m["psnr"])
        rec["ssim_off"].append(m["ssim"])
        rec["fovea_psnr_off"].append(_fovea_key(m))
    d = np.asarray(rec["psnr"]) - np.asarray(rec["psnr_off"])
    rec["history_gain_db_min"] = float(np.nanmin(np.where(np.isfinite(d), d, 100.0)))
    return rec


def _add_metrics(rec, prefix, m):
    """Append one frame's whole-frame PSNR, SSIM and foveal PSNR (``metrics``' dict ``m``) to the series
    ``{prefix}psnr``, ``{prefix}ssim`` and ``{prefix}fovea_psnr`` of ``rec``."""
    rec[f"{prefix}psnr"].append(m["psnr"])
    rec[f"{prefix}ssim"].append(m["ssim"])
    rec[f"{prefix}fovea_psnr"].append(_fovea_key(m))


def _last_record(records, kind, scene, width, config):
    """The last record of ``kind`` for (scene, width, config), or None."""
    return next((r for r in reversed(records) if r["kind"] == kind and r["scene"] == scene and r["width"] == width
                 and r["config"] == config), None)


def ao_quality(fw, scene, w, h, dev, cfg, frames, metrics, ao=8, converged_ao=256, sweep=(), timing_frames=0):
    """The full-resolution frame and the foveated frame, both with ``ao`` AO rays per pixel, against a converged
    frame (``converged_ao`` rays per pixel) of the same camera, time and gaze, along the camera path with a
    moving gaze. Returns per-frame series for both and the per-frame difference (foveated - reference, dB).

    ``sweep``: other AO ray counts of the full-resolution frame (brute force with fewer rays), each with its
    PSNR series against the same converged frames; with ``timing_frames`` > 0, every full-resolution frame of
    the sweep and the foveated frame are then timed the way ``timing`` times them (interleaved, medians), so
    time can be set against error at equal footing."""
    fov = scene.camera.fov_y_deg
    cao = cfg.with_(shading={"ao_samples": int(ao)})
    conv = fw.FrameLoop(scene, w, h, config=cfg.with_(shading={"ao_samples": int(converged_ao)}), device=dev,
                        timing=False, policy="foveated")
    full = fw.FrameLoop(scene, w, h, config=cao, device=dev, timing=False, policy="full")
    fovl = fw.FrameLoop(scene, w, h, config=cao, device=dev, timing=False, policy="foveated")
    others = {int(a): fw.FrameLoop(scene, w, h, config=cfg.with_(shading={"ao_samples": int(a)}), device=dev,
                                   timing=False, policy="full") for a in sweep if int(a) != int(ao)}
    conv_img = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    rec = {"ao_samples": int(ao), "converged_ao": int(converged_ao), "psnr": [], "ssim": [], "fovea_psnr": [],
           "ref_psnr": [], "ref_ssim": [], "ref_fovea_psnr": [], "sampling_rate": [],
           "sweep_psnr": {str(a): [] for a in others}}
    for i in range(frames):
        t = i / 30.0
        g = gaze_path(i, frames, w, h)
        wp.copy(conv_img, conv.render_reference(scene.camera_at(t), time=t, gaze_px=g).image)
        f = fovl.render(scene.camera_at(t), gaze_px=g, time=t)
        _add_metrics(rec, "", metrics(f.image, conv_img, g, fov))
        rec["sampling_rate"].append(f.stats["sampling_rate"])
        _add_metrics(rec, "ref_", metrics(full.render(scene.camera_at(t), gaze_px=g, time=t).image, conv_img, g, fov))
        for a, lp in others.items():
            rec["sweep_psnr"][str(a)].append(metrics(lp.render(scene.camera_at(t), gaze_px=g, time=t).image,
                                                     conv_img, g, fov)["psnr"])
    d = np.asarray(rec["psnr"]) - np.asarray(rec["ref_psnr"])
    rec["gain_db"] = d.tolist()
    rec["gain_db_min"] = float(np.min(d))
    if timing_frames > 0:
        loops = {"foveated": fovl, str(int(ao)): full, **{str(a): lp for a, lp in others.items()}}
        med = _timed_interleaved(loops, scene, w, h, timing_frames, {k: 8 for k in loops})
        rec["fov_ms"] = med.pop("foveated")
        rec["sweep_ms"] = med  # full-resolution frame ms per AO ray count (the timed ``ao`` one included)
    return rec


def _timed_interleaved(loops: dict, scene, w, h, n, warm: dict, seed: int = 0) -> dict:
    """Median synchronized frame ms of each loop, the loops taking turns frame by frame (frame i of every loop
    renders the same camera, time and gaze), so that clock and load drift hit them alike. ``warm``: frames each
    loop renders first, untimed (the "auto" loop's include its policy measurement).

    The turns come in a new order every frame (a permutation drawn from ``seed``): a loop that always renders
    right after the same other loop pays for it. With a fixed order (full resolution, foveated, auto) the auto
    loop always followed the foveated one, and its full-resolution frames measured 1.002-1.051x the
    reference's; with shuffled turns the same loops measured 1.000-1.012x, and a second reference loop
    0.999-1.011x (H100, `auto-order-e31-a251d8e-cuda.log`): the frame after the foveated loop's usually spends
    more host time (median +5 us over 32 cases), the host's caches holding the other loop's state."""
    t0_frame = _warm_up(loops, scene, w, h, n, warm)  # one timeline: every warm-up ends where the timed frames begin
    ms = {name: [] for name in loops}
    names = list(loops)
    rng = np.random.default_rng(seed)
    for i in range(t0_frame, t0_frame + n):
        for j in rng.permutation(len(names)):
            ms[names[j]].append(_timed_frame(loops[names[j]], scene, i, n, w, h))
    return {name: float(np.median(v)) for name, v in ms.items()}


def _timed_frame(loop, scene, i: int, n: int, w: int, h: int) -> float:
    """Synchronized wall ms of ``loop`` rendering frame ``i`` of the camera path (its time, camera and gaze)."""
    t = i / 30.0
    g = gaze_path(i, n, w, h)
    wp.synchronize_device(loop.device)
    t_start = time.perf_counter()
    # each loop gets its own camera object, made inside the timed region as an application would: a camera shared
    # by the loops would carry its cached basis and kernel parameters from the first loop that used it to the others
    # (c9cc304's run: the first loop, the reference, paid 0.10-0.20 ms more)
    loop.render(scene.camera_at(t), gaze_px=g, time=t)
    wp.synchronize_device(loop.device)
    return (time.perf_counter() - t_start) * 1e3


TURNS = ("frames", "blocks")
BLOCK_FRAMES, BLOCK_SKIP = 10, 2


def record_turns(rec: dict) -> str:
    """The turn schedule that timed a timing record: its "turns", or "frames" for records written before
    ``--turns`` existed (they were all timed frame by frame)."""
    return rec.get("turns", "frames")


def _warm_up(loops: dict, scene, w, h, n, warm: dict) -> int:
    """Render each loop's ``warm`` frames, untimed, so that every warm-up ends where the timed frames begin; returns
    that frame index."""
    t0_frame = max(warm.values())
    for name, loop in loops.items():
        for i in range(t0_frame - warm[name], t0_frame):
            render_path_frame(loop, scene, i, n, w, h)
    return t0_frame


def _timed_blocks(loops: dict, scene, w, h, n, warm: dict, block: int = BLOCK_FRAMES, skip: int = BLOCK_SKIP,
                  seed: int = 0) -> dict:
    """Median synchronized frame ms of each loop, the loops taking turns block by block: in each round every loop
    (in a new seeded order) renders the same ``block`` consecutive frames of the camera path (camera, time, gaze),
    each synchronized and timed as ``_timed_interleaved`` times them; the first ``skip`` frames of a turn are left
    out of the medians. Rounds go on until every loop has at least ``n`` timed frames.

    This is how an application runs one loop: frame after frame with nothing else on the GPU between them, so the
    data a frame leaves in the GPU's caches (the history, the previous depth, the BVH) is there for the next one.
    In ``_timed_interleaved`` every frame follows another loop's frame, which evicts it. Alternating blocks keeps
    what that scheme is for: clock and load drift hit the loops alike. Measured on the H100 (session 34,
    ``frame-s34-turns-c9f0667-run{1,2,3}``, 9 scenes x 2 sizes x 2 shadings): the two schedules' speed-ups agree
    within 2.5%, so the frame-by-frame figures do not understate the foveated frame."""
    if not 0 <= skip < block:
        raise ValueError(f"skip must be in [0, block - 1] = [0, {block - 1}], got {skip}")
    t0_frame = _warm_up(loops, scene, w, h, n, warm)
    ms = {name: [] for name in loops}
    names = list(loops)
    rng = np.random.default_rng(seed)
    rounds = -(-n // (block - skip))
    for r in range(rounds):
        f0 = t0_frame + r * block
        for j in rng.permutation(len(names)):
            for i in range(f0, f0 + block):
                frame_ms = _timed_frame(loops[names[j]], scene, i, n, w, h)
                if i - f0 >= skip:
                    ms[names[j]].append(frame_ms)
    return {name: float(np.median(v)) for name, v in ms.items()}


def timing(fw, scene, w, h, dev, cfg, n, turns=("frames",)):
    """The timing part's records for one scene, size and configuration: one per item of ``turns`` ("frames":
    ``_timed_interleaved``, "blocks": ``_timed_blocks``), each with its own fresh loops and the same camera path,
    and the per-stage times (timing runs, measured once) in every one."""
    bad = [t for t in turns if t not in TURNS]
    if bad or not turns:
        raise ValueError(f"turns items must be in {list(TURNS)}, got {list(turns)}")
    outs = [_timing_turns(fw, scene, w, h, dev, cfg, n, t) for t in turns]
    traced_keys = ("gbuffer", "shade", "indirect", "indirect_build")

    def stage_run(timing_mode):
        """Median per-stage ms of frames 6-15 of a ``timing=timing_mode`` foveated loop, the mean sampling
        rate, and the loop."""
        tl = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=timing_mode, policy="foveated")
        stages, rates = {}, []
        for i in range(16):
            f = render_path_frame(tl, scene, i, 16, w, h)
            if i >= 6:
                rates.append(f.stats["sampling_rate"])
                for k, v in f.stats.items():
                    if k.startswith("ms_") and k != "ms_frame":
                        stages.setdefault(k[3:], []).append(v)
        return {k: float(np.median(v)) for k, v in stages.items()}, rates, tl

    def overheads(fov_ms, stage_ms):
        traced = sum(stage_ms.get(k, 0.0) for k in traced_keys)
        return (float(max(fov_ms - traced, 0.0)),
                float(sum(v for k, v in stage_ms.items() if k not in traced_keys + ("scene",))))

    stage_ms, rates, tl = stage_run(True)
    # the same from CUDA-event stage times (timing="gpu": one synchronization per frame, no per-stage
    # synchronization inflating the small stages; a stage's host work that overlaps earlier kernels left out)
    gpu_ms = stage_run("gpu")[0] if dev.is_cuda else None
    for out in outs:
        overhead, stage_sum = overheads(out["fov_ms"], stage_ms)
        out.update(stage_ms=stage_ms, overhead_ms=overhead, overhead_stage_sum_ms=stage_sum,
                   timing_sampling_rate=float(np.mean(rates)),
                   bvh=[tl.dscene.bvh_constructor, tl.dscene.bvh_leaf_size])  # the tree built (after any fallback)
        if gpu_ms is not None:
            out["stage_gpu_ms"] = gpu_ms
            out["overhead_gpu_ms"], out["overhead_stage_sum_gpu_ms"] = overheads(out["fov_ms"], gpu_ms)
    return outs


def _timing_turns(fw, scene, w, h, dev, cfg, n, turns: str) -> dict:
    """Reference, foveated and default-policy frame times of new loops, timed with ``turns``."""
    loops = {"full": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="full"),
             "foveated": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated"),
             "auto": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False)}
    auto = loops["auto"]
    # the auto loop measures both paths over its first frames; its timed frames come after (no re-measurement
    # falls inside them: POLICY_PERIOD is far longer)
    warm = {"full": 8, "foveated": 8, "auto": auto.policy_measurement_frames() + 2}
    timed = _timed_interleaved if turns == "frames" else _timed_blocks
    med = timed(loops, scene, w, h, n, warm)
    out = {"turns": turns, "ref_ms": med["full"], "fov_ms": med["foveated"], "auto_ms": med["auto"],
           "auto_path": auto._pol_choice, "auto_estimates": dict(auto._pol_est),
           "speedup": med["full"] / med["foveated"]}
    if turns == "blocks":
        out["block_frames"], out["block_skip"] = BLOCK_FRAMES, BLOCK_SKIP
    return out


def stochastic(fw, scene, w, h, dev, cfg, frames, metrics):
    """ao_samples=4: static view convergence and motion vs history off, against a 256-ray reference."""
    fov = scene.camera.fov_y_deg
    c4 = cfg.with_(shading={"ao_samples": 4})
    conv = fw.FrameLoop(scene, w, h, config=cfg.with_(shading={"ao_samples": 256}), device=dev, timing=False,
                        policy="foveated")
    ref_img = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    cam = scene.camera_at(0.0)
    g = (w * 0.5, h * 0.5)
    wp.copy(ref_img, conv.render_reference(cam, time=0.0).image)
    loop = fw.FrameLoop(scene, w, h, config=c4, device=dev, timing=False, policy="foveated")
    static = []
    for i in range(30):
        f = loop.render(cam, gaze_px=g, time=0.0)
        if i in (0, 29):
            static.append(metrics(f.image, ref_img, g, fov)["psnr"])
    on = fw.FrameLoop(scene, w, h, config=c4, device=dev, timing=False, policy="foveated")
    off = fw.FrameLoop(scene, w, h, config=c4.with_(temporal={"enabled": False}), device=dev, timing=False,
                       policy="foveated")
    mon, moff = [], []
    for i in range(frames):
        t = i / 30.0
        cam = scene.camera_at(t)
        g = gaze_path(i, frames, w, h)
        wp.copy(ref_img, conv.render_reference(cam, time=t).image)
        mon.append(metrics(on.render(cam, gaze_px=g, time=t).image, ref_img, g, fov)["psnr"])
        moff.append(metrics(off.render(cam, gaze_px=g, time=t).image, ref_img, g, fov)["psnr"])
    return {"static_psnr_frame0": static[0], "static_psnr_frame29": static[1],
            "static_gain_db": static[1] - static[0], "motion_psnr_on": mon, "motion_psnr_off": moff,
            "motion_min_gain_db": float(np.min(np.asarray(mon) - np.asarray(moff)))}


def main(argv=None):
    p = base_parser(__doc__)
    p.add_argument("--scenes", default=ALL_SCENES)
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--timing-frames", type=int, default=50, help="timed frames per loop (0: the aoquality part times nothing)")
    p.add_argument("--configs", default="default={}",
                   help="';'-separated name=python-dict Config.with_ overrides (quality part per config)")
    p.add_argument("--parts", default="quality,timing", help="quality,timing,aoquality,stochastic")
    p.add_argument("--ao-samples", type=int, default=8, help="AO rays per pixel of the aoquality part (1-64)")
    p.add_argument("--ao-sweep", default="1,2,4",
                   help="other AO ray counts of the full-resolution frame in the aoquality part ('' for none)")
    p.add_argument("--converged-ao", type=int, default=256,
                   help="AO rays per pixel of the aoquality part's converged frame (above --ao-samples, <= 4096)")
    p.add_argument("--stochastic-scenes", default="cornell,city")
    p.add_argument("--name", default="frame")
    p.add_argument("--bvh", default=None, help="every scene's BVH as CTOR or CTOR-LEAF (e.g. sah-4; default: auto)")
    p.add_argument("--psnr-only", action="store_true", help="skip SSIM (host PSNR only: fast sweeps)")
    p.add_argument("--turns", default="frames",
                   help="how the timing part's loops take turns: frames (one frame each, in a new order every "
                        "frame), blocks (%d frames each, the first %d untimed), or both: frames,blocks"
                        % (BLOCK_FRAMES, BLOCK_SKIP))
    args = p.parse_args(argv)
    import foveawarp as fw

    wp.config.quiet = True
    dev = wp.get_device(args.device)
    metrics, where = _metric_fn(args.psnr_only)
    parts = set(args.parts.split(","))
    unknown = parts - {"quality", "timing", "aoquality", "stochastic"}
    if unknown:
        p.error(f"--parts items must be in [quality, timing, aoquality, stochastic], got {sorted(unknown)}")
    if not 1 <= args.ao_samples <= 64:
        p.error(f"--ao-samples must be in [1, 64], got {args.ao_samples}")
    items = [v.strip() for v in args.ao_sweep.split(",") if v.strip()]
    if not all(v.isdigit() and 1 <= int(v) <= 64 for v in items):
        p.error(f"--ao-sweep items must be integers in [1, 64], got {args.ao_sweep!r}")
    sweep = [int(v) for v in items]
    if not args.ao_samples < args.converged_ao <= 4096:
        p.error(f"--converged-ao must be in [{args.ao_samples + 1}, 4096] (above --ao-samples), got {args.converged_ao}")
    bvh = None
    if args.bvh:
        from benchmarks.bvh import parse_configs

        (bvh,) = parse_configs(p, args.bvh, "--bvh") if "," not in args.bvh else p.error("--bvh takes one choice")
    configs = []
    for item in args.configs.split(";"):
        name, _, lit = item.partition("=")
        configs.append((name.strip(), ast.literal_eval(lit) if lit.strip() else {}))
    turns = tuple(v.strip() for v in args.turns.split(",") if v.strip())
    if not turns or any(t not in TURNS for t in turns) or len(set(turns)) != len(turns):
        p.error(f"--turns must be distinct items of {list(TURNS)}, got {args.turns!r}")
    records, rows, arows = [], [], []
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    if args.quick:
        sizes, args.frames, args.timing_frames = [(96, 54)], 4, 3
    for name in args.scenes.split(","):
        try:
            scene = fw.load_scene(name)
            if bvh is not None:
                scene.bvh_constructor, scene.bvh_leaf_size = bvh
        except ValueError as e:
            print(f"skip {name}: {e}", flush=True)
            continue
        for w, h in sizes:
            for cname, over in configs:
                cfg = fw.Config().with_(**over) if over else fw.Config()
                base = {"device": dev.alias, "scene": scene.name, "width": w, "height": h, "config": cname,
                        "overrides": over, "metrics_on": where, "commit": git_commit(),
                        "bvh_requested": [scene.bvh_constructor, scene.bvh_leaf_size]}
                t0 = time.perf_counter()
                if "quality" in parts:
                    q = quality(fw, scene, w, h, dev, cfg, args.frames, metrics)
                    q["sampling_rate_series"] = q.pop("sampling_rate")
                    rec = {**base, "kind": "quality", "sampling_rate": float(np.mean(q["sampling_rate_series"])), **q}
                    records.append(rec)
                    row = {"scene": scene.name, "size": f"{w}x{h}", "config": cname,
                           "rate": rec["sampling_rate"], "rate_max": float(np.max(q["sampling_rate_series"])),
                           "psnr": _summ(q["psnr"])["mean"], "psnr_min": _summ(q["psnr"])["min"],
                           "ssim": float(np.mean(q["ssim"])), "ssim_min": float(np.min(q["ssim"])),
                           "fovea_min": _summ(q["fovea_psnr"])["min"],
                           "psnr_off": _summ(q["psnr_off"])["mean"], "hist_gain_min": q["history_gain_db_min"]}
                    rows.append(row)
                    print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
                if "aoquality" in parts:
                    aq = ao_quality(fw, scene, w, h, dev, cfg, args.frames, metrics, args.ao_samples,
                                    args.converged_ao, sweep, args.timing_frames)
                    aq["sampling_rate_series"] = aq.pop("sampling_rate")
                    rec = {**base, "kind": "ao_quality", "sampling_rate": float(np.mean(aq["sampling_rate_series"])),
                           **aq}
                    records.append(rec)
                    row = {"scene": scene.name, "size": f"{w}x{h}", "config": cname, "ao": args.ao_samples,
                           "rate": rec["sampling_rate"],
                           "ref_psnr": _summ(aq["ref_psnr"])["mean"], "ref_psnr_min": _summ(aq["ref_psnr"])["min"],
                           "fov_psnr": _summ(aq["psnr"])["mean"], "fov_psnr_min": _summ(aq["psnr"])["min"],
                           "ref_ssim": float(np.mean(aq["ref_ssim"])), "fov_ssim": float(np.mean(aq["ssim"])),
                           "ref_fovea": _summ(aq["ref_fovea_psnr"])["mean"], "fov_fovea": _summ(aq["fovea_psnr"])["mean"],
                           "gain_db_min": aq["gain_db_min"],
                           **{f"ref{a}_psnr": _summ(v)["mean"] for a, v in aq["sweep_psnr"].items()},
                           **({"fov_ms": aq["fov_ms"], **{f"ref{a}_ms": v for a, v in aq["sweep_ms"].items()}}
                              if "fov_ms" in aq else {})}
                    arows.append(row)
                    print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
                if "timing" in parts:
                    qrec = _last_record(records, "quality", scene.name, w, cname)
                    qual = {} if qrec is None else {
                        "psnr": _summ(qrec["psnr"])["mean"], "ssim": float(np.mean(qrec["ssim"])),
                        "fovea_psnr": _summ(qrec["fovea_psnr"])["mean"], "quality_shading": "default"}
                    arec = _last_record(records, "ao_quality", scene.name, w, cname)
                    aqual = {} if arec is None or arec["ao_samples"] != 8 else {
                        "psnr": _summ(arec["psnr"])["mean"], "ssim": float(np.mean(arec["ssim"])),
                        "fovea_psnr": _summ(arec["fovea_psnr"])["mean"], "ref_psnr": _summ(arec["ref_psnr"])["mean"],
                        "ref_ssim": float(np.mean(arec["ref_ssim"])),
                        "quality_shading": f"ao8 against {arec['converged_ao']} AO rays"}
                    for shading, sover in (("default", {}), ("ao8", {"shading": {"ao_samples": 8}})):
                        c2 = cfg.with_(**sover) if sover else cfg
                        for tm in timing(fw, scene, w, h, dev, c2, args.timing_frames, turns):
                            rec = {**base, "kind": "timing", "shading": shading, "gbuffer_mode": c2.foveation.gbuffer,
                                   "sampling_rate": tm["timing_sampling_rate"],
                                   **(aqual if shading == "ao8" and aqual else qual), **tm}
                            records.append(rec)
                            print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in rec.items()
                                   if k not in ("stage_ms", "stage_gpu_ms", "overrides", "auto_estimates")}, flush=True)
                        print("   stages", {k: round(v, 3) for k, v in tm["stage_ms"].items()}, flush=True)
                        if "stage_gpu_ms" in tm:
                            print("   stages (gpu)", {k: round(v, 3) for k, v in tm["stage_gpu_ms"].items()}, flush=True)
                if "stochastic" in parts and scene.name.split("+")[0] in args.stochastic_scenes.split(","):
                    st = stochastic(fw, scene, w, h, dev, cfg, min(args.frames, 30), metrics)
                    records.append({**base, "kind": "stochastic", **st})
                    print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in st.items()
                           if not isinstance(v, list)}, flush=True)
                print(f"   ({time.perf_counter() - t0:.1f} s)", flush=True)
                # keep what is measured so far (a run cut short by a time limit still leaves its records)
                write_results(args.name, dev, {"records": records, "frames": args.frames,
                                               "timing_frames": args.timing_frames, "partial": True}, "", args.out)
    md = md_table(rows, list(rows[0])) if rows else ""
    trows = [{"scene": r["scene"], "size": f"{r['width']}x{r['height']}", "config": r["config"],
              "shading": r["shading"], **({"turns": r["turns"]} if len(turns) > 1 else {}), "rate": r["sampling_rate"], "ref_ms": r["ref_ms"], "fov_ms": r["fov_ms"],
              "speedup": r["speedup"], "auto_ms": r["auto_ms"], "auto_path": r["auto_path"],
              "overhead_ms": r["overhead_ms"], **({"overhead_gpu_ms": r["overhead_gpu_ms"]}
                                                   if "overhead_gpu_ms" in r else {})}
             for r in records if r["kind"] == "timing"]
    if arows:
        md += "\n\n" + md_table(arows, list(arows[0]))
    if trows:
        md += "\n\n" + md_table(trows, list(trows[0]))
    write_results(args.name, dev, {"records": records, "frames": args.frames, "timing_frames": args.timing_frames},
                  md, args.out)
    plot(records, Path(args.out) if args.out else Path(__file__).resolve().parent / "results", args.name, dev)
    print(md)


def pareto(points):
    """Indices of (ms, psnr) points that no other point beats in both (less time and more PSNR)."""
    return [i for i, (t, q) in enumerate(points)
            if not any(t2 <= t and q2 >= q and (t2 < t or q2 > q) for j, (t2, q2) in enumerate(points) if j != i)]


def plot(records, folder, name, dev):
    """Time against error per scene and resolution: foveated points per configuration and shading, the
    full-resolution reference's time as a vertical line, the Pareto front of the foveated points; where a
    record carries the reference's own error (``ref_psnr``: heavy shading against a converged frame), the
    reference as a cross at its time and error. Where the aoquality part timed its loops, that shading's panel
    takes every time from that one loop (the foveated point, the reference line and the brute-force crosses)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except Exception:
        print("matplotlib not installed: no plot")
        return
    tim = [r for r in records if r["kind"] == "timing" and "psnr" in r]
    if not tim:
        return
    keys = sorted({(r["scene"], r["width"], r["height"]) for r in tim}, key=lambda k: (k[1], k[0]))
    configs_seen = {r["config"] for r in tim}  # points are labelled by configuration only where there are several
    n = len(keys)
    cols = min(n, 6)
    rows = (n + cols - 1) // cols
    # one or two panels get more room than a panel of a grid, so their labels and legend stay readable
    pw, ph = (5.0, 4.0) if cols <= 2 else (3.2, 2.8)
    fig, axes = plt.subplots(rows, cols, figsize=(pw * cols, ph * rows), squeeze=False)
    for ax, key in zip(axes.flat, keys):
        rs = [r for r in tim if (r["scene"], r["width"], r["height"]) == key]
        for shading, mk in (("default", "o"), ("ao8", "s")):
            pts = [(r["fov_ms"], r["psnr"], r["config"]) for r in rs if r["shading"] == shading]
            if not pts:
                continue
            ref = [r["ref_ms"] for r in rs if r["shading"] == shading][0]
            aq = [r for r in records if r["kind"] == "ao_quality" and "sweep_ms" in r
                  and (r["scene"], r["width"], r["height"]) == key and f"ao{r['ao_samples']}" == shading]
            if aq:
                # one timing loop for the whole panel of this shading: the aoquality part's, where the foveated
                # frame and every full-resolution frame took turns
                a = aq[-1]
                pts = [(a["fov_ms"], p[1], p[2]) for p in pts]
                ref = a["sweep_ms"][str(a["ao_samples"])]
            line = ax.axvline(ref, ls="--", lw=1, color="C0" if shading == "default" else "C3")
            ax.scatter([p[0] for p in pts], [p[1] for p in pts], marker=mk, color=line.get_color(),
                       label=f"{shading} foveated (ref {ref:.2f} ms)")
            refq = [(r["ref_ms"], r["ref_psnr"]) for r in rs if r["shading"] == shading and "ref_psnr" in r]
            if refq and not aq:  # the reference's own error (heavy shading, both against a converged frame)
                ax.scatter([q[0] for q in refq], [q[1] for q in refq], marker="x", color=line.get_color(),
                           label=f"{shading} reference")
            if aq:  # brute force with fewer AO rays: full-resolution frames at their time and error
                series = {**a["sweep_psnr"], str(a["ao_samples"]): a["ref_psnr"]}
                bf = sorted((a["sweep_ms"][k], _summ(v)["mean"], k) for k, v in series.items() if k in a["sweep_ms"])
                ax.plot([b[0] for b in bf], [b[1] for b in bf], ls=":", marker="x", lw=1, color=line.get_color(),
                        label="full resolution, " + "/".join(b[2] for b in bf) + " AO rays")
            front = sorted(pareto([(p[0], p[1]) for p in pts]), key=lambda i: pts[i][0])
            ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], color=line.get_color(), lw=1)
            for k, p in enumerate(pts):  # labels stepped up and down so that close points' labels part
                ax.annotate(p[2] if len(configs_seen) > 1 else shading, (p[0], p[1]), fontsize=6,
                            xytext=(4, 6 * (k % 3) - 6), textcoords="offset points")
        ax.set_title(f"{key[0]} {key[1]}x{key[2]}", fontsize=8)
        ax.set_xlabel("frame ms", fontsize=7)
        ax.set_ylabel("PSNR dB (mean over the path)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=5)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    alias = dev if isinstance(dev, str) else wp.get_device(dev).alias  # a string: redraw from a JSON elsewhere
    note = ("; circles: default shading against full-resolution tracing; squares and crosses: "
            f"{int(aqs[0]['ao_samples'])} AO rays and fewer against {int(aqs[0]['converged_ao'])}-ray frames"
            if (aqs := [r for r in records if r["kind"] == "ao_quality"]) else "")
    # wrapped to the figure's width (about 15 characters an inch at this size): a long title was cut at both ends
    title = f"foveated frame time vs PSNR; dashed: full-resolution reference ({alias}){note}"
    fig.suptitle(textwrap.fill(title, width=max(40, int(15 * fig.get_figwidth()))), fontsize=9)
    fig.tight_layout()
    tag = "cuda" if alias.startswith("cuda") else "cpu"
    fig.savefig(folder / f"{name}-{tag}.png", dpi=110)


if __name__ == "__main__":
    main()
