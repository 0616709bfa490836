"""What one band-parallel CPU launch costs beyond its kernel (issue 16): ``parallel.launch`` of a kernel that
does almost nothing (360 x 4 items, every row its own band) at several thread counts, median and p90 of the
launches. ``--root DIR`` measures the foveawarp package under DIR instead of this checkout (an A/B of two trees
in one session). Each thread count is measured with the Python team (the native team stopped) and then with
the native team (``parallel.NATIVE_TEAM``, where the package has one and the threads fit the usable cores). Writes
benchmarks/results/cpu-dispatch-cpu.{json,md}.

    python benchmarks/cpu_dispatch.py [--root DIR] [--threads 1,2,4,8,16]
"""

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.append(str(ROOT))

from benchmarks._common import base_parser, md_table, write_results  # noqa: E402


def main(argv=None):
    p = base_parser(__doc__)
    p.add_argument("--root", default=None, help="folder holding the foveawarp package to measure")
    p.add_argument("--threads", default="1,2,4,8,16")
    args = p.parse_args(argv)
    if args.root:
        sys.path.insert(0, str(Path(args.root).resolve()))
        for m in [m for m in sys.modules if m == "foveawarp" or m.startswith("foveawarp.")]:
            del sys.modules[m]
    import numpy as np
    import warp as wp

    wp.config.quiet = True
    import foveawarp.parallel as par

    @wp.kernel(enable_backward=False)
    def nearly_nothing(a: wp.array2d(dtype=float), b: wp.array2d(dtype=float), row0: int):
        y, x = wp.tid()
        y += row0
        if x == 0:
            b[y, x] = a[y, x]

    repeats = args.repeats or (20 if args.quick else 400)
    h, w = 360, 4
    a = wp.zeros((h, w), dtype=float, device="cpu")
    b = wp.zeros_like(a)
    rows = []
    has_native = hasattr(par, "NATIVE_TEAM")
    saved = getattr(par, "NATIVE_TEAM", False)
    teams = ("native", "python") if has_native else ("python",)
    try:
        for n in [int(t) for t in args.threads.split(",")]:
            def f():
                par.launch(nearly_nothing, (h, w), [a], [b], device="cpu", threads=n, min_band_items=1)

            ts = {t: [] for t in teams}
            for t in teams[::-1]:  # the Python team first, with no native team running (its workers would
                if has_native:     # spin and nap beside the Python team's threads)
                    par.NATIVE_TEAM = t == "native"
                    if t == "python" and hasattr(par, "shutdown_native_team"):
                        par.shutdown_native_team()
                for _ in range(args.warmup + 10):
                    f()
                for _ in range(repeats):
                    t0 = time.perf_counter()
                    f()
                    ts[t].append(time.perf_counter() - t0)
            for t in teams:
                used = t if n > 1 and (t == "python" or n <= par.usable_cores()) else ("python" if n > 1 else "-")
                rows.append({"threads": n, "team": used,
                             "bands": len(par.bands(h, n * par.bands_per_thread(n), w, 1)) if n > 1 else 1,
                             "launch_us_median": float(np.median(ts[t]) * 1e6),
                             "launch_us_p90": float(np.percentile(ts[t], 90) * 1e6)})
                print(rows[-1], flush=True)
    finally:
        if has_native:
            par.NATIVE_TEAM = saved
    md = md_table(rows, ["threads", "team", "bands", "launch_us_median", "launch_us_p90"])
    print(md)
    write_results("cpu-dispatch", "cpu", {"package": str(Path(par.__file__).resolve().parent.parent.name),
                                          "resolution": f"{w}x{h}", "scene": "none (a no-op kernel)",
                                          "repeats": repeats, "rows": rows}, md, args.out)


if __name__ == "__main__":
    main()
