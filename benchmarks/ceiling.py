"""Upper bounds on the foveated frame's speed-up, from measured stage times: what each issue-14 target would need.

Reads the JSON of ``benchmarks/frame.py --parts timing`` (one or more runs) and, optionally, the markdown of
``benchmarks/ncu_frame.py`` (Nsight Compute: each kernel's DRAM floor). No GPU is used. Per scene, size and shading,
from the foveated frame's GPU stage times (``stage_gpu_ms``: CUDA events, one synchronization per frame):

* G: the G-buffer (the same kernel in the reference; one primary ray per pixel);
* F: the fixed passes (``overhead_stage_sum_gpu_ms``: sampling, compaction, temporal resolve, Voronoi + Sibson);
* rate: the sampling rate; ref: the reference frame's time.

Bounds on ref / foveated time:

* **A, traced shading free**: ref / (G + F). The target is out of reach while the G-buffer and the fixed passes
  cost what they do, however cheap the traced pixels' shading becomes.
* **B, fixed passes at their DRAM floor and traced shading free**: ref / (G + min(F_floor, F)), with F_floor the
  summed Nsight DRAM floors (bytes moved / copy bandwidth) of the fixed-pass kernels of the same scene, size and
  shading (where the markdown has them). Out of reach while the passes move the bytes they move.
* **C, the list at the full frame's per-pixel shading cost**: ref / (G + F + rate * (ref - G)): the traced pixels
  shaded as cheaply per pixel as the reference shades every pixel (its frame less its G-buffer). The list's
  measured cost against that share (``shade`` / (rate * (ref - G))) is reported beside it.

And one estimate, not a bound (where the Nsight markdown has the G-buffer kernel):

* **D, the G-buffer at its DRAM floor in both frames, the rest as measured**: (ref - G + G_floor) / (fov - G +
  G_floor), with G_floor the G-buffer kernel's Nsight DRAM floor and fov the measured foveated frame. A rasterized
  G-buffer (the thesis's) writes the same bytes, so this is about the best a raster G-buffer could give both frames
  while the passes and the list cost what they do. The G-buffer is shared, so a cheaper one raises the speed-up only
  where the reference costs more than the foveated frame.

The targets (issue 14, H100): default shading >= 1.0x everywhere and >= 1.5x on city and bunny at 3840x2160;
8 AO rays (``ao8``) >= 3x at 3840x2160 and >= 2.5x at 1920x1080 on city, bunny and the meshes of ../shared/scenes.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

from benchmarks.frame import TURNS, record_turns  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
MESHES = ("spot", "teapot", "nefertiti", "ogre")
# the kernels of the fixed passes (sampling, compaction, temporal resolve, Voronoi + Sibson), by name prefix, in the
# Nsight markdown; the G-buffer, the shading and an animated scene's update are not counted
_FIXED = ("frame_setup", "sampling_map", "tile_pass", "compact_", "block_scan", "resolve", "stoch_box", "refresh_thin",
          "jfa_", "voronoi", "sibson")
SIZES = ((1920, 1080), (3840, 2160))  # the sizes the issue names


def target(scene: str, width: int, height: int, shading: str):
    """The issue's speed-up target for (scene, size, shading), or None where it sets none (other sizes too)."""
    if (width, height) not in SIZES:
        return None
    if shading == "default":
        return 1.5 if (scene in ("city", "bunny") and width == 3840) else 1.0
    if shading == "ao8" and scene in ("city", "bunny", *MESHES):
        return 3.0 if width == 3840 else 2.5
    return None


def _ncu_fov_rows(path):
    """(key (scene, "WxH", shading), kernel name, DRAM floor ms) of each foveated-frame kernel row of the markdown."""
    for line in Path(path).read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 8 or cells[3] != "fov":
            continue
        try:
            floor = float(cells[7])
        except ValueError:
            continue
        yield (cells[0], cells[1], cells[2]), cells[4], floor


def _sum_floors(path, prefixes) -> dict:
    out: dict = {}
    for key, kernel, floor in _ncu_fov_rows(path):
        if kernel.startswith(prefixes):
            out[key] = out.get(key, 0.0) + floor
    return out


