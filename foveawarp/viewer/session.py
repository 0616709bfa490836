"""The viewer's shared session: the state the clients steer (gaze, camera, mode, overlays, knobs, scene) and the
render thread that turns it into compressed frames, off the event loop.

It drives only the public API: ``load_scene``, ``Config.with_``, ``Camera``, ``FrameLoop.render`` /
``render_reference`` and ``frame.stats``. All clients share one session (docs/viewer.md).
"""

from __future__ import annotations

import io
import json
import math
import os
import threading
import time
from collections import deque
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import warp as wp

from .. import parallel
from .._util import check_image_size, get_device
from ..camera import Camera
from ..config import Config
from ..kernels.display import FLAG_ERROR, FLAG_GAZE, FLAG_RINGS, FLAG_SAMPLING, compose_display_kernel
from .protocol import KNOBS, MODES, OVERLAYS, Limits, ProtocolError

__all__ = ["ViewerSession", "scene_labels"]

DOF_APERTURE_M = 0.05          # aperture when the page turns depth of field on (and Config() has none)
ORBIT_DEG_PER_PX = 0.3         # camera rotation per CSS pixel of drag
FLY_STEP_REL = 0.01            # eye travel per fly message of unit strength, as a fraction of the scene extent
CONVERGE_FRAMES = 48           # frames still rendered after the last change (temporal history settles)
RING_DEG = 5.0                 # eccentricity ring spacing
ERROR_GAIN = 8.0               # heat-map gain: mean |foveated - reference| of 1/8 is full scale
LATENCY_WINDOW = 2000          # gaze-to-frame latencies kept for the percentiles


def scene_labels(scenes) -> list:
    """The names the page sees for the launch scenes: a built-in or named scene keeps its name, a file path
    becomes its file stem (made unique); the page can only choose among these labels, never send a path."""
    labels, seen = [], set()
    for s in scenes:
        if not isinstance(s, (str, os.PathLike)) or not str(s):
            raise ValueError(f"scene must be a scene name or a file path, got {s!r}")
        base = Path(str(s)).stem if (os.sep in str(s) or Path(str(s)).suffix) else str(s)
        label, k = base, 2
        while label in seen:
            label, k = f"{base}-{k}", k + 1
        seen.add(label)
        labels.append(label)
    return labels


