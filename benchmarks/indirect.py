"""Indirect light (ALGORITHMS.md C): the light quad-tree against the exact all-VPL sum and Poisson-sampled RSM.

For ``cornell`` and ``bunny-in-box`` (skipped when the bunny mesh is absent) at 1920x1080 with a 256^2 RSM
(``--quick``: 96x54, RSM 64), the receivers are the G-buffer hit pixels of the scene's default camera.
Per method:
  * ``ms_gather``: median ms of ``IndirectStage.run_full`` (the gather at every hit pixel);
  * ``ms_static``: an indirect frame with the light and geometry static (``update()`` skips the build);
  * ``ms_dynamic``: an indirect frame that rebuilds the RSM, pyramid and cut (or sample list) every frame;
  * ``ms_frame_static`` / ``ms_frame_dynamic``: the same plus the reference frame (G-buffer, direct shading
    with shadow rays, tone map) of ``FrameLoop.render_reference``;
  * ``rel_err``: relative L2 error of the indirect radiance against the exact sum over the receivers. The
    exact sum (N^2 VPLs per receiver) is computed on every ``--exact-stride``-th hit pixel (default: every
    pixel with ``--quick`` or on CUDA, every 16th on the CPU at full size); the errors of all methods are
    measured on that same subset.
Methods: the light tree with limit levels 6, 5, 4 (level L has 2^L x 2^L nodes) and threshold sets
(depth 0.05, normal 0.9) [the paper's] and (0.25, 0.6) [looser], start level 3; the paper's per-receiver
traversal for the first set; RSM sampling with 256, 1024, 2040 samples (+ 4096, 8192 at full size, so that
the equal-error comparison interpolates rather than extrapolates).
Comparisons: for each tree row, the sampled RSM at EQUAL ERROR (samples from log error vs log samples,
piecewise linear; ms piecewise linear in samples, proportional to samples outside the measured range) and
at EQUAL TIME (samples at the tree's ms_static, then the error there); "extrapolated" marks targets
outside the measured sample counts. Paper claims to check on the GPU: tree >= 7x faster than sampling at equal error; static frames
>= 1.5x faster than rebuilt ones.

On CUDA the frames are replayed as CUDA graphs (``--no-graphs`` to launch kernels one by one).

python benchmarks/indirect.py --device cuda:0
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, time_ms, write_results  # noqa: E402

THRESHOLDS = ((0.05, 0.9), (0.25, 0.6))
LIMITS = (6, 5, 4)


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


def _lerp(x, y, t):
    """Piecewise-linear y(t) through the points (x, y) sorted by x, extended linearly by the end segments.
    Returns (value, extrapolated)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    o = np.argsort(x)
    x, y = x[o], y[o]
    if x[0] <= t <= x[-1]:
        return float(np.interp(t, x, y)), False
    i = 0 if t < x[0] else len(x) - 2
    slope = (y[i + 1] - y[i]) / ((x[i + 1] - x[i]) or 1e-30)
    return float(y[i] + (t - x[i]) * slope), True


def _ms_at(samples, ms, n):
    """ms of the sampled RSM at n samples: piecewise linear between measurements; outside, proportional to n
    from the nearest measurement (the gather is linear in the sample count)."""
    s, m = np.asarray(samples, float), np.asarray(ms, float)
    if s.min() <= n <= s.max():
        return float(np.interp(n, s, m))
    j = int(np.argmin(s)) if n < s.min() else int(np.argmax(s))
    return float(m[j] * n / s[j])


def equal_error(samples, errs, ms, target_err):
    """(samples, sampled ms, extrapolated) where the sampled RSM's error equals ``target_err``
    (log error vs log samples, piecewise linear)."""
    ls, ext = _lerp(np.log(np.maximum(errs, 1e-30)), np.log(samples), math.log(max(target_err, 1e-30)))
    n = math.exp(ls)
    return n, _ms_at(samples, ms, n), ext


def equal_time(samples, errs, ms, target_ms):
    """(samples, sampled error, extrapolated) where the sampled RSM's time equals ``target_ms``."""
    s, m = np.asarray(samples, float), np.asarray(ms, float)
    if m.min() <= target_ms <= m.max():
        n, ext = _lerp(m, s, target_ms)
    else:
        j = int(np.argmin(m)) if target_ms < m.min() else int(np.argmax(m))
        n, ext = s[j] * target_ms / max(m[j], 1e-30), True
    le, ext2 = _lerp(np.log(samples), np.log(np.maximum(errs, 1e-30)), math.log(max(n, 1.0)))
    return n, math.exp(le), ext or ext2


