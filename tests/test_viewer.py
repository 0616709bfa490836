"""The live viewer: message validation, camera moves, the display kernel against NumPy, gaze traces,
and a real server on a free loopback port driven by a WebSocket client (frames, /stats.json, errors, a client
that vanishes, a fuzz of 1000 garbage messages). CPU, 96 x 54: seconds."""

from __future__ import annotations

import asyncio
import io
import json
import math
import random
import urllib.request

import numpy as np
import pytest
import warp as wp

from foveawarp import parallel
import foveawarp as fw
from foveawarp.gaze_trace import GazeTrace, load_gaze_trace
from foveawarp.kernels.display import FLAG_ERROR, FLAG_RINGS, FLAG_SAMPLING, compose_display_kernel
from foveawarp.viewer.protocol import KNOBS, MAX_MESSAGE_CHARS, Limits, ProtocolError, parse_message
from foveawarp.viewer.session import ViewerSession, fly, orbit, scene_labels

W, H = 96, 54
LIM = Limits(W, H, ("cornell", "earth"), has_trace=False)

# -- message validation ----------------------------------------------------------------------------------------

GOOD = [
    ('{"type": "gaze", "x": 10, "y": 20.5}', {"type": "gaze", "x": 10.0, "y": 20.5}),
    ('{"type": "gaze", "x": -96, "y": 108, "seq": 7}', {"type": "gaze", "x": -96.0, "y": 108.0, "seq": 7}),
    ('{"type": "orbit", "dx": 3, "dy": -4}', {"type": "orbit", "dx": 3.0, "dy": -4.0}),
    ('{"type": "fly", "forward": 1}', {"type": "fly", "forward": 1.0, "right": 0.0, "up": 0.0}),
    ('{"type": "play", "on": true}', {"type": "play", "on": True}),
    ('{"type": "reset_camera"}', {"type": "reset_camera"}),
    ('{"type": "mode", "value": "side_by_side"}', {"type": "mode", "value": "side_by_side"}),
    ('{"type": "overlay", "rings": true, "error": false}', {"type": "overlay", "rings": True, "error": False}),
    ('{"type": "set", "knob": "falloff_deg", "value": null}', {"type": "set", "knob": "falloff_deg", "value": None}),
    ('{"type": "set", "knob": "falloff_deg", "value": 180}', {"type": "set", "knob": "falloff_deg", "value": 180.0}),
    ('{"type": "set", "knob": "block", "value": 64}', {"type": "set", "knob": "block", "value": 64}),
    ('{"type": "set", "knob": "ao_samples", "value": 0}', {"type": "set", "knob": "ao_samples", "value": 0}),
    ('{"type": "set", "knob": "dof", "value": true}', {"type": "set", "knob": "dof", "value": True}),
    ('{"type": "scene", "name": "earth"}', {"type": "scene", "name": "earth"}),
    ('{"type": "gaze_source", "value": "mouse"}', {"type": "gaze_source", "value": "mouse"}),
    ('{"type": "reset_stats"}', {"type": "reset_stats"}),
]

