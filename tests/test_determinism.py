"""Determinism: two fresh FrameLoops on one device give bit-identical outputs for the same scene, seed and sequence;
and the parity part of benchmarks/robustness.py agrees with itself (--save then --compare on one device: every
array equal, exit 0)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import warp as wp

import foveawarp as fw

W, H = 64, 48
REPO = Path(__file__).resolve().parent.parent

VARIANTS = {
    # AO rays: the per-pixel random streams are used; the short block slides (BVH refit, velocity saliency)
    "ao+motion": ({"motion": True}, {"shading": {"ao_samples": 2}}),
    # area-light samples (random too), light-quad-tree indirect and the depth-of-field gather
    "area+indirect+dof": ({"motion": True, "area_light": True},
                          {"shading": {"ao_samples": 1, "indirect": "lighttree"},
                           "indirect": {"rsm_size": 32, "limit_level": 4},
                           "dof": {"aperture_m": 0.02, "focal_length_m": 0.05, "px_per_m": 20000.0}}),
}


def _copy(a):
    return np.array(a.numpy(), copy=True)  # CPU arrays: .numpy() is a view the next frame overwrites


def _render(device, scene_kw, over, frames=4):
    scene = fw.load_scene("cornell", **scene_kw)
    loop = fw.FrameLoop(scene, W, H, config=fw.Config().with_(**over), device=device, timing=False, policy="foveated")
    out = {}
    gazes = [(20.0, 24.0), (26.0, 22.0), (-40.0, 24.0), (40.0, 30.0)]
    for i in range(frames):
        t = 0.1 * i
        f = loop.render(scene.camera_at(t), gaze_px=gazes[i % len(gazes)], time=t, cut=(i == 3))
        out[f"image{i}"] = _copy(f.image)
        out[f"sample_map{i}"] = _copy(f.sampling_map)
        for k, v in f.extras.items():
            out[f"{k}{i}"] = _copy(v)
        for k in ("sampling_rate", "cache_hit_rate", "rays_traced"):
            out[f"{k}{i}"] = np.asarray(f.stats[k])
    for k, v in f.gbuffer.numpy().items():
        out[f"gbuffer.{k}"] = v.copy()
    for k in ("probability", "saliency", "sample_map", "cache_hit", "prev_index", "num_samples", "num_cache_hits"):
        out[f"sampling.{k}"] = _copy(getattr(loop.sampling, k))
    out["radiance"] = _copy(loop.radiance)
    out["reference"] = _copy(loop.render_reference(scene.camera_at(0.1 * (frames - 1)), time=0.1 * (frames - 1)).image)
    return out


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_two_fresh_frame_loops_are_bit_identical(device, variant):
    scene_kw, over = VARIANTS[variant]
    a = _render(device, scene_kw, over)
    b = _render(device, scene_kw, over)
    assert sorted(a) == sorted(b)
    differ = [k for k in a if a[k].dtype != b[k].dtype or a[k].tobytes() != b[k].tobytes()]
    assert not differ, f"not bit-identical on {device}: {differ}"
    # the sequence did exercise what it claims: finite images, a partial sampling map, AO / random streams on
    for i in range(4):
        assert np.all(np.isfinite(a[f"image{i}"]))
    assert 0.0 < float(a["sampling_rate3"]) < 1.0


def test_parity_script_self_parity(device, tmp_path):
    """robustness.py --parts parity --save then --compare on the same device: every array bit-identical, exit
    status 0."""
    npz = tmp_path / "parity.npz"
    script = str(REPO / "benchmarks" / "robustness.py")
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    r1 = subprocess.run([sys.executable, script, "--parts", "parity", "--quick", "--device", device, "--save",
                         str(npz), "--out", str(tmp_path)], capture_output=True, text=True, cwd=REPO, env=env,
                        timeout=600)
    assert r1.returncode == 0, r1.stdout[-3000:] + r1.stderr[-3000:]
    assert npz.is_file()
    r2 = subprocess.run([sys.executable, script, "--parts", "parity", "--device", device, "--compare", str(npz),
                         "--out", str(tmp_path)], capture_output=True, text=True, cwd=REPO, env=env, timeout=600)
    assert r2.returncode == 0, r2.stdout[-3000:] + r2.stderr[-3000:]
    tag = "cuda" if wp.get_device(device).is_cuda else "cpu"
    (res,) = json.loads((tmp_path / f"robustness-{tag}.json").read_text())["records"]
    assert res["mode"] == "compare" and res["pass"] is True
    assert res["determinism"]["bit_identical"] is True
    assert res["all_bit_identical_to_saved"] is True
    assert all(c["pass"] for c in res["checks"])
    assert res["arrays"]["sampling.sample_map"]["equal_fraction"] == 1.0
    assert (tmp_path / f"robustness-{tag}.md").is_file()
