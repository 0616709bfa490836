"""Time versus error: foveated frames against full-resolution render_reference over a camera/gaze path.

For each scene and each foveation setting: median frame ms on the device (synchronized, no per-stage timing)
and PSNR / SSIM (whole frame and foveal / mid / far regions) against render_reference. Writes JSON, CSV, a
markdown table, a time-vs-PSNR plot with the Pareto front, and a recommended setting. Also the 4K timing on
`city`: default shading (shadow rays + light-quad-tree indirect) and heavy shading (8 AO rays) against the
reference.

python benchmarks/quality.py --device cuda:0
"""

from __future__ import annotations

import csv
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import RESULTS, base_parser, md_table, time_ms, write_results  # noqa: E402

SETTINGS = {
    "default": {},
    "mar0.022": {"foveation": {"mar_slope": 0.022}},
    "mar0.034": {"foveation": {"mar_slope": 0.034}},
    "block2": {"foveation": {"block": 2}},
    "block6": {"foveation": {"block": 6}},
    "block8": {"foveation": {"block": 8}},
    "xi0.15": {"foveation": {"min_probability": 0.15}},
    "xi0.3": {"foveation": {"min_probability": 0.3}},
    "no-saliency": {"saliency": {"use_albedo": False, "use_normal": False, "use_velocity": False,
                                 "use_dof": False}},
    "strategy-none": {"reorder": {"strategy": "none"}},
    "strategy-scan": {"reorder": {"strategy": "scan"}},
    "no-sibson": {"reconstruction": {"sibson": False}},
    # FoveationConfig.falloff_deg: eq. 2 normalized by the MAR at this eccentricity (rates near or below 30%)
    "falloff30": {"foveation": {"falloff_deg": 30.0}},
    "falloff20": {"foveation": {"falloff_deg": 20.0}},
    "falloff12": {"foveation": {"falloff_deg": 12.0}},
    "falloff20-sal0.5": {"foveation": {"falloff_deg": 20.0}, "saliency": {"albedo_scale": 0.5, "normal_scale": 0.5}},
}


def _metrics(args):
    img, ref, gaze, fov = args
    from foveawarp.metrics import region_metrics

    return region_metrics(img, ref, gaze, fov)


def gaze_path(i, n, w, h):
    t = i / max(n, 1)
    return (w * (0.5 + 0.3 * math.sin(2 * math.pi * t)), h * (0.5 + 0.2 * math.sin(4 * math.pi * t + 0.5)))


def pareto(points):
    """Indices of points (ms, psnr) not dominated (less ms and more psnr)."""
    idx = []
    for i, (t, q) in enumerate(points):
        if not any((t2 <= t and q2 >= q and (t2 < t or q2 > q)) for j, (t2, q2) in enumerate(points) if j != i):
            idx.append(i)
    return idx


def run_scene(fw, scene, w, h, dev, frames, metric_every, settings, pool, base_cfg):
    rows = []
    fov = scene.camera.fov_y_deg
    ref_loop = fw.FrameLoop(scene, w, h, config=base_cfg, device=dev, timing=False, policy="foveated")
    refs = {}
    for i in range(0, frames, metric_every):
        t = i / 30.0
        refs[i] = ref_loop.render_reference(scene.camera_at(t), time=t).numpy().copy()
    ref_ms = time_ms(lambda: ref_loop.render_reference(scene.camera_at(0.0), time=0.0), dev, 5, 1)["median_ms"]
    for name, over in settings.items():
        cfg = base_cfg.with_(**over) if over else base_cfg
        loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
        jobs, rates, hits, ms = [], [], [], []
        for i in range(frames):
            t = i / 30.0
            g = gaze_path(i, frames, w, h)
            wp.synchronize_device(dev)
            t0 = time.perf_counter()
            f = loop.render(scene.camera_at(t), gaze_px=g, time=t)
            wp.synchronize_device(dev)
            if i >= 2:  # the first frames compile / have no history
                ms.append((time.perf_counter() - t0) * 1e3)
            rates.append(f.stats["sampling_rate"])
            hits.append(f.stats["cache_hit_rate"])
            if i in refs:
                jobs.append((f.numpy().copy(), refs[i], g, fov))
        mets = list(pool.map(_metrics, jobs)) if pool else [_metrics(j) for j in jobs]
        row = {"scene": scene.name, "setting": name, "resolution": f"{w}x{h}", "frame_ms": float(np.median(ms)),
               "reference_ms": ref_ms, "sampling_rate": float(np.mean(rates)), "cache_hit_rate": float(np.mean(hits))}
        for k in mets[0]:
            vals = [m[k] for m in mets if np.isfinite(m[k])]
            row[k] = float(np.mean(vals)) if vals else float("nan")
        rows.append(row)
        print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    return rows


