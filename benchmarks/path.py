"""Foveated path tracing against full-resolution path tracing, at equal time and at equal quality.

Per scene x size (``ShadingConfig.integrator = "path"``, ``--max-depth``), along the scene's camera path
(1/30 s a frame) with a moving gaze (the Lissajous figure of frame.py), every loop renders the same
``--warm`` + ``--frames`` frames; the first ``--warm`` are untimed (compilation, CUDA-graph capture, a filled
history), the others are each synchronized and timed (median ms) and scored:

* the full-resolution frame (``FrameLoop(policy="full")``: every pixel traced, no reuse) at each ``--full-spp``;
* the foveated frame (``policy="foveated"``: the sampled pixels traced, the temporal resolve accumulating the
  paths with history clipping, Sibson reconstruction; with demodulation, the periphery filter, its history or its
  variance guide per ``--variants`` item, by default the path integrator's defaults) at each ``--fov-spp`` under
  each ``--budgets`` item (``ShadingConfig.path_budget``: "pixel", spp paths at every traced pixel; "frame", a
  full-resolution frame's spp x W x H paths shared by sampling probability, at most ``--max-spp`` per pixel).

Target: the converged image of each frame's camera, traced by the loops' own path stage (the same pixel filter
and material). In the fovea (eccentricity <= 5 degrees of the gaze) ``--fovea-spp`` paths per pixel over the
fovea's bounding box; over the whole frame ``--converged-spp`` (sizes up to ``--whole-max-pixels``: whole-frame
PSNR and FovVideoVDP). All metrics compare display images (the loops' tone map applied to the target):

* fovea PSNR: per frame (mean and min over the path) and of the fovea's squared error pooled over all frames
  (``fovea_psnr``: the figure the curves and the read-offs use; a per-frame mean would weigh frames whose fovea
  falls on the empty background, near 100 dB, as much as the others), and fovea FLIP (``flip-evaluator``, its default 67 pixels per degree: the mean of FLIP's error map
  over the fovea, computed on the fovea's bounding box plus a margin);
* whole-frame PSNR and FovVideoVDP (``pyfvvdp``, foveated mode with each frame's gaze as the fixation point, the
  ``standard_fhd`` display with the camera's field of view: ``foveawarp.metrics.fovvdp``).

Read off per scene and size:

* equal quality: for each foveated item, the full-resolution time at the same fovea PSNR (linear in log time
  between the two full-resolution items around it) over the foveated time; above the best full-resolution item
  only a lower bound (the best item's time), flagged. ``equal_quality_speedup`` is that of the default
  foveated item (the first ``--fov-spp`` of the first budget);
* equal time: the full-resolution frame at the first ``--full-spp`` (``ref_ms``) against the slowest foveated item
  that is not slower than it (``fov_ms``; with none, the fastest foveated item, flagged); the read-offs are the
  first ``--variants`` item's, ``equal_time_by_variant`` gives each variant's.

Writes path-<tag>.json / .md and path-<tag>.png (fovea PSNR against frame ms, both curves, per scene and size);
``--images DIR``: the equal-time pair's last frame per scene and size, the gaze and the 5-degree fovea marked.
The canonical results come from the command below at 1920x1080 and the same at 3840x2160 (tools/canonical.sh
part4); where a device call allows less time, a few scenes per run with ``--keep benchmarks/results/path-h200.json``
build the same JSON.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import (base_parser, git_commit, kept_records, md_table, parse_sizes, plot_path,  # noqa: E402
                                progress, pyplot, save_grid, write_results)
from benchmarks.frame import gaze_path  # noqa: E402

CANONICAL = ("python benchmarks/path.py --device cuda:0 --out benchmarks/results --tag h200 "
             "--scenes cornell,bunny,city --sizes 1920x1080 --images benchmarks/out/path-images")
FOVEA_DEG = 5.0
# --variants: (ReconstructionConfig.demodulate, ShadingConfig overrides) of the foveated frames
_FILTER = {"path_filter": "atrous"}
VARIANTS = {"plain": (False, {"path_filter": "none"}), "demod": (True, {"path_filter": "none"}),
            "filter": (False, _FILTER), "demod+filter": (True, _FILTER),
            "demod+filter+history": (True, {**_FILTER, "path_history": 0.75}),
            "demod+filter+variance": (True, {**_FILTER, "path_filter_guide": "variance"}),
            "demod+filter5+variance": (True, {**_FILTER, "path_filter_guide": "variance",
                                              "path_filter_iterations": 5})}
FLIP_MARGIN = 8  # pixels of context around the fovea's box for FLIP's spatial filters


def load(fw, name: str):
    """The scene ``name``; cornell with its area light (the path integrator's test of emitters)."""
    return fw.load_scene(name, area_light=True) if name == "cornell" else fw.load_scene(name)


def fovea_box(ecc: np.ndarray, margin: int):
    """(y0, y1, x0, x1): the bounding box of the pixels within FOVEA_DEG of the gaze plus ``margin``, on screen;
    None when the fovea is off screen."""
    ys, xs = np.nonzero(ecc <= FOVEA_DEG)
    if ys.size == 0:
        return None
    h, w = ecc.shape
    return (max(int(ys.min()) - margin, 0), min(int(ys.max()) + 1 + margin, h),
            max(int(xs.min()) - margin, 0), min(int(xs.max()) + 1 + margin, w))


class Target:
    """Converged display images of the frames (the fovea's box, and the whole frame where asked), traced by a
    path stage of the loops' scene and shading, on the device."""

    def __init__(self, fw, scene, w, h, dev, shading, fovea_spp: int, whole_spp: int):
        from foveawarp.scene import DeviceScene
        from foveawarp.stages.path import PathStage

        self.w, self.h, self.dev = w, h, dev
        self.shading = fw.Config().with_(shading={**shading, "radiance_clamp": None}).shading
        self.stage = PathStage(DeviceScene(scene, device=dev), self.shading, w, h, dev)
        self.fovea_spp, self.whole_spp = int(fovea_spp), int(whole_spp)
        self.one = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        self.disp = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        self.stream = 1 << 20  # frame indices of the target's passes: apart from the loops' streams

    def _converged(self, camera, spp: int, work=None) -> np.ndarray:
        acc = np.zeros((self.h, self.w, 3), np.float64)
        done = 0
        while done < spp:
            n = min(256, spp - done)
            self.stage.run(camera, self.stream, self.one, work, spp=n)
            self.stream += 1
            acc += self.one.numpy() * n
            done += n
        return (acc / spp).astype(np.float32)

    def display(self, hdr: np.ndarray) -> np.ndarray:
        from foveawarp.kernels.tonemap import tonemap_kernel

        src = wp.array(hdr, dtype=wp.vec3, device=self.dev)
        wp.launch(tonemap_kernel, dim=(self.h, self.w), inputs=[src, float(self.shading.exposure),
                                                                 float(self.shading.white_point)],
                  outputs=[self.disp, 0], device=self.dev)
        return self.disp.numpy()

    def frame(self, camera, box, whole: bool):
        """(fovea box's converged display image or None, whole frame's or None)."""
        fov = None
        if box is not None:
            y0, y1, x0, x1 = box
            yy, xx = np.mgrid[y0:y1, x0:x1]
            work = wp.array((yy * self.w + xx).ravel().astype(np.int32), dtype=wp.int32, device=self.dev)
            fov = self.display(self._converged(camera, self.fovea_spp, work))[y0:y1, x0:x1].copy()
        full = self.display(self._converged(camera, self.whole_spp)) if whole else None
        if full is not None and fov is not None and self.fovea_spp <= self.whole_spp:
            fov = full[box[0]:box[1], box[2]:box[3]].copy()
        return fov, full


def flip_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    import flip_evaluator

    err, _, _ = flip_evaluator.evaluate(b.astype(np.float32), a.astype(np.float32), "LDR")
    return np.asarray(err, np.float64)


def mse(a, b, mask=None) -> float:
    d = (np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2
    return float((d[mask] if mask is not None else d).mean())


def psnr_of(m: float) -> float:
    """PSNR of a mean squared error of [0, 1] images (100 dB at an error below 1e-10)."""
    return 100.0 if m <= 1e-10 else float(10.0 * math.log10(1.0 / m))


def psnr(a, b, mask=None) -> float:
    return psnr_of(mse(a, b, mask))


def run_item(fw, scene, w, h, dev, cfg, policy, frames, warm, targets, fov_deg, flip_on, video, keep_last):
    """One loop along the path: median frame ms of the timed frames, per-frame fovea PSNR / FLIP, whole-frame
    PSNR (and the frames for FovVideoVDP), the paths per pixel by band (foveated)."""
    loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy=policy)
    n = warm + frames
    ms, fp, fm, ff, wpsnr, vid, bands, rates = [], [], [], [], [], [], [], []
    last = None
    for i in range(n):
        t = i / 30.0
        g = gaze_path(i, n, w, h)
        cam = scene.camera_at(t)
        wp.synchronize_device(dev)
        t0 = time.perf_counter()
        f = loop.render(cam, gaze_px=g, time=t)
        wp.synchronize_device(dev)
        dt = (time.perf_counter() - t0) * 1e3
        if i < warm:
            continue
        ms.append(dt)
        img = f.image.numpy()
        if not np.isfinite(img).all():
            raise RuntimeError(f"non-finite pixels in frame {i} of {policy} {cfg.shading.spp} spp")
        tg = targets[i - warm]
        if tg["box"] is not None:
            y0, y1, x0, x1 = tg["box"]
            crop = img[y0:y1, x0:x1]
            fm.append(mse(crop, tg["fovea"], tg["disc"]))
            fp.append(psnr_of(fm[-1]))
            if flip_on:
                ff.append(float(flip_map(crop, tg["fovea"])[tg["disc"]].mean()))
        if tg["whole"] is not None:
            wpsnr.append(psnr(img, tg["whole"]))
            if video:
                vid.append(img.astype(np.float16))
        if policy == "foveated":
            rates.append(float(f.stats["sampling_rate"]))
            bands.append({k: v["paths_per_pixel"] for k, v in f.stats["paths_by_band"].items()})
        if keep_last and i == n - 1:
            last = img
    out = {"ms": float(np.median(ms)), "ms_series": ms, "fovea_psnr": fp, "fovea_flip": ff, "psnr": wpsnr,
           "fovea_psnr_pooled": psnr_of(float(np.mean(fm))) if fm else float("nan")}
    if rates:
        out["sampling_rate_mean"] = float(np.mean(rates))
        out["paths_per_pixel_by_band"] = {k: float(np.mean([b[k] for b in bands])) for k in bands[0]}
    if video and vid and len(vid) == frames:
        from foveawarp.metrics import fovvdp

        gz = np.array([gaze_path(i, n, w, h) for i in range(warm, n)])
        ref = np.stack([targets[k]["whole"] for k in range(frames)])
        out["fvvdp_jod"] = float(fovvdp(np.stack(vid).astype(np.float32), ref, gz, fov_deg))
    return out, last


def _mean(v):
    return float(np.mean(np.minimum(v, 100.0))) if len(v) else float("nan")


def equal_quality(full_pts, q):
    """(full-resolution ms at fovea PSNR ``q``, lower bound?) from the (ms, psnr) points of the full-resolution
    curve: linear in log ms between the neighbours; below the cheapest point its time (the foveated item is at
    least that much faster); above the best point the best point's time, flagged as a lower bound."""
    pts = sorted(full_pts, key=lambda p: p[1])
    if q <= pts[0][1]:
        return pts[0][0], q < pts[0][1]
    if q > pts[-1][1]:
        return pts[-1][0], True
    (t0, q0), (t1, q1) = next((a, b) for a, b in zip(pts, pts[1:]) if a[1] <= q <= b[1])
    s = 0.0 if q1 == q0 else (q - q0) / (q1 - q0)
    return float(math.exp(math.log(t0) + s * (math.log(t1) - math.log(t0)))), False


def save_pair(folder: Path, scene: str, w: int, h: int, fov_img, ref_img, gaze, fov_deg, labels):
    """PNG of the two frames side by side, the gaze marked by a cross and the fovea's 5-degree circle."""
    import imageio.v3 as iio

    from foveawarp.metrics import eccentricity_np

    ecc = eccentricity_np(w, h, gaze, fov_deg)
    ring = np.abs(ecc - FOVEA_DEG) < max(0.04, 0.9 * fov_deg / h)
    gx, gy = int(gaze[0]), int(gaze[1])
    s = max(2, h // 100)
    panels = []
    for img in (fov_img, ref_img):
        a = np.clip(np.asarray(img, np.float32), 0.0, 1.0).copy()
        a[ring] = (1.0, 0.85, 0.1)
        a[max(gy - 4 * s, 0):gy + 4 * s, max(gx - s // 2, 0):gx + s // 2 + 1] = (1.0, 0.85, 0.1)
        a[max(gy - s // 2, 0):gy + s // 2 + 1, max(gx - 4 * s, 0):gx + 4 * s] = (1.0, 0.85, 0.1)
        panels.append(a)
    gap = np.ones((h, max(4, w // 200), 3), np.float32)
    out = np.concatenate([panels[0], gap, panels[1]], axis=1)
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / f"path-{scene}-{w}x{h}.png"
    iio.imwrite(p, (out * 255 + 0.5).astype(np.uint8))
    (folder / f"path-{scene}-{w}x{h}.txt").write_text(" | ".join(labels) + "\n")


def main(argv=None):
    p = base_parser(__doc__, CANONICAL)
    p.add_argument("--scenes", default="cornell,bunny,city")
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--max-depth", type=int, default=5)
    p.add_argument("--full-spp", default="1,2,4,8,16", help="comma list of the full-resolution frame's spp")
    p.add_argument("--fov-spp", default="1,2,4,8", help="comma list of the foveated frame's spp")
    p.add_argument("--budgets", default="pixel,frame", help="comma list of ShadingConfig.path_budget items")
    p.add_argument("--max-spp", type=int, default=64, help="ShadingConfig.max_spp of the 'frame' budget")
    p.add_argument("--variants", default="demod+filter",
                   help="comma list of the foveated frames' reconstruction: plain (ReconstructionConfig.demodulate "
                        "off, ShadingConfig.path_filter 'none'), demod (demodulated, no filter), filter (the filter "
                        "alone), demod+filter (both: the path integrator's defaults), demod+filter+history (both and "
                        "ShadingConfig.path_history 0.75), demod+filter+variance (both, the filter's variance "
                        "guide: ShadingConfig.path_filter_guide), demod+filter5+variance (that with 5 iterations); "
                        "the first is the read-offs' (the full-resolution frames have none of them)")
    p.add_argument("--summarize", default=None, metavar="FILE.json",
                   help="render nothing: write FILE's markdown tables and plot again next to it from its records")
    p.add_argument("--frames", type=int, default=16, help="timed and scored frames per item")
    p.add_argument("--warm", type=int, default=6, help="untimed frames before them")
    p.add_argument("--fovea-spp", type=int, default=1024, help="paths per pixel of the fovea's converged target")
    p.add_argument("--converged-spp", type=int, default=128,
                   help="paths per pixel of the whole frame's converged target (0: fovea metrics only)")
    p.add_argument("--whole-max-pixels", type=int, default=1920 * 1080,
                   help="whole-frame target, PSNR and FovVideoVDP for sizes up to this many pixels")
    p.add_argument("--keep", default=None, metavar="FILE.json",
                   help="a path JSON whose records this run does not repeat (scene, size) stay in the output, "
                        "each with its own commit")
    p.add_argument("--images", default=None, metavar="DIR", help="write the equal-time pair's last frame here")
    args = p.parse_args(argv)
    if args.summarize:
        summarize(args.summarize)
        return
    import foveawarp as fw
    from foveawarp.metrics import eccentricity_np, flip_available, fovvdp_available

    sizes = parse_sizes(p, args.sizes)

    def ints(opt, text, lo, hi):
        try:
            v = [int(s) for s in text.split(",") if s]
            if not v or min(v) < lo or max(v) > hi:
                raise ValueError
        except ValueError:
            p.error(f"{opt} must be a comma list of integers in [{lo}, {hi}], got {text!r}")
        return v

    full_spp = ints("--full-spp", args.full_spp, 1, 4096)
    fov_spp = ints("--fov-spp", args.fov_spp, 1, 4096)
    budgets = [b for b in args.budgets.split(",") if b]
    if not budgets or any(b not in ("pixel", "frame") for b in budgets):
        p.error(f"--budgets must be a comma list of pixel, frame; got {args.budgets!r}")
    if args.frames < 2 or args.warm < 1:
        p.error(f"--frames must be >= 2 and --warm >= 1, got {args.frames} and {args.warm}")
    if args.quick:
        sizes, full_spp, fov_spp = [(64, 36)], full_spp[:2], fov_spp[:1]
        args.frames, args.warm, args.fovea_spp, args.converged_spp = 3, 2, 32, 16
    kept = kept_records(p, args.keep, "path", lambda r: (r["scene"], int(r["width"]), int(r["height"])))
    dev = wp.get_device(args.device)
    flip_on, fvvdp_on = flip_available(), fovvdp_available()
    variants = [v for v in args.variants.split(",") if v]
    if not variants or any(v not in VARIANTS for v in variants) or len(set(variants)) < len(variants):
        p.error(f"--variants must be a comma list of distinct {', '.join(VARIANTS)}; got {args.variants!r}")
    records = []
    names = [s for s in args.scenes.split(",") if s]
    for name in names:
        scene = load(fw, name)
        fov_deg = scene.camera.fov_y_deg
        for (w, h) in sizes:
            base = {"integrator": "path", "max_depth": args.max_depth, "rr_depth": 5, "max_spp": args.max_spp}
            whole = w * h <= args.whole_max_pixels and args.converged_spp > 0
            t0 = time.perf_counter()
            tgt = Target(fw, scene, w, h, dev, base, args.fovea_spp, args.converged_spp if whole else 0)
            n = args.warm + args.frames
            targets = []
            for i in progress(range(args.warm, n), f"{name} {w}x{h} target"):
                g = gaze_path(i, n, w, h)
                ecc = eccentricity_np(w, h, g, fov_deg)
                box = fovea_box(ecc, FLIP_MARGIN)
                fv, full = tgt.frame(scene.camera_at(i / 30.0), box, whole)
                disc = None if box is None else ecc[box[0]:box[1], box[2]:box[3]] <= FOVEA_DEG
                targets.append({"box": box, "fovea": fv, "whole": full, "disc": disc})
            target_s = time.perf_counter() - t0
            items = [("full", "pixel", s, "-") for s in full_spp] + [
                ("foveated", b, s, v) for v in variants for b in budgets for s in fov_spp]
            res = {}
            lasts = {}
            for policy, budget, spp, variant in progress(items, f"{name} {w}x{h} items"):
                demod, over = VARIANTS.get(variant, (False, {"path_filter": "none"}))
                cfg = fw.Config().with_(shading={**base, "spp": spp, "path_budget": budget, **over},
                                        reconstruction={"demodulate": demod})
                out, last = run_item(fw, scene, w, h, dev, cfg, policy, args.frames, args.warm, targets, fov_deg,
                                     flip_on, whole and fvvdp_on, bool(args.images))
                res[(policy, budget, spp, variant)] = out
                lasts[(policy, budget, spp, variant)] = last
            rec = {"scene": name, "width": w, "height": h, "integrator": "path", "max_depth": args.max_depth,
                   "variants": variants, "frames": args.frames, "warm": args.warm, "fovea_deg": FOVEA_DEG,
                   "fovea_spp": args.fovea_spp,
                   "converged_spp": args.converged_spp if whole else 0, "target_s": round(target_s, 1),
                   "commit": git_commit(), "items": []}
            for (policy, budget, spp, variant), o in res.items():
                it = {"policy": policy, "path_budget": budget, "spp": spp, "variant": variant, "ms": o["ms"],
                      "fovea_psnr": o["fovea_psnr_pooled"], "fovea_psnr_mean": _mean(o["fovea_psnr"]),
                      "fovea_psnr_min": float(np.min(o["fovea_psnr"])) if o["fovea_psnr"] else None,
                      "fovea_flip_mean": float(np.mean(o["fovea_flip"])) if o["fovea_flip"] else None,
                      "fovea_flip_max": float(np.max(o["fovea_flip"])) if o["fovea_flip"] else None,
                      "psnr_mean": _mean(o["psnr"]) if o["psnr"] else None,
                      "psnr_min": float(np.min(o["psnr"])) if o["psnr"] else None,
                      "fvvdp_jod": o.get("fvvdp_jod"),
                      "series": {"ms": o["ms_series"], "fovea_psnr": o["fovea_psnr"], "fovea_flip": o["fovea_flip"],
                                 "psnr": o["psnr"]}}
                for k in ("sampling_rate_mean", "paths_per_pixel_by_band"):
                    if k in o:
                        it[k] = o[k]
                rec["items"].append(it)
            full_pts = [(it["ms"], it["fovea_psnr"]) for it in rec["items"] if it["policy"] == "full"]
            for it in rec["items"]:
                if it["policy"] == "foveated":
                    t_eq, bound = equal_quality(full_pts, it["fovea_psnr"])
                    it["equal_quality_full_ms"], it["equal_quality_speedup"] = t_eq, t_eq / it["ms"]
                    it["equal_quality_lower_bound"] = bound
            ref = rec["items"][0]
            by_variant = {}
            for v in variants:
                fovs = [it for it in rec["items"] if it["policy"] == "foveated" and it["variant"] == v]
                within = [it for it in fovs if it["ms"] <= ref["ms"]]
                e = max(within, key=lambda it: it["ms"]) if within else min(fovs, key=lambda it: it["ms"])
                by_variant[v] = {"item": f"{e['path_budget']} {e['spp']} spp", "within": bool(within),
                                 "ms": e["ms"], "fovea_psnr": e["fovea_psnr"], "fovea_flip": e["fovea_flip_mean"],
                                 "fvvdp_jod": e["fvvdp_jod"], "psnr": e["psnr_mean"]}
            # the read-offs: the first variant's
            fovs = [it for it in rec["items"] if it["policy"] == "foveated" and it["variant"] == variants[0]]
            rec["equal_quality_speedup"] = fovs[0]["equal_quality_speedup"]
            rec["equal_quality_lower_bound"] = fovs[0]["equal_quality_lower_bound"]
            rec["equal_quality_item"] = f"{fovs[0]['path_budget']} {fovs[0]['spp']} spp"
            within = [it for it in fovs if it["ms"] <= ref["ms"]]
            eq = max(within, key=lambda it: it["ms"]) if within else min(fovs, key=lambda it: it["ms"])
            rec["equal_time_item"] = f"{eq['path_budget']} {eq['spp']} spp"
            rec["equal_time_within"] = bool(within)
            rec["equal_time_by_variant"] = by_variant
            rec.update(ref_ms=ref["ms"], ref_spp=ref["spp"], fov_ms=eq["ms"],
                       fovea_psnr_fov=eq["fovea_psnr"], fovea_psnr_ref=ref["fovea_psnr"],
                       fovea_flip_fov=eq["fovea_flip_mean"], fovea_flip_ref=ref["fovea_flip_mean"],
                       fvvdp_jod_fov=eq["fvvdp_jod"], fvvdp_jod_ref=ref["fvvdp_jod"],
                       psnr_fov=eq["psnr_mean"], psnr_ref=ref["psnr_mean"])
            records.append(rec)
            print(f"{name} {w}x{h}: full {ref['spp']} spp {ref['ms']:.2f} ms fovea {ref['fovea_psnr']:.2f} dB; "
                  f"foveated {rec['equal_time_item']} {eq['ms']:.2f} ms fovea {eq['fovea_psnr']:.2f} dB; "
                  f"equal quality {rec['equal_quality_speedup']:.2f}x", file=sys.stderr, flush=True)
            if args.images:
                key_eq = ("foveated", eq["path_budget"], eq["spp"], variants[0])
                key_ref = ("full", "pixel", ref["spp"], "-")
                save_pair(Path(args.images), name, w, h, lasts[key_eq], lasts[key_ref],
                          gaze_path(n - 1, n, w, h), fov_deg,
                          [f"foveated, {rec['equal_time_item']}, {eq['ms']:.1f} ms",
                           f"full resolution, {ref['spp']} spp, {ref['ms']:.1f} ms"])
    done = {(r["scene"], r["width"], r["height"]) for r in records}
    records = [r for r in kept if (r["scene"], r["width"], r["height"]) not in done] + records
    write_results("path", dev, records, tables(records), args.out, args.tag,
                  extra={"flip": flip_on, "fovvdp": fvvdp_on})
    plot(records, plot_path("path", dev, args.out, args.tag), wp.get_device(dev).alias)


def tables(records) -> str:
    """The markdown of a path JSON's records: the read-offs per scene and size, and, where a record measured more
    than one ``--variants`` item, each variant's equal-time item."""
    rows = [{"scene": r["scene"], "size": f"{r['width']}x{r['height']}",
             "ref (spp, ms)": f"{r['ref_spp']}, {r['ref_ms']:.2f}",
             "fov (item, ms)": f"{r['equal_time_item']}, {r['fov_ms']:.2f}",
             "fovea PSNR fov/ref": f"{r['fovea_psnr_fov']:.2f} / {r['fovea_psnr_ref']:.2f}",
             "fovea FLIP fov/ref": _pair(r["fovea_flip_fov"], r["fovea_flip_ref"], "{:.3f}"),
             "JOD fov/ref": _pair(r["fvvdp_jod_fov"], r["fvvdp_jod_ref"], "{:.2f}"),
             "equal-quality speed-up": f"{'>=' if r['equal_quality_lower_bound'] else ''}"
                                       f"{r['equal_quality_speedup']:.2f}x ({r['equal_quality_item']})"}
            for r in records]
    out = md_table(rows)
    vrows = []
    for r in records:
        by = r.get("equal_time_by_variant") or {}
        if len(by) < 2:
            continue
        for v, e in by.items():
            vrows.append({"scene": r["scene"], "size": f"{r['width']}x{r['height']}",
                          "full res (spp, ms)": f"{r['ref_spp']}, {r['ref_ms']:.2f}", "variant": v,
                          "fov (item, ms)": f"{e['item']}, {e['ms']:.2f}" + ("" if e["within"] else " (slower)"),
                          "fovea PSNR fov/ref": f"{e['fovea_psnr']:.2f} / {r['fovea_psnr_ref']:.2f}",
                          "fovea FLIP fov/ref": _pair(e["fovea_flip"], r["fovea_flip_ref"], "{:.3f}"),
                          "PSNR fov/ref": _pair(e["psnr"], r["psnr_ref"], "{:.2f}"),
                          "JOD fov/ref": _pair(e["fvvdp_jod"], r["fvvdp_jod_ref"], "{:.2f}")})
    if vrows:
        out += "\n\n## Equal time by variant of the foveated reconstruction\n\n" + md_table(vrows)
    return out


def summarize(json_path) -> None:
    """``--summarize``: the .md and .png of a path JSON written again from its records (its device and commit)."""
    import json

    p = Path(json_path)
    d = json.loads(p.read_text())
    p.with_suffix(".md").write_text(f"# path on {d['device']} ({d['device_alias']}), commit {d['commit'][:12]}\n\n"
                                    f"{tables(d['records'])}\n")
    plot(d["records"], p.with_suffix(".png"), d["device_alias"])


def _pair(a, b, fmt):
    return f"{'-' if a is None else fmt.format(a)} / {'-' if b is None else fmt.format(b)}"


def plot(records, path, device_alias: str):
    """Fovea PSNR (of the fovea's squared error over all frames) against frame ms: the full-resolution curve and one
    foveated curve per budget, per scene and size (``device_alias`` in the title: a JSON's ``device_alias``
    re-plots its records)."""
    plt = pyplot()
    if plt is None or not records:
        return
    from matplotlib import ticker

    cols = min(len(records), 3)
    nrows = -(-len(records) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.4 * nrows), squeeze=False)
    for ax, r in zip(axes.flat, records):
        groups = {}
        for it in r["items"]:
            label = "full resolution" if it["policy"] == "full" else f"foveated, {it['path_budget']} budget"
            if it["policy"] != "full" and len(r.get("variants", [])) > 1:
                label += f", {it['variant']}"
            groups.setdefault(label, []).append(it)
        for k, (label, its) in enumerate(groups.items()):
            its = sorted(its, key=lambda it: it["ms"])
            ax.plot([it["ms"] for it in its], [it["fovea_psnr"] for it in its], marker="o", color=f"C{k}",
                    label=label)
            for it in its:
                ax.annotate(str(it["spp"]), (it["ms"], it["fovea_psnr"]), fontsize=6, xytext=(3, 3),
                            textcoords="offset points")
        ax.set_xscale("log")
        # labels at 1, 2, 5 x 10^k in plain numbers: the default minor labels of an axis shorter than a decade
        # overlap
        ax.xaxis.set_major_locator(ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.set_title(f"{r['scene']} {r['width']}x{r['height']}, max_depth {r['max_depth']}", fontsize=8)
        ax.set_xlabel("frame ms (labels: spp)", fontsize=7)
        ax.set_ylabel("fovea PSNR dB vs converged (all frames)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=6)
    save_grid(plt, fig, axes, len(records), f"path tracing: fovea error against frame time ({device_alias})", path)


if __name__ == "__main__":
    main()
