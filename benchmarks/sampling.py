"""Sampling-map stage benchmark: foveation probability + saliency + binarization + cache test.

Times ``SamplingStage.run`` (Lab prepass, fused per-pixel pass, tile pass) on cornell G-buffers at 1080p and
4K (``--quick``: 160 x 90), steady state (second frame on: the cache test runs), median of >= 20 synchronized
repeats, plus the per-kernel split. Then prints the sampling rate of the built-in scenes at default settings.

    python benchmarks/sampling.py --device cuda:0
    python benchmarks/sampling.py --device cpu --quick --out bench-out
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, time_ms, write_results  # noqa: E402
import foveawarp as fw  # noqa: E402
from foveawarp._util import get_device  # noqa: E402
from foveawarp.kernels.sampling import sampling_map_kernel  # noqa: E402
from foveawarp.kernels.saliency import lab_kernel  # noqa: E402
from foveawarp.stages.sampling import SamplingStage, launch_tile_pass  # noqa: E402


def bench_size(w: int, h: int, dev, repeats: int, warmup: int) -> list:
    loop = fw.FrameLoop("cornell", w, h, device=dev, timing=False, policy="foveated")
    cam = loop.scene.camera
    stage = SamplingStage(w, h, fw.Config(), device=dev)
    gaze = (0.5 * w, 0.5 * h)
    loop.render_reference(cam)
    stage.run(loop.gbuffer, cam, gaze, 0, moving=False, first_frame=True)
    stage.end_frame(loop.gbuffer)
    loop.render_reference(cam)  # second frame: reprojection UVs and history exist
    g = loop.gbuffer
    state = {"f": 1}

    def run(moving):
        def fn():
            stage.run(g, cam, gaze, state["f"], moving=moving, first_frame=False, eye_prev=cam.eye)
            state["f"] += 1
        return fn

    rows = []
    for label, moving in (("run (static)", False), ("run (moving: velocity term)", True)):
        t = time_ms(run(moving), dev, repeats, warmup)
        rows.append({"size": f"{w}x{h}", "what": label, **t})
    stats = stage.stats()
    # the split, launched exactly as run() does
    split = {
        "lab prepass": lambda: fw.parallel.launch(lab_kernel, dim=(h, w), inputs=[g.albedo],
                                                  outputs=[stage._lab_array()], device=dev),
        "fused pass": lambda: fw.parallel.launch(
            sampling_map_kernel, dim=(h, w),
            inputs=[stage.params, stage.frame_params, stage.ranks, stage.lab, g.normal, g.depth, g.hit,
                    g.position, g.reproj_uv, g.prev_dist, stage.depth_prev, stage.valid_prev, 0, g.face,
                    stage._no_face_lab, 0],
            outputs=[stage._dummy_map, stage._dummy_map, stage.sample_map, stage.cache_hit, stage.prev_index,
                     stage.tile_counts],
            device=dev),
        "tile pass": lambda: launch_tile_pass(stage.ranks, stage.params, stage.frame_params, stage.tiles,
                                              stage.sample_map, stage.cache_hit, stage.num_samples,
                                              stage.num_cache_hits, dev),
    }
    for label, fn in split.items():
        rows.append({"size": f"{w}x{h}", "what": label, **time_ms(fn, dev, repeats, warmup)})
    for r in rows:
        r["sampling_rate"] = stats["sampling_rate"]
        r["cache_hit_rate"] = stats["cache_hit_rate"]
    return rows


def scene_rates(names, w: int, h: int, dev) -> list:
    rows = []
    for name in names:
        loop = fw.FrameLoop(name, w, h, device=dev, timing=False, policy="foveated")
        cam = loop.scene.camera
        loop.render_reference(cam)
        stage = SamplingStage(w, h, fw.Config(), device=dev)
        stage.run(loop.gbuffer, cam, (0.5 * w, 0.5 * h), 0, moving=False, first_frame=True)
        s = stage.stats()
        rows.append({
            "scene": name, "size": f"{w}x{h}", "sampling_rate": s["sampling_rate"],
            "mean_foveation_p": float(stage.probability.numpy().mean()),
            "mean_saliency": float(stage.saliency.numpy().mean()),
            "hit_fraction": float(loop.gbuffer.hit.numpy().mean()),
        })
    return rows


def main(argv=None):
    p = base_parser(__doc__.splitlines()[0])
    args = p.parse_args(argv)
    dev = get_device(args.device)
    repeats = args.repeats or 20
    sizes = [(160, 90)] if args.quick else [(1920, 1080), (3840, 2160)]
    rows = []
    for w, h in sizes:
        rows += bench_size(w, h, dev, repeats, args.warmup)
    rate_size = (160, 90) if args.quick else (1920, 1080)
    names = ["cornell", "eyechart", "earth"] + ([] if args.quick else ["city"])
    rates = scene_rates(names, *rate_size, dev)

    t1 = md_table(rows, ["size", "what", "median_ms", "p10_ms", "p90_ms", "repeats", "sampling_rate",
                         "cache_hit_rate"])
    t2 = md_table(rates, ["scene", "size", "sampling_rate", "mean_foveation_p", "mean_saliency", "hit_fraction"])
    print(f"device: {dev.alias}\n")
    print(t1)
    print(t2)
    write_results("sampling", dev, {"timings": rows, "scene_rates": rates, "quick": bool(args.quick)},
                  t1 + "\n" + t2, out=args.out)


if __name__ == "__main__":
    main()
