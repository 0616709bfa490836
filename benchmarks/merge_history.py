"""Study (issue 14, session 36): the temporal resolve's history half merged into the sampling pass.

On CUDA the foveated frame makes two passes over every pixel that read the same G-buffer fields: the sampling pass
(``sampling_map_kernel``: probability, saliency, threshold, cache test) before the shading, and the temporal
resolve (``resolve_kernel``, or ``resolve_stoch_boxed_kernel`` with stochastic shading) after it. Only the traced
pixels' resolve needs the shading; every other pixel's (history reused, a miss's background, a hole) could be
resolved in the sampling pass, which has already read the pixel's depth, normal, reprojection and hit, leaving the
traced pixels to a launch over their list (a thread per traced pixel, as the clip boxes are gathered today).

Session 10 built this for deterministic shading in the library (bf3dd3f) and reverted it, slower
(``docs/frame-results.md``); this measures it again with today's kernels, and for the stochastic resolve too.

This times, on frame 12 of each camera path, the package's two passes (as the stages launch them) against the
merged pair: one per-pixel kernel that runs the sampling pass's per-pixel function and then, where the pixel is
not a traced surface, the resolve's per-pixel function; and a list kernel that runs the resolve's function at the
frame's traced pixels (``ReorderStage.work``). Both pairs write scratch copies of the outputs from the same inputs
(the frame's G-buffer, the previous frame's history, the frame's shading and clip boxes, the final sample map after
the tile pass for the list), and the study checks that every output is equal. The merged kernel is compiled with
several register caps (``--caps``; "none": uncapped). Each pair's parts are timed alone too.

    python benchmarks/merge_history.py --device cuda:0 [--scenes bunny,nefertiti,city,cornell] [--shadings ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import SHADINGS  # noqa: E402
from benchmarks._study import alternating, run_study, study_parser  # noqa: E402
from benchmarks.list_shading import _frame_loop  # noqa: E402
from foveawarp.kernels.load import load_u8  # noqa: E402
from foveawarp.kernels.sampling import (FrameParams, SamplingParams, _make_sampling_pixel,  # noqa: E402
                                       sampling_map_kernel)
from foveawarp.kernels.shade import list_pixel  # noqa: E402
from foveawarp.kernels.temporal import TemporalParams, _make_resolve_kernels  # noqa: E402

_KERNELS: dict = {}


def merged_kernels(stochastic: bool, cap):
    """(merged per-pixel kernel, list kernel) for the resolve kind (``stochastic``: the boxed stochastic kind, else
    the deterministic one) and the merged kernel's register cap (None: uncapped); made once per pair."""
    key = (bool(stochastic), cap)
    if key in _KERNELS:
        return _KERNELS[key]
    spix = _make_sampling_pixel(False)
    rpix = _make_resolve_kernels(True, boxed=True)[2] if stochastic else _make_resolve_kernels(False)[2]
    kind = "stoch" if stochastic else "det"

    @wp.kernel(enable_backward=False, grid_stride=False, cuda_max_registers=cap,
               name=f"merged_history_{kind}_{cap or 'nocap'}_kernel", module="unique")
    def merged(
        sp: SamplingParams,
        frame: wp.array(dtype=FrameParams),
        ranks: wp.array2d(dtype=wp.int32),
        lab: wp.array2d(dtype=wp.vec3),
        normal: wp.array2d(dtype=wp.vec3),
        depth: wp.array2d(dtype=float),
        hit: wp.array2d(dtype=wp.uint8),
        position: wp.array2d(dtype=wp.vec3),
        reproj_uv: wp.array2d(dtype=wp.vec2),
        prev_dist: wp.array2d(dtype=float),
        depth_prev: wp.array2d(dtype=float),
        valid_prev: wp.array2d(dtype=wp.uint8),
        face: wp.array2d(dtype=wp.int32),
        face_lab: wp.array(dtype=wp.vec3),
        lab_by_face: int,
        no_map: wp.array2d(dtype=float),
        out_sample: wp.array2d(dtype=wp.uint8),
        out_cache_hit: wp.array2d(dtype=wp.uint8),
        out_prev_index: wp.array2d(dtype=wp.int32),
        tp: TemporalParams,
        moved: wp.array2d(dtype=wp.uint8),
        fresh: wp.array2d(dtype=wp.vec3),
        fresh_stoch: wp.array2d(dtype=wp.vec3),
        normal_prev: wp.array(dtype=wp.vec3),
        meta_prev: wp.array(dtype=wp.int32),
        color_prev: wp.array(dtype=wp.vec3),
        stoch_prev: wp.array(dtype=wp.vec3),
        out_color: wp.array(dtype=wp.vec3),
        out_filled: wp.array2d(dtype=wp.uint8),
        out_depth: wp.array2d(dtype=float),
        out_normal: wp.array(dtype=wp.vec3),
        out_meta: wp.array(dtype=wp.int32),
        out_stoch: wp.array(dtype=wp.vec3),
        box_lo: wp.array2d(dtype=wp.vec3),
        box_hi: wp.array2d(dtype=wp.vec3),
    ):
        y, x = wp.tid()
        spix(x, y, sp, frame[0], ranks, lab, normal, depth, hit, position, reproj_uv, prev_dist, depth_prev,
             valid_prev, 0, face, face_lab, lab_by_face, no_map, no_map, out_sample, out_cache_hit, out_prev_index,
             -1, -1.0, 0)
        # the history half: every pixel but a traced surface (a traced one waits for its shading: the list kernel)
        if load_u8(out_sample, y, x) == wp.uint8(0) or load_u8(hit, y, x) == wp.uint8(0):
            rpix(x, y, tp, out_sample, hit, normal, depth, reproj_uv, prev_dist, moved, fresh, fresh_stoch,
                 depth_prev, normal_prev, meta_prev, color_prev, stoch_prev, out_color, out_filled, out_depth,
                 out_normal, out_meta, out_stoch, box_lo, box_hi)

    @wp.kernel(enable_backward=False, name=f"list_resolve_{kind}_kernel", module="unique")
    def listed(
        work: wp.array(dtype=wp.int32),
        count: wp.array(dtype=wp.int32),
        width: int,
        tp: TemporalParams,
        sample_map: wp.array2d(dtype=wp.uint8),
        hit: wp.array2d(dtype=wp.uint8),
        normal: wp.array2d(dtype=wp.vec3),
        depth: wp.array2d(dtype=float),
        reproj_uv: wp.array2d(dtype=wp.vec2),
        prev_dist: wp.array2d(dtype=float),
        moved: wp.array2d(dtype=wp.uint8),
        fresh: wp.array2d(dtype=wp.vec3),
        fresh_stoch: wp.array2d(dtype=wp.vec3),
        depth_prev: wp.array2d(dtype=float),
        normal_prev: wp.array(dtype=wp.vec3),
        meta_prev: wp.array(dtype=wp.int32),
        color_prev: wp.array(dtype=wp.vec3),
        stoch_prev: wp.array(dtype=wp.vec3),
        out_color: wp.array(dtype=wp.vec3),
        out_filled: wp.array2d(dtype=wp.uint8),
        out_depth: wp.array2d(dtype=float),
        out_normal: wp.array(dtype=wp.vec3),
        out_meta: wp.array(dtype=wp.int32),
        out_stoch: wp.array(dtype=wp.vec3),
        box_lo: wp.array2d(dtype=wp.vec3),
        box_hi: wp.array2d(dtype=wp.vec3),
    ):
        i = wp.tid()
        if i >= count[0]:
            return
        x, y = list_pixel(work[i], width)
        rpix(x, y, tp, sample_map, hit, normal, depth, reproj_uv, prev_dist, moved, fresh, fresh_stoch, depth_prev,
             normal_prev, meta_prev, color_prev, stoch_prev, out_color, out_filled, out_depth, out_normal, out_meta,
             out_stoch, box_lo, box_hi)

    _KERNELS[key] = (merged, listed)
    return _KERNELS[key]


