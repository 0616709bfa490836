"""Study (issue 14, session 35): the list's AO lanes traced by SM-local segments of the list, on CUDA.

The foveated frame's list of traced pixels shades at 1.26-1.7x the reference's per-pixel cost, because its
peripheral pixels are sparse and sparse rays share less of their BVH walk (docs/frame-results.md, sessions 28-30).
``shade_ao_list_kernel`` hands the list's lanes to thread blocks in index order; the hardware places the blocks
on whichever SM is free, so the blocks that share one SM's L1 at once come from places of the list (and the
screen) far apart. Here a persistent launch (a few resident blocks per SM) gives each SM a contiguous segment of
the list (``%smid``), its warps taking 32 lanes at a time from the segment's counter, and taking from the next
segments once theirs is done: the warps sharing an L1 trace neighbouring pixels. ``nseg=1`` is the same
persistent launch with one counter for the whole list (dynamic fetching without the SM locality).

Each variant's ``ao_part`` is checked equal to the package kernel's (every lane traced once, the same rays), on
any device (``study``; the timings are CUDA's).

    python benchmarks/ao_segments.py --device cuda:0 [--scenes bunny,nefertiti,city,spot] [--sizes 3840x2160]

Writes benchmarks/results/ao-segments-cuda.{json,md} (``--name``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._study import run_study, study_parser  # noqa: E402
from benchmarks.list_shading import _frame_loop, _list_array  # noqa: E402
from foveawarp.kernels.shade import (AreaLightParams, ShadeParams, ao_list_lane,  # noqa: E402
                                     shade_ao_list_kernel)


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    unsigned r;
    asm volatile("mov.u32 %0, %%smid;" : "=r"(r));
    return (int)r;
#else
    return 0;
#endif
""")
def sm_id() -> int:
    """The SM this thread runs on (CUDA); 0 elsewhere."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    return (int)(threadIdx.x & 31u);
#else
    return 0;
#endif
""")
def lane_id() -> int:
    """This thread's lane in its warp (CUDA); 0 elsewhere."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    return 32;
#else
    return 1;
#endif
""")
def warp_width() -> int:
    """Threads that fetch work together: a CUDA warp's 32; 1 on the CPU (one thread at a time)."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__)
    __syncwarp();
    int v = 0;
    if ((threadIdx.x & 31u) == 0u) {
        int* p = ctr.data + s;
        v = *((volatile int*)p);
        if (v < limit) v = atomicAdd(p, step);
    }
    return __shfl_sync(0xffffffffu, v, 0);
#else
    const int v = ctr.data[s];
    if (v < limit) ctr.data[s] = v + step;
    return v;
#endif
""")
def warp_fetch(ctr: wp.array(dtype=wp.int32), s: int, step: int, limit: int) -> int:
    """The warp's next ``step`` entries of segment ``s``: its counter's old value, the same on every lane (CUDA:
    the whole warp must call it together)."""
    ...