BAD = [
    ("not json", "not valid JSON"),
    ("", "not valid JSON"),
    ("[1, 2]", "JSON object"),
    ('"gaze"', "JSON object"),
    ("{}", "type must be one of"),
    ('{"type": "teleport"}', "type must be one of"),
    ('{"type": 5}', "type must be one of"),
    ('{"type": "gaze", "x": NaN, "y": 1}', "gaze x must be a finite number"),
    ('{"type": "gaze", "x": Infinity, "y": 1}', "gaze x must be a finite number"),
    ('{"type": "gaze", "x": 1, "y": -Infinity}', "gaze y must be a finite number"),
    ('{"type": "gaze", "x": 1e300, "y": 1}', "in [-96, 192]"),
    ('{"type": "gaze", "x": 193, "y": 1}', "in [-96, 192]"),
    ('{"type": "gaze", "x": 1, "y": -55}', "in [-54, 108]"),
    ('{"type": "gaze", "x": "1", "y": 1}', "gaze x must be a number"),
    ('{"type": "gaze", "x": true, "y": 1}', "gaze x must be a number"),
    ('{"type": "gaze", "x": 1}', "missing field"),
    ('{"type": "gaze", "x": 1, "y": 1, "z": 0}', "unknown field"),
    ('{"type": "gaze", "x": 1, "y": 1, "seq": -1}', "seq must be an integer"),
    ('{"type": "gaze", "x": 1, "y": 1, "seq": 1.5}', "seq must be an integer"),
    ('{"type": "gaze", "x": ' + "9" * 400 + ', "y": 1}', "gaze x must be a finite number"),
    ('{"type": "orbit", "dx": 1e6, "dy": 0}', "orbit dx"),
    ('{"type": "fly", "forward": 2}', "fly forward must be a finite number in [-1, 1]"),
    ('{"type": "play", "on": 1}', "play on must be true or false"),
    ('{"type": "mode", "value": "wireframe"}', "mode value must be one of"),
    ('{"type": "overlay"}', "at least one"),
    ('{"type": "overlay", "sampling": "yes"}', "overlay sampling must be true or false"),
    ('{"type": "set", "knob": "exposure", "value": 1}', "set knob must be one of"),
    ('{"type": "set", "knob": "falloff_deg", "value": 0}', "set falloff_deg: value must be in (0, 180]"),
    ('{"type": "set", "knob": "falloff_deg", "value": 181}', "set falloff_deg: value must be in (0, 180]"),
    ('{"type": "set", "knob": "falloff_deg", "value": NaN}', "finite number in (0, 180]"),
    ('{"type": "set", "knob": "block", "value": 0}', "set block: value must be in [1, 64]"),
    ('{"type": "set", "knob": "block", "value": 65}', "set block: value must be in [1, 64]"),
    ('{"type": "set", "knob": "block", "value": 4.0}', "must be an integer in [1, 64]"),
    ('{"type": "set", "knob": "block", "value": null}', "must not be null"),
    ('{"type": "set", "knob": "ao_samples", "value": 257}', "set ao_samples: value must be in [0, 256]"),
    ('{"type": "set", "knob": "temporal", "value": 1}', "set temporal: value must be true or false"),
    ('{"type": "scene", "name": "/etc/passwd"}', "scene name must be one of"),
    ('{"type": "scene", "name": "city"}', "scene name must be one of"),
    ('{"type": "gaze_source", "value": "trace"}', "no gaze trace"),
    ("[" * 5000, "at most 4096 characters"),
    ('{"type": "gaze", "x": 1, "y": 1, "pad": "' + "x" * MAX_MESSAGE_CHARS + '"}', "at most 4096"),
]


@pytest.mark.parametrize("text, expected", GOOD)
def test_valid_messages_are_normalized(text, expected):
    assert parse_message(text, LIM) == expected


@pytest.mark.parametrize("text, needle", BAD)
def test_invalid_messages_raise_protocol_error_saying_why(text, needle):
    with pytest.raises(ProtocolError) as ei:
        parse_message(text, LIM)
    assert needle in str(ei.value), str(ei.value)


def test_binary_messages_are_rejected():
    with pytest.raises(ProtocolError, match="JSON text"):
        parse_message(b'{"type": "reset_stats"}', LIM)


def test_deeply_nested_json_is_an_error_not_a_crash():
    with pytest.raises(ProtocolError):
        parse_message("[" * 2000 + "]" * 2000, LIM)


_KNOB_FIELDS = {
    "falloff_deg": ("foveation", "falloff_deg"),
    "block": ("foveation", "block"),
    "ao_samples": ("shading", "ao_samples"),
    "max_depth": ("shading", "max_depth"),
    "spp": ("shading", "spp"),
    "path_history": ("shading", "path_history"),
}


@pytest.mark.parametrize("name", sorted(_KNOB_FIELDS))
def test_knob_ranges_match_the_config_validation(name):
    """The page's documented knob ranges are exactly the ranges Config accepts (Config is the reference)."""
    k = KNOBS[name]
    stage, fieldname = _KNOB_FIELDS[name]
    step = 1 if k.kind == "int" else 1e-6
    inside = [k.hi] + ([] if k.lo_open else [k.lo]) + ([k.lo + step] if k.lo_open else [])
    outside = [k.hi + step, k.lo - step] + ([k.lo] if k.lo_open else [])
    for v in inside:
        v = int(v) if k.kind == "int" else float(v)
        assert k.check(v) == v
        fw.Config().with_(**{stage: {fieldname: v}})
    for v in outside:
        v = int(v) if k.kind == "int" else float(v)
        with pytest.raises(ProtocolError):
            k.check(v)
        with pytest.raises(ValueError):
            fw.Config().with_(**{stage: {fieldname: v}})


