"""Is the foveated frame faster than full-resolution tracing, and how close is it?

Per scene x size x shading (``--ao-samples``: AO rays per pixel, 0 = the default direct shading), along the
scene's camera path (1/30 s a frame) with a moving gaze (a Lissajous figure):

* timing: the full-resolution reference (``FrameLoop(policy="full")``), the foveated frame forced on
  (``policy="foveated"``) and the default policy ("auto"), timed the same way in one run: synchronized frames
  after warm-up (on CUDA each steady-state frame is one CUDA-graph replay), medians of ``--timing-frames``
  frames, the three loops taking turns frame by frame in a new seeded order every frame (``--turns blocks``:
  in blocks of consecutive frames); speed-up = reference ms / foveated ms; per-stage ms of a ``timing=True``
  loop (and of ``timing="gpu"`` on CUDA);
* quality: per-frame PSNR, SSIM, fovea PSNR (eccentricity <= 5 deg of the gaze) and FLIP (when the optional
  ``flip-evaluator`` is installed) of the foveated frame, with their mean and min over ``--frames`` frames, and
  FovVideoVDP (when the optional ``pyfvvdp`` is installed; ``--fvvdp-max-pixels``) of the whole video in its
  foveated mode with each frame's gaze, in JOD (10 = no visible difference).
  Target: ``render_reference`` of the same camera, time and gaze; with stochastic shading the target is a
  converged frame (``--converged-ao`` AO rays per pixel, ``--converged-samples`` samples per area light and of a
  textured scene's environment), and the full-resolution frame with the foveated frame's shading gets its own
  error against it too (so both sit on the time-vs-error plot).
* ``--configs``: other foveation settings as ``name=python-dict`` Config.with_ overrides, each its own record.
* ``--keep FILE.json``: the records of an earlier frame JSON that this run does not repeat stay in the output,
  each with its own ``commit`` (a re-run of some scenes replaces only theirs).

Writes frame-<tag>.json / .md and frame-<tag>.png (x = frame ms, y = PSNR: foveated and reference points).

``--summarize FILE.json`` renders nothing: it prints the README's results table from a frame JSON (with
``--readme README.md`` it writes the table between the README's results markers instead).
"""

from __future__ import annotations

import ast
import json
import math
import sys
import textwrap
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
import warp as wp  # noqa: E402

from benchmarks._common import (REPO, base_parser, git_commit, kept_records, md_table, parse_sizes,  # noqa: E402
                                plot_path, progress, pyplot, save_grid, scenes_present, write_results)

ALL_SCENES = "cornell,city,eyechart,earth,bunny,spot,teapot,nefertiti,ogre"
CANONICAL = ("python benchmarks/frame.py --device cuda:0 --out benchmarks/results --tag h200 "
             "--scenes cornell,bunny --sizes 1920x1080,3840x2160 --ao-samples 0,8 --frames 20 --timing-frames 20")


def gaze_path(i, n, w, h):
    """A moving gaze: a Lissajous figure over the central 60 % x 40 % of the screen."""
    t = i / max(n, 1)
    return (w * (0.5 + 0.3 * math.sin(2 * math.pi * t)), h * (0.5 + 0.2 * math.sin(4 * math.pi * t + 0.5)))


def render_path_frame(loop, scene, i: int, n: int, w: int, h: int):
    """``loop`` renders frame ``i`` of the scene's camera path (time i / 30 s) with the gaze of ``gaze_path(i, n)``;
    returns the frame."""
    t = i / 30.0
    return loop.render(scene.camera_at(t), gaze_px=gaze_path(i, n, w, h), time=t)


def _psnr_only(img, ref, g, fov):
    """PSNR of the whole frame and of the fovea (<= 5 deg) on the host, SSIM left out (fast sweeps)."""
    from foveawarp.metrics import psnr, region_masks

    a, b = img.numpy(), ref.numpy()
    h, w = a.shape[:2]
    masks = region_masks(w, h, g, fov)
    out = {"psnr": psnr(a, b), "ssim": float("nan")}
    for k, mk in masks.items():
        out[f"psnr_{k}"] = psnr(a, b, mask=mk) if mk.any() else float("nan")
    return out


