"""The scene BVH: build time and tracing time per constructor and leaf size (``Scene.bvh_constructor`` /
``Scene.bvh_leaf_size``, ``foveawarp.scene.resolve_bvh``).

    python benchmarks/bvh.py --device cuda:0 [--scenes cornell,eyechart,earth,bunny,spot,teapot,nefertiti,ogre,city]
                             [--size 3840x2160] [--configs auto,sah-4,sah-2,cubql,cubql-2,lbvh-2]

Per scene x configuration ("ctor" or "ctor-leaf"; "auto" = the device's default): the ``wp.Mesh`` build (median of
3, synchronized), the G-buffer launch, and the full-resolution shading launch with default shading and with 8 AO
rays (synchronized wall time, median of ``--repeats``, scene camera). The reference image of each configuration
is compared with the first configuration's: a BVH changes only which of two faces at the same distance a ray
reports (shared edges), so a few pixels may differ. Writes benchmarks/results/bvh-<device>.{json,md}.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, scenes_present, shading_config, time_ms, write_results  # noqa

DEFAULT_SCENES = "cornell,eyechart,earth,bunny,spot,teapot,nefertiti,ogre,city"


def parse_configs(p, text: str, opt: str = "--configs") -> list:
    from foveawarp.scene import BVH_CONSTRUCTORS, BVH_MAX_LEAF

    out = []
    for item in [v for v in text.split(",") if v]:
        ctor, _, leaf = item.partition("-")
        dash = "-" in item
        if ctor not in BVH_CONSTRUCTORS or (dash and not (leaf.isdigit() and 1 <= int(leaf) <= BVH_MAX_LEAF)):
            p.error(f"{opt} items must be ctor or ctor-leaf with ctor in {list(BVH_CONSTRUCTORS)} and leaf in "
                    f"[1, {BVH_MAX_LEAF}], got {item!r}")
        out.append((ctor, int(leaf) if leaf else None))
    if not out:
        p.error(f"{opt} is empty")
    return out


def main(argv=None) -> None:
    p = base_parser(__doc__.split("\n\n")[0])
    p.add_argument("--scenes", default=DEFAULT_SCENES)
    p.add_argument("--size", default="3840x2160")
    p.add_argument("--configs", default="auto,sah-4,sah-2,cubql,cubql-2,lbvh-2")
    args = p.parse_args(argv)
    import foveawarp as fw

    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
        if w < 1 or h < 1:
            raise ValueError
    except ValueError:
        p.error(f"--size must be WxH with positive integers, got {args.size!r}")
    configs = parse_configs(p, args.configs)
    if args.quick:  # the smoke-test size, whatever --size says
        w, h = 96, 54
    repeats = args.repeats or (3 if args.quick else 15)
    dev = wp.get_device(args.device)
    rows = []
    for scene in scenes_present(fw, args.scenes):  # a freshly loaded scene each: its BVH fields are ours to set
        first = None
        pts = wp.array(scene.vertices, dtype=wp.vec3, device=dev)
        idx = wp.array(scene.faces.reshape(-1), dtype=wp.int32, device=dev)
        for ctor, leaf in configs:
            scene.bvh_constructor, scene.bvh_leaf_size = ctor, leaf
            row = {"scene": scene.name, "triangles": int(len(scene.faces)), "width": w, "height": h,
                   "config": ctor + (f"-{leaf}" if leaf else "")}
            for shading in ("default", "ao8"):
                loop = fw.FrameLoop(scene, w, h, config=shading_config(fw, shading), device=dev, graph=False,
                                    timing=False)
                built = (loop.dscene.bvh_constructor, loop.dscene.bvh_leaf_size)  # after any fallback
                cam = scene.camera
                loop.render_reference(cam)
                if shading == "default":
                    img = loop.image.numpy()
                    first = img if first is None else first
                    d = np.abs(img - first).max(axis=-1)
                    row["pixels_differ_from_first"] = int((d > 0).sum())
                    row["max_abs_diff_from_first"] = float(d.max())
                loop.upload_shade_params(cam)
                g = time_ms(lambda: loop.gbuffer_stage.run(loop.gbuffer, cam, cam), dev, repeats, args.warmup)
                s = time_ms(lambda: loop.shade.full(loop.gbuffer, loop.radiance, loop.radiance_stoch), dev,
                            repeats, args.warmup)
                if shading == "default":
                    row["gbuffer_ms"] = g["median_ms"]
                row[f"shade_{shading}_ms"] = s["median_ms"]
                del loop
            bt = []
            for _ in range(3):  # the build of the tree the loops got
                wp.synchronize_device(dev)
                t0 = time.perf_counter()
                wp.Mesh(points=pts, indices=idx, bvh_constructor=built[0], bvh_leaf_size=built[1])
                wp.synchronize_device(dev)
                bt.append((time.perf_counter() - t0) * 1e3)
            row.update(constructor=built[0], leaf_size=built[1] if built[1] is not None else "Warp default",
                       build_ms=statistics.median(bt))
            rows.append(row)
            print(f"{scene.name} {row['config']}: build {row['build_ms']:.2f} ms, gbuffer {row['gbuffer_ms']:.3f}, "
                  f"shade {row['shade_default_ms']:.3f} / ao8 {row['shade_ao8_ms']:.3f} ms, "
                  f"{row['pixels_differ_from_first']} px differ", flush=True)
    cols = ["scene", "triangles", "config", "constructor", "leaf_size", "build_ms", "gbuffer_ms", "shade_default_ms",
            "shade_ao8_ms", "pixels_differ_from_first", "max_abs_diff_from_first"]
    md = (f"## Scene BVH choices ({dev}, {w}x{h}; launches: median of {repeats} synchronized runs, scene camera; "
          f"build: median of 3)\n\n" + md_table(rows, cols))
    path = write_results("bvh", dev, {"repeats": repeats, "width": w, "height": h, "records": rows}, md, args.out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
