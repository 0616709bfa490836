"""Does the light tree give indirect light cheaper than a sampled RSM at the same perceived quality, light moving?

Indirect light is ALGORITHMS.md C. For each scene (``cornell``, ``bunny-in-box``, ``teapot-in-box``: the Cornell box
with the teapot mesh in place of the bunny; mesh scenes are skipped when the mesh is absent) and each RSM size
(``--rsm``, default 256,512 on CUDA), the scene's spot light moves along an arc over ``--frames`` frames (default
8): its position turns about the vertical through its rest position (radius 15% of the scene extent, -60 to +60
degrees), aimed at a fixed point 1.5 m along its rest axis, so the RSM and every VPL move every frame. Per frame,
every method renders the full frame, direct (``FrameLoop.render_reference``, shadow rays) + indirect, tone-mapped
(the frame loop's Hable operator), and is compared with the same frame with the EXACT all-VPL
indirect sum:
  * ``flip``: mean FLIP (NVIDIA ``flip-evaluator``, LDR, sRGB inputs, pixels per degree 67 x eval_width / 1920:
    the eval frame seen at the size of a 1080p frame at FLIP's default 67 ppd); absent: ``null`` and the
    equal-FLIP columns are skipped (no other metric stands in for it);
  * ``ssim`` (scikit-image, channel-wise, data range 1; 1 - SSIM is reported as ``dssim``) and ``rel_l2`` of the
    tone-mapped frame;
  * ``flicker``: ``sum |(F_t - F_t-1) - (E_t - E_t-1)| / sum |E_t - E_t-1|`` over all pixels and frame pairs (F the
    method's tone-mapped frames, E the exact ones): 0 when the error does not change from frame to frame.
Sizes. The quality metrics are measured on frames of ``--eval-size`` (default 480x270 on CUDA: the exact sum
over 512^2 VPLs at 1080p would be 5e11 VPL terms per frame); the timings on frames of ``--size`` (default
1920x1080 on CUDA): ``ms_gather`` (``run_full`` over every hit pixel), ``ms_rebuild`` (``build``: RSM trace +
pyramid + cut, or RSM trace + sample list) and ``ms_frame = ms_gather + ms_rebuild`` (the light moves every
frame). CUDA graphs replay the launches unless ``--no-graphs``.
Methods: ``exact``; tree variants (``--variants``: the default ``IndirectConfig`` first, then the paper's point
clusters without refinement, the extended emitters without refinement, other refinement settings and limit
levels); the Poisson-sampled RSM on a geometric ladder of sample counts (x2 from 64 to rsm^2 / 2; timings above
``--max-timed`` samples are extrapolated linearly in the sample count from the two largest timed counts, and
say so).
Comparisons per tree variant: the sample count at which the sampled RSM's FLIP (and flicker) equals the tree's
(piecewise linear in log samples vs log metric, at the first ladder step that reaches it; a tree better than
every ladder point is reported as a lower bound ``>=``), the sampled ``ms_frame`` there, and the time ratio
``speedup = sampled ms_frame / tree ms_frame`` (rebuild counted: the light moves every frame);
``gather_speedup`` is the same ratio of ``ms_gather`` alone (a static light); ``count_speedup`` is the equal-quality
sample count over the tree's ``sample_equiv`` (its gather time in sampled VPLs, timed interleaved with a
1024-sample gather: robust to a shared machine's load, and the figure to read on the CPU).
Writes indirect-<tag>.json / .md and the side-by-side image indirect-<tag>.png: per scene at the first RSM size,
the last frame: exact | tree (default) | sampled RSM at the tree's ``ms_frame`` (equal time), and below it
|difference| x 8.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, parse_sizes, plot_path, progress, time_ms, write_results  # noqa

CANONICAL = ("python benchmarks/indirect.py --device cuda:0 --out benchmarks/results --tag h200 "
             "--scenes cornell,bunny-in-box --rsm 256")

# (label, IndirectConfig overrides); the first is the default config
VARIANTS = {
    # start 4, limit 7, extended emitters (scale 1.0), refinement t0.32 (second-order error), min angular size
    # 0.25, min radius 0.5 d_min, budget 512
    "default": {},
    "point L4 (paper)": dict(start_level=3, limit_level=4, cluster_radius_scale=0.0, refine_budget=0),
    "extended L4": dict(start_level=3, limit_level=4, refine_budget=0),
    "extended L6": dict(limit_level=6, refine_budget=0),
    "extended L7": dict(refine_budget=0),
    "L6 refine t0.08": dict(limit_level=6, refine_threshold=0.08),
    "L7 refine t0.64": dict(refine_threshold=0.64),
    "L7 refine t0.16": dict(refine_threshold=0.16),
    # the previous default's settings (limit 6, t0.02, budget 256, no minimum radius), with today's split rule
    "L6 t0.02 b256 mr0 (previous)": dict(limit_level=6, refine_threshold=0.02, refine_budget=256,
                                         refine_min_radius=0.0),
    # calibration only (not in the default set)
    "L6 refine t0.02": dict(limit_level=6, refine_threshold=0.02),
    "L6 refine t0.16": dict(limit_level=6, refine_threshold=0.16),
    "L7 refine r0.35": dict(refine_min_ratio=0.35),
    "L7 refine mr1": dict(refine_min_radius=1.0),
    "extended L6 s1.5": dict(limit_level=6, cluster_radius_scale=1.5, refine_budget=0),
}
DEFAULT_VARIANTS = ("default", "point L4 (paper)", "extended L4", "extended L6", "extended L7", "L6 refine t0.08",
                    "L7 refine t0.64", "L7 refine t0.16", "L6 t0.02 b256 mr0 (previous)")
QUICK_VARIANTS = ("default", "point L4 (paper)", "extended L6")


# ---------------------------------------------------------------------------------------------------
# metrics (run in worker processes)


def _flip(ref, test, ppd):
    try:
        import flip_evaluator
    except ImportError:
        return None
    _, mean, _ = flip_evaluator.evaluate(ref, test, "LDR", inputsRGB=True, applyMagma=False,
                                         computeMeanError=True, parameters={"ppd": float(ppd)})
    return float(mean)


def _frame_metrics(ref, test, ppd, use_flip=True):
    from skimage.metrics import structural_similarity

    ref = np.clip(ref, 0.0, 1.0).astype(np.float32)
    test = np.clip(test, 0.0, 1.0).astype(np.float32)
    ssim = float(structural_similarity(ref, test, channel_axis=2, data_range=1.0))
    rel = float(np.linalg.norm(test - ref) / max(np.linalg.norm(ref), 1e-30))
    return {"flip": _flip(ref, test, ppd) if use_flip else None, "ssim": ssim, "rel_l2": rel}


def flip_available() -> bool:
    try:
        import flip_evaluator  # noqa: F401

        return True
    except ImportError:
        return False


# ---------------------------------------------------------------------------------------------------
# equal-quality solve


def crossing(ns, vals, target):
    """Sample count where the ladder's metric (decreasing in n, roughly) first reaches ``target``:
    (n, bound) with bound "" (interpolated in log n vs log metric), ">=" (the target is below every ladder
    value: n is the largest count, a lower bound) or "<=" (the target is above the first value: n is the
    smallest count, an upper bound)."""
    ns = np.asarray(ns, float)
    vals = np.maximum(np.asarray(vals, float), 1e-12)
    o = np.argsort(ns)
    ns, vals = ns[o], vals[o]
    target = max(float(target), 1e-12)
    if vals[0] <= target:
        return float(ns[0]), "<="
    for i in range(1, len(ns)):
        if vals[i] <= target:
            a, b = math.log(vals[i - 1]), math.log(vals[i])
            t = 0.0 if a == b else (a - math.log(target)) / (a - b)
            return float(math.exp(math.log(ns[i - 1]) + t * (math.log(ns[i]) - math.log(ns[i - 1])))), ""
    return float(ns[-1]), ">="


def ms_at(ns, ms, n):
    """Sampled ms_frame at n samples: piecewise linear between ladder points, linear beyond the ends."""
    ns, ms = np.asarray(ns, float), np.asarray(ms, float)
    o = np.argsort(ns)
    ns, ms = ns[o], ms[o]
    if ns[0] <= n <= ns[-1]:
        return float(np.interp(n, ns, ms))
    i = 0 if n < ns[0] else len(ns) - 2
    slope = (ms[i + 1] - ms[i]) / max(ns[i + 1] - ns[i], 1e-30)
    return float(max(ms[i] + (n - ns[i]) * slope, 1e-6))


def n_at_ms(ns, ms, target):
    """Sample count whose sampled ms_frame equals ``target`` (ms increasing in n), at least 1."""
    ns, ms = np.asarray(ns, float), np.asarray(ms, float)
    o = np.argsort(ns)
    ns, ms = ns[o], ms[o]
    if ms[0] <= target <= ms[-1]:
        return max(1.0, float(np.interp(target, ms, ns)))
    i = 0 if target < ms[0] else len(ns) - 2
    slope = (ns[i + 1] - ns[i]) / max(ms[i + 1] - ms[i], 1e-30)
    return max(1.0, float(ns[i] + (target - ms[i]) * slope))


# ---------------------------------------------------------------------------------------------------
# scene, light path


def load_named(name):
    import foveawarp as fw
    from foveawarp.scene import find_named_mesh
    from foveawarp.scenes import bunny_in_box

    if name == "teapot-in-box":
        p = find_named_mesh("teapot")
        if p is None:
            raise ValueError("teapot-in-box needs teapot.obj in the shared scene folder")
        return bunny_in_box(path=p)
    return fw.load_scene(name)


def arc_light(light0, extent, t, frames):
    """The spot light of frame t: turned about the vertical through its rest position, aimed at a fixed point."""
    import foveawarp as fw

    p0 = np.asarray(light0.position, float)
    d0 = np.asarray(light0.direction, float)
    target = p0 + 1.5 * d0
    phi = math.radians(-60.0 + 120.0 * t / max(frames - 1, 1))
    r = 0.15 * extent
    p = p0 + r * np.array([math.sin(phi), 0.0, math.cos(phi) - 1.0])
    return fw.Light(kind=light0.kind, position=tuple(p), direction=tuple(target - p), cone_deg=light0.cone_deg,
                    intensity=light0.intensity, penumbra=light0.penumbra)


def set_light(ds, idx, light):
    """Replace light ``idx`` of the DeviceScene's host scene and its device copy (the same conversion as
    DeviceScene)."""
    from foveawarp.kernels.shade import LightParams
    from foveawarp.scene import light_params

    ds.scene.lights[idx] = light
    ps = [light_params(l) for l in ds.scene.lights]
    ds.lights = wp.array(ps, dtype=LightParams, device=ds.device)


def _graph_or_plain(fn, dev, use_graphs):
    """A callable replaying ``fn``'s launches as a CUDA graph when possible, else ``fn`` itself."""
    if not (use_graphs and dev.is_cuda):
        return fn, False
    try:
        fn()  # load modules outside the capture
        with wp.ScopedCapture(device=dev) as cap:
            fn()
        g = cap.graph
        return (lambda: wp.capture_launch(g)), True
    except Exception as e:  # capture can fail (e.g. no mempool); fall back to plain launches
        print(f"  (graph capture failed: {e}; timing plain launches)")
        return fn, False


