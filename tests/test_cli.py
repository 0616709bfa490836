"""The console script: demo smoke test at tiny size, render, warmup, and argument errors."""

import json

import pytest

from foveawarp.cli import main


def test_demo_smoke(tmp_path):
    out = tmp_path / "demo"
    rc = main(["demo", "--device", "cpu", "--width", "32", "--height", "24", "--frames", "2", "--out", str(out)])
    assert rc == 0
    assert (out / "frame_0000.png").is_file() and (out / "frame_0001.png").is_file()
    stats = json.loads((out / "stats.json").read_text())
    assert len(stats["frames"]) == 2 and stats["width"] == 32
    assert all("ms_frame" in f for f in stats["frames"])


def test_demo_path_tracing_is_one_flag(tmp_path):
    """demo --integrator path: the frames are path traced (stats count paths, not rays); render does it on a
    textured scene too."""
    out = tmp_path / "demo"
    rc = main(["demo", "--device", "cpu", "--width", "32", "--height", "24", "--frames", "2", "--out", str(out),
               "--integrator", "path"])
    assert rc == 0 and (out / "frame_0001.png").is_file()
    frames = json.loads((out / "stats.json").read_text())["frames"]
    assert all(f["paths_traced"] > 0 and "rays_traced" not in f for f in frames)
    rc = main(["render", "--scene", "room", "--device", "cpu", "--width", "24", "--height", "16", "--out",
               str(tmp_path / "r"), "--integrator", "path", "--frames", "1", "--no-panel"])
    assert rc == 0 and (tmp_path / "r" / "frame_0000.png").is_file()


def test_render_with_gaze(tmp_path):
    out = tmp_path / "r"
    rc = main(["render", "--scene", "earth", "--device", "cpu", "--width", "24", "--height", "16", "--frames",
               "1", "--gaze", "3,4", "--out", str(out), "--no-panel"])
    assert rc == 0 and (out / "frame_0000.png").is_file()


def test_render_bad_scene_is_a_clear_error(tmp_path, capsys):
    rc = main(["render", "--scene", "nope.obj", "--device", "cpu", "--out", str(tmp_path)])
    assert rc == 2
    assert "nope.obj" in capsys.readouterr().err


def test_bad_arguments():
    with pytest.raises(SystemExit):
        main(["render", "--width", "0"])
    with pytest.raises(SystemExit):
        main(["render", "--gaze", "nan,1"])


def test_warmup(capsys):
    assert main(["warmup", "--device", "cpu"]) == 0
    assert "kernel modules" in capsys.readouterr().out


def test_render_debug_and_dof_views(tmp_path):
    out = tmp_path / "dbg"
    rc = main(["render", "--scene", "cornell", "--device", "cpu", "--width", "40", "--height", "24", "--frames",
               "1", "--out", str(out), "--debug", "--dof"])
    assert rc == 0
    assert (out / "debug_0000.png").is_file()  # probability | saliency | binary map | cache hits
    assert (out / "dof_comparison.png").is_file()
    assert "thin_lens" in (out / "dof_comparison.txt").read_text()


def test_bench_help_lists_the_entry_points_that_exist(capsys):
    """`foveawarp bench --help` names every benchmarks/NAME.py entry point (private modules left out) and no
    other; the default, frame, is one of them."""
    from pathlib import Path

    from foveawarp.cli import build_parser

    with pytest.raises(SystemExit) as e:
        main(["bench", "--help"])
    assert e.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    listed = out.split("Entry points: ", 1)[1].split(" positional arguments", 1)[0]
    names = {n.strip() for n in listed.split(",")}
    on_disk = {f.stem for f in (Path(__file__).resolve().parent.parent / "benchmarks").glob("*.py")
               if not f.stem.startswith("_")}
    assert names == on_disk and "frame" in on_disk, (names, on_disk)
    assert build_parser().parse_args(["bench"]).name == "frame"


def test_bench_unknown_name_lists_the_entry_points(capsys):
    assert main(["bench", "quality", "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert "'quality' not found" in err and "frame" in err and "robustness" in err


def test_bench_runs_an_entry_point(tmp_path):
    """`foveawarp bench robustness --quick` runs benchmarks/robustness.py with the options given and returns its
    exit status: both parts pass and the JSON names the CPU device."""
    assert main(["bench", "robustness", "--device", "cpu", "--quick", "--out", str(tmp_path)]) == 0
    res = json.loads((tmp_path / "robustness-cpu.json").read_text())
    assert res["pass"] is True and res["device_alias"] == "cpu"
    assert [r["part"] for r in res["records"]] == ["soak", "parity"]
