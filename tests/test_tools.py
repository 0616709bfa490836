"""The maintainer tools of tools/, where a check is cheap on the CPU.

timeline.py: the split of a frame's wall time on the GPU's timeline, checked against an independent reference (a
dense time grid) on random work, on a hand-built frame, through the Chrome trace it reads, and end to end on the CPU
with a stand-in profiler (no GPU work: every frame is all lead). ncu_frame.py: its driver, the report's split at the
marker kernels and the floor arithmetic. Every tool: a docstring whose first paragraph says what it is for, and a
line in the README's tools list."""

import json
import re
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:
    sys.path.append(str(REPO))

from tools import ncu_frame  # noqa: E402
from tools import timeline as T  # noqa: E402

TOOLS = sorted(p for p in (REPO / "tools").iterdir() if p.suffix in (".py", ".sh"))

_iv = st.lists(st.tuples(st.integers(0, 400), st.integers(0, 60)), max_size=12)


def _grid_cover(intervals, scale=1):
    """Covered length by marking integer time cells: the independent reference of ``union_length``."""
    cells = np.zeros(600 * scale, bool)
    for s, d in intervals:
        cells[s * scale:(s + d) * scale] = True
    return cells.sum() / scale


@settings(max_examples=200, deadline=None)
@given(_iv)
def test_union_length_matches_a_time_grid(iv):
    assert T.union_length([(float(s), float(s + d)) for s, d in iv]) == pytest.approx(_grid_cover(iv))


@settings(max_examples=200, deadline=None)
@given(_iv, st.integers(0, 100), st.integers(450, 600))
def test_frame_anatomy_adds_up(iv, start, end):
    """lead + busy + gaps + tail is the wall time whenever the work ends inside the frame; busy and gaps match the
    grid over the work that starts inside it; nothing is negative."""
    ev = [{"ts": float(s), "dur": float(d), "kind": "kernel", "name": f"k{s % 3}"} for s, d in iv]
    a = T.frame_anatomy(ev, float(start), float(end))
    inside = [(s, d) for s, d in iv if start <= s <= end]
    assert a["n_kernels"] == len(inside)
    assert a["busy_us"] == pytest.approx(_grid_cover(inside))
    assert a["kernels_us"] == pytest.approx(sum(d for _, d in inside))
    assert min(a["lead_us"], a["busy_us"], a["gaps_us"], a["tail_us"]) >= 0
    if inside:
        first, last = min(s for s, _ in inside), max(s + d for s, d in inside)
        assert a["lead_us"] == first - start and a["gaps_us"] == pytest.approx(last - first - _grid_cover(inside))
        if last <= end:
            assert a["lead_us"] + a["busy_us"] + a["gaps_us"] + a["tail_us"] == pytest.approx(end - start)
    else:
        assert a["lead_us"] == end - start and a["busy_us"] == 0


def test_frame_anatomy_by_hand():
    """A frame from 0 to 100 µs: a copy at 10-12, kernels 20-50 and 45-60 (overlapping), a memset 70-72, work of
    another frame at 150."""
    ev = [{"ts": 10.0, "dur": 2.0, "kind": "copy", "name": "HtoD"},
          {"ts": 20.0, "dur": 30.0, "kind": "kernel", "name": "a"},
          {"ts": 45.0, "dur": 15.0, "kind": "kernel", "name": "b"},
          {"ts": 70.0, "dur": 2.0, "kind": "memset", "name": "Memset"},
          {"ts": 150.0, "dur": 5.0, "kind": "kernel", "name": "a"}]
    a = T.frame_anatomy(ev, 0.0, 100.0)
    assert (a["lead_us"], a["busy_us"], a["gaps_us"], a["tail_us"]) == (10.0, 44.0, 18.0, 28.0)
    assert (a["n_kernels"], a["n_memsets"], a["n_copies"], a["kernels_us"]) == (2, 1, 1, 45.0)
    assert a["per_kernel"] == {"a": 30.0, "b": 15.0}
    s = T.summarize([a, T.frame_anatomy(ev, 140.0, 160.0)])
    assert s["frames"] == 2 and s["per_kernel"] == {"a": pytest.approx(0.0175), "b": pytest.approx(0.015)}
    assert s["lead_us"] == 10.0 and s["n_kernels"] == 1.5