def test_session_config_follows_the_knobs():
    knobs = {"falloff_deg": 20.0, "block": 8, "temporal": False, "ao_samples": 4, "dof": True, "indirect": True,
             "timing": True, "path": False, "max_depth": 5, "spp": 1}
    cfg = ViewerSession.config_for(knobs)
    assert cfg.foveation.falloff_deg == 20.0 and cfg.foveation.block == 8
    assert cfg.temporal.enabled is False and cfg.shading.ao_samples == 4
    assert cfg.dof.enabled and cfg.shading.indirect == "lighttree"
    off = ViewerSession.config_for({**knobs, "dof": False, "indirect": False})
    assert not off.dof.enabled and off.shading.indirect == "none" and off.shading.integrator == "direct"
    path = ViewerSession.config_for({**knobs, "indirect": False, "path": True, "max_depth": 3, "spp": 2})
    assert (path.shading.integrator, path.shading.max_depth, path.shading.spp) == ("path", 3, 2)
    assert path.shading.path_filter == "none"
    filt = ViewerSession.config_for({**knobs, "indirect": False, "path": True, "path_filter": True})
    assert filt.shading.path_filter == "atrous" and filt.shading.path_history == 0.0
    hist = ViewerSession.config_for({**knobs, "indirect": False, "path": True, "path_history": 0.5})
    assert hist.shading.path_history == 0.5 and hist.shading.path_filter_guide == "relative"
    guided = ViewerSession.config_for({**knobs, "indirect": False, "path": True, "path_filter": True,
                                       "path_filter_variance": True})
    assert guided.shading.path_filter_guide == "variance"
    with pytest.raises(ValueError, match="computes indirect light itself"):
        ViewerSession.config_for({**knobs, "path": True})


def test_scene_labels_hide_paths():
    assert scene_labels(["cornell", "/some/dir/bunny.obj", "other/bunny.ply", "earth"]) == [
        "cornell", "bunny", "bunny-2", "earth"]


# -- camera moves -------------------------------------------------------------------------------------------------


def test_orbit_keeps_distance_and_full_turn_returns():
    cam = fw.Camera(eye=(0.3, 1.2, 3.5), target=(0, 1, 0))
    d0 = np.linalg.norm(np.subtract(cam.eye, cam.target))
    c = cam
    for _ in range(8):
        c = orbit(c, 45.0, 0.0)
        assert np.isclose(np.linalg.norm(np.subtract(c.eye, c.target)), d0, rtol=1e-9)
    np.testing.assert_allclose(c.eye, cam.eye, atol=1e-9)
    # pitching far stops 5 degrees short of the pole
    top = orbit(cam, 0.0, 400.0)
    off = np.subtract(top.eye, top.target) / d0
    assert math.degrees(math.acos(np.clip(off[1], -1, 1))) == pytest.approx(5.0, abs=1e-6)
    assert np.isclose(np.linalg.norm(np.subtract(top.eye, top.target)), d0)


def test_fly_moves_eye_and_target_along_the_camera_axes():
    cam = fw.Camera(eye=(0, 1, 3.5), target=(0, 1, 0))
    c = fly(cam, np.array([0.5, 0.25, 0.1]))
    r, u, f = cam.basis()
    expect = 0.5 * f + 0.25 * r + 0.1 * u
    np.testing.assert_allclose(np.subtract(c.eye, cam.eye), expect, atol=1e-12)
    np.testing.assert_allclose(np.subtract(c.target, cam.target), expect, atol=1e-12)


# -- display kernel against NumPy ----------------------------------------------------------------------------


def _compose_np(img, ref, smap, flags, err_gain=8.0):
    """Independent NumPy version of the overlay rules (no rings)."""
    c = np.clip(np.nan_to_num(img, nan=0.0), 0, 1)
    if flags & FLAG_ERROR:
        e = np.minimum(np.abs(c - np.clip(ref, 0, 1)).sum(-1) * (err_gain / 3.0), 1.0)
        heat = np.stack([np.minimum(3 * e, 1), np.clip(3 * e - 1, 0, 1), np.clip(3 * e - 2, 0, 1)], -1)
        c = c * 0.25 + heat * 0.75
    if flags & FLAG_SAMPLING:
        c = np.where(smap[..., None] != 0, c * 0.55 + np.array([0.45, 0.05, 0.3]), c * 0.7)
    return np.floor(c * 255 + 0.5).astype(np.int32)