def _caps(text: str) -> list:
    out = []
    for c in text.split(","):
        out.append(None if c == "none" else int(c))
    return out


def study(fw, scene, w, h, dev, t_ms, frames: int, shadings, caps) -> dict:
    res = {}
    for shading in shadings:
        ao = int(SHADINGS[shading].get("shading", {}).get("ao_samples", 0))
        loop = _frame_loop(fw, scene, w, h, dev, ao, 4, frames)
        res[shading] = _compare(loop, w, h, dev, t_ms, caps)
    return res


def _compare(loop, w, h, dev, t_ms, caps) -> dict:
    s, t, g, r = loop.sampling, loop.temporal, loop.gbuffer, loop.reorder
    kind = loop._resolve_kind()
    stochastic = kind["stochastic"]
    prev = 1 - t._cur  # the frame just rendered read this history and wrote the other (then swapped)
    dp, vp, table, by_face = s._frame_inputs(g, t._depth[prev], t._filled[prev], loop.dscene.face_lab)
    tp = t.params(use_history=True, stochastic=stochastic, background=loop.config.shading.background,
                  samples=kind["samples"])
    hist = [t._depth[prev], t._normal[prev], t._meta[prev], t._color_flat[prev], t._stoch[prev]]
    cur = 1 - prev
    if stochastic:
        box_lo, box_hi = t._boxes()
    else:
        box_lo = box_hi = t._no_box

    def scratch_sampling():
        return [wp.empty_like(a) for a in (s.sample_map, s.cache_hit, s.prev_index)]

    def scratch_resolve():
        return [wp.zeros_like(a) for a in (t._color_flat[cur], t._filled[cur], t._depth[cur], t._normal[cur],
                                           t._meta[cur], t._stoch[cur])]

    s_args = [s.params, s.frame_params, s.ranks, s.lab, g.normal, g.depth, g.hit, g.position, g.reproj_uv,
              g.prev_dist, dp, vp, 0, g.face, table, by_face]
    pkg_s = scratch_sampling()
    pkg_r = scratch_resolve()
    pkg_resolve = _make_resolve_kernels(True, boxed=True)[0] if stochastic else _make_resolve_kernels(False)[0]
    r_in = [tp, s.sample_map, g.hit, g.normal, g.depth, g.reproj_uv, g.prev_dist, g.moved, loop.radiance,
            loop.radiance_stoch, *hist]

    def pkg_sampling():
        wp.launch(sampling_map_kernel, dim=(h, w), inputs=s_args,
                  outputs=[s._dummy_map, s._dummy_map, *pkg_s, s.tile_counts, 0], device=dev)

    def pkg_resolve_pass():
        wp.launch(pkg_resolve, dim=(h, w), inputs=r_in, outputs=[*pkg_r, box_lo, box_hi, 0], device=dev)

    def pkg():
        pkg_sampling()
        pkg_resolve_pass()

    m_s = scratch_sampling()
    m_r = scratch_resolve()
    l_in = [r.work, r.count, w, tp, s.sample_map, g.hit, g.normal, g.depth, g.reproj_uv, g.prev_dist, g.moved,
            loop.radiance, loop.radiance_stoch, *hist]
    variants = {}
    for cap in caps:
        mk, lk = merged_kernels(stochastic, cap)
        m_in = [s.params, s.frame_params, s.ranks, s.lab, g.normal, g.depth, g.hit, g.position, g.reproj_uv,
                g.prev_dist, dp, vp, g.face, table, by_face, s._dummy_map, *m_s, tp, g.moved, loop.radiance,
                loop.radiance_stoch, t._normal[prev], t._meta[prev], t._color_flat[prev], t._stoch[prev], *m_r,
                box_lo, box_hi]

        def merged_pass(mk=mk, m_in=m_in):
            wp.launch(mk, dim=(h, w), inputs=m_in, device=dev)

        def list_pass(lk=lk):
            wp.launch(lk, dim=r.work.shape[0], inputs=[*l_in, *m_r, box_lo, box_hi], device=dev)

        variants[cap or "nocap"] = (merged_pass, list_pass)

    # equality: every variant's outputs against the package's, from the same inputs
    pkg()
    for name, (mp, lp) in variants.items():
        for a in m_r:
            a.zero_()
        mp()
        lp()
        wp.synchronize_device(dev)
        for a, b, what in zip([*pkg_s, *pkg_r], [*m_s, *m_r], ("sample", "cache_hit", "prev_index", "color",
                                                                  "filled", "depth", "normal", "meta", "stoch")):
            if not np.array_equal(a.numpy(), b.numpy()):
                raise AssertionError(f"merged ({name}): {what} differs from the package's two passes")
    n = int(r.count.numpy()[0])
    out = {"stochastic": stochastic, "n_list": n, "traced_fraction": n / (w * h),
           "pkg_sampling_ms": t_ms(pkg_sampling), "pkg_resolve_ms": t_ms(pkg_resolve_pass)}
    out.update(alternating(t_ms, {"pkg": pkg, **{f"merged_{name}": (lambda mp=mp, lp=lp: (mp(), lp()))
                                                 for name, (mp, lp) in variants.items()}}))
    for name, (mp, lp) in variants.items():
        out[f"merged_{name}_pixel_ms"] = t_ms(mp)
        out[f"merged_{name}_list_ms"] = t_ms(lp)
    out["variants"] = list(variants)
    return out


