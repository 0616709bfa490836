"""The benchmark entry points of benchmarks/, run as a user runs them (``python benchmarks/NAME.py ... --out DIR``)
at tiny sizes on the CPU: each writes its JSON, markdown and (where it has one) PNG, and the JSON's fields and
values are sane: the device, commit, sizes and scenes it ran, figures that are finite, positive and consistent with
each other (no timing assertions: a ratio is checked against the two numbers it divides). Also: the common options
and canonical command of every entry point's --help, bad options refused by name, tools/canonical.sh's parts, and
frame.py's two timing schedules with stand-in loops."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.append(str(REPO))

from benchmarks import _common  # noqa: E402

ENTRY_POINTS = sorted(f.stem for f in (REPO / "benchmarks").glob("*.py") if not f.stem.startswith("_"))
CPU_NAME = _common.cpu_model()


def _run(name: str, args: list, out: Path, env=None, ok=True) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / f"{name}.py"), *args, "--out", str(out)],
                       capture_output=True, text=True, cwd=REPO, env=env, timeout=600)
    if ok:
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return r


def _expected_commit() -> str:
    if os.environ.get("FOVEAWARP_COMMIT"):
        return os.environ["FOVEAWARP_COMMIT"]
    r = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True)
    return r.stdout.strip() if r.returncode == 0 else "unknown"


def _result(name: str, out: Path, tag: str = "cpu", png: bool = True, commit=None) -> dict:
    """The run's JSON, after the checks every entry point shares: the files, the device, the commit (``commit``,
    else the checkout's full hash), every record's device / width / height / scene, and a markdown table."""
    stem = out / f"{name}-{tag}"
    res = json.loads(stem.with_suffix(".json").read_text())
    assert res["benchmark"] == name and res["device_alias"] == "cpu" and res["is_cuda"] is False
    assert res["device"] == CPU_NAME and res["warp"] == wp.__version__
    if commit is None:
        commit = _expected_commit()
        if commit != "unknown" and not os.environ.get("FOVEAWARP_COMMIT"):
            assert re.fullmatch(r"[0-9a-f]{40}", commit), commit  # the full hash, not an abbreviation
    assert res["commit"] == commit
    assert res["wall_s"] > 0 and res["records"]
    for r in res["records"]:
        assert r["device"] == CPU_NAME and {"width", "height", "scene"} <= set(r), r
    md = stem.with_suffix(".md").read_text()
    assert md.startswith(f"# {name} on {CPU_NAME} (cpu), commit {commit[:12]}") and "|---|" in md
    assert stem.with_suffix(".png").is_file() == png
    if png:
        assert stem.with_suffix(".png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return res


def _pos(*values) -> bool:
    return all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in values)


def test_frame(tmp_path):
    """frame.py: per scene x AO setting one record with the quality series along the path (PSNR, SSIM, fovea
    PSNR), their mean and min, the three loops' frame times, the speed-ups they make and the default policy's
    path; with AO rays the full-resolution frame's own error against the converged target too. The tag names the
    files."""
    _run("frame", ["--quick", "--device", "cpu", "--scenes", "cornell,nosuchmesh", "--ao-samples", "0,2",
                   "--converged-ao", "8", "--tag", "smoke"], tmp_path)
    res = _result("frame", tmp_path, "smoke")
    assert (res["frames"], res["timing_frames"], res["turns"]) == (3, 3, "frames")
    assert [(r["scene"], r["ao_samples"], r["width"], r["height"]) for r in res["records"]] == [
        ("cornell", 0, 64, 36), ("cornell", 2, 64, 36)]  # the missing mesh is skipped
    for r in res["records"]:
        s = r["series"]
        assert len(s["psnr"]) == len(s["ssim"]) == len(s["fovea_psnr"]) == len(r["sampling_rate_series"]) == 3
        psnr = [math.inf if v is None else v for v in s["psnr"]]  # a frame equal to its target: inf, null in JSON
        assert (r["psnr_min"] or math.inf) == pytest.approx(min(psnr))
        assert r["psnr_mean"] == pytest.approx(np.mean(np.minimum(psnr, 100.0)))
        assert 10.0 < min(psnr) and 10.0 < r["psnr_mean"] <= 100.0 and 0.0 < r["ssim_mean"] <= 1.0
        assert all(0.0 < v <= 1.0 for v in r["sampling_rate_series"])
        assert _pos(r["ref_ms"], r["fov_ms"], r["auto_ms"])
        assert r["speedup"] == pytest.approx(r["ref_ms"] / r["fov_ms"])
        assert r["auto_speedup"] == pytest.approx(r["ref_ms"] / r["auto_ms"])
        assert r["auto_path"] in ("foveated", "full") and set(r["auto_estimates"]) >= {"foveated_ms", "full_ms"}
        assert r["stage_ms"] and all(v >= 0 for v in r["stage_ms"].values())
        # FovVideoVDP where pyfvvdp is installed: one JOD per video, at most 10 (no visible difference)
        assert ("+fovvdp" in r["metrics_on"]) == ("fovvdp_jod" in r)
        if "fovvdp_jod" in r:
            assert 0.0 < r["fovvdp_jod"] <= 10.0 + 1e-6 and "fovvdp" not in s
    plain, ao = res["records"]
    assert plain["quality_target"] == "render_reference" and "ref_psnr_mean" not in plain
    if "fovvdp_jod" in ao:  # 2 AO rays against 8: visibly different from the converged frame
        assert ao["fovvdp_jod"] < 10.0 and ao["ref_fovvdp_jod"] < 10.0
    assert ao["quality_target"] == "8 AO rays" and len(ao["ref_series"]["psnr"]) == 3
    # 2 AO rays against 8: neither frame equals the converged one
    assert 10.0 < ao["ref_psnr_mean"] < 100.0 and ao["psnr_mean"] < 100.0
    md = (tmp_path / "frame-smoke.md").read_text()
    assert "| speedup |" in md and "| psnr_mean |" in md and "| auto_path |" in md


def test_frame_stochastic_target_and_keep(tmp_path):
    """frame.py on the room (its environment is sampled: stochastic shading): the target is converged with
    --converged-samples and the full-resolution frame gets its own error; --keep keeps an earlier JSON's records
    that the run does not repeat, with their commit, and the repeated one is replaced; a bad --keep is refused."""
    old = {"benchmark": "frame", "commit": "c0ffee", "records": [
        {"scene": "cornell", "width": 64, "height": 36, "config": "default", "ao_samples": 0, "psnr_mean": 40.0},
        {"scene": "room", "width": 64, "height": 36, "config": "default", "ao_samples": 0, "psnr_mean": 14.5}]}
    keep = tmp_path / "old.json"
    keep.write_text(json.dumps(old))
    _run("frame", ["--quick", "--device", "cpu", "--scenes", "room", "--ao-samples", "0", "--frames", "2",
                   "--timing-frames", "0", "--converged-samples", "16", "--keep", str(keep), "--tag", "keep"],
         tmp_path)
    res = _result("frame", tmp_path, "keep", png=False)  # no timing: no time-vs-error plot
    kept, room = res["records"]
    assert (kept["scene"], kept["commit"], kept["psnr_mean"]) == ("cornell", "c0ffee", 40.0)
    assert room["scene"] == "room" and room["commit"] == res["commit"] != "c0ffee"
    assert room["quality_target"] == "16 light and environment samples" and len(room["ref_series"]["psnr"]) == 2
    assert 10.0 < room["psnr_mean"] < 100.0 and 10.0 < room["ref_psnr_mean"] < 100.0
    assert res["kept_from"] == "old.json" and res["kept_records"] == 1
    bad = tmp_path / "bad.json"
    bad.write_text('{"benchmark": "stages", "records": []}')
    r = _run("frame", ["--quick", "--device", "cpu", "--scenes", "room", "--keep", str(bad)], tmp_path, ok=False)
    assert r.returncode == 2 and "--keep must name a frame JSON" in r.stderr


def test_frame_summarize_prints_the_readme_table(tmp_path):
    """frame.py --summarize: one row per timed and measured record with the figures of the JSON, the plot's link,
    and --readme writes it between the markers (a README without them is refused by name)."""
    from benchmarks import frame

    rec = {"scene": "bunny", "width": 3840, "height": 2160, "config": "default", "ao_samples": 8,
           "quality_target": "256 AO rays", "ref_ms": 9.0, "fov_ms": 3.0, "speedup": 3.0, "auto_ms": 3.1,
           "auto_path": "foveated", "psnr_mean": 41.23, "psnr_min": 39.06, "ssim_mean": 0.9871, "device": "GPU"}
    res = {"benchmark": "frame", "device": "NVIDIA H200", "warp": "1.19.0", "frames": 30, "timing_frames": 30,
           "records": [rec, {**rec, "scene": "cornell", "fov_ms": 0.5}]}
    del res["records"][1]["psnr_mean"]  # timed but not measured: left out
    j = tmp_path / "frame-h200.json"
    j.write_text(json.dumps(res))
    text = frame.summarize(j, base=tmp_path)
    assert "| bunny | 3840x2160 | 8 | 9.00 | 3.00 | 3.00x | 3.10 ms (foveated) | 41.2 / 39.1 | 0.987 |" in text
    assert "cornell" not in text and "On NVIDIA H200" in text and "256 AO rays" in text
    assert text.rstrip().endswith("![frame time against PSNR](frame-h200.png)")
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n{frame.README_BEGIN}\nold\n{frame.README_END}\n\nrest\n")
    r = _run("frame", ["--summarize", str(j), "--readme", str(readme)], tmp_path)
    new = readme.read_text()
    assert frame.readme_results(new) == frame.summarize(j).strip() and new.endswith("\n\nrest\n")
    assert r.stdout == frame.summarize(j)
    readme.write_text("# no markers\n")
    bad = _run("frame", ["--summarize", str(j), "--readme", str(readme)], tmp_path, ok=False)
    assert bad.returncode == 2 and "lacks the results markers" in bad.stderr
    bad = _run("frame", ["--summarize", str(tmp_path / "none.json")], tmp_path, ok=False)
    assert bad.returncode == 2 and "--summarize must name a frame JSON" in bad.stderr


def test_path(tmp_path):
    """path.py: per scene x size one record with the full-resolution and foveated items (frame ms, fovea PSNR and
    FLIP against the converged target, whole-frame PSNR), the equal-time and equal-quality read-offs with the
    fields the canonical JSON carries, the pair's image; --keep keeps the records this run does not repeat."""
    imgs = tmp_path / "img"
    _run("path", ["--device", "cpu", "--quick", "--scenes", "cornell", "--images", str(imgs)], tmp_path)
    res = _result("path", tmp_path)
    (r,) = res["records"]
    for k in ("device", "scene", "width", "height", "integrator", "max_depth", "ref_ms", "fov_ms",
              "equal_quality_speedup", "fovea_psnr_fov", "fovea_psnr_ref", "fovea_flip_fov", "fovea_flip_ref",
              "fvvdp_jod_fov", "fvvdp_jod_ref", "commit"):
        assert k in r, k
    assert r["integrator"] == "path" and r["max_depth"] == 5 and _pos(r["ref_ms"], r["fov_ms"])
    pols = [(it["policy"], it["path_budget"]) for it in r["items"]]
    assert pols.count(("full", "pixel")) == 2 and ("foveated", "pixel") in pols and ("foveated", "frame") in pols
    for it in r["items"]:
        assert _pos(it["ms"]) and len(it["series"]["fovea_psnr"]) == r["frames"] == 3
        assert 0 < it["fovea_psnr"] <= 100
        # FLIP where flip-evaluator is installed (the bench and metrics extras), else left out
        assert (0 <= it["fovea_flip_mean"] <= 1) if res["flip"] else it["fovea_flip_mean"] is None
        if it["policy"] == "foveated":
            assert _pos(it["equal_quality_speedup"]) and set(it["paths_per_pixel_by_band"]) == {"0-5", "5-20", "20+"}
    # more paths per pixel bring the full-resolution frame's fovea closer to the converged target
    full = sorted((it for it in r["items"] if it["policy"] == "full"), key=lambda it: it["spp"])
    assert full[1]["fovea_psnr"] > full[0]["fovea_psnr"]
    assert (imgs / "path-cornell-64x36.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    keep = tmp_path / "keep.json"
    keep.write_text((tmp_path / "path-cpu.json").read_text().replace('"cornell"', '"elsewhere"'))
    _run("path", ["--device", "cpu", "--quick", "--scenes", "cornell", "--keep", str(keep)], tmp_path)
    assert [x["scene"] for x in _result("path", tmp_path)["records"]] == ["elsewhere", "cornell"]


def test_path_variants_and_summarize(tmp_path):
    """path.py --variants: each foveated item once per variant, with its own configuration (the filtered ones
    differ from the plain ones outside the fovea, and the periphery's history and the variance guide from the
    filter alone), the equal-time read-off per variant and its table; a bad list refused; --summarize writes the markdown and the
    plot again from the JSON alone."""
    _run("path", ["--device", "cpu", "--quick", "--scenes", "cornell", "--budgets", "pixel",
                  "--variants", "demod+filter,plain,demod+filter+history,demod+filter+variance"], tmp_path)
    res = _result("path", tmp_path)
    (r,) = res["records"]
    assert r["variants"] == ["demod+filter", "plain", "demod+filter+history", "demod+filter+variance"]
    fov = {it["variant"]: it for it in r["items"] if it["policy"] == "foveated"}
    assert set(fov) == set(r["variants"]) and {it["variant"] for it in r["items"] if it["policy"] == "full"} == {"-"}
    # the fovea as traced in all, the rest of the frame filtered in two, and steadied by its history in one
    for v in ("plain", "demod+filter+history", "demod+filter+variance"):
        assert fov["demod+filter"]["fovea_psnr"] == pytest.approx(fov[v]["fovea_psnr"], abs=0.01)
    for v in ("plain", "demod+filter+history", "demod+filter+variance"):
        assert fov["demod+filter"]["psnr_mean"] != fov[v]["psnr_mean"], v
    by = r["equal_time_by_variant"]
    assert set(by) == set(r["variants"]) and r["equal_time_item"] == by["demod+filter"]["item"]
    md = (tmp_path / "path-cpu.md").read_text()
    assert "Equal time by variant" in md and "| demod+filter |" in md and "| plain |" in md
    (tmp_path / "path-cpu.md").unlink()
    (tmp_path / "path-cpu.png").unlink(missing_ok=True)
    _run("path", ["--summarize", str(tmp_path / "path-cpu.json")], tmp_path)
    assert (tmp_path / "path-cpu.md").read_text() == md
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "path.py"), "--variants", "plain,svgf"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "--variants must be a comma list of distinct plain, demod" in r.stderr


