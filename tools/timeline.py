"""Where a frame's wall time goes on the GPU's own timeline, foveated against full resolution (CUDA, PyTorch's
profiler).

``frame.py`` times each frame as a user sees it: synchronized wall time, from ``render``'s call to the GPU's last
work. Its per-stage GPU times come from another run with events between the stages, and never add up to the wall
time. This tool reads the GPU's timeline itself (CUPTI, through PyTorch's profiler, which records every kernel,
memset and copy of the process, CUDA-graph nodes included) while the loops render the same frames of the camera
path, taking turns as in ``frame.py``: the reference (``policy="full"``), the foveated loop (forced), the default
policy's loop past its measurement (``path`` says which path it rendered in the profiled frames) and a second
reference, ``control``, whose difference from the first is the spread of two identical loops in the same run
(``--loops``). Each frame's wall time splits into:

* ``lead_us``: from ``render``'s call to the GPU's first work of the frame (host work the GPU waits for);
* ``busy_ms``: the union of the frame's kernels, memsets and copies on the GPU;
* ``gaps_us``: the GPU's idle time between its first and last work of the frame (launch latencies between graph
  nodes and between launches, waits on the host);
* ``tail_us``: from the GPU's last work to the synchronization's return.

``kernels_ms`` is the frame's kernels summed one by one (more than ``busy_ms`` where they overlap), ``n_kernels``,
``n_memsets`` and ``n_copies`` count them, and ``per_kernel`` (JSON) gives each kernel's median ms. Medians over
``--frames`` frames per loop. ``wall_ms`` is the same frames' median wall time under the profiler and
``plain_wall_ms`` the median over the ``--frames`` frames before them, timed without it as ``frame.py`` times
them. The profiler slows the host (its callbacks on every CUDA call), so ``lead_us`` is larger than without it,
alike for every loop: compare the loops with each other, not with ``plain_wall_ms``.

    python tools/timeline.py --device cuda:0 [--scenes bunny,nefertiti,cornell,city] [--sizes ...] [--target 2]

CUDA only, and PyTorch must import. Writes timeline-<tag>.{json,md} under ``--out`` (default benchmarks/out); the
accounting table (``--from-json`` prints it again from a results file, no device needed) sets each foveated frame
against its reference and, with ``--target``, the ms it must lose to reach that speed-up.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import (base_parser, checked_shadings_sizes, md_table, scenes_present,  # noqa: E402
                                shading_config, write_results)
from benchmarks.frame import _timed_interleaved, render_path_frame  # noqa: E402

LOOPS = ("reference", "foveated", "auto", "control")
GPU_CATS = {"kernel": "kernel", "gpu_memset": "memset", "gpu_memcpy": "copy"}
MARK = "fw-frame"


def union_length(intervals) -> float:
    """Total length covered by the half-open intervals ``[(start, end), ...]`` (overlaps counted once)."""
    total, cur_s, cur_e = 0.0, None, None
    for s, e in sorted(intervals):
        if cur_e is None or s > cur_e:
            if cur_e is not None:
                total += cur_e - cur_s
            cur_s, cur_e = s, e
        else:
            cur_e = max(cur_e, e)
    if cur_e is not None:
        total += cur_e - cur_s
    return total


def frame_anatomy(gpu_events: list, start_us: float, end_us: float) -> dict:
    """One frame's split of its wall interval ``[start_us, end_us]`` (µs on the trace's clock) by the GPU work
    ``gpu_events`` (dicts with ``ts``, ``dur`` in µs, ``kind`` in kernel / memset / copy, ``name``) that starts
    inside it. A frame with no GPU work is all lead."""
    ev = [e for e in gpu_events if start_us <= e["ts"] <= end_us]
    wall = end_us - start_us
    count = {k: sum(e["kind"] == k for e in ev) for k in ("kernel", "memset", "copy")}
    if not ev:
        return {"wall_us": wall, "lead_us": wall, "busy_us": 0.0, "gaps_us": 0.0, "tail_us": 0.0,
                "kernels_us": 0.0, "n_kernels": 0, "n_memsets": 0, "n_copies": 0, "per_kernel": {}}
    iv = [(e["ts"], e["ts"] + e["dur"]) for e in ev]
    first = min(s for s, _ in iv)
    last = max(e for _, e in iv)
    busy = union_length(iv)
    per = {}
    for e in ev:
        if e["kind"] == "kernel":
            per[e["name"]] = per.get(e["name"], 0.0) + e["dur"]
    return {"wall_us": wall, "lead_us": first - start_us, "busy_us": busy, "gaps_us": (last - first) - busy,
            "tail_us": max(0.0, end_us - last), "kernels_us": sum(per.values()), "n_kernels": count["kernel"],
            "n_memsets": count["memset"], "n_copies": count["copy"], "per_kernel": per}


def trace_frames(trace: dict) -> tuple:
    """(GPU work, frame marks) of a Chrome trace that PyTorch's profiler exported: the kernels, memsets and copies
    as ``frame_anatomy`` reads them, and the ``record_function`` ranges named ``fw-frame:<loop>:<i>`` as
    (loop, i, start µs, end µs) in start order."""
    gpu, marks = [], []
    for e in trace.get("traceEvents", []):
        if e.get("ph") != "X":
            continue
        cat = e.get("cat", "")
        if cat in GPU_CATS:
            gpu.append({"ts": float(e["ts"]), "dur": float(e.get("dur", 0.0)), "kind": GPU_CATS[cat],
                        "name": e.get("name", "")})
        elif cat == "user_annotation" and str(e.get("name", "")).startswith(MARK + ":"):
            _, loop, i = e["name"].split(":")
            marks.append((loop, int(i), float(e["ts"]), float(e["ts"]) + float(e.get("dur", 0.0))))
    marks.sort(key=lambda m: m[2])
    return gpu, marks


def summarize(frames: list) -> dict:
    """Medians over one loop's ``frame_anatomy`` dicts (ms for wall, busy and kernels; µs for the rest), and each
    kernel's median ms over the frames that ran it."""
    med = lambda k: float(np.median([f[k] for f in frames]))  # noqa: E731
    names = sorted({n for f in frames for n in f["per_kernel"]})
    per = {n: float(np.median([f["per_kernel"][n] for f in frames if n in f["per_kernel"]])) / 1e3 for n in names}
    return {"wall_ms": med("wall_us") / 1e3, "lead_us": med("lead_us"), "busy_ms": med("busy_us") / 1e3,
            "gaps_us": med("gaps_us"), "tail_us": med("tail_us"), "kernels_ms": med("kernels_us") / 1e3,
            "n_kernels": med("n_kernels"), "n_memsets": med("n_memsets"), "n_copies": med("n_copies"),
            "frames": len(frames), "per_kernel": per}


