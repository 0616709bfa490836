"""The soak part of ``robustness.py``: many frames with a moving camera, a moving gaze and moving objects; memory
flat, no NaN, stable frame time.

One FrameLoop (timing=False, policy="foveated") renders ``--frames`` frames (the first ``--warmup`` of them are
warm-up and excluded from every statistic). Per frame: the camera follows the scene's orbit path
(``Scene.camera_at``), the gaze follows a Lissajous curve that leaves the screen part of the time, and ``time=``
advances at ``--fps`` so animated objects move (``cornell`` is loaded with ``motion=True``: the short block slides).
Every ``--cut-every`` frames the frame is a forced camera cut (``cut=True``), so the history-reset path is soaked
too. Four consecutive forced cuts fall in the warm-up: on CUDA the frame body is captured as one CUDA graph per
configuration (history on/off, ping-pong parity, ...), run eagerly the first time and captured the second, so every
configuration the soak visits is captured before the first memory sample. ``graph_states_after_warmup`` counts
FrameLoop's ``stats['graph']`` ("replayed", "captured", "warm-up", "eager") over the timed frames.

Each frame is timed on the host with ``wp.synchronize_device`` before and after ``render`` (perf_counter). Every
``--check-every`` frames (and after the last one) the display image is read back and checked for NaN / Inf, and
memory is sampled:

- CUDA: Warp's memory-pool statistics, ``wp.get_mempool_used_mem_current`` / ``wp.get_mempool_used_mem_high``
  (bytes in use by Warp's allocator), the device's used memory (``Device.total_memory - Device.free_memory``,
  which includes other processes) and the host process's resident set size;
- CPU: the process's resident set size (``/proc/self/statm``; Warp's CPU arrays are host memory).

Verdicts: "memory flat" when Warp's pool use did not grow at all after warm-up (0 bytes: end and maximum equal the
first sample after warm-up; CUDA), or when the process RSS grew by less than 1 MiB (CPU); "no NaN" when every
checked image was finite; "frame time stable" when the median of the last tenth of the timed frames is within
10 % of the median of the first tenth. The soak fails (``robustness.py`` exits 1) when NaN/Inf was seen or memory
was not flat.
"""

from __future__ import annotations

import gc
import math
import os
import resource
import sys
import time

import numpy as np
import warp as wp

from benchmarks._common import md_table

MIB = 1024 * 1024
RSS_FLAT_BYTES = 1 * MIB  # CPU verdict: RSS growth after warm-up below this
STABLE_RATIO = 1.10  # frame time stable: last-tenth median within 10 % of first-tenth median


# -- paths ---------------------------------------------------------------------------------------------------------
def gaze_at(t: float, w: int, h: int) -> tuple:
    """Lissajous gaze (periods 7.3 s and 4.1 s). The amplitude is 0.52 of the screen size about its centre, so the
    gaze is off screen whenever |sin| > 0.96 on either axis (about a third of a long run)."""
    gx = w * (0.5 + 0.52 * math.sin(2.0 * math.pi * t / 7.3))
    gy = h * (0.5 + 0.52 * math.sin(2.0 * math.pi * t / 4.1 + 0.7))
    return (gx, gy)


def on_screen(g, w: int, h: int) -> bool:
    return 0.0 <= g[0] < w and 0.0 <= g[1] < h