def timing_4k(fw, dev, repeats, quick, scene_name=None, settings=None, size=None):
    """Frame ms at 4K on `city` (default shading, heavy shading, and each named extra setting): the foveated
    frame along a slowly moving camera (CUDA graph replay and eager launches), the static-view refresh phase,
    and ``render_reference``; plus a synchronized per-stage breakdown (timing mode)."""
    w, h = size or ((160, 90) if quick else (3840, 2160))
    scene = fw.load_scene(scene_name or ("cornell" if quick else "city"))
    cases = [("default (shadows + light-tree indirect)", {"shading": {"indirect": "lighttree"}}),
             ("heavy (shadows + 8 AO rays)", {"shading": {"ao_samples": 8}})]
    for name in settings or ():
        cases.append((f"heavy, {name}", {**SETTINGS[name], "shading": {"ao_samples": 8}}))
    out = []
    for label, over in cases:
        cfg = fw.Config().with_(**over)
        g = (w * 0.5, h * 0.5)
        state = {"i": 0}

        def moving(loop):
            i = state["i"]
            state["i"] += 1
            return loop.render(scene.camera_at(i / 240.0), gaze_px=g)

        row = {"scene": scene.name, "resolution": f"{w}x{h}", "shading": label, "overrides": over}
        for tag, graph in (("foveated_ms", None), ("foveated_eager_ms", False)):
            loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, graph=graph, policy="foveated")
            state["i"] = 0
            row[tag] = time_ms(lambda: moving(loop), dev, repeats, 4)["median_ms"]
            st = moving(loop).stats
            row["sampling_rate" if graph is None else "sampling_rate_eager"] = st["sampling_rate"]
            row["graph_state" if graph is None else "graph_state_eager"] = st["graph"]
        # a static view: after convergence only the refresh budget is traced
        loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
        for _ in range(20):
            loop.render(scene.camera, gaze_px=g)
        row["static_refresh_ms"] = time_ms(lambda: loop.render(scene.camera, gaze_px=g), dev, repeats, 2)["median_ms"]
        st = loop.render(scene.camera, gaze_px=g).stats
        row["static_refresh_rate"] = st["sampling_rate"]
        row["static_refresh_skipped"] = "trace" in st["skipped"]
        ref = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
        row["reference_ms"] = time_ms(lambda: ref.render_reference(scene.camera), dev, max(3, repeats // 2), 1)[
            "median_ms"]
        row["speedup"] = row["reference_ms"] / row["foveated_ms"]
        timed = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=True, policy="foveated")
        for i in range(3):
            st = timed.render(scene.camera_at(i / 240.0), gaze_px=g).stats
        row["stages_ms"] = {k: v for k, v in st.items() if k.startswith("ms_")}
        out.append(row)
        print(row, flush=True)
    return out


