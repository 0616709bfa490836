"""The foveated frame's list shading, kernel by kernel (issue 14, session 20), on frames of each scene's camera path.

Part ``lists``: the shading pass alone (``ShadeStage.list``, 8 AO rays) over the foveated frame's list; the same
list thinned to every 2nd and 4th entry; a uniform random choice of as many surface pixels (in the same tile
order); as many surface pixels packed around the gaze (the nearest to it, in the same tile order); the foveated
list shuffled; the list of every surface pixel; and the full-frame shading. ``fov_time_share`` /
``fov_pixel_share``: the foveated list's part of the all-surface list's time / of its pixels. A list whose time
barely falls when it is thinned is bound by one thread's chain of rays, not by the rays' throughput (what
``ShadingConfig.ao_lanes`` answers). ``--lanes`` sets the AO lanes of the list launches (1: one thread per pixel,
the form the study first measured); ``--split`` whether the list's light sources are shaded apart from its AO pass
(``ShadeStage.split_direct``: "auto" the package's rule, "on", "off"; each record says what ran in ``split``).
``gaze_dense_max_px`` / ``fov_max_px``: how far (Chebyshev, pixels) the gaze-packed / foveated list reaches from the
last frame's gaze.

Part ``caps``: CUDA register caps (``cuda_max_registers``) of the shading kernels: each variant is the package's
kernel function compiled again with another cap ("nocap": none) and timed alone on the same frame, its output
checked equal to the package kernel's. With 8 AO rays: the list's AO pass, the list shading, the full-frame
shading; with default shading: the list and full-frame shading. The package's own caps are in
``foveawarp/kernels/shade.py``.

    python benchmarks/list_shading.py --device cuda:0 [--parts lists,caps] [--scenes bunny,spot,city,cornell]

Writes benchmarks/results/list-shading-<cuda|cpu>.{json,md} (``--name``): per scene, size and shading, the median
ms of each launch (``--repeats`` timed calls of ``--inner`` launches each, synchronized; warm-up first). No host
work between the launches of one timed call.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import base_parser, git_commit, launch_timer, md_table, write_results  # noqa: E402
from benchmarks.frame import gaze_path, render_path_frame  # noqa: E402

CAPS = {"shade_ao_list_kernel": ("nocap", 64, 56, 48), "shade_list_kernel": ("nocap", 80, 64, 48),
        "shade_full_tiles_kernel": ("nocap", 80, 64, 48)}


def _frame_loop(fw, scene, w, h, dev, ao: int, lanes: int, frames: int):
    """A foveated loop (the "tile" list on every device) advanced ``frames`` frames along the camera path."""
    cfg = fw.Config().with_(shading={"ao_samples": ao, "ao_lanes": lanes}, reorder={"strategy": "tile"})
    loop = fw.FrameLoop(scene, w, h, config=cfg, device=dev, policy="foveated", graph=False)
    for i in range(frames):
        render_path_frame(loop, scene, i, 30, w, h)
    wp.synchronize_device(dev)
    return loop


def _list_array(idx, dev):
    work = wp.array(np.ascontiguousarray(idx, dtype=np.int32), dtype=wp.int32, device=dev)
    return work, wp.array([len(idx)], dtype=wp.int32, device=dev)


def part_lists(fw, scene, w, h, dev, t_ms, lanes: int, frames: int, split=None) -> dict:
    loop = _frame_loop(fw, scene, w, h, dev, 8, lanes, frames)
    st, g = loop.shade, loop.gbuffer
    st.split_direct = split
    rad, rs = loop.radiance, loop.radiance_stoch
    hit = g.hit.numpy() != 0
    n = int(loop.reorder.count.numpy()[0])
    fov = loop.reorder.work.numpy()[:n]
    res = {"n_list": n, "n_hit": int(hit.sum()), "n_px": w * h, "lanes": st.ao_lanes(), "split": st.splits()}

    def list_ms(idx):
        work, count = _list_array(idx, dev)
        return t_ms(lambda: st.list(g, work, count, rad, rs))

    res["fov_list_ms"] = list_ms(fov)
    res["fov_every2_ms"] = list_ms(fov[::2])
    res["fov_every4_ms"] = list_ms(fov[::4])
    pick = np.zeros(w * h, np.uint8)
    surface = np.flatnonzero(hit.ravel())
    pick[np.random.default_rng(1).choice(surface, size=min(n, surface.size), replace=False)] = 1
    mk = wp.array(pick.reshape(h, w), dtype=wp.uint8, device=dev)
    loop.reorder.run(mk)  # the same tile order as the foveated list
    res["uniform_list_ms"] = list_ms(loop.reorder.work.numpy()[:int(loop.reorder.count.numpy()[0])])
    # as many surface pixels, the nearest to the last frame's gaze (Chebyshev distance, ties in raster order), in
    # the tile order: the foveated list's content without its thinning towards the periphery
    gx, gy = gaze_path(frames - 1, 30, w, h)
    ys, xs = np.divmod(surface, w)
    cheb = np.maximum(np.abs(xs + 0.5 - gx), np.abs(ys + 0.5 - gy))
    pick[:] = 0
    pick[surface[np.argsort(cheb, kind="stable")[:n]]] = 1
    loop.reorder.run(wp.array(pick.reshape(h, w), dtype=wp.uint8, device=dev))
    packed = loop.reorder.work.numpy()[:int(loop.reorder.count.numpy()[0])]
    res["gaze_dense_n"] = int(packed.size)

    def reach(idx):  # the farthest listed pixel from the gaze (Chebyshev, pixel centres)
        return float(np.maximum(np.abs(idx % w + 0.5 - gx), np.abs(idx // w + 0.5 - gy)).max(initial=0.0))

    # the n surface pixels nearest the gaze reach no farther than any n surface pixels, the foveated list's included
    res["gaze_dense_max_px"], res["fov_max_px"] = reach(packed), reach(fov)
    res["gaze_dense_list_ms"] = list_ms(packed)
    # the foveated list in a random order: what the tile order is worth
    res["fov_shuffled_ms"] = list_ms(fov[np.random.default_rng(2).permutation(n)])
    loop.reorder.run(wp.array(hit.astype(np.uint8), dtype=wp.uint8, device=dev))
    res["all_hits_list_ms"] = list_ms(loop.reorder.work.numpy()[:int(loop.reorder.count.numpy()[0])])
    res["full_ms"] = t_ms(lambda: st.full(g, rad, rs))
    res["fov_ns_per_px"] = res["fov_list_ms"] / max(n, 1) * 1e6
    res["all_hits_ns_per_px"] = res["all_hits_list_ms"] / max(res["n_hit"], 1) * 1e6
    # the list's share of the frame's shading work: its time over the all-surface list's, against its share of
    # the surface pixels (a list as dear per pixel as the whole frame has equal shares)
    res["fov_time_share"] = res["fov_list_ms"] / res["all_hits_list_ms"] if res["all_hits_list_ms"] > 0 else 0.0
    res["fov_pixel_share"] = n / max(res["n_hit"], 1)
    return res


def _variants():
    """{(kernel name, cap): kernel}: the package's kernel functions compiled again with each cap."""
    import foveawarp.kernels.shade as sh

    out = {}
    for base, caps in CAPS.items():
        k = getattr(sh, base)
        for c in caps:
            if c == "nocap":
                out[(base, c)] = wp.kernel(enable_backward=False, name=f"{base}_study_nocap")(k.func)
            else:
                out[(base, c)] = wp.kernel(enable_backward=False, cuda_max_registers=c,
                                           name=f"{base}_study_r{c}")(k.func)
    return out


