"""The viewer's frame delivery and its latency measurements: the JPEG encoders against the image they
encode, the one-frame slot (a slow client gets the newest frame, never a queue), the render thread's wait for a
frame's send (and that it never waits for a busy or departed client), a clean stop, and the two gaze-to-frame
latency definitions against hand-computed values. No rendering: fake sockets and a session that draws nothing;
well under a second."""

from __future__ import annotations

import asyncio
import io
import sys
import threading

import numpy as np
import pytest

from foveawarp.viewer.session import JPEG_ENCODERS, ViewerSession, encode_jpeg, jpeg_encoder, resolve_jpeg_encoder

W, H = 96, 54


def _test_image(w, h):
    """A smooth colour gradient with a bright disc: what a JPEG at high quality reproduces closely."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    r = 255 * x / max(w - 1, 1)
    g = 255 * y / max(h - 1, 1)
    b = 128 + 100 * np.sin(x / 9.0) * np.cos(y / 7.0)
    disc = (x - 0.6 * w) ** 2 + (y - 0.4 * h) ** 2 < (0.2 * h) ** 2
    img = np.stack([r, g, b], axis=-1)
    img[disc] = (230, 230, 40)
    return np.clip(img + 0.5, 0, 255).astype(np.uint8)


# -- encoders ---------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("encoder", ["pillow", "simplejpeg"])
@pytest.mark.parametrize("size", [(W, H), (97, 55), (17, 9)])
def test_encode_jpeg_decodes_back_to_the_image(encoder, size):
    pytest.importorskip("PIL")
    if encoder == "simplejpeg":
        pytest.importorskip("simplejpeg", reason="simplejpeg (viewer extra) is not installed")
    from PIL import Image

    w, h = size
    img = _test_image(w, h)
    jpeg = encode_jpeg(img, 95, encoder)
    assert jpeg[:2] == b"\xff\xd8" and jpeg[-2:] == b"\xff\xd9"        # SOI ... EOI
    im = Image.open(io.BytesIO(jpeg))
    assert im.format == "JPEG" and im.size == (w, h) and im.mode == "RGB"
    # 4:2:0: the luma component is sampled 2x2 against the chroma ones
    assert [(hs, vs) for _, hs, vs, _ in im.layer] == [(2, 2), (1, 1), (1, 1)]
    assert not im.info.get("progressive") and not im.info.get("progression")
    dec = np.asarray(im.convert("RGB")).astype(np.float64)
    # quality 95: the luma (full resolution in 4:2:0) within a few levels everywhere; the colour is blurred at
    # the disc's edge by the chroma subsampling, so RGB is checked on average, tighter where the image is larger
    luma = np.array([0.299, 0.587, 0.114])
    assert np.abs(dec @ luma - img @ luma).max() < 12.0
    assert np.abs(dec @ luma - img @ luma).mean() < 1.5
    assert np.abs(dec - img).mean() < (3.0 if w >= 64 else 10.0)
    # a lower quality makes a smaller file of the same size
    small = encode_jpeg(img, 30, encoder)
    assert Image.open(io.BytesIO(small)).size == (w, h) and len(small) < len(jpeg)


def test_encoders_agree_on_the_picture():
    pytest.importorskip("PIL")
    pytest.importorskip("simplejpeg", reason="simplejpeg (viewer extra) is not installed")
    from PIL import Image

    img = _test_image(W, H)
    a, b = (np.asarray(Image.open(io.BytesIO(encode_jpeg(img, 80, e))).convert("RGB")).astype(np.int16)
            for e in ("pillow", "simplejpeg"))
    assert np.abs(a - b).mean() < 2.0      # same libjpeg-turbo, same settings: near-identical pixels


def test_encoder_choice_is_validated_and_falls_back_to_pillow(monkeypatch):
    for bad in ("gif", "", None, 3):
        with pytest.raises(ValueError, match="encoder must be one of"):
            resolve_jpeg_encoder(bad)
        with pytest.raises(ValueError, match="encoder must be one of"):
            ViewerSession(["cornell"], W, H, device="cpu", encoder=bad)
    assert resolve_jpeg_encoder("pillow") == "pillow"
    assert set(JPEG_ENCODERS) == {"auto", "simplejpeg", "pillow"}
    monkeypatch.setitem(sys.modules, "simplejpeg", None)            # as if the package were not installed
    assert resolve_jpeg_encoder("auto") == "pillow"
    assert ViewerSession(["cornell"], W, H, device="cpu").encoder == "pillow"
    assert jpeg_encoder().startswith("Pillow")
    with pytest.raises(ValueError, match="simplejpeg"):
        resolve_jpeg_encoder("simplejpeg")


# -- latency definitions -----------------------------------------------------------------------------------------

def test_latency_per_rendered_gaze_and_per_gaze_message():
    s = ViewerSession(["cornell"], W, H, device="cpu")
    g = lambda x: {"type": "gaze", "x": float(x), "y": 1.0}  # noqa: E731
    s.apply(g(1), t_arrival=10.000)            # gaze 1: replaced by gaze 2 before a frame took it
    s.apply(g(2), t_arrival=10.004)            # gaze 2: rendered
    s.frame_left({"gaze_id": 2, "gaze_t": 10.004}, t_left=10.010)
    assert list(s.latencies) == pytest.approx([6.0])
    assert list(s.latencies_msg) == pytest.approx([10.0, 6.0])
    s.frame_left({"gaze_id": 2, "gaze_t": 10.004}, t_left=10.020)   # a later frame with the same gaze: no sample
    s.frame_left({"gaze_id": 0, "gaze_t": None}, t_left=10.021)     # a trace frame: no sample
    assert len(s.latencies) == 1 and len(s.latencies_msg) == 2
    s.apply(g(3), t_arrival=10.012)
    s.apply(g(4), t_arrival=10.013)
    s.frame_left({"gaze_id": 3, "gaze_t": 10.012}, t_left=10.030)   # gaze 4 arrived during that frame: waits on
    assert list(s.latencies) == pytest.approx([6.0, 18.0])
    assert list(s.latencies_msg) == pytest.approx([10.0, 6.0, 18.0])
    s.frame_left({"gaze_id": 4, "gaze_t": 10.013}, t_left=10.040)
    assert list(s.latencies) == pytest.approx([6.0, 18.0, 27.0])
    assert list(s.latencies_msg) == pytest.approx([10.0, 6.0, 18.0, 27.0])
    st = s.stats_snapshot()
    assert st["latency_samples"] == 3 and st["latency_msg_samples"] == 4
    assert st["latency_ms_p50"] == pytest.approx(18.0)
    assert st["latency_msg_ms_p50"] == pytest.approx(14.0)
    assert st["latency_msg_ms_p95"] == pytest.approx(np.percentile([10.0, 6.0, 18.0, 27.0], 95))
    # gaze messages while a trace drives the gaze are never rendered: they are not waited for
    s.gaze_source = "trace"
    s.apply(g(5), t_arrival=10.050)
    s.gaze_source = "mouse"
    s.apply(g(6), t_arrival=10.060)
    s.frame_left({"gaze_id": 6, "gaze_t": 10.060}, t_left=10.070)
    assert list(s.latencies_msg)[-1] == pytest.approx(10.0) and len(s.latencies_msg) == 5
    s.apply({"type": "reset_stats"})
    st = s.stats_snapshot()
    assert st["latency_samples"] == 0 and st["latency_msg_samples"] == 0 and st["latency_msg_ms_p95"] is None


# -- the one-frame slot and the render thread's wait ----------------------------------------------------------------

class GatedWS:
    """A fake WebSocket whose ``send`` waits for ``gate`` (a slow client) and records what went out."""

    def __init__(self, gate_open=True, log=None):
        self.sent = []
        self.gate = asyncio.Event()
        if gate_open:
            self.gate.set()
        self.log = log

    async def send(self, data):
        await self.gate.wait()
        await asyncio.sleep(0.01)
        self.sent.append(data)
        if self.log is not None:
            self.log.append("sent")


def _server():
    pytest.importorskip("websockets", reason="the viewer extra (websockets) is not installed")
    from foveawarp.viewer.server import ViewerServer

    return ViewerServer(ViewerSession(["cornell"], W, H, device="cpu"), port=0)


async def _until(pred, limit=2000):
    for _ in range(limit):
        if pred():
            return
        await asyncio.sleep(0.001)
    raise AssertionError("condition not met")


def test_a_slow_client_gets_the_newest_frame_never_a_queue():
    srv = _server()
    from foveawarp.viewer.server import _Client, _Delivery

    async def run():
        slow = GatedWS(gate_open=False)
        fast = GatedWS()
        cs, cf = _Client(slow), _Client(fast)
        srv._clients.update({cs, cf})
        tasks = [asyncio.create_task(srv._sender(c)) for c in (cs, cf)]
        d1 = _Delivery()
        srv._on_frame(b"f1", {"frame": 1}, d1)
        await _until(lambda: cs.busy and len(fast.sent) == 1)      # the slow client is stuck sending frame 1
        assert not d1.event.is_set()                                # ... and the render thread waits for it
        later = []
        for k in range(2, 6):
            d = _Delivery()
            srv._on_frame(b"f%d" % k, {"frame": k}, d)
            later.append(d)
            await _until(lambda: len(fast.sent) == k)               # the fast client gets every frame
            assert d.event.is_set()                                 # a client busy sending is not waited for
        slow.gate.set()
        await _until(lambda: len(slow.sent) == 2)
        await asyncio.sleep(0.05)
        assert slow.sent == [b"f1", b"f5"]                          # frames 2-4 dropped, the newest next
        assert cs.dropped == 3 and cs.sent == 2 and cf.dropped == 0 and cf.sent == 5
        assert fast.sent == [b"f1", b"f2", b"f3", b"f4", b"f5"]
        assert d1.event.is_set()
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)

    asyncio.run(run())


def test_a_client_that_leaves_owing_a_frame_releases_the_render_thread():
    srv = _server()
    from foveawarp.viewer.server import _Delivery

    d = _Delivery()

    class LeavingWS(GatedWS):
        def __aiter__(self):
            return self

        async def __anext__(self):
            # a frame arrives for this idle client, and the connection ends before its sender runs
            srv._on_frame(b"f", {"frame": 1}, d)
            assert not d.event.is_set()
            raise StopAsyncIteration

    async def run():
        ws = LeavingWS()
        await srv._handler(ws)
        assert d.event.is_set() and ws.sent[1:] == []               # only the state message went out
        assert not srv._clients

    asyncio.run(run())


def test_publish_returns_after_the_frame_has_left_and_stop_ends_the_threads():
    srv = _server().start_in_thread()
    from foveawarp.viewer.server import _Client

    log = []
    try:
        srv._publish_threadsafe(b"nobody", {"frame": 0})           # no client: returns at once
        ws = GatedWS(log=log)

        async def attach():
            c = _Client(ws)
            srv._clients.add(c)
            asyncio.get_running_loop().create_task(srv._sender(c))

        asyncio.run_coroutine_threadsafe(attach(), srv._loop).result(10)
        for k in range(3):
            srv._publish_threadsafe(b"f%d" % k, {"frame": k})
            log.append("returned")
        # each publish (the render thread's) returned only once its frame had been written to the client
        assert log == ["sent", "returned"] * 3 and ws.sent == [b"f0", b"f1", b"f2"]
        render = srv.session._thread
        assert render is not None and render.is_alive()
    finally:
        srv.stop()
    assert not render.is_alive() and srv.session._thread is None
    assert not [t for t in threading.enumerate() if t.name in ("foveawarp-render", "foveawarp-viewer")]
    srv._publish_threadsafe(b"late", {"frame": 9})                  # after stop: returns, sends nothing
    assert ws.sent == [b"f0", b"f1", b"f2"]


# -- the CPU frame path ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("env, expected", [(None, "cores"), ("1", 1)])
def test_the_viewer_renders_with_the_band_parallel_cpu_path(monkeypatch, env, expected):
    """The viewer's FrameLoop uses the band-parallel CPU launches on the usable cores (FOVEAWARP_CPU_THREADS
    overrides), like every FrameLoop."""
    from foveawarp import parallel

    if env is None:
        monkeypatch.delenv(parallel.ENV_VAR, raising=False)
    else:
        monkeypatch.setenv(parallel.ENV_VAR, env)
    s = ViewerSession(["cornell"], W, H, device="cpu")
    with s._cond:
        snap = s._snapshot()
    s._ensure_loops(snap)
    want = parallel.usable_cores() if expected == "cores" else expected
    assert s._loop.cpu_threads == want


def test_path_knob_renders_path_traced_frames():
    """The page's path knob (with max_depth and spp) switches the session's loops to the path integrator: the
    frame's stats count the paths traced, spp per traced pixel, and the frame is finite."""
    s = ViewerSession(["cornell"], W, H, device="cpu")
    s.apply({"type": "set", "knob": "indirect", "value": False})
    for knob, value in (("path", True), ("max_depth", 3), ("spp", 2)):
        s.apply({"type": "set", "knob": knob, "value": value})
    with s._cond:
        snap = s._snapshot()
    s._ensure_loops(snap)
    assert s._loop.path is not None and s._loop.config.shading.max_depth == 3
    for _ in range(2):
        payload, meta = s._render(snap)
    st = s.stats_snapshot()
    n = int(s._loop.reorder.count.numpy()[0]) if st.get("sampling_rate", 1.0) < 1.0 else W * H
    assert st["paths_traced"] == 2 * n and "rays_traced" not in st
    assert np.isfinite(s._loop.hdr.numpy()).all()


def test_path_filter_knob_filters_the_foveated_frame():
    """The page's periphery-filter and periphery-history knobs build the loop's a-trous filter and history
    blend; the frames stay finite."""
    s = ViewerSession(["cornell"], W, H, device="cpu")
    s.apply({"type": "set", "knob": "indirect", "value": False})
    for knob, value in (("path", True), ("path_filter", True), ("path_history", 0.5)):
        s.apply({"type": "set", "knob": knob, "value": value})
    with s._cond:
        snap = s._snapshot()
    s._ensure_loops(snap)
    assert s._loop.path_filter is not None and s._loop.config.shading.path_filter == "atrous"
    assert s._loop.path_history is not None and s._loop.config.shading.path_history == 0.5
    for _ in range(2):
        s._render(snap)
    out = s._loop.filtered.numpy()
    assert np.isfinite(out).all() and out.max() > 0.0  # the filter wrote the frame