@wp.kernel(enable_backward=False, grid_stride=False, cuda_max_registers=64)
def ao_segments_kernel(
    spa: wp.array(dtype=ShadeParams),
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    area_lights: wp.array(dtype=AreaLightParams),
    ao_part: wp.array2d(dtype=wp.uint8),
    ctr: wp.array(dtype=wp.int32),
    nseg: int,
    smid: int,
):
    """Persistent: the list's ``count[0] * G`` lanes in ``nseg`` segments (a multiple of 32 lanes each on CUDA,
    where a warp takes 32 lanes at a time; the CPU's threads take one at a time, so the same lanes); the warps
    of SM m start on segment m % nseg (``smid`` 1; 0: the block's index instead) and move to the next once it is
    taken. ``ctr`` (nseg zeros) counts each segment's lanes handed out."""
    sp = spa[0]
    total = count[0] * ao_part.shape[1]
    ww = warp_width()
    seglen = (((total + nseg - 1) // nseg) + ww - 1) // ww * ww
    lane = lane_id()
    s = int(0)
    if smid != 0:
        s = sm_id() % nseg
    else:
        s = (wp.tid() // 128) % nseg
    tries = int(0)
    while tries < nseg:
        b = warp_fetch(ctr, s, ww, seglen)
        if b >= seglen:
            s = s + 1
            if s >= nseg:
                s = 0
            tries = tries + 1
        else:
            k = s * seglen + b + lane
            if k < total:
                ao_list_lane(sp, work, pos, normal, hit, area_lights, ao_part, k)


VARIANTS = (("package", 0, 0, 0), ("sm-seg r8", 8, -1, 1), ("sm-seg r4", 4, -1, 1), ("block-seg r8", 8, -1, 0),
            ("one-counter r8", 8, 1, 1))


def study(fw, scene, w, h, dev, t_ms, frames: int) -> dict:
    loop = _frame_loop(fw, scene, w, h, dev, 8, 4, frames)
    st, g, ds = loop.shade, loop.gbuffer, loop.dscene
    nsm = st._sm_count()
    hit = g.hit.numpy() != 0
    n = int(loop.reorder.count.numpy()[0])
    fov = loop.reorder.work.numpy()[:n].copy()
    loop.reorder.run(wp.array(hit.astype(np.uint8), dtype=wp.uint8, device=dev))
    allhits = loop.reorder.work.numpy()[:int(loop.reorder.count.numpy()[0])].copy()
    res = {"n_list": n, "n_hit": int(hit.sum()), "n_px": w * h, "sm_count": nsm}
    lanes = st.ao_lanes()
    ao_blocks, ao_block_dim = st._ao_launch_shape()
    for lname, idx in (("fov", fov), ("allhits", allhits)):
        work, count = _list_array(idx, dev)
        cap = int(work.shape[0])
        part = wp.zeros((cap, lanes), dtype=wp.uint8, device=dev)
        ctr = wp.zeros(nsm, dtype=wp.int32, device=dev)
        args = [st.params_dev, work, count, g.position, g.normal, g.hit, ds.area_lights, part]
        want = None
        for vname, r, nseg, smid in VARIANTS:
            if vname == "package":
                def run():
                    wp.launch(shade_ao_list_kernel, dim=cap * lanes, inputs=[*args, 0], device=dev,
                              max_blocks=ao_blocks, block_dim=ao_block_dim)
            else:
                ns = nsm if nseg < 0 else nseg
                c = ctr if ns == nsm else wp.zeros(ns, dtype=wp.int32, device=dev)

                def run(r=r, ns=ns, smid=smid, c=c):
                    c.zero_()
                    wp.launch(ao_segments_kernel, dim=nsm * r * 128, inputs=[*args, c, ns, smid], device=dev,
                              block_dim=128)
            part.fill_(255)
            run()
            wp.synchronize_device(dev)
            got = part.numpy().copy()
            if want is None:
                want = got
            elif not np.array_equal(got, want):
                raise AssertionError(f"{vname} on the {lname} list changed ao_part")
            res[f"{lname}_{vname.replace(' ', '_')}_ms"] = t_ms(run)
    return res


def _row(r: dict) -> dict:
    row = {"round": r["round"], "list": r["n_list"]}
    for lname in ("fov", "allhits"):
        base = r[f"{lname}_package_ms"]
        row[f"{lname} package ms"] = base
        for vname, *_ in VARIANTS[1:]:
            row[f"{lname} {vname} / package"] = r[f"{lname}_{vname.replace(' ', '_')}_ms"] / base
    return row


def main(argv=None):
    p = study_parser(__doc__, "ao-segments", "bunny,nefertiti,city,spot", 10)
    p.add_argument("--rounds", type=int, default=2, help="each scene and size studied this many times")
    args = p.parse_args(argv)
    run_study(p, args, "the study is of CUDA SMs", study, _row, rounds=args.rounds)


if __name__ == "__main__":
    main()
