"""Smoke runs of the benchmark scripts with tiny sizes: they run, write their JSON / markdown and report sanely
(no timing assertions)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import warp as wp

from foveawarp.kernels.shade import LightParams, ShadeParams

REPO = Path(__file__).resolve().parent.parent


def _run(args, tmp_path):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    r = subprocess.run([sys.executable, *args, "--out", str(tmp_path)], capture_output=True, text=True, cwd=REPO,
                       env=env, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    return r


def test_soak_quick(device, tmp_path):
    frames, warmup, every = 60, 10, 10
    _run([str(REPO / "benchmarks" / "soak.py"), "--quick", "--device", device, "--frames", str(frames),
          "--warmup", str(warmup), "--width", "64", "--height", "36", "--check-every", str(every), "--cut-every",
          "25"], tmp_path)
    tag = "cuda" if wp.get_device(device).is_cuda else "cpu"
    res = json.loads((tmp_path / f"soak-{tag}.json").read_text())
    assert (tmp_path / f"soak-{tag}.md").is_file()
    assert res["benchmark"] == "soak" and res["resolution"] == "64x36" and res["frames"] == frames
    assert res["scene"] == "cornell+motion" and res["animated"] is True
    assert res["commit"] and res["device"] == wp.get_device(device).alias
    ft = res["frame_time"]
    assert ft["timed_frames"] == frames - warmup
    assert 0 < ft["p50_ms"] <= ft["p90_ms"] <= ft["p99_ms"] <= ft["max_ms"]
    # a memory sample at the first frame after warm-up, every `every` frames, and after the last frame
    assert [s["frame"] for s in res["memory_samples"]] == [*range(warmup, frames, every), frames - 1]
    assert res["nan_checks"] == len(res["memory_samples"]) and res["nan_frames"] == []
    assert res["warmup_cuts"] == [5, 6, 7, 8]
    assert res["forced_cuts"] == 6  # frames 5-8 (warm-up), 25, 50
    assert sum(res["graph_states_after_warmup"].values()) == frames - warmup
    assert res["gaze_off_screen_frames"] > 0
    assert res["verdict"]["no_nan"] is True and res["verdict"]["memory_flat"] is True
    if tag == "cuda":
        assert "mempool_used" in res["memory"]


def test_viewer_benchmark_quick(tmp_path):
    """benchmarks/viewer.py on the CPU at 96x54 for one second: the viewer process starts, frames arrive and
    decode at the right size, latencies are recorded (no speed assertion)."""
    import pytest

    pytest.importorskip("websockets", reason="the viewer extra (websockets) is not installed")
    _run([str(REPO / "benchmarks" / "viewer.py"), "--quick", "--device", "cpu", "--seconds", "1", "--warmup-s",
          "0.5"], tmp_path)
    res = json.loads((tmp_path / "viewer-cpu.json").read_text())
    assert res["benchmark"] == "viewer" and res["device"] == "cpu" and res["commit"]
    (row,) = res["rows"]
    assert row["resolution"] == "96x54" and row["decoded_sizes_ok"] is True
    assert row["frames"] > 0 and row["fps_delivered"] > 0
    assert row["latency_samples"] > 0 and 0 < row["latency_server_p50_ms"] <= row["latency_server_p95_ms"]
    # every gaze message waits at least as long as the rendered ones (it includes those replaced before a frame)
    assert 0 < row["latency_msg_p50_ms"] <= row["latency_msg_p95_ms"]
    assert row["latency_msg_p95_ms"] >= row["latency_server_p50_ms"]
    assert row["encoder"] in ("simplejpeg", "pillow") and res["load_average"] is not None
    assert (tmp_path / "viewer-cpu.md").is_file()


def test_cpu_benchmark_quick(tmp_path):
    """benchmarks/cpu.py at 96x54 on the CPU with 1 and 2 threads: scaling rows, foveated vs reference rows,
    the primary-ray comparison (Embree part only when embreex is installed) and the plot's inputs."""
    _run([str(REPO / "benchmarks" / "cpu.py"), "--quick", "--device", "cpu", "--scenes", "cornell", "--threads",
          "1,2", "--oversplit", "2", "--frames", "2"], tmp_path)
    res = json.loads((tmp_path / "cpu-cpu.json").read_text())
    assert res["benchmark"] == "cpu" and res["resolution"] == "96x54" and res["commit"]
    assert [r["threads"] for r in res["scaling"]] == [1, 2]
    assert res["scaling"][0]["foveated_speedup"] == 1.0
    assert all(r["foveated_ms"] > 0 and r["reference_ms"] > 0 for r in res["scaling"])
    assert [(r["scene"], r["shading"]) for r in res["foveated_vs_reference"]] == [("cornell", "default"),
                                                                               ("cornell", "ao_samples=8")]
    # the default-policy loop ("auto"): timed after its measurement, with the path it chose and its estimates
    for r in res["foveated_vs_reference"]:
        assert r["auto_path"] in ("foveated", "full") and r["auto_ms"] > 0
        assert set(r["auto_estimates_ms"]) == {"foveated_ms", "full_ms"}
        assert r["reference_over_auto"] == r["reference_ms"] / r["auto_ms"]
    (rays,) = res["primary_rays"]
    assert rays["rays"] == 96 * 54 and 0 < rays["hit_fraction"] < 1
    if "embree_1t_mrays_s" in rays:
        assert rays["same_hit_miss"] > 0.99 and rays["same_face"] > 0.95
    else:
        assert "not installed" in rays["embree"]
    assert [r["oversplit"] for r in res["oversplit_sweep"]] == [2]