def _metric_fn(fast=False):
    import foveawarp.metrics as m

    if fast:
        return _psnr_only, "host-psnr-only"

    dev_fn = getattr(m, "region_metrics_device", None)
    if dev_fn is not None:
        return dev_fn, "device"
    return (lambda img, ref, g, fov: m.region_metrics(img.numpy(), ref.numpy(), g, fov)), "host"


def _fovea_key(d):
    for k in ("psnr_fovea", "fovea_psnr"):
        if k in d:
            return d[k]
    return float("nan")


def _summ(v):
    a = np.asarray(v, float)
    f = a[np.isfinite(a)]
    cap = np.minimum(a, 100.0)  # identical frames (inf dB) count as 100 dB in means
    return {"mean": float(np.mean(cap)), "min": float(np.min(a)) if a.size else float("nan"),
            "finite_min": float(np.min(f)) if f.size else float("inf")}


def _timed_interleaved(loops: dict, scene, w, h, n, warm: dict, seed: int = 0) -> dict:
    """Median synchronized frame ms of each loop, the loops taking turns frame by frame (frame i of every loop
    renders the same camera, time and gaze), so that clock and load drift hit them alike. ``warm``: frames each
    loop renders first, untimed (the "auto" loop's include its policy measurement).

    The turns come in a new order every frame (a permutation drawn from ``seed``): a loop that always renders
    right after the same other loop pays for it (the host's caches hold the other loop's state; with a fixed
    order the auto loop's full-resolution frames measured up to 1.05x the reference's on an H100, shuffled
    1.00-1.01x)."""
    t0_frame = _warm_up(loops, scene, w, h, n, warm)  # one timeline: every warm-up ends where the timed frames begin
    ms = {name: [] for name in loops}
    names = list(loops)
    rng = np.random.default_rng(seed)
    for i in range(t0_frame, t0_frame + n):
        for j in rng.permutation(len(names)):
            ms[names[j]].append(_timed_frame(loops[names[j]], scene, i, n, w, h))
    return {name: float(np.median(v)) for name, v in ms.items()}


def _timed_frame(loop, scene, i: int, n: int, w: int, h: int) -> float:
    """Synchronized wall ms of ``loop`` rendering frame ``i`` of the camera path (its time, camera and gaze)."""
    t = i / 30.0
    g = gaze_path(i, n, w, h)
    wp.synchronize_device(loop.device)
    t_start = time.perf_counter()
    # each loop gets its own camera object, made inside the timed region as an application would: a camera shared
    # by the loops carries its cached basis and kernel parameters from the first loop that used it to the others
    # (the first loop paid 0.10-0.20 ms more per frame on an H100)
    loop.render(scene.camera_at(t), gaze_px=g, time=t)
    wp.synchronize_device(loop.device)
    return (time.perf_counter() - t_start) * 1e3


TURNS = ("frames", "blocks")
BLOCK_FRAMES, BLOCK_SKIP = 10, 2


def _warm_up(loops: dict, scene, w, h, n, warm: dict) -> int:
    """Render each loop's ``warm`` frames, untimed, so that every warm-up ends where the timed frames begin; returns
    that frame index."""
    t0_frame = max(warm.values())
    for name, loop in loops.items():
        for i in range(t0_frame - warm[name], t0_frame):
            render_path_frame(loop, scene, i, n, w, h)
    return t0_frame


