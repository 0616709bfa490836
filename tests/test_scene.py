"""Scene loading (OBJ / PLY / GLB written to a temp dir), built-in scenes, and bad inputs."""

import numpy as np
import pytest
import trimesh

import foveawarp as fw


@pytest.mark.parametrize("ext", ["obj", "ply", "glb", "stl"])
def test_load_mesh_files(tmp_path, ext):
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    if ext in ("ply", "glb"):
        m.visual.face_colors = np.tile([200, 30, 30, 255], (len(m.faces), 1)).astype(np.uint8)
    p = tmp_path / f"ball.{ext}"
    m.export(p)
    s = fw.load_scene(str(p))
    assert s.num_triangles == len(m.faces) + 2  # + ground quad
    lo, hi = s.bounds
    assert abs(s.vertices[2:, 1].min() - 0.0) < 1e-5 or s.vertices[:, 1].min() >= -1e-5  # sits on the ground
    if ext in ("ply", "glb"):
        # face colours become albedo
        np.testing.assert_allclose(s.face_albedo[2:], np.tile(np.array([200, 30, 30]) / 255.0, (len(m.faces), 1)), atol=1e-3)
    loop = fw.FrameLoop(s, 32, 24, device="cpu")
    f = loop.render_reference()
    assert f.gbuffer.hit.numpy().any()


def test_builtin_scenes_deterministic_and_sized():
    a = fw.load_scene("cornell")
    b = fw.load_scene("cornell")
    np.testing.assert_array_equal(a.vertices, b.vertices)
    e = fw.load_scene("earth")
    assert e.num_triangles == 960
    ey = fw.load_scene("eyechart")
    assert ey.num_triangles > 1000
    for s in (a, e, ey):
        assert s.lights and s.camera is not None and s.camera_path is not None


def test_city_has_a_million_triangles():
    c = fw.load_scene("city")
    assert c.num_triangles >= 1_000_000
    c2 = fw.load_scene("city")
    np.testing.assert_array_equal(c.faces[:1000], c2.faces[:1000])


def test_missing_file():
    with pytest.raises(ValueError, match="neither a built-in name"):
        fw.load_scene("no/such/file.obj")


def test_non_mesh_file(tmp_path):
    p = tmp_path / "notes.obj"
    p.write_text("this is not a mesh\njust words\n")
    with pytest.raises(ValueError, match="no triangle mesh|could not be read"):
        fw.load_scene(str(p))
    q = tmp_path / "data.bin"
    q.write_bytes(b"\x00\x01\x02garbage")
    with pytest.raises(ValueError, match=r"data\.bin"):
        fw.load_scene(str(q))


def test_points_only_file(tmp_path):
    p = tmp_path / "pts.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(ValueError, match="no triangle mesh|could not be read"):
        fw.load_scene(str(p))


def test_bad_scene_arrays():
    with pytest.raises(ValueError, match="faces"):
        fw.Scene(vertices=np.zeros((3, 3)), faces=np.zeros((0, 3), int), face_albedo=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="faces"):
        fw.Scene(vertices=np.zeros((4, 3)), faces=np.zeros((2, 4), int), face_albedo=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="vertices"):
        fw.Scene(vertices=np.full((3, 3), np.nan), faces=[[0, 1, 2]], face_albedo=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="indices"):
        fw.Scene(vertices=np.zeros((3, 3)), faces=[[0, 1, 5]], face_albedo=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="face_albedo"):
        fw.Scene(vertices=np.eye(3), faces=[[0, 1, 2]], face_albedo=(2.0, 0.5, 0.5))


@pytest.mark.parametrize("w,h", [(0, 10), (10, 0), (-3, 5), (10.5, 5)])
def test_zero_size_image(w, h):
    with pytest.raises(ValueError, match="width|height"):
        fw.FrameLoop("cornell", w, h, device="cpu")


def test_bad_device():
    with pytest.raises(ValueError, match="device"):
        fw.FrameLoop("cornell", 8, 8, device="tpu:7")


def test_bad_config_fields():
    with pytest.raises(ValueError, match="FoveationConfig.block"):
        fw.FoveationConfig(block=0)
    with pytest.raises(ValueError, match="ReorderConfig.strategy"):
        fw.ReorderConfig(strategy="sorted")
    with pytest.raises(ValueError, match="ShadingConfig.exposure"):
        fw.ShadingConfig(exposure=float("nan"))
    with pytest.raises(ValueError, match="IndirectConfig.rsm_size"):
        fw.IndirectConfig(rsm_size=100)
    with pytest.raises(ValueError, match="DofConfig.focus_depth_m"):
        fw.DofConfig(focal_length_m=0.05, focus_depth_m=0.05)
    with pytest.raises(ValueError, match="config"):
        fw.FrameLoop("cornell", 8, 8, config={"block": 4}, device="cpu")
    cfg = fw.Config().with_(foveation={"block": 8})
    assert cfg.foveation.block == 8 and cfg.foveation.effective_min_probability >= 1 / 64
