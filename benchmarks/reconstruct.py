"""Reconstruction benchmark.

``--overhead`` (issue 14): the per-frame cost of the stage as FrameLoop runs it (1+JFA, bounded start, bounded
Sibson, block 4) on (a) a sparse mask (foveated sampling only, ~25 % seeds) and (b) a mostly-filled mask
(~95 % seeds, holes clustered like disocclusions), at 1920x1080 and 3840x2160: median synchronized wall time
of ``run`` (>= 20 repeats after warm-up), median replay time of its captured CUDA graph, and per-kernel GPU
times from Warp's CUDA activity timing (``wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | ...)``), no host
sync between the kernels. Writes reconstruct-overhead-<cpu|cuda>.json/.md.

    python benchmarks/reconstruct.py --overhead --device cuda:0
    python benchmarks/reconstruct.py --overhead --device cpu --sizes 320x180

Without ``--overhead``: the sweep of JFA variants (time, wrong-distance rate vs SciPy's EDT), bounded vs exact
Sibson (time, max abs difference), and the stage's per-frame cost over seed densities, for uniform random
masks and masks with the block-4 guarantee.

    python benchmarks/reconstruct.py --device cuda:0
    python benchmarks/reconstruct.py --device cpu --quick --out /tmp/bench

Targets (H100): 1+JFA wrong-distance pixels <= 0.01%; JFA + bounded Sibson <= 1.5 ms at 4K;
bounded Sibson >= 20x faster than exact at 5% seeds. Issue 14: the stage <= 0.35 ms at 4K, <= 0.1 ms at 1080p.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import warp as wp

sys.path.append(str(Path(__file__).resolve().parent.parent))

from benchmarks._common import base_parser, md_table, time_ms, write_results  # noqa: E402
from benchmarks._kernel_timing import graph_time, kernel_times  # noqa: E402
from benchmarks._masks import bench_masks  # noqa: E402

if "--package-root" in sys.argv:  # time another checkout's foveawarp (e.g. the one before a change)
    sys.path.insert(0, str(Path(sys.argv[sys.argv.index("--package-root") + 1]).resolve()))
from foveawarp._util import get_device  # noqa: E402
from foveawarp.config import JFA_VARIANTS, ReconstructionConfig  # noqa: E402
from foveawarp.stages.reconstruct import (  # noqa: E402
    ReconstructStage,
    jfa_start_step_for_block,
    sibson_window_for_block,
)

BLOCK = 4


def uniform_mask(h, w, density, rng):
    return (rng.random((h, w)) < density).astype(np.uint8)


def block_mask(h, w, k, density, rng):
    """One random seed per aligned k x k tile (partial edge tiles too), plus uniform extras up to ``density``."""
    extra = max(0.0, (density - 1.0 / (k * k)) / (1.0 - 1.0 / (k * k)))
    m = rng.random((h, w)) < extra
    ty = np.arange(0, h, k)
    tx = np.arange(0, w, k)
    oy = (rng.random((ty.size, tx.size)) * np.minimum(k, h - ty)[:, None]).astype(int)
    ox = (rng.random((ty.size, tx.size)) * np.minimum(k, w - tx)[None, :]).astype(int)
    m[ty[:, None] + oy, tx[None, :] + ox] = True
    return m.astype(np.uint8)


def exact_d2(mask):
    from scipy import ndimage

    h, w = mask.shape
    _, (iy, ix) = ndimage.distance_transform_edt(mask == 0, return_indices=True)
    yy, xx = np.mgrid[0:h, 0:w]
    return (iy - yy).astype(np.int64) ** 2 + (ix - xx).astype(np.int64) ** 2


def nearest_d2(nearest):
    h, w = nearest.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    return (nearest[..., 1].astype(np.int64) - yy) ** 2 + (nearest[..., 0].astype(np.int64) - xx) ** 2


def overhead(args, dev):
    """Issue 14: the stage's per-frame cost on sparse and mostly-filled masks, per kernel."""

    if args.sizes:
        sizes = [tuple(int(v) for v in t.split("x")) for t in args.sizes.split(",")]
    else:
        sizes = [(160, 90)] if args.quick else [(1920, 1080), (3840, 2160)]
    repeats = max(args.repeats or 20, 1 if args.quick else 20)
    warmup = max(args.warmup, 1)
    rng = np.random.default_rng(0)
    rows, cases = [], []
    for w, h in sizes:
        stage = ReconstructStage(w, h, ReconstructionConfig(), BLOCK, dev)  # the FrameLoop default
        color_in = wp.array(rng.random((h, w, 3)).astype(np.float32), dtype=wp.vec3, device=dev)
        out = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        for name, m in bench_masks(w, h, rng, BLOCK):
            mask = wp.array(m, dtype=wp.uint8, device=dev)
            run = lambda: stage.run(color_in, mask, out)  # noqa: E731
            wall = time_ms(run, dev, repeats, warmup)
            g = graph_time(run, dev, repeats, warmup)
            k = kernel_times(run, dev, repeats, warmup)
            rec = {"width": w, "height": h, "mask": name, "seeds_pct": 100.0 * float(m.mean()),
                   "jfa_steps": list(stage.steps), "run_ms": wall["median_ms"], "run_p10_ms": wall["p10_ms"],
                   "run_p90_ms": wall["p90_ms"], "graph_ms": g["graph_ms"], "graph_error": g["error"],
                   "gpu_ms": None if k is None else k["gpu_ms"], "launches": None if k is None else k["launches"],
                   "kernels": None if k is None else k["kernels"]}
            cases.append(rec)
            rows.append({"size": f"{w}x{h}", "mask": name, "seeds %": rec["seeds_pct"], "run ms": rec["run_ms"],
                         "graph ms": "n/a" if g["graph_ms"] is None else g["graph_ms"],
                         "GPU kernels ms": "n/a" if k is None else k["gpu_ms"],
                         "launches": "n/a" if k is None else k["launches"],
                         "per kernel (ms, launches)": "n/a (CPU)" if k is None else "; ".join(
                             f"{n} {v['median_ms']:.4f} x{v['launches']:g}" for n, v in k["kernels"].items())})
            print(rows[-1], flush=True)
            if g["error"] and dev.is_cuda:
                print(f"graph capture failed: {g['error']}", flush=True)
    table = (f"## ReconstructStage.run, default config (1+JFA, bounded start, bounded Sibson, block {BLOCK}); "
             f"device {dev.alias}; medians of {repeats}\n\n"
             + md_table(rows, ["size", "mask", "seeds %", "run ms", "graph ms", "GPU kernels ms", "launches",
                               "per kernel (ms, launches)"]))
    print(table)
    path = write_results("reconstruct-overhead", dev, {"block": BLOCK, "repeats": repeats, "cases": cases,
                                                       "note": ("run ms: synchronized wall time of one run; "
                                                                "graph ms: replay of its captured CUDA graph; "
                                                                "GPU kernels ms: sum of the kernels' CUDA "
                                                                "activity times")}, table, out=args.out)
    print(f"wrote {path}")


