"""Reordered versus unreordered tracing of the sampled pixels (thesis A3).

For each scene, resolution, mask (foveated or scattered random, ~10 / 30 / 50 % sampling) and shading cost
(light: direct light with shadow rays; heavy: + 8 ambient-occlusion rays), the median ms of:
full-resolution shading, "none" (every pixel launched, unsampled threads exit), and each strategy
(compaction + tracing, and each part alone). Ratios to full and to "none"; "ideal" = rate x full.

python benchmarks/reorder.py --device cuda:0
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, time_ms, write_results  # noqa: E402

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


def main():
    p = base_parser(__doc__)
    p.add_argument("--scenes", default="cornell,city,bunny")
    p.add_argument("--sizes", default=None, help="e.g. 1920x1080,3840x2160")
    args = p.parse_args()
    import foveawarp as fw
    from foveawarp.kernels.shade import shade_rows_kernel
    from foveawarp.stages.reorder import ReorderStage

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    if args.sizes:
        sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    else:
        sizes = [(160, 90)] if args.quick else [(1920, 1080), (3840, 2160)]
    repeats = args.repeats or (2 if args.quick else 20)
    rates = [0.1, 0.3, 0.5]
    rng = np.random.default_rng(1)
    rows = []
    for name in args.scenes.split(","):
        if args.quick and name == "city":
            continue
        try:
            scene = fw.load_scene(name)
        except ValueError as e:
            print(f"skip {name}: {e}")
            continue
        for w, h in sizes:
            for shading, ao in (("light", 0), ("heavy", 8)):
                cfg = fw.Config(shading=fw.ShadingConfig(ao_samples=ao))
                loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False)
                cam = scene.camera
                loop.render_reference(cam)  # G-buffer for this view; compile
                full = time_ms(lambda: loop.shade_full(cam), dev, repeats, args.warmup)["median_ms"]
                for kind in ("foveated", "random"):
                    for rate in rates:
                        m_np = foveated_mask(w, h, rate, rng) if kind == "foveated" else (
                            rng.random((h, w)) < rate).astype(np.uint8)
                        mask = wp.array(m_np, dtype=wp.uint8, device=dev)
                        real_rate = float(m_np.mean())
                        row = {"scene": scene.name, "resolution": f"{w}x{h}", "shading": shading, "mask": kind,
                               "rate": real_rate, "full_ms": full, "ideal_ms": real_rate * full}
                        row["none_ms"] = time_ms(lambda: loop.shade_masked(cam, mask), dev, repeats,
                                                 args.warmup)["median_ms"]
                        for s in STRATS:
                            stage = ReorderStage(w, h, fw.ReorderConfig(strategy=s), dev)
                            stage.run(mask)
                            comp = time_ms(lambda: stage.run(mask), dev, repeats, args.warmup)["median_ms"]
                            if s in ("rows", "rows+balance"):
                                sp = loop.upload_shade_params(cam)

                                def trace():
                                    wp.launch(shade_rows_kernel, dim=(h, w),
                                              inputs=[sp, stage.coords, stage.counts, *loop._shade_inputs()],
                                              outputs=[loop.radiance, loop.radiance_stoch], device=dev)
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
                        print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    cols = ["scene", "resolution", "shading", "mask", "rate", "full_ms", "ideal_ms", "none_ms", "rows_ms",
            "rows+balance_ms", "scan_ms", "tile_ms", "best", "speedup_vs_none", "best_vs_ideal"]
    table = md_table(rows, cols)
    print(table)
    write_results("reorder", dev, {"rows": rows, "repeats": repeats, "note": (
        "X_ms = compaction + tracing (median of repeats, synchronized); X_trace_ms tracing alone; ideal_ms = "
        "rate x full_ms; best_vs_ideal = best strategy's tracing time / ideal")}, table, args.out)


if __name__ == "__main__":
    main()