def _timed_blocks(loops: dict, scene, w, h, n, warm: dict, block: int = BLOCK_FRAMES, skip: int = BLOCK_SKIP,
                  seed: int = 0) -> dict:
    """Median synchronized frame ms of each loop, the loops taking turns block by block: in each round every loop
    (in a new seeded order) renders the same ``block`` consecutive frames of the camera path (camera, time, gaze),
    each synchronized and timed as ``_timed_interleaved`` times them; the first ``skip`` frames of a turn are left
    out of the medians. Rounds go on until every loop has at least ``n`` timed frames.

    This is how an application runs one loop: frame after frame with nothing else on the GPU between them, so the
    data a frame leaves in the GPU's caches (the history, the previous depth, the BVH) is there for the next one.
    In ``_timed_interleaved`` every frame follows another loop's frame, which evicts it. Alternating blocks keeps
    what that scheme is for: clock and load drift hit the loops alike. The two schedules' speed-ups agree within
    2.5 % (H100, 9 scenes x 2 sizes x 2 shadings)."""
    if not 0 <= skip < block:
        raise ValueError(f"skip must be in [0, block - 1] = [0, {block - 1}], got {skip}")
    t0_frame = _warm_up(loops, scene, w, h, n, warm)
    ms = {name: [] for name in loops}
    names = list(loops)
    rng = np.random.default_rng(seed)
    rounds = -(-n // (block - skip))
    for r in range(rounds):
        f0 = t0_frame + r * block
        for j in rng.permutation(len(names)):
            for i in range(f0, f0 + block):
                frame_ms = _timed_frame(loops[names[j]], scene, i, n, w, h)
                if i - f0 >= skip:
                    ms[names[j]].append(frame_ms)
    return {name: float(np.median(v)) for name, v in ms.items()}


def timing(fw, scene, w, h, dev, cfg, n, turns=("frames",)):
    """The timing part's records for one scene, size and configuration: one per item of ``turns`` ("frames":
    ``_timed_interleaved``, "blocks": ``_timed_blocks``), each with its own fresh loops and the same camera path,
    and the per-stage times (timing runs, measured once) in every one."""
    bad = [t for t in turns if t not in TURNS]
    if bad or not turns:
        raise ValueError(f"turns items must be in {list(TURNS)}, got {list(turns)}")
    outs = [_timing_turns(fw, scene, w, h, dev, cfg, n, t) for t in turns]
    traced_keys = ("gbuffer", "shade", "indirect", "indirect_build")

    def stage_run(timing_mode):
        """Median per-stage ms of frames 6-15 of a ``timing=timing_mode`` foveated loop, the mean sampling
        rate, and the loop."""
        tl = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=timing_mode, policy="foveated")
        stages, rates = {}, []
        for i in range(16):
            f = render_path_frame(tl, scene, i, 16, w, h)
            if i >= 6:
                rates.append(f.stats["sampling_rate"])
                for k, v in f.stats.items():
                    if k.startswith("ms_") and k != "ms_frame":
                        stages.setdefault(k[3:], []).append(v)
        return {k: float(np.median(v)) for k, v in stages.items()}, rates, tl

    def overheads(fov_ms, stage_ms):
        traced = sum(stage_ms.get(k, 0.0) for k in traced_keys)
        return (float(max(fov_ms - traced, 0.0)),
                float(sum(v for k, v in stage_ms.items() if k not in traced_keys + ("scene",))))

    stage_ms, rates, tl = stage_run(True)
    # the same from CUDA-event stage times (timing="gpu": one synchronization per frame, no per-stage
    # synchronization inflating the small stages; a stage's host work that overlaps earlier kernels left out)
    gpu_ms = stage_run("gpu")[0] if dev.is_cuda else None
    for out in outs:
        overhead, stage_sum = overheads(out["fov_ms"], stage_ms)
        out.update(stage_ms=stage_ms, overhead_ms=overhead, overhead_stage_sum_ms=stage_sum,
                   timing_sampling_rate=float(np.mean(rates)),
                   bvh=[tl.dscene.bvh_constructor, tl.dscene.bvh_leaf_size])  # the tree built (after any fallback)
        if gpu_ms is not None:
            out["stage_gpu_ms"] = gpu_ms
            out["overhead_gpu_ms"], out["overhead_stage_sum_gpu_ms"] = overheads(out["fov_ms"], gpu_ms)
    return outs