def _compose(img, ref, smap, gaze, fov, flags):
    h, w = smap.shape
    out = wp.zeros((h, w, 3), dtype=wp.uint8, device="cpu")
    parallel.launch(compose_display_kernel, dim=(h, w),
                    inputs=[wp.array(img, dtype=wp.vec3, device="cpu"), wp.array(ref, dtype=wp.vec3, device="cpu"),
                            wp.array(smap, dtype=wp.uint8, device="cpu"), wp.vec2(*gaze),
                            math.tan(math.radians(fov) / 2), 5.0, 8.0, flags, 0], outputs=[out], device="cpu")
    return out.numpy().astype(np.int32)


@pytest.mark.parametrize("flags", [0, FLAG_SAMPLING, FLAG_ERROR, FLAG_SAMPLING | FLAG_ERROR])
def test_display_kernel_matches_numpy(flags, rng):
    img = rng.uniform(-0.2, 1.2, (20, 30, 3)).astype(np.float32)
    img[3, 4, 1] = np.nan
    ref = rng.uniform(0, 1, (20, 30, 3)).astype(np.float32)
    smap = (rng.uniform(size=(20, 30)) < 0.4).astype(np.uint8)
    got = _compose(img, ref, smap, (10.0, 7.0), 60.0, flags)
    np.testing.assert_allclose(got, _compose_np(img, ref, smap, flags), atol=1)


def test_eccentricity_rings_lie_where_ops_eccentricity_crosses_5_degrees():
    h, w, fov, gaze = 90, 160, 70.0, (57.3, 41.9)
    img = np.full((h, w, 3), 0.0, np.float32)
    got = _compose(img, img, np.zeros((h, w), np.uint8), gaze, fov, FLAG_RINGS)
    ring = got[..., 0] > 100
    ecc = fw.ops.eccentricity_deg(w, h, gaze, fov, device="cpu").astype(np.float64)
    # reference: the band index floor(e / 5) changes between a pixel and its right or lower neighbour
    band = np.floor(ecc / 5.0)
    ecc_r = np.pad(band, ((0, 0), (0, 1)), mode="edge")[:, 1:]
    ecc_d = np.pad(band, ((0, 1), (0, 0)), mode="edge")[1:, :]
    expect = (band != ecc_r) | (band != ecc_d)
    # edge pixels need the off-screen neighbour the kernel computes; borderline bands may differ by rounding
    near = np.abs(ecc / 5.0 - np.round(ecc / 5.0)) < 0.02
    inner = np.zeros_like(expect)
    inner[:-1, :-1] = True
    mism = (ring != expect) & inner & ~near
    assert ring.sum() > 50 and not mism.any(), f"{mism.sum()} ring pixels differ"


# -- gaze traces ------------------------------------------------------------------------------------------------


def test_gaze_trace_csv_interpolates_and_loops(tmp_path):
    p = tmp_path / "trace.csv"
    p.write_text("# recorded\ny_px,t_s,x_px\n10,0.0,100\n30,1.0,300\n\n50,2.0,100\n")
    tr = load_gaze_trace(p)
    assert len(tr) == 3 and tr.duration_s == 2.0
    assert tr.at(0.5) == pytest.approx((200.0, 20.0))
    assert tr.at(1.5) == pytest.approx((200.0, 40.0))
    assert tr.at(2.5) == pytest.approx(tr.at(0.5))           # looped
    assert tr.at(2.5, loop=False) == pytest.approx((100.0, 50.0))
    assert tr.at(-1.0, loop=False) == pytest.approx((100.0, 10.0))