def study(fw, torch_profiler, scene, w, h, shading: str, dev, frames: int, warm: int, loops_on=LOOPS) -> dict:
    """The loops of ``loops_on`` (of ``LOOPS``: ``reference`` and ``control`` are ``policy="full"``, ``foveated``
    forced, ``auto`` the default policy, past its measurement) on the same frames of the camera path, taking turns
    in a new order each frame: ``frames`` frames timed plain (``frame._timed_interleaved``, after the warm-up), then
    the next ``frames`` under the profiler."""
    cfg = shading_config(fw, shading)
    make = {"reference": dict(policy="full"), "foveated": dict(policy="foveated"), "auto": {},
            "control": dict(policy="full")}
    loops = {n: fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, **make[n]) for n in loops_on}
    # every warm-up ends at the same frame; the default policy's past its measurement
    need = {n: warm + (loop.policy_measurement_frames() + 8 if n == "auto" else 0) for n, loop in loops.items()}
    plain = _timed_interleaved(loops, scene, w, h, frames, need)  # frame.py's way: the timed frames t0 .. t0 + frames
    t0 = max(need.values())
    names = list(loops)
    rng = np.random.default_rng(1)
    rates, paths = [], []
    act = [torch_profiler.ProfilerActivity.CPU, torch_profiler.ProfilerActivity.CUDA]
    with torch_profiler.profile(activities=act) as prof:
        for i in range(t0 + frames, t0 + 2 * frames):
            for j in rng.permutation(len(names)):
                name = names[j]
                wp.synchronize_device(dev)
                with torch_profiler.record_function(f"{MARK}:{name}:{i}"):
                    f = render_path_frame(loops[name], scene, i, frames, w, h)
                    wp.synchronize_device(dev)
                if name == "foveated":
                    rates.append(float(f.stats["sampling_rate"]))  # a device read, outside the frame's mark
                elif name == "auto":
                    paths.append(f.stats["policy"]["path"])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "trace.json"
        prof.export_chrome_trace(str(path))
        trace = json.loads(path.read_text())
    gpu, marks = trace_frames(trace)
    res = {"shading": shading, "sampling_rate": float(np.median(rates)) if rates else None,
           "auto_paths": sorted(set(paths))}
    for name in names:
        fr = [frame_anatomy(gpu, s, e) for loop, _, s, e in marks if loop == name]
        if not fr:
            raise RuntimeError(f"the profiler recorded no frame of the {name} loop (is CUPTI available?)")
        res[name] = {**summarize(fr), "plain_wall_ms": plain[name]}
    return res


def kernel_group(name: str) -> str:
    """The part of the frame a kernel belongs to: ``scene`` (an animated scene's update: rigid motion, the BVH
    refit and Warp's mesh kernels), ``gbuffer``, ``shading`` (the package's ``shade_*`` kernels) or ``passes``
    (the rest: the foveated frame's fixed passes, the shading parameters, memsets)."""
    base = name.split("_cuda_kernel_forward")[0]
    if base.startswith(("rigid_motion", "wp::", "void cub::")):
        return "scene"
    if base.startswith("gbuffer"):
        return "gbuffer"
    if base.startswith("shade_"):
        return "shading"
    return "passes"


GROUPS = ("scene", "gbuffer", "shading", "passes")


