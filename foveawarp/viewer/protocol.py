"""The viewer's client messages: one JSON object per WebSocket text message, validated here.

``parse_message(text, limits)`` returns a normalized dict or raises :class:`ProtocolError`, whose text goes
back to the client as ``{"type": "error", "message": ...}``; the session goes on. Nothing here imports the
server's libraries, so the rules are testable alone.

Messages (fields beyond those listed are errors):

==============  ==============================================================================================
type            fields
==============  ==============================================================================================
gaze            x, y: gaze in render pixels, finite, in [-width, 2 width] x [-height, 2 height];
                seq (optional): integer in [0, 2**53], echoed in the frames rendered with this gaze
orbit           dx, dy: mouse drag in CSS pixels, finite, each in [-10000, 10000]
fly             forward, right, up: each finite in [-1, 1] (one key-repeat step; scaled by the scene size)
play            on: true / false (the scene's camera path)
reset_camera    (none)
mode            value: "foveated" | "reference" | "side_by_side"
overlay         any of sampling, rings, error, gaze: true / false (at least one)
set             knob: a name of KNOBS; value: in the knob's documented range
scene           name: one of the scenes named at launch
gaze_source     value: "mouse" | "trace" ("trace" only when a gaze trace was given)
reset_stats     (none)
==============  ==============================================================================================
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field

__all__ = ["ProtocolError", "Knob", "KNOBS", "MODES", "Limits", "parse_message", "MAX_MESSAGE_CHARS"]

MAX_MESSAGE_CHARS = 4096
MAX_SEQ = 2**53
MAX_DRAG_PX = 10000.0
MODES = ("foveated", "reference", "side_by_side")
OVERLAYS = ("sampling", "rings", "error", "gaze")
GAZE_SOURCES = ("mouse", "trace")


class ProtocolError(ValueError):
    """A client message that cannot be applied; its text is sent back to the client."""


@dataclass(frozen=True)
class Knob:
    """A setting the page may change. ``kind``: "int", "float", "bool"; ``nullable``: None is allowed
    (meaning the library's default behaviour); [lo, hi] the documented range (``lo_open``: lo excluded)."""

    name: str
    kind: str
    lo: float = 0.0
    hi: float = 0.0
    lo_open: bool = False
    nullable: bool = False
    doc: str = ""

    def describe(self) -> dict:
        d = {"kind": self.kind, "nullable": self.nullable, "doc": self.doc}
        if self.kind != "bool":
            d.update(lo=self.lo, hi=self.hi, lo_open=self.lo_open)
        return d

    def check(self, value):
        if value is None:
            if self.nullable:
                return None
            raise ProtocolError(f"set {self.name}: value must not be null")
        if self.kind == "bool":
            if not isinstance(value, bool):
                raise ProtocolError(f"set {self.name}: value must be true or false, got {_short(value)}")
            return value
        rng = f"{'(' if self.lo_open else '['}{_num(self.lo)}, {_num(self.hi)}]"
        if self.kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                raise ProtocolError(f"set {self.name}: value must be an integer in {rng}, got {_short(value)}")
        elif isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ProtocolError(f"set {self.name}: value must be a finite number in {rng}, got {_short(value)}")
        if value < self.lo or value > self.hi or (self.lo_open and value == self.lo):
            raise ProtocolError(f"set {self.name}: value must be in {rng}, got {_short(value)}")
        return int(value) if self.kind == "int" else float(value)


# The knobs and their documented ranges (the Config fields they set, see foveawarp/config.py).
KNOBS = {
    k.name: k
    for k in (
        Knob("falloff_deg", "float", 0.0, 180.0, lo_open=True, nullable=True,
             doc="FoveationConfig.falloff_deg in (0, 180] degrees; null = thesis normalizer"),
        Knob("block", "int", 1, 64, doc="FoveationConfig.block: jitter block size in pixels, [1, 64]"),
        Knob("temporal", "bool", doc="TemporalConfig.enabled: reuse reprojected history"),
        Knob("ao_samples", "int", 0, 256, doc="ShadingConfig.ao_samples: AO rays per shaded pixel, [0, 256]"),
        Knob("dof", "bool", doc="depth of field: DofConfig.aperture_m = 0.05 m focused at the gaze, or 0"),
        Knob("indirect", "bool", doc='ShadingConfig.indirect: "lighttree" (one-bounce) or "none"'),
        Knob("timing", "bool", doc="FrameLoop(timing=...): per-stage milliseconds (synchronizes each stage)"),
        Knob("path", "bool", doc='ShadingConfig.integrator: "path" (path tracing; indirect off) or '
                                  '"direct"'),
        Knob("path_filter", "bool", doc='ShadingConfig.path_filter: "atrous" (the foveated path-traced frame\'s '
                                         'periphery filtered) or "none"'),
        Knob("path_filter_variance", "bool", doc='ShadingConfig.path_filter_guide: "variance" (the filter\'s '
                                                  'luminance stop from each pixel\'s temporal variance) or '
                                                  '"relative"'),
        Knob("path_history", "float", 0.0, 0.95, doc="ShadingConfig.path_history: the previous frame's weight in "
                                                      "the path-traced periphery, [0, 0.95]; 0 = off"),
        Knob("max_depth", "int", 1, 4096, doc="ShadingConfig.max_depth of the path integrator, [1, 4096]"),
        Knob("spp", "int", 1, 65536, doc="ShadingConfig.spp: paths per traced pixel, [1, 65536]"),
    )
}


@dataclass(frozen=True)
class Limits:
    """What the server allows: render size, the launch scene names, whether a gaze trace is loaded."""

    width: int
    height: int
    scenes: tuple = field(default_factory=tuple)
    has_trace: bool = False


_FIELDS = {
    "gaze": ({"x", "y"}, {"seq"}),
    "orbit": ({"dx", "dy"}, set()),
    "fly": (set(), {"forward", "right", "up"}),
    "play": ({"on"}, set()),
    "reset_camera": (set(), set()),
    "mode": ({"value"}, set()),
    "overlay": (set(), set(OVERLAYS)),
    "set": ({"knob", "value"}, set()),
    "scene": ({"name"}, set()),
    "gaze_source": ({"value"}, set()),
    "reset_stats": (set(), set()),
}
TYPES = tuple(_FIELDS)


def parse_message(text, limits: Limits) -> dict:
    """Validate one client message (a ``str`` holding a JSON object) and return it normalized:
    ``{"type": ..., <fields>}`` with numbers as Python floats / ints. Raises :class:`ProtocolError`."""
    if not isinstance(text, str):
        raise ProtocolError("messages must be JSON text, not binary")
    if len(text) > MAX_MESSAGE_CHARS:
        raise ProtocolError(f"message must be at most {MAX_MESSAGE_CHARS} characters, got {len(text)}")
    try:
        msg = json.loads(text)
    except (ValueError, RecursionError) as e:  # bad JSON, too deep, too many digits
        raise ProtocolError(f"message is not valid JSON: {str(e)[:120]}") from None
    if not isinstance(msg, dict):
        raise ProtocolError(f"message must be a JSON object, got {type(msg).__name__}")
    kind = msg.get("type")
    if not isinstance(kind, str) or kind not in _FIELDS:
        raise ProtocolError(f"type must be one of {list(TYPES)}, got {_short(kind)}")
    required, optional = _FIELDS[kind]
    keys = set(msg) - {"type"}
    missing = required - keys
    if missing:
        raise ProtocolError(f"{kind}: missing field(s) {sorted(missing)}")
    extra = keys - required - optional
    if extra:
        raise ProtocolError(f"{kind}: unknown field(s) {sorted(extra)[:5]}; allowed {sorted(required | optional)}")
    out = {"type": kind}
    if kind == "gaze":
        out["x"] = _number(msg["x"], "gaze x", -limits.width, 2.0 * limits.width)
        out["y"] = _number(msg["y"], "gaze y", -limits.height, 2.0 * limits.height)
        if "seq" in msg:
            seq = msg["seq"]
            if isinstance(seq, bool) or not isinstance(seq, int) or not 0 <= seq <= MAX_SEQ:
                raise ProtocolError(f"gaze seq must be an integer in [0, {MAX_SEQ}], got {_short(seq)}")
            out["seq"] = seq
    elif kind == "orbit":
        out["dx"] = _number(msg["dx"], "orbit dx", -MAX_DRAG_PX, MAX_DRAG_PX)
        out["dy"] = _number(msg["dy"], "orbit dy", -MAX_DRAG_PX, MAX_DRAG_PX)
    elif kind == "fly":
        for k in ("forward", "right", "up"):
            out[k] = _number(msg.get(k, 0.0), f"fly {k}", -1.0, 1.0)
    elif kind == "play":
        out["on"] = _bool(msg["on"], "play on")
    elif kind == "mode":
        out["value"] = _choice(msg["value"], "mode value", MODES)
    elif kind == "overlay":
        if not keys:
            raise ProtocolError(f"overlay: give at least one of {list(OVERLAYS)}")
        for k in keys:
            out[k] = _bool(msg[k], f"overlay {k}")
    elif kind == "set":
        name = msg["knob"]
        if not isinstance(name, str) or name not in KNOBS:
            raise ProtocolError(f"set knob must be one of {list(KNOBS)}, got {_short(name)}")
        out["knob"] = name
        out["value"] = KNOBS[name].check(msg["value"])
    elif kind == "scene":
        out["name"] = _choice(msg["name"], "scene name", limits.scenes)
    elif kind == "gaze_source":
        out["value"] = _choice(msg["value"], "gaze_source value", GAZE_SOURCES)
        if out["value"] == "trace" and not limits.has_trace:
            raise ProtocolError("gaze_source trace: no gaze trace was given at launch (--gaze-trace FILE.csv)")
    return out


def error_message(text: str) -> str:
    """The JSON text sent back for a rejected message."""
    return json.dumps({"type": "error", "message": str(text)[:500]})


def _number(v, name: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ProtocolError(f"{name} must be a number in [{_num(lo)}, {_num(hi)}], got {_short(v)}")
    try:
        f = float(v)
    except OverflowError:
        f = math.inf
    if not math.isfinite(f) or f < lo or f > hi:
        raise ProtocolError(f"{name} must be a finite number in [{_num(lo)}, {_num(hi)}], got {_short(v)}")
    return f


def _bool(v, name: str) -> bool:
    if not isinstance(v, bool):
        raise ProtocolError(f"{name} must be true or false, got {_short(v)}")
    return v


def _choice(v, name: str, choices) -> str:
    if not isinstance(v, str) or v not in choices:
        raise ProtocolError(f"{name} must be one of {list(choices)}, got {_short(v)}")
    return v


def _num(v) -> str:
    return str(int(v)) if float(v).is_integer() else repr(float(v))


def _short(v) -> str:
    try:
        s = json.dumps(v)
    except Exception:  # unserializable or an int too long to print
        s = f"<{type(v).__name__}>"
    return s if len(s) <= 60 else s[:57] + "..."