def test_gaze_trace_csv_errors(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("t_s,x_px\n0,1\n")
    with pytest.raises(ValueError, match="header must name the columns"):
        load_gaze_trace(p)
    p.write_text("0,1,2\n1,a,2\n")
    with pytest.raises(ValueError, match="row 2 must hold numbers"):
        load_gaze_trace(p)
    p.write_text("# only a comment\n")
    with pytest.raises(ValueError, match="holds no samples"):
        load_gaze_trace(p)


def test_render_replays_a_gaze_trace(tmp_path):
    from foveawarp.cli import main

    p = tmp_path / "t.csv"
    p.write_text("t_s,x_px,y_px\n0,4,5\n0.0333333333,20,10\n1,30,12\n")
    out = tmp_path / "r"
    rc = main(["render", "--device", "cpu", "--width", "32", "--height", "18", "--frames", "2", "--gaze-trace",
               str(p), "--out", str(out), "--no-panel"])
    assert rc == 0
    frames = json.loads((out / "stats.json").read_text())["frames"]
    tr = GazeTrace([0, 1 / 30.0, 1], [4, 20, 30], [5, 10, 12])
    for i, f in enumerate(frames):
        assert tuple(f["gaze_px"]) == pytest.approx(tr.at(i / 30.0), abs=1e-4)


def test_view_refuses_an_unknown_scene_at_launch(capsys):
    from foveawarp.cli import main

    assert main(["view", "--device", "cpu", "--scene", "no-such-scene.obj", "--port", "0"]) == 2
    assert "no-such-scene.obj" in capsys.readouterr().err


# -- the server ----------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def server():
    pytest.importorskip("websockets", reason="the viewer extra (websockets) is not installed")
    pytest.importorskip("PIL")
    from foveawarp.viewer.server import ViewerServer

    srv = ViewerServer(ViewerSession(["cornell", "earth"], W, H, device="cpu"), port=0).start_in_thread()
    yield srv
    srv.stop()


def _decode(msg):
    from PIL import Image

    n = int.from_bytes(msg[:4], "little")
    header = json.loads(msg[4:4 + n])
    img = np.asarray(Image.open(io.BytesIO(msg[4 + n:])).convert("RGB"))
    return header, img


def _stats(srv):
    with urllib.request.urlopen(srv.url + "stats.json", timeout=10) as r:
        return json.loads(r.read())


async def _until(ws, pred, timeout=60.0, limit=500):
    """Receive messages until ``pred(msg)`` is true (bounded in count and time); returns (match, seen texts)."""
    texts = []
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    for _ in range(limit):
        m = await asyncio.wait_for(ws.recv(), max(end - loop.time(), 0.01))
        if isinstance(m, str):
            texts.append(json.loads(m))
            if pred(texts[-1]):
                return texts[-1], texts
            continue
        h, img = _decode(m)
        if pred((h, img)):
            return (h, img), texts
    raise AssertionError("condition not met within the message limit")


def _frame_with_seq(seq):
    return lambda m: isinstance(m, tuple) and m[0]["seq"] == seq


def _connect(srv):
    from websockets.asyncio.client import connect

    return connect(f"ws://127.0.0.1:{srv.port}/ws", open_timeout=30, close_timeout=5)


def test_server_serves_page_and_static_files(server):
    with urllib.request.urlopen(server.url, timeout=10) as r:
        html = r.read().decode()
    assert "<canvas" in html and "/viewer.js" in html
    with urllib.request.urlopen(server.url + "viewer.js", timeout=10) as r:
        assert "WebSocket" in r.read().decode()
    with pytest.raises(urllib.error.HTTPError) as ei:
        urllib.request.urlopen(server.url + "../pyproject.toml", timeout=10)
    assert ei.value.code == 404


def test_frames_follow_the_gaze_and_stats_report_it(server):
    async def run():
        async with _connect(server) as ws:
            state = json.loads(await ws.recv())
            assert state["type"] == "state" and state["scenes"] == ["cornell", "earth"]
            for seq, (x, y) in enumerate([(10.0, 12.0), (80.5, 40.25), (-3.0, 60.0)], start=1):
                await ws.send(json.dumps({"type": "gaze", "x": x, "y": y, "seq": seq}))
                (h, img), _ = await _until(ws, _frame_with_seq(seq))
                assert img.shape == (H, W, 3) and h["width"] == W and h["height"] == H
                assert h["gaze"] == [x, y]
                assert img.std() > 1.0                     # a rendered scene, not a flat image
                st = _stats(server)
                assert st["gaze_px"] == [x, y]             # the latest frame used this gaze
                assert st["width"] == W and st["height"] == H and st["frames"] >= seq
                for k, t in (("frames", int), ("fps", float), ("ms_frame", float), ("sampling_rate", float)):
                    assert isinstance(st[k], t), k
                assert 0.0 < st["sampling_rate"] <= 1.0
                assert st["latency_samples"] >= 1 and st["latency_ms_p50"] > 0
    asyncio.run(run())


def test_a_client_joining_an_idle_session_gets_a_frame_unasked(server):
    """A second client that sends nothing, joining once the session has rendered its state and gone idle, still
    receives a frame of the current state (the page waits for one before it maps the mouse)."""
    async def run():
        async with _connect(server) as ws:
            await ws.send(json.dumps({"type": "gaze", "x": 20.0, "y": 10.0, "seq": 7}))
            await _until(ws, _frame_with_seq(7))
            await asyncio.sleep(1.0)  # the convergence frames end: nothing is due
            async with _connect(server) as ws2:
                (h, img), texts = await _until(ws2, lambda m: isinstance(m, tuple), timeout=30.0)
                assert texts and texts[0]["type"] == "state"
                assert img.shape == (H, W, 3) and h["gaze"] == [20.0, 10.0] and img.std() > 1.0
    asyncio.run(run())


def test_modes_overlays_knobs_and_errors_keep_the_session(server):
    async def run():
        async with _connect(server) as ws:
            await ws.recv()
            await ws.send(json.dumps({"type": "mode", "value": "side_by_side"}))
            await ws.send(json.dumps({"type": "overlay", "rings": True, "sampling": True, "error": True}))
            await ws.send(json.dumps({"type": "set", "knob": "block", "value": 99}))
            await ws.send(json.dumps({"type": "set", "knob": "block", "value": 8}))
            await ws.send(json.dumps({"type": "gaze", "x": 20, "y": 20, "seq": 101}))
            (h, img), texts = await _until(ws, _frame_with_seq(101))
            assert any(t["type"] == "error" and "block" in t["message"] for t in texts)
            assert img.shape == (H, 2 * W, 3) and h["render_width"] == W
            await ws.send(json.dumps({"type": "scene", "name": "earth"}))
            await ws.send(json.dumps({"type": "orbit", "dx": 30, "dy": 5}))
            await ws.send(json.dumps({"type": "fly", "forward": 1, "right": -0.5}))
            await ws.send(json.dumps({"type": "mode", "value": "foveated"}))
            await ws.send(json.dumps({"type": "gaze", "x": 30, "y": 30, "seq": 102}))
            (h, img), texts = await _until(ws, _frame_with_seq(102))
            assert img.shape == (H, W, 3)
            assert h["stats"]["scene"] == "earth"
            state = [t for t in texts if t["type"] == "state"][-1]
            assert state["knobs"]["block"] == 8 and state["scene"] == "earth"
            await ws.send(json.dumps({"type": "overlay", "rings": False, "sampling": False, "error": False}))
            await ws.send(json.dumps({"type": "scene", "name": "cornell"}))
            await ws.send(json.dumps({"type": "set", "knob": "block", "value": 4}))
    asyncio.run(run())


def test_a_client_that_vanishes_mid_frame_does_not_disturb_another(server):
    async def run():
        async with _connect(server) as a:
            await a.recv()
            b = await _connect(server).__aenter__()
            await b.recv()
            await b.send(json.dumps({"type": "gaze", "x": 5, "y": 5}))
            await a.send(json.dumps({"type": "gaze", "x": 6, "y": 6, "seq": 201}))
            b.transport.abort()                      # vanish without a close handshake, frames in flight
            (h, img), _ = await _until(a, _frame_with_seq(201))
            assert img.shape == (H, W, 3)
            await a.send(json.dumps({"type": "gaze", "x": 7, "y": 8, "seq": 202}))
            (h, img), _ = await _until(a, _frame_with_seq(202))
            assert h["gaze"] == [7.0, 8.0]
    asyncio.run(run())
    # both connections end up removed (bounded wait: the server notices the aborted one on its own)
    for _ in range(100):
        if _stats(server)["clients"] == 0:
            break
        import time

        time.sleep(0.1)
    assert _stats(server)["clients"] == 0


def _garbage(rnd: random.Random) -> "str | bytes":
    kind = rnd.randrange(8)
    valid = json.dumps({"type": "gaze", "x": 10, "y": 10})
    if kind == 0:
        return bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 200)))
    if kind == 1:
        return "".join(chr(rnd.randrange(32, 0x2FF)) for _ in range(rnd.randrange(0, 300)))
    if kind == 2:   # a valid message with bytes flipped
        s = list(valid)
        for _ in range(rnd.randrange(1, 4)):
            s[rnd.randrange(len(s))] = chr(rnd.randrange(32, 127))
        return "".join(s)
    if kind == 3:
        t = rnd.choice(["gaze", "set", "orbit", "fly", "mode", "scene", "overlay", "play", "nope", None, 3])
        v = rnd.choice([None, True, "x", -1, 1e308, float("nan"), [1], {"a": 1}, "../../etc/passwd", 2**70])
        return json.dumps({"type": t, "x": v, "y": v, "knob": rnd.choice(list(KNOBS) + ["zz"]), "value": v,
                           "name": v, "dx": v})
    if kind == 4:
        return json.dumps({"type": "gaze", "x": rnd.choice([float("nan"), float("inf"), 1e12, -1e12]), "y": 0})
    if kind == 5:
        return "[" * rnd.randrange(1, 3000)
    if kind == 6:
        return json.dumps({"type": "set", "knob": rnd.choice(list(KNOBS)), "value": rnd.choice([-5, 1e9, "1", []])})
    return json.dumps(rnd.choice([[], {}, "", 0, None, [{"type": "gaze"}]]))


