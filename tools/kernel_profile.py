"""Per-kernel GPU times of one foveated frame and one reference frame (CUDA activity timing, no host sync
between kernels), to see where the rate-independent overhead goes. Writes kernel-profile-<tag>.{json,md} under
``--out`` (default benchmarks/out).

    python tools/kernel_profile.py --device cuda:0 [--scenes cornell,bunny,city] [--sizes 1920x1080,3840x2160]
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, write_results  # noqa: E402


def kernel_times(fn, frames: int) -> dict:
    """Mean GPU ms per frame of every kernel / memset / memcpy that ``fn(i)`` launches."""
    wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | wp.TIMING_MEMSET | wp.TIMING_MEMCPY | wp.TIMING_KERNEL_BUILTIN)
    for i in range(frames):
        fn(i)
    res = wp.timing_end()
    acc = defaultdict(float)
    for r in res:
        acc[r.name] += r.elapsed / frames
    return dict(acc)


def main(argv=None):
    p = base_parser(__doc__)
    p.add_argument("--scenes", default="cornell,bunny,city")
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--config", default="", help="python dict literal of Config.with_ overrides")
    args = p.parse_args(argv)
    import ast

    import foveawarp as fw

    dev = wp.get_device(args.device)
    over = ast.literal_eval(args.config) if args.config else {}
    cfg = fw.Config().with_(**over) if over else fw.Config()
    rows, payload = [], []
    for name in args.scenes.split(","):
        scene = fw.load_scene(name)
        for size in args.sizes.split(","):
            w, h = (int(v) for v in size.split("x"))
            loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, graph=False, policy="foveated")

            def fov(i):
                t = (i + 1) / 30.0
                loop.render(scene.camera_at(t), gaze_px=(w * (0.5 + 0.2 * (i % 3 - 1)), h * 0.5), time=t)

            def ref(i):
                t = (i + 1) / 30.0
                loop.render_reference(scene.camera_at(t), time=t)

            for i in range(4):
                fov(i)
                ref(i)
            wp.synchronize_device(dev)
            if not dev.is_cuda:
                print("CUDA activity timing needs a CUDA device; CPU run only checks the script")
                return
            kf = kernel_times(fov, args.frames)
            kr = kernel_times(ref, args.frames)
            rec = {"scene": scene.name, "width": w, "height": h, "foveated_kernels_ms": kf,
                   "reference_kernels_ms": kr, "foveated_gpu_ms": sum(kf.values()),
                   "reference_gpu_ms": sum(kr.values())}
            payload.append(rec)
            print(f"\n== {scene.name} {w}x{h}: foveated GPU sum {rec['foveated_gpu_ms']:.3f} ms, "
                  f"reference {rec['reference_gpu_ms']:.3f} ms", flush=True)
            for k, v in sorted(kf.items(), key=lambda kv: -kv[1]):
                print(f"   fov {v:8.4f}  {k}")
            for k, v in sorted(kr.items(), key=lambda kv: -kv[1]):
                print(f"   ref {v:8.4f}  {k}")
            rows.append({"scene": scene.name, "resolution": f"{w}x{h}", "foveated_gpu_ms": rec["foveated_gpu_ms"],
                         "reference_gpu_ms": rec["reference_gpu_ms"]})
    write_results("kernel-profile", dev, payload, md_table(rows, list(rows[0])), args.out, args.tag,
                  extra={"config": over})


if __name__ == "__main__":
    main()