def bench_scene(name, args, dev):
    import foveawarp as fw
    from foveawarp.config import IndirectConfig
    from foveawarp.stages.indirect import IndirectStage

    try:
        scene = fw.load_scene(name)
    except ValueError as e:
        print(f"skip {name}: {e}")
        return None
    w, h = (96, 54) if args.quick else (1920, 1080)
    n = args.rsm or (64 if args.quick else 256)
    repeats = args.repeats or (3 if args.quick else 20)
    warmup = args.warmup
    loop = fw.FrameLoop(scene, w, h, device=dev, timing=False)
    loop.render_reference(scene.camera)
    g = loop.gbuffer
    hit = g.hit.numpy().reshape(-1).astype(bool)
    idx = np.flatnonzero(hit)
    stride = args.exact_stride or (1 if (args.quick or dev.is_cuda) else 16)
    sub = idx[::stride]
    P = g.position.numpy().reshape(-1, 3)[sub]
    N = g.normal.numpy().reshape(-1, 3)[sub]
    A = g.albedo.numpy().reshape(-1, 3)[sub]
    rp, rn, ra = (wp.array(a, dtype=wp.vec3, device=dev) for a in (P, N, A))
    out = wp.zeros(len(sub), dtype=wp.vec3, device=dev)
    scratch = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    print(f"{name}: {w}x{h}, {idx.size} hit pixels, RSM {n}^2, exact on {len(sub)} receivers (stride {stride})")

    def base_frame():
        loop.render_reference(scene.camera)

    t_base = time_ms(base_frame, dev, repeats, warmup)["median_ms"]

    def measure(label, cfg, method, **kw):
        st = IndirectStage(loop.dscene, cfg, dev, method=method, **kw)
        st.update()
        st.run_points(rp, rn, ra, out)
        res = out.numpy().astype(np.float64)
        k = st.cluster_count()
        gather, gg = _graph_or_plain(lambda: st.run_full(g, scratch), dev, not args.no_graphs)
        dyn, _ = _graph_or_plain(lambda: (st.build(), st.run_full(g, scratch)), dev, not args.no_graphs)
        build, _ = _graph_or_plain(st.build, dev, not args.no_graphs)
        reps = repeats if method != "exact" else max(1, min(repeats, 3))
        wu = warmup if method != "exact" else 1

        def static_frame():
            st.update()
            gather()

        t_g = time_ms(gather, dev, reps, wu)["median_ms"]
        t_s = time_ms(static_frame, dev, reps, wu)["median_ms"]
        t_d = time_ms(dyn, dev, reps, wu)["median_ms"]
        t_b = time_ms(build, dev, reps, wu)["median_ms"]
        t_fs = time_ms(lambda: (base_frame(), static_frame()), dev, reps, wu)["median_ms"]
        t_fd = time_ms(lambda: (base_frame(), dyn()), dev, reps, wu)["median_ms"]
        row = {"scene": name, "method": label, "clusters": k, "ms_gather": t_g, "ms_build": t_b, "ms_static": t_s,
               "ms_dynamic": t_d, "dyn_over_static": t_d / max(t_s, 1e-9), "ms_frame_static": t_fs,
               "ms_frame_dynamic": t_fd, "frame_dyn_over_static": t_fd / max(t_fs, 1e-9), "graphs": gg}
        return row, res

    rows = []
    exact_cfg = IndirectConfig(rsm_size=n, start_level=0, limit_level=0)
    row, exact = measure("exact", exact_cfg, "exact")
    row["rel_err"] = 0.0
    rows.append(row)
    ex_norm = max(float(np.linalg.norm(exact)), 1e-30)
    leaf = int(round(math.log2(n)))

    def err(res):
        return float(np.linalg.norm(res - exact) / ex_norm)

    tree_rows = []
    for dthr, nthr in THRESHOLDS:
        for lim in LIMITS:
            lim_ = min(lim, leaf)
            cfg = IndirectConfig(rsm_size=n, depth_threshold=dthr, normal_threshold=nthr, start_level=min(3, lim_),
                                 limit_level=lim_)
            methods = [("lighttree", "tree")]
            if (dthr, nthr) == THRESHOLDS[0]:
                methods.append(("traverse", "tree-per-receiver"))
            for method, tag in methods:
                row, res = measure(f"{tag} L{lim_} d{dthr} n{nthr}", cfg, method)
                row.update(limit_level=lim_, depth_threshold=dthr, normal_threshold=nthr, rel_err=err(res))
                rows.append(row)
                if method == "lighttree":
                    tree_rows.append(row)
    samples = [256, 1024, 2040] + ([] if args.quick else [4096, 8192])
    samples = [s for s in samples if s <= n * n]
    samp_rows = []
    for s in samples:
        cfg = IndirectConfig(rsm_size=n, start_level=0, limit_level=0)
        row, res = measure(f"sampled {s}", cfg, "sampled", samples=s, seed=args.seed)
        row.update(samples=s, rel_err=err(res))
        rows.append(row)
        samp_rows.append(row)

    comps = []
    if len(samp_rows) >= 2:
        ss = [r["samples"] for r in samp_rows]
        es = [r["rel_err"] for r in samp_rows]
        ms = [r["ms_static"] for r in samp_rows]
        msd = [r["ms_dynamic"] for r in samp_rows]
        for r in tree_rows:
            n_eq, ms_eq, ext = equal_error(ss, es, ms, r["rel_err"])
            _, msd_eq, _ = equal_error(ss, es, msd, r["rel_err"])
            n_t, e_t, ext_t = equal_time(ss, es, ms, r["ms_static"])
            comps.append({"scene": name, "tree": r["method"], "tree_err": r["rel_err"], "tree_ms_static": r["ms_static"],
                          "eq_err_samples": n_eq, "eq_err_sampled_ms_static": ms_eq,
                          "speedup_static": ms_eq / max(r["ms_static"], 1e-9),
                          "speedup_dynamic": msd_eq / max(r["ms_dynamic"], 1e-9),
                          "eq_err_extrapolated": ext, "eq_time_samples": n_t, "eq_time_sampled_err": e_t,
                          "eq_time_err_ratio": e_t / max(r["rel_err"], 1e-30), "eq_time_extrapolated": ext_t})
    return {"scene": name, "width": w, "height": h, "rsm_size": n, "hit_pixels": int(idx.size),
            "exact_receivers": int(len(sub)), "exact_stride": int(stride), "ms_base_frame": t_base,
            "rows": rows, "comparisons": comps}


