"""What does each stage of a frame cost on its own?

Parts (``--parts``, comma list; default all):

* ``sampling``: ``SamplingStage.run`` (Lab prepass, fused per-pixel pass, tile pass) on cornell G-buffers, steady
  state (second frame on: the cache test runs), static and moving, with the per-kernel split; the sampling rate
  of a few built-in scenes at default settings.
* ``reconstruct``: the JFA variants (time, wrong-distance pixels against SciPy's EDT), bounded against exact
  Sibson (time, max abs difference) and the stage's per-frame run (JFA + bounded Sibson) on uniform random masks
  and masks with the block-4 guarantee; the default stage on a sparse (~25 %) and a mostly-filled (~95 %) mask
  with its captured CUDA graph's replay and per-kernel GPU times (CUDA).
* ``bvh``: per scene and BVH constructor / leaf size: the ``wp.Mesh`` build (median of 3) and the G-buffer and
  full-resolution shading launches (default shading and 8 AO rays), traced rays per second.
* ``metrics``: ``region_metrics_device`` (PSNR + SSIM per region) against the host ``region_metrics``, on
  synthetic frames (a gradient with texture and the same plus noise, sigma 0.05); their largest difference.
* ``reference``: the full-resolution reference path per scene: G-buffer, shading, shading with 8 AO rays, tone
  map and the whole ``render_reference``.
* ``textures``: what textures cost: per textured scene (``--textured-scenes``), the full-resolution G-buffer and
  shading with its materials and textures, and of the same geometry without them (each face its mean base
  colour: the untextured kernels).

Medians of ``--repeats`` synchronized runs after ``--warmup``. Writes stages-<tag>.json / .md.
"""

from __future__ import annotations

import dataclasses
import math
import statistics
import sys
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import (base_parser, md_table, parse_sizes, progress, scenes_present,  # noqa: E402
                                shading_config, time_ms, write_results)
from benchmarks._kernel_timing import graph_time, kernel_times  # noqa: E402
from benchmarks._masks import bench_masks  # noqa: E402

import foveawarp as fw  # noqa: E402
from foveawarp.config import JFA_VARIANTS, ReconstructionConfig  # noqa: E402
from foveawarp.kernels.sampling import sampling_map_kernel  # noqa: E402
from foveawarp.kernels.saliency import lab_kernel  # noqa: E402
from foveawarp.stages.reconstruct import ReconstructStage, jfa_start_step_for_block, sibson_window_for_block  # noqa
from foveawarp.stages.sampling import SamplingStage, launch_tile_pass  # noqa: E402

# the textures part has its own canonical run (tools/canonical.sh "textures": stages-textures-h200)
CANONICAL = ("python benchmarks/stages.py --device cuda:0 --out benchmarks/results --tag h200 "
             "--parts sampling,reconstruct,bvh,metrics,reference --sizes 1920x1080,3840x2160 "
             "--scenes cornell,city,bunny,nefertiti")
PARTS = ("sampling", "reconstruct", "bvh", "metrics", "reference", "textures")
BLOCK = 4


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


def uniform_mask(h, w, density, rng):
    return (rng.random((h, w)) < density).astype(np.uint8)


def block_mask(h, w, k, density, rng):
    """One random seed per aligned k x k tile (partial edge tiles too), plus uniform extras up to ``density``."""
    extra = max(0.0, (density - 1.0 / (k * k)) / (1.0 - 1.0 / (k * k)))
    m = rng.random((h, w)) < extra
    ty = np.arange(0, h, k)
    tx = np.arange(0, w, k)
    oy = (rng.random((ty.size, tx.size)) * np.minimum(k, h - ty)[:, None]).astype(int)
    ox = (rng.random((ty.size, tx.size)) * np.minimum(k, w - tx)[None, :]).astype(int)
    m[ty[:, None] + oy, tx[None, :] + ox] = True
    return m.astype(np.uint8)


def exact_d2(mask):
    from scipy import ndimage

    h, w = mask.shape
    _, (iy, ix) = ndimage.distance_transform_edt(mask == 0, return_indices=True)
    yy, xx = np.mgrid[0:h, 0:w]
    return (iy - yy).astype(np.int64) ** 2 + (ix - xx).astype(np.int64) ** 2