def test_policy_cost_quick(tmp_path):
    """benchmarks/policy_cost.py: render(policy="full") and, with --auto, render with the default policy against
    render_reference, frame by frame (no speed assertion); the loops draw the same image, so all are timed on the
    same work."""
    _run([str(REPO / "benchmarks" / "policy_cost.py"), "--quick", "--device", "cpu", "--scenes", "cornell",
          "--shadings", "default", "--auto"], tmp_path)
    res = json.loads((tmp_path / "policy-cost-cpu.json").read_text())
    assert res["benchmark"] == "policy-cost" and res["commit"]
    (row,) = res["rows"]
    assert (row["scene"], row["shading"], row["width"], row["height"], row["frames"]) == ("cornell", "default", 96,
                                                                                          54, 6)
    assert row["reference_ms"] > 0 and row["render_full_ms"] > 0
    assert row["ratio"] == row["render_full_ms"] / row["reference_ms"]
    assert row["auto_ms"] > 0 and row["auto_path"] in ("full", "foveated")
    assert row["auto_ratio"] == row["auto_ms"] / row["reference_ms"]


def test_cpu_dispatch_quick(tmp_path):
    """benchmarks/cpu_dispatch.py: per-launch dispatch cost at 1 and 2 threads (no speed assertion)."""
    _run([str(REPO / "benchmarks" / "cpu_dispatch.py"), "--quick", "--threads", "1,2"], tmp_path)
    res = json.loads((tmp_path / "cpu-dispatch-cpu.json").read_text())
    assert res["benchmark"] == "cpu-dispatch" and res["commit"]
    assert [r["threads"] for r in res["rows"]] == [1, 1, 2, 2]  # the native team's row, then the Python team's
    assert all(0 < r["launch_us_median"] <= r["launch_us_p90"] for r in res["rows"])
    assert res["rows"][2]["bands"] > 1 and res["rows"][3]["team"] == "python"
    assert res["rows"][2]["team"] in ("native", "python")  # native where 2 threads fit the usable cores


def test_cpu_team_quick(tmp_path):
    """benchmarks/cpu_team.py: the native and the Python team on the same frame loops (no speed assertion)."""
    _run([str(REPO / "benchmarks" / "cpu_team.py"), "--quick", "--threads", "2", "--scenes", "cornell"], tmp_path)
    res = json.loads((tmp_path / "cpu-team-cpu.json").read_text())
    assert res["benchmark"] == "cpu-team" and res["commit"]
    assert [(r["scene"], r["shading"], r["threads"]) for r in res["records"]] == [("cornell", "default", 2),
                                                                                  ("cornell", "ao8", 2)]
    for r in res["records"]:
        for s in ("native", "python"):
            assert len(r["ms"][f"foveated_{s}"]) == len(r["ms"][f"full_{s}"]) == 2 * 2
            assert r[f"full_over_foveated_{s}"] == r[f"full_{s}_ms"] / r[f"foveated_{s}_ms"]


def test_default_loop_quick(tmp_path):
    """benchmarks/default_loop.py: the API example's loop (every FrameLoop default) against render_reference and
    the forced foveated frame (no speed assertion). The default loop is the cost policy with timing on; its
    timed frames follow the policy's 24 measurement frames, and a full-resolution frame equals the reference."""
    _run([str(REPO / "benchmarks" / "default_loop.py"), "--quick", "--device", "cpu", "--scenes", "cornell",
          "--shadings", "default"], tmp_path)
    res = json.loads((tmp_path / "default-loop-cpu.json").read_text())
    assert res["benchmark"] == "default-loop" and res["commit"]
    (row,) = res["rows"]
    assert (row["scene"], row["shading"], row["width"], row["height"], row["frames"]) == ("cornell", "default", 64,
                                                                                          36, 3)
    assert row["timing"] is True and row["policy"] == "auto"
    assert set(row["default_paths"]) <= {"full", "foveated"} and sum(row["default_paths"].values()) == 3
    assert row["policy_foveated_ms"] > 0 and row["policy_full_ms"] > 0
    assert all(len(v) == 3 and min(v) > 0 for v in row["frame_ms"].values())
    assert row["default_over_reference"] == row["default_ms"] / row["reference_ms"]
    paths, ps = row["default_path_series"], row["default_psnr_series"]
    assert len(paths) == len(ps) == len(row["foveated_psnr_series"]) == 3
    for path, db in zip(paths, ps):  # a full-resolution frame is the reference's image, exactly
        assert db == float("inf") if path == "full" else db > 20.0


def test_switch_history_quick(tmp_path):
    """benchmarks/switch_history.py: full frames, then foveated ones with the seeded history and after a cut; the
    seeded loop takes its history from the full frame exactly once (at the switch)."""
    _run([str(REPO / "benchmarks" / "switch_history.py"), "--quick", "--device", "cpu", "--scenes", "cornell",
          "--shadings", "default"], tmp_path)
    res = json.loads((tmp_path / "switch-history-cpu.json").read_text())
    assert res["benchmark"] == "switch-history" and res["commit"]
    (row,) = res["rows"]
    assert (row["scene"], row["width"], row["height"], row["before"], row["after"]) == ("cornell", 64, 36, 2, 3)
    assert row["seeded_first_frame"] and not row["seeded_later_frames"]
    for k in ("seeded", "cut"):
        assert len(row[f"{k}_psnr_series"]) == 3 and row[f"{k}_first_psnr"] == row[f"{k}_psnr_series"][0]
        assert row[f"{k}_psnr"]["min"] == min(row[f"{k}_psnr_series"])