def test_reorder(tmp_path):
    """reorder.py: per scene, shading, mask and rate the full, masked ("none") and reordered times, each strategy's
    total the sum of its compaction and tracing, the best the fastest, the achieved rate near the asked one."""
    _run("reorder", ["--quick", "--device", "cpu", "--scenes", "cornell"], tmp_path)
    res = _result("reorder", tmp_path)
    assert res["mode"] == "tracing"
    rows = res["records"]
    assert len(rows) == 2 * 2 * 3  # shadings x masks x rates
    assert {(r["shading"], r["mask"]) for r in rows} == {(s, m) for s in ("light", "heavy")
                                                          for m in ("foveated", "random")}
    for r in rows:
        assert (r["scene"], r["width"], r["height"]) == ("cornell", 64, 36)
        assert min(abs(r["rate"] - t) for t in (0.1, 0.3, 0.5)) < 0.1
        assert _pos(r["full_ms"], r["none_ms"]) and r["ideal_ms"] == pytest.approx(r["rate"] * r["full_ms"])
        for s in ("rows", "rows+balance", "scan", "tile"):
            assert _pos(r[f"{s}_compact_ms"], r[f"{s}_trace_ms"])
            assert r[f"{s}_ms"] == pytest.approx(r[f"{s}_compact_ms"] + r[f"{s}_trace_ms"])
        assert r["best_ms"] == min(r[f"{s}_ms"] for s in ("rows", "rows+balance", "scan", "tile"))
        assert r["speedup_vs_none"] == pytest.approx(r["none_ms"] / r["best_ms"])


