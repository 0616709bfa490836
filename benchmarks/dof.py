"""How fast is the depth-of-field pass, and how close does it come to a thin-lens ray-traced reference?

The pass is the pixel-intensity scatter of ALGORITHMS.md B.

Speed: median ms of one ``DofStage.run`` (prepare + tile max radius + dilation + gather; and the atomic scatter
for comparison) at 1920x1080 and 3840x2160 (``--quick``: 160x90) for max CoC 8, 16, 32 px, on two synthetic
color + depth images: "ramp" (inverse depth linear across the image, so the CoC covers 0..max on both
sides of the focus, with wavy depth edges) and "worst" (every pixel blurred at the max CoC).

Quality: PSNR / SSIM against the thin-lens ray-traced reference (``dof_reference.render_thin_lens``) of the
pinhole image, the scatter with no fix, the foreground fix only, the background fix only, and both, on
``cornell`` (focus on the tall block, then on the short block) at 480x270 with 64 lens samples (``--quick``:
96x54, 16 samples), and on "edges", a synthetic scene made for the two artifacts (a bright foreground bar in
front of an in-focus checker wall, a bright far wall behind it). Writes dof-<tag>.json / .md and dof-<tag>.png:
one row per quality case, pinhole, scatter, corrected scatter and thin-lens reference side by side.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, parse_sizes, plot_path, progress, time_ms, write_results  # noqa

CANONICAL = "python benchmarks/dof.py --device cuda:0 --out benchmarks/results --tag h200"

FOCAL_M = 0.05
PX_PER_M = 20000.0


def synthetic(w, h, kind, max_coc, focus_m, rng):
    """(color (H, W, 3), view depth (H, W), aperture_m) such that the CoC reaches ``max_coc``."""
    color = rng.random((h, w, 3)).astype(np.float32)
    if kind == "worst":
        inv_z = np.zeros((h, w))  # everything at infinity
        span = 1.0 / focus_m
    else:
        xx = (np.arange(w) + 0.5) / w
        yy = (np.arange(h) + 0.5) / h
        wave = 0.08 * np.sin(2.0 * math.pi * 6.0 * yy)[:, None]
        inv_z = np.clip(2.0 / focus_m * (1.0 - xx[None, :] + wave), 0.0, None)  # 1/Z in [0, 2 / Z_f]
        span = 1.0 / focus_m
    depth = np.where(inv_z > 0, 1.0 / np.maximum(inv_z, 1e-12), np.inf).astype(np.float32)
    # C = E F px_per_m Z_f / (Z_f - F) |1/Z_f - 1/Z|  ->  E so that C = max_coc at |1/Z_f - 1/Z| = span
    aperture = max_coc / (FOCAL_M * PX_PER_M * focus_m / (focus_m - FOCAL_M) * span)
    return color, depth, aperture


def time_stage(w, h, dev, repeats, warmup, rng):
    import foveawarp as fw
    from foveawarp.stages.dof import DofStage

    rows = []
    focus = 3.0
    for kind in ("ramp", "worst"):
        for max_coc in (8.0, 16.0, 32.0):
            color, depth, aperture = synthetic(w, h, kind, max_coc, focus, rng)
            cw = wp.array(color, dtype=wp.vec3, device=dev)
            dw = wp.array(depth, dtype=float, device=dev)
            out = wp.zeros((h, w), dtype=wp.vec3, device=dev)
            row = {"part": "speed", "scene": f"synthetic {kind}", "image": kind, "width": w, "height": h,
                   "resolution": f"{w}x{h}", "max_coc_px": max_coc}
            for method in ("gather", "scatter"):
                cfg = fw.DofConfig(aperture_m=aperture, focal_length_m=FOCAL_M, focus_depth_m=focus,
                                   px_per_m=PX_PER_M, max_coc_px=max_coc)
                stage = DofStage(w, h, cfg, dev, method=method)
                t = time_ms(lambda: stage.run(cw, dw, None, None, out), dev, repeats, warmup)
                row[f"{method}_ms"] = t["median_ms"]
                row[f"{method}_p90_ms"] = t["p90_ms"]
                if method == "gather":
                    row["mean_coc_px"] = float(stage.coc.numpy().mean())
                    # mean half-width of the gather windows (isqrt of the dilated max floor(R^2) per tile)
                    row["mean_window_px"] = float(np.floor(np.sqrt(stage.tile_window.numpy())).mean())
            rows.append(row)
    return rows


def edges_scene():
    """Camera at the origin looking down -z. An in-focus checker wall (z = -3 m) on the left two thirds, a
    bright foreground bar (z = -1.2 m) in front of it, and an emissive far wall (z = -15 m) behind."""
    import foveawarp as fw
    from foveawarp.scenes import SceneBuilder

    b = SceneBuilder()
    sq, n = 0.2, 14
    for i in range(n):
        for j in range(n):
            alb = (0.85, 0.8, 0.7) if (i + j) % 2 == 0 else (0.1, 0.12, 0.3)
            b.add_quad((-2.2 + i * sq, -1.4 + j * sq, -3.0), (sq, 0, 0), (0, sq, 0), alb)
    b.add_quad((-0.55, -2.0, -1.2), (0.14, 0, 0), (0, 4.0, 0), (0.9, 0.3, 0.1), emission=(1.2, 0.35, 0.1))
    b.add_quad((-20.0, -12.0, -15.0), (40.0, 0, 0), (0, 24.0, 0), (0.0, 0.0, 0.0), emission=(0.9, 1.0, 1.2))
    cam = fw.Camera(eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, -1.0), up=(0.0, 1.0, 0.0), fov_y_deg=40.0)
    light = fw.Light(kind="point", position=(0.5, 1.0, -0.5), intensity=(8.0, 8.0, 8.0))
    return b.build(lights=[light], camera=cam, name="edges")


def quality(w, h, samples, dev):
    import foveawarp as fw
    from foveawarp.dof_reference import COMPARISON_VARIANTS, render_dof_comparison
    from foveawarp.metrics import psnr, ssim

    cornell = fw.load_scene("cornell")
    cases = []
    cam = cornell.camera
    for target, p in (("tall block", (-0.34, 0.9, -0.3)), ("short block", (0.36, 0.45, 0.32))):
        gx, gy = cam.project(np.array(p), w, h)[:2]
        cases.append((cornell, f"cornell, focus on the {target}", (float(gx), float(gy)),
                      fw.DofConfig(aperture_m=0.1, focal_length_m=FOCAL_M, px_per_m=PX_PER_M * w / 480.0,
                                   max_coc_px=16.0)))
    edges = edges_scene()
    cases.append((edges, "edges, focus on the checker wall", None,
                  fw.DofConfig(aperture_m=0.04, focal_length_m=FOCAL_M, focus_depth_m=3.0,
                               px_per_m=PX_PER_M * w / 480.0, max_coc_px=16.0)))
    rows, strips = [], []
    names = ["pinhole", *COMPARISON_VARIANTS]
    for scene, label, gaze, cfg in progress(cases, "dof quality"):
        imgs = render_dof_comparison(scene, scene.camera, w, h, cfg, samples, dev, gaze_px=gaze)
        ref = imgs["thin_lens"]
        for name in names:
            fg, bg = COMPARISON_VARIANTS.get(name, (None, None))
            rows.append({"part": "quality", "scene": scene.name, "width": w, "height": h, "lens_samples": samples,
                         "case": label, "image": name, "foreground_fix": fg, "background_fix": bg,
                         "psnr_db": psnr(imgs[name], ref), "ssim": ssim(imgs[name], ref)})
        strips.append(np.concatenate([imgs[k] for k in ("pinhole", "scatter", "corrected", "thin_lens")], axis=1))
    return rows, np.concatenate(strips, axis=0)


def main(argv=None):
    p = base_parser(__doc__, CANONICAL)
    p.add_argument("--sizes", default="1920x1080,3840x2160", help="timing sizes, WxH comma list (quick 160x90)")
    p.add_argument("--quality-size", default="480x270", help="quality image size WxH (quick 96x54)")
    p.add_argument("--samples", type=int, default=64, help="thin-lens samples per pixel (quick 16)")
    args = p.parse_args(argv)
    import imageio.v2 as imageio

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    sizes = [(160, 90)] if args.quick else parse_sizes(p, args.sizes)
    ((qw, qh),) = [(96, 54)] if args.quick else parse_sizes(p, args.quality_size, "--quality-size")
    if args.samples < 1:
        p.error(f"--samples must be >= 1, got {args.samples}")
    samples = min(args.samples, 16) if args.quick else args.samples
    repeats = args.repeats or (3 if args.quick else 30)
    rng = np.random.default_rng(7)

    speed = []
    for w, h in progress(sizes, "dof speed"):
        speed += time_stage(w, h, dev, repeats, args.warmup, rng)
    qrows, strip = quality(qw, qh, samples, dev)

    t1 = md_table(speed, ["image", "resolution", "max_coc_px", "mean_coc_px", "mean_window_px", "gather_ms",
                          "gather_p90_ms", "scatter_ms"])
    t2 = md_table(qrows, ["case", "image", "psnr_db", "ssim"])
    table = (f"### DoF speed (one DofStage.run, median ms of {repeats})\n\n{t1}\n"
             f"### DoF quality against the thin-lens reference ({qw}x{qh}, {samples} lens samples)\n\n{t2}")
    write_results("dof", dev, speed + qrows, table, args.out, args.tag, extra={
        "repeats": repeats, "quality_size": f"{qw}x{qh}", "lens_samples": samples,
        "note": ("gather_ms: prepare + tile max radius + dilation + gather; scatter_ms: prepare + clear + atomic "
                 "scatter + normalize. Quality px_per_m is scaled with the width (20000 at 480 px) so the "
                 "blur is the same fraction of the image at every size. PNG columns: pinhole, scatter (no fix), "
                 "corrected scatter, thin-lens reference; rows: the quality cases in order.")})
    imageio.imwrite(plot_path("dof", dev, args.out, args.tag),
                    (np.clip(strip, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8))
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
