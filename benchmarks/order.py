"""Thread order of the per-pixel ray launches: the G-buffer's primary rays and the full-resolution shading (shadow
and AO rays) with each warp on a block of pixels (``kernels/order.py``) against the plain (H, W) launch (a warp
on 32 pixels of a row).

    python benchmarks/order.py --device cuda:0 [--scenes cornell,eyechart,bunny,city] [--sizes 1920x1080,3840x2160]
                               [--widths 0,4,8,16,32] [--shadings default,ao8]

Per scene x size x block width: the G-buffer launch and the full shading launch, each timed alone (synchronized
wall time around the launch, median of ``--repeats``), on the scene camera. Width 0 is the (H, W) launch; 32 is
a 32 x 1 block (the row order, padded to whole blocks). Each order gives the same values (tests/test_order.py),
so only the time is reported. Writes benchmarks/results/order-<device>.{json,md}.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import (base_parser, checked_shadings_sizes, md_table, scenes_present,  # noqa: E402
                                shading_config, time_ms, write_results)


def main(argv=None) -> None:
    p = base_parser(__doc__.split("\n\n")[0])
    p.add_argument("--scenes", default="cornell,eyechart,bunny,city")
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--widths", default="0,4,8,16,32", help="block widths (0: the (H, W) launch)")
    p.add_argument("--shadings", default="default,ao8")
    args = p.parse_args(argv)
    import foveawarp as fw
    from foveawarp._util import ORDER_WIDTHS
    from foveawarp.stages.gbuffer import GBufferStage
    from foveawarp.stages.shade import ShadeStage

    shadings, sizes = checked_shadings_sizes(p, args)
    try:
        widths = [int(v) for v in args.widths.split(",") if v]
        if not widths or any(v != 0 and v not in ORDER_WIDTHS for v in widths):
            raise ValueError
    except ValueError:
        p.error(f"--widths must be a comma list of 0 and {ORDER_WIDTHS}, got {args.widths!r}")
    if args.quick:
        sizes = [(96, 54)]
    repeats = args.repeats or (3 if args.quick else 30)
    dev = wp.get_device(args.device)
    saved = GBufferStage.order_width, ShadeStage.order_width
    rows = []
    try:
        for scene in scenes_present(fw, args.scenes):
            for w, h in sizes:
                for shading in shadings:
                    for bw in widths:
                        GBufferStage.order_width = ShadeStage.order_width = bw
                        loop = fw.FrameLoop(scene, w, h, config=shading_config(fw, shading), device=dev,
                                            graph=False, timing=False)
                        cam = scene.camera
                        loop.render_reference(cam)
                        loop.upload_shade_params(cam)
                        g = time_ms(lambda: loop.gbuffer_stage.run(loop.gbuffer, cam, cam), dev, repeats,
                                    args.warmup)
                        s = time_ms(lambda: loop.shade.full(loop.gbuffer, loop.radiance, loop.radiance_stoch),
                                    dev, repeats, args.warmup)
                        row = {"scene": scene.name, "width": w, "height": h, "shading": shading,
                               "block": f"{bw}x{32 // bw}" if bw else "row (H, W launch)", "block_width": bw,
                               "gbuffer_ms": g["median_ms"], "shade_full_ms": s["median_ms"]}
                        rows.append(row)
                        print(f"{scene.name} {w}x{h} {shading} {row['block']}: gbuffer {g['median_ms']:.3f} ms, "
                              f"shade {s['median_ms']:.3f} ms", flush=True)
    finally:
        GBufferStage.order_width, ShadeStage.order_width = saved
    cols = ["scene", "width", "height", "shading", "block", "gbuffer_ms", "shade_full_ms"]
    md = (f"## Thread order of the ray launches ({dev}; median of {repeats} synchronized launches, scene camera)\n\n"
          + md_table(rows, cols))
    path = write_results("order", dev, {"repeats": repeats, "records": rows}, md, args.out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