def test_stages(tmp_path):
    """stages.py, every part: sampling runs and rates, JFA variants with their wrong-pixel share against the
    exact distance transform, bounded against exact Sibson, BVH configurations that draw the same G-buffer, device
    metrics equal to the host's, the reference's parts, a textured scene's G-buffer and shading with and without its
    textures."""
    _run("stages", ["--quick", "--device", "cpu"], tmp_path)
    res = _result("stages", tmp_path, png=False)
    assert res["parts"] == ["sampling", "reconstruct", "bvh", "metrics", "reference", "textures"]
    by = {}
    for r in res["records"]:
        by.setdefault(r["part"], []).append(r)
    assert set(by) == {"sampling", "sampling_rate", "reconstruct", "reconstruct_stage", "bvh", "metrics",
                       "reference", "textures"}
    assert all(_pos(r["median_ms"]) and 0 < r["sampling_rate"] <= 1 for r in by["sampling"])
    for r in by["reconstruct"]:
        assert 0 < r["seeds_pct"] < 100 and _pos(r["sibson_bounded_ms"], r["sibson_exact_ms"])
        assert all(0 <= v["wrong_pct"] <= 100 and _pos(v["ms"]) for v in r["jfa"].values())
        assert 0 <= r["max_abs_diff"] < 1.0
    assert {r["config"] for r in by["bvh"]} == {"auto", "sah-4", "sah-2", "cubql", "lbvh-2"}
    assert all(r["pixels_differ_from_first"] == 0 and _pos(r["gbuffer_ms"]) for r in by["bvh"])
    (m,) = by["metrics"]
    assert m["max_abs_diff"] < 1e-3 and _pos(m["device_ms"], m["host_ms"])
    (ref,) = by["reference"]
    assert _pos(ref["gbuffer_ms"], ref["shade_ms"], ref["shade_ao8_ms"], ref["frame_ms"])
    (tex,) = by["textures"]
    assert tex["scene"] == "room" and _pos(tex["gbuffer_textured_ms"], tex["gbuffer_untextured_ms"],
                                           tex["shade_textured_ms"], tex["shade_untextured_ms"])
    assert tex["gbuffer_ratio"] == tex["gbuffer_textured_ms"] / tex["gbuffer_untextured_ms"]