class ViewerSession:
    """One FrameLoop (plus a reference loop when asked) steered by every connected client.

    Args:
        scenes: scene names or mesh paths allowed for this session (the first is shown first).
        width, height: render size in pixels.
        device: Warp device; None = Warp's default.
        gaze_trace: a :class:`foveawarp.gaze_trace.GazeTrace` to replay instead of the mouse, or None.
        timing: per-stage timing of the FrameLoop (default: on for the CPU, off on CUDA, where the frame
            body then runs as a CUDA graph).
        quality: JPEG quality in [10, 100].
        encoder: the JPEG encoder, one of ``JPEG_ENCODERS``: "auto" (default) = simplejpeg when installed (the
            ``viewer`` extra), else Pillow; "simplejpeg" or "pillow" to force one (ValueError when absent).
    """

    def __init__(self, scenes=("cornell",), width: int = 640, height: int = 360, device=None, gaze_trace=None,
                 timing: Optional[bool] = None, quality: int = 80, encoder: str = "auto"):
        self.width, self.height = check_image_size(width, height)
        scenes = list(scenes) if scenes else ["cornell"]
        self._sources = dict(zip(scene_labels(scenes), [str(s) for s in scenes]))
        if not isinstance(quality, int) or isinstance(quality, bool) or not 10 <= quality <= 100:
            raise ValueError(f"quality must be an integer in [10, 100], got {quality!r}")
        self.quality = quality
        self.encoder = resolve_jpeg_encoder(encoder)
        self.device = get_device(device)
        self.trace = gaze_trace
        self.limits = Limits(self.width, self.height, tuple(self._sources), gaze_trace is not None)
        base = Config()
        if timing is None:
            timing = not self.device.is_cuda
        self.knobs = {
            "falloff_deg": base.foveation.falloff_deg,
            "block": int(base.foveation.block),
            "temporal": bool(base.temporal.enabled),
            "ao_samples": int(base.shading.ao_samples),
            "dof": bool(base.dof.enabled),
            "indirect": base.shading.indirect == "lighttree",
            "timing": bool(timing),
            "path": base.shading.integrator == "path",
            "path_filter": base.shading.path_filter == "atrous",
            "path_filter_variance": base.shading.path_filter_guide == "variance",
            "path_history": float(base.shading.path_history),
            "max_depth": int(base.shading.max_depth),
            "spp": int(base.shading.spp),
        }
        self._config = self.config_for(self.knobs)
        # shared state (guarded by _cond)
        self._cond = threading.Condition()
        self.scene = next(iter(self._sources))
        self.mode = "foveated"
        self.overlays = {k: False for k in OVERLAYS}
        self.overlays["gaze"] = gaze_trace is not None
        self.playing = False
        self.gaze_source = "trace" if gaze_trace is not None else "mouse"
        self.gaze = (self.width * 0.5, self.height * 0.5)
        self._gaze_id = 0              # server-side count of gaze messages
        self._gaze_seq = None          # the client's seq of the latest gaze
        self._gaze_t = None            # arrival time (perf_counter) of the latest gaze
        self._orbit = [0.0, 0.0]
        self._fly = np.zeros(3)
        self._reset_camera = False
        self._version = 0
        self._rendered_version = -1
        self._converge_left = 0
        self._clients = 0
        self._stop = False
        # render-thread state
        self._thread: Optional[threading.Thread] = None
        self._publish: Optional[Callable] = None
        self._publish_error: Optional[Callable] = None
        self._scenes: dict = {}
        self._failed_scenes: set = set()
        self._loop = self._ref_loop = None
        self._loop_key = None
        self._camera: Optional[Camera] = None
        self._play_t = 0.0
        self._last_tick = None
        self._trace_t0 = time.perf_counter()
        self._out = self._host = None
        # statistics
        self._stats_lock = threading.Lock()
        self.frames = 0
        self._frame_times: deque = deque(maxlen=240)
        self.latencies: deque = deque(maxlen=LATENCY_WINDOW)       # per rendered gaze (see frame_left)
        self.latencies_msg: deque = deque(maxlen=LATENCY_WINDOW)   # per gaze message
        self._arrivals: deque = deque(maxlen=LATENCY_WINDOW)       # (gaze id, arrival) not yet on a frame
        self._last_left_gaze = 0
        self._stats: dict = {}

    # -- configuration --------------------------------------------------------------------------------
    @staticmethod
    def config_for(knobs: dict) -> Config:
        """The FrameLoop config for the page's knob values (ValueError when a combination is invalid)."""
        base = Config()
        aperture = (base.dof.aperture_m if base.dof.enabled else DOF_APERTURE_M) if knobs["dof"] else 0.0
        return base.with_(
            foveation={"falloff_deg": knobs["falloff_deg"], "block": knobs["block"]},
            temporal={"enabled": knobs["temporal"]},
            shading={"ao_samples": knobs["ao_samples"], "indirect": "lighttree" if knobs["indirect"] else "none",
                     "integrator": "path" if knobs["path"] else "direct", "max_depth": knobs["max_depth"],
                     "spp": knobs["spp"], "path_filter": "atrous" if knobs.get("path_filter") else "none",
                     "path_filter_guide": "variance" if knobs.get("path_filter_variance") else "relative",
                     "path_history": float(knobs.get("path_history", 0.0))},
            dof={"aperture_m": aperture},
        )

    # -- called from the event loop -----------------------------------------------------------------------
    def set_clients(self, n: int) -> None:
        """The number of connected clients; one more than before renders a frame of the current state, so that
        a client joining an idle session gets its first frame (the page maps the mouse through its size)."""
        with self._cond:
            if int(n) > self._clients:
                self._version += 1
            self._clients = int(n)
            self._cond.notify_all()

    def apply(self, msg: dict, t_arrival: Optional[float] = None) -> bool:
        """Apply a validated message (see ``protocol.parse_message``). Returns True when the state every
        client shows changed (the server then broadcasts ``state_message()``). Raises ProtocolError."""
        kind = msg["type"]
        broadcast = False
        with self._cond:
            if kind == "gaze":
                self.gaze = (msg["x"], msg["y"])
                self._gaze_id += 1
                self._gaze_seq = msg.get("seq")
                self._gaze_t = t_arrival if t_arrival is not None else time.perf_counter()
                if self.gaze_source == "mouse":
                    with self._stats_lock:
                        self._arrivals.append((self._gaze_id, self._gaze_t))
            elif kind == "orbit":
                self._orbit[0] += msg["dx"]
                self._orbit[1] += msg["dy"]
                broadcast = self.playing
                self.playing = False
            elif kind == "fly":
                self._fly += (msg["forward"], msg["right"], msg["up"])
                broadcast = self.playing
                self.playing = False
            elif kind == "play":
                self.playing = msg["on"]
                self._last_tick = None
                broadcast = True
            elif kind == "reset_camera":
                self._reset_camera = True
                self.playing = False
                broadcast = True
            elif kind == "mode":
                self.mode = msg["value"]
                broadcast = True
            elif kind == "overlay":
                for k in OVERLAYS:
                    if k in msg:
                        self.overlays[k] = msg[k]
                broadcast = True
            elif kind == "set":
                knobs = dict(self.knobs)
                knobs[msg["knob"]] = msg["value"]
                try:
                    cfg = self.config_for(knobs)
                except ValueError as e:
                    raise ProtocolError(f"set {msg['knob']}: {e}") from None
                self.knobs, self._config = knobs, cfg
                broadcast = True
            elif kind == "scene":
                self.scene = msg["name"]
                self._reset_camera = True
                self.playing = False
                broadcast = True
            elif kind == "gaze_source":
                self.gaze_source = msg["value"]
                broadcast = True
            elif kind == "reset_stats":
                with self._stats_lock:
                    self.latencies.clear()
                    self.latencies_msg.clear()
                    self._frame_times.clear()
            self._version += 1
            self._converge_left = CONVERGE_FRAMES
            self._cond.notify_all()
        return broadcast

    def state_message(self) -> dict:
        """What every client shows besides the frames: scene list, mode, overlays, knobs and their ranges."""
        with self._cond:
            return {
                "type": "state", "width": self.width, "height": self.height, "device": str(self.device),
                "scenes": list(self._sources), "scene": self.scene, "mode": self.mode, "modes": list(MODES),
                "overlays": dict(self.overlays), "playing": self.playing, "gaze_source": self.gaze_source,
                "has_trace": self.trace is not None, "knobs": dict(self.knobs),
                "knob_info": {k: v.describe() for k, v in KNOBS.items()}, "encoder": jpeg_encoder(self.encoder),
            }

    def stats_snapshot(self) -> dict:
        """The latest frame's statistics (``GET /stats.json``)."""
        with self._stats_lock:
            s = dict(self._stats)
            lat = np.asarray(self.latencies, dtype=np.float64)
            lat_msg = np.asarray(self.latencies_msg, dtype=np.float64)
            times = list(self._frame_times)
        s.setdefault("frames", 0)
        s.setdefault("gaze_px", [self.width * 0.5, self.height * 0.5])
        s.setdefault("width", self.width)
        s.setdefault("height", self.height)
        s.setdefault("ms_frame", 0.0)
        s.setdefault("sampling_rate", 0.0)
        s["fps"] = _fps(times)
        s["latency_samples"] = int(lat.size)
        s["latency_ms_p50"] = float(np.percentile(lat, 50)) if lat.size else None
        s["latency_ms_p95"] = float(np.percentile(lat, 95)) if lat.size else None
        s["latency_msg_samples"] = int(lat_msg.size)
        s["latency_msg_ms_p50"] = float(np.percentile(lat_msg, 50)) if lat_msg.size else None
        s["latency_msg_ms_p95"] = float(np.percentile(lat_msg, 95)) if lat_msg.size else None
        s["clients"] = self._clients
        s["encoder"] = self.encoder
        return s

    def frame_left(self, meta: dict, t_left: Optional[float] = None) -> None:
        """A frame has just left for a client (called by the server after the send). Records the gaze-to-frame
        latencies, both in ms from a gaze message's arrival at the server:

        - ``latencies`` (``latency_ms_*``, the issue's definition): to the first frame rendered with that gaze
          leaving; only gazes that a frame used count (a gaze replaced by a newer one before the next frame
          started is never rendered);
        - ``latencies_msg`` (``latency_msg_ms_*``): every gaze message, to the first frame rendered with it or a
          newer gaze leaving (what an eye tracker's sample waits until the screen reflects it or a later one).
        """
        gid = meta.get("gaze_id", 0)
        if gid <= self._last_left_gaze:
            return
        t = time.perf_counter() if t_left is None else t_left
        with self._stats_lock:
            self._last_left_gaze = gid
            if meta.get("gaze_t") is not None:
                self.latencies.append((t - meta["gaze_t"]) * 1e3)
            while self._arrivals and self._arrivals[0][0] <= gid:
                self.latencies_msg.append((t - self._arrivals.popleft()[1]) * 1e3)

    # -- render thread ----------------------------------------------------------------------------------
    def start(self, publish: Callable, publish_error: Optional[Callable] = None) -> None:
        """Start the render thread; ``publish(payload: bytes, meta: dict)`` receives each encoded frame (from
        that thread), ``publish_error(text)`` each render failure.

        One frame is in flight at a time: the thread takes the newest shared state (gaze, camera, knobs),
        renders, encodes and calls ``publish``, and only then takes the state for the next frame. ``publish``
        may block until the frame has left (the server's does, bounded): the send is then part of the frame's
        cycle, so a gaze waits at most for the frame in flight plus its own, and frames are never queued."""
        self._publish, self._publish_error = publish, publish_error
        self._stop = False
        self._thread = threading.Thread(target=self._run, name="foveawarp-render", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 30.0) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def _due(self) -> bool:
        if self._clients <= 0:
            return False
        return (self._version != self._rendered_version or self.playing or self._converge_left > 0
                or self.gaze_source == "trace")

    def _run(self) -> None:
        with wp.ScopedDevice(self.device):
            while True:
                with self._cond:
                    while not self._stop and not self._due():
                        self._cond.wait(timeout=0.5)
                    if self._stop:
                        return
                    snap = self._snapshot()
                try:
                    payload, meta = self._render(snap)
                except Exception as e:  # a failed scene load or render must not end the session
                    with self._cond:
                        if snap["scene"] not in self._scenes:  # it did not load: go back to one that may
                            self._failed_scenes.add(snap["scene"])
                            if self.scene == snap["scene"]:
                                ok = [s for s in self._sources if s not in self._failed_scenes]
                                fallback = next((s for s in ok if s in self._scenes), ok[0] if ok else None)
                                if fallback is not None:
                                    self.scene = fallback
                                    self._version += 1
                        self._converge_left = 0
                    if self._publish_error is not None:
                        self._publish_error(f"render failed: {type(e).__name__}: {e}")
                    time.sleep(0.2)
                    continue
                if self._publish is not None:
                    self._publish(payload, meta)

    def _snapshot(self) -> dict:
        """Copy the shared state for one frame and consume the pending camera moves (lock held)."""
        snap = {
            "version": self._version, "scene": self.scene, "mode": self.mode, "overlays": dict(self.overlays),
            "knobs": dict(self.knobs), "config": self._config, "playing": self.playing,
            "gaze_source": self.gaze_source, "gaze": self.gaze, "gaze_id": self._gaze_id,
            "gaze_seq": self._gaze_seq, "gaze_t": self._gaze_t, "orbit": tuple(self._orbit),
            "fly": self._fly.copy(), "reset_camera": self._reset_camera,
        }
        self._orbit = [0.0, 0.0]
        self._fly[:] = 0.0
        self._reset_camera = False
        self._rendered_version = self._version
        self._converge_left = max(self._converge_left - 1, 0)
        return snap

    def _scene_obj(self, label: str):
        if label not in self._scenes:
            from ..scene import load_scene

            self._scenes[label] = load_scene(self._sources[label])
        return self._scenes[label]

    def _ensure_loops(self, snap: dict):
        from ..frame_loop import FrameLoop

        scene = self._scene_obj(snap["scene"])
        key = (snap["scene"], snap["config"], snap["knobs"]["timing"])
        if key != self._loop_key:
            # policy "foveated": the page's foveated view always shows the foveated frame (the library's "auto"
            # may trace every pixel where that is cheaper; the page's "reference" mode shows that side)
            self._loop = FrameLoop(scene, self.width, self.height, config=snap["config"], device=self.device,
                                   timing=snap["knobs"]["timing"], policy="foveated")
            self._ref_loop = None
            if self._loop_key is None or self._loop_key[0] != snap["scene"]:
                self._camera = scene.camera
                self._play_t = 0.0
            self._loop_key = key
        need_ref = snap["mode"] != "foveated" or snap["overlays"]["error"]
        if need_ref and self._ref_loop is None:
            self._ref_loop = FrameLoop(scene, self.width, self.height, config=snap["config"], device=self.device,
                                       timing=snap["knobs"]["timing"])
        return scene

    def _update_camera(self, scene, snap: dict) -> None:
        now = time.perf_counter()
        if snap["reset_camera"]:
            self._camera = scene.camera
            self._play_t = 0.0
        if snap["playing"]:
            dt = 0.0 if self._last_tick is None else min(now - self._last_tick, 0.25)
            self._play_t += dt
            self._camera = scene.camera_at(self._play_t)
        self._last_tick = now if snap["playing"] else None
        dx, dy = snap["orbit"]
        if dx or dy:
            self._camera = orbit(self._camera, -dx * ORBIT_DEG_PER_PX, -dy * ORBIT_DEG_PER_PX)
        if np.any(snap["fly"]):
            self._camera = fly(self._camera, snap["fly"] * FLY_STEP_REL * scene.extent)

    def _gaze_for(self, snap: dict) -> tuple:
        if snap["gaze_source"] == "trace" and self.trace is not None:
            return self.trace.at(time.perf_counter() - self._trace_t0)
        return snap["gaze"]

    def _display_buffers(self, out_w: int):
        if self._out is None or self._out.shape[1] != out_w:
            shape = (self.height, out_w, 3)
            self._out = wp.zeros(shape, dtype=wp.uint8, device=self.device)
            self._host = (wp.zeros(shape, dtype=wp.uint8, device="cpu", pinned=True) if self.device.is_cuda
                          else self._out)
        return self._out, self._host

    def _render(self, snap: dict):
        t0 = time.perf_counter()
        scene = self._ensure_loops(snap)
        self._update_camera(scene, snap)
        cam, mode, ov = self._camera, snap["mode"], snap["overlays"]
        gaze = self._gaze_for(snap)
        w, h = self.width, self.height
        fov = None
        if mode != "reference":
            fov = self._loop.render(cam, gaze_px=gaze, time=self._play_t)
        ref = None
        if mode != "foveated" or ov["error"]:
            ref = self._ref_loop.render_reference(cam, time=self._play_t, gaze_px=gaze)
        out_w = 2 * w if mode == "side_by_side" else w
        out, host = self._display_buffers(out_w)
        ring_flags = (FLAG_RINGS if ov["rings"] else 0) | (FLAG_GAZE if ov["gaze"] else 0)
        tan_half = math.tan(math.radians(cam.fov_y_deg) * 0.5)
        g = wp.vec2(float(gaze[0]), float(gaze[1]))
        main = fov if fov is not None else ref
        flags = ring_flags
        if fov is not None:
            flags |= (FLAG_SAMPLING if ov["sampling"] else 0) | (FLAG_ERROR if ov["error"] and ref is not None else 0)
        parallel.launch(compose_display_kernel, dim=(h, w),
                        inputs=[main.image, ref.image if ref is not None else main.image, main.sampling_map, g,
                                tan_half, RING_DEG, ERROR_GAIN, flags, 0], outputs=[out], device=self.device)
        if mode == "side_by_side":
            parallel.launch(compose_display_kernel, dim=(h, w),
                            inputs=[ref.image, ref.image, ref.sampling_map, g, tan_half, RING_DEG, ERROR_GAIN,
                                    ring_flags, w],
                            outputs=[out], device=self.device)
        if host is not out:
            wp.copy(host, out)
        wp.synchronize_device(self.device)
        st = main.stats
        stats = _frame_stats(st)
        t1 = time.perf_counter()
        jpeg = encode_jpeg(host.numpy(), self.quality, self.encoder)
        t2 = time.perf_counter()
        with self._stats_lock:
            self.frames += 1
            self._frame_times.append(t2)
            fps = _fps(list(self._frame_times))
            frame_no = self.frames
        stats.update(frames=frame_no, gaze_px=[float(gaze[0]), float(gaze[1])], width=w, height=h,
                     ms_frame=(t1 - t0) * 1e3, ms_encode=(t2 - t1) * 1e3, fps=fps, jpeg_bytes=len(jpeg),
                     scene=snap["scene"], mode=mode, device=str(self.device),
                     gaze_source=snap["gaze_source"])
        if fov is not None and ref is not None:
            stats["reference"] = True
        with self._stats_lock:
            self._stats = stats
        header = {"frame": frame_no, "width": out_w, "height": h, "render_width": w, "render_height": h,
                  "gaze": stats["gaze_px"], "seq": snap["gaze_seq"] if snap["gaze_source"] == "mouse" else None,
                  "stats": stats}
        hb = json.dumps(header, default=_json_default).encode()
        payload = len(hb).to_bytes(4, "little") + hb + jpeg
        meta = {"frame": frame_no, "gaze_id": snap["gaze_id"] if snap["gaze_source"] == "mouse" else 0,
                "gaze_t": snap["gaze_t"] if snap["gaze_source"] == "mouse" else None}
        return payload, meta


