"""`foveawarp` console script: demo, render, view, warmup, bench."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["main"]


def _parse_gaze(s: str):
    try:
        x, y = (float(v) for v in s.split(","))
    except Exception:
        raise argparse.ArgumentTypeError(f"--gaze must be X,Y in pixels, got {s!r}") from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise argparse.ArgumentTypeError(f"--gaze must be finite, got {s!r}")
    return x, y


def _positive_int(s: str) -> int:
    try:
        v = int(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {s!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {s!r}")
    return v


def _positive_float(s: str) -> float:
    try:
        v = float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number of seconds, got {s!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number of seconds, got {s!r}")
    return v


def _default_device(dev):
    import warp as wp

    from ._util import init_warp

    init_warp()
    if dev is not None:
        return dev
    return "cuda:0" if wp.is_cuda_available() else "cpu"


def _gaze_path(i: int, n: int, w: int, h: int):
    """A Lissajous gaze path over the middle of the screen."""
    t = i / max(n, 1)
    return (w * (0.5 + 0.3 * math.sin(2 * math.pi * t)), h * (0.5 + 0.25 * math.sin(4 * math.pi * t + 0.5)))


def _write_png(path: Path, img: np.ndarray) -> None:
    import imageio.v2 as imageio

    imageio.imwrite(str(path), (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8))


def _try_mp4(frames_dir: Path, pngs: list, fps: int = 24):
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401
    except Exception:
        return None
    out = frames_dir / "animation.mp4"
    try:
        with imageio.get_writer(str(out), fps=fps, macro_block_size=1) as wr:
            for p in pngs:
                wr.append_data(imageio.imread(str(p)))
    except Exception as e:  # ffmpeg missing at run time
        print(f"(no MP4: {e})", file=sys.stderr)
        return None
    return out


def _panel(frame, ref_img=None) -> np.ndarray:
    """Side-by-side panel: sampling map, sparse shading, reconstruction, reference, error (thesis Figs 40-45)."""
    img = frame.numpy()
    parts = []
    ex = frame.extras
    smap = frame.sampling_map.numpy().astype(np.float32)
    parts.append(np.repeat(smap[..., None], 3, axis=2))
    if "sparse" in ex:
        sparse = ex["sparse"].numpy() if hasattr(ex["sparse"], "numpy") else np.asarray(ex["sparse"])
        parts.append(np.clip(sparse * 2.0, 0.0, 1.0) ** (1.0 / 2.2))  # linear radiance, display gamma
    parts.append(img)
    if ref_img is not None:
        parts.append(ref_img)
        err = np.abs(img - ref_img).mean(axis=2)
        err = np.clip(err * 8.0, 0, 1)
        parts.append(np.stack([err, err * 0.3, 1.0 - err], axis=2) * (err[..., None] > 0.002))
    return np.concatenate(parts, axis=1)


def _render_sequence(scene_name, width, height, frames, device, gaze, out_dir: Path, debug=False, dof=False,
                     panel=True, desc="frames", gaze_trace=None, integrator="direct"):
    from tqdm import tqdm

    import foveawarp as fw

    out_dir.mkdir(parents=True, exist_ok=True)
    scene = fw.load_scene(scene_name)
    # the demo shows foveation: the default "auto" policy would render full frames where they are cheaper
    cfg = fw.Config().with_(shading={"integrator": integrator})
    loop = fw.FrameLoop(scene, width, height, config=cfg, device=device, policy="foveated")
    ref_loop = fw.FrameLoop(scene, width, height, config=cfg, device=device) if panel else None
    all_stats, pngs = [], []
    fps = 30.0
    for i in tqdm(range(frames), desc=desc, unit="frame"):
        t = i / fps
        cam = scene.camera_at(t)
        g = gaze if gaze is not None else (gaze_trace.at(t) if gaze_trace is not None
                                           else _gaze_path(i, frames, width, height))
        frame = loop.render(cam, gaze_px=g, time=t)
        ref = ref_loop.render_reference(cam, time=t).numpy() if panel else None
        img = _panel(frame, ref) if panel else frame.numpy()
        p = out_dir / f"frame_{i:04d}.png"
        _write_png(p, img)
        pngs.append(p)
        st = {k: v for k, v in frame.stats.items()}
        if ref is not None:
            from .metrics import psnr

            st["psnr_vs_reference"] = psnr(frame.numpy(), ref)
        all_stats.append(st)
        if debug:
            _write_debug(loop, frame, out_dir, i)
    if dof:
        _write_dof(scene, width, height, device, out_dir)
    mp4 = _try_mp4(out_dir, pngs)
    summary = {
        "scene": scene.name, "triangles": scene.num_triangles, "width": width, "height": height,
        "device": str(loop.device), "frames": all_stats, "mp4": str(mp4.name) if mp4 else None,
    }
    (out_dir / "stats.json").write_text(json.dumps(summary, indent=1, default=_json_default))
    return summary


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return str(o)


def _write_debug(loop, frame, out_dir: Path, i: int) -> None:
    """Debug views of the sampling stage: probability, saliency, binary map, cache hits."""
    st = getattr(loop, "sampling", None)
    views = []
    for name in ("probability", "saliency", "sample_map", "cache_hit"):
        a = getattr(st, name, None) if st is not None else None
        if a is None:
            continue
        v = a.numpy().astype(np.float32)
        views.append(np.repeat(v[..., None], 3, axis=2))
    if views:
        _write_png(out_dir / f"debug_{i:04d}.png", np.concatenate(views, axis=1))


def _write_dof(scene, width, height, device, out_dir: Path) -> None:
    try:
        from .dof_reference import render_dof_comparison
    except ImportError:
        print("depth of field comparison not available in this build", file=sys.stderr)
        return
    if scene.materials is not None:
        print(f"depth of field comparison skipped: its thin-lens reference shades per-face colours, and scene "
              f"{scene.name!r} has materials", file=sys.stderr)
        return
    imgs = render_dof_comparison(scene, scene.camera, width, height, device=device)
    _write_png(out_dir / "dof_comparison.png", np.concatenate(list(imgs.values()), axis=1))
    (out_dir / "dof_comparison.txt").write_text("left to right: " + ", ".join(imgs.keys()) + "\n")


def cmd_demo(args) -> int:
    device = _default_device(args.device)
    import warp as wp

    cuda = wp.get_device(device).is_cuda
    # the CPU device runs its launches as row bands on every core (foveawarp.parallel): 24 frames at 480x270
    # take 6 s on 2 cores with a warm kernel cache, 15 s with the first run's compilation
    w = args.width or (1920 if cuda else 480)
    h = args.height or (1080 if cuda else 270)
    n = args.frames or (60 if cuda else 24)
    t0 = time.perf_counter()
    s = _render_sequence(args.scene, w, h, n, device, None, Path(args.out), debug=False, panel=True, desc="demo",
                         gaze_trace=_load_trace(args.gaze_trace), integrator=args.integrator)
    ms = [f.get("ms_frame", float("nan")) for f in s["frames"]]
    print(f"demo: {n} frames of {s['scene']} at {w}x{h} on {s['device']} in {time.perf_counter() - t0:.1f} s "
          f"(median frame {np.median(ms):.1f} ms incl. timing syncs); output in {args.out}/")
    return 0


def cmd_render(args) -> int:
    device = _default_device(args.device)
    if args.gaze is not None and args.gaze_trace is not None:
        raise ValueError("give --gaze or --gaze-trace, not both")
    s = _render_sequence(args.scene, args.width, args.height, args.frames, device, args.gaze, Path(args.out),
                         debug=args.debug, dof=args.dof, panel=args.panel, desc="render",
                         gaze_trace=_load_trace(args.gaze_trace), integrator=args.integrator)
    print(f"render: {len(s['frames'])} frames of {s['scene']} at {args.width}x{args.height} on {s['device']}; "
          f"output in {args.out}/")
    return 0


def _load_trace(path):
    if path is None:
        return None
    from .gaze_trace import load_gaze_trace

    return load_gaze_trace(path)


def cmd_view(args) -> int:
    """Serve the live viewer until interrupted (Ctrl-C)."""
    import asyncio

    device = _default_device(args.device)
    import warp as wp

    cuda = wp.get_device(device).is_cuda
    w = args.width or (1280 if cuda else 320)
    h = args.height or (720 if cuda else 180)
    trace = _load_trace(args.gaze_trace)
    scenes = args.scene or default_view_scenes()
    _check_scene_sources(scenes)
    try:
        from .viewer.server import ViewerServer
    except ImportError as e:
        print(f"foveawarp: error: {e}", file=sys.stderr)
        return 2
    from .viewer.session import ViewerSession

    timing = None if args.timing is None else args.timing == "on"
    session = ViewerSession(scenes, w, h, device=device, gaze_trace=trace, timing=timing, quality=args.quality,
                            encoder=args.encoder)
    server = ViewerServer(session, host=args.host, port=args.port)
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"warning: the viewer listens on {args.host}, not only on this machine's loopback: anyone who can "
              f"reach this address can watch and steer it (it has no authentication). Prefer the default "
              f"127.0.0.1 with an SSH tunnel.", file=sys.stderr)

    async def run():
        await server.start()
        print(f"foveawarp view: {', '.join(session.limits.scenes)} at {w}x{h} on {device}; open {server.url}"
              f" (Ctrl-C stops)", flush=True)
        try:
            if args.serve_seconds is None:
                await asyncio.Event().wait()
            else:
                await asyncio.sleep(args.serve_seconds)
        finally:
            await server.close()

    try:
        asyncio.run(run())
    except KeyboardInterrupt:
        pass
    return 0


def default_view_scenes() -> list:
    """The viewer's scenes when ``--scene`` names none: cornell, the procedural textured room, the textured models
    that ship (suzanne, wicker) and those of the shared scenes folder that are there (barrel, milk-truck,
    grey-white-room)."""
    from .meshio import TEXTURED_SCENES, find_textured_scene

    return ["cornell", "room"] + [n for n in TEXTURED_SCENES if find_textured_scene(n) is not None]


def _check_scene_sources(scenes) -> None:
    """Fail at launch (not in the page) for a scene that is neither a known name nor an existing file, or a named
    textured scene whose file is not found."""
    from . import scenes as builtin
    from .meshio import TEXTURED_SCENES, find_textured_scene, textured_scene_help
    from .scene import NAMED_MESHES, find_named_mesh

    for s in scenes:
        if s in TEXTURED_SCENES:
            if find_textured_scene(s) is None:
                raise ValueError(textured_scene_help(s))
            continue
        if s in builtin.BUILTIN:
            continue
        if s in NAMED_MESHES:
            if find_named_mesh(s) is None:
                raise ValueError(f"scene {s!r} needs {NAMED_MESHES[s]!r}; set FOVEAWARP_SCENES to its folder")
            continue
        if not Path(s).is_file():
            raise ValueError(f"scene {s!r} is neither a built-in name {sorted(builtin.BUILTIN) + sorted(NAMED_MESHES)} "
                             "nor an existing file")


def cmd_warmup(args) -> int:
    """Compile every kernel module for the device ahead of time."""
    import importlib
    import pkgutil

    import warp as wp

    from . import kernels

    device = _default_device(args.device)
    t0 = time.perf_counter()
    names = []
    for m in pkgutil.iter_modules(kernels.__path__):
        mod = importlib.import_module(f"{kernels.__name__}.{m.name}")
        names.append(m.name)
        wp.load_module(mod, device=device)
    print(f"warmup: compiled/loaded {len(names)} kernel modules ({', '.join(sorted(names))}) for {device} "
          f"in {time.perf_counter() - t0:.1f} s")
    return 0


BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def bench_names() -> list:
    """The benchmark entry points of the source checkout (``benchmarks/NAME.py``, private modules left out); none
    in an installed wheel."""
    return sorted(f.stem for f in BENCHMARKS.glob("*.py") if not f.stem.startswith("_"))


def cmd_bench(args) -> int:
    import runpy

    script = BENCHMARKS / f"{args.name}.py"
    if args.name not in bench_names():
        names = ", ".join(bench_names()) or "none: benchmarks ship with the source checkout, not the wheel"
        print(f"benchmark {args.name!r} not found at {script} (entry points: {names})", file=sys.stderr)
        return 2
    argv = (["--device", args.device] if args.device else []) + (["--quick"] if args.quick else [])
    if args.out:
        argv += ["--out", args.out]
    mod = runpy.run_path(str(script), run_name=f"benchmarks.{args.name}")
    rc = mod["main"](argv)
    return rc if isinstance(rc, int) else 0


_SCENE_HELP = ("cornell | city | eyechart | earth | bunny-in-box | room | suzanne | wicker | barrel | milk-truck | "
               "grey-white-room | bunny | spot | teapot | nefertiti | ogre | PATH (.gltf .glb .obj .ply .stl, or a "
               "Mitsuba .xml)")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="foveawarp", description="Foveated real-time ray tracing with NVIDIA Warp")
    sub = p.add_subparsers(dest="cmd", required=True)

    d = sub.add_parser("demo", help="render a short foveated animation of the default scene with a moving gaze")
    d.add_argument("--scene", default="cornell", help=f"{_SCENE_HELP} (default cornell; room: textured)")
    d.add_argument("--device", default=None, help='"cpu", "cuda:0", ... (default: CUDA when present)')
    d.add_argument("--width", type=_positive_int, default=None)
    d.add_argument("--height", type=_positive_int, default=None)
    d.add_argument("--frames", type=_positive_int, default=None)
    d.add_argument("--out", default="foveawarp-out/demo")
    d.add_argument("--integrator", choices=("direct", "path"), default="direct",
                   help="direct light (default) or path tracing (ShadingConfig.integrator)")
    d.add_argument("--gaze-trace", default=None, metavar="FILE.csv",
                   help="replay a recorded gaze (CSV columns t_s,x_px,y_px; frame i at t = i / 30 s)")
    d.set_defaults(func=cmd_demo)

    r = sub.add_parser("render", help="render frames of a scene (built-in name or mesh file)")
    r.add_argument("--scene", default="cornell", help=_SCENE_HELP)
    r.add_argument("--width", type=_positive_int, default=640)
    r.add_argument("--height", type=_positive_int, default=360)
    r.add_argument("--frames", type=_positive_int, default=1)
    r.add_argument("--device", default=None)
    r.add_argument("--gaze", type=_parse_gaze, default=None, help="X,Y in pixels (default: a moving gaze)")
    r.add_argument("--out", default="foveawarp-out/render")
    r.add_argument("--integrator", choices=("direct", "path"), default="direct",
                   help="direct light (default) or path tracing (ShadingConfig.integrator)")
    r.add_argument("--debug", action="store_true", help="also write the sampling-map debug views")
    r.add_argument("--dof", action="store_true", help="also write the depth-of-field comparison")
    r.add_argument("--no-panel", dest="panel", action="store_false", help="write only the foveated image")
    r.add_argument("--gaze-trace", default=None, metavar="FILE.csv",
                   help="replay a recorded gaze (CSV columns t_s,x_px,y_px; frame i at t = i / 30 s)")
    r.set_defaults(func=cmd_render)

    v = sub.add_parser("view", help="serve the live viewer: a page whose foveated frames follow the mouse")
    v.add_argument("--scene", action="extend", nargs="+", default=None, metavar="NAME|PATH",
                   help="the scenes the page may offer (default: cornell, room and the textured models found); "
                   "the page names them, never sends paths")
    v.add_argument("--device", default=None, help='"cpu", "cuda:0", ... (default: CUDA when present)')
    v.add_argument("--width", type=_positive_int, default=None, help="render width (default 1280 CUDA, 320 CPU)")
    v.add_argument("--height", type=_positive_int, default=None, help="render height (default 720 CUDA, 180 CPU)")
    v.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    v.add_argument("--port", type=int, default=8765, help="port (0 picks a free one)")
    v.add_argument("--gaze-trace", default=None, metavar="FILE.csv",
                   help="replay a recorded gaze (CSV columns t_s,x_px,y_px, looped) instead of the mouse")
    v.add_argument("--timing", choices=("on", "off"), default=None,
                   help="per-stage timing (default: on for the CPU, off on CUDA, which then replays CUDA graphs)")
    v.add_argument("--quality", type=int, default=80, help="JPEG quality in [10, 100] (default 80)")
    v.add_argument("--encoder", choices=("auto", "simplejpeg", "pillow"), default="auto",
                   help="JPEG encoder (default auto: simplejpeg when installed, else Pillow)")
    v.add_argument("--serve-seconds", type=_positive_float, default=None,
                   help="stop after this many seconds (scripted runs; default: until Ctrl-C)")
    v.set_defaults(func=cmd_view)

    w = sub.add_parser("warmup", help="compile every kernel module for a device ahead of time")
    w.add_argument("--device", default=None)
    w.set_defaults(func=cmd_warmup)

    names = bench_names()
    b = sub.add_parser("bench", help="run a benchmark entry point of the source checkout (default: frame)",
                       description="Run benchmarks/NAME.py of the source checkout with its default sizes; each "
                                   "script takes more options when run directly (python benchmarks/NAME.py --help). "
                                   "Entry points: " + (", ".join(names) or "none (an installed wheel has none)"))
    b.add_argument("name", nargs="?", default="frame", help="the entry point (default: frame)")
    b.add_argument("--device", default=None)
    b.add_argument("--quick", action="store_true", help="tiny sizes and few repeats")
    b.add_argument("--out", default=None, help="output folder (default: benchmarks/out)")
    b.set_defaults(func=cmd_bench)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ValueError as e:
        print(f"foveawarp: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