def test_dof(tmp_path):
    """dof.py: gather and scatter times per image and max CoC, the mean CoC within the max, PSNR / SSIM of the
    five images of each quality case against the thin-lens reference, and the comparison strip's size (one row
    per case, four images a row)."""
    _run("dof", ["--quick", "--device", "cpu"], tmp_path)
    res = _result("dof", tmp_path)
    speed = [r for r in res["records"] if r["part"] == "speed"]
    qual = [r for r in res["records"] if r["part"] == "quality"]
    assert sorted((r["image"], r["max_coc_px"]) for r in speed) == sorted(
        (i, c) for i in ("ramp", "worst") for c in (8.0, 16.0, 32.0))
    for r in speed:
        assert (r["width"], r["height"]) == (160, 90) and _pos(r["gather_ms"], r["scatter_ms"])
        assert 0 <= r["mean_coc_px"] <= r["max_coc_px"] + 1e-3
    cases = sorted({r["case"] for r in qual})
    assert len(cases) == 3 and len(qual) == 15
    for r in qual:
        assert (r["width"], r["height"], r["lens_samples"]) == (96, 54, 16)
        assert 15.0 < r["psnr_db"] < 100.0 and 0.0 < r["ssim"] <= 1.0
    import imageio.v3 as iio

    assert iio.imread(tmp_path / "dof-cpu.png").shape[:2] == (3 * 54, 4 * 96)