def accounting(rec: dict, target=None) -> dict:
    """One record's foveated frame against its reference: both plain wall times, the speed-up, and with a
    ``target`` speed-up the ms the foveated frame must lose to reach it (negative: reached; None without a
    target); the foveated frame's kernels by ``kernel_group`` (ms, medians per kernel summed) with its time off
    the kernels (wall under the profiler less busy, ms) beside the reference's."""
    ref, fov = rec["reference"], rec["foveated"]
    out = {"ref_ms": ref["plain_wall_ms"], "fov_ms": fov["plain_wall_ms"],
           "speedup": ref["plain_wall_ms"] / fov["plain_wall_ms"], "target": target,
           "cut_needed_ms": None if target is None else fov["plain_wall_ms"] - ref["plain_wall_ms"] / target}
    for g in GROUPS:
        out[f"fov_{g}_ms"] = sum(v for k, v in fov["per_kernel"].items() if kernel_group(k) == g)
    out["fov_off_kernels_ms"] = fov["wall_ms"] - fov["busy_ms"]
    out["ref_off_kernels_ms"] = ref["wall_ms"] - ref["busy_ms"]
    return out


ROW_KEYS = ("plain_wall_ms", "wall_ms", "lead_us", "busy_ms", "gaps_us", "tail_us", "kernels_ms", "n_kernels",
            "n_memsets", "n_copies")


def accounting_table(records: list, target=None) -> str:
    """``accounting`` of each record with a reference and a foveated loop, as a markdown table."""
    rows = [{"scene": r["scene"], "size": f"{r['width']}x{r['height']}", "shading": r["shading"],
             **accounting(r, target)} for r in records if "reference" in r and "foveated" in r]
    return md_table(rows, list(rows[0])) if rows else ""


def main(argv=None) -> list:
    p = base_parser(__doc__)
    p.add_argument("--scenes", default="bunny,nefertiti,cornell,city")
    p.add_argument("--sizes", default="3840x2160,1920x1080")
    p.add_argument("--shadings", default="default,ao8")
    p.add_argument("--frames", type=int, default=30, help="frames per loop, timed plain and again profiled")
    p.add_argument("--warm", type=int, default=12, help="untimed frames of each loop first")
    p.add_argument("--loops", default=",".join(LOOPS), help=f"a comma list of {', '.join(LOOPS)}")
    p.add_argument("--target", type=float, default=None, help="speed-up the accounting measures against (> 0)")
    p.add_argument("--from-json", default=None, help="print the accounting table of a results JSON of this script "
                   "(no device needed) and exit")
    args = p.parse_args(argv)
    if args.target is not None and not args.target > 0:
        p.error(f"--target must be a speed-up > 0, got {args.target}")
    if args.from_json:
        try:
            records = json.loads(Path(args.from_json).read_text())["records"]
            table = accounting_table(records, args.target)
            if not table:
                raise ValueError("no record has both a reference and a foveated loop")
        except (OSError, ValueError, KeyError, TypeError) as e:
            p.error(f"--from-json must be a results JSON of this script (records with a reference and a foveated "
                    f"loop), got {args.from_json!r} ({type(e).__name__}: {e})")
        print(table)
        return []
    shadings, sizes = checked_shadings_sizes(p, args)
    loops_on = [n for n in args.loops.split(",") if n]
    if not loops_on or any(n not in LOOPS for n in loops_on) or len(set(loops_on)) < len(loops_on):
        p.error(f"--loops must be a comma list of distinct names of {', '.join(LOOPS)}, got {args.loops!r}")
    if args.frames < 1 or args.warm < 0:
        p.error(f"--frames must be >= 1 and --warm >= 0, got {args.frames} and {args.warm}")
    wp.config.quiet = True
    dev = wp.get_device(args.device)
    if not dev.is_cuda:
        p.error(f"--device must be a CUDA device (the study reads the CUDA timeline), got {args.device!r}")
    try:
        import torch.profiler as torch_profiler
    except ImportError as e:
        p.error(f"PyTorch's profiler must import (it reads the GPU's timeline through CUPTI): {e}")
    import foveawarp as fw

    records, rows = [], []
    for scene in scenes_present(fw, args.scenes):
        for w, h in sizes:
            for shading in shadings:
                r = {"scene": scene.name, "width": w, "height": h,
                     **study(fw, torch_profiler, scene, w, h, shading, dev, args.frames, args.warm, loops_on)}
                records.append(r)
                for name in loops_on:
                    rows.append({"scene": scene.name, "size": f"{w}x{h}", "shading": shading, "loop": name,
                                 **{k: r[name][k] for k in ROW_KEYS},
                                 "path": "/".join(r["auto_paths"]) if name == "auto" else ""})
                    print(rows[-1], flush=True)
    md = (md_table(rows, list(rows[0])) + "\n" + accounting_table(records, args.target)) if rows else \
        "no scene loaded\n"
    write_results("timeline", dev, records, md, args.out, args.tag,
                  extra={"frames": args.frames, "warm": args.warm, "target": args.target})
    print(md)
    return records


if __name__ == "__main__":
    main()