def main(argv=None):
    p = base_parser(__doc__.splitlines()[0])
    p.add_argument("--scenes", default="cornell,bunny-in-box")
    p.add_argument("--rsm", type=int, default=None, help="RSM edge (default 256; --quick 64)")
    p.add_argument("--exact-stride", type=int, default=None, help="exact sum on every k-th hit pixel")
    p.add_argument("--seed", type=int, default=0, help="Poisson-disk pattern seed")
    p.add_argument("--no-graphs", action="store_true", help="no CUDA graph replay")
    args = p.parse_args(argv)
    import foveawarp as fw  # noqa: F401  (initializes warp quietly)
    from foveawarp._util import get_device

    dev = get_device(args.device)
    results = []
    for name in [s.strip() for s in args.scenes.split(",") if s.strip()]:
        r = bench_scene(name, args, dev)
        if r is not None:
            results.append(r)
    cols = ["scene", "method", "clusters", "rel_err", "ms_gather", "ms_build", "ms_static", "ms_dynamic",
            "dyn_over_static", "ms_frame_static", "ms_frame_dynamic", "frame_dyn_over_static"]
    ccols = ["scene", "tree", "tree_err", "tree_ms_static", "eq_err_samples", "eq_err_sampled_ms_static",
             "speedup_static", "speedup_dynamic", "eq_err_extrapolated", "eq_time_samples", "eq_time_sampled_err",
             "eq_time_err_ratio"]
    md = ""
    for r in results:
        md += (f"### {r['scene']} {r['width']}x{r['height']}, RSM {r['rsm_size']}^2, {r['hit_pixels']} receivers "
               f"(exact on {r['exact_receivers']}), reference frame {r['ms_base_frame']:.3f} ms\n\n")
        md += md_table(r["rows"], cols) + "\n"
        if r["comparisons"]:
            md += "Equal error / equal time against the sampled RSM:\n\n" + md_table(r["comparisons"], ccols) + "\n"
    print(md)
    path = write_results("indirect", dev, {"quick": bool(args.quick), "results": results}, md, out=args.out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