# -- camera moves (pure functions of Camera) ----------------------------------------------------------------


def orbit(cam: Camera, yaw_deg: float, pitch_deg: float) -> Camera:
    """Rotate the eye about the target: ``yaw_deg`` about the camera's up vector, ``pitch_deg`` about its right
    vector; the elevation stays at least 5 degrees away from the up vector and its opposite."""
    up = np.asarray(cam.up, dtype=np.float64)
    up /= np.linalg.norm(up)
    target = np.asarray(cam.target, dtype=np.float64)
    off = np.asarray(cam.eye, dtype=np.float64) - target
    r = float(np.linalg.norm(off))
    off = _rotate(off, up, math.radians(yaw_deg))
    right = np.cross(off, up)
    if np.linalg.norm(right) > 1e-12:
        right /= np.linalg.norm(right)
        elev = math.degrees(math.acos(max(-1.0, min(1.0, float(np.dot(off, up)) / r))))
        new_elev = min(max(elev - pitch_deg, 5.0), 175.0)
        off = _rotate(off, right, math.radians(elev - new_elev))
    off *= r / max(float(np.linalg.norm(off)), 1e-30)
    return Camera(eye=tuple(target + off), target=tuple(target), up=cam.up, fov_y_deg=cam.fov_y_deg)


def fly(cam: Camera, step) -> Camera:
    """Move eye and target together by ``step`` = (forward, right, up) in world units along the camera axes."""
    r, u, f = cam.basis()
    d = step[0] * f + step[1] * r + step[2] * u
    return Camera(eye=tuple(np.add(cam.eye, d)), target=tuple(np.add(cam.target, d)), up=cam.up,
                  fov_y_deg=cam.fov_y_deg)


