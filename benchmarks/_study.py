"""The frame of the CUDA kernel studies (``ao_segments.py``, ``l2_cold.py``, ``gbuffer_lean.py``): their common
options, the refusal of a non-CUDA device, the loop over scenes and sizes on frames of each camera path, and the
JSON and markdown they write."""

from __future__ import annotations

import numpy as np
import warp as wp

from benchmarks._common import base_parser, git_commit, launch_timer, md_table, write_results


def study_parser(doc: str, name: str, scenes: str, inner: int):
    """``base_parser`` with ``--scenes``, ``--sizes`` (4K and 1080p), ``--frames``, ``--inner`` and ``--name``."""
    p = base_parser(doc)
    p.add_argument("--scenes", default=scenes)
    p.add_argument("--sizes", default="3840x2160,1920x1080")
    p.add_argument("--frames", type=int, default=12, help="frames of the camera path before the timings")
    p.add_argument("--inner", type=int, default=inner, help="launches per timed call")
    p.add_argument("--name", default=name)
    return p


def run_study(p, args, why: str, study, row, rounds: int = 1, setup=None, meta=None) -> list:
    """Refuse a non-CUDA ``--device`` (``why``: what the study is of), then for each round, scene and size record
    ``study(fw, scene, w, h, device, t_ms, frames, *extra)`` with the device, scene, size and commit (``extra``:
    what ``setup(device, args)`` returned, once; ``meta``: more fields of every record) and tabulate
    ``row(record)``. Writes ``--name``'s JSON and markdown; returns the records."""
    import foveawarp as fw

    wp.config.quiet = True
    dev = wp.get_device(args.device)
    if not dev.is_cuda:
        p.error(f"--device must be a CUDA device ({why}), got {args.device!r}")
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    repeats = args.repeats or 15
    t_ms = launch_timer(dev, repeats, args.inner, args.warmup)
    extra = () if setup is None else tuple(setup(dev, args))
    records, rows = [], []
    for rnd in range(rounds):
        for name in args.scenes.split(","):
            scene = fw.load_scene(name)
            for w, h in sizes:
                r = {"device": dev.alias, "scene": scene.name, "width": w, "height": h, "round": rnd,
                     "commit": git_commit(), **(meta or {}), **study(fw, scene, w, h, dev, t_ms, args.frames, *extra)}
                records.append(r)
                rows.append({"scene": name, "size": f"{w}x{h}", **row(r)})
                print(rows[-1], flush=True)
    md = md_table(rows, list(rows[0]))
    write_results(args.name, dev, {"records": records, "repeats": repeats, "inner": args.inner}, md, args.out)
    print(md)
    return records


def alternating(t_ms, fns: dict, rounds: int = 3) -> dict:
    """Time each callable of ``fns`` (name -> fn) with ``t_ms``, taking turns for ``rounds`` rounds, so that drift
    hits them alike: ``{name}_ms_{k}`` for round k and ``{name}_ms``, the median over the rounds."""
    out = {}
    for k in range(rounds):
        for name, fn in fns.items():
            out[f"{name}_ms_{k}"] = t_ms(fn)
    for name in fns:
        out[f"{name}_ms"] = float(np.median([out[f"{name}_ms_{k}"] for k in range(rounds)]))
    return out