def ncu_floors(path) -> dict:
    """{(scene, "WxH", shading): summed DRAM floor ms of the foveated frame's fixed-pass kernels}."""
    return _sum_floors(path, _FIXED)


def ncu_gbuffer_floors(path) -> dict:
    """{(scene, "WxH", shading): the DRAM floor ms of the foveated frame's G-buffer kernel(s)}."""
    return _sum_floors(path, ("gbuffer",))


def bounds(rec: dict, floor_ms=None, gbuffer_floor_ms=None) -> dict:
    """The bounds A, B (None without a floor) and C and the estimate D (None without the G-buffer's floor) of one
    timing record (see the module docstring)."""
    g = float(rec["stage_gpu_ms"]["gbuffer"])
    f = float(rec["overhead_stage_sum_gpu_ms"])
    ref = float(rec["ref_ms"])
    rate = float(rec.get("timing_sampling_rate", rec["sampling_rate"]))
    a = ref / (g + f)
    # a floor above the measured passes (other kernels counted, or a different run) bounds nothing: the measurement
    b = ref / (g + min(floor_ms, f)) if floor_ms is not None else None
    full_share = rate * max(ref - g, 0.0)  # the list's shading at the full frame's per-pixel cost
    c = ref / (g + f + full_share)
    shade = rec["stage_gpu_ms"].get("shade")
    ratio = float(shade) / full_share if (shade is not None and full_share > 0.0) else None
    d = None
    if gbuffer_floor_ms is not None:
        gf = min(float(gbuffer_floor_ms), g)  # a floor above the measured kernel changes nothing
        fov = float(rec["fov_ms"])
        d = (ref - g + gf) / (fov - g + gf) if fov - g + gf > 0.0 else None
    return {"gbuffer_ms": g, "fixed_ms": f, "rate": rate, "ref_ms": ref, "bound_free_shading": a,
            "bound_floor_free_shading": b, "bound_list_at_full_cost": c, "list_cost_per_pixel_vs_full": ratio,
            "estimate_gbuffer_at_floor": d}


def analyse(runs: list, floors: dict, gbuffer_floors=None, turns: str = "frames") -> list:
    """Rows per (scene, size, shading): the measured speed-ups of each run, the target, and the bounds over the
    runs (the largest bound, the smallest stage times and list cost ratio: a transient cannot lower a bound).
    Only records timed with the turn schedule ``turns`` count (``frame.py --turns``; a record without one was timed
    frame by frame), so a run that timed both schedules counts once."""
    groups: dict = {}
    for run in runs:
        for r in run["records"]:
            if (r.get("kind") != "timing" or r.get("config", "default") != "default"
                    or record_turns(r) != turns):
                continue
            key = (r["scene"], int(r["width"]), int(r["height"]), r["shading"])
            groups.setdefault(key, []).append(r)
    rows = []
    for (scene, w, h, shading), recs in groups.items():
        fl = floors.get((scene, f"{w}x{h}", shading))
        gfl = (gbuffer_floors or {}).get((scene, f"{w}x{h}", shading))
        bs = [bounds(r, fl, gfl) for r in recs]
        # over the runs: the most favourable value of each (the bounds are upper bounds, so a run whose stage
        # times a transient inflated must not lower them): the largest bound, the smallest cost; a run may lack a
        # value (no shade stage, ref <= G)
        med = {}
        for k in bs[0]:
            vals = [b[k] for b in bs if b[k] is not None]
            pick = (max if k.startswith("bound_") else
                    min if k in ("gbuffer_ms", "fixed_ms", "list_cost_per_pixel_vs_full") else statistics.median)
            med[k] = pick(vals) if vals else None
        t = target(scene, w, h, shading)
        row = {"scene": scene, "width": w, "height": h, "shading": shading, "target": t,
               "speedups": [float(r["speedup"]) for r in recs],
               "auto_speedups": [float(r["ref_ms"]) / float(r["auto_ms"]) for r in recs if r.get("auto_ms")],
               "auto_paths": [r.get("auto_path") for r in recs], **med}
        if t is not None:
            met = min(row["speedups"]) >= t
            if met:
                verdict = "met"
            elif t <= 1.0 and row["auto_speedups"] and all(p == "full" for p in row["auto_paths"]):
                lo = min(row["auto_speedups"])
                verdict = ("met by the default policy (full resolution)" if lo >= t else
                           f"the default policy renders full resolution, at {1.0 / lo:.3f}x the reference's time "
                           f"at worst: missed by the policy's overhead and the runs' spread")
            elif med["bound_floor_free_shading"] is not None and med["bound_floor_free_shading"] < t:
                verdict = "out of reach: G-buffer + fixed passes at their DRAM floor exceed ref / target"
            elif med["bound_free_shading"] < t:
                verdict = "out of reach with today's fixed passes: G-buffer + fixed passes exceed ref / target"
            elif med["bound_list_at_full_cost"] < t:
                verdict = "needs the list cheaper per pixel than shading every pixel"
            else:
                verdict = "missed: within the bounds (the list's per-pixel cost and the passes' speed)"
            row["verdict"] = verdict
        rows.append(row)
    rows.sort(key=lambda r: (r["shading"], r["width"], r["scene"]))
    return rows