def test_fuzz_a_thousand_garbage_messages_then_frames_still_come(server):
    rnd = random.Random(20)
    msgs = [_garbage(rnd) for _ in range(1000)]
    rejected = 0
    for m in msgs:
        try:
            parse_message(m, server.session.limits)
        except ProtocolError:
            rejected += 1
    assert rejected >= 900

    async def run():
        async with _connect(server) as ws:
            await ws.recv()
            for m in msgs:
                await ws.send(m)
            await ws.send(json.dumps({"type": "gaze", "x": 11, "y": 12, "seq": 301}))
            (h, img), texts = await _until(ws, _frame_with_seq(301), timeout=120, limit=5000)
            errors = [t for t in texts if t["type"] == "error"]
            assert len(errors) == rejected                # every rejected message got its error back
            assert img.shape == (H, W, 3) and img.std() > 1.0
        # a fresh client is served too
        async with _connect(server) as ws:
            await ws.recv()
            await ws.send(json.dumps({"type": "gaze", "x": 12, "y": 13, "seq": 302}))
            (h, img), _ = await _until(ws, _frame_with_seq(302))
            assert h["gaze"] == [12.0, 13.0]
    asyncio.run(run())


def test_cross_origin_websocket_is_refused(server):
    from websockets.asyncio.client import connect
    from websockets.exceptions import InvalidStatus

    async def run():
        with pytest.raises(InvalidStatus) as ei:
            async with connect(f"ws://127.0.0.1:{server.port}/ws", origin="http://evil.example",
                               open_timeout=10):
                pass
        assert ei.value.response.status_code == 403
    asyncio.run(run())


