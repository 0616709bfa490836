"""A/B of the CPU band dispatcher (``foveawarp.parallel.NATIVE_BANDS``: bands run by one native call per thread,
``kernels/bands.py``) against the Python band loop, in one process: the same frame loops, the two settings
alternated round by round (their order flipped every round), so both see the same machine load.

    python benchmarks/cpu_native_ab.py --device cpu [--threads 16] [--scenes cornell,bunny] [--rounds 8]

Reports per scene x shading x path (foveated, reference): the median over rounds of each round's median frame
time, and the best round, for each setting. Writes benchmarks/results/cpu-native-ab-cpu.{json,md}.
"""

from __future__ import annotations

import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._common import base_parser, md_table, shading_config, write_results  # noqa: E402
from benchmarks.cpu import frame_ms  # noqa: E402


def main(argv=None) -> None:
    p = base_parser(__doc__.split("\n\n")[0])
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: the usable cores)")
    p.add_argument("--scenes", default="cornell,bunny")
    p.add_argument("--shadings", default="default,ao8")
    p.add_argument("--size", default="640x360")
    p.add_argument("--rounds", type=int, default=8)
    p.add_argument("--frames", type=int, default=8, help="frames per round and setting")
    args = p.parse_args(argv)
    import foveawarp as fw
    from foveawarp import parallel

    if args.device not in (None, "cpu"):
        p.error(f"--device must be cpu (the dispatcher is the CPU's), got {args.device!r}")
    w, h = (int(v) for v in args.size.split("x"))
    frames, rounds = (2, 2) if args.quick else (args.frames, args.rounds)
    if args.quick:
        w, h = 96, 54
    threads = parallel.resolve_cpu_threads(args.threads)
    saved = parallel.NATIVE_BANDS
    rows = []
    try:
        for name in args.scenes.split(","):
            scene = fw.load_scene(name)
            for shading in args.shadings.split(","):
                cfg = shading_config(fw, shading)
                loops = {ref: fw.FrameLoop(scene, w, h, config=cfg, device="cpu", cpu_threads=threads, timing=False,
                                           policy="foveated")
                         for ref in (False, True)}
                per = {(nat, ref): [] for nat in (True, False) for ref in (False, True)}
                pos = 0
                for r in range(rounds + 1):  # round 0 warms both settings up and is not counted
                    for nat in ((True, False) if r % 2 == 0 else (False, True)):
                        parallel.NATIVE_BANDS = nat
                        for ref, fl in loops.items():
                            ts = frame_ms(fl, frames, ref, start=pos)
                            if r > 0:
                                per[(nat, ref)].append(statistics.median(ts))
                        pos += frames
                for (nat, ref), v in per.items():
                    rows.append({"scene": scene.name, "shading": shading, "path": "reference" if ref else "foveated",
                                 "native_bands": nat, "threads": threads, "median_ms": statistics.median(v),
                                 "best_ms": min(v)})
                    print(f"{scene.name} {shading} {'reference' if ref else 'foveated'} native={nat}: "
                          f"{statistics.median(v):.3f} ms (best {min(v):.3f})", flush=True)
    finally:
        parallel.NATIVE_BANDS = saved
    cols = ["scene", "shading", "path", "native_bands", "threads", "median_ms", "best_ms"]
    md = (f"## CPU band dispatcher A/B ({w}x{h}, {threads} threads, {rounds} rounds of {frames} frames per setting, "
          f"alternated)\n\n" + md_table(rows, cols))
    path = write_results("cpu-native-ab", "cpu", {"threads": threads, "rounds": rounds, "frames": frames,
                                                  "width": w, "height": h, "records": rows}, md, args.out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