def test_ncu_frame_parts(tmp_path):
    """benchmarks/ncu_frame.py: its driver renders the bracketed frames (the CPU runs it without the profiler),
    the report's kernels are cut into frames at the markers, Warp's entry names are shortened, and the floor is
    the DRAM bytes over the copy bandwidth. Without a CUDA device the benchmark refuses to start."""
    sys.path.insert(0, str(REPO))
    from benchmarks import ncu_frame

    out = subprocess.run([sys.executable, str(REPO / "benchmarks" / "ncu_frame.py"), "--drive", "--device", "cpu",
                          "--scenes", "cornell", "--sizes", "40x24", "--shadings", "default", "--warmup-frames", "2"],
                         capture_output=True, text=True, check=True).stdout
    assert "CONFIG cornell 40 24 default" in out
    rate = float(out.split("RATE ")[1].split()[0])
    assert 0.0 < rate <= 1.0
    bad = subprocess.run([sys.executable, str(REPO / "benchmarks" / "ncu_frame.py"), "--device", "cpu"],
                         capture_output=True, text=True)
    assert bad.returncode != 0 and "--device must be a CUDA device" in bad.stderr
    assert ncu_frame.kernel_name("sibson_gather_kernel_ce134398_cuda_kernel_forward") == "sibson_gather_kernel"
    assert ncu_frame.kernel_name("void foo(int)") == "void foo"
    metrics = {m: 0.0 for m in ncu_frame.METRICS}
    ks = [{"kernel": n, **metrics} for n in ("ncu_foveated_marker_kernel", "a", "b", "ncu_reference_marker_kernel",
                                              "c", "ncu_foveated_marker_kernel", "d", "ncu_reference_marker_kernel")]
    frames = ncu_frame._split(ks)
    assert [([k["kernel"] for k in f], [k["kernel"] for k in r]) for f, r in frames] == [(["a", "b"], ["c"]),
                                                                                        (["d"], [])]
    k = {"kernel": "x", **metrics, "gpu__time_duration.sum": 2.0e5, "dram__bytes_read.sum": 3.0e8,
         "dram__bytes_write.sum": 1.0e8}
    row = ncu_frame.kernel_row(k, 2.0e12, 1000)
    assert row["ms"] == pytest.approx(0.2, rel=1e-12) and row["floor_ms"] == pytest.approx(0.2, rel=1e-12)
    assert row["x_floor"] == pytest.approx(1.0, rel=1e-12) and row["bytes_per_pixel"] == 4.0e5
    tot = ncu_frame.summarize([row, row])
    assert tot["gpu_ms"] == pytest.approx(0.4, rel=1e-12) and tot["dram_bytes"] == 8.0e8
    assert tot["floor_ms"] == pytest.approx(0.4, rel=1e-12) and tot["bytes_per_pixel"] == 8.0e5


def test_order_quick(tmp_path):
    """benchmarks/order.py: the G-buffer and full shading launches timed per block width (no speed assertion);
    a bad width is refused by name."""
    _run([str(REPO / "benchmarks" / "order.py"), "--quick", "--device", "cpu", "--scenes", "cornell", "--widths",
          "0,8", "--shadings", "default"], tmp_path)
    res = json.loads((tmp_path / "order-cpu.json").read_text())
    assert res["benchmark"] == "order" and res["commit"]
    assert [r["block"] for r in res["records"]] == ["row (H, W launch)", "8x4"]
    assert all(r["gbuffer_ms"] > 0 and r["shade_full_ms"] > 0 for r in res["records"])
    bad = subprocess.run([sys.executable, str(REPO / "benchmarks" / "order.py"), "--widths", "3"],
                         capture_output=True, text=True, cwd=REPO)
    assert bad.returncode != 0 and "--widths" in bad.stderr


def test_bvh_quick(tmp_path):
    """benchmarks/bvh.py: build and launch times per BVH choice (no speed assertion), the reference images of
    every choice compared with the first; a bad choice is refused by name."""
    _run([str(REPO / "benchmarks" / "bvh.py"), "--quick", "--device", "cpu", "--scenes", "cornell", "--configs",
          "auto,sah-2,cubql"], tmp_path)
    res = json.loads((tmp_path / "bvh-cpu.json").read_text())
    assert res["benchmark"] == "bvh" and res["commit"]
    rec = res["records"]
    assert [r["config"] for r in rec] == ["auto", "sah-2", "cubql"]
    assert [r["constructor"] for r in rec] == ["sah", "sah", "cubql"] and rec[1]["leaf_size"] == 2
    assert all(r["build_ms"] > 0 and r["gbuffer_ms"] > 0 and r["shade_ao8_ms"] > 0 for r in rec)
    assert all(isinstance(r["pixels_differ_from_first"], int) and r["pixels_differ_from_first"] >= 0 for r in rec)
    assert all(0.0 <= r["max_abs_diff_from_first"] <= 1.0 for r in rec)
    for bad_cfg in ("kd", "sah-0", "sah-x"):
        bad = subprocess.run([sys.executable, str(REPO / "benchmarks" / "bvh.py"), "--configs", bad_cfg],
                             capture_output=True, text=True, cwd=REPO)
        assert bad.returncode != 0 and "--configs" in bad.stderr


