"""Shared benchmark helpers: device resolution, synchronized median timing, JSON/markdown output."""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import warp as wp

RESULTS = Path(__file__).resolve().parent / "results"
REPO = Path(__file__).resolve().parent.parent
SHARED_SCENES = REPO.parent / "shared" / "scenes"


def base_parser(description: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--device", default=None, help='Warp device, e.g. "cpu" or "cuda:0" (default: Warp\'s default)')
    p.add_argument("--quick", action="store_true", help="tiny sizes and few repeats (CPU smoke run)")
    p.add_argument("--repeats", type=int, default=None, help="timed repeats (median reported)")
    p.add_argument("--warmup", type=int, default=3, help="untimed warm-up runs")
    p.add_argument("--out", default=None, help="output folder for JSON/markdown (default benchmarks/results)")
    return p


def git_commit() -> str:
    """The commit the results come from: $FOVEAWARP_COMMIT when set (a copied working tree, e.g. on a remote GPU
    machine, may carry a stale .git), else ``git rev-parse --short HEAD``."""
    env = os.environ.get("FOVEAWARP_COMMIT")
    if env:
        return env
    try:
        return subprocess.check_output(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, text=True,
                                       stderr=subprocess.DEVNULL).strip()
    except Exception:
        return "unknown"


def device_info(device) -> dict:
    d = wp.get_device(device)
    return {"device": d.alias, "device_name": d.name if d.is_cuda else platform.processor() or "cpu",
            "is_cuda": bool(d.is_cuda), "warp": wp.__version__}


def time_ms(fn, device, repeats: int = 20, warmup: int = 3) -> dict:
    """Median (and p10/p90) wall time of ``fn()`` in ms, synchronizing the device around each call."""
    for _ in range(warmup):
        fn()
    wp.synchronize_device(device)
    ts = []
    for _ in range(repeats):
        wp.synchronize_device(device)
        t0 = time.perf_counter()
        fn()
        wp.synchronize_device(device)
        ts.append((time.perf_counter() - t0) * 1e3)
    ts.sort()
    q = lambda f: ts[min(len(ts) - 1, int(f * len(ts)))]  # noqa: E731
    return {"median_ms": statistics.median(ts), "p10_ms": q(0.1), "p90_ms": q(0.9), "repeats": repeats}


def launch_timer(device, repeats: int, inner: int, warmup: int):
    """``t_ms(fn)``: ms per call of ``fn``, from ``time_ms`` (synchronized, median of ``repeats``) over timed calls
    of ``inner`` calls each: launches too short to time one by one."""

    def t_ms(fn) -> float:
        def many():
            for _ in range(inner):
                fn()

        return time_ms(many, device, repeats, warmup)["median_ms"] / inner

    return t_ms


def write_results(name: str, device, payload: dict, table_md: str, out=None) -> Path:
    d = wp.get_device(device)
    folder = Path(out) if out else RESULTS
    folder.mkdir(parents=True, exist_ok=True)
    tag = "cuda" if d.is_cuda else "cpu"
    payload = {"benchmark": name, "commit": git_commit(), **device_info(device), **payload}
    p = folder / f"{name}-{tag}.json"
    p.write_text(json.dumps(payload, indent=1, default=float))
    (folder / f"{name}-{tag}.md").write_text(table_md + "\n")
    return p


def md_table(rows: list, cols: list) -> str:
    head = "| " + " | ".join(cols) + " |\n|" + "|".join("---" for _ in cols) + "|\n"
    body = ""
    for r in rows:
        cells = []
        for c in cols:
            v = r.get(c, "")
            cells.append(f"{v:.3f}" if isinstance(v, float) else str(v))
        body += "| " + " | ".join(cells) + " |\n"
    return head + body


# the two shadings the frame benchmarks compare: Config.with_ overrides by name
SHADINGS = {"default": {}, "ao8": {"shading": {"ao_samples": 8}}}


def shading_config(fw, name: str):
    """``fw.Config()`` with the overrides of ``SHADINGS[name]``."""
    return fw.Config().with_(**SHADINGS[name]) if SHADINGS[name] else fw.Config()


def checked_shadings_sizes(p: argparse.ArgumentParser, args) -> tuple:
    """(shading names, [(width, height)]) from ``--shadings`` and ``--sizes``, or a parser error naming the
    option, the value and what is allowed."""
    shadings = [s for s in args.shadings.split(",") if s]
    if not shadings or any(s not in SHADINGS for s in shadings):
        p.error(f"--shadings must be a comma list of {', '.join(SHADINGS)}, got {args.shadings!r}")
    try:
        sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",") if s]
        if not sizes or any(len(s) != 2 or min(s) < 1 for s in sizes):
            raise ValueError
    except ValueError:
        p.error(f"--sizes must be a comma list of WxH with positive integers, got {args.sizes!r}")
    return shadings, sizes


def scenes_present(fw, names: str):
    """The scenes of the comma list ``names`` that load here; a shared mesh missing on this machine is skipped
    with a line saying so."""
    for name in [s for s in names.split(",") if s]:
        try:
            yield fw.load_scene(name)
        except (FileNotFoundError, ValueError) as e:
            print(f"skip {name}: {e}", flush=True)