def test_trace_frames_reads_the_profilers_chrome_trace():
    trace = {"traceEvents": [
        {"ph": "X", "cat": "user_annotation", "name": "fw-frame:foveated:13", "ts": 200, "dur": 50},
        {"ph": "X", "cat": "user_annotation", "name": "fw-frame:reference:12", "ts": 100, "dur": 50},
        {"ph": "X", "cat": "user_annotation", "name": "something else", "ts": 0, "dur": 500},
        {"ph": "X", "cat": "kernel", "name": "k", "ts": 110.5, "dur": 20},
        {"ph": "X", "cat": "gpu_memset", "name": "Memset", "ts": 205, "dur": 1},
        {"ph": "X", "cat": "gpu_memcpy", "name": "Memcpy HtoD", "ts": 206, "dur": 1},
        {"ph": "X", "cat": "cuda_runtime", "name": "cudaLaunchKernel", "ts": 105, "dur": 3},
        {"ph": "i", "cat": "kernel", "name": "instant", "ts": 1}]}
    gpu, marks = T.trace_frames(trace)
    assert marks == [("reference", 12, 100.0, 150.0), ("foveated", 13, 200.0, 250.0)]
    assert [(e["kind"], e["ts"]) for e in gpu] == [("kernel", 110.5), ("memset", 205.0), ("copy", 206.0)]


class _StandInProfiler:
    """PyTorch's profiler as the study uses it, writing only the frame marks (a CPU run has no GPU work)."""

    class ProfilerActivity:
        CPU, CUDA = "cpu", "cuda"

    def __init__(self):
        self.events = []

    @contextmanager
    def record_function(self, name):
        t0 = len(self.events) * 1000.0
        yield
        self.events.append({"ph": "X", "cat": "user_annotation", "name": name, "ts": t0, "dur": 500.0})

    @contextmanager
    def profile(self, activities):
        outer = self

        class _P:
            def export_chrome_trace(self, path):
                Path(path).write_text(json.dumps({"traceEvents": outer.events}))

        yield _P()


def test_study_runs_on_cpu_with_a_stand_in_profiler():
    import foveawarp as fw

    prof = _StandInProfiler()
    res = T.study(fw, prof, fw.load_scene("cornell"), 48, 32, "default", wp.get_device("cpu"), 3, 2)
    assert 0 < res["sampling_rate"] <= 1
    for name in T.LOOPS:
        r = res[name]
        assert r["frames"] == 3 and r["plain_wall_ms"] > 0 and r["lead_us"] == 500.0 and r["n_kernels"] == 0
    assert sorted(e["name"].split(":")[1] for e in prof.events) == \
        ["auto"] * 3 + ["control"] * 3 + ["foveated"] * 3 + ["reference"] * 3
    assert set(res["auto_paths"]) <= {"full", "foveated"} and res["auto_paths"]


def test_timeline_refuses_the_cpu_and_bad_options():
    run = lambda *a: subprocess.run([sys.executable, str(REPO / "tools" / "timeline.py"), *a],  # noqa: E731
                                    capture_output=True, text=True, cwd=REPO, timeout=300)
    r = run("--device", "cpu")
    assert r.returncode == 2 and "--device must be a CUDA device (the study reads the CUDA timeline), got 'cpu'" \
        in r.stderr
    r = run("--device", "cpu", "--frames", "0")
    assert r.returncode == 2 and "--frames must be >= 1 and --warm >= 0, got 0 and 12" in r.stderr
    r = run("--device", "cpu", "--loops", "reference,reference")
    assert r.returncode == 2 and "--loops must be a comma list of distinct names of reference, foveated, auto, control, got " \
        "'reference,reference'" in r.stderr
    r = run("--device", "cpu", "--shadings", "ao9")
    assert r.returncode == 2 and "--shadings must be a comma list" in r.stderr
    r = run("--device", "cpu", "--target", "0")
    assert r.returncode == 2 and "--target must be a speed-up > 0, got 0.0" in r.stderr


