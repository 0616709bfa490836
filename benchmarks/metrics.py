"""Image-quality metrics on the device versus on the host.

For each resolution, the median ms of ``region_metrics_device`` (whole-frame and per-region PSNR + SSIM, frames
already on the device, one read of the sums), of ``psnr_device`` and ``ssim_device`` alone, and of the host
``region_metrics`` (NumPy + scikit-image on one core) including the read of both frames from the device. Also
the largest difference between the device and host results (they must agree to ~1e-12).

The frames are synthetic: a smooth colour gradient with texture, and the same plus Gaussian noise (sigma 0.05).

python benchmarks/metrics.py --device cuda:0
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, time_ms, write_results  # noqa: E402


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


def main():
    p = base_parser(__doc__)
    p.add_argument("--sizes", default=None, help="e.g. 1920x1080,3840x2160")
    p.add_argument("--host-repeats", type=int, default=None, help="timed repeats of the host version")
    p.add_argument("--fov", type=float, default=60.0, help="vertical field of view in degrees")
    args = p.parse_args()
    from foveawarp import metrics

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    if args.sizes:
        sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    else:
        sizes = [(96, 54), (160, 90)] if args.quick else [(1920, 1080), (3840, 2160)]
    repeats = args.repeats or (3 if args.quick else 20)
    host_repeats = args.host_repeats or (1 if args.quick else 3)
    rows = []
    for w, h in sizes:
        img, ref = frames(w, h)
        wi, wr = (wp.array(v, dtype=wp.vec3, device=dev) for v in (img, ref))
        gaze = (0.55 * w, 0.45 * h)

        def device_call():
            return metrics.region_metrics_device(wi, wr, gaze, args.fov)

        def host_call():
            return metrics.region_metrics(wi.numpy(), wr.numpy(), gaze, args.fov)

        hv = host_call()  # also the host's warm-up (imports)
        t_dev = time_ms(device_call, dev, repeats, args.warmup)
        t_psnr = time_ms(lambda: metrics.psnr_device(wi, wr), dev, repeats, args.warmup)
        t_ssim = time_ms(lambda: metrics.ssim_device(wi, wr), dev, repeats, args.warmup)
        t_host = time_ms(host_call, dev, host_repeats, 0)
        dv = device_call()
        row = {"resolution": f"{w}x{h}", "device_ms": t_dev["median_ms"], "device_p10_ms": t_dev["p10_ms"],
               "device_p90_ms": t_dev["p90_ms"], "psnr_device_ms": t_psnr["median_ms"],
               "ssim_device_ms": t_ssim["median_ms"], "host_ms": t_host["median_ms"],
               "speedup": t_host["median_ms"] / t_dev["median_ms"], "max_abs_diff": max_abs_diff(hv, dv),
               "repeats": repeats, "host_repeats": host_repeats, "device_result": dv}
        rows.append(row)
        print(f"{row['resolution']}: region_metrics_device {row['device_ms']:.3f} ms (psnr {row['psnr_device_ms']:.3f},"
              f" ssim {row['ssim_device_ms']:.3f}), host {row['host_ms']:.1f} ms, x{row['speedup']:.1f}, "
              f"max |diff| {row['max_abs_diff']:.2e}", flush=True)
    cols = ["resolution", "device_ms", "psnr_device_ms", "ssim_device_ms", "host_ms", "speedup", "max_abs_diff"]
    table = md_table([{**r, "max_abs_diff": f"{r['max_abs_diff']:.1e}"} for r in rows], cols)
    print(table)
    path = write_results("metrics", dev, {"scene": "synthetic gradient + noise (sigma 0.05)", "fov_y_deg": args.fov,
                                          "rows": rows}, table, args.out)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