def part_caps(fw, scene, w, h, dev, t_ms, variants, frames: int) -> list:
    from foveawarp._util import check_order_width, tile_order_threads

    recs = []
    for ao in (8, 0):
        loop = _frame_loop(fw, scene, w, h, dev, ao, 4, frames)
        st, g, ds = loop.shade, loop.gbuffer, loop.dscene
        work, count = loop.reorder.work, loop.reorder.count
        n = work.shape[0]
        rad, rs = loop.radiance, loop.radiance_stoch
        lanes = st.ao_lanes() if st.ao_lanes() >= 2 else 0
        part = st._ao_part if lanes else st._no_part
        blocks = st._list_blocks()
        sc = st.config
        wlog2 = check_order_width("ShadeStage.order_width", st.order_width) or 0
        res = {"shading": "ao8" if ao else "default", "n_list": int(count.numpy()[0])}

        ao_blocks, ao_block_dim = st._ao_launch_shape()  # the AO lanes launch's own shape, as ShadeStage.list

        def run_ao(k):
            wp.launch(k, dim=n * lanes, inputs=[st.params_dev, work, count, g.position, g.normal, g.hit,
                                                ds.area_lights, part, 0], device=dev, max_blocks=ao_blocks,
                      **({"block_dim": ao_block_dim} if ao_block_dim else {}))

        def run_list(k):
            wp.launch(k, dim=n, inputs=[st.params_dev, work, count, *st.inputs(g), part, lanes, rad, rs, 0],
                      device=dev, max_blocks=blocks)

        def run_full(k):
            wp.launch(k, dim=tile_order_threads(h, w, st.order_width),
                      inputs=[st.params_dev, *st.inputs(g), float(sc.exposure), float(sc.white_point), 0, rad, rs,
                              st._dummy_display, wlog2, 0], device=dev)

        checks = (("shade_ao_list_kernel", run_ao, lambda: part.numpy()),
                  ("shade_list_kernel", run_list, lambda: rad.numpy()),
                  ("shade_full_tiles_kernel", run_full, lambda: rad.numpy()))
        for base, run, read in checks:
            if base == "shade_ao_list_kernel" and not lanes:
                continue
            run(variants[(base, "nocap")])
            wp.synchronize_device(dev)
            want = read().copy()
            for c in CAPS[base]:
                k = variants[(base, c)]
                res[f"{base}_{c}_ms"] = t_ms(lambda: run(k))
                if not np.array_equal(read(), want):
                    raise AssertionError(f"{base} with cap {c} changed the output")
        recs.append(res)
    return recs