def test_frame_quick(tmp_path):
    """benchmarks/frame.py: quality in motion, the heavy shading's error against a converged frame (both the
    full-resolution and the foveated frame), and the interleaved timing (no speed assertion). The ao8 timing
    record carries the aoquality part's figures, the default one the default-shading quality run's; bad
    arguments are refused by name."""
    _run([str(REPO / "benchmarks" / "frame.py"), "--quick", "--device", "cpu", "--scenes", "cornell", "--parts",
          "quality,aoquality,timing", "--converged-ao", "32"], tmp_path)
    res = json.loads((tmp_path / "frame-cpu.json").read_text())
    assert res["benchmark"] == "frame" and res["commit"]
    kinds = [r["kind"] for r in res["records"]]
    assert kinds == ["quality", "ao_quality", "timing", "timing"]
    q, aq, td, ta = res["records"]
    n = res["frames"]
    assert n == 4 and (aq["width"], aq["height"], aq["ao_samples"], aq["converged_ao"]) == (96, 54, 8, 32)
    for k in ("psnr", "ssim", "fovea_psnr", "ref_psnr", "ref_ssim", "ref_fovea_psnr", "gain_db",
              "sampling_rate_series"):
        assert len(aq[k]) == n, k
    # 8 rays against 32: neither frame equals the converged one, both are close to it
    assert all(15.0 < v < 100.0 for v in aq["psnr"] + aq["ref_psnr"])
    assert all(0.0 < v <= 1.0 for v in aq["ssim"] + aq["ref_ssim"])
    assert aq["gain_db"] == pytest.approx([a - b for a, b in zip(aq["psnr"], aq["ref_psnr"])], abs=1e-12)
    assert aq["gain_db_min"] == min(aq["gain_db"])
    # brute force with fewer rays: its error series, and every full-resolution frame timed with the foveated one
    assert sorted(aq["sweep_psnr"]) == ["1", "2", "4"] and all(len(v) == n for v in aq["sweep_psnr"].values())
    assert all(15.0 < v < 100.0 for v in sum(aq["sweep_psnr"].values(), []))
    assert sorted(aq["sweep_ms"]) == ["1", "2", "4", "8"] and min(aq["sweep_ms"].values()) > 0 and aq["fov_ms"] > 0
    # more rays, closer to the converged frame (means over the path); the foveated loop traced a part of the pixels
    means = [sum(aq["sweep_psnr"][k]) / n for k in ("1", "2", "4")] + [sum(aq["ref_psnr"]) / n]
    assert means == sorted(means) and means[0] < means[-1] - 3.0, means
    assert all(0.0 < r < 1.0 for r in aq["sampling_rate_series"])
    assert (td["shading"], td["quality_shading"]) == ("default", "default")
    assert td["psnr"] == pytest.approx(min(100.0, sum(min(v, 100.0) for v in q["psnr"]) / n))
    assert "ref_psnr" not in td
    assert ta["shading"] == "ao8" and ta["quality_shading"] == "ao8 against 32 AO rays"
    assert ta["psnr"] == pytest.approx(sum(aq["psnr"]) / n) and ta["ref_psnr"] == pytest.approx(sum(aq["ref_psnr"]) / n)
    assert all(r["ref_ms"] > 0 and r["fov_ms"] > 0 for r in (td, ta))
    md = (tmp_path / "frame-cpu.md").read_text()
    assert "| ref_psnr |" in md and "| speedup |" in md
    for bad_args, name in ((["--parts", "quality,bogus"], "--parts"), (["--ao-samples", "0"], "--ao-samples"),
                           (["--converged-ao", "8"], "--converged-ao"), (["--ao-sweep", "2,x"], "--ao-sweep"),
                           (["--ao-sweep", "0"], "--ao-sweep"), (["--turns", "blocks,rounds"], "--turns"),
                           (["--turns", "blocks,blocks"], "--turns")):
        bad = subprocess.run([sys.executable, str(REPO / "benchmarks" / "frame.py"), "--quick", "--device", "cpu",
                              "--scenes", "cornell", "--out", str(tmp_path / "bad"), *bad_args],
                             capture_output=True, text=True, cwd=REPO, timeout=120)
        assert bad.returncode != 0 and name in bad.stderr, bad.stderr


def test_frame_timing_turns():
    """benchmarks/frame.py's two timing schedules, with stand-in loops that log what they render: with turns by
    frames every loop renders each frame once, the loops in a new order every frame; with turns by blocks each
    loop renders runs of BLOCK_FRAMES consecutive frames, every loop the same runs, so its own frames follow one
    another, and the rounds give each loop at least n timed frames; each loop's frames are its warm-up then
    consecutive path frames in both; a bad skip is refused by name."""
    sys.path.insert(0, str(REPO))
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
            assert all(sorted(k for k, _ in p) == ["a", "b"] and p[0][1] == p[1][1] == 5 + i for i, p in enumerate(pairs))
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


def test_list_shading_quick(tmp_path):
    """benchmarks/list_shading.py: the list study (thinned, uniform and all-surface lists next to the foveated one)
    and the register-cap study (every variant's output checked equal to the uncapped kernel's, in the script)."""
    _run([str(REPO / "benchmarks" / "list_shading.py"), "--quick", "--device", "cpu", "--scenes", "cornell"],
         tmp_path)
    res = json.loads((tmp_path / "list-shading-cpu.json").read_text())
    assert res["benchmark"] == "list-shading" and res["commit"]
    kinds = [r["kind"] for r in res["records"]]
    assert kinds == ["lists", "caps", "caps"]
    lists, ao, default = res["records"]
    assert 0 < lists["n_list"] < lists["n_px"] and lists["n_hit"] <= lists["n_px"] and lists["lanes"] == 4
    assert lists["split"] is False  # the CPU's default: no list split
    assert all(lists[k] > 0 for k in ("fov_list_ms", "fov_every2_ms", "fov_every4_ms", "uniform_list_ms",
                                      "gaze_dense_list_ms", "fov_shuffled_ms", "all_hits_list_ms", "full_ms"))
    assert lists["fov_pixel_share"] == lists["n_list"] / lists["n_hit"]
    assert lists["fov_time_share"] == lists["fov_list_ms"] / lists["all_hits_list_ms"]
    # the gaze-packed list: as many pixels as the foveated list (all surface pixels), the nearest to the gaze, so it
    # reaches no farther from the gaze than the foveated list does
    assert lists["gaze_dense_n"] == lists["n_list"]
    assert 0 < lists["gaze_dense_max_px"] <= lists["fov_max_px"]
    assert (ao["shading"], default["shading"]) == ("ao8", "default")
    assert sum(k.startswith("shade_ao_list_kernel_") for k in ao) == 4
    assert not any(k.startswith("shade_ao_list_kernel_") for k in default)
    assert sum(k.startswith("shade_full_tiles_kernel_") for k in default) == 4
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "list_shading.py"), "--quick", "--device", "cpu",
                        "--parts", "bogus"], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert r.returncode != 0 and "--parts items must be in [lists, caps], got 'bogus'" in r.stderr
    # the split forced on: the lists part runs the light sources' pass, the AO pass and the completing pass
    _run([str(REPO / "benchmarks" / "list_shading.py"), "--quick", "--device", "cpu", "--scenes", "cornell",
          "--parts", "lists", "--split", "on", "--name", "split-on"], tmp_path)
    on = json.loads((tmp_path / "split-on-cpu.json").read_text())["records"][0]
    assert on["split"] is True and on["n_list"] == lists["n_list"] and on["fov_list_ms"] > 0


