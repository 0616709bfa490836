"""The split temporal resolve (``TemporalStage.split``) against the whole resolve, with the full-resolution
reference, in one run.

Per scene x size x shading: three FrameLoops of the same scene, size and configuration (the reference,
``policy="full"``; the foveated frame with the split resolve; the foveated frame with the whole resolve,
``temporal.split = False``) take turns frame by frame in a new order every frame along the scene's camera path with a
moving gaze (``frame.py``'s ``_timed_interleaved``: warm-up, synchronized frames, medians). ``--rounds`` repeats the
whole interleaved run. The foveated frames are also compared with each other on a shared frame (their images must be
equal byte for byte: the split changes no value), and the records say so.

python benchmarks/split_resolve.py --device cuda:0 [--scenes ...] [--sizes 1920x1080,3840x2160]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import (base_parser, checked_shadings_sizes, md_table, scenes_present,  # noqa: E402
                                shading_config, write_results)
from benchmarks.frame import _timed_interleaved, gaze_path  # noqa: E402

SCENES = "bunny,nefertiti,city,spot,ogre,teapot,cornell"


def case(fw, scene, w, h, dev, cfg, frames: int, rounds: int, history_blocks=(0,)) -> dict:
    """Median ms of the reference, the whole resolve's foveated frame and the split one's with each history-half
    launch shape (``TemporalStage.HISTORY_BLOCKS_PER_SM``) (per round), and whether the foveated frames' images agree
    on the frame after their last timed one."""
    loops = {"full": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="full"),
             "whole": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")}
    for b in history_blocks:
        loops[f"split{b}"] = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
    for k, loop in loops.items():
        if k != "full":
            loop._ensure_foveated_stages()  # made on a loop's first foveated frame: here, to set the split
            # the split is the default on CUDA; forced so that a CPU run compares the two too
            loop.temporal.split = k != "whole"
            if k != "whole":
                loop.temporal.HISTORY_BLOCKS_PER_SM = int(k[5:])
    first = f"split{history_blocks[0]}"
    per = []
    for r in range(rounds):
        warm = {k: 8 if r == 0 else 2 for k in loops}
        per.append(_timed_interleaved(loops, scene, w, h, frames, warm, seed=r))
    # one more frame of each foveated loop at the same camera, time and gaze: their images must be equal (the same
    # history behind them: both rendered the same frames)
    t = 1.0
    imgs = [loops[k].render(scene.camera_at(t), gaze_px=gaze_path(3, 10, w, h), time=t).image.numpy().copy()
            for k in loops if k != "full"]  # copies: on the CPU numpy() is a view of the loop's image
    # the sampling rate of the timed frames: the median over a timing-free replay of the path's frames 8-15
    rate = []
    for i in range(16):
        f = loops[first].render(scene.camera_at(i / 30.0), gaze_px=gaze_path(i, 16, w, h), time=i / 30.0)
        if i >= 8:
            rate.append(float(f.stats["sampling_rate"]))
    out = {k: [p[k] for p in per] for k in loops}
    out.update(ref_ms=float(np.median(out["full"])), whole_ms=float(np.median(out["whole"])),
               split_ms={b: float(np.median(out[f"split{b}"])) for b in history_blocks},
               images_equal=bool(all(np.array_equal(imgs[0], im) for im in imgs[1:])),
               sampling_rate=float(np.median(rate)))
    out["speedup_whole"] = out["ref_ms"] / out["whole_ms"]
    out["split_vs_whole"] = {b: v / out["whole_ms"] for b, v in out["split_ms"].items()}
    out["speedup_split"] = {b: out["ref_ms"] / v for b, v in out["split_ms"].items()}
    return out


def main(argv=None) -> int:
    p = base_parser(__doc__.splitlines()[0])
    p.add_argument("--scenes", default=SCENES)
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--shadings", default="default,ao8")
    p.add_argument("--frames", type=int, default=50, help="timed frames per loop and round")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--strategy", default="auto", choices=["auto", "tile", "scan"],
                   help="ReorderConfig.strategy (auto: tile on CUDA; the split needs a flat list: tile or scan)")
    p.add_argument("--history-blocks", default="0",
                   help="comma list of TemporalStage.HISTORY_BLOCKS_PER_SM values, a split loop each (0: a thread "
                        "per pixel)")
    p.add_argument("--name", default="split-resolve")
    args = p.parse_args(argv)
    shadings, sizes = checked_shadings_sizes(p, args)
    if args.frames < 1:
        p.error(f"--frames must be >= 1, got {args.frames}")
    if args.rounds < 1:
        p.error(f"--rounds must be >= 1, got {args.rounds}")
    try:
        hb = [int(v) for v in args.history_blocks.split(",") if v]
        if not hb or any(not 0 <= v <= 64 for v in hb):
            raise ValueError
    except ValueError:
        p.error(f"--history-blocks must be a comma list of integers in [0, 64], got {args.history_blocks!r}")
    if args.quick:
        sizes, args.frames, args.rounds = [(64, 40)], 3, 1
    import foveawarp as fw

    dev = wp.get_device(args.device)
    records, rows = [], []
    for scene in scenes_present(fw, args.scenes):
        for w, h in sizes:
            for shading in shadings:
                cfg = shading_config(fw, shading).with_(reorder={"strategy": args.strategy})
                r = case(fw, scene, w, h, dev, cfg, args.frames, args.rounds, hb)
                rec = {"device": dev.alias, "scene": scene.name, "width": w, "height": h, "shading": shading,
                       "strategy": args.strategy, **r}
                records.append(rec)
                row = {"scene": scene.name, "size": f"{w}x{h}", "shading": shading, "rate": r["sampling_rate"],
                       "ref ms": r["ref_ms"], "whole ms": r["whole_ms"], "speed-up whole": r["speedup_whole"]}
                for b in hb:
                    row[f"split ms ({b}/SM)"] = r["split_ms"][b]
                    row[f"split / whole ({b}/SM)"] = r["split_vs_whole"][b]
                    row[f"speed-up split ({b}/SM)"] = r["speedup_split"][b]
                row["images equal"] = r["images_equal"]
                rows.append(row)
                print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in rows[-1].items()}, flush=True)
    table = md_table(rows, list(rows[0]) if rows else ["scene"])
    head = (f"Split temporal resolve against the whole resolve ({args.rounds} rounds of {args.frames} interleaved "
            f"frames; medians), with the full-resolution reference of the same run\n\n")
    write_results(args.name, dev, {"records": records, "frames": args.frames, "rounds": args.rounds},
                  head + table, args.out)
    print(table)
    return 0 if all(r["images_equal"] for r in records) else 1


if __name__ == "__main__":
    sys.exit(main())