def markdown(rows: list, sources: list) -> str:
    def f(v, d=2):
        return "-" if v is None else f"{v:.{d}f}"

    out = [f"Speed-up bounds from measured GPU stage times ({', '.join(sources)}). A: traced shading free. "
           "B: also the fixed passes at their Nsight DRAM floor. C: the list at the full frame's per-pixel shading "
           "cost. Over the runs: the largest bound, the smallest G-buffer and fixed-pass times and list ratio. "
           "D (an estimate, the median over the runs): the G-buffer at its DRAM floor in both frames, the rest as "
           "measured.", "",
           "| scene | size | shading | target | measured speed-up (runs) | auto: ref / default policy | G-buffer ms | "
           "fixed passes ms | rate | A | B | C | list cost per pixel / full frame's | D | verdict |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['scene']} | {r['width']}x{r['height']} | {r['shading']} | {f(r['target'], 1)} | "
                   f"{' / '.join(f'{s:.2f}' for s in r['speedups'])} | "
                   f"{' / '.join(f'{s:.3f}' for s in r['auto_speedups']) or '-'} | {f(r['gbuffer_ms'], 3)} | "
                   f"{f(r['fixed_ms'], 3)} | {r['rate']:.3f} | {f(r['bound_free_shading'])} | "
                   f"{f(r['bound_floor_free_shading'])} | {f(r['bound_list_at_full_cost'])} | "
                   f"{f(r['list_cost_per_pixel_vs_full'])} | {f(r.get('estimate_gbuffer_at_floor'))} | "
                   f"{r.get('verdict', '-')} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--timing", nargs="+", required=True, help="frame.py --parts timing JSON files (runs)")
    p.add_argument("--ncu", nargs="*", default=[], help="ncu_frame.py markdown files (DRAM floors), optional")
    p.add_argument("--name", default="ceiling", help="output file stem")
    p.add_argument("--out", default=None, help="output folder (default benchmarks/results)")
    p.add_argument("--turns", default="frames", choices=TURNS,
                   help="the turn schedule of the timing records that count (frame.py --turns)")
    a = p.parse_args(argv)
    for flag, paths in (("--timing", a.timing), ("--ncu", a.ncu)):
        for t in paths:
            if not Path(t).is_file():
                p.error(f"{flag}: no such file: {t}")
    runs = [json.loads(Path(t).read_text()) for t in a.timing]
    floors: dict = {}
    gfloors: dict = {}
    for path in a.ncu:
        floors.update(ncu_floors(path))
        gfloors.update(ncu_gbuffer_floors(path))
    rows = analyse(runs, floors, gfloors, a.turns)
    if not rows:
        p.error(f"no timing record of the default configuration timed by {a.turns} in the --timing files")
    out = Path(a.out) if a.out else RESULTS
    out.mkdir(parents=True, exist_ok=True)
    sources = [Path(t).name for t in a.timing] + [Path(n).name for n in a.ncu]
    res = {"benchmark": "ceiling", "sources": sources, "commits": sorted({r.get("commit", "?") for r in runs}),
           "device": runs[0].get("device_name", runs[0].get("device")), "rows": rows}
    (out / f"{a.name}.json").write_text(json.dumps(res, indent=1))
    md = markdown(rows, sources)
    (out / f"{a.name}.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
