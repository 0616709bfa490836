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


def case(fw, scene, w, h, dev, cfg, frames: int, rounds: int) -> dict:
    """Median ms of the reference, the split and the whole resolve's foveated frames (per round), and whether the
    two foveated frames' images agree on the frame after their last timed one."""
    loops = {"full": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="full"),
             "split": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated"),
             "whole": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")}
    for k in ("split", "whole"):
        loops[k]._ensure_foveated_stages()  # made on a loop's first foveated frame: here, to set the split
    loops["split"].temporal.split = True  # the default on CUDA; forced so that a CPU run compares the two too
    loops["whole"].temporal.split = False
    per = []
    for r in range(rounds):
        warm = {k: 8 if r == 0 else 2 for k in loops}
        per.append(_timed_interleaved(loops, scene, w, h, frames, warm, seed=r))
    # one more frame of each foveated loop at the same camera, time and gaze: their images must be equal (the same
    # history behind them: both rendered the same frames)
    t = 1.0
    imgs = [loops[k].render(scene.camera_at(t), gaze_px=gaze_path(3, 10, w, h), time=t).image.numpy().copy()
            for k in ("split", "whole")]  # copies: on the CPU numpy() is a view of the loop's image
    rate = float(loops["split"].render(scene.camera_at(t), gaze_px=gaze_path(3, 10, w, h), time=t)
                 .stats["sampling_rate"])
    out = {k: [p[k] for p in per] for k in loops}
    out.update(ref_ms=float(np.median(out["full"])), split_ms=float(np.median(out["split"])),
               whole_ms=float(np.median(out["whole"])), images_equal=bool(np.array_equal(imgs[0], imgs[1])),
               sampling_rate=rate)
    out["split_vs_whole"] = out["split_ms"] / out["whole_ms"]
    out["speedup_split"] = out["ref_ms"] / out["split_ms"]
    out["speedup_whole"] = out["ref_ms"] / out["whole_ms"]
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
    p.add_argument("--name", default="split-resolve")
    args = p.parse_args(argv)
    shadings, sizes = checked_shadings_sizes(p, args)
    if args.frames < 1:
        p.error(f"--frames must be >= 1, got {args.frames}")
    if args.rounds < 1:
        p.error(f"--rounds must be >= 1, got {args.rounds}")
    if args.quick:
        sizes, args.frames, args.rounds = [(64, 40)], 3, 1
    import foveawarp as fw

    dev = wp.get_device(args.device)
    records, rows = [], []
    for scene in scenes_present(fw, args.scenes):
        for w, h in sizes:
            for shading in shadings:
                cfg = shading_config(fw, shading).with_(reorder={"strategy": args.strategy})
                r = case(fw, scene, w, h, dev, cfg, args.frames, args.rounds)
                rec = {"device": dev.alias, "scene": scene.name, "width": w, "height": h, "shading": shading,
                       "strategy": args.strategy, **r}
                records.append(rec)
                rows.append({"scene": scene.name, "size": f"{w}x{h}", "shading": shading,
                             "rate": r["sampling_rate"], "ref ms": r["ref_ms"], "split ms": r["split_ms"],
                             "whole ms": r["whole_ms"], "split / whole": r["split_vs_whole"],
                             "speed-up split": r["speedup_split"], "speed-up whole": r["speedup_whole"],
                             "images equal": r["images_equal"]})
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