def test_indirect(tmp_path):
    """indirect.py: one record per method (tree variants and the sampled ladder) with frame = gather + rebuild,
    flicker and 1 - SSIM in range; one comparison per tree variant at equal quality; the side-by-side image."""
    _run("indirect", ["--quick", "--device", "cpu", "--scenes", "cornell", "--workers", "1"], tmp_path)
    res = _result("indirect", tmp_path)
    assert res["complete"] is True and res["size"] == [96, 54]
    methods = [r for r in res["records"] if r["part"] == "methods"]
    comps = [r for r in res["records"] if r["part"] == "comparisons"]
    (run,) = res["runs"]
    assert [r["method"] for r in methods] == ["default", "point L4 (paper)", "extended L6"] + [
        f"sampled {s}" for s in run["ladder"]]
    for r in methods:
        assert (r["scene"], r["rsm"]) == ("cornell", 32)
        assert r["ms_frame"] == pytest.approx(r["ms_gather"] + r["ms_rebuild"]) and _pos(r["ms_gather"])
        assert 0 <= r["dssim"] < 1 and r["flicker"] >= 0 and r["rel_l2"] >= 0
        assert (r["flip"] is None) == (not res["flip_available"])
    assert [c["tree"] for c in comps] == ["default", "point L4 (paper)", "extended L6"]
    assert all(c["eq_dssim_bound"] in ("", ">=", "<=") for c in comps)


