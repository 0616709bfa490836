"""The clip-box list launch (``stoch_box_list_kernel``) over its capacity-sized list: a block per 256 entries of the
capacity (every thread past the count exits at once) against a grid of 32 blocks per SM whose threads step over the
list a grid apart (the other list launches' form, ``ShadeStage._list_blocks``).

For each scene at each size, with 8 AO rays: a foveated FrameLoop renders 12 frames of its camera path with a moving
gaze; the box launch is then timed both ways on the last frame's list (CUDA events, the two forms alternating,
medians of ``--repeats``), and the two forms' boxes compared byte for byte.

python benchmarks/box_list_launch.py --device cuda:0 [--scenes ...] [--sizes 1920x1080,3840x2160]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, scenes_present, write_results  # noqa: E402
from benchmarks.frame import gaze_path  # noqa: E402


def main(argv=None) -> int:
    p = base_parser(__doc__.splitlines()[0])
    p.add_argument("--scenes", default="bunny,nefertiti,city,spot,ogre,teapot,cornell")
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--name", default="box-list-launch")
    args = p.parse_args(argv)
    repeats = args.repeats or 200
    if repeats < 1:
        p.error(f"--repeats must be >= 1, got {repeats}")
    try:
        sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",") if s]
        if not sizes or any(len(s) != 2 or min(s) < 1 for s in sizes):
            raise ValueError
    except ValueError:
        p.error(f"--sizes must be a comma list of WxH with positive integers, got {args.sizes!r}")
    if args.quick:
        sizes, repeats = [(64, 40)], 3
    import foveawarp as fw
    from foveawarp.kernels.temporal import stoch_box_list_kernel

    dev = wp.get_device(args.device)
    if not dev.is_cuda:
        p.error(f"--device must be a CUDA device (the launch shapes are CUDA's), got {args.device!r}")
    cfg = fw.Config().with_(shading={"ao_samples": 8})
    rows, records = [], []
    for scene in scenes_present(fw, args.scenes):
        for w, h in sizes:
            fl = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
            for i in range(12):
                f = fl.render(scene.camera_at(i / 30.0), gaze_px=gaze_path(i, 12, w, h), time=i / 30.0)
            rate = float(f.stats["sampling_rate"])
            st, work, count = fl.temporal, fl.reorder.work, fl.reorder.count
            tp = st.params(use_history=True, stochastic=True, samples=8)
            inputs = [tp, work, count, w, fl.sampling.sample_map, fl.gbuffer.hit, fl.radiance_stoch]
            outs = {k: (wp.zeros((h, w), dtype=wp.vec3, device=dev), wp.zeros((h, w), dtype=wp.vec3, device=dev))
                    for k in ("capacity", "grid")}
            blocks = {"capacity": 0, "grid": 32 * dev.sm_count}

            def launch(k):
                wp.launch(stoch_box_list_kernel, dim=work.shape[0], inputs=inputs, outputs=list(outs[k]), device=dev,
                          max_blocks=blocks[k])

            for k in blocks:
                launch(k)  # warm-up (and the outputs compared below)
            ms = {k: [] for k in blocks}
            ev = [wp.Event(dev, enable_timing=True) for _ in range(2)]
            for r in range(repeats):
                for k in (("capacity", "grid") if r % 2 == 0 else ("grid", "capacity")):
                    dev.stream.record_event(ev[0])
                    launch(k)
                    dev.stream.record_event(ev[1])
                    wp.synchronize_device(dev)
                    ms[k].append(wp.get_event_elapsed_time(ev[0], ev[1]))
            equal = all(np.array_equal(outs["capacity"][j].numpy(), outs["grid"][j].numpy()) for j in range(2))
            med = {k: float(np.median(v)) for k, v in ms.items()}
            rec = {"scene": scene.name, "width": w, "height": h, "listed": int(count.numpy()[0]),
                   "capacity": int(work.shape[0]), "sampling_rate": rate, "capacity_ms": med["capacity"],
                   "grid_ms": med["grid"], "grid_vs_capacity": med["grid"] / med["capacity"], "equal": equal}
            records.append(rec)
            rows.append({"scene": scene.name, "size": f"{w}x{h}", "listed": rec["listed"], "rate": rate,
                         "capacity ms": med["capacity"], "grid ms": med["grid"],
                         "grid / capacity": rec["grid_vs_capacity"], "boxes equal": equal})
            print({k: (round(v, 4) if isinstance(v, float) else v) for k, v in rows[-1].items()}, flush=True)
    table = md_table(rows, list(rows[0]) if rows else ["scene"])
    write_results(args.name, dev, {"records": records, "repeats": repeats},
                  f"stoch_box_list_kernel launch shapes ({repeats} alternating launches each, CUDA events, "
                  f"medians)\n\n" + table, args.out)
    print(table)
    return 0 if all(r["equal"] for r in records) else 1


if __name__ == "__main__":
    sys.exit(main())
