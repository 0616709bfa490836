"""Quality when the cost policy switches from full resolution back to foveation (session 14).

Since 316413c a foveated frame that follows a full-resolution one takes that frame as its history (a temporal
resolve of it with every pixel traced) instead of a camera cut. This renders, per scene x size x shading, two loops
along the scene's camera path with a moving gaze: both trace every pixel for ``--before`` frames
(``policy="full"``), then render foveated frames (``policy="foveated"``) for ``--after`` frames; one takes the
seeded history (the default), the other is told ``cut=True`` on its first foveated frame (what the loop did
before). Per-frame PSNR and foveal PSNR against ``render_reference`` of the same camera, time and gaze; the mean
and min over the foveated frames, and the first foveated frame on its own.

    python benchmarks/switch_history.py --device cuda:0 --sizes 1920x1080 --scenes cornell,city,bunny
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import (base_parser, checked_shadings_sizes, md_table, scenes_present,  # noqa: E402
                               shading_config, write_results)
from benchmarks.frame import _fovea_key, _metric_fn, _summ, gaze_path  # noqa: E402

import foveawarp as fw  # noqa: E402


def run_case(scene, w, h, shading, dev, before, after, metric) -> dict:
    cfg = shading_config(fw, shading)
    loops = {k: fw.FrameLoop(scene, w, h, config=cfg, device=dev, policy="full", timing=False)
             for k in ("seeded", "cut")}
    ref = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False)
    n = before + after
    series = {k: [] for k in loops}
    fovea = {k: [] for k in loops}
    seeded_flags = []
    for i in range(n):
        t = i / 30.0
        g = gaze_path(i, n, w, h)
        if i == before:
            for lp in loops.values():
                lp.policy = "foveated"
        r = ref.render_reference(scene.camera_at(t), time=t, gaze_px=g)
        for k, lp in loops.items():
            f = lp.render(scene.camera_at(t), gaze_px=g, time=t, cut=(k == "cut" and i == before))
            if i >= before:
                m = metric(f.image, r.image, g, scene.camera.fov_y_deg)
                series[k].append(m["psnr"])
                fovea[k].append(_fovea_key(m))
                if k == "seeded":
                    seeded_flags.append(bool(f.stats["history_seeded"]))
    row = {"scene": scene.name, "width": w, "height": h, "shading": shading, "before": before, "after": after,
           "seeded_first_frame": seeded_flags[0], "seeded_later_frames": any(seeded_flags[1:])}
    for k in loops:
        row[f"{k}_psnr"] = _summ(series[k])
        row[f"{k}_fovea_psnr"] = _summ(fovea[k])
        row[f"{k}_psnr_series"] = series[k]
        row[f"{k}_first_psnr"] = series[k][0]
    return row


def main(argv=None) -> None:
    p = base_parser(__doc__.split("\n")[0])
    p.add_argument("--scenes", default="cornell,city,bunny")
    p.add_argument("--sizes", default="1920x1080")
    p.add_argument("--shadings", default="default,ao8")
    p.add_argument("--before", type=int, default=6, help="full-resolution frames before the switch (>= 1)")
    p.add_argument("--after", type=int, default=24, help="foveated frames from the switch on (>= 1)")
    args = p.parse_args(argv)
    for name in ("before", "after"):
        if getattr(args, name) < 1:
            p.error(f"--{name} must be an integer >= 1, got {getattr(args, name)}")
    shadings, sizes = checked_shadings_sizes(p, args)
    dev = wp.get_device(args.device)
    before, after = (args.before, args.after) if not args.quick else (2, 3)
    if args.quick:
        sizes = [(64, 36)]
    metric, metric_kind = _metric_fn(fast=not dev.is_cuda)
    rows = []
    for scene in scenes_present(fw, args.scenes):
        for w, h in sizes:
            for shading in shadings:
                row = run_case(scene, w, h, shading, dev, before, after, metric)
                rows.append(row)
                print({k: v for k, v in row.items() if not k.endswith("_series")}, flush=True)
    flat = [{**r, "seeded_first": r["seeded_first_psnr"], "cut_first": r["cut_first_psnr"],
             "seeded_mean": r["seeded_psnr"]["mean"], "cut_mean": r["cut_psnr"]["mean"],
             "seeded_min": r["seeded_psnr"]["min"], "cut_min": r["cut_psnr"]["min"]} for r in rows]
    cols = ["scene", "width", "height", "shading", "seeded_first", "cut_first", "seeded_mean", "cut_mean",
            "seeded_min", "cut_min"]
    md = (f"## Switching from full resolution to foveation: seeded history against a cut, {dev.alias}\n\n"
          f"PSNR in dB against render_reference ({metric_kind}); {before} full frames, then {after} foveated "
          f"frames (first = the switch frame; mean and min over the {after}).\n\n" + md_table(flat, cols))
    print(md)
    write_results("switch-history", dev, {"rows": rows, "metric": metric_kind}, md, args.out)


if __name__ == "__main__":
    main()
