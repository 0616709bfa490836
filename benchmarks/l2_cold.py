"""Study (issue 14, session 35): what a cold L2 costs the list's AO rays, and whether prefetching the mesh helps.

In the foveated frame the list's AO rays run after the sampling map and the compaction, passes that stream a few
hundred MB through the 50 MB L2 at 4K; in the reference the full-frame shading runs right after the G-buffer's
primary rays, which leave the BVH and triangles in L2. Timed alone, back to back, the AO pass finds them there.

Per scene and size, on frame 12 of the camera path (8 AO rays), the list's AO lanes launch
(``shade_ao_list_kernel``, as ``ShadeStage.list`` launches it) and the full-frame AO shading
(``ShadeStage.full``):
* ``warm``: launched back to back;
* ``cold``: after a write of ``--flush-mb`` MB (the flush's own time, measured alone, subtracted);
* ``cold+prefetch``: after the flush and a launch that prefetches the mesh into L2 (the BVH's nodes, the primitive
  indices, the triangles' indices and points: ``prefetch.global.L2``, one thread per 128-byte line; the prefetch's
  own time is reported and subtracted too);
* ``prefetch-last+cold``: the mesh prefetched with the ``evict_last`` priority first, then the flush: whether the
  mesh's lines survive a streaming pass.
Outputs are checked equal across the conditions.

    python benchmarks/l2_cold.py --device cuda:0 [--scenes bunny,nefertiti,city,spot] [--sizes 3840x2160,1920x1080]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._study import run_study, study_parser  # noqa: E402
from benchmarks.list_shading import _frame_loop  # noqa: E402
from foveawarp.kernels.shade import shade_ao_list_kernel  # noqa: E402

_PREFETCH = """
#if defined(__CUDA_ARCH__)
    const wp::Mesh m = wp::mesh_get(id);
    long long l = (long long)line;
    const char* base = 0;
    long long bytes[5] = {(long long)m.bvh.num_nodes * 16, (long long)m.bvh.num_nodes * 16,
                          (long long)m.num_tris * 4, (long long)m.num_tris * 12, (long long)m.num_points * 12};
    const char* ptrs[5] = {(const char*)m.bvh.node_lowers, (const char*)m.bvh.node_uppers,
                           (const char*)m.bvh.primitive_indices, (const char*)m.indices.data,
                           (const char*)m.points.data};
    for (int r = 0; r < 5; ++r) {
        const long long lines = (bytes[r] + 127) / 128;
        if (l < lines) { base = ptrs[r] + l * 128; break; }
        l -= lines;
    }
    if (base) {
        if (last) asm volatile("prefetch.global.L2::evict_last [%0];" :: "l"(base));
        else asm volatile("prefetch.global.L2 [%0];" :: "l"(base));
    }
#endif
"""


@wp.func_native(_PREFETCH)
def mesh_prefetch_line(id: wp.uint64, line: int, last: int):
    """Prefetch 128-byte line ``line`` of the mesh's traversal data (BVH nodes, primitive indices, triangle indices,
    points, in that order) into L2 (CUDA; ``last`` 1: with the evict_last priority); past the end: nothing."""
    ...


@wp.kernel(enable_backward=False)
def mesh_prefetch_kernel(mesh: wp.uint64, last: int):
    mesh_prefetch_line(mesh, wp.tid(), last)


def prefetch_lines(num_tris: int, num_points: int) -> int:
    """An upper bound of the mesh's traversal data in 128-byte lines (at most 2 nodes per triangle)."""
    return (2 * 2 * num_tris * 16 + num_tris * 16 + num_points * 12) // 128 + 8


def study(fw, scene, w, h, dev, t_ms, frames: int, flush) -> dict:
    loop = _frame_loop(fw, scene, w, h, dev, 8, 4, frames)
    st, g, ds = loop.shade, loop.gbuffer, loop.dscene
    work, count = loop.reorder.work, loop.reorder.count
    cap = int(work.shape[0])
    lanes = st.ao_lanes()
    part = wp.zeros((cap, lanes), dtype=wp.uint8, device=dev)
    ao_blocks, ao_block_dim = st._ao_launch_shape()
    rad, rs = loop.radiance, loop.radiance_stoch
    mesh_id = ds.mesh.id
    nl = prefetch_lines(int(ds.indices.shape[0]) // 3, int(ds.points.shape[0]))

    def ao():
        wp.launch(shade_ao_list_kernel, dim=cap * lanes, inputs=[st.params_dev, work, count, g.position, g.normal,
                                                                 g.hit, ds.area_lights, part, 0],
                  device=dev, max_blocks=ao_blocks, block_dim=ao_block_dim)

    def full():
        st.full(g, rad, rs)

    def pf(last=0):
        wp.launch(mesh_prefetch_kernel, dim=nl, inputs=[mesh_id, last], device=dev)

    res = {"n_list": int(count.numpy()[0]), "mesh_mb": nl * 128 / 1e6,
           "flush_ms": t_ms(flush), "prefetch_ms": t_ms(pf),
           "flush_prefetch_ms": t_ms(lambda: (flush(), pf())),
           "prefetchlast_flush_ms": t_ms(lambda: (pf(1), flush()))}
    for name, fn, read in (("ao_list", ao, lambda: part.numpy()), ("full", full, lambda: rad.numpy())):
        fn()
        wp.synchronize_device(dev)
        want = read().copy()
        res[f"{name}_warm_ms"] = t_ms(fn)
        res[f"{name}_cold_ms"] = t_ms(lambda: (flush(), fn())) - res["flush_ms"]
        res[f"{name}_cold_prefetch_ms"] = t_ms(lambda: (flush(), pf(), fn())) - res["flush_prefetch_ms"]
        res[f"{name}_prefetchlast_cold_ms"] = t_ms(lambda: (pf(1), flush(), fn())) - res["prefetchlast_flush_ms"]
        if not np.array_equal(read(), want):
            raise AssertionError(f"{name}: the output changed between the conditions")
    return res


def _row(r: dict) -> dict:
    row = {"list": r["n_list"], "mesh MB": r["mesh_mb"], "prefetch ms": r["prefetch_ms"]}
    for k in ("ao_list", "full"):
        for c in ("warm", "cold", "cold_prefetch", "prefetchlast_cold"):
            row[f"{k} {c}"] = r[f"{k}_{c}_ms"]
    return row


def _flusher(dev, args):
    """The flush: a write of ``--flush-mb`` MB."""
    junk = wp.zeros(args.flush_mb * 1024 * 1024 // 4, dtype=wp.float32, device=dev)
    return (lambda: junk.fill_(1.0),)


def main(argv=None):
    p = study_parser(__doc__, "l2-cold", "bunny,nefertiti,city,spot", 5)
    p.add_argument("--flush-mb", type=int, default=256, help="MB written between launches to evict L2")
    args = p.parse_args(argv)
    run_study(p, args, "the study is of the CUDA L2", study, _row, setup=_flusher, meta={"flush_mb": args.flush_mb})


if __name__ == "__main__":
    main()
