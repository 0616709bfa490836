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
