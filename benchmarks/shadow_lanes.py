"""Study (issue 14, session 36): the list's shadow rays in a lean launch of their own.

The foveated frame's list shading (``shade_list_kernel``, after the AO lanes) traces one shadow ray per point or
spot light for each traced pixel, in a kernel of ~127 registers (Nsight Compute: 20% occupancy on the H100). On
the sparse list those rays cost 3-4x the full frame's per ray (``list-shadows-e23-fe02422-cuda.log``: bunny at
4K, 0.215 ms for the list's shading with shadows, 0.036 without). This times, on frame 12 of each camera path:

* ``shade_ms``: the package's list shading after the AO lanes, shadows on, in its unsplit form (``split_direct``
  off: at 1920x1080 and below the frame shades the lights' part beside the AO pass instead);
* ``noshadow_ms``: the same kernel with the scene's shadows off (the floor of a shading that reads its lights'
  visibility instead of tracing it);
* ``lanes_ms``: a lean kernel, a thread per (traced pixel, light), tracing the same shadow ray as
  ``shade_direct_parts`` (same origin offset, direction, length, any-hit query) and writing a visibility byte; in
  the AO lanes' launch shape (``ShadeStage._ao_launch_shape``).

``lanes + noshadow`` against ``shade`` bounds what moving the shadow rays out of the shading could save. The
visibility bytes are checked against the package's own rays: where every light is visible the shading with shadows
equals the shading without them, and where one is blocked it is no brighter in any channel.

    python benchmarks/shadow_lanes.py --device cuda:0 [--scenes bunny,nefertiti,city,spot] [--sizes ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._study import alternating, run_study, study_parser  # noqa: E402
from benchmarks.list_shading import _frame_loop  # noqa: E402
from foveawarp import parallel  # noqa: E402
from foveawarp.kernels.shade import (LightParams, ShadeParams, list_pixel, shade_ao_list_kernel,  # noqa: E402
                                     shade_list_kernel, spot_factor, visible)


@wp.kernel(enable_backward=False)
def shadow_lanes_kernel(
    spa: wp.array(dtype=ShadeParams),
    work: wp.array(dtype=wp.int32),
    count: wp.array(dtype=wp.int32),
    pos: wp.array2d(dtype=wp.vec3),
    normal: wp.array2d(dtype=wp.vec3),
    hit: wp.array2d(dtype=wp.uint8),
    lights: wp.array(dtype=LightParams),
    vis: wp.array2d(dtype=wp.uint8),
    row0: int,
):
    """Thread k = i L + l (L = ``vis.shape[1]``, k below ``count[0] * L``): ``vis[i, l]`` = 0 where the shadow ray
    of light l from list entry i's surface point is blocked, else 1 (no ray where ``shade_direct_parts`` traces
    none: a miss, a light behind the surface or outside its cone, shadows off, a light past ``num_lights``)."""
    k = wp.tid() + row0
    nl = vis.shape[1]
    if k >= count[0] * nl:
        return
    i = k // nl
    li = k - i * nl
    sp = spa[0]
    x, y = list_pixel(work[i], sp.width)
    v = wp.uint8(1)
    if hit[y, x] != wp.uint8(0) and li < sp.num_lights and sp.shadows != 0:
        p = pos[y, x]
        n = normal[y, x]
        l = lights[li]
        dl = l.position - p
        dist2 = wp.dot(dl, dl)
        if dist2 > 1.0e-30:
            dist = wp.sqrt(dist2)
            wi = dl / dist
            if wp.dot(n, wi) > 0.0 and spot_factor(l, -wi) > 0.0:
                if visible(sp.mesh, p, n, sp.ray_eps, wi, dist) <= 0.0:
                    v = wp.uint8(0)
    vis[i, li] = v


@wp.kernel(enable_backward=False)
def shadows_off_kernel(spa: wp.array(dtype=ShadeParams)):
    sp = spa[0]
    sp.shadows = 0
    spa[0] = sp


def study(fw, scene, w, h, dev, t_ms, frames: int) -> dict:
    res = {}
    for shading, ao in (("default", 0), ("ao8", 8)):
        loop = _frame_loop(fw, scene, w, h, dev, ao, 4, frames)
        res[shading] = _compare(loop, w, h, dev, t_ms, ao)
    return res


def _compare(loop, w, h, dev, t_ms, ao: int) -> dict:
    st, g, r, ds = loop.shade, loop.gbuffer, loop.reorder, loop.dscene
    st.split_direct = False
    work, count = r.work, r.count
    cap = int(work.shape[0])
    nl = max(1, int(ds.lights.shape[0]))
    lanes = st.ao_lanes() if ao > 0 else 0
    if lanes >= 2:
        part = wp.zeros((cap, lanes), dtype=wp.uint8, device=dev)
        ao_blocks, ao_bd = st._ao_launch_shape()
        parallel.launch(shade_ao_list_kernel, dim=cap * lanes,
                        inputs=[st.params_dev, work, count, g.position, g.normal, g.hit, ds.area_lights],
                        outputs=[part], device=dev, count=count, per_count=lanes, max_blocks=ao_blocks,
                        block_dim=ao_bd)
    else:
        lanes = 0
        part = st._no_part
    no_sh = wp.clone(st.params_dev)
    wp.launch(shadows_off_kernel, dim=1, inputs=[no_sh], device=dev)
    out_a, out_b = wp.zeros_like(loop.radiance), wp.zeros_like(loop.radiance)
    sa, sb = wp.zeros_like(loop.radiance), wp.zeros_like(loop.radiance)
    vis = wp.zeros((cap, nl), dtype=wp.uint8, device=dev)
    blocks = st._list_blocks()
    ao_blocks, ao_bd = st._ao_launch_shape()

    def shade(params, out, out_s):
        parallel.launch(shade_list_kernel, dim=cap, inputs=[params, work, count, *st.inputs(g), part, lanes],
                        outputs=[out, out_s], device=dev, count=count, max_blocks=blocks)

    def shadow_lanes():
        parallel.launch(shadow_lanes_kernel, dim=cap * nl,
                        inputs=[st.params_dev, work, count, g.position, g.normal, g.hit, ds.lights],
                        outputs=[vis], device=dev, count=count, per_count=nl, max_blocks=ao_blocks, block_dim=ao_bd)

    shade(st.params_dev, out_a, sa)
    shade(no_sh, out_b, sb)
    shadow_lanes()
    wp.synchronize_device(dev)
    n = int(count.numpy()[0])
    idx = work.numpy()[:n]
    a = out_a.numpy().reshape(-1, 3)[idx]
    b = out_b.numpy().reshape(-1, 3)[idx]
    v = vis.numpy()[:n]
    lit = v.min(axis=1) == 1
    if not np.array_equal(a[lit], b[lit]):
        raise AssertionError("a pixel with every light visible shades differently with shadows on and off")
    if np.any(a[~lit] > b[~lit]):
        raise AssertionError("a pixel with a blocked light is brighter with shadows on")
    res = {"n_list": n, "lights": int(ds.lights.shape[0]), "blocked_fraction": float(1.0 - lit.mean()) if n else 0.0,
           "ao_lanes": lanes}
    res.update(alternating(t_ms, {"shade": lambda: shade(st.params_dev, out_a, sa),
                                  "noshadow": lambda: shade(no_sh, out_b, sb), "lanes": shadow_lanes}))
    return res


def _row(r: dict) -> dict:
    row = {}
    for shading in ("default", "ao8"):
        v = r[shading]
        row[f"{shading}: shade ms"] = v["shade_ms"]
        row[f"{shading}: lanes + noshadow ms"] = v["lanes_ms"] + v["noshadow_ms"]
        row[f"{shading}: ratio"] = (v["lanes_ms"] + v["noshadow_ms"]) / v["shade_ms"]
    return row


def main(argv=None):
    p = study_parser(__doc__, "shadow-lanes", "bunny,nefertiti,city,spot,teapot,ogre", 10)
    args = p.parse_args(argv)
    run_study(p, args, "the study times CUDA launch shapes", study, _row)


if __name__ == "__main__":
    main()