# ---------------------------------------------------------------------------------------------------


def bench(name, n, args, dev, pool, sizes):
    import foveawarp as fw
    from foveawarp.config import IndirectConfig
    from foveawarp.kernels.tonemap import tonemap_kernel
    from foveawarp.stages.indirect import IndirectStage

    try:
        scene = load_named(name)
    except (FileNotFoundError, ValueError) as e:
        print(f"skip {name}: {e}", file=sys.stderr)
        return None
    (tw, th), (ew, eh) = sizes
    frames = args.frames
    variants = [v for v in (args.variants.split(",") if args.variants else
                            (QUICK_VARIANTS if args.quick else DEFAULT_VARIANTS)) if v]
    for v in variants:
        if v not in VARIANTS:
            raise SystemExit(f"unknown variant {v!r}; known: {', '.join(VARIANTS)}")
    ladder = []
    s = 64
    while s <= (n * n) // 2 and s <= args.max_samples:
        ladder.append(s)
        s *= 2
    repeats = args.repeats or (3 if args.quick else 10)
    leaf = int(round(math.log2(n)))
    cfgs = {}
    for v in variants:  # levels clamped to the leaves of small RSMs
        kw = {**IndirectConfig().__dict__, **VARIANTS[v], "rsm_size": n}
        kw["limit_level"] = min(kw["limit_level"], leaf)
        kw["start_level"] = min(kw["start_level"], kw["limit_level"])
        cfgs[v] = IndirectConfig(**kw)
    base = IndirectConfig(rsm_size=n, start_level=0, limit_level=0)  # exact and sampled: levels unused

    # --- timing at the timing size (static camera; build() is the moving light's per-frame rebuild) ----
    tl = fw.FrameLoop(scene, tw, th, device=dev, timing=False)
    tl.render_reference(scene.camera)
    scratch = wp.zeros((th, tw), dtype=wp.vec3, device=dev)
    timings = {}
    n_ref = min(1024, (n * n) // 2)
    ref_st = IndirectStage(tl.dscene, base, dev, method="sampled", samples=n_ref, seed=args.seed)
    ref_st.update(force=True)
    ref_gather, _ = _graph_or_plain(lambda: ref_st.run_full(tl.gbuffer, scratch), dev, not args.no_graphs)

    def once(fn):
        wp.synchronize_device(dev)
        t0 = time.perf_counter()
        fn()
        wp.synchronize_device(dev)
        return time.perf_counter() - t0

    def sample_equivalents(gather, reps):
        """The tree gather's cost in sampled VPLs: median over interleaved pairs of (tree gather time / time of
        the ``n_ref``-sample gather) x n_ref; interleaving cancels slow drifts of a shared machine's load."""
        ratios = []
        for _ in range(max(reps, 5)):
            a = once(gather)
            b = once(ref_gather)
            ratios.append(a / max(b, 1e-12))
        return float(np.median(ratios)) * n_ref

    def time_stage(label, cfg, method, reps, **kw):
        st = IndirectStage(tl.dscene, cfg, dev, method=method, **kw)
        st.update(force=True)
        gather, gg = _graph_or_plain(lambda: st.run_full(tl.gbuffer, scratch), dev, not args.no_graphs)
        build, _ = _graph_or_plain(st.build, dev, not args.no_graphs)
        tgd = time_ms(gather, dev, reps, min(args.warmup, reps))
        tg = tgd["median_ms"]
        tb = time_ms(build, dev, reps, min(args.warmup, reps))["median_ms"]
        timings[label] = {"ms_gather": tg, "ms_gather_p10": tgd["p10_ms"], "ms_rebuild": tb, "ms_frame": tg + tb,
                          "clusters": st.cluster_count(), "graphs": gg, "timed": True}
        if method == "lighttree":
            timings[label]["sample_equiv"] = sample_equivalents(gather, reps)

    for v in variants:
        time_stage(v, cfgs[v], "lighttree", repeats)
    for s in ladder:
        if s <= args.max_timed:
            time_stage(f"sampled {s}", base, "sampled", repeats, samples=s, seed=args.seed)
    timed = [s for s in ladder if s <= args.max_timed]
    for s in ladder:
        if s > args.max_timed:  # linear in the sample count through the two largest timed counts
            a, b = timed[-2], timed[-1]
            ta, tb_ = timings[f"sampled {a}"], timings[f"sampled {b}"]
            k = (s - b) / (b - a)
            tg = tb_["ms_gather"] + k * (tb_["ms_gather"] - ta["ms_gather"])
            timings[f"sampled {s}"] = {"ms_gather": tg, "ms_rebuild": tb_["ms_rebuild"],
                                       "ms_frame": tg + tb_["ms_rebuild"], "clusters": s, "graphs": False,
                                       "timed": False}
    del tl

    # --- quality at the eval size over the moving-light frames --------------------------------------------
    el = fw.FrameLoop(scene, ew, eh, device=dev, timing=False)
    ds = el.dscene
    li = IndirectStage(ds, base, dev, method="exact").light_index
    light0 = ds.scene.lights[li]
    ext = float(ds.extent)
    sc = el.config.shading
    methods = [("exact", base, "exact", {})] + [(v, cfgs[v], "lighttree", {}) for v in variants] + \
              [(f"sampled {s}", base, "sampled", {"samples": s, "seed": args.seed}) for s in ladder]
    stages = {lab: IndirectStage(ds, cfg, dev, method=m, **kw) for lab, cfg, m, kw in methods}
    hdr = wp.zeros((eh, ew), dtype=wp.vec3, device=dev)
    ldr = wp.zeros((eh, ew), dtype=wp.vec3, device=dev)
    ppd = 67.0 * ew / 1920.0
    futures = {lab: [] for lab in stages}
    prev = {}
    flick_num = {lab: 0.0 for lab in stages}
    flick_den = 0.0
    last = {}
    try:
        for t in range(frames):
            set_light(ds, li, arc_light(light0, ext, t, frames))
            el.render_reference(scene.camera)
            direct = wp.clone(el.radiance)
            imgs = {}
            for lab, st in stages.items():
                st.update()
                wp.copy(hdr, direct)
                st.run_full(el.gbuffer, hdr)
                fw.parallel.launch(tonemap_kernel, dim=(eh, ew), inputs=[hdr, float(sc.exposure),
                                   float(sc.white_point)], outputs=[ldr], device=dev)
                imgs[lab] = ldr.numpy().astype(np.float32)
            ex = imgs["exact"]
            if t > 0:
                de = ex - prev["exact"]
                flick_den += float(np.abs(de).sum())
                for lab in stages:
                    flick_num[lab] += float(np.abs((imgs[lab] - prev[lab]) - de).sum())
            for lab in stages:
                if lab != "exact":
                    futures[lab].append(pool.submit(_frame_metrics, ex, imgs[lab], ppd, args.have_flip))
            prev = imgs
            if t == frames - 1:
                last = {"exact": ex, "tree": imgs[variants[0]]}
    finally:
        set_light(ds, li, light0)
    rows = []
    for lab, cfg, m, kw in methods:
        if lab == "exact":
            continue
        res = [f.result() for f in futures[lab]]
        flips = [r["flip"] for r in res]
        row = {"part": "methods", "scene": name, "width": tw, "height": th, "eval_width": ew, "eval_height": eh,
               "rsm": n, "method": lab, "kind": "tree" if m == "lighttree" else "sampled",
               "flip": None if any(f is None for f in flips) else float(np.mean(flips)),
               "dssim": float(np.mean([1.0 - r["ssim"] for r in res])),
               "rel_l2": float(np.mean([r["rel_l2"] for r in res])),
               "flicker": flick_num[lab] / max(flick_den, 1e-30)}
        row.update(timings[lab])
        if m == "sampled":
            row["samples"] = kw["samples"]
        else:
            row["config"] = {k: getattr(cfg, k) for k in ("start_level", "limit_level", "cluster_radius_scale",
                                                          "refine_threshold", "refine_budget", "refine_min_ratio",
                                                          "refine_min_radius")}
        rows.append(row)

    samp = [r for r in rows if r["kind"] == "sampled"]
    ns = [r["samples"] for r in samp]
    msf = [r["ms_frame"] for r in samp]
    msg = [r["ms_gather"] for r in samp]
    comps = []
    for r in rows:
        if r["kind"] != "tree":
            continue
        c = {"part": "comparisons", "scene": name, "width": tw, "height": th, "rsm": n, "tree": r["method"],
             "tree_ms_frame": r["ms_frame"], "tree_flip": r["flip"],
             "tree_flicker": r["flicker"]}
        for key in ("flip", "flicker", "dssim"):
            if r[key] is None or any(x[key] is None for x in samp):
                c[f"eq_{key}_samples"] = c[f"eq_{key}_bound"] = c[f"speedup_eq_{key}"] = None
                continue
            n_eq, bound = crossing(ns, [x[key] for x in samp], r[key])
            ms_eq = ms_at(ns, msf, n_eq)
            c[f"eq_{key}_samples"] = n_eq
            c[f"eq_{key}_bound"] = bound
            c[f"eq_{key}_sampled_ms"] = ms_eq
            c[f"speedup_eq_{key}"] = ms_eq / max(r["ms_frame"], 1e-9)
            c[f"gather_speedup_eq_{key}"] = ms_at(ns, msg, n_eq) / max(r["ms_gather"], 1e-9)
            c[f"count_speedup_eq_{key}"] = n_eq / max(r["sample_equiv"], 1e-9)
        comps.append(c)

    # the side-by-side: sampled RSM at the default tree's ms_frame, last frame
    tree0 = next(r for r in rows if r["method"] == variants[0])
    n_time = int(round(min(n_at_ms(ns, msf, tree0["ms_frame"]), n * n)))
    set_light(ds, li, arc_light(light0, ext, frames - 1, frames))
    try:
        el.render_reference(scene.camera)
        st = IndirectStage(ds, base, dev, method="sampled", samples=n_time, seed=args.seed)
        st.update()
        wp.copy(hdr, el.radiance)
        st.run_full(el.gbuffer, hdr)
        fw.parallel.launch(tonemap_kernel, dim=(eh, ew), inputs=[hdr, float(sc.exposure), float(sc.white_point)],
                           outputs=[ldr], device=dev)
        last["sampled"] = ldr.numpy().astype(np.float32)
    finally:
        set_light(ds, li, light0)
    return {"scene": name, "rsm": n, "size": [tw, th], "eval_size": [ew, eh], "frames": frames, "ladder": ladder,
            "hit_pixels_eval": int(el.gbuffer.hit.numpy().sum()), "flip_ppd": ppd, "rows": rows,
            "comparisons": comps, "equal_time_samples": n_time}, last


def side_by_side(panels):
    """Rows per scene: exact | tree | sampled (equal time), then |difference from exact| x 8."""
    blocks = []
    for p in panels:
        ex, tr, sa = p["exact"], p["tree"], p["sampled"]
        top = np.concatenate([ex, tr, sa], axis=1)
        diff = lambda a: np.clip(8.0 * np.abs(a - ex), 0.0, 1.0)  # noqa: E731
        bot = np.concatenate([np.zeros_like(ex), diff(tr), diff(sa)], axis=1)
        blocks += [top, bot]
    return (np.clip(np.concatenate(blocks, axis=0), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def main(argv=None):
    p = base_parser(__doc__, CANONICAL)
    p.add_argument("--scenes", default="cornell,bunny-in-box,teapot-in-box")
    p.add_argument("--rsm", default=None, help="RSM edges, comma separated (CUDA: 256,512; CPU: 64,128; --quick 32)")
    p.add_argument("--size", default=None, help="timing frame WxH (CUDA 1920x1080, CPU 240x135, --quick 96x54)")
    p.add_argument("--eval-size", default=None, help="quality frame WxH (CUDA 480x270, CPU 240x135, --quick 96x54)")
    p.add_argument("--frames", type=int, default=8, help="frames of the moving light (>= 2)")
    p.add_argument("--variants", default=None, help=f"tree variants, comma separated, of: {', '.join(VARIANTS)}")
    p.add_argument("--max-samples", type=int, default=1 << 16, help="largest sampled-RSM count of the ladder")
    p.add_argument("--max-timed", type=int, default=1 << 13,
                   help="ladder counts above this are timed by linear extrapolation in the sample count")
    p.add_argument("--workers", type=int, default=None, help="metric worker processes (default: cores, <= 8)")
    p.add_argument("--seed", type=int, default=0, help="Poisson-disk pattern seed")
    p.add_argument("--no-graphs", action="store_true", help="no CUDA graph replay")
    args = p.parse_args(argv)
    if args.frames < 2:
        p.error(f"--frames must be >= 2, got {args.frames}")
    bad = [v for v in (args.variants or "").split(",") if v and v not in VARIANTS]
    if bad:
        p.error(f"--variants must be a comma list of {', '.join(VARIANTS)}, got {bad}")
    try:
        rsms = [int(x) for x in args.rsm.split(",")] if args.rsm else None
    except ValueError:
        rsms = []
    if rsms is not None and (not rsms or any(n < 4 or n & (n - 1) for n in rsms)):
        p.error(f"--rsm must be a comma list of powers of two >= 4, got {args.rsm!r}")
    import foveawarp as fw  # noqa: F401  (initializes warp quietly)
    from foveawarp._util import get_device

    dev = get_device(args.device)
    cuda = dev.is_cuda
    (size,) = parse_sizes(p, args.size, "--size") if args.size else [(96, 54) if args.quick else (1920, 1080) if cuda
                                                                        else (240, 135)]
    (esize,) = parse_sizes(p, args.eval_size, "--eval-size") if args.eval_size else [
        (96, 54) if args.quick else (480, 270) if cuda else (240, 135)]
    rsms = rsms or ([32] if args.quick else [256, 512] if cuda else [64, 128])
    have_flip = flip_available()
    args.have_flip = have_flip
    if not have_flip:
        print("FLIP unavailable (pip install flip-evaluator, or .[bench]): flip columns are null, no equal-FLIP "
              "comparison; dssim (1 - SSIM) is reported as a separate, labelled comparison", file=sys.stderr)
    workers = args.workers or max(1, min(8, (os.cpu_count() or 2)))
    results, panels = [], []
    cols = ["scene", "rsm", "method", "clusters", "sample_equiv", "flip", "flicker", "dssim", "rel_l2", "ms_gather",
            "ms_gather_p10", "ms_rebuild", "ms_frame", "timed"]
    ccols = ["scene", "rsm", "tree", "tree_ms_frame", "tree_flip", "eq_flip_samples", "eq_flip_bound",
             "speedup_eq_flip", "gather_speedup_eq_flip", "count_speedup_eq_flip", "tree_flicker", "eq_flicker_samples",
             "eq_flicker_bound", "speedup_eq_flicker", "gather_speedup_eq_flicker", "count_speedup_eq_flicker",
             "eq_dssim_samples", "speedup_eq_dssim"]

    def save(final):
        """Write the JSON / markdown / side-by-side so far (after every scene and RSM size, so that a run cut
        short by a time limit still leaves its finished parts)."""
        md = (f"Indirect light, moving spot light: quality at {esize[0]}x{esize[1]} against the exact all-VPL sum "
              f"(FLIP {'flip-evaluator' if have_flip else 'UNAVAILABLE'}), timing at {size[0]}x{size[1]} "
              f"(ms_frame = gather + rebuild).{'' if final else ' PARTIAL: the run did not finish.'}\n\n")
        for r in results:
            md += (f"### {r['scene']}, RSM {r['rsm']}^2, {r['frames']} frames, {r['hit_pixels_eval']} hit pixels at "
                   f"eval size, FLIP ppd {r['flip_ppd']:.2f}, sampled at equal time: {r['equal_time_samples']}\n\n")
            md += md_table(r["rows"], cols) + "\n"
            md += ("Equal FLIP / equal flicker / equal 1-SSIM against the sampled RSM (speedup = sampled ms_frame / "
                   "tree ms_frame; bound '>=': the tree beats every ladder count, the ratio is a lower bound):\n\n")
            md += md_table(r["comparisons"], ccols) + "\n"
        records = [x for r in results for x in r["rows"] + r["comparisons"]]
        runs = [{k: v for k, v in r.items() if k not in ("rows", "comparisons")} for r in results]
        write_results("indirect", dev, records, md, args.out, args.tag, extra={
            "quick": bool(args.quick), "flip_available": have_flip, "size": list(size), "eval_size": list(esize),
            "complete": bool(final), "runs": runs})
        if panels:
            import imageio.v3 as iio

            iio.imwrite(plot_path("indirect", dev, args.out, args.tag), side_by_side(panels))
        if final:
            print(md)

    cases = [(s.strip(), i, n) for s in args.scenes.split(",") if s.strip() for i, n in enumerate(rsms)]
    skipped = set()
    # spawned (not forked) workers: the parent holds a CUDA context; the workers only run NumPy / FLIP / SSIM
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        for name, i, n in progress(cases, "indirect"):
            if name in skipped:
                continue
            out = bench(name, n, args, dev, pool, (size, esize))
            if out is None:
                skipped.add(name)
                continue
            r, last = out
            results.append(r)
            if i == 0:
                panels.append(last)
            save(False)
    save(True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
