"""Host time of the G-buffer launch call on CUDA, in segments: the frame's critical path before its first kernel.

The GPU idles until ``render``'s G-buffer kernel is launched, so every microsecond of host time up to that launch
is paid by every frame, foveated or not. Per frame (a new camera each frame, as a camera path gives; the previous
frame's camera struct cached, as in a ``FrameLoop``), medians over ``--frames`` frames, each after a
synchronization:

* ``inputs_us``: the launch's arguments, the new camera's kernel struct (``Camera.params``) included;
* ``replay_us``: ``parallel.Relaunch._replay``, re-setting the recorded command's changed arguments;
* ``launch_us``: the recorded command's ``launch()``;
* ``plain_launch_us``: a plain ``wp.launch`` of the same kernel and arguments, for comparison;
* ``stage_run_us``: the whole ``GBufferStage.run`` call for a new camera.

Run (CUDA only)::

    python benchmarks/gbuffer_launch_host.py --device cuda:0 --specs eyechart:1920x1080,bunny:3840x2160

Results: ``gbuffer-launch-host[-NAME]-cuda.{json,md}``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, write_results  # noqa: E402

COLS = ("inputs_us", "replay_us", "launch_us", "plain_launch_us", "stage_run_us")


def measure(fw, name: str, w: int, h: int, dev, frames: int) -> dict:
    scene = fw.load_scene(name)
    loop = fw.FrameLoop(scene, w, h, device=dev, timing=False, policy="full")
    for i in range(10):
        loop.render(scene.camera_at(i / 30.0))
    gs, ds, g = loop.gbuffer_stage, loop.dscene, loop.gbuffer
    rows = []
    prev = scene.camera_at(9 / 30.0)
    prev.params(w, h)
    for i in range(10, 10 + frames):
        cam = scene.camera_at(i / 30.0)
        wp.synchronize_device(dev)
        t0 = time.perf_counter()
        gs._set_order()
        inputs = [ds.mesh.id, ds.indices, ds.points_prev, ds.vertex_normals, ds.face_smooth,
                  cam.params(w, h), prev.params(w, h), gs.max_t(cam)]
        outputs = [g.position, g.normal, g.depth, g.face, g.hit, g.reproj_uv, g.prev_dist, g.moved, gs._wlog2]
        t1 = time.perf_counter()
        rl = gs._launch
        if not rl._replay(gs._dim, wp.get_device(dev), [*inputs, *outputs, 0]):
            raise RuntimeError("the G-buffer launch was not recorded for replay")
        t2 = time.perf_counter()
        rl._cmd.launch()
        t3 = time.perf_counter()
        wp.synchronize_device(dev)
        t4 = time.perf_counter()
        wp.launch(gs._kernel, dim=gs._dim, inputs=inputs, outputs=[*outputs, 0], device=dev)
        t5 = time.perf_counter()
        wp.synchronize_device(dev)
        nxt = scene.camera_at(i / 30.0 + 1e-3)
        t6 = time.perf_counter()
        gs.run(g, nxt, cam)
        t7 = time.perf_counter()
        prev = cam
        rows.append([t1 - t0, t2 - t1, t3 - t2, t5 - t4, t7 - t6])
    med = np.median(np.array(rows), axis=0) * 1e6
    return {"scene": name, "width": w, "height": h, "frames": frames, **{c: float(v) for c, v in zip(COLS, med)}}


def main(argv=None) -> int:
    p = base_parser(__doc__.split("\n")[0])
    p.add_argument("--specs", default="eyechart:1920x1080,bunny:3840x2160,cornell:1920x1080",
                   help="scene:WIDTHxHEIGHT, comma-separated")
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--name", default="", help="suffix of the results file stem")
    a = p.parse_args(argv)
    import foveawarp as fw

    dev = wp.get_device(a.device)
    if not dev.is_cuda:
        p.error(f"--device must be a CUDA device (the recorded launch is CUDA's), got {dev.alias}")
    rows = []
    for spec in a.specs.split(","):
        name, size = spec.split(":")
        w, h = (int(v) for v in size.split("x"))
        rows.append(measure(fw, name, w, h, dev, 20 if a.quick else a.frames))
        print(rows[-1], flush=True)
    md = md_table(rows, ["scene", "width", "height", *COLS])
    write_results("gbuffer-launch-host" + (f"-{a.name}" if a.name else ""), dev, {"rows": rows}, md, a.out)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