def main(argv=None):
    p = base_parser(__doc__)
    p.add_argument("--scenes", default="bunny,spot,city,cornell")
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--parts", default="lists,caps", help="lists,caps")
    p.add_argument("--lanes", type=int, default=None, help="AO lanes of the lists part (default: the config's)")
    p.add_argument("--split", choices=["auto", "on", "off"], default="auto",
                   help="the lists part's ShadeStage.split_direct (auto: the package's rule)")
    p.add_argument("--frames", type=int, default=12, help="frames of the camera path before the timings")
    p.add_argument("--inner", type=int, default=10, help="launches per timed call")
    p.add_argument("--name", default="list-shading")
    args = p.parse_args(argv)
    import foveawarp as fw

    wp.config.quiet = True
    dev = wp.get_device(args.device)
    parts = set(args.parts.split(","))
    if not parts or parts - {"lists", "caps"}:
        p.error(f"--parts items must be in [lists, caps], got {args.parts!r}")
    lanes = fw.ShadingConfig().ao_lanes if args.lanes is None else args.lanes
    fw.ShadingConfig(ao_lanes=lanes)  # a bad --lanes is refused by the config's own check
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    repeats = args.repeats or 25
    if args.quick:
        sizes, repeats, args.inner, args.frames = [(96, 64)], 3, 2, 3
    t_ms = launch_timer(dev, repeats, args.inner, args.warmup)
    variants = _variants() if "caps" in parts else None
    records, rows = [], []
    for name in args.scenes.split(","):
        scene = fw.load_scene(name)
        for w, h in sizes:
            base = {"device": dev.alias, "scene": scene.name, "width": w, "height": h, "commit": git_commit()}
            if "lists" in parts:
                r = {**base, "kind": "lists", **part_lists(fw, scene, w, h, dev, t_ms, lanes, args.frames,
                                                                    {"auto": None, "on": True, "off": False}[args.split])}
                records.append(r)
                rows.append({"scene": name, "size": f"{w}x{h}", "part": "lists", "lanes": r["lanes"], "split": r["split"],
                             "list": r["n_list"], "fov": r["fov_list_ms"], "every2": r["fov_every2_ms"],
                             "every4": r["fov_every4_ms"], "uniform": r["uniform_list_ms"],
                             "gaze_dense": r["gaze_dense_list_ms"], "shuffled": r["fov_shuffled_ms"],
                             "all_hits": r["all_hits_list_ms"], "full": r["full_ms"]})
                print(rows[-1], flush=True)
            if "caps" in parts:
                for r in part_caps(fw, scene, w, h, dev, t_ms, variants, args.frames):
                    records.append({**base, "kind": "caps", **r})
                    print(name, w, r, flush=True)
    md = md_table(rows, list(rows[0])) if rows else ""
    crow = [{"scene": r["scene"], "size": f"{r['width']}x{r['height']}", "shading": r["shading"],
             **{k[:-3]: v for k, v in r.items() if k.endswith("_ms")}} for r in records if r["kind"] == "caps"]
    if crow:
        cols = list(dict.fromkeys(k for r in crow for k in r))
        md += "\n\n" + md_table([{c: r.get(c, "") for c in cols} for r in crow], cols)
    write_results(args.name, dev, {"records": records, "repeats": repeats, "inner": args.inner}, md, args.out)
    print(md)


if __name__ == "__main__":
    main()