def main(argv=None):
    p = base_parser(__doc__.splitlines()[0])
    p.add_argument("--no-edt-4k", action="store_true", help="skip the SciPy EDT (wrong-pixel rates) at 4K")
    p.add_argument("--no-exact", action="store_true", help="skip the exact (scatter) Sibson")
    p.add_argument("--overhead", action="store_true", help="issue 14: per-kernel cost on sparse / filled masks")
    p.add_argument("--sizes", default=None, help="--overhead sizes, e.g. 1920x1080,3840x2160")
    p.add_argument("--package-root", default=None, help="import foveawarp from this checkout instead")
    args = p.parse_args(argv)
    dev = get_device(args.device)
    if args.overhead:
        overhead(args, dev)
        return
    sizes = [(160, 90)] if args.quick else [(1920, 1080), (3840, 2160)]
    densities = [0.01, 0.05, 0.10, 0.30]
    repeats = args.repeats or (3 if args.quick else 20)
    warmup = 1 if args.quick else args.warmup
    rng = np.random.default_rng(0)
    J = sibson_window_for_block(BLOCK)
    s0 = jfa_start_step_for_block(BLOCK)

    jfa_rows, sib_rows, results = [], [], []
    for w, h in sizes:
        do_edt = not (args.no_edt_4k and w * h > 4_000_000)
        color_in = wp.array(rng.random((h, w, 3)).astype(np.float32), dtype=wp.vec3, device=dev)
        out_b = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        out_e = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        full = {v: ReconstructStage(w, h, ReconstructionConfig(jfa_variant=v, bounded_jfa_start=False), BLOCK, dev)
                for v in JFA_VARIANTS}
        bounded_jfa = ReconstructStage(w, h, ReconstructionConfig(jfa_variant="1+jfa"), BLOCK, dev)
        bounded = ReconstructStage(w, h, ReconstructionConfig(), BLOCK, dev)  # the FrameLoop default
        exact = ReconstructStage(w, h, ReconstructionConfig(), BLOCK, dev, exact_sibson=True)
        for kind in ("uniform", "block4"):
            for dens in densities:
                mask_np = uniform_mask(h, w, dens, rng) if kind == "uniform" else block_mask(h, w, BLOCK, dens, rng)
                if kind == "block4" and dens < 1.0 / BLOCK**2 and dens != densities[0]:
                    continue  # same masks as the first density below 1/16
                mask = wp.array(mask_np, dtype=wp.uint8, device=dev)
                seeds_pct = 100.0 * float(mask_np.mean())
                t0 = time.perf_counter()
                d_ref = exact_d2(mask_np) if do_edt else None
                edt_s = time.perf_counter() - t0
                rec = {"width": w, "height": h, "mask": kind, "density": dens, "seeds_pct": seeds_pct,
                       "edt_cpu_s": edt_s if do_edt else None, "jfa": {}}
                starts = [("full", None)] + ([("bounded", s0)] if kind == "block4" else [])
                for v in JFA_VARIANTS:
                    for start_name, _ in starts:
                        st = full[v] if start_name == "full" else None
                        if st is None:
                            if v != "1+jfa":
                                continue
                            st = bounded_jfa
                        t = time_ms(lambda st=st: st.run_jfa(mask), dev, repeats, warmup)
                        st.run_jfa(mask)
                        wrong = None
                        if d_ref is not None:
                            d = nearest_d2(st.nearest.numpy())
                            if np.any(d < d_ref):
                                raise AssertionError(f"{v}: JFA nearer than exact")
                            wrong = 100.0 * float(np.count_nonzero(d != d_ref)) / d.size
                        rec["jfa"][f"{v}/{start_name}"] = {"ms": t["median_ms"], "wrong_pct": wrong,
                                                           "passes": len(st.steps)}
                        jfa_rows.append({"size": f"{w}x{h}", "mask": kind, "seeds %": seeds_pct, "variant": v,
                                         "start": start_name if start_name == "full" else f"{s0}",
                                         "passes": len(st.steps), "ms": t["median_ms"],
                                         "wrong %": "n/a" if wrong is None else f"{wrong:.5f}"})
                # Sibson on one shared nearest map (the default stage's: 1+JFA, bounded start on block masks)
                stage = bounded if kind == "block4" else full["1+jfa"]
                stage.run_jfa(mask)
                near = stage.nearest
                t_b = time_ms(lambda: bounded.run_interpolate(color_in, out_b, near), dev, repeats, warmup)
                bounded.run_interpolate(color_in, out_b, near)
                rmax = float(bounded.max_radius.numpy()[0])
                t_e = diff = None
                if not args.no_exact:
                    t_e = time_ms(lambda: exact.run_interpolate(color_in, out_e, near), dev,
                                  max(3, repeats // 4), min(warmup, 1))
                    exact.run_interpolate(color_in, out_e, near)
                    diff = float(np.abs(out_b.numpy() - out_e.numpy()).max())
                # the per-frame stage cost (JFA + bounded Sibson) as FrameLoop runs it
                frame_stage = bounded if kind == "block4" else full["1+jfa"]
                t_run = time_ms(lambda: frame_stage.run(color_in, mask, out_b), dev, repeats, warmup)
                rec.update(max_radius_px=rmax, sibson_window=J, sibson_bounded_ms=t_b["median_ms"],
                           sibson_exact_ms=None if t_e is None else t_e["median_ms"], max_abs_diff=diff,
                           stage_run_ms=t_run["median_ms"], stage_jfa_start=frame_stage.start_step)
                results.append(rec)
                sib_rows.append({
                    "size": f"{w}x{h}", "mask": kind, "seeds %": seeds_pct, "max r_q px": rmax, "J": J,
                    "bounded ms": t_b["median_ms"],
                    "exact ms": "skipped" if t_e is None else t_e["median_ms"],
                    "speed-up": "n/a" if t_e is None else f"{t_e['median_ms'] / max(t_b['median_ms'], 1e-9):.1f}x",
                    "max abs diff": "n/a" if diff is None else f"{diff:.2e}",
                    "stage run ms (JFA+Sibson)": t_run["median_ms"],
                })
                ex_s = "-" if t_e is None else f"{t_e['median_ms']:.3f}"
                print(f"{w}x{h} {kind:7s} {seeds_pct:6.2f}% seeds: bounded {t_b['median_ms']:.3f} ms, "
                      f"exact {ex_s} ms, run {t_run['median_ms']:.3f} ms", flush=True)
        if not do_edt:
            print(f"note: SciPy EDT skipped at {w}x{h} (--no-edt-4k): no wrong-pixel rates there")

    jfa_md = md_table(jfa_rows, ["size", "mask", "seeds %", "variant", "start", "passes", "ms", "wrong %"])
    sib_md = md_table(sib_rows, ["size", "mask", "seeds %", "max r_q px", "J", "bounded ms", "exact ms",
                                 "speed-up", "max abs diff", "stage run ms (JFA+Sibson)"])
    table = (f"## JFA (device {dev.alias}; wrong % = pixels whose JFA distance exceeds SciPy's EDT)\n\n{jfa_md}\n"
             f"## Sibson: bounded gather (J={J}, block {BLOCK}) vs exact scatter, on the same 1+JFA map\n\n{sib_md}")
    print(table)
    path = write_results("reconstruct", dev, {"block": BLOCK, "sibson_window": J, "jfa_bounded_start": s0,
                                              "repeats": repeats, "quick": bool(args.quick), "cases": results},
                         table, out=args.out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
