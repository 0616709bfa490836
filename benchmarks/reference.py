"""Full-resolution reference path: G-buffer + shading + tone map ms per scene and resolution.

python benchmarks/reference.py --device cuda:0      (writes results/reference-cuda.json and .md)
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import SHARED_SCENES, base_parser, md_table, time_ms, write_results  # noqa: E402


def main():
    p = base_parser(__doc__)
    p.add_argument("--scenes", default="cornell,city,bunny")
    args = p.parse_args()
    import foveawarp as fw

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    sizes = [(160, 90)] if args.quick else [(1920, 1080), (3840, 2160)]
    repeats = args.repeats or (3 if args.quick else 20)
    rows = []
    for name in args.scenes.split(","):
        if args.quick and name == "city":
            continue
        try:
            scene = fw.load_scene(name)
        except ValueError as e:
            print(f"skip {name}: {e}")
            continue
        for w, h in sizes:
            loop = fw.FrameLoop(scene, w, h, device=dev, timing=False)
            cam = scene.camera
            loop.render_reference(cam)  # compile + warm
            g = time_ms(lambda: loop._gbuffer(cam, cam), dev, repeats, args.warmup)
            s = time_ms(lambda: loop.shade_full(cam), dev, repeats, args.warmup)
            ao = time_ms(lambda: loop.shade_full(cam, ao_samples=8), dev, repeats, args.warmup)
            t = time_ms(lambda: loop._tonemap(loop.radiance, loop.image), dev, repeats, args.warmup)
            f = time_ms(lambda: loop.render_reference(cam), dev, repeats, args.warmup)
            rows.append({"scene": scene.name, "triangles": scene.num_triangles, "resolution": f"{w}x{h}",
                         "gbuffer_ms": g["median_ms"], "shade_ms": s["median_ms"],
                         "shade_ao8_ms": ao["median_ms"], "tonemap_ms": t["median_ms"],
                         "frame_ms": f["median_ms"]})
            print(rows[-1], flush=True)
    cols = ["scene", "triangles", "resolution", "gbuffer_ms", "shade_ms", "shade_ao8_ms", "tonemap_ms",
            "frame_ms"]
    table = md_table(rows, cols)
    print(table)
    write_results("reference", dev, {"rows": rows, "repeats": repeats,
                                     "note": "frame_ms = render_reference incl. host-side launch overhead and "
                                             "one synchronize; shading = direct light with shadow rays"},
                  table, args.out)


if __name__ == "__main__":
    main()