def test_cpu(tmp_path):
    """cpu.py at 96x54 with 1 and 2 threads: scaling rows (speed-ups over the first), foveated vs reference rows
    with the default policy, the primary-ray comparison (Embree only when embreex is installed), the plot."""
    _run("cpu", ["--quick", "--device", "cpu", "--scenes", "cornell", "--threads", "1,2", "--oversplit", "2",
                 "--frames", "2"], tmp_path)
    res = _result("cpu", tmp_path)
    by = {}
    for r in res["records"]:
        by.setdefault(r["part"], []).append(r)
    assert [r["threads"] for r in by["scaling"]] == [1, 2] and res["threads"] == [1, 2]
    for r in by["scaling"]:
        assert _pos(r["foveated_ms"], r["reference_ms"]) and (r["width"], r["height"]) == (96, 54)
        assert r["foveated_speedup"] == pytest.approx(by["scaling"][0]["foveated_ms"] / r["foveated_ms"])
    assert by["scaling"][0]["foveated_speedup"] == 1.0
    assert [r["oversplit"] for r in by["oversplit"]] == [2] and len(by["variants"]) == 4
    assert [(r["scene"], r["shading"]) for r in by["versus"]] == [("cornell", "default"), ("cornell", "ao_samples=8")]
    for r in by["versus"]:
        assert r["auto_path"] in ("foveated", "full") and _pos(r["auto_ms"], r["foveated_ms"], r["reference_ms"])
        assert r["reference_over_auto"] == pytest.approx(r["reference_ms"] / r["auto_ms"])
        assert 0 < r["sampled_fraction"] <= 1
    (rays,) = by["rays"]
    assert rays["rays"] == 96 * 54 and 0 < rays["hit_fraction"] < 1 and rays["packet_same_face_as_single"] > 0.999
    if "embree_1t_mrays_s" in rays:
        assert rays["same_hit_miss"] > 0.99 and rays["same_face"] > 0.95
    else:
        assert "not installed" in rays["embree"]


def test_viewer(tmp_path):
    """viewer.py at 96x54 for one second: the viewer process starts, frames arrive and decode at the right size,
    latencies are recorded and ordered (every gaze message waits at least as long as the rendered ones)."""
    pytest.importorskip("websockets", reason="the viewer extra (websockets) is not installed")
    _run("viewer", ["--quick", "--device", "cpu", "--seconds", "1", "--warmup-s", "0.5"], tmp_path)
    res = _result("viewer", tmp_path, png=False)
    (row,) = res["records"]
    assert (row["scene"], row["width"], row["height"], row["resolution"]) == ("cornell", 96, 54, "96x54")
    assert row["decoded_sizes_ok"] is True and row["frames"] > 0 and _pos(row["fps_delivered"])
    assert row["frame_ms"] == pytest.approx(1e3 / row["fps_delivered"])
    assert row["latency_samples"] > 0 and 0 < row["latency_server_p50_ms"] <= row["latency_server_p95_ms"]
    assert 0 < row["latency_msg_p50_ms"] <= row["latency_msg_p95_ms"]
    assert row["encoder"] in ("simplejpeg", "pillow") and res["seconds"] == 1.0


def test_robustness(tmp_path):
    """robustness.py, both parts, with FOVEAWARP_COMMIT standing in for the commit: the soak's samples, cuts and
    verdicts; the parity part's determinism and saved arrays; exit status 0."""
    frames, warmup, every = 60, 10, 10
    npz = tmp_path / "parity.npz"
    _run("robustness", ["--quick", "--device", "cpu", "--frames", str(frames), "--warmup", str(warmup), "--width",
                        "64", "--height", "36", "--check-every", str(every), "--cut-every", "25", "--save",
                        str(npz)], tmp_path, env={"FOVEAWARP_COMMIT": "stand-in-commit"})
    res = _result("robustness", tmp_path, commit="stand-in-commit")
    assert res["parts"] == ["soak", "parity"] and res["pass"] is True
    soak, parity = res["records"]
    assert (soak["scene"], soak["width"], soak["height"], soak["frames"]) == ("cornell+motion", 64, 36, frames)
    ft = soak["frame_time"]
    assert ft["timed_frames"] == frames - warmup
    assert 0 < ft["p50_ms"] <= ft["p90_ms"] <= ft["p99_ms"] <= ft["max_ms"]
    # a memory sample at the first frame after warm-up, every `every` frames, and after the last frame
    assert [s["frame"] for s in soak["memory_samples"]] == [*range(warmup, frames, every), frames - 1]
    assert soak["nan_checks"] == len(soak["memory_samples"]) and soak["nan_frames"] == []
    assert soak["warmup_cuts"] == [5, 6, 7, 8] and soak["forced_cuts"] == 6  # frames 5-8 (warm-up), 25, 50
    assert sum(soak["graph_states_after_warmup"].values()) == frames - warmup
    assert soak["gaze_off_screen_frames"] > 0 and len(soak["window_median_ms"]) == (frames - warmup) // every
    assert soak["verdict"]["no_nan"] is True and soak["verdict"]["memory_flat"] is True and soak["pass"] is True
    assert (parity["mode"], parity["width"], parity["height"]) == ("save", 64, 48)
    assert parity["determinism"]["bit_identical"] is True and parity["pass"] is True
    with np.load(npz) as z:
        assert "image" in z.files and z["image"].shape == (48, 64, 3)