def test_policy_sim_quick(tmp_path):
    """benchmarks/policy_sim.py drives the policy's state machine with synthetic frame times (no rendering): it
    runs, writes its JSON / markdown, and reports sane figures."""
    _run([str(REPO / "benchmarks" / "policy_sim.py"), "--quick", "--cases", "0.9:0.03:0.01,1.3:0.02:0"], tmp_path)
    res = json.loads((tmp_path / "policy-sim-cpu.json").read_text())
    assert res["benchmark"] == "policy-sim" and res["commit"] and (tmp_path / "policy-sim-cpu.md").is_file()
    a, b = res["rows"]
    assert (a["fov_cost"], a["sigma"], a["episode"]) == (0.9, 0.03, 0.01)
    for r in (a, b):
        assert 0.0 <= r["dearer_pct"] <= 100.0 and r["rechecks"] >= 0
        assert min(r["fov_cost"], 1.0) <= r["mean_cost"] <= max(r["fov_cost"], 1.0)
    # foveation 30% dearer with little noise: the policy settles on full resolution after its measurement
    assert b["dearer_pct"] < 5.0


@pytest.mark.parametrize("case", ["abc", "0.9:0.1", "0:0.1:0", "0.9:-1:0", "0.9:0.1:2"])
def test_policy_sim_refuses_bad_cases(tmp_path, case):
    """A malformed or out-of-range --cases entry: an argparse error naming --cases and the entry."""
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "policy_sim.py"), "--quick", "--cases", case,
                        "--out", str(tmp_path)], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert r.returncode == 2 and "--cases" in r.stderr and repr(case) in r.stderr


def _kernel_ab_payload():
    """Two versions, two rounds, one case: kernel times chosen so that the means are known by hand."""
    def rec(resolve, other, fov_extra, ref):
        k = {"forward kernel resolve_kernel_aaaa": resolve, "forward kernel gbuffer_tiles_kernel_bbbb": other}
        return {"scene": "bunny", "width": 64, "height": 36, "foveated_kernels_ms": k,
                "reference_kernels_ms": {"forward kernel x": ref}, "foveated_gpu_ms": resolve + other + fov_extra,
                "reference_gpu_ms": ref}
    runs = [{"code": "old", "round": 1, "shading": "default", "records": [rec(0.30, 0.5, 0.2, 2.0)]},
            {"code": "old", "round": 2, "shading": "default", "records": [rec(0.34, 0.5, 0.2, 2.2)]},
            {"code": "new", "round": 1, "shading": "default", "records": [rec(0.20, 0.5, 0.2, 2.0)]},
            {"code": "new", "round": 2, "shading": "default", "records": [rec(0.22, 0.5, 0.2, 2.0)]}]
    return {"new_commit": "n", "old_commit": "o", "device_name": "test", "runs": runs}


def test_kernel_ab_summary(tmp_path, monkeypatch):
    """benchmarks/kernel_ab.py: the kernel means, their ratio, the sums' speed-ups, against hand-computed values,
    and the markdown next to the JSON; a file without runs is refused."""
    monkeypatch.syspath_prepend(str(REPO))
    from benchmarks.kernel_ab import main, summarise

    rows = summarise(_kernel_ab_payload(), "resolve")
    assert len(rows) == 1
    r = rows[0]
    assert (r["scene"], r["size"], r["shading"]) == ("bunny", "64x36", "default")
    assert r["old_kernel_ms"] == pytest.approx(0.32) and r["new_kernel_ms"] == pytest.approx(0.21)
    assert r["kernel_ratio"] == pytest.approx(0.21 / 0.32)
    assert r["old_kernel_spread_ms"] == pytest.approx(0.04) and r["new_kernel_spread_ms"] == pytest.approx(0.02)
    assert r["old_fov_ms"] == pytest.approx(1.02) and r["new_fov_ms"] == pytest.approx(0.91)
    assert r["old_speedup"] == pytest.approx(2.1 / 1.02) and r["new_speedup"] == pytest.approx(2.0 / 0.91)
    p = tmp_path / "ab.json"
    p.write_text(json.dumps(_kernel_ab_payload()))
    assert main([str(p)]) == 0
    md = (tmp_path / "ab.md").read_text()
    assert "| bunny | 64x36 | default | 0.3200 | 0.2100 | 0.656 |" in md
    (tmp_path / "empty.json").write_text(json.dumps({"new_commit": "n", "old_commit": "o", "runs": []}))
    with pytest.raises(SystemExit):
        main([str(tmp_path / "empty.json")])


def test_benchmarks_import_the_library_on_pythonpath_first(tmp_path):
    """A benchmark script run with another foveawarp on PYTHONPATH (an old version extracted for an A/B) must run
    that one: the scripts add the repository after PYTHONPATH, not before it (session 31's A/B ran the working tree
    on both sides). The stand-in library here refuses to import, with its own message."""
    fake = tmp_path / "lib" / "foveawarp"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text('raise ImportError("the foveawarp on PYTHONPATH was imported")\n')
    env = {**os.environ, "PYTHONPATH": str(tmp_path / "lib")}
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "cpu.py"), "--help"], capture_output=True,
                       text=True, cwd=tmp_path, env=env, timeout=300)
    assert r.returncode != 0 and "the foveawarp on PYTHONPATH was imported" in r.stderr, r.stderr[-2000:]
    # and without it, the repository's library is found (the script's own parent, appended)
    env.pop("PYTHONPATH")
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "cpu.py"), "--help"], capture_output=True,
                       text=True, cwd=tmp_path, env=env, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]


def _timing(scene, w, h, shading, ref, fov, auto):
    return {"kind": "timing", "scene": scene, "width": w, "height": h, "shading": shading, "ref_ms": ref,
            "fov_ms": fov, "auto_ms": auto}


