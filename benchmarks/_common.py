"""Shared benchmark code: the common options, device names, synchronized median timing, the progress bar and the
JSON / markdown / PNG output every entry point writes."""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

import warp as wp

REPO = Path(__file__).resolve().parent.parent
# the default --out: ignored by git, so that a plain run never touches the tracked tree
OUT = REPO / "benchmarks" / "out"
SHARED_SCENES = REPO.parent / "shared" / "scenes"
# what every JSON record carries (``write_results`` refuses a record without them)
RECORD_KEYS = ("device", "width", "height", "scene")
# the process's start, near enough: the JSON's wall_s (what a canonical run costs) counts from here
T0 = time.perf_counter()


def base_parser(doc: str, canonical: str | None = None) -> argparse.ArgumentParser:
    """The options of every entry point (and of the tools): ``--device``, ``--out``, ``--tag``, ``--quick``,
    ``--repeats``, ``--warmup``. ``--help`` begins with ``canonical``, the command of the canonical run, when
    given (the tools have none)."""
    head = f"canonical run: {canonical}\n\n" if canonical else ""
    p = argparse.ArgumentParser(description=head + doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default=None, help='Warp device, e.g. "cpu" or "cuda:0" (default: Warp\'s default)')
    p.add_argument("--out", default=str(OUT), help="output folder for JSON / markdown / PNG (default: benchmarks/out)")
    p.add_argument("--tag", default=None,
                   help="file name tag: <benchmark>-<tag>.json/.md/.png (default: cuda or cpu, from the device)")
    p.add_argument("--quick", action="store_true", help="tiny sizes and few repeats (CPU smoke run)")
    p.add_argument("--repeats", type=int, default=None, help="timed repeats (median reported)")
    p.add_argument("--warmup", type=int, default=3, help="untimed warm-up runs")
    return p


def parse_sizes(p: argparse.ArgumentParser, text: str, opt: str = "--sizes") -> list:
    """[(width, height)] from a comma list of WxH, or a parser error naming the option, the value and the form."""
    try:
        sizes = [tuple(int(v) for v in s.split("x")) for s in text.split(",") if s]
        if not sizes or any(len(s) != 2 or min(s) < 1 for s in sizes):
            raise ValueError
    except ValueError:
        p.error(f"{opt} must be a comma list of WxH with positive integers, got {text!r}")
    return sizes


def git_commit() -> str:
    """The commit the results come from: $FOVEAWARP_COMMIT when set (a copied working tree has no .git), else
    ``git rev-parse HEAD``, else "unknown"."""
    env = os.environ.get("FOVEAWARP_COMMIT")
    if env:
        return env
    try:
        return subprocess.check_output(["git", "rev-parse", "HEAD"], cwd=REPO, text=True,
                                       stderr=subprocess.DEVNULL).strip()
    except Exception:
        return "unknown"


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo on Linux), else platform.processor(), else "cpu"."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "cpu"


def device_name(device) -> str:
    """The device's name: the GPU's ("NVIDIA H200") or the CPU model."""
    d = wp.get_device(device)
    return d.name if d.is_cuda else cpu_model()


def device_info(device) -> dict:
    d = wp.get_device(device)
    return {"device": device_name(d), "device_alias": d.alias, "is_cuda": bool(d.is_cuda), "warp": wp.__version__,
            "cpu_threads": os.cpu_count()}


def default_tag(device) -> str:
    return "cuda" if wp.get_device(device).is_cuda else "cpu"


def progress(iterable, desc: str, total=None):
    """A tqdm progress bar on stderr (the table goes to stdout)."""
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, file=sys.stderr, leave=False, dynamic_ncols=True)


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