def test_foveawarp_view_command_serves_and_stops_on_ctrl_c():
    """The console command as a user starts it: prints the URL, serves the page and /stats.json, and exits
    cleanly on SIGINT (Ctrl-C)."""
    pytest.importorskip("websockets", reason="the viewer extra (websockets) is not installed")
    import os
    import signal
    import subprocess
    import sys
    import threading
    from pathlib import Path

    repo = Path(__file__).resolve().parent.parent

    # a terminal's foreground process gets Ctrl-C with Python's default handler; a test run started in the
    # background by a shell without job control inherits SIGINT ignored, and so would the viewer (it would never
    # see the signal and the wait below would time out): the child installs the handler a terminal's process has,
    # then runs the console command as `python -m foveawarp.cli` does
    start = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
             "from foveawarp.cli import main; sys.exit(main(sys.argv[1:]))")
    proc = subprocess.Popen([sys.executable, "-c", start, "view", "--device", "cpu", "--width", "32",
                             "--height", "18", "--port", "0"], cwd=repo, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lines, found = [], threading.Event()

    def read():
        for line in proc.stdout:
            lines.append(line)
            if "open http://127.0.0.1:" in line:
                found.set()
        found.set()

    threading.Thread(target=read, daemon=True).start()
    try:
        assert found.wait(120), "".join(lines)
        url = next(ln for ln in lines if "open http://" in ln).split("open ")[1].split()[0]
        assert url.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(url, timeout=10) as r:
            assert b"<canvas" in r.read()
        with urllib.request.urlopen(url + "stats.json", timeout=10) as r:
            st = json.loads(r.read())
        assert st["width"] == 32 and st["height"] == 18 and st["frames"] == 0
        proc.send_signal(signal.SIGINT)
        assert proc.wait(60) == 0, "".join(lines)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def test_view_warns_when_listening_beyond_loopback(monkeypatch, capsys):
    """--host other than loopback prints a warning (the server start itself is stubbed out here)."""
    pytest.importorskip("websockets", reason="the viewer extra (websockets) is not installed")
    from foveawarp import cli
    from foveawarp.viewer import server as server_mod

    started = []

    async def fake_start(self):
        started.append((self.host, self.port))
        raise KeyboardInterrupt

    monkeypatch.setattr(server_mod.ViewerServer, "start", fake_start)
    assert cli.main(["view", "--device", "cpu", "--width", "16", "--height", "9", "--host", "0.0.0.0",
                     "--port", "0"]) == 0
    assert started == [("0.0.0.0", 0)]
    assert "warning" in capsys.readouterr().err


def test_a_scene_that_fails_to_load_is_reported_and_the_session_goes_on(tmp_path):
    pytest.importorskip("websockets", reason="the viewer extra (websockets) is not installed")
    from foveawarp.viewer.server import ViewerServer

    bad = tmp_path / "broken.obj"
    bad.write_bytes(b"\x00\x01 not a mesh \xff" * 8)
    srv = ViewerServer(ViewerSession(["cornell", str(bad)], W, H, device="cpu"), port=0).start_in_thread()
    try:
        async def run():
            async with _connect(srv) as ws:
                state = json.loads(await ws.recv())
                assert state["scenes"] == ["cornell", "broken"] and "JPEG" not in state["encoder"]
                await ws.send(json.dumps({"type": "scene", "name": "broken"}))
                back = lambda m: isinstance(m, dict) and m["type"] == "state" and m["scene"] == "cornell"  # noqa
                err, texts = await _until(ws, lambda m: isinstance(m, dict) and m["type"] == "error")
                assert "render failed" in err["message"] and "broken.obj" in err["message"]
                if not any(back(t) for t in texts):     # the state may come before or after the error
                    await _until(ws, back)
                await ws.send(json.dumps({"type": "gaze", "x": 9, "y": 9, "seq": 401}))
                (h, img), _ = await _until(ws, _frame_with_seq(401))
                assert img.shape == (H, W, 3) and h["stats"]["scene"] == "cornell"
        asyncio.run(run())
    finally:
        srv.stop()


def test_gaze_trace_drives_the_viewer_until_the_page_switches_to_the_mouse():
    pytest.importorskip("websockets", reason="the viewer extra (websockets) is not installed")
    from foveawarp.viewer.server import ViewerServer

    trace = GazeTrace([0.0, 0.5, 1.0], [10.0, 50.0, 10.0], [20.0, 20.0, 20.0])
    srv = ViewerServer(ViewerSession(["cornell"], W, H, device="cpu", gaze_trace=trace), port=0).start_in_thread()
    try:
        async def run():
            async with _connect(srv) as ws:
                state = json.loads(await ws.recv())
                assert state["gaze_source"] == "trace" and state["has_trace"] and state["overlays"]["gaze"]
                await ws.send(json.dumps({"type": "gaze", "x": 90, "y": 50, "seq": 501}))   # ignored
                xs = set()
                for _ in range(12):
                    (h, img), _ = await _until(ws, lambda m: isinstance(m, tuple))
                    gx, gy = h["gaze"]
                    assert gy == pytest.approx(20.0) and 10.0 <= gx <= 50.0 and h["seq"] is None
                    xs.add(round(gx, 3))
                assert len(xs) > 1                                 # the trace moves the gaze
                await ws.send(json.dumps({"type": "gaze_source", "value": "mouse"}))
                await ws.send(json.dumps({"type": "gaze", "x": 90, "y": 50, "seq": 502}))
                (h, img), _ = await _until(ws, _frame_with_seq(502))
                assert h["gaze"] == [90.0, 50.0]
        asyncio.run(run())
    finally:
        srv.stop()