def _timing_turns(fw, scene, w, h, dev, cfg, n, turns: str) -> dict:
    """Reference, foveated and default-policy frame times of new loops, timed with ``turns``."""
    loops = {"full": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="full"),
             "foveated": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated"),
             "auto": fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False)}
    auto = loops["auto"]
    # the auto loop measures both paths over its first frames; its timed frames come after (no re-measurement
    # falls inside them: POLICY_PERIOD is far longer)
    warm = {"full": 8, "foveated": 8, "auto": auto.policy_measurement_frames() + 2}
    timed = _timed_interleaved if turns == "frames" else _timed_blocks
    med = timed(loops, scene, w, h, n, warm)
    out = {"turns": turns, "ref_ms": med["full"], "fov_ms": med["foveated"], "auto_ms": med["auto"],
           "auto_path": auto._pol_choice, "auto_estimates": dict(auto._pol_est),
           "speedup": med["full"] / med["foveated"]}
    if turns == "blocks":
        out["block_frames"], out["block_skip"] = BLOCK_FRAMES, BLOCK_SKIP
    return out


def _with_flip(metrics):
    """``metrics`` plus the mean FLIP error (host) where flip-evaluator is installed."""
    from foveawarp.metrics import flip, flip_available

    if not flip_available():
        return metrics, False

    def both(img, ref, g, fov):
        m = dict(metrics(img, ref, g, fov))
        m["flip"] = flip(img.numpy(), ref.numpy())
        return m

    return both, True


SERIES = ("psnr", "ssim", "fovea_psnr", "flip")  # per frame; "fovvdp" (one value per video) joins them


def path_quality(fw, scene, w, h, dev, cfg, frames, metrics, converged_ao=0, converged_area=0, video=False):
    """Per-frame error series along the camera path with the moving gaze: ``fov`` of the foveated frame (history
    on, ``policy="foveated"``) and, where ``cfg``'s shading is stochastic (AO rays; area-light or environment
    samples), ``ref`` of the full-resolution frame with ``cfg``'s shading, both against a converged frame
    (``converged_ao`` AO rays per pixel where ``cfg`` has AO rays, ``converged_area`` samples per area light and
    of the environment where it has those); with deterministic shading the target is ``render_reference`` of
    ``cfg`` and ``ref`` is None (the reference is the target). Also the sampling rates and ``target`` (what the
    target is); with ``video``, FovVideoVDP (``foveawarp.metrics.fovvdp``) of each whole video against the
    target's, as ``fovvdp`` (one value per series)."""
    fov_deg = scene.camera.fov_y_deg
    fovl = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="foveated")
    sc = cfg.shading
    over = {}
    if fovl.shade.stochastic():
        if sc.ao_samples and converged_ao:
            over["ao_samples"] = int(converged_ao)
        if fovl.shade.stochastic_samples() > sc.ao_samples and converged_area:
            over["area_light_samples"] = int(converged_area)
    target_cfg = cfg.with_(shading=over) if over else cfg
    target = fw.FrameLoop(scene, w, h, config=target_cfg, device=dev, timing=False, policy="foveated")
    full = fw.FrameLoop(scene, w, h, config=cfg, device=dev, timing=False, policy="full") if over else None
    names = {"ao_samples": "AO rays", "area_light_samples": "light and environment samples"}
    what = " + ".join(f"{v} {names[k]}" for k, v in over.items()) or "render_reference"
    tgt = wp.zeros((h, w), dtype=wp.vec3, device=dev)
    out = {"fov": {k: [] for k in SERIES}, "ref": {k: [] for k in SERIES} if full else None, "sampling_rate": [],
           "target": what}
    vids = {"target": [], "fov": [], "ref": [], "gaze": []} if video else None

    def add(series, m):
        series["psnr"].append(m["psnr"])
        series["ssim"].append(m["ssim"])
        series["fovea_psnr"].append(_fovea_key(m))
        if "flip" in m:
            series["flip"].append(m["flip"])

    for i in range(frames):
        t = i / 30.0
        g = gaze_path(i, frames, w, h)
        wp.copy(tgt, target.render_reference(scene.camera_at(t), time=t, gaze_px=g).image)
        f = fovl.render(scene.camera_at(t), gaze_px=g, time=t)
        add(out["fov"], metrics(f.image, tgt, g, fov_deg))
        out["sampling_rate"].append(f.stats["sampling_rate"])
        if vids is not None:
            vids["target"].append(tgt.numpy().copy())
            vids["fov"].append(f.image.numpy().copy())
            vids["gaze"].append(g)
        if full is not None:
            fr = full.render(scene.camera_at(t), gaze_px=g, time=t).image
            add(out["ref"], metrics(fr, tgt, g, fov_deg))
            if vids is not None:
                vids["ref"].append(fr.numpy().copy())
    if vids is not None:
        from foveawarp.metrics import fovvdp

        for key in ("fov", "ref"):
            if out[key] is not None:
                out[key]["fovvdp"] = [fovvdp(np.stack(vids[key]), np.stack(vids["target"]), np.array(vids["gaze"]),
                                             fov_deg)]
    return out


