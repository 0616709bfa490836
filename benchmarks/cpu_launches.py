"""Where a CPU frame's time goes, launch by launch, at several thread counts (issue 16).

Every kernel launch of ``FrameLoop.render`` on the CPU device is timed (CPU launches are synchronous, so a
launch's wall time is its cost: the kernel, its band split and the thread pool), summed per kernel over the
timed frames; the frame's time outside launches (Python of the head and the stages) is the rest. A kernel that
takes the same time at 16 threads as at 1 is serial; the ratio of the two is its scaling.

    python benchmarks/cpu_launches.py --device cpu [--threads 1,16] [--scenes cornell] [--frames 6] [--shading ao8]

Writes benchmarks/results/cpu-launches-cpu.{json,md}.
"""

from __future__ import annotations

import collections
import sys
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import SHADINGS, base_parser, md_table, shading_config, write_results  # noqa: E402


class LaunchTimer:
    """Wraps ``parallel.launch``, ``wp.launch`` and ``wp.launch_tiled`` (the outermost call of a nest counts)."""

    def __init__(self):
        import foveawarp.parallel as parallel

        self.ms = collections.defaultdict(float)
        self.count = collections.Counter()
        self._depth = 0
        self._targets = [(parallel, "launch"), (wp, "launch"), (wp, "launch_tiled")]
        self._saved = [getattr(m, n) for m, n in self._targets]

    def _wrap(self, fn):
        def timed(kernel, *a, **k):
            if self._depth or k.get("record_cmd"):
                return fn(kernel, *a, **k)
            self._depth += 1
            t0 = time.perf_counter()
            try:
                return fn(kernel, *a, **k)
            finally:
                self._depth -= 1
                self.ms[kernel.key] += (time.perf_counter() - t0) * 1e3
                self.count[kernel.key] += 1
        return timed

    def __enter__(self):
        for (m, n), f in zip(self._targets, self._saved):
            setattr(m, n, self._wrap(f))
        return self

    def __exit__(self, *exc):
        for (m, n), f in zip(self._targets, self._saved):
            setattr(m, n, f)


def profile(fw, scene, w, h, threads: int, policy: str, frames: int, warm: int = 3, config=None) -> dict:
    # graph=False: eager launches, each one timed (a replayed body runs its bands without these calls)
    loop = fw.FrameLoop(scene, w, h, config=config, device="cpu", policy=policy, cpu_threads=threads, timing=False,
                        graph=False)
    for i in range(warm):
        loop.render(scene.camera_at(i / 30), gaze_px=(w * 0.45, h * 0.5), time=i / 30)
    with LaunchTimer() as lt:
        t0 = time.perf_counter()
        for i in range(warm, warm + frames):
            loop.render(scene.camera_at(i / 30), gaze_px=(w * 0.45 + 3 * i, h * 0.5), time=i / 30)
        frame_ms = (time.perf_counter() - t0) * 1e3 / frames
    kernels = {k: v / frames for k, v in lt.ms.items()}
    return {"frame_ms": frame_ms, "launch_ms": sum(kernels.values()), "kernels_ms": kernels,
            "launches_per_frame": sum(lt.count.values()) / frames}


def main(argv=None):
    p = base_parser(__doc__)
    p.add_argument("--threads", default="1,16")
    p.add_argument("--scenes", default="cornell")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--shading", default="default", help=f"one of {', '.join(SHADINGS)}")
    args = p.parse_args(argv)
    if args.shading not in SHADINGS:
        p.error(f"--shading must be one of {', '.join(SHADINGS)}, got {args.shading!r}")
    import foveawarp as fw

    config = shading_config(fw, args.shading)
    threads = [int(t) for t in args.threads.split(",")]
    records, rows = [], []
    for name in args.scenes.split(","):
        scene = fw.load_scene(name)
        for policy in ("foveated", "full"):
            per = {n: profile(fw, scene, args.width, args.height, n, policy, args.frames, config=config)
                   for n in threads}
            rec = {"scene": name, "width": args.width, "height": args.height, "shading": args.shading,
                   "path": policy,
                   "by_threads": {str(n): v for n, v in per.items()}}
            records.append(rec)
            lo, hi = threads[0], threads[-1]
            every = set().union(*(per[n]["kernels_ms"] for n in threads))
            keys = sorted(every, key=lambda k: -max(per[n]["kernels_ms"].get(k, 0.0) for n in threads))
            for k in keys + ["(outside launches)", "(frame)"]:
                def val(n):
                    r = per[n]
                    if k == "(frame)":
                        return r["frame_ms"]
                    if k == "(outside launches)":
                        return r["frame_ms"] - r["launch_ms"]
                    return r["kernels_ms"].get(k, 0.0)
                row = {"scene": name, "path": policy, "kernel": k}
                for n in threads:
                    row[f"ms_{n}t"] = val(n)
                # a kernel that only one thread count launches (a band form) has no scaling of its own
                row[f"scaling_{hi}t"] = val(lo) / val(hi) if val(lo) > 0 and val(hi) > 0 else ""
                rows.append(row)
            print(f"== {name} {policy}: " + ", ".join(f"{n} threads {per[n]['frame_ms']:.1f} ms" for n in threads),
                  flush=True)
    cols = ["scene", "path", "kernel"] + [f"ms_{n}t" for n in threads] + [f"scaling_{threads[-1]}t"]
    md = md_table(rows, cols)
    print(md)
    write_results("cpu-launches", "cpu", {"threads": threads, "frames": args.frames, "records": records}, md,
                  args.out)


if __name__ == "__main__":
    main()
