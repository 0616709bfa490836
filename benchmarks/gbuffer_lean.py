"""Study (issue 14, session 35): what the reprojection fields cost the G-buffer that the full-resolution frames trace.

``render_reference`` (and the default policy's full-resolution frames) trace the same G-buffer kernel as the
foveated frame, reprojection included: each hit reads its face's three previous vertex positions, projects the
point with the previous camera and writes ``reproj_uv``, ``prev_dist`` and ``moved`` (13 bytes a pixel). No
full-resolution frame reads them (a foveated frame computes its own reprojection towards the previous frame).
This times the package's CUDA G-buffer kernel (``gbuffer_tiles_kernel``, as ``GBufferStage`` launches it) against
a kernel made of the same functions without the reprojection (``primary_normal``, ``store_surface``), on frame 12
of each camera path, and checks that the fields both write are equal.

    python benchmarks/gbuffer_lean.py --device cuda:0 [--scenes bunny,nefertiti,city,spot,cornell]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._study import alternating, run_study, study_parser  # noqa: E402
from benchmarks.list_shading import _frame_loop  # noqa: E402
from foveawarp.kernels.camera import CameraParams, camera_ray_dir  # noqa: E402
from foveawarp.kernels.gbuffer import gbuffer_tiles_kernel, primary_normal, store_surface  # noqa: E402
from foveawarp.kernels.load import load1_i32  # noqa: E402
from foveawarp.kernels.order import tile_order_pixel  # noqa: E402


@wp.kernel(enable_backward=False)
def gbuffer_lean_tiles_kernel(
    mesh: wp.uint64,
    indices: wp.array(dtype=wp.int32),
    vnormals: wp.array(dtype=wp.vec3),
    smooth: wp.array(dtype=wp.uint8),
    cam: CameraParams,
    max_t: float,
    out_pos: wp.array2d(dtype=wp.vec3),
    out_normal: wp.array2d(dtype=wp.vec3),
    out_depth: wp.array2d(dtype=float),
    out_face: wp.array2d(dtype=wp.int32),
    out_hit: wp.array2d(dtype=wp.uint8),
    wlog2: int,
):
    p = tile_order_pixel(wp.tid(), out_depth.shape[1], wlog2)
    x = p[0]
    y = p[1]
    if x < out_depth.shape[1] and y < out_depth.shape[0]:
        d = camera_ray_dir(cam, float(x) + 0.5, float(y) + 0.5)
        q = wp.mesh_query_ray(mesh, cam.eye, d, max_t)
        if q.result:
            i0 = load1_i32(indices, q.face * 3 + 0)
            i1 = load1_i32(indices, q.face * 3 + 1)
            i2 = load1_i32(indices, q.face * 3 + 2)
            n = primary_normal(q.normal, d, q.face, q.u, q.v, i0, i1, i2, vnormals, smooth)
            store_surface(y, x, cam.eye + d * q.t, n, q.t, q.face, wp.uint8(1), out_pos, out_normal, out_depth,
                          out_face, out_hit)
        else:
            store_surface(y, x, wp.vec3(0.0, 0.0, 0.0), wp.vec3(0.0, 0.0, 0.0), max_t, -1, wp.uint8(0), out_pos,
                          out_normal, out_depth, out_face, out_hit)


def study(fw, scene, w, h, dev, t_ms, frames: int) -> dict:
    loop = _frame_loop(fw, scene, w, h, dev, 0, 4, frames)
    gs, g, ds = loop.gbuffer_stage, loop.gbuffer, loop.dscene
    gs._set_order()
    cam = scene.camera_at(frames / 30.0)
    prev = scene.camera_at((frames - 1) / 30.0)
    cam_p, max_t = cam.params(w, h), gs.max_t(cam)
    inputs = [ds.mesh.id, ds.indices, ds.points_prev, ds.vertex_normals, ds.face_smooth, cam_p, prev.params(w, h),
              max_t]
    outputs = [g.position, g.normal, g.depth, g.face, g.hit, g.reproj_uv, g.prev_dist, g.moved, gs._wlog2, 0]

    def pkg():
        wp.launch(gbuffer_tiles_kernel, dim=gs._dim, inputs=inputs + outputs, device=dev)

    lean_out = [wp.empty_like(a) for a in (g.position, g.normal, g.depth, g.face, g.hit)]

    lean_inputs = [ds.mesh.id, ds.indices, ds.vertex_normals, ds.face_smooth, cam_p, max_t, *lean_out, gs._wlog2]

    def lean():  # its arguments built once, as the package kernel's
        wp.launch(gbuffer_lean_tiles_kernel, dim=gs._dim, inputs=lean_inputs, device=dev)

    pkg()
    lean()
    wp.synchronize_device(dev)
    for a, b in zip((g.position, g.normal, g.depth, g.face, g.hit), lean_out):
        if not np.array_equal(a.numpy(), b.numpy()):
            raise AssertionError("the lean G-buffer differs from the package's in a field both write")
    res = {"hit_fraction": float((g.hit.numpy() != 0).mean())}
    res.update(alternating(t_ms, {"package": pkg, "lean": lean}))
    return res


def _row(r: dict) -> dict:
    return {"hits": r["hit_fraction"], "package ms": r["package_ms"], "lean ms": r["lean_ms"],
            "lean / package": r["lean_ms"] / r["package_ms"]}


def main(argv=None):
    p = study_parser(__doc__, "gbuffer-lean", "bunny,nefertiti,city,spot,cornell", 10)
    args = p.parse_args(argv)
    run_study(p, args, "the tiles launch is CUDA's", study, _row)


if __name__ == "__main__":
    main()