def _rotate(v, axis, angle):
    # Rodrigues' rotation formula
    c, s = math.cos(angle), math.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * float(np.dot(axis, v)) * (1.0 - c)


# -- helpers ------------------------------------------------------------------------------------------------


JPEG_ENCODERS = ("auto", "simplejpeg", "pillow")


def _has_simplejpeg() -> bool:
    try:
        import simplejpeg  # noqa: F401
    except ImportError:
        return False
    return True


def resolve_jpeg_encoder(name: str = "auto") -> str:
    """"simplejpeg" or "pillow" for ``name`` in ``JPEG_ENCODERS`` ("auto": simplejpeg when installed)."""
    if name not in JPEG_ENCODERS:
        raise ValueError(f"encoder must be one of {JPEG_ENCODERS}, got {name!r}")
    if name == "auto":
        return "simplejpeg" if _has_simplejpeg() else "pillow"
    if name == "simplejpeg" and not _has_simplejpeg():
        raise ValueError("encoder 'simplejpeg' needs the simplejpeg package (pip install -e .[viewer])")
    return name


def jpeg_encoder(name: str = "auto") -> str:
    """Which JPEG encoder the frames use, e.g. "simplejpeg 1.9.0, libjpeg-turbo, 4:2:0" or
    "Pillow 13.0.0, libjpeg-turbo 3.2.0, 4:2:0"."""
    name = resolve_jpeg_encoder(name)
    if name == "simplejpeg":
        import simplejpeg

        return f"simplejpeg {getattr(simplejpeg, '__version__', '?')}, libjpeg-turbo, 4:2:0"
    import PIL
    from PIL import features

    turbo = features.version_feature("libjpeg_turbo") if features.check_feature("libjpeg_turbo") else None
    return f"Pillow {PIL.__version__}, " + (f"libjpeg-turbo {turbo}" if turbo else "libjpeg") + ", 4:2:0"