def _summary(prefix: str, series: dict) -> dict:
    """Mean and min (max for FLIP, an error) of each series; identical frames (inf dB) count as 100 dB in
    means. FovVideoVDP, one value per video, as ``fovvdp_jod``."""
    out = {}
    for k, v in series.items():
        if not v:
            continue
        if k == "fovvdp":
            out[f"{prefix}fovvdp_jod"] = float(v[0])
            continue
        s = _summ(v)
        out[f"{prefix}{k}_mean"] = s["mean"]
        if k == "flip":
            out[f"{prefix}flip_max"] = float(np.max(v))
        else:
            out[f"{prefix}{k}_min"] = s["min"]
    return out


def _parse_configs(p, text: str) -> list:
    configs = []
    for item in [s for s in text.split(";") if s.strip()]:
        name, _, lit = item.partition("=")
        try:
            over = ast.literal_eval(lit) if lit.strip() else {}
        except (ValueError, SyntaxError):
            over = None
        if not name.strip() or not isinstance(over, dict):
            p.error(f"--configs must be ';'-separated name=python-dict items, got {item!r}")
        configs.append((name.strip(), over))
    return configs or [("default", {})]


# the README's results at a glance lie between these two lines; tests/test_readme.py checks them against the JSON
README_BEGIN = ("<!-- results: python benchmarks/frame.py --summarize benchmarks/results/frame-h200.json "
                "--readme README.md -->")
README_END = "<!-- /results -->"


def _num(v, fmt: str) -> str:
    return "n/a" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def summarize(json_path, base=REPO) -> str:
    """The README's results table from a frame JSON: one row per record that was both timed and measured
    (reference, foveated and default-policy ms, speed-up, PSNR mean / min, SSIM and FLIP means, FovVideoVDP JOD),
    a line naming the device and the conditions, and the time-vs-error plot beside the JSON (its path relative to ``base``)."""
    import json

    path = Path(json_path)
    d = json.loads(path.read_text())
    if d.get("benchmark") != "frame":
        raise ValueError(f"{path} is not a frame.py result (benchmark {d.get('benchmark')!r}); pass frame-<tag>.json")
    recs = [r for r in d["records"] if "fov_ms" in r and "psnr_mean" in r]
    if not recs:
        raise ValueError(f"{path} has no record with both timing and quality (run frame.py with --frames and "
                         f"--timing-frames > 0)")
    configs = len({r["config"] for r in recs}) > 1
    rows = []
    for r in recs:
        row = {"scene": r["scene"], "size": f"{r['width']}x{r['height']}"}
        if configs:
            row["config"] = r["config"]
        row.update({"AO rays": str(r["ao_samples"]), "reference ms": _num(r["ref_ms"], ".2f"),
                    "foveated ms": _num(r["fov_ms"], ".2f"), "speed-up": _num(r["speedup"], ".2f") + "x",
                    "default policy": f"{_num(r['auto_ms'], '.2f')} ms ({r['auto_path']})",
                    "PSNR dB mean / min": f"{_num(r['psnr_mean'], '.1f')} / {_num(r['psnr_min'], '.1f')}",
                    "SSIM mean": _num(r.get("ssim_mean"), ".3f")})
        if any("flip_mean" in x for x in recs):
            row["FLIP mean"] = _num(r.get("flip_mean"), ".3f")
        if any("fovvdp_jod" in x for x in recs):
            row["FovVideoVDP JOD"] = _num(r.get("fovvdp_jod"), ".2f")
        rows.append(row)
    cols = list(rows[0])
    table = "| " + " | ".join(cols) + " |\n|" + "|".join("---" for _ in cols) + "|\n"
    table += "".join("| " + " | ".join(r[c] for c in cols) + " |\n" for r in rows)
    png = path.with_suffix(".png")
    try:
        rel = png.resolve().relative_to(Path(base).resolve()).as_posix()
    except ValueError:
        rel = png.as_posix()
    targets = sorted({r["quality_target"] for r in recs if r["ao_samples"]})
    lead = (f"On {d['device']}, Warp {d['warp']}: frame ms are medians of {d['timing_frames']} synchronized frames "
            f"along each scene's camera path with a moving gaze; errors are over {d['frames']} frames of the same "
            f"path, against the full-resolution `render_reference` of the same camera, time and gaze"
            + (f" (with AO rays: a frame converged with {' / '.join(targets)} per pixel)" if targets else "")
            + f". From `{path.name}`; how it is measured: [docs/performance.md](docs/performance.md).")
    lead = textwrap.fill(lead, 116, break_on_hyphens=False, break_long_words=False)
    return f"{lead}\n\n{table}\n![frame time against PSNR]({rel})\n"