# -- memory --------------------------------------------------------------------------------------------------------
def host_rss_bytes() -> int:
    """Current resident set size of this process (bytes); the peak from getrusage where /proc is missing."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        ru = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return int(ru) * (1 if sys.platform == "darwin" else 1024)


def mempool_available(dev) -> bool:
    return bool(dev.is_cuda and wp.is_mempool_supported(dev) and wp.is_mempool_enabled(dev))


def memory_sample(dev, frame: int) -> dict:
    """One memory sample (bytes), taken with the device idle and after a garbage collection."""
    wp.synchronize_device(dev)
    gc.collect()
    s = {"frame": frame, "host_rss": host_rss_bytes()}
    if dev.is_cuda:
        if mempool_available(dev):
            s["mempool_used"] = int(wp.get_mempool_used_mem_current(dev))
            s["mempool_high"] = int(wp.get_mempool_used_mem_high(dev))
        s["device_used"] = int(dev.total_memory - dev.free_memory)
    return s


def memory_summary(samples: list, key: str) -> dict:
    v = [s[key] for s in samples if key in s]
    if not v:
        return {}
    return {"first_after_warmup": v[0], "end": v[-1], "max": max(v), "min": min(v), "growth": v[-1] - v[0],
            "max_minus_first": max(v) - v[0]}


# -- stats ---------------------------------------------------------------------------------------------------------
def frame_time_summary(ms: np.ndarray) -> dict:
    if ms.size == 0:
        return {}
    tenth = max(1, ms.size // 10)
    first, last = float(np.median(ms[:tenth])), float(np.median(ms[-tenth:]))
    ratio = last / first if first > 0 else float("nan")
    return {"timed_frames": int(ms.size), "mean_ms": float(ms.mean()), "std_ms": float(ms.std()),
            "p50_ms": float(np.percentile(ms, 50)), "p90_ms": float(np.percentile(ms, 90)),
            "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max()), "min_ms": float(ms.min()),
            "first_tenth_median_ms": first, "last_tenth_median_ms": last, "drift_ratio": ratio,
            "stable": bool(1.0 / STABLE_RATIO <= ratio <= STABLE_RATIO)}


def load(fw, name: str, motion: bool):
    """Load a scene; ``motion=True`` is passed only to builders that take it (cornell)."""
    if motion:
        try:
            return fw.load_scene(name, motion=True)
        except TypeError:
            print(f"(scene {name!r} has no motion option: objects stay still; camera and gaze still move)")
    return fw.load_scene(name)


def add_options(p) -> None:
    """The soak's options on ``robustness.py``'s parser."""
    g = p.add_argument_group("soak")
    g.add_argument("--frames", type=int, default=None,
                   help="soak frames in all, warm-up included (default 10000; quick 200)")
    g.add_argument("--width", type=int, default=None, help="soak width (default 1920; quick 128)")
    g.add_argument("--height", type=int, default=None, help="soak height (default 1080; quick 72)")
    g.add_argument("--scene", default="cornell", help="soak scene name or path (default cornell, loaded with motion)")
    g.add_argument("--no-motion", dest="motion", action="store_false", help="load the scene without object motion")
    g.add_argument("--fps", type=float, default=60.0, help="scene seconds per frame = 1 / fps (default 60)")
    g.add_argument("--check-every", type=int, default=None,
                   help="NaN check + memory sample period in frames (default 100; quick 20)")
    g.add_argument("--cut-every", type=int, default=None,
                   help="force a camera cut every N frames (0: never; default 1000; quick 50)")
    g.add_argument("--ao", type=int, default=0, help="ShadingConfig.ao_samples of the soak (default 0)")


def settings(p, args) -> dict:
    """The soak's sizes and periods from the options (``--quick`` defaults), or a parser error naming the option."""
    s = {"width": args.width or (128 if args.quick else 1920), "height": args.height or (72 if args.quick else 1080),
         "frames": args.frames or (200 if args.quick else 10000),
         "warmup": args.warmup if args.warmup is not None else (20 if args.quick else 100),
         "check_every": args.check_every or (20 if args.quick else 100),
         "cut_every": args.cut_every if args.cut_every is not None else (50 if args.quick else 1000)}
    if min(s["width"], s["height"], s["frames"], s["check_every"]) < 1 or s["cut_every"] < 0:
        p.error(f"--width, --height, --frames and --check-every must be >= 1 and --cut-every >= 0, got {s}")
    if not 0 <= s["warmup"] < s["frames"]:
        p.error(f"--warmup must be in [0, frames), got {s['warmup']} with {s['frames']} frames")
    return s