def main():
    p = base_parser(__doc__)
    p.add_argument("--scenes", default="cornell,city,eyechart,earth,bunny,spot,teapot")
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--height", type=int, default=None)
    p.add_argument("--frames", type=int, default=None)
    p.add_argument("--settings", default=None, help="comma list of setting names (default: all)")
    p.add_argument("--skip-4k", action="store_true")
    p.add_argument("--t4k-settings", default="falloff20,falloff12",
                   help="extra settings (names in SETTINGS) timed at 4K with heavy shading")
    p.add_argument("--only-4k", action="store_true", help="skip the sweep, run only the 4K timing")
    args = p.parse_args()
    import foveawarp as fw

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    w = args.width or (64 if args.quick else 1920)
    h = args.height or (36 if args.quick else 1080)
    frames = args.frames or (4 if args.quick else 30)
    metric_every = 2 if args.quick else 6
    names = args.settings.split(",") if args.settings else (["default", "block8"] if args.quick else list(SETTINGS))
    settings = {k: SETTINGS[k] for k in names}
    # the sweep measures the foveated pipeline itself: the static-view refresh budget is off (scenes whose camera
    # stands still would otherwise trace less after 16 frames); timing_4k measures the refresh phase separately
    base_cfg = fw.Config().with_(temporal={"refresh_fraction": 1.0})
    if args.only_4k:
        t4k = timing_4k(fw, dev, 5 if args.quick else 20, args.quick,
                        settings=[x for x in args.t4k_settings.split(",") if x],
                        size=(args.width, args.height) if args.width and args.height else None,
                        scene_name=None if "," in args.scenes else args.scenes)
        table = md_table(t4k, ["scene", "resolution", "shading", "sampling_rate", "foveated_ms", "foveated_eager_ms",
                               "static_refresh_ms", "static_refresh_rate", "reference_ms", "speedup"])
        print(table)
        write_results("quality-4k" if not args.width else f"quality-{args.width}x{args.height}", dev,
                      {"timing_4k": t4k}, table, args.out)
        return
    rows = []
    pool = None if args.quick else ProcessPoolExecutor(max_workers=12)
    scenes = args.scenes.split(",") if not args.quick else ["cornell", "earth"]
    for name in scenes:
        try:
            scene = fw.load_scene(name)
        except ValueError as e:
            print(f"skip {name}: {e}")
            continue
        rows += run_scene(fw, scene, w, h, dev, frames, metric_every, settings, pool, base_cfg)
    # aggregate per setting over scenes; Pareto front on (mean ms, mean PSNR)
    agg = []
    for s in settings:
        rs = [r for r in rows if r["setting"] == s]
        if not rs:
            continue
        agg.append({"setting": s, "frame_ms": float(np.mean([r["frame_ms"] for r in rs])),
                    "psnr": float(np.mean([r["psnr"] for r in rs])), "ssim": float(np.mean([r["ssim"] for r in rs])),
                    "psnr_fovea": float(np.nanmean([r["psnr_fovea"] for r in rs])),
                    "sampling_rate": float(np.mean([r["sampling_rate"] for r in rs]))})
    front = pareto([(a["frame_ms"], a["psnr"]) for a in agg])
    for i, a in enumerate(agg):
        a["pareto"] = i in front
    best_q = max(agg[i]["psnr"] for i in front)
    # recommended: the fastest setting on the front within 1 dB of the front's best mean PSNR
    rec = min((agg[i] for i in front if agg[i]["psnr"] >= best_q - 1.0), key=lambda a: a["frame_ms"])
    t4k = [] if args.skip_4k else timing_4k(fw, dev, 5 if args.quick else 20, args.quick,
                                            settings=[x for x in args.t4k_settings.split(",") if x])
    out_dir = Path(args.out) if args.out else RESULTS
    out_dir.mkdir(parents=True, exist_ok=True)
    tag = "cuda" if dev.is_cuda else "cpu"
    with open(out_dir / f"quality-{tag}.csv", "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=list(rows[0].keys()))
        wr.writeheader()
        wr.writerows(rows)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7, 4.5))
        for a in agg:
            ax.scatter(a["frame_ms"], a["psnr"], c="tab:red" if a["pareto"] else "tab:gray", zorder=3)
            ax.annotate(a["setting"], (a["frame_ms"], a["psnr"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        fr = sorted((agg[i] for i in front), key=lambda a: a["frame_ms"])
        ax.plot([a["frame_ms"] for a in fr], [a["psnr"] for a in fr], "r--", label="Pareto front")
        ax.set_xlabel(f"frame ms ({dev.alias}, {w}x{h}, mean over scenes)")
        ax.set_ylabel("PSNR dB vs full-resolution reference (mean over scenes)")
        ax.set_title(f"foveawarp time vs error (recommended: {rec['setting']})")
        ax.legend()
        fig.tight_layout()
        fig.savefig(out_dir / f"quality-{tag}.png", dpi=120)
    except ImportError:
        print("(matplotlib missing: no plot; pip install -e .[plots])")
    cols = ["scene", "setting", "frame_ms", "reference_ms", "sampling_rate", "cache_hit_rate", "psnr", "ssim",
            "psnr_fovea", "psnr_mid", "psnr_far"]
    table = md_table(rows, cols) + "\n\nPer setting (mean over scenes):\n\n" + md_table(
        agg, ["setting", "frame_ms", "sampling_rate", "psnr", "ssim", "psnr_fovea", "pareto"])
    table += f"\n\nRecommended setting: **{rec['setting']}**\n"
    if t4k:
        table += "\n4K timing:\n\n" + md_table(t4k, ["scene", "resolution", "shading", "sampling_rate", "foveated_ms",
                                                    "foveated_eager_ms", "static_refresh_ms", "static_refresh_rate",
                                                    "reference_ms", "speedup"])
    print(table)
    write_results("quality", dev, {"rows": rows, "per_setting": agg, "recommended": rec, "timing_4k": t4k,
                                   "frames": frames, "metric_every": metric_every, "resolution": f"{w}x{h}",
                                   "base_overrides": {"temporal": {"refresh_fraction": 1.0}}},
                  table, args.out)
    if pool:
        pool.shutdown()


if __name__ == "__main__":
    main()
