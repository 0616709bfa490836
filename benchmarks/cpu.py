"""How fast is the CPU device: how do frames scale with threads, and is the foveated frame faster there?

The CPU device runs band-parallel launches (``foveawarp.parallel``). Parts:

* thread scaling: median foveated and reference frame time at 1, 2, 4, ..., cores threads (cornell);
* foveated vs the full-resolution reference per scene, default shading and ``ao_samples=8``, all threads;
* primary rays of the scene camera: Warp's BVH one ray at a time (``wp.mesh_query_ray``, "warp_single") and
  in packets of 8 rays (``kernels/packet.py``, "warp": the G-buffer's CPU path, the same hits), one thread and
  all threads, against Embree (``embreex``, optional: ``pip install embreex``; one thread) on the same rays:
  Mrays/s per core and hit agreement.

Frames follow the scene's camera path (1/30 s per frame) with the gaze at the screen centre, after warm-up
frames (the per-scene rows also time both paths with ``frame.py``'s moving gaze, a Lissajous figure over the
central 60 % x 40 % of the screen, one period per 60 frames, in loops of their own, interleaved with the
others); the policy is fixed ("foveated" / the reference), ``timing=False``, except in the per-scene rows'
"default policy" column (``FrameLoop``'s default with ``timing=False``: "auto", timed after its measurement
frames, with the path it chose). With ``timing=False`` a loop replays its recorded frame body (``FrameLoop``'s
``graph``; the CPU's ``parallel.record``); the reference is timed both as ``render_reference`` (eager) and as a
``policy="full"`` loop (its body replayed), and the faster of the two is the one the ratios divide. Writes
cpu-<tag>.json / .md and the thread-scaling plot cpu-<tag>.png (matplotlib).

    python benchmarks/cpu.py --device cpu                 # 640x360, cornell + bunny, 1..cores threads
    python benchmarks/cpu.py --device cpu --quick         # 96x54 smoke run
"""

from __future__ import annotations

import os
import statistics
import sys
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, plot_path, progress, pyplot, write_results  # noqa: E402
from benchmarks.frame import gaze_path  # noqa: E402
import foveawarp as fw  # noqa: E402
from foveawarp import parallel  # noqa: E402
from foveawarp._util import get_device  # noqa: E402
from foveawarp.kernels.packet import packet_ray_kernel  # noqa: E402

# on the H200 machine's host CPU (16 cores)
CANONICAL = "python benchmarks/cpu.py --device cpu --out benchmarks/results --tag h200"


@wp.kernel(enable_backward=False)
def primary_ray_kernel(mesh: wp.uint64, origin: wp.vec3, dirs: wp.array(dtype=wp.vec3), max_t: float,
                       out_t: wp.array(dtype=float), out_face: wp.array(dtype=wp.int32), row0: int):
    i = wp.tid()
    i += row0
    q = wp.mesh_query_ray(mesh, origin, dirs[i], max_t)
    if q.result:
        out_t[i] = q.t
        out_face[i] = q.face
    else:
        out_t[i] = -1.0
        out_face[i] = -1


def thread_counts(cores: int) -> list:
    out, n = [], 1
    while n < cores:
        out.append(n)
        n *= 2
    out.append(cores)
    return out


GAZE_PERIOD = 60  # frames per period of the moving gaze (frame.py's Lissajous figure)


def frame_ms(fl, frames: int, reference: bool, start: int = 0, moving: bool = False) -> list:
    """Wall times (ms) of ``frames`` frames along the scene's camera path from frame ``start``; the gaze at the
    screen centre, or (``moving``) along ``frame.py``'s moving gaze, one period per ``GAZE_PERIOD`` frames."""
    sc = fl.scene
    ts = []
    for i in range(start, start + frames):
        t = i / 30.0
        cam = sc.camera_at(t)
        g = gaze_path(i, GAZE_PERIOD, fl.width, fl.height) if moving else None
        t0 = time.perf_counter()
        if reference:
            fl.render_reference(cam, time=t, gaze_px=g)
        else:
            fl.render(cam, time=t, gaze_px=g)
        wp.synchronize_device(fl.device)
        ts.append((time.perf_counter() - t0) * 1e3)
    return ts


