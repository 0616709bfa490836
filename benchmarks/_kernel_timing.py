"""Per-kernel GPU timing for the benchmarks that split a stage by kernel (reorder, stages): Warp's CUDA activity
timing, plus the synchronized wall time of a call and of its captured CUDA graph's replay."""

from __future__ import annotations

import re
import statistics

import warp as wp

from benchmarks._common import time_ms

# kernels, Warp's built-in kernels (array_scan, fills) and memsets: everything a stage's run puts on the GPU
CUDA_FILTER = wp.TIMING_KERNEL | wp.TIMING_KERNEL_BUILTIN | wp.TIMING_MEMSET


def _short(name: str) -> str:
    """"forward kernel jfa_pass_kernel_1a2b3c4d" -> "jfa_pass_kernel" (Warp's activity name, hash dropped)."""
    last = name.split()[-1] if name else name
    return re.sub(r"_[0-9a-f]{8}$", "", last)


def kernel_times(fn, device, repeats: int, warmup: int) -> dict:
    """GPU time of every kernel / memset ``fn()`` launches, from ``wp.timing_begin(cuda_filter=...)`` /
    ``wp.timing_end()`` around each of ``repeats`` calls (after ``warmup`` untimed calls).

    Returns {"kernels": {name: {"launches": per call, "median_ms": median over calls of the summed time}},
    "gpu_ms": median over calls of the sum over all activities, "launches": activities per call}.
    CUDA only (the CPU has no activity timing): returns None on the CPU."""
    d = wp.get_device(device)
    if not d.is_cuda:
        return None
    for _ in range(warmup):
        fn()
    wp.synchronize_device(d)
    per_call = []
    for _ in range(repeats):
        wp.timing_begin(cuda_filter=CUDA_FILTER, synchronize=True)
        fn()
        res = wp.timing_end(synchronize=True)
        acc: dict = {}
        for r in res:
            acc.setdefault(_short(r.name), []).append(float(r.elapsed))
        per_call.append(acc)
    names = sorted({n for c in per_call for n in c})
    kernels = {}
    for n in names:
        sums = [sum(c.get(n, [])) for c in per_call]
        kernels[n] = {"launches": statistics.median([len(c.get(n, [])) for c in per_call]),
                      "median_ms": statistics.median(sums)}
    totals = [sum(sum(v) for v in c.values()) for c in per_call]
    launches = statistics.median([sum(len(v) for v in c.values()) for c in per_call])
    return {"kernels": kernels, "gpu_ms": statistics.median(totals), "launches": launches}


def graph_time(fn, device, repeats: int, warmup: int) -> dict:
    """Capture ``fn()`` as a CUDA graph (what FrameLoop replays) and time its replay (synchronized wall time,
    median). {"graph_ms": ..., "error": None} or {"graph_ms": None, "error": why} (also on the CPU)."""
    d = wp.get_device(device)
    if not d.is_cuda:
        return {"graph_ms": None, "error": "CPU device: no graphs"}
    fn()  # load modules before capturing
    wp.synchronize_device(d)
    try:
        with wp.ScopedCapture(device=d) as cap:
            fn()
    except Exception as e:  # capture must work: report it instead of failing the whole benchmark
        return {"graph_ms": None, "error": f"{type(e).__name__}: {e}"}
    t = time_ms(lambda: wp.capture_launch(cap.graph), d, repeats, warmup)
    return {"graph_ms": t["median_ms"], "error": None}