def test_status_table_values(tmp_path, monkeypatch, capsys):
    """benchmarks/status.py: the speed-ups of each run, the default policy's worst ratio (default shading only),
    the quality columns, against hand-computed values; a scene without timing records is left out, a missing
    quality figure shows "-", and a file that is not a frame.py result is refused."""
    monkeypatch.syspath_prepend(str(REPO))
    from benchmarks.status import main

    run1 = [_timing("bunny", 64, 36, "default", 1.0, 1.25, 1.02), _timing("bunny", 64, 36, "ao8", 9.0, 3.0, 3.1),
            _timing("city", 64, 36, "default", 2.0, 2.5, 1.96)]
    run2 = [_timing("bunny", 64, 36, "default", 1.1, 1.0, 1.21), _timing("bunny", 64, 36, "ao8", 8.0, 4.0, 9.0)]
    quality = [{"kind": "quality", "scene": "bunny", "width": 64, "height": 36, "psnr": [40.0, 44.0, 45.0]},
               {"kind": "ao_quality", "scene": "bunny", "width": 64, "height": 36, "psnr": [30.0, 32.0],
                "ref_psnr": [35.0, 36.0]},
               {"kind": "quality", "scene": "bunny", "width": 128, "height": 72, "psnr": [1.0]}]
    files = []
    for i, recs in enumerate((run1, run2, quality)):
        f = tmp_path / f"r{i}.json"
        f.write_text(json.dumps({"records": recs}))
        files.append(str(f))
    out = tmp_path / "status.md"
    assert main(["--timing", files[0], files[1], "--quality", files[2], "--sizes", "64x36", "--quality-size", "64x36",
                 "--scenes", "teapot,bunny,city", "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0].startswith("| scene | 64x36 default | 64x36 8 AO rays | default policy / reference, worst |")
    # bunny: 1.0 / 1.25 = 0.80x and 1.1 / 1.0 = 1.10x; 9 / 3 = 3.00x and 8 / 4 = 2.00x; the policy's worst with
    # default shading max(1.02, 1.21 / 1.1 = 1.1) (the ao8 run's 9 / 8 is not counted); PSNR mean 43.0, min 40.0;
    # AO means 31.0 / 35.5
    assert lines[2] == "| bunny | 0.80x / 1.10x | 3.00x / 2.00x | 1.100 | 43.0 / 40.0 | 31.0 / 35.5 |"
    # city: in run 1 only, default shading only; no quality records; teapot: no timing at all, left out
    assert lines[3] == "| city | 0.80x / - | - / - | 0.980 | - | - |"
    assert len(lines) == 4
    assert capsys.readouterr().out.splitlines() == lines
    (tmp_path / "bad.json").write_text(json.dumps({"runs": []}))
    with pytest.raises(SystemExit):
        main(["--timing", str(tmp_path / "bad.json")])
    with pytest.raises(SystemExit, match="--quality-size must be WIDTHxHEIGHT, got '64by36'"):
        main(["--timing", files[0], "--quality-size", "64by36"])
    with pytest.raises(SystemExit, match="--sizes items must be positive WIDTHxHEIGHT, got '0x36'"):
        main(["--timing", files[0], "--sizes", "0x36"])
    with pytest.raises(SystemExit):  # no scene of --scenes in the runs
        main(["--timing", files[0], "--scenes", "teapot"])
    with pytest.raises(SystemExit):  # records without "turns" were timed frame by frame: none by blocks
        main(["--timing", files[0], "--turns", "blocks"])


def test_status_turns(tmp_path, monkeypatch, capsys):
    """benchmarks/status.py with runs that recorded both turn schedules: --turns picks the schedule of the status
    table; --compare-turns gives each run's speed-up by each, the ratio of their medians over the runs and the
    policy's worst ratio with each, against hand-computed values; a scene, size or shading missing a schedule in a
    run is left out, and runs without both schedules are refused."""
    monkeypatch.syspath_prepend(str(REPO))
    from benchmarks.status import main

    def t(shading, turns, ref, fov, auto):
        return {**_timing("bunny", 64, 36, shading, ref, fov, auto), "turns": turns}

    run1 = [t("default", "frames", 1.0, 1.25, 1.02), t("default", "blocks", 1.0, 1.0, 1.03),
            t("ao8", "frames", 9.0, 3.0, 3.0), t("ao8", "blocks", 9.0, 2.0, 2.0)]
    run2 = [t("default", "blocks", 1.2, 1.0, 1.2), t("default", "frames", 1.0, 2.0, 1.05),
            t("ao8", "frames", 8.0, 4.0, 4.0), {**_timing("city", 64, 36, "ao8", 1.0, 1.0, 1.0), "turns": "blocks"}]
    runs3 = run1 + [{**_timing("city", 64, 36, "ao8", 1.0, 1.0, 1.0), "turns": "frames"}]
    files = []
    for i, recs in enumerate((run1, run2, runs3)):
        f = tmp_path / f"t{i}.json"
        f.write_text(json.dumps({"records": recs}))
        files.append(str(f))
    base = ["--timing", files[0], files[1], "--sizes", "64x36", "--scenes", "bunny,city"]
    assert main(base + ["--turns", "blocks"]) == 0
    lines = capsys.readouterr().out.splitlines()
    # blocks: bunny 1.0 / 1.0 = 1.00x and 1.2 / 1.0 = 1.20x; ao8 9 / 2 = 4.50x, none in run 2; policy max(1.03, 1.0)
    assert lines[2] == "| bunny | 1.00x / 1.20x | 4.50x / - | 1.030 | - | - |"
    assert lines[3] == "| city | - / - | - / 1.00x | - | - | - |"
    assert main(base + ["--compare-turns"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("| scene | size | shading | speed-up, frame by frame (runs) | speed-up, blocks (runs) |")
    # default: frames 0.80x / 0.50x (median 0.65), blocks 1.00x / 1.20x (median 1.10): 1.10 / 0.65 = 1.692;
    # the policy's worst: frames max(1.02, 1.05), blocks max(1.03, 1.0); ao8 has no blocks record in run 2, city
    # no frames record anywhere: both left out
    assert lines[2:] == ["| bunny | 64x36 | default | 0.80x / 0.50x | 1.00x / 1.20x | 1.692 | 1.050; 1.030 |"]
    assert main(["--timing", files[0], files[2], "--sizes", "64x36", "--scenes", "bunny,city", "--compare-turns"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[3] == "| bunny | 64x36 | 8 AO rays | 3.00x / 3.00x | 4.50x / 4.50x | 1.500 | - |"
    with pytest.raises(SystemExit):  # no run with both schedules
        main(["--timing", files[1], "--sizes", "64x36", "--scenes", "city", "--compare-turns"])


def test_readme_status_table_matches_the_committed_json(monkeypatch, capsys):
    """Each of the README's status tables is what benchmarks/status.py makes of the JSON files its command names
    (committed results): a hand-edited or stale figure there fails this test."""
    import shlex

    monkeypatch.syspath_prepend(str(REPO))
    from benchmarks.status import main

    readme = (REPO / "README.md").read_text().splitlines()
    cmds = [ln for ln in readme if ln.startswith("python benchmarks/status.py ")]
    assert cmds
    for cmd in cmds:
        args = [str(REPO / a) if a.startswith("benchmarks/results/") else a for a in shlex.split(cmd)[2:]]
        assert main(args) == 0
        table = capsys.readouterr().out.splitlines()
        # the table printed right after the command's code block
        start = readme.index(table[0], readme.index(cmd))
        assert readme[start:start + len(table)] == table, cmd


def _cpu_timer():
    from benchmarks._common import launch_timer

    return launch_timer(wp.get_device("cpu"), 1, 1, 0)


def test_ao_segments_variants_trace_every_lane_once(monkeypatch):
    """benchmarks/ao_segments.py (session 35): on the CPU a thread fetches one lane at a time, so every persistent
    variant must give ``shade_ao_list_kernel``'s ao_part exactly (``study`` checks it on the foveated and the
    all-surface list of bunny, 8 AO rays, 4 lanes); a variant that leaves lanes untraced is caught."""
    import foveawarp as fw
    from benchmarks import ao_segments as A

    dev = wp.get_device("cpu")
    scene = fw.load_scene("bunny")
    res = A.study(fw, scene, 96, 64, dev, _cpu_timer(), 3)
    assert 0 < res["n_list"] < res["n_hit"] <= res["n_px"] == 96 * 64
    for lname in ("fov", "allhits"):
        for vname, *_ in A.VARIANTS:
            assert res[f"{lname}_{vname.replace(' ', '_')}_ms"] > 0

    @wp.kernel(enable_backward=False)
    def lazy(spa: wp.array(dtype=A.ShadeParams), work: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32),
             pos: wp.array2d(dtype=wp.vec3), normal: wp.array2d(dtype=wp.vec3), hit: wp.array2d(dtype=wp.uint8),
             area_lights: wp.array(dtype=A.AreaLightParams), ao_part: wp.array2d(dtype=wp.uint8),
             ctr: wp.array(dtype=wp.int32), nseg: int, smid: int):
        k = wp.tid()
        if k < count[0] * ao_part.shape[1] and k % 2 == 0:  # every other lane only
            A.ao_list_lane(spa[0], work, pos, normal, hit, area_lights, ao_part, k)

    monkeypatch.setattr(A, "ao_segments_kernel", lazy)
    with pytest.raises(AssertionError, match="changed ao_part"):
        A.study(fw, scene, 96, 64, dev, _cpu_timer(), 3)


def test_gbuffer_lean_equals_the_package_kernel_where_both_write():
    """benchmarks/gbuffer_lean.py (session 35): the G-buffer copy without the reprojection fields writes the same
    position, normal, depth, face and hit as ``gbuffer_tiles_kernel`` (``study`` checks it; bunny has smooth
    faces, cornell flat ones and misses)."""
    import foveawarp as fw
    from benchmarks import gbuffer_lean as G

    for name in ("bunny", "cornell"):
        res = G.study(fw, fw.load_scene(name), 96, 64, wp.get_device("cpu"), _cpu_timer(), 3)
        assert 0 < res["hit_fraction"] < 1 and res["package_ms"] > 0 and res["lean_ms"] > 0


def test_l2_cold_study_runs_on_cpu():
    """benchmarks/l2_cold.py (session 35): the conditions run (the prefetch is a no-op off CUDA) and give the
    same outputs (checked in ``study``); the line bound covers the mesh's traversal data."""
    import foveawarp as fw
    from benchmarks import l2_cold as L

    dev = wp.get_device("cpu")
    junk = wp.zeros(1 << 16, dtype=wp.float32, device=dev)
    scene = fw.load_scene("bunny")
    res = L.study(fw, scene, 96, 64, dev, _cpu_timer(), 3, lambda: junk.fill_(1.0))
    assert res["n_list"] > 0 and res["ao_list_warm_ms"] > 0 and res["full_warm_ms"] > 0
    nt, npt = len(scene.faces), len(scene.vertices)
    # BVH nodes (at most 2 per triangle, 2 x 16 bytes), primitive indices, triangle indices and points
    assert L.prefetch_lines(nt, npt) * 128 >= 2 * nt * 32 + nt * 4 + nt * 12 + npt * 12


def test_merge_history_equals_the_package_passes_on_cpu():
    """benchmarks/merge_history.py (session 36): the sampling pass merged with the resolve's history half, then the
    traced pixels' resolve over the list, write what the package's two passes write (checked in ``_compare``, for
    the deterministic and the stochastic boxed resolve); a changed output would raise there."""
    import foveawarp as fw
    from benchmarks import merge_history as M

    res = M.study(fw, fw.load_scene("bunny"), 96, 64, wp.get_device("cpu"), _cpu_timer(), 6, ["default", "ao8"],
                  [None])
    assert res["default"]["stochastic"] is False and res["ao8"]["stochastic"] is True
    for v in res.values():
        assert 0 < v["n_list"] < 96 * 64 and v["pkg_ms"] > 0 and v["merged_nocap_ms"] > 0


@wp.func
def _next_list_pixel(idx: int, width: int):
    """A wrong list lookup for the test below: the traced pixel's right neighbour (its own on the last column)."""
    y = idx // width
    return wp.min(idx - y * width + 1, width - 1), y


def test_merge_history_check_catches_a_wrong_merge(monkeypatch):
    """The study's equality check fails when the merged pair resolves the wrong pixels."""
    import foveawarp as fw
    from benchmarks import merge_history as M

    monkeypatch.setattr(M, "list_pixel", _next_list_pixel)
    monkeypatch.setattr(M, "_KERNELS", {})
    with pytest.raises(AssertionError, match="differs from the package's two passes"):
        M.study(fw, fw.load_scene("bunny"), 96, 64, wp.get_device("cpu"), _cpu_timer(), 6, ["default"], [None])


def test_merge_history_refuses_bad_options():
    for args, msg in ((["--caps", "12"], "--caps must be a comma list of 'none' or integers in [16, 255], got '12'"),
                      (["--caps", "x"], "--caps must be a comma list of 'none' or integers in [16, 255], got 'x'"),
                      (["--shadings", "ao9"], "--shadings must be a comma list of default, ao8, got 'ao9'")):
        r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "merge_history.py"), "--device", "cpu", *args],
                           capture_output=True, text=True, cwd=REPO, timeout=300)
        assert r.returncode == 2 and msg in r.stderr


def test_shadow_lanes_study_runs_on_cpu():
    """benchmarks/shadow_lanes.py (session 36): the lean shadow rays' visibility agrees with the package's list
    shading (checked in ``_compare``: equal with shadows on and off where every light is visible), on a scene with
    one light and one with three."""
    import foveawarp as fw
    from benchmarks import shadow_lanes as S

    for name, nl in (("bunny", 1), ("city", 3)):
        res = S.study(fw, fw.load_scene(name), 96, 64, wp.get_device("cpu"), _cpu_timer(), 6)
        for v in res.values():
            assert v["lights"] == nl and v["n_list"] > 0 and 0 < v["blocked_fraction"] < 1
            assert v["shade_ms"] > 0 and v["noshadow_ms"] > 0 and v["lanes_ms"] > 0


@wp.kernel(enable_backward=False)
def _all_visible_kernel(spa: wp.array(dtype=ShadeParams), work: wp.array(dtype=wp.int32),
                        count: wp.array(dtype=wp.int32), pos: wp.array2d(dtype=wp.vec3),
                        normal: wp.array2d(dtype=wp.vec3), hit: wp.array2d(dtype=wp.uint8),
                        lights: wp.array(dtype=LightParams), vis: wp.array2d(dtype=wp.uint8), row0: int):
    k = wp.tid() + row0
    if k < count[0] * vis.shape[1]:
        vis[k // vis.shape[1], k % vis.shape[1]] = wp.uint8(1)


def test_shadow_lanes_check_catches_wrong_visibility(monkeypatch):
    """The study's check fails when the lean kernel calls every light visible (bunny has shadowed pixels)."""
    import foveawarp as fw
    from benchmarks import shadow_lanes as S

    monkeypatch.setattr(S, "shadow_lanes_kernel", _all_visible_kernel)
    with pytest.raises(AssertionError, match="every light visible shades differently"):
        S.study(fw, fw.load_scene("bunny"), 96, 64, wp.get_device("cpu"), _cpu_timer(), 6)


@pytest.mark.parametrize("script", ["ao_segments.py", "l2_cold.py", "gbuffer_lean.py", "merge_history.py",
                                    "shadow_lanes.py"])
def test_cuda_studies_refuse_the_cpu(script):
    r = subprocess.run([sys.executable, str(REPO / "benchmarks" / script), "--device", "cpu"], capture_output=True,
                       text=True, cwd=REPO, timeout=300)
    assert r.returncode == 2 and "--device must be a CUDA device" in r.stderr


def test_policy_host_quick(tmp_path):
    """benchmarks/policy_host.py (session 35): the three loops' host and frame times and the profiles, on the CPU
    (where every launch is synchronous: the host time is the frame's)."""
    _run([str(REPO / "benchmarks" / "policy_host.py"), "--device", "cpu", "--specs", "cornell:48x32", "--frames", "3",
          "--profile"], tmp_path)
    res = json.loads((tmp_path / "policy-host-cpu.json").read_text())
    (r,) = res["records"]
    assert (r["scene"], r["width"], r["height"]) == ("cornell", 48, 32) and r["auto_path"] in ("full", "foveated")
    for n in ("reference", "full", "auto"):
        assert 0 < r[f"{n}_host_us"] <= r[f"{n}_frame_us"] and "render" in r[f"{n}_profile"]
    for bad in ("cornell", "cornell:64", "cornell:64x0", ":64x48"):
        r = subprocess.run([sys.executable, str(REPO / "benchmarks" / "policy_host.py"), "--device", "cpu", "--specs",
                            bad], capture_output=True, text=True, cwd=REPO, timeout=300)
        assert r.returncode == 2 and f"--specs items must be SCENE:WIDTHxHEIGHT (e.g. cornell:1920x1080), got {bad!r}" \
            in r.stderr


def test_study_alternating_takes_turns_and_keeps_the_median():
    """benchmarks/_study.alternating: the callables are timed in turn, round after round, and each median is over
    its own rounds."""
    from benchmarks._study import alternating

    calls = []
    times = iter([5.0, 1.0, 3.0, 2.0, 4.0, 9.0])

    def t_ms(fn):
        calls.append(fn())
        return next(times)

    out = alternating(t_ms, {"a": lambda: "a", "b": lambda: "b"}, rounds=3)
    assert calls == ["a", "b"] * 3
    assert [out[f"a_ms_{k}"] for k in range(3)] == [5.0, 3.0, 4.0] and out["a_ms"] == 4.0
    assert [out[f"b_ms_{k}"] for k in range(3)] == [1.0, 2.0, 9.0] and out["b_ms"] == 2.0
