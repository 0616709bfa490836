"""The CPU's two thread teams side by side (issue 16): the native team (``parallel.NATIVE_TEAM`` on: workers that
wait for bands in native code) against the Python team (off: threads woken through locks, a GIL hand-off per
band), on the same frame loops in one process, the setting toggled round by round.

For each scene and shading, a foveated and a full-resolution ``FrameLoop`` render frames along the scene's camera
path with a moving gaze; every round renders ``--frames`` frames of each loop under each setting (the order of the
settings alternates between rounds, so both see the same disturbance from other work on the machine; the native
team is stopped before a Python-team round, and each round starts with one untimed frame per loop). Medians of
per-frame wall times (CPU launches are synchronous, so a frame's wall time is its cost).

    python benchmarks/cpu_team.py --device cpu [--threads 16] [--rounds 6] [--frames 8] [--scenes cornell,bunny]

Writes benchmarks/results/cpu-team-cpu.{json,md}.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

from benchmarks._common import SHADINGS, base_parser, md_table, shading_config, write_results  # noqa: E402

SETTINGS = ("native", "python")


def frame_times(loop, scene, w, h, start: int, frames: int) -> list:
    """Wall ms of ``frames`` frames from frame index ``start`` of the scene's camera path (gaze moving right)."""
    out = []
    for i in range(start, start + frames):
        t0 = time.perf_counter()
        loop.render(scene.camera_at(i / 30), gaze_px=(w * 0.45 + 3 * (i % 40), h * 0.5), time=i / 30)
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def main(argv=None):
    p = base_parser(__doc__)
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: the usable cores)")
    p.add_argument("--scenes", default="cornell,bunny")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--rounds", type=int, default=6)
    p.add_argument("--frames", type=int, default=8)
    args = p.parse_args(argv)
    import warp as wp

    import foveawarp as fw
    from foveawarp import parallel

    if args.quick:
        args.width, args.height, args.rounds, args.frames = 96, 54, 2, 2
    dev = "cpu" if args.device is None else args.device
    if not wp.get_device(dev).is_cpu:
        p.error(f"--device must be the CPU device (the teams run CPU launches), got {args.device!r}")
    threads = parallel.resolve_cpu_threads(args.threads, "--threads")
    if threads > parallel.usable_cores():
        print(f"note: {threads} threads exceed the {parallel.usable_cores()} usable cores: both settings then run "
              "the Python team", flush=True)
    w, h = args.width, args.height
    records, rows = [], []
    saved = parallel.NATIVE_TEAM
    try:
        for shading in SHADINGS:
            for name in args.scenes.split(","):
                scene = fw.load_scene(name)
                loops = {path: fw.FrameLoop(scene, w, h, config=shading_config(fw, shading), device=dev,
                                            policy=path, cpu_threads=threads, timing=False)
                         for path in ("foveated", "full")}
                for setting in SETTINGS:  # warm both settings (the native team is built by its first launch)
                    parallel.NATIVE_TEAM = setting == "native"
                    for loop in loops.values():
                        frame_times(loop, scene, w, h, 0, 3)
                ms = {(path, s): [] for path in loops for s in SETTINGS}
                start = 3
                for r in range(args.rounds):
                    for setting in SETTINGS if r % 2 == 0 else SETTINGS[::-1]:
                        parallel.NATIVE_TEAM = setting == "native"
                        if setting == "python":  # no native workers spinning or napping beside its threads
                            parallel.shutdown_native_team()
                        for loop in loops.values():  # untimed: a native team starts again here
                            frame_times(loop, scene, w, h, start, 1)
                        for path, loop in loops.items():
                            ms[(path, setting)] += frame_times(loop, scene, w, h, start, args.frames)
                    start += args.frames
                med = {k: statistics.median(v) for k, v in ms.items()}
                rec = {"scene": name, "shading": shading, "width": w, "height": h, "threads": threads,
                       "frames_per_round": args.frames, "rounds": args.rounds,
                       "ms": {f"{path}_{s}": v for (path, s), v in ms.items()}}
                for s in SETTINGS:
                    rec[f"foveated_{s}_ms"] = med[("foveated", s)]
                    rec[f"full_{s}_ms"] = med[("full", s)]
                    rec[f"full_over_foveated_{s}"] = med[("full", s)] / med[("foveated", s)]
                records.append(rec)
                rows.append({k: v for k, v in rec.items() if k != "ms" and k not in ("frames_per_round", "rounds")})
                print(f"{name} {shading} {threads}t: " + " | ".join(
                    f"{s}: foveated {med[('foveated', s)]:.2f} full {med[('full', s)]:.2f} ms" for s in SETTINGS),
                    flush=True)
    finally:
        parallel.NATIVE_TEAM = saved
    cols = ["scene", "shading", "threads"] + [f"{k}_{s}_ms" for s in SETTINGS for k in ("foveated", "full")] + \
        [f"full_over_foveated_{s}" for s in SETTINGS]
    md = md_table(rows, cols)
    print(md)
    write_results("cpu-team", dev, {"records": records}, md, args.out)


if __name__ == "__main__":
    main()