def write_readme(readme, text: str) -> None:
    """Replace what lies between the README's results markers with ``text``; a README without both markers is
    refused (ValueError naming them)."""
    readme = Path(readme)
    s = readme.read_text()
    a, b = s.find(README_BEGIN), s.find(README_END)
    if a < 0 or b < a:
        raise ValueError(f"{readme} lacks the results markers {README_BEGIN!r} ... {README_END!r}")
    readme.write_text(s[:a + len(README_BEGIN)] + "\n" + text + s[b:])


def readme_results(text: str):
    """What lies between the results markers of a README's text (stripped), or None without the markers."""
    a, b = text.find(README_BEGIN), text.find(README_END)
    return None if a < 0 or b < a else text[a + len(README_BEGIN):b].strip()


def main(argv=None):
    p = base_parser(__doc__, CANONICAL)
    p.add_argument("--summarize", default=None, metavar="FILE.json",
                   help="print the README's results table from a frame JSON (renders nothing)")
    p.add_argument("--readme", default=None, help="with --summarize: write the table into this README instead")
    p.add_argument("--scenes", default=ALL_SCENES)
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--ao-samples", default="0,8", help="comma list of AO rays per pixel (0: the default shading)")
    p.add_argument("--converged-ao", type=int, default=256,
                   help="AO rays per pixel of the quality target when --ao-samples > 0 (above every item, <= 4096)")
    p.add_argument("--converged-samples", type=int, default=256,
                   help="samples per area light and of the environment of the quality target where the shading "
                        "samples them (area lights, textured scenes with an environment), in [1, 256]")
    p.add_argument("--keep", default=None, metavar="FILE.json",
                   help="a frame JSON whose records this run does not repeat (scene, size, config, AO) are kept "
                        "in the output, each with its own commit")
    p.add_argument("--frames", type=int, default=30, help="frames of the quality series (0: no quality)")
    p.add_argument("--timing-frames", type=int, default=30, help="timed frames per loop (0: no timing)")
    p.add_argument("--turns", default="frames", choices=TURNS,
                   help="the loops take turns frame by frame (frames) or in blocks of %d frames (blocks)"
                        % BLOCK_FRAMES)
    p.add_argument("--configs", default="default={}",
                   help="';'-separated name=python-dict Config.with_ overrides, e.g. "
                        "\"default={};mar0.034={'foveation': {'mar_slope': 0.034}}\"")
    p.add_argument("--psnr-only", action="store_true", help="host PSNR only, no SSIM (fast sweeps)")
    p.add_argument("--fvvdp-max-pixels", type=int, default=1920 * 1080,
                   help="FovVideoVDP of sizes up to this many pixels, when pyfvvdp is installed (0: none)")
    args = p.parse_args(argv)
    if args.readme and not args.summarize:
        p.error("--readme goes with --summarize FILE.json")
    if args.summarize:
        if not Path(args.summarize).is_file():
            p.error(f"--summarize must name a frame JSON, got {args.summarize!r} (no such file)")
        try:
            text = summarize(args.summarize)
            if args.readme:
                write_readme(args.readme, text)
        except ValueError as e:
            p.error(str(e))
        print(text, end="")
        return []
    import foveawarp as fw

    wp.config.quiet = True
    dev = wp.get_device(args.device)
    try:
        aos = [int(v) for v in args.ao_samples.split(",") if v.strip()]
    except ValueError:
        aos = []
    if not aos or any(not 0 <= a <= 256 for a in aos):
        p.error(f"--ao-samples must be a comma list of integers in [0, 256], got {args.ao_samples!r}")
    if not max(aos) < args.converged_ao <= 4096:
        p.error(f"--converged-ao must be in [{max(aos) + 1}, 4096] (above every --ao-samples), got "
                f"{args.converged_ao}")
    if not 1 <= args.converged_samples <= 256:
        p.error(f"--converged-samples must be in [1, 256], got {args.converged_samples}")
    kept = _kept_records(p, args.keep)
    if args.frames < 0 or args.timing_frames < 0:
        p.error(f"--frames and --timing-frames must be >= 0, got {args.frames} and {args.timing_frames}")
    if args.fvvdp_max_pixels < 0:
        p.error(f"--fvvdp-max-pixels must be >= 0, got {args.fvvdp_max_pixels}")
    sizes = parse_sizes(p, args.sizes)
    configs = _parse_configs(p, args.configs)
    if args.quick:
        sizes, args.frames, args.timing_frames = [(64, 36)], min(args.frames, 3), min(args.timing_frames, 3)
        args.converged_ao = min(args.converged_ao, max(16, max(aos) + 1))
    metrics, where = _metric_fn(args.psnr_only)
    metrics, with_flip = _with_flip(metrics)
    from foveawarp.metrics import fovvdp_available

    with_fvvdp = args.fvvdp_max_pixels > 0 and fovvdp_available()
    scenes = list(scenes_present(fw, args.scenes))
    cases = [(s, wh, c, a) for s in scenes for wh in sizes for c in configs for a in aos]
    records, rows = [], []
    for scene, (w, h), (cname, over), ao in progress(cases, "frame"):
        base_cfg = fw.Config().with_(**over) if over else fw.Config()
        cfg = base_cfg.with_(shading={"ao_samples": ao}) if ao else base_cfg
        t0 = time.perf_counter()
        rec = {"scene": scene.name, "width": w, "height": h, "config": cname, "overrides": over, "ao_samples": ao,
               "metrics_on": where + ("+flip" if with_flip else "") + ("+fovvdp" if with_fvvdp else ""),
               "frames": args.frames,
               "timing_frames": args.timing_frames}
        if args.frames:
            q = path_quality(fw, scene, w, h, dev, cfg, args.frames, metrics, args.converged_ao,
                             args.converged_samples, video=with_fvvdp and w * h <= args.fvvdp_max_pixels)
            rec.update(sampling_rate=float(np.mean(q["sampling_rate"])), sampling_rate_series=q["sampling_rate"],
                       quality_target=q["target"],
                       **_summary("", q["fov"]),
                       series={k: v for k, v in q["fov"].items() if v and k != "fovvdp"})
            if q["ref"] is not None:
                rec.update(**_summary("ref_", q["ref"]),
                           ref_series={k: v for k, v in q["ref"].items() if v and k != "fovvdp"})
        if args.timing_frames:
            (tm,) = timing(fw, scene, w, h, dev, cfg, args.timing_frames, (args.turns,))
            tm["auto_speedup"] = tm["ref_ms"] / tm["auto_ms"]
            rec.update(tm)
        rec["seconds"] = time.perf_counter() - t0
        records.append(rec)
    commit = git_commit()
    for r in records:
        r["commit"] = commit
    done = {_record_key(r) for r in records}
    kept = [r for r in kept if _record_key(r) not in done]
    records = kept + records
    rows = [_table_row(r) for r in records]
    cols = list(dict.fromkeys(k for r in rows for k in r))
    md = md_table(rows, cols)
    write_results("frame", dev, records, md, args.out, args.tag,
                  extra={"frames": args.frames, "timing_frames": args.timing_frames, "turns": args.turns,
                         "kept_from": args.keep and Path(args.keep).name, "kept_records": len(kept)})
    plot(records, plot_path("frame", dev, args.out, args.tag), dev)
    print(md)
    return records