def run(fw, dev, args, s: dict, bar=None) -> tuple:
    """The soak of settings ``s`` on ``dev``: (record, markdown, passed). ``bar``: a progress bar advanced once per
    frame."""
    w, h, frames, warmup = s["width"], s["height"], s["frames"], s["warmup"]
    check_every, cut_every = s["check_every"], s["cut_every"]
    scene = load(fw, args.scene, args.motion)
    cfg = fw.Config().with_(shading={"ao_samples": args.ao}) if args.ao else fw.Config()
    loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
    print(f"soak: {scene.summary()} at {w}x{h} on {dev.alias}: {frames} frames ({warmup} warm-up), "
          f"check every {check_every}", file=sys.stderr, flush=True)

    # four consecutive forced cuts in the warm-up: on CUDA the frame body is a CUDA graph per configuration
    # (history on/off x ping-pong parity, ...) that runs eagerly once and is captured the second time, so each cut
    # configuration has run eagerly and been captured before the first memory sample
    warm_cuts = set(range(warmup // 2, warmup // 2 + 4)) if (cut_every and warmup >= 8) else set()
    graph_states: dict = {}
    ms = np.zeros(frames, dtype=np.float64)  # preallocated: the soak itself must not grow host memory
    samples: list = []
    nan_frames: list = []
    checks = off_screen = cuts = 0
    rates = []
    t_start = time.perf_counter()
    for i in range(frames):
        t = i / args.fps
        cam = scene.camera_at(t)
        g = gaze_at(t, w, h)
        off_screen += not on_screen(g, w, h)
        cut = bool(cut_every and ((i > 0 and i % cut_every == 0) or i in warm_cuts))
        cuts += cut
        wp.synchronize_device(dev)
        t0 = time.perf_counter()
        frame = loop.render(cam, gaze_px=g, time=t, cut=cut)
        wp.synchronize_device(dev)
        ms[i] = (time.perf_counter() - t0) * 1e3
        if i >= warmup:  # read after the timed region (reading stats copies the device counters)
            st = str(frame.stats.get("graph", "n/a")).split(" (")[0]
            graph_states[st] = graph_states.get(st, 0) + 1
        last = i == frames - 1
        if i == warmup or (i > warmup and (i - warmup) % check_every == 0) or last:
            img = frame.image.numpy()
            bad = int(img.size - np.count_nonzero(np.isfinite(img)))
            checks += 1
            if bad:
                nan_frames.append({"frame": i, "non_finite_values": bad})
            rates.append(float(frame.stats["sampling_rate"]))
            samples.append(memory_sample(dev, i))
        if bar is not None:
            bar.update(1)
    wall_s = time.perf_counter() - t_start

    timed = ms[warmup:]
    ft = frame_time_summary(timed)
    # per-window medians (one per check period): the frame-time series at a glance
    windows = [float(np.median(timed[k:k + check_every])) for k in range(0, timed.size, check_every)]
    mem = {"host_rss": memory_summary(samples, "host_rss")}
    if dev.is_cuda:
        mem["mempool_used"] = memory_summary(samples, "mempool_used")
        mem["mempool_high"] = memory_summary(samples, "mempool_high")
        mem["device_used"] = memory_summary(samples, "device_used")
    if dev.is_cuda and mem.get("mempool_used"):
        m = mem["mempool_used"]
        flat = m["growth"] == 0 and m["max_minus_first"] == 0
        criterion = "Warp mempool bytes in use after warm-up: growth 0 and max == first sample"
    elif dev.is_cuda:
        m = mem["device_used"]
        flat = m["growth"] == 0 and m["max_minus_first"] == 0
        criterion = "mempool disabled: device used bytes (total - free) after warm-up: growth 0"
    else:
        m = mem["host_rss"]
        flat = m["growth"] < RSS_FLAT_BYTES
        criterion = f"process RSS growth after warm-up < {RSS_FLAT_BYTES // MIB} MiB"
    host_growth = mem["host_rss"]["growth"]
    verdict = {"memory_flat": bool(flat), "memory_criterion": criterion,
               "host_rss_growth_bytes": int(host_growth), "host_rss_flat": bool(host_growth < RSS_FLAT_BYTES),
               "no_nan": not nan_frames, "frame_time_stable": ft.get("stable", True),
               "stable_criterion": f"last-tenth median / first-tenth median in [1/{STABLE_RATIO}, {STABLE_RATIO}]"}
    passed = bool(flat and not nan_frames)
    rec = {
        "part": "soak", "scene": scene.name, "animated": scene.is_animated, "width": w, "height": h,
        "frames": frames, "warmup": warmup, "check_every": check_every, "fps": args.fps, "cut_every": cut_every,
        "forced_cuts": cuts, "warmup_cuts": sorted(warm_cuts), "graph_states_after_warmup": graph_states,
        "gaze_off_screen_frames": off_screen, "ao_samples": args.ao, "wall_s": wall_s, "frame_time": ft,
        "window_median_ms": windows, "memory": mem, "memory_samples": samples, "nan_checks": checks,
        "nan_frames": nan_frames, "sampling_rate_mean": float(np.mean(rates)), "verdict": verdict, "pass": passed,
        "method": "frame ms = host perf_counter between wp.synchronize_device calls around FrameLoop.render "
                  "(timing=False, policy='foveated'); statistics over the frames after warm-up; memory sampled every "
                  "check_every frames after warm-up with the device idle and after gc.collect()",
    }
    row = {"scene": scene.name, "resolution": f"{w}x{h}", "frames": frames, "warmup": warmup, "p50_ms": ft["p50_ms"],
           "p90_ms": ft["p90_ms"], "p99_ms": ft["p99_ms"], "max_ms": ft["max_ms"], "drift_ratio": ft["drift_ratio"],
           "nan_frames": len(nan_frames), "memory_growth_bytes": int(m["growth"]),
           "memory_flat": verdict["memory_flat"]}
    md = "## Soak\n\n" + md_table([row])
    md += "\n" + "\n".join([
        f"- memory: {criterion}: " + ", ".join(f"{k} {v}" for k, v in m.items()),
        f"- host RSS after warm-up: first {mem['host_rss']['first_after_warmup'] / MIB:.2f} MiB, end "
        f"{mem['host_rss']['end'] / MIB:.2f} MiB, max {mem['host_rss']['max'] / MIB:.2f} MiB",
        f"- NaN/Inf checks: {checks}, frames with non-finite values: {len(nan_frames)}",
        f"- gaze off screen in {off_screen} of {frames} frames; {cuts} forced camera cuts; mean sampling rate "
        f"{rec['sampling_rate_mean']:.3f}; frame body after warm-up: {graph_states}",
        f"- verdict: memory {'flat' if flat else 'NOT flat'}, {'no NaN' if not nan_frames else 'NaN/Inf seen'}, "
        f"frame time {'stable' if verdict['frame_time_stable'] else 'NOT stable'} "
        f"(drift {ft['drift_ratio']:.3f})"]) + "\n"
    return rec, md, passed