def test_accounting_by_hand():
    """The split of a record into the speed-up, the cut a target needs and the foveated frame's kernel groups."""
    rec = {"scene": "bunny", "width": 3840, "height": 2160, "shading": "ao8",
           "reference": {"plain_wall_ms": 9.0, "wall_ms": 9.3, "busy_ms": 9.1, "per_kernel": {}},
           "foveated": {"plain_wall_ms": 3.2, "wall_ms": 3.4, "busy_ms": 3.1, "per_kernel": {
               "gbuffer_tiles_kernel_6f3c439d_cuda_kernel_forward": 0.6,
               "shade_ao_list_kernel_3f_cuda_kernel_forward": 1.0, "shade_list_kernel_fc_cuda_kernel_forward": 0.2,
               "sampling_map_kernel_38_cuda_kernel_forward": 0.3, "memset32": 0.01,
               "wp::bvh_refit_kernel(int, int const*)": 0.02, "void cub::DeviceScanKernel<float>(int)": 0.01,
               "rigid_motion_kernel_aa_cuda_kernel_forward": 0.005}}}
    a = T.accounting(rec, 3.0)
    assert a["target"] == 3.0 and a["speedup"] == pytest.approx(9.0 / 3.2)
    assert a["cut_needed_ms"] == pytest.approx(3.2 - 3.0)
    assert (a["fov_gbuffer_ms"], a["fov_shading_ms"]) == (0.6, pytest.approx(1.2))
    assert a["fov_passes_ms"] == pytest.approx(0.31) and a["fov_scene_ms"] == pytest.approx(0.035)
    assert a["fov_off_kernels_ms"] == pytest.approx(0.3) and a["ref_off_kernels_ms"] == pytest.approx(0.2)
    assert T.accounting(rec)["cut_needed_ms"] is None and T.accounting(rec, 2.0)["cut_needed_ms"] < 0


def test_from_json_tabulates_a_results_file(tmp_path):
    rec = {"scene": "spot", "width": 1920, "height": 1080, "shading": "default",
           "reference": {"plain_wall_ms": 0.5, "wall_ms": 0.6, "busy_ms": 0.4, "per_kernel": {}},
           "foveated": {"plain_wall_ms": 0.6, "wall_ms": 0.7, "busy_ms": 0.5, "per_kernel": {}}}
    f = tmp_path / "t.json"
    f.write_text(json.dumps({"records": [rec]}))
    r = subprocess.run([sys.executable, str(REPO / "tools" / "timeline.py"), "--from-json", str(f), "--target",
                        "1"], capture_output=True, text=True, cwd=REPO, timeout=300)
    assert r.returncode == 0, r.stderr
    head, _, row = r.stdout.strip().splitlines()
    assert "cut_needed_ms" in head
    assert row.startswith("| spot | 1920x1080 | default | 0.500 | 0.600 | 0.833 | 1.000 | 0.100")


def test_from_json_refuses_what_is_not_a_results_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"records": [{"scene": "spot"}]}))
    for path in (str(tmp_path / "missing.json"), str(bad)):
        r = subprocess.run([sys.executable, str(REPO / "tools" / "timeline.py"), "--from-json", path],
                           capture_output=True, text=True, cwd=REPO, timeout=300)
        assert r.returncode == 2 and "--from-json must be a results JSON of this script" in r.stderr
        assert repr(path) in r.stderr


def test_ncu_frame_parts():
    """tools/ncu_frame.py: its driver renders the bracketed frames (the CPU runs it without the profiler), the
    report's kernels are cut into frames at the markers, Warp's entry names are shortened, and the floor is the
    DRAM bytes over the copy bandwidth. Without a CUDA device the tool refuses to start."""
    script = str(REPO / "tools" / "ncu_frame.py")
    out = subprocess.run([sys.executable, script, "--drive", "--device", "cpu", "--scenes", "cornell", "--sizes",
                          "40x24", "--shadings", "default", "--warmup-frames", "2"],
                         capture_output=True, text=True, check=True, timeout=300).stdout
    assert "CONFIG cornell 40 24 default" in out
    rate = float(out.split("RATE ")[1].split()[0])
    assert 0.0 < rate <= 1.0
    bad = subprocess.run([sys.executable, script, "--device", "cpu"], capture_output=True, text=True, timeout=300)
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


@pytest.mark.parametrize("tool", TOOLS, ids=lambda p: p.name)
def test_each_tool_has_a_docstring_and_a_readme_line(tool):
    """A Python tool opens with a docstring whose first paragraph (at least a sentence) says what it is for; a
    shell tool with a comment block; the README's tools list has a line naming the file."""
    text = tool.read_text()
    if tool.suffix == ".py":
        import ast

        doc = ast.get_docstring(ast.parse(text)) or ""
    else:
        doc = "\n".join(line.lstrip("# ") for line in text.splitlines()[1:] if line.startswith("#"))
    first = doc.split("\n\n")[0]
    assert len(first.split()) >= 8 and "." in doc, f"{tool.name}: no opening paragraph"
    readme = (REPO / "README.md").read_text()
    assert re.search(rf"^\s*(?:tools/)?{re.escape(tool.name)}\s{{2,}}\S", readme, flags=re.M), \
        f"README.md has no tools-list line for tools/{tool.name}"
