"""Scenes from files and from a clean clone: load_scene reads every supported format through one call, the
procedural textured room is deterministic, the named textured scenes load (the shipped ones without the shared
scenes folder), and the command line and the viewer offer them."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import trimesh

import foveawarp as fw
from foveawarp import meshio
from foveawarp.cli import _check_scene_sources, default_view_scenes, main

_MTL = "newmtl red\nKd 0.9 0.1 0.1\n"
_OBJ = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nusemtl red\nf 1 2 3 4\n"
_XML = ('<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="50"/>'
        '<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>'
        '<shape type="sphere"><bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.7, 0.3"/></bsdf></shape>'
        '<emitter type="point"><point name="position" x="2" y="3" z="4"/><float name="intensity" value="30"/>'
        '</emitter></scene>')


def _files(tmp_path) -> dict:
    ball = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    out = {}
    for ext in ("glb", "gltf", "ply", "stl"):
        p = tmp_path / f"ball.{ext}"
        ball.export(p)
        out[ext] = p
    (tmp_path / "m.mtl").write_text(_MTL)
    (tmp_path / "quad.obj").write_text(_OBJ)
    (tmp_path / "bare.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "scene.xml").write_text(_XML)
    out.update({"obj": tmp_path / "quad.obj", "bare-obj": tmp_path / "bare.obj", "xml": tmp_path / "scene.xml"})
    return out


def _load(p, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fw.load_scene(str(p), **kw)


def test_load_scene_reads_every_format_through_one_call(tmp_path):
    files = _files(tmp_path)
    ball_tris = len(trimesh.creation.icosphere(subdivisions=1).faces)
    for kind in ("glb", "gltf", "obj", "xml"):  # scene files: their own content, materials, no ground
        s = _load(files[kind])
        assert meshio.scene_file_kind(files[kind]) == "scene", kind
        assert s.materials is not None and s.lights and s.camera is not None, kind
        assert s.num_triangles == {"glb": ball_tris, "gltf": ball_tris, "obj": 2}.get(kind, s.num_triangles)
    np.testing.assert_allclose(_load(files["obj"]).face_albedo, [[0.9, 0.1, 0.1]] * 2, atol=1 / 255)
    xml = _load(files["xml"])
    np.testing.assert_allclose(xml.camera.eye, (0, 0, 5)) and np.testing.assert_allclose(
        xml.face_albedo.mean(axis=0), (0.2, 0.7, 0.3), atol=1e-6)
    for kind in ("ply", "stl", "bare-obj"):  # meshes: placed on a ground quad
        s = _load(files[kind])
        assert meshio.scene_file_kind(files[kind]) == "mesh" and s.materials is None
        assert s.num_triangles == (ball_tris if kind != "bare-obj" else 1) + 2, kind
    # each renders
    for kind in ("glb", "obj", "xml", "ply"):
        f = fw.FrameLoop(_load(files[kind]), 24, 16, device="cpu").render_reference()
        assert f.gbuffer.hit.numpy().any() and np.isfinite(f.numpy()).all(), kind


def test_unknown_extensions_and_missing_files_are_named(tmp_path):
    p = tmp_path / "thing.fbx"
    p.write_bytes(b"Kaydara FBX Binary")
    with pytest.raises(ValueError, match=r"thing\.fbx.*'\.fbx'.*\.gltf.*\.xml"):
        fw.load_scene(str(p))
    with pytest.raises(ValueError, match="nor an existing file"):
        fw.load_scene(str(tmp_path / "absent.glb"))
    bad = tmp_path / "bad.glb"
    bad.write_bytes(b"glTF" + b"\x00" * 4)
    with pytest.raises(ValueError, match=r"bad\.glb"):
        fw.load_scene(str(bad))


def test_scene_file_lights_and_cameras(tmp_path):
    # a glTF without lights gets the default lights, with a warning naming the file
    ball = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    p = tmp_path / "plain.glb"
    ball.export(p)
    with pytest.warns(UserWarning, match=r"plain\.glb.*default lights"):
        s = fw.load_scene(str(p))
    assert len(s.lights) == 2
    # a Mitsuba scene lit only by an emitting surface or an environment gets none
    (tmp_path / "glow.xml").write_text('<scene version="3.0.0"><shape type="rectangle"><emitter type="area">'
                                       '<rgb name="radiance" value="5, 5, 5"/></emitter></shape>'
                                       '<shape type="cube"/></scene>')
    s = _load(tmp_path / "glow.xml")
    assert s.lights == [] and s.face_emission.max() == pytest.approx(5.0)
    (tmp_path / "sky.xml").write_text('<scene version="3.0.0"><shape type="cube"/><emitter type="constant">'
                                      '<rgb name="radiance" value="1, 1, 1"/></emitter></scene>')
    assert _load(tmp_path / "sky.xml").lights == []
    # camera_index picks the file's camera; one that does not exist is named
    (tmp_path / "two.xml").write_text('<scene version="3.0.0"><shape type="cube"/>' + "".join(
        f'<sensor type="perspective"><float name="fov" value="40"/><transform name="to_world"><lookat '
        f'origin="{x}, 0, 6" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>' for x in (0, 3)) + '</scene>')
    np.testing.assert_allclose(_load(tmp_path / "two.xml", camera_index=1).camera.eye, (3, 0, 6))
    with pytest.raises(ValueError, match=r"camera_index must be an integer in \[0, 1\]"):
        _load(tmp_path / "two.xml", camera_index=2)


def test_room_is_textured_and_deterministic():
    a, b = fw.load_scene("room"), fw.load_scene("room")
    for k in ("vertices", "faces", "uvs", "tangents", "face_material", "face_albedo"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert len(a.images) == len(b.images) > 0
    for x, y in zip(a.images, b.images):
        np.testing.assert_array_equal(x, y)
    assert a.materials is not None and len(a.materials) > 3 and a.environment is not None
    assert (a.materials.texture >= 0).any()  # some material reads a texture
    for x in a.images:
        assert np.isfinite(x).all() and x.min() >= 0.0


def test_shipped_textured_scenes_load_without_the_shared_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("FOVEAWARP_SCENES_DIR", str(tmp_path))  # an empty folder: only the assets are there
    for name, tris in (("suzanne", 3936), ("wicker", 3072)):
        p = meshio.find_textured_scene(name)
        assert p is not None and p.is_relative_to(meshio.assets_dir()), name
        s = _load(name)
        assert s.num_triangles == tris and s.materials is not None and len(s.images) > 0, name
    for name in ("barrel", "milk-truck", "grey-white-room"):
        assert meshio.find_textured_scene(name) is None
        with pytest.raises(ValueError, match="FOVEAWARP_SCENES_DIR"):
            fw.load_scene(name)
        with pytest.raises(ValueError, match=name):
            _check_scene_sources([name])
    assert default_view_scenes() == ["cornell", "room", "suzanne", "wicker"]


@pytest.mark.parametrize("name, tris", [("barrel", 1148), ("milk-truck", 3624), ("grey-white-room", 143163)])
def test_shared_textured_scenes(name, tris):
    if meshio.find_textured_scene(name) is None:
        pytest.skip(meshio.textured_scene_help(name))
    s = _load(name)
    assert s.num_triangles == tris and s.materials is not None and s.camera is not None
    assert np.isfinite(s.face_albedo).all()
    assert name in default_view_scenes()


def test_cli_render_takes_scene_files_and_demo_takes_room(tmp_path):
    files = _files(tmp_path)
    for kind in ("xml", "glb", "obj"):
        out = tmp_path / f"r-{kind}"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            rc = main(["render", "--scene", str(files[kind]), "--device", "cpu", "--width", "24", "--height", "16",
                       "--frames", "1", "--out", str(out), "--no-panel"])
        assert rc == 0 and (out / "frame_0000.png").is_file(), kind
    out = tmp_path / "demo"
    rc = main(["demo", "--scene", "room", "--device", "cpu", "--width", "24", "--height", "16", "--frames", "1",
               "--out", str(out)])
    assert rc == 0 and json.loads((out / "stats.json").read_text())["scene"] == "room"


def test_viewer_offers_the_textured_scenes():
    from foveawarp.viewer.session import ViewerSession

    scenes = default_view_scenes()
    assert {"room", "suzanne", "wicker"} <= set(scenes)
    _check_scene_sources(scenes)
    session = ViewerSession(scenes, 32, 18, device="cpu")
    assert list(session.limits.scenes)[: 4] == ["cornell", "room", "suzanne", "wicker"]


def test_room_foveated_frame_shows_the_sky_where_rays_miss(device):
    """Where primary rays miss, the room's foveated frame shows its sky (the environment along each pixel's ray,
    as the G-buffer saw it), equal to the full-resolution reference there, not one background colour."""
    w, h = 64, 36
    loop = fw.FrameLoop("room", w, h, device=device, policy="foveated")
    cam = loop.scene.camera
    for _ in range(2):
        img = loop.render(cam, gaze_px=(0.3 * w, 0.6 * h)).image.numpy().copy()
    miss = loop.gbuffer.hit.numpy() == 0
    ref = loop.render_reference(cam).image.numpy()
    assert miss.sum() > 0.05 * w * h  # the camera sees the sky through the open side
    np.testing.assert_array_equal(img[miss], ref[miss])
    assert np.ptp(img[miss], axis=0).max() > 0.01  # the sky's gradient, not a constant