def test_robustness_refuses_bad_options(tmp_path):
    for args, text in ((["--parts", "soak,bogus"], "--parts must be"), (["--parts", "soak", "--save", "x.npz"],
                       "--save and --compare belong to the parity part"),
                       (["--compare", str(tmp_path / "none.npz")], "--compare must name a .npz"),
                       (["--frames", "10", "--warmup", "10"], "--warmup must be in [0, frames)")):
        r = _run("robustness", ["--device", "cpu", *args], tmp_path, ok=False)
        assert r.returncode == 2 and text in r.stderr, (args, r.stderr[-500:])


def test_help_shows_the_common_options_and_the_canonical_run(capsys):
    """Every entry point's --help begins with its canonical command (the one tools/canonical.sh runs, writing
    <name>-h200 files into benchmarks/results) and has the common options."""
    import runpy

    canonical = " ".join((REPO / "tools" / "canonical.sh").read_text().replace("\\\n", " ").split())
    for name in ENTRY_POINTS:
        mod = runpy.run_path(str(REPO / "benchmarks" / f"{name}.py"), run_name=f"benchmarks.{name}")
        with pytest.raises(SystemExit) as e:
            mod["main"](["--help"])
        assert e.value.code == 0
        out = capsys.readouterr().out
        cmd = mod["CANONICAL"]
        assert f"canonical run: {cmd}" in " ".join(out.split()), name
        assert cmd.startswith(f"python benchmarks/{name}.py --device ") and "--out benchmarks/results --tag h200" in cmd
        assert cmd in canonical, f"tools/canonical.sh does not run {name}'s canonical command: {cmd}"
        for opt in ("--device", "--out", "--tag", "--quick"):
            assert opt in out, (name, opt)


def test_canonical_sh_parts(tmp_path):
    """tools/canonical.sh with a stand-in python that logs its arguments: part1 and part2 together run every
    entry point but path once, each part its own, part3 the textured frame and stages runs, part4 the eight path
    runs (the 4K entry one scene per run); a list runs the names given; an unknown name is refused; without
    frame-h200.json the README step fails and the exit status says so."""
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "python").write_text('#!/bin/sh\necho "$*" >> "$FAKE_LOG"\n')
    (fake / "python").chmod(0o755)

    def run(*args):
        log = tmp_path / f"log{len(list(tmp_path.iterdir()))}"
        env = {**os.environ, "PATH": f"{fake}{os.pathsep}{os.environ['PATH']}", "FAKE_LOG": str(log),
               "FOVEAWARP_COMMIT": "x"}
        r = subprocess.run(["bash", str(REPO / "tools" / "canonical.sh"), *args], capture_output=True, text=True,
                           env=env, timeout=60)
        scripts = [line.split()[0] for line in log.read_text().splitlines()] if log.exists() else []
        return r, scripts

    json_there = (REPO / "benchmarks" / "results" / "frame-h200.json").is_file()
    r1, s1 = run("part1")
    assert s1[:2] == ["benchmarks/frame.py", "benchmarks/reorder.py"]
    assert r1.returncode == (0 if json_there else 1) and ("readme" in r1.stderr)
    r2, s2 = run("part2")
    assert r2.returncode == 0, r2.stderr
    entries = {f"benchmarks/{n}.py" for n in ENTRY_POINTS}
    assert not set(s1[:2]) & set(s2)
    assert s2.count("benchmarks/robustness.py") == 2  # the parity's CPU half, then the CUDA run
    r5, s5 = run("part3")
    assert r5.returncode == 0 and s5 == ["benchmarks/frame.py", "benchmarks/stages.py"], r5.stderr
    r6, s6 = run("part4")
    assert r6.returncode == 0 and s6 == ["benchmarks/path.py"] * 8, r6.stderr
    assert set(s1[:2]) | set(s2) | set(s5) | set(s6) == entries
    r3, s3 = run("dof", "cpu")
    assert r3.returncode == 0 and s3 == ["benchmarks/dof.py", "benchmarks/cpu.py"]
    r4, s4 = run("bogus")
    assert r4.returncode == 2 and "unknown part or entry point 'bogus'" in r4.stderr and s4 == []