def _finite(v):
    """``v`` with every non-finite float replaced by None (strict JSON has no NaN / Infinity)."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    if hasattr(v, "item") and not isinstance(v, (str, bytes)):  # numpy scalars
        return _finite(v.item())
    return v


def write_results(name: str, device, records: list, table_md: str, out=None, tag=None, extra=None) -> Path:
    """Write ``<out>/<name>-<tag>.json`` (top level: benchmark, commit, device info, wall seconds so far,
    ``extra``; ``records``, each with its device name) and ``<name>-<tag>.md``; returns the JSON's path. A record without width, height and
    scene is refused (a ValueError naming the record)."""
    info = device_info(device)
    recs = []
    for i, r in enumerate(records):
        r = {**r, "device": info["device"]}
        missing = [k for k in RECORD_KEYS if k not in r]
        if missing:
            raise ValueError(f"records[{i}] of {name} lacks {missing}; every record carries {list(RECORD_KEYS)}")
        recs.append(r)
    folder = Path(out) if out else OUT
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"{name}-{tag or default_tag(device)}"
    payload = {"benchmark": name, "commit": git_commit(), **info, "wall_s": round(time.perf_counter() - T0, 1),
               **(extra or {}), "records": recs}
    p = folder / f"{stem}.json"
    p.write_text(json.dumps(_finite(payload), indent=1, default=float))
    (folder / f"{stem}.md").write_text(f"# {name} on {info['device']} ({info['device_alias']}), commit "
                                       f"{payload['commit'][:12]}\n\n{table_md}\n")
    print(f"wrote {p} and {p.with_suffix('.md').name}", file=sys.stderr)
    return p


def plot_path(name: str, device, out=None, tag=None) -> Path:
    """Where ``name``'s PNG goes: ``<out>/<name>-<tag>.png``."""
    folder = Path(out) if out else OUT
    folder.mkdir(parents=True, exist_ok=True)
    return folder / f"{name}-{tag or default_tag(device)}.png"


def pyplot():
    """matplotlib.pyplot on the Agg backend, or None (with a line saying so) when matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except Exception:
        print("matplotlib not installed: no plot", file=sys.stderr)
        return None
    return plt


def save_grid(plt, fig, axes, used: int, title: str, path) -> None:
    """Finish a grid of plots: the axes after the first ``used`` hidden, the title, the layout, the PNG at 110 dpi
    written to ``path`` and the figure closed."""
    for ax in list(axes.flat)[used:]:
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def md_table(rows: list, cols=None) -> str:
    if not rows:
        return "(no rows)\n"
    cols = cols or list(rows[0])
    head = "| " + " | ".join(cols) + " |\n|" + "|".join("---" for _ in cols) + "|\n"
    body = ""
    for r in rows:
        cells = []
        for c in cols:
            v = r.get(c, "")
            cells.append(f"{v:.3f}" if isinstance(v, float) else str(v))
        body += "| " + " | ".join(cells) + " |\n"
    return head + body


def scenes_present(fw, names: str):
    """The scenes of the comma list ``names`` that load here; a mesh missing on this machine is skipped with a
    line saying so."""
    for name in [s for s in names.split(",") if s]:
        try:
            yield fw.load_scene(name)
        except (FileNotFoundError, ValueError) as e:
            print(f"skip {name}: {e}", file=sys.stderr, flush=True)


def slug(text: str) -> str:
    """A file-name-safe form of ``text``."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-").lower()


def launch_timer(device, repeats: int, inner: int, warmup: int):
    """``t_ms(fn)``: ms per call of ``fn``, from ``time_ms`` (synchronized, median of ``repeats``) over timed calls
    of ``inner`` calls each: launches too short to time one by one."""

    def t_ms(fn) -> float:
        def many():
            for _ in range(inner):
                fn()

        return time_ms(many, device, repeats, warmup)["median_ms"] / inner

    return t_ms


# the two shadings the profiling tools compare: Config.with_ overrides by name
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
    return shadings, parse_sizes(p, args.sizes)


def kept_records(p, path, benchmark: str, key) -> list:
    """The records of ``--keep FILE.json``, a ``benchmark`` JSON (each given the file's commit where it has none
    of its own; ``key(record)`` must read every record), or a parser error naming the file and what was wrong."""
    if path is None:
        return []
    try:
        d = json.loads(Path(path).read_text())
        recs = d["records"]
        for r in recs:
            key(r)
    except (OSError, ValueError, KeyError, TypeError) as e:
        p.error(f"--keep must name a {benchmark} JSON with records (scene, width, height), got {path!r}: {e}")
    if d.get("benchmark") != benchmark:
        p.error(f"--keep must name a {benchmark} JSON, got {path!r} (benchmark {d.get('benchmark')!r})")
    return [{**r, "commit": r.get("commit", d.get("commit", "unknown"))} for r in recs]
