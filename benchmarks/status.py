"""The README's "Where it stands" table, from committed ``frame.py`` JSON: no GPU, no hand copying.

Per scene, one row:

* the speed-up (reference time / foveated time) of every ``--timing`` run, at each size and shading, "run 1 / run 2";
* the default policy's time over the reference's, the worst over the runs, sizes and the default shading (the
  policy renders full resolution where foveation costs more; 8 AO rays are not counted: there it keeps foveation);
* from the ``--quality`` JSON (``frame.py --parts quality,aoquality``) at ``--quality-size``: the default shading's
  PSNR in motion against full resolution (mean / min over the path), and with 8 AO rays the foveated frame's and the
  full-resolution frame's PSNR against the converged frame (means over the path).

Scenes come in ``--scenes`` order; a scene missing from the timing runs is left out, and a quality figure missing
from the quality JSON is shown as "-".

    python benchmarks/status.py --timing benchmarks/results/frame-s33-41b29e8-timing-run{1,2}-cuda.json \\
        --quality benchmarks/results/frame-2e786dc-{a,b}-cuda.json

Records carry the turn schedule that timed them (``frame.py --turns``; records without one were timed frame by
frame): ``--turns`` picks the schedule of the table (default "frames"). ``--compare-turns`` prints instead, per
scene, size and shading, the speed-up of every run with each schedule and the ratio of their medians over the
runs (blocks / frames), from runs that recorded both (``frame.py --turns frames,blocks``).

Writes nothing unless ``--out`` names a file for the markdown; prints it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from benchmarks._common import md_table  # noqa: E402
from benchmarks.frame import TURNS, _summ, record_turns  # noqa: E402

SCENE_ORDER = "bunny,nefertiti,city,spot,ogre,teapot,cornell,eyechart,earth"
SHADINGS = (("default", "default"), ("ao8", "8 AO rays"))


def _load(paths) -> list[dict]:
    recs = []
    for p in paths:
        payload = json.loads(Path(p).read_text())
        if "records" not in payload:
            raise SystemExit(f"{p}: no 'records' (not a frame.py result)")
        recs.append(payload["records"])
    return recs


def _size(option: str, s: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in s.lower().split("x"))
    except ValueError:
        raise SystemExit(f"{option} must be WIDTHxHEIGHT, got {s!r}") from None
    if w <= 0 or h <= 0:
        raise SystemExit(f"{option} must be positive WIDTHxHEIGHT, got {s!r}")
    return w, h


def find_timing(run: list[dict], scene: str, w: int, h: int, shading: str, turns: str = "frames"):
    """The timing record of ``scene`` at w x h with ``shading`` timed with ``turns`` in one run's records, or
    None (a record without "turns" was timed frame by frame)."""
    for r in run:
        if (r.get("kind") == "timing" and r["scene"] == scene and r["width"] == w and r["height"] == h
                and r["shading"] == shading and record_turns(r) == turns):
            return r
    return None


def turns_rows(timing_runs: list[list[dict]], scenes: list[str],
               sizes: list[tuple[int, int]]) -> tuple[list[str], list[list[str]]]:
    """(column names, rows of strings) of the comparison of the two turn schedules: per scene, size and shading
    with both schedules in every run, each run's speed-up by frames and by blocks, the ratio of the two medians
    over the runs (blocks / frames), and the default policy's time over the reference's with each (worst run)."""
    cols = ["scene", "size", "shading", "speed-up, frame by frame (runs)", "speed-up, blocks (runs)",
            "blocks / frames (medians)", "default policy / reference, worst: frames; blocks"]
    out = []
    for scene in scenes:
        for w, h in sizes:
            for s, label in SHADINGS:
                f = [find_timing(run, scene, w, h, s, "frames") for run in timing_runs]
                b = [find_timing(run, scene, w, h, s, "blocks") for run in timing_runs]
                if not all(f) or not all(b):
                    continue
                sf = [r["ref_ms"] / r["fov_ms"] for r in f]
                sb = [r["ref_ms"] / r["fov_ms"] for r in b]
                row = [scene, f"{w}x{h}", label, " / ".join(f"{v:.2f}x" for v in sf),
                       " / ".join(f"{v:.2f}x" for v in sb), f"{float(np.median(sb)) / float(np.median(sf)):.3f}"]
                row.append("-" if s != "default" else
                           f"{max(r['auto_ms'] / r['ref_ms'] for r in f):.3f}; "
                           f"{max(r['auto_ms'] / r['ref_ms'] for r in b):.3f}")
                out.append(row)
    return cols, out


def rows(timing_runs: list[list[dict]], quality: list[dict], scenes: list[str], sizes: list[tuple[int, int]],
         quality_size: tuple[int, int], turns: str = "frames") -> tuple[list[str], list[list[str]]]:
    """(column names, rows of strings) of the status table, from the records timed with ``turns``."""
    cols = ["scene"]
    for w, h in sizes:
        for _, label in SHADINGS:
            cols.append(f"{w}x{h} {label}")
    qw, qh = quality_size
    cols += ["default policy / reference, worst", f"PSNR in motion, {qw}x{qh} default: mean / min dB",
             f"{qw}x{qh} 8 AO rays vs converged: foveated / full dB"]

    def timing(run, scene, w, h, shading):
        return find_timing(run, scene, w, h, shading, turns)

    def quality_rec(kind, scene):
        for r in quality:
            if r.get("kind") == kind and r["scene"] == scene and r["width"] == qw and r["height"] == qh:
                return r
        return None

    out = []
    for scene in scenes:
        found = [timing(run, scene, w, h, s) for run in timing_runs for w, h in sizes for s, _ in SHADINGS]
        if not any(found):
            continue
        row = [scene]
        for w, h in sizes:
            for s, _ in SHADINGS:
                vals = [timing(run, scene, w, h, s) for run in timing_runs]
                row.append(" / ".join("-" if r is None else f"{r['ref_ms'] / r['fov_ms']:.2f}x" for r in vals))
        pol = [r["auto_ms"] / r["ref_ms"] for run in timing_runs for w, h in sizes
               if (r := timing(run, scene, w, h, "default")) is not None]
        row.append(f"{max(pol):.3f}" if pol else "-")
        q = quality_rec("quality", scene)
        # frame.py's summaries: an identical frame (inf dB) counts as 100 dB in a mean
        row.append("-" if q is None else f"{_summ(q['psnr'])['mean']:.1f} / {_summ(q['psnr'])['min']:.1f}")
        a = quality_rec("ao_quality", scene)
        row.append("-" if a is None else f"{_summ(a['psnr'])['mean']:.1f} / {_summ(a['ref_psnr'])['mean']:.1f}")
        out.append(row)
    return cols, out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--timing", nargs="+", required=True, help="frame.py --parts timing JSON files (one per run)")
    p.add_argument("--quality", nargs="*", default=[], help="frame.py JSON files with quality / aoquality records")
    p.add_argument("--scenes", default=SCENE_ORDER, help="comma-separated scenes, in the table's order")
    p.add_argument("--sizes", default="1920x1080,3840x2160", help="comma-separated WIDTHxHEIGHT, in column order")
    p.add_argument("--quality-size", default="3840x2160", help="the size of the PSNR columns")
    p.add_argument("--out", default=None, help="write the markdown to this file too")
    p.add_argument("--turns", default="frames", choices=TURNS, help="the turn schedule of the table's records")
    p.add_argument("--compare-turns", action="store_true",
                   help="print the two schedules' speed-ups side by side instead (runs that recorded both)")
    a = p.parse_args(argv)
    sizes = [_size("--sizes items", s) for s in a.sizes.split(",") if s.strip()]
    if not sizes:
        p.error("--sizes names no size")
    runs = _load(a.timing)
    scenes = [s.strip() for s in a.scenes.split(",") if s.strip()]
    if a.compare_turns:
        cols, table = turns_rows(runs, scenes, sizes)
        if not table:
            p.error("no scene of --scenes has timing records of both turn schedules in every --timing file")
    else:
        quality = [r for recs in _load(a.quality) for r in recs]
        cols, table = rows(runs, quality, scenes, sizes, _size("--quality-size", a.quality_size), a.turns)
        if not table:
            p.error(f"no scene of --scenes has a timing record timed by {a.turns} in the --timing files")
    md = md_table([dict(zip(cols, r)) for r in table], cols)
    if a.out:
        Path(a.out).write_text(md)
    print(md, end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