def nearest_d2(nearest):
    h, w = nearest.shape[:2]
    yy, xx = np.mgrid[0:h, 0:w]
    return (nearest[..., 1].astype(np.int64) - yy) ** 2 + (nearest[..., 0].astype(np.int64) - xx) ** 2


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


def frames(w, h, seed=3):
    """(img, ref) float32 (h, w, 3) frames in [0, 1]."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    u, v = xx / w, yy / h
    ref = np.stack([0.5 + 0.3 * np.sin(6.0 * u + 2.0 * c) * np.cos(4.0 * v - c) + 0.15 * np.sin(0.7 * xx + 0.3 * yy)
                    for c in range(3)], axis=2)
    img = ref + rng.normal(0.0, 0.05, ref.shape)
    return np.clip(img, 0, 1).astype(np.float32), np.clip(ref, 0, 1).astype(np.float32)


def max_abs_diff(host: dict, dev: dict) -> float:
    worst = 0.0
    for k, hv in host.items():
        dv = dev[k]
        if math.isfinite(hv) or math.isfinite(dv):
            worst = max(worst, abs(hv - dv) if math.isfinite(hv) and math.isfinite(dv) else math.inf)
    return worst

def part_sampling(args, dev, sizes, repeats):
    records = []
    for w, h in sizes:
        for r in bench_size(w, h, dev, repeats, args.warmup):
            records.append({"part": "sampling", "scene": "cornell", "width": w, "height": h, **r})
    rw, rh = sizes[0]
    for r in scene_rates([s.name for s in scenes_present(fw, args.scenes)], rw, rh, dev):
        records.append({"part": "sampling_rate", "width": rw, "height": rh, **r})
    md = ("## Sampling stage\n\n" + md_table([r for r in records if r["part"] == "sampling"],
                                               ["size", "what", "median_ms", "p10_ms", "p90_ms", "sampling_rate",
                                                "cache_hit_rate"])
          + "\n## Sampling rate at default settings\n\n"
          + md_table([r for r in records if r["part"] == "sampling_rate"],
                     ["scene", "size", "sampling_rate", "mean_foveation_p", "mean_saliency", "hit_fraction"]))
    return records, md


def part_reconstruct(args, dev, sizes, repeats):
    densities = [0.05, 0.30] if args.quick else [0.01, 0.05, 0.10, 0.30]
    warmup = 1 if args.quick else args.warmup
    rng = np.random.default_rng(0)
    J = sibson_window_for_block(BLOCK)
    s0 = jfa_start_step_for_block(BLOCK)
    records, jfa_rows, sib_rows, ovh_rows = [], [], [], []
    for w, h in sizes:
        color_in = wp.array(rng.random((h, w, 3)).astype(np.float32), dtype=wp.vec3, device=dev)
        out_b = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        out_e = wp.zeros((h, w), dtype=wp.vec3, device=dev)
        full = {v: ReconstructStage(w, h, ReconstructionConfig(jfa_variant=v, bounded_jfa_start=False), BLOCK, dev)
                for v in JFA_VARIANTS}
        bounded = ReconstructStage(w, h, ReconstructionConfig(), BLOCK, dev)  # the FrameLoop default
        exact = ReconstructStage(w, h, ReconstructionConfig(), BLOCK, dev, exact_sibson=True)
        for kind in ("uniform", "block4"):
            for dens in densities:
                mask_np = uniform_mask(h, w, dens, rng) if kind == "uniform" else block_mask(h, w, BLOCK, dens, rng)
                mask = wp.array(mask_np, dtype=wp.uint8, device=dev)
                seeds_pct = 100.0 * float(mask_np.mean())
                d_ref = exact_d2(mask_np)
                rec = {"part": "reconstruct", "scene": "synthetic mask", "width": w, "height": h, "mask": kind,
                       "density": dens, "seeds_pct": seeds_pct, "jfa": {}}
                variants = [(v, "full", full[v]) for v in JFA_VARIANTS]
                if kind == "block4":
                    variants.append(("1+jfa", f"bounded {s0}", bounded))
                for v, start, st in variants:
                    t = time_ms(lambda st=st: st.run_jfa(mask), dev, repeats, warmup)
                    st.run_jfa(mask)
                    d = nearest_d2(st.nearest.numpy())
                    wrong = 100.0 * float(np.count_nonzero(d != d_ref)) / d.size
                    rec["jfa"][f"{v}/{start}"] = {"ms": t["median_ms"], "wrong_pct": wrong, "passes": len(st.steps)}
                    jfa_rows.append({"size": f"{w}x{h}", "mask": kind, "seeds %": seeds_pct, "variant": v,
                                     "start": start, "passes": len(st.steps), "ms": t["median_ms"],
                                     "wrong %": f"{wrong:.5f}"})
                stage = bounded if kind == "block4" else full["1+jfa"]
                stage.run_jfa(mask)
                near = stage.nearest
                t_b = time_ms(lambda: bounded.run_interpolate(color_in, out_b, near), dev, repeats, warmup)
                t_e = time_ms(lambda: exact.run_interpolate(color_in, out_e, near), dev, max(3, repeats // 4),
                              min(warmup, 1))
                bounded.run_interpolate(color_in, out_b, near)
                exact.run_interpolate(color_in, out_e, near)
                diff = float(np.abs(out_b.numpy() - out_e.numpy()).max())
                t_run = time_ms(lambda: stage.run(color_in, mask, out_b), dev, repeats, warmup)
                rec.update(sibson_window=J, sibson_bounded_ms=t_b["median_ms"], sibson_exact_ms=t_e["median_ms"],
                           max_abs_diff=diff, stage_run_ms=t_run["median_ms"])
                records.append(rec)
                sib_rows.append({"size": f"{w}x{h}", "mask": kind, "seeds %": seeds_pct, "J": J,
                                 "bounded ms": t_b["median_ms"], "exact ms": t_e["median_ms"],
                                 "speed-up": t_e["median_ms"] / max(t_b["median_ms"], 1e-9),
                                 "max abs diff": f"{diff:.2e}", "stage run ms": t_run["median_ms"]})
        # the default stage as FrameLoop runs it, per kernel, on the frame loop's two typical masks
        for name, m in bench_masks(w, h, rng, BLOCK):
            mask = wp.array(m, dtype=wp.uint8, device=dev)
            run = lambda: bounded.run(color_in, mask, out_b)  # noqa: E731
            wall = time_ms(run, dev, repeats, warmup)
            g = graph_time(run, dev, repeats, warmup)
            k = kernel_times(run, dev, repeats, warmup)
            records.append({"part": "reconstruct_stage", "scene": "synthetic mask", "width": w, "height": h,
                            "mask": name, "seeds_pct": 100.0 * float(m.mean()), "run_ms": wall["median_ms"],
                            "graph_ms": g["graph_ms"], "gpu_ms": None if k is None else k["gpu_ms"],
                            "kernels": None if k is None else k["kernels"]})
            ovh_rows.append({"size": f"{w}x{h}", "mask": name, "seeds %": records[-1]["seeds_pct"],
                             "run ms": wall["median_ms"], "graph ms": "n/a" if g["graph_ms"] is None else g["graph_ms"],
                             "GPU kernels ms": "n/a" if k is None else k["gpu_ms"]})
    md = (f"## JFA (wrong % = pixels whose JFA distance exceeds SciPy's EDT)\n\n{md_table(jfa_rows)}\n"
          f"## Sibson: bounded gather (J={J}, block {BLOCK}) vs exact scatter, on the same 1+JFA map\n\n"
          f"{md_table(sib_rows)}\n## The default stage (1+JFA, bounded start, bounded Sibson)\n\n{md_table(ovh_rows)}")
    return records, md


def part_bvh(args, dev, sizes, repeats):
    configs = parse_configs(args._parser, args.bvh_configs, "--bvh-configs")
    w, h = sizes[-1]
    rows = []
    for scene in scenes_present(fw, args.scenes):  # a freshly loaded scene each: its BVH fields are ours to set
        first = None
        pts = wp.array(scene.vertices, dtype=wp.vec3, device=dev)
        idx = wp.array(scene.faces.reshape(-1), dtype=wp.int32, device=dev)
        for ctor, leaf in configs:
            scene.bvh_constructor, scene.bvh_leaf_size = ctor, leaf
            row = {"part": "bvh", "scene": scene.name, "triangles": int(len(scene.faces)), "width": w, "height": h,
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
                    row["pixels_differ_from_first"] = int((np.abs(img - first).max(axis=-1) > 0).sum())
                loop.upload_shade_params(cam)
                g = time_ms(lambda: loop.gbuffer_stage.run(loop.gbuffer, cam, cam), dev, repeats, args.warmup)
                s = time_ms(lambda: loop.shade.full(loop.gbuffer, loop.radiance, loop.radiance_stoch), dev,
                            repeats, args.warmup)
                if shading == "default":
                    row["gbuffer_ms"] = g["median_ms"]
                    row["primary_mrays_per_s"] = w * h / max(g["median_ms"], 1e-9) / 1e3
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
    cols = ["scene", "triangles", "config", "constructor", "leaf_size", "build_ms", "gbuffer_ms", "primary_mrays_per_s",
            "shade_default_ms", "shade_ao8_ms", "pixels_differ_from_first"]
    return rows, f"## Scene BVH choices ({w}x{h}, scene camera; build: median of 3)\n\n" + md_table(rows, cols)


def part_metrics(args, dev, sizes, repeats):
    from foveawarp import metrics

    fov = 60.0
    host_repeats = 1 if args.quick else 3
    rows = []
    for w, h in sizes:
        img, ref = frames(w, h)
        wi, wr = (wp.array(v, dtype=wp.vec3, device=dev) for v in (img, ref))
        gaze = (0.55 * w, 0.45 * h)
        hv = metrics.region_metrics(wi.numpy(), wr.numpy(), gaze, fov)  # also the host's warm-up (imports)
        t_dev = time_ms(lambda: metrics.region_metrics_device(wi, wr, gaze, fov), dev, repeats, args.warmup)
        t_psnr = time_ms(lambda: metrics.psnr_device(wi, wr), dev, repeats, args.warmup)
        t_ssim = time_ms(lambda: metrics.ssim_device(wi, wr), dev, repeats, args.warmup)
        t_host = time_ms(lambda: metrics.region_metrics(wi.numpy(), wr.numpy(), gaze, fov), dev, host_repeats, 0)
        dv = metrics.region_metrics_device(wi, wr, gaze, fov)
        rows.append({"part": "metrics", "scene": "synthetic gradient + noise (sigma 0.05)", "width": w, "height": h,
                     "resolution": f"{w}x{h}", "device_ms": t_dev["median_ms"], "psnr_device_ms": t_psnr["median_ms"],
                     "ssim_device_ms": t_ssim["median_ms"], "host_ms": t_host["median_ms"],
                     "speedup": t_host["median_ms"] / t_dev["median_ms"], "max_abs_diff": max_abs_diff(hv, dv),
                     "device_result": dv})
    cols = ["resolution", "device_ms", "psnr_device_ms", "ssim_device_ms", "host_ms", "speedup", "max_abs_diff"]
    return rows, "## Metrics on the device vs the host\n\n" + md_table(
        [{**r, "max_abs_diff": f"{r['max_abs_diff']:.1e}"} for r in rows], cols)


def part_reference(args, dev, sizes, repeats):
    rows = []
    for scene in scenes_present(fw, args.scenes):
        for w, h in sizes:
            loop = fw.FrameLoop(scene, w, h, device=dev, timing=False)
            cam = scene.camera
            loop.render_reference(cam)  # compile + warm
            view = loop._contexts.build(cam, cam, (w * 0.5, h * 0.5), loop.frame_index, loop._max_t(cam))
            g = time_ms(lambda: loop._gbuffer(view), dev, repeats, args.warmup)
            s = time_ms(lambda: loop.shade_full(cam), dev, repeats, args.warmup)
            ao = time_ms(lambda: loop.shade_full(cam, ao_samples=8), dev, repeats, args.warmup)
            t = time_ms(lambda: loop._tonemap(loop.radiance, loop.image), dev, repeats, args.warmup)
            f = time_ms(lambda: loop.render_reference(cam), dev, repeats, args.warmup)
            rows.append({"part": "reference", "scene": scene.name, "triangles": scene.num_triangles, "width": w,
                         "height": h, "resolution": f"{w}x{h}", "gbuffer_ms": g["median_ms"],
                         "shade_ms": s["median_ms"], "shade_ao8_ms": ao["median_ms"], "tonemap_ms": t["median_ms"],
                         "frame_ms": f["median_ms"]})
    cols = ["scene", "triangles", "resolution", "gbuffer_ms", "shade_ms", "shade_ao8_ms", "tonemap_ms", "frame_ms"]
    return rows, ("## Full-resolution reference (frame_ms: render_reference with its host work and one "
                  "synchronization)\n\n" + md_table(rows, cols))


def untextured(scene):
    """``scene`` without materials, textures or environment: the same geometry, lights and camera, each face its
    mean base colour (``Scene.face_albedo``), drawn by the untextured G-buffer and shading."""
    return dataclasses.replace(scene, name=f"{scene.name} (untextured)", materials=None, face_material=None,
                               uvs=None, uvs1=None, tangents=None, images=[], environment=None)


def part_textures(args, dev, sizes, repeats):
    rows = []
    for scene in scenes_present(fw, args.textured_scenes):
        for w, h in sizes:
            row = {"part": "textures", "scene": scene.name, "triangles": scene.num_triangles, "width": w,
                   "height": h, "resolution": f"{w}x{h}"}
            for kind, sc in (("textured", scene), ("untextured", untextured(scene))):
                loop = fw.FrameLoop(sc, w, h, device=dev, timing=False)
                cam = sc.camera
                loop.render_reference(cam)  # compile + warm
                view = loop._contexts.build(cam, cam, (w * 0.5, h * 0.5), loop.frame_index, loop._max_t(cam))
                row[f"gbuffer_{kind}_ms"] = time_ms(lambda: loop._gbuffer(view), dev, repeats,
                                                    args.warmup)["median_ms"]
                row[f"shade_{kind}_ms"] = time_ms(lambda: loop.shade_full(cam), dev, repeats,
                                                  args.warmup)["median_ms"]
            row["gbuffer_ratio"] = row["gbuffer_textured_ms"] / row["gbuffer_untextured_ms"]
            row["shade_ratio"] = row["shade_textured_ms"] / row["shade_untextured_ms"]
            rows.append(row)
    cols = ["scene", "triangles", "resolution", "gbuffer_textured_ms", "gbuffer_untextured_ms", "gbuffer_ratio",
            "shade_textured_ms", "shade_untextured_ms", "shade_ratio"]
    return rows, ("## Textures: the full-resolution G-buffer and shading with the scene's materials and textures "
                  "against the same geometry untextured (each face its mean base colour)\n\n" + md_table(rows, cols))


def main(argv=None):
    p = base_parser(__doc__, CANONICAL)
    p.add_argument("--parts", default=",".join(PARTS), help=f"comma list of {', '.join(PARTS)}")
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--scenes", default="cornell,city,bunny,nefertiti", help="scenes of the bvh / reference parts")
    p.add_argument("--textured-scenes", default="room,suzanne,wicker,barrel,milk-truck",
                   help="scenes of the textures part (those not found are skipped and named)")
    p.add_argument("--bvh-configs", default="auto,sah-4,sah-2,cubql,lbvh-2",
                   help="BVH constructors of the bvh part: ctor or ctor-leaf, comma list")
    args = p.parse_args(argv)
    args._parser = p
    parts = [s for s in args.parts.split(",") if s]
    if not parts or any(s not in PARTS for s in parts):
        p.error(f"--parts must be a comma list of {', '.join(PARTS)}, got {args.parts!r}")
    sizes = [(64, 36)] if args.quick else parse_sizes(p, args.sizes)
    if args.quick:
        args.scenes = args.scenes.split(",")[0]
        args.textured_scenes = args.textured_scenes.split(",")[0]
    repeats = args.repeats or (3 if args.quick else 20)
    wp.config.quiet = True
    dev = wp.get_device(args.device)
    records, mds = [], []
    for part in progress(parts, "stages"):
        recs, md = globals()[f"part_{part}"](args, dev, sizes, repeats)
        records += recs
        mds.append(md)
    md = "\n".join(mds)
    write_results("stages", dev, records, md, args.out, args.tag, extra={"repeats": repeats, "parts": parts})
    print(md)
    return records


if __name__ == "__main__":
    main()