def _record_key(r: dict) -> tuple:
    return r["scene"], int(r["width"]), int(r["height"]), r.get("config", "default"), int(r.get("ao_samples", 0))


def _table_row(rec: dict) -> dict:
    row = {"scene": rec["scene"], "size": f"{rec['width']}x{rec['height']}", "config": rec.get("config", "default"),
           "ao": rec.get("ao_samples", 0)}
    for k in ("sampling_rate", "ref_ms", "fov_ms", "speedup", "auto_ms", "auto_path", "psnr_mean", "psnr_min",
              "ssim_mean", "fovea_psnr_mean", "fovea_psnr_min", "flip_mean", "fovvdp_jod", "ref_psnr_mean"):
        if k in rec:
            row[k] = rec[k]
    return row


def _kept_records(p, path) -> list:
    """The records of ``--keep FILE.json`` (``_common.kept_records`` of a frame JSON)."""
    return kept_records(p, path, "frame", _record_key)


def plot(records, path, dev):
    """Time against error per scene and size: x = frame ms, y = mean PSNR over the path; foveated points (one per
    configuration and shading) and the reference's (its own error where it has one: AO shading against the
    converged frame; a dashed line at its time where it is the target)."""
    plt = pyplot()
    recs = [r for r in records if "fov_ms" in r and "psnr_mean" in r]
    if plt is None or not recs:
        return
    keys = sorted({(r["scene"], r["width"], r["height"]) for r in recs}, key=lambda k: (k[1], k[0]))
    cols = min(len(keys), 4)
    nrows = -(-len(keys) // cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.2 * cols, 3.4 * nrows), squeeze=False)
    for ax, key in zip(axes.flat, keys):
        for k, ao in enumerate(sorted({r["ao_samples"] for r in recs})):
            color = f"C{k}"
            rs = [r for r in recs if (r["scene"], r["width"], r["height"]) == key and r["ao_samples"] == ao]
            ax.scatter([r["fov_ms"] for r in rs], [r["psnr_mean"] for r in rs], color=color, marker="o",
                       label=f"foveated, {ao} AO")
            for r in rs:
                ax.annotate(r["config"], (r["fov_ms"], r["psnr_mean"]), fontsize=6, xytext=(3, 3),
                            textcoords="offset points")
            refs = [r for r in rs if "ref_psnr_mean" in r]
            if refs:
                ax.scatter([r["ref_ms"] for r in refs], [r["ref_psnr_mean"] for r in refs], color=color, marker="x",
                           label=f"reference, {ao} AO")
            elif rs:
                ax.axvline(rs[0]["ref_ms"], color=color, ls="--", lw=1, label=f"reference, {ao} AO (target)")
        ax.set_title(f"{key[0]} {key[1]}x{key[2]}", fontsize=8)
        ax.set_xlabel("frame ms", fontsize=7)
        ax.set_ylabel("PSNR dB (mean over the path)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=5)
    title = f"frame time vs PSNR, foveated and full-resolution reference ({wp.get_device(dev).alias})"
    save_grid(plt, fig, axes, len(keys), textwrap.fill(title, width=max(40, int(15 * fig.get_figwidth()))), path)


if __name__ == "__main__":
    main()