def encode_jpeg(rgb: np.ndarray, quality: int, encoder: str = "auto") -> bytes:
    """(H, W, 3) uint8 -> baseline JPEG bytes, 4:2:0 chroma, no Huffman optimisation.

    simplejpeg (libjpeg-turbo's TurboJPEG API) reads the array in place and releases the GIL for the whole
    encode, so the event loop thread keeps receiving gazes and sending meanwhile; Pillow (fallback) first copies
    the pixels into its own image and re-takes the GIL between parts of the encode."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    if resolve_jpeg_encoder(encoder) == "simplejpeg":
        import simplejpeg

        return simplejpeg.encode_jpeg(rgb, quality=int(quality), colorspace="RGB", colorsubsampling="420",
                                      fastdct=False)
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb, "RGB").save(buf, format="JPEG", quality=int(quality), subsampling="4:2:0", optimize=False)
    return buf.getvalue()


def _frame_stats(st) -> dict:
    """The JSON-able part of ``frame.stats``: rates, counts, ``ms_<stage>`` (the loop's own ``ms_frame``
    becomes ``ms_loop``), the names of the skipped stages."""
    out = {}
    for k in ("sampling_rate", "cache_hit_rate", "rays_traced", "paths_traced", "static_frames", "graph", "strategy"):
        if k in st:
            out[k] = st[k]
    for k, v in st.items():
        if isinstance(k, str) and k.startswith("ms_"):
            out["ms_loop" if k == "ms_frame" else k] = v
    sk = st.get("skipped") or {}
    out["skipped"] = sorted(sk) if isinstance(sk, dict) else []
    return {k: _plain(v) for k, v in out.items()}


def _plain(v):
    """NumPy scalars as Python numbers; non-finite floats as None (JSON has no NaN)."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _fps(times: list) -> float:
    """Frames per second over the last second of frame times (perf_counter)."""
    if len(times) < 2:
        return 0.0
    recent = [t for t in times if t >= times[-1] - 1.0]
    if len(recent) < 2:
        recent = times[-2:]
    span = recent[-1] - recent[0]
    return float((len(recent) - 1) / span) if span > 0 else 0.0


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return str(o)