def test_benchmarks_import_the_library_on_pythonpath_first(tmp_path):
    """An entry point run with another foveawarp on PYTHONPATH (an old version extracted for an A/B) runs that
    one: the scripts add the repository after PYTHONPATH, not before it. The stand-in library here refuses to
    import, with its own message; without it the repository's library is found."""
    fake = tmp_path / "lib" / "foveawarp"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text('raise ImportError("the foveawarp on PYTHONPATH was imported")\n')
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "lib")}
    script = str(REPO / "benchmarks" / "cpu.py")
    r = subprocess.run([sys.executable, script, "--help"], capture_output=True, text=True, cwd=tmp_path, env=env,
                       timeout=300)
    assert r.returncode != 0 and "the foveawarp on PYTHONPATH was imported" in r.stderr, r.stderr[-2000:]
    env.pop("PYTHONPATH")
    r = subprocess.run([sys.executable, script, "--help"], capture_output=True, text=True, cwd=tmp_path, env=env,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]


def test_write_results_refuses_a_record_without_its_size_or_scene(tmp_path):
    with pytest.raises(ValueError, match=r"records\[1\] of x lacks \['scene'\]"):
        _common.write_results("x", "cpu", [{"scene": "a", "width": 1, "height": 1}, {"width": 1, "height": 1}],
                              "", tmp_path)
    p = _common.write_results("x", "cpu", [{"scene": "a", "width": 1, "height": 2, "v": float("inf")}], "t",
                              tmp_path, "t")
    assert p == tmp_path / "x-t.json" and json.loads(p.read_text())["records"][0]["v"] is None  # strict JSON


def test_frame_timing_turns():
    """frame.py's two timing schedules, with stand-in loops that log what they render: with turns by frames every
    loop renders each frame once, the loops in a new order every frame; with turns by blocks each loop renders
    runs of BLOCK_FRAMES consecutive frames, every loop the same runs, and the rounds give each loop at least n
    timed frames; each loop's frames are its warm-up then consecutive path frames in both; a bad skip is refused by
    name."""
    from benchmarks import frame as fb

    log = []

    class Loop:
        device = wp.get_device("cpu")

        def __init__(self, name):
            self.name = name

        def render(self, camera, gaze_px=None, time=None):
            log.append((self.name, round(time * 30.0)))

    class Scene:
        @staticmethod
        def camera_at(t):
            return t

    n, warm = 20, {"a": 3, "b": 5}
    for timed in (fb._timed_interleaved, fb._timed_blocks):
        log.clear()
        med = timed({"a": Loop("a"), "b": Loop("b")}, Scene(), 64, 32, n, warm)
        assert sorted(med) == ["a", "b"] and all(v >= 0.0 for v in med.values())
        for name, w0 in warm.items():
            frames = [i for k, i in log if k == name]
            assert frames == list(range(5 - w0, 5 - w0 + len(frames))), (timed.__name__, name, frames)
        timed_part = log[3 + 5:]  # after both warm-ups
        if timed is fb._timed_interleaved:
            assert len(timed_part) == 2 * n
            pairs = [timed_part[2 * i: 2 * i + 2] for i in range(n)]
            assert all(sorted(k for k, _ in p) == ["a", "b"] and p[0][1] == p[1][1] == 5 + i
                       for i, p in enumerate(pairs))
            assert len({tuple(k for k, _ in p) for p in pairs}) == 2  # both orders occur
        else:
            per = fb.BLOCK_FRAMES - fb.BLOCK_SKIP
            rounds = -(-n // per)
            assert len(timed_part) == 2 * rounds * fb.BLOCK_FRAMES
            runs = [timed_part[j: j + fb.BLOCK_FRAMES] for j in range(0, len(timed_part), fb.BLOCK_FRAMES)]
            for r in range(rounds):
                a, b = runs[2 * r], runs[2 * r + 1]
                assert {a[0][0], b[0][0]} == {"a", "b"} and len({k for k, _ in a}) == len({k for k, _ in b}) == 1
                f0 = 5 + r * fb.BLOCK_FRAMES
                assert [i for _, i in a] == [i for _, i in b] == list(range(f0, f0 + fb.BLOCK_FRAMES))
    with pytest.raises(ValueError, match="skip"):
        fb._timed_blocks({"a": Loop("a")}, Scene(), 64, 32, 4, {"a": 1}, block=4, skip=4)