def _row(r: dict) -> dict:
    row = {}
    for shading, v in r.items():
        if not isinstance(v, dict):
            continue
        row[f"{shading}: package ms"] = v["pkg_ms"]
        for name in v["variants"]:
            row[f"{shading}: merged {name} / package"] = v[f"merged_{name}_ms"] / v["pkg_ms"]
    return row


def main(argv=None):
    p = study_parser(__doc__, "merge-history", "bunny,nefertiti,city,cornell", 10)
    p.add_argument("--shadings", default="default,ao8")
    p.add_argument("--caps", default="none,48,64", help="register caps of the merged kernel (none: uncapped)")
    args = p.parse_args(argv)
    shadings = [x for x in args.shadings.split(",") if x]
    if not shadings or any(x not in SHADINGS for x in shadings):
        p.error(f"--shadings must be a comma list of {', '.join(SHADINGS)}, got {args.shadings!r}")
    try:
        caps = _caps(args.caps)
        if not caps or any(c is not None and not 16 <= c <= 255 for c in caps):
            raise ValueError
    except ValueError:
        p.error(f"--caps must be a comma list of 'none' or integers in [16, 255], got {args.caps!r}")
    run_study(p, args, "the study times CUDA kernels", lambda *a: study(*a, shadings, caps), _row)


if __name__ == "__main__":
    main()
