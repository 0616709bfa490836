"""Is tracing the sampled pixels faster reordered than unreordered, compaction included?

For each scene, size, mask (foveated or scattered random, ~10 / 30 / 50 % sampling) and shading cost (light:
direct light with shadow rays; heavy: + 8 ambient-occlusion rays), the median ms of: full-resolution shading,
"none" (every pixel launched, unsampled threads exit: the masked launch), and each of the thesis's strategies
"rows" (strategy 1, row CSR), "rows+balance" (strategy 2), "scan" and "tile" (8x8 screen tiles in Morton
order), each as compaction + tracing (the sum of the two medians, both synchronized) and each part alone.
Ratios to full and to "none"; "ideal" = rate x full.

``--overhead``: the compaction alone per strategy on a sparse foveated mask (~25 %) and a mostly-filled one
(~95 %), with its CUDA graph's replay and per-kernel GPU times (CUDA). Writes reorder-<tag>.json / .md and, for
the tracing, reorder-<tag>.png (ms / full-resolution ms against the sampling rate, per shading and mask).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import (base_parser, md_table, parse_sizes, plot_path, progress, pyplot,  # noqa: E402
                                save_grid, time_ms, write_results)
from benchmarks._kernel_timing import graph_time, kernel_times  # noqa: E402
from benchmarks._masks import bench_masks  # noqa: E402

CANONICAL = ("python benchmarks/reorder.py --device cuda:0 --out benchmarks/results --tag h200 "
             "--scenes cornell,city,bunny --sizes 1920x1080,3840x2160")

STRATS = ["rows", "rows+balance", "scan", "tile"]


def foveated_mask(w, h, rate, rng, gaze=None):
    """Dense fovea, sparse periphery: p = clip(1 - k * r, xi, 1) (r = distance to the gaze in image heights),
    with k found by bisection so that mean(p) = rate, then random thresholds."""
    gx, gy = gaze or (w * 0.55, h * 0.45)
    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot(xx + 0.5 - gx, yy + 0.5 - gy) / h
    xi = min(0.05, rate * 0.5)
    lo, hi = 0.0, 1e4
    for _ in range(60):
        k = 0.5 * (lo + hi)
        if np.clip(1 - k * r, xi, 1).mean() > rate:
            lo = k
        else:
            hi = k
    p = np.clip(1 - k * r, xi, 1)
    return (rng.random((h, w)) < p).astype(np.uint8)


def overhead(args):
    """The compaction alone per strategy on sparse and mostly-filled masks, per kernel."""
    import foveawarp as fw
    from foveawarp.stages.reorder import ReorderStage

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    sizes = [(64, 36)] if args.quick else parse_sizes(args.parser, args.sizes)
    repeats = max(args.repeats or 20, 20)
    warmup = max(args.warmup, 1)
    rng = np.random.default_rng(1)
    rows, cases = [], []
    for w, h in sizes:
        for name, m in bench_masks(w, h, rng):
            mask = wp.array(m, dtype=wp.uint8, device=dev)
            for s in STRATS:
                stage = ReorderStage(w, h, fw.ReorderConfig(strategy=s), dev)
                run = lambda: stage.run(mask)  # noqa: E731
                wall = time_ms(run, dev, repeats, warmup)
                g = graph_time(run, dev, repeats, warmup)
                k = kernel_times(run, dev, repeats, warmup)
                rec = {"scene": "synthetic mask", "width": w, "height": h, "mask": name, "rate": float(m.mean()),
                       "strategy": s,
                       "run_ms": wall["median_ms"], "run_p10_ms": wall["p10_ms"], "run_p90_ms": wall["p90_ms"],
                       "graph_ms": g["graph_ms"], "graph_error": g["error"],
                       "gpu_ms": None if k is None else k["gpu_ms"],
                       "launches": None if k is None else k["launches"],
                       "kernels": None if k is None else k["kernels"]}
                cases.append(rec)
                rows.append({"size": f"{w}x{h}", "mask": name, "rate": rec["rate"], "strategy": s,
                             "run ms": rec["run_ms"], "graph ms": "n/a" if g["graph_ms"] is None else g["graph_ms"],
                             "GPU kernels ms": "n/a" if k is None else k["gpu_ms"],
                             "launches": "n/a" if k is None else k["launches"],
                             "per kernel (ms, launches)": "n/a (CPU)" if k is None else "; ".join(
                                 f"{n} {v['median_ms']:.4f} x{v['launches']:g}" for n, v in k["kernels"].items())})
                if g["error"] and dev.is_cuda:
                    print(f"graph capture failed: {g['error']}", flush=True)
    table = (f"## ReorderStage.run (compaction only); device {dev.alias}; medians of {repeats}\n\n"
             + md_table(rows, ["size", "mask", "rate", "strategy", "run ms", "graph ms", "GPU kernels ms",
                               "launches", "per kernel (ms, launches)"]))
    print(table)
    write_results("reorder", dev, cases, table, args.out, args.tag, extra={
        "mode": "overhead", "repeats": repeats,
        "note": ("run ms: synchronized wall time of one run; graph ms: replay of its captured CUDA graph; GPU kernels "
                 "ms: sum of the kernels' CUDA activity times")})


def main(argv=None):
    p = base_parser(__doc__, CANONICAL)
    p.add_argument("--scenes", default="cornell,city,bunny")
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--overhead", action="store_true", help="the compaction's cost per kernel, no tracing")
    args = p.parse_args(argv)
    args.parser = p
    if args.overhead:
        overhead(args)
        return
    import foveawarp as fw
    from foveawarp.kernels.shade import shade_rows_kernel
    from foveawarp.stages.reorder import ReorderStage

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    sizes = [(64, 36)] if args.quick else parse_sizes(args.parser, args.sizes)
    repeats = args.repeats or (2 if args.quick else 20)
    rates = [0.1, 0.3, 0.5]
    rng = np.random.default_rng(1)
    rows = []
    names = [n for n in args.scenes.split(",") if n]
    for name in progress(names[:1] if args.quick else names, "reorder"):
        try:
            scene = fw.load_scene(name)
        except (FileNotFoundError, ValueError) as e:
            print(f"skip {name}: {e}", file=sys.stderr)
            continue
        for w, h in sizes:
            for shading, ao in (("light", 0), ("heavy", 8)):
                cfg = fw.Config(shading=fw.ShadingConfig(ao_samples=ao))
                loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
                cam = scene.camera
                loop.render_reference(cam)  # G-buffer for this view; compile
                full = time_ms(lambda: loop.shade_full(cam), dev, repeats, args.warmup)["median_ms"]
                for kind in ("foveated", "random"):
                    for rate in rates:
                        m_np = foveated_mask(w, h, rate, rng) if kind == "foveated" else (
                            rng.random((h, w)) < rate).astype(np.uint8)
                        mask = wp.array(m_np, dtype=wp.uint8, device=dev)
                        real_rate = float(m_np.mean())
                        row = {"scene": scene.name, "width": w, "height": h, "resolution": f"{w}x{h}",
                               "shading": shading, "mask": kind, "rate": real_rate, "full_ms": full,
                               "ideal_ms": real_rate * full}
                        row["none_ms"] = time_ms(lambda: loop.shade_masked(cam, mask), dev, repeats,
                                                 args.warmup)["median_ms"]
                        for s in STRATS:
                            stage = ReorderStage(w, h, fw.ReorderConfig(strategy=s), dev)
                            stage.run(mask)
                            comp = time_ms(lambda: stage.run(mask), dev, repeats, args.warmup)["median_ms"]
                            if s in ("rows", "rows+balance"):
                                sp = loop.upload_shade_params(cam)

                                def trace():
                                    loop.shade.rows(loop.gbuffer, stage.coords, stage.counts, loop.radiance,
                                                    loop.radiance_stoch)
                            else:
                                def trace():
                                    loop.shade_list(cam, stage.work, stage.count)
                            tr = time_ms(trace, dev, repeats, args.warmup)["median_ms"]
                            tot = comp + tr  # sum of the two medians (timed separately, synchronized)
                            row[f"{s}_compact_ms"] = comp
                            row[f"{s}_trace_ms"] = tr
                            row[f"{s}_ms"] = tot
                        best = min(STRATS, key=lambda s: row[f"{s}_ms"])
                        row["best"] = best
                        row["best_ms"] = row[f"{best}_ms"]
                        row["speedup_vs_none"] = row["none_ms"] / max(row["best_ms"], 1e-9)
                        row["best_vs_ideal"] = row[f"{best}_trace_ms"] / max(row["ideal_ms"], 1e-9)
                        row["best_vs_full"] = row["best_ms"] / max(full, 1e-9)
                        rows.append(row)
    cols = ["scene", "resolution", "shading", "mask", "rate", "full_ms", "ideal_ms", "none_ms", "rows_ms",
            "rows+balance_ms", "scan_ms", "tile_ms", "best", "speedup_vs_none", "best_vs_ideal"]
    table = md_table(rows, cols)
    write_results("reorder", dev, rows, table, args.out, args.tag, extra={
        "mode": "tracing", "repeats": repeats,
        "note": ("X_ms = compaction + tracing (median of repeats, synchronized); X_trace_ms tracing alone; ideal_ms = "
                 "rate x full_ms; best_vs_ideal = best strategy's tracing time / ideal")})
    plot(rows, plot_path("reorder", dev, args.out, args.tag), dev)
    print(table)


def plot(rows, path, dev):
    """ms / full-resolution ms against the sampling rate: unreordered ("none"), each strategy (compaction
    counted) and the ideal rate x full, one panel per shading and mask, every scene and size."""
    plt = pyplot()
    if plt is None or not rows:
        return
    panels = sorted({(r["shading"], r["mask"]) for r in rows})
    fig, axes = plt.subplots(1, len(panels), figsize=(3.6 * len(panels), 3.2), squeeze=False)
    for ax, (shading, mask) in zip(axes.flat, panels):
        rs = sorted((r for r in rows if (r["shading"], r["mask"]) == (shading, mask)), key=lambda r: r["rate"])
        ax.plot([0, 1], [0, 1], "k:", lw=1, label="ideal")
        for k, s in enumerate(["none"] + STRATS):
            ax.scatter([r["rate"] for r in rs], [r[f"{s}_ms"] / r["full_ms"] for r in rs], s=10, color=f"C{k}",
                       label=s if s != "none" else "none (masked launch)")
        ax.set_title(f"{shading} shading, {mask} mask", fontsize=8)
        ax.set_xlabel("sampling rate", fontsize=7)
        ax.set_ylabel("ms / full-resolution ms", fontsize=7)
        ax.tick_params(labelsize=6)
    axes.flat[0].legend(fontsize=5)
    save_grid(plt, fig, axes, axes.size, f"reordered vs unreordered tracing, compaction counted "
                                         f"({wp.get_device(dev).alias})", path)


if __name__ == "__main__":
    main()