def interleaved(loops: dict, frames: int, warmup: int, rounds: int) -> dict:
    """Median and best (minimum over rounds of the per-round median) frame time of every (key -> (loop,
    reference[, moving gaze])) entry, the entries measured in turn within each round: on a machine shared with
    other jobs every entry sees the same interference, and the best round is the least disturbed one."""
    for fl, ref, *mv in loops.values():
        frame_ms(fl, warmup, ref, moving=bool(mv and mv[0]))
    per = {k: [] for k in loops}
    allt = {k: [] for k in loops}
    for r in range(rounds):
        for k, (fl, ref, *mv) in loops.items():
            ts = frame_ms(fl, frames, ref, start=warmup + r * frames, moving=bool(mv and mv[0]))
            per[k].append(statistics.median(ts))
            allt[k] += ts
    return {k: {"median_ms": statistics.median(allt[k]), "best_ms": min(per[k])} for k in loops}


def rays_bench(scene_name, w, h, dev, threads_all, repeats):
    sc = fw.load_scene(scene_name)
    ds = fw.scene.DeviceScene(sc, dev)
    cam = sc.camera_at(0.0)
    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    dirs_np = np.ascontiguousarray(cam.ray_dirs(xs.ravel(), ys.ravel(), w, h), dtype=np.float32)
    n = dirs_np.shape[0]
    dirs = wp.array(dirs_np, dtype=wp.vec3, device=dev)
    out_t = wp.zeros(n, dtype=float, device=dev)
    out_f = wp.zeros(n, dtype=wp.int32, device=dev)
    out_uv = wp.zeros(n, dtype=wp.vec2, device=dev)
    out_n = wp.zeros(n, dtype=wp.vec3, device=dev)
    origin = wp.vec3(*[float(v) for v in cam.eye])
    row = {"scene": scene_name, "rays": n}
    # "warp_single": wp.mesh_query_ray one ray at a time; "warp": packets of 8 rays (kernels/packet.py), the
    # G-buffer's CPU path, the same hits
    single_faces = None
    for kind, kernel, dim in (("warp_single", primary_ray_kernel, n), ("warp", packet_ray_kernel, (n + 7) // 8)):
        outs = [out_t, out_f] if kind == "warp_single" else [out_t, out_f, out_uv, out_n]
        for label, nt in ((f"{kind}_1t", 1), (f"{kind}_{threads_all}t", threads_all)):
            def run(nt=nt, kernel=kernel, dim=dim, outs=outs):
                parallel.launch(kernel, dim, [ds.mesh.id, origin, dirs, 1.0e6], outs, dev, threads=nt)
                wp.synchronize_device(dev)
            run()
            ts = []
            for _ in range(repeats):
                t0 = time.perf_counter()
                run()
                ts.append(time.perf_counter() - t0)
            row[f"{label}_mrays_s"] = n / statistics.median(ts) / 1e6
        if kind == "warp_single":
            single_faces = out_f.numpy().copy()
    row["warp_threads"] = threads_all
    row["packet_same_face_as_single"] = float((out_f.numpy() == single_faces).mean())
    warp_t, warp_f = out_t.numpy(), out_f.numpy()
    row["hit_fraction"] = float((warp_f >= 0).mean())
    try:
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh
    except ImportError:
        row["embree"] = "embreex not installed (pip install embreex): comparison skipped"
        return row
    es = rtcs.EmbreeScene()
    TriangleMesh(es, sc.vertices[sc.faces].astype(np.float32))
    origins = np.broadcast_to(np.asarray(cam.eye, np.float32), dirs_np.shape).copy()
    res = es.run(origins, dirs_np, output=1)
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = es.run(origins, dirs_np, output=1)
        ts.append(time.perf_counter() - t0)
    row["embree_1t_mrays_s"] = n / statistics.median(ts) / 1e6
    ef, et = np.asarray(res["primID"]), np.asarray(res["tfar"])
    both = (ef >= 0) & (warp_f >= 0)
    row["same_hit_miss"] = float(((ef >= 0) == (warp_f >= 0)).mean())
    row["same_face"] = float((ef[both] == warp_f[both]).mean()) if both.any() else 1.0
    row["max_rel_t_diff"] = float(np.max(np.abs(et[both] - warp_t[both]) / np.maximum(et[both], 1e-6))) if (
        both.any()) else 0.0
    row["warp_per_core_vs_embree"] = row["warp_1t_mrays_s"] / row["embree_1t_mrays_s"]
    row["warp_single_per_core_vs_embree"] = row["warp_single_1t_mrays_s"] / row["embree_1t_mrays_s"]
    return row


def main(argv=None):
    p = base_parser(__doc__, CANONICAL)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--scenes", default="cornell,bunny")
    p.add_argument("--threads", default=None, help="comma list of thread counts (default 1, 2, 4, ..., cores)")
    p.add_argument("--frames", type=int, default=None, help="timed frames per point and round")
    p.add_argument("--rounds", type=int, default=None, help="interleaved rounds (default 3; 1 with --quick)")
    p.add_argument("--scaling-scene", default="cornell")
    p.add_argument("--oversplit", default="1,2,4,8", help="bands per thread to compare at the most threads ('' = skip)")
    p.add_argument("--stages", action="store_true", help="per-stage ms at 1 and at the most threads")
    args = p.parse_args(argv)
    try:
        threads = [int(t) for t in args.threads.split(",")] if args.threads else None
        oversplits = [int(v) for v in args.oversplit.split(",") if v]
    except ValueError:
        threads = oversplits = [0]
    if (threads is not None and (not threads or min(threads) < 1)) or (oversplits and min(oversplits) < 1):
        p.error(f"--threads and --oversplit must be comma lists of positive integers, got {args.threads!r} and "
                f"{args.oversplit!r}")
    if min(args.width, args.height) < 1:
        p.error(f"--width and --height must be >= 1, got {args.width}x{args.height}")
    dev = get_device(args.device or "cpu")
    if args.quick:
        args.width, args.height = 96, 54
    frames = args.frames or (4 if args.quick else 6)
    rounds = args.rounds or (1 if args.quick else 3)
    warmup = 2 if args.quick else args.warmup
    repeats = args.repeats or (3 if args.quick else 7)
    cores = parallel.usable_cores()
    threads = threads or thread_counts(cores)
    tmax = max(threads)
    w, h = args.width, args.height
    scenes = [s for s in args.scenes.split(",") if s]
    sscene = args.scaling_scene
    where = {"scene": sscene, "width": w, "height": h}
    extra = {"usable_cores": cores, "threads": threads, "frames": frames, "rounds": rounds, "warmup": warmup,
             "bands_per_thread": {t: parallel.bands_per_thread(t) for t in threads},
             "load_average_at_start": os.getloadavg() if hasattr(os, "getloadavg") else None,
             "camera": "scene camera path, 1/30 s per frame; gaze at the centre"}
    steps = (3 if dev.is_cpu else 0) + 2 * len(scenes) + (len(scenes) if dev.is_cpu else 0) + bool(args.stages)
    bar = progress(None, "cpu", total=steps)

    scaling = []
    if dev.is_cpu:
        loops = {}
        for t in threads:
            fl = fw.FrameLoop(sscene, w, h, device=dev, timing=False, policy="foveated", cpu_threads=t)
            loops[(t, False)] = (fl, False)
            loops[(t, True)] = (fl, True)
        m = interleaved(loops, frames, warmup, rounds)
        for t in threads:
            fo, re_ = m[(t, False)], m[(t, True)]
            scaling.append({"part": "scaling", **where, "threads": t, "foveated_ms": fo["median_ms"],
                            "foveated_best_ms": fo["best_ms"], "reference_ms": re_["median_ms"],
                            "reference_best_ms": re_["best_ms"]})
        b = scaling[0]
        for r in scaling:
            r["foveated_speedup"] = b["foveated_ms"] / r["foveated_ms"]
            r["foveated_speedup_best"] = b["foveated_best_ms"] / r["foveated_best_ms"]
            r["reference_speedup"] = b["reference_ms"] / r["reference_ms"]
            r["reference_speedup_best"] = b["reference_best_ms"] / r["reference_best_ms"]
        bar.update(1)
    oversplit = []
    if dev.is_cpu and tmax > 1 and oversplits:
        # bands per thread at the most threads (parallel.OVERSPLIT): load balance against the cost of a band. A
        # loop's replayed body keeps the bands it was recorded with, so each value gets its own foveated and
        # full-resolution (policy "full") loops, recorded while it is set; the loops are then timed in turn
        default = parallel.OVERSPLIT
        loops = {}
        for k in oversplits:
            parallel.OVERSPLIT = k
            for name, policy in (("fov", "foveated"), ("ref", "full")):
                fl = fw.FrameLoop(sscene, w, h, device=dev, timing=False, policy=policy, cpu_threads=tmax)
                frame_ms(fl, max(warmup, 3), False)
                loops[(k, name)] = (fl, False)
        parallel.OVERSPLIT = default
        m = interleaved(loops, frames, warmup, rounds)
        sc0 = loops[next(iter(loops))][0].scene
        for k in oversplits:
            fo, re_ = m[(k, "fov")], m[(k, "ref")]
            oversplit.append({"part": "oversplit", **where, "oversplit": k, "threads": tmax,
                              "foveated_ms": fo["median_ms"], "foveated_best_ms": fo["best_ms"],
                              "reference_ms": re_["median_ms"], "reference_best_ms": re_["best_ms"],
                              "reference_over_foveated": re_["median_ms"] / fo["median_ms"],
                              "foveated_body": loops[(k, "fov")][0].render(sc0.camera_at(0.0)).stats["graph"]})
    if dev.is_cpu:
        bar.update(1)
    variants = []
    if dev.is_cpu and tmax > 1:
        # the reorder compaction (tile kernels) runs on one thread; "none" (the CPU's "auto") shades every pixel's
        # mask entry instead; "disc": one exact nearest-seed launch instead of the JFA passes
        loops = {}
        for label, cfg in (("default (reorder auto = none on the CPU)", fw.Config()),
                           ("reorder=tile", fw.Config().with_(reorder={"strategy": "tile"})),
                           ("jfa_variant=disc", fw.Config().with_(reconstruction={"jfa_variant": "disc"})),
                           ("jfa_variant=1+jfa", fw.Config().with_(reconstruction={"jfa_variant": "1+jfa"}))):
            loops[label] = (fw.FrameLoop(sscene, w, h, config=cfg, device=dev, timing=False, policy="foveated",
                                         cpu_threads=tmax), False)
        m = interleaved(loops, frames, warmup, rounds)
        for label in loops:
            variants.append({"part": "variants", **where, "variant": label, "threads": tmax,
                             "foveated_ms": m[label]["median_ms"], "foveated_best_ms": m[label]["best_ms"]})
    if dev.is_cpu:
        bar.update(1)

    versus = []
    for sc in scenes:
        for label, cfg in (("default", fw.Config()), ("ao_samples=8", fw.Config().with_(shading={"ao_samples": 8}))):
            versus.append(foveated_vs_reference(sc, label, cfg, w, h, dev, tmax, frames, warmup, rounds))
            bar.update(1)

    rays = []
    if dev.is_cpu:
        for sc in scenes:
            rays.append({"part": "rays", "width": w, "height": h, **rays_bench(sc, w, h, dev, tmax, repeats)})
            bar.update(1)

    stages = []
    if dev.is_cpu and args.stages:
        stages = stage_ms(sscene, w, h, dev, sorted({1, tmax}), frames, warmup)
        bar.update(1)
    bar.close()

    md = f"## CPU device, {w}x{h}, {cores} usable cores\n\n"
    if scaling:
        md += (f"### Thread scaling ({sscene}; median of all {frames * rounds} frames, and best = the "
               f"least disturbed of {rounds} interleaved rounds)\n\n")
        md += md_table(scaling, ["threads", "foveated_ms", "foveated_speedup", "foveated_best_ms",
                                 "foveated_speedup_best", "reference_ms", "reference_speedup", "reference_best_ms",
                                 "reference_speedup_best"])
    if oversplit:
        md += (f"\n### Bands per thread (parallel.OVERSPLIT; default at {tmax} threads: "
               f"{parallel.bands_per_thread(tmax)}) at {tmax} threads\n\n")
        md += md_table(oversplit, ["oversplit", "threads", "foveated_ms", "foveated_best_ms", "reference_ms",
                                   "reference_best_ms", "reference_over_foveated", "foveated_body"])
    if variants:
        md += f"\n### Frame variants at {tmax} threads ({sscene})\n\n"
        md += md_table(variants, ["variant", "threads", "foveated_ms", "foveated_best_ms"])
    md += f"\n### Foveated vs full-resolution reference ({tmax} threads)\n\n"
    md += md_table(versus, ["scene", "shading", "foveated_ms", "reference_ms", "reference_over_foveated",
                            "foveated_best_ms", "reference_best_ms", "reference_over_foveated_best",
                            "sampled_fraction", "auto_ms", "auto_path", "reference_over_auto", "foveated_moving_ms",
                            "reference_moving_ms", "reference_over_foveated_moving",
                            "reference_over_foveated_moving_best", "reference_eager_ms", "reference_full_policy_ms",
                            "foveated_body"])
    if rays:
        md += "\n### Primary rays (scene camera, one ray per pixel)\n\n"
        cols = ["scene", "rays", "warp_single_1t_mrays_s", "warp_1t_mrays_s", f"warp_{tmax}t_mrays_s",
                "embree_1t_mrays_s", "warp_single_per_core_vs_embree", "warp_per_core_vs_embree",
                "packet_same_face_as_single", "same_hit_miss", "same_face", "max_rel_t_diff", "embree"]
        md += md_table(rays, [c for c in cols if any(c in r for r in rays)])
    if stages:
        md += f"\n### Stage ms ({sscene}, timing=True: each stage synchronized)\n\n"
        keys = []
        for r in stages:
            keys += [k for k in r if k not in keys and k not in ("part", "scene", "width", "height")]
        md += md_table(stages, keys)
    write_results("cpu", dev, scaling + oversplit + variants + versus + rays + stages, md, args.out, args.tag,
                  extra=extra)
    if scaling:
        plot(scaling, plot_path("cpu", dev, args.out, args.tag), sscene, w, h)
    print(md)
    return 0


def foveated_vs_reference(sc, label, cfg, w, h, dev, tmax, frames, warmup, rounds) -> dict:
    """One scene and shading at ``tmax`` threads: the foveated loop, the reference two ways, the default policy,
    and both paths again with the moving gaze, timed in interleaved rounds."""
    kw = dict(config=cfg, device=dev, timing=False, cpu_threads=tmax)
    fl = fw.FrameLoop(sc, w, h, policy="foveated", **kw)
    fl_ref = fw.FrameLoop(sc, w, h, policy="foveated", **kw)
    # the default policy ("auto" with timing=False): its measurement (both paths, a few frames each) runs first,
    # so the timed frames render the path it chose
    fl_auto = fw.FrameLoop(sc, w, h, **kw)
    frame_ms(fl_auto, fl_auto.policy_measurement_frames() + 1, False)
    # the same two paths with frame.py's moving gaze (its own loops: a loop's history follows its gaze)
    fl_mv = fw.FrameLoop(sc, w, h, policy="foveated", **kw)
    fl_ref_mv = fw.FrameLoop(sc, w, h, policy="foveated", **kw)
    # the reference two ways: render_reference (G-buffer and full shading, eager), and a loop with policy="full"
    # (the same launches through render, its body replayed as the foveated loops' are); the faster of the two is
    # the reference of the ratios
    fl_full = fw.FrameLoop(sc, w, h, policy="full", **kw)
    fl_full_mv = fw.FrameLoop(sc, w, h, policy="full", **kw)
    m = interleaved({"fov": (fl, False), "ref_eager": (fl_ref, True), "ref_full": (fl_full, False),
                     "auto": (fl_auto, False), "fov_mv": (fl_mv, False, True), "ref_eager_mv": (fl_ref_mv, True, True),
                     "ref_full_mv": (fl_full_mv, False, True)}, frames, warmup, rounds)
    for suffix in ("", "_mv"):
        a, b = m["ref_eager" + suffix], m["ref_full" + suffix]
        m["ref" + suffix] = {"median_ms": min(a["median_ms"], b["median_ms"]),
                             "best_ms": min(a["best_ms"], b["best_ms"])}
    frac = float(fl.sampling.sample_map.numpy().mean())  # the last timed foveated frame
    # how the loops ran their frame bodies (FrameLoop stats["graph"]: "replayed" once recorded)
    body_state = fl.render(fl.scene.camera_at(0.0)).stats["graph"]
    full_state = fl_full.render(fl_full.scene.camera_at(0.0)).stats["graph"]
    fov, ref, auto = m["fov"]["median_ms"], m["ref"]["median_ms"], m["auto"]["median_ms"]
    pol = fl_auto.render(fl_auto.scene.camera_at(0.0)).stats["policy"]  # the path it renders, estimates
    return {"part": "versus", "scene": sc, "width": w, "height": h, "shading": label, "threads": tmax,
            "foveated_ms": fov, "reference_ms": ref, "reference_over_foveated": ref / fov,
            "foveated_best_ms": m["fov"]["best_ms"], "reference_best_ms": m["ref"]["best_ms"],
            "reference_over_foveated_best": m["ref"]["best_ms"] / m["fov"]["best_ms"],
            "sampled_fraction": frac, "auto_ms": auto, "auto_path": pol["path"], "reference_over_auto": ref / auto,
            "foveated_moving_ms": m["fov_mv"]["median_ms"], "reference_moving_ms": m["ref_mv"]["median_ms"],
            "reference_over_foveated_moving": m["ref_mv"]["median_ms"] / m["fov_mv"]["median_ms"],
            "reference_over_foveated_moving_best": m["ref_mv"]["best_ms"] / m["fov_mv"]["best_ms"],
            "auto_estimates_ms": {k: pol[k] for k in ("foveated_ms", "full_ms") if k in pol},
            "reference_eager_ms": m["ref_eager"]["median_ms"], "reference_full_policy_ms": m["ref_full"]["median_ms"],
            "foveated_body": body_state, "reference_full_policy_body": full_state}


def stage_ms(sscene, w, h, dev, thread_list, frames, warmup) -> list:
    """Where the time goes at each thread count: per-stage ms of a timing=True loop (each stage synchronized),
    foveated and reference; a stage that does not shrink with threads is serial."""
    out = []
    for t in thread_list:
        for label, ref in (("foveated", False), ("reference", True)):
            fl = fw.FrameLoop(sscene, w, h, device=dev, timing=True, policy="foveated", cpu_threads=t)
            acc = {}
            for i in range(warmup + frames):
                tt = (i + 1) / 30.0
                cam = fl.scene.camera_at(tt)
                f = fl.render_reference(cam, time=tt) if ref else fl.render(cam, gaze_px=(w / 2, h / 2), time=tt)
                if i >= warmup:
                    for k, v in f.stats.items():
                        if k.startswith("ms_"):
                            acc.setdefault(k[3:], []).append(v)
            out.append({"part": "stages", "scene": sscene, "width": w, "height": h, "threads": t, "path": label,
                        **{k: statistics.median(v) for k, v in acc.items()}})
    return out


def plot(scaling, path, sscene, w, h):
    """Speed-up over one thread against threads, foveated and reference, with the ideal line."""
    plt = pyplot()
    if plt is None:
        return
    fig, ax = plt.subplots(figsize=(5, 4))
    ts = [r["threads"] for r in scaling]
    ax.plot(ts, ts, "k:", label="ideal")
    ax.plot(ts, [r["foveated_speedup"] for r in scaling], "o-", label="foveated frame (median)")
    ax.plot(ts, [r["reference_speedup"] for r in scaling], "s-", label="reference frame (median)")
    ax.plot(ts, [r["foveated_speedup_best"] for r in scaling], "o--", alpha=0.6, label="foveated (best round)")
    ax.set_xlabel("threads")
    ax.set_ylabel("speed-up over 1 thread")
    ax.set_title(f"CPU scaling, {sscene} {w}x{h}")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
