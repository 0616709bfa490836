"""The cost policy: which path (foveated or full resolution) each frame of a :class:`FrameLoop` renders.

:class:`CostPolicy` owns the policy's state and decides from the frame times it is fed; it launches nothing and
reads no clock, so it can be driven by synthetic timings. Per frame the caller asks :meth:`CostPolicy.next_frame`
for (path, timed, watched), renders that path, and gives back the frame's time: :meth:`CostPolicy.record` for a
timed measurement frame, :meth:`CostPolicy.watch` for a watched frame of the chosen path.

The rule ("auto"): a measurement every ``PERIOD`` frames renders ``WARM`` untimed + ``TIMED`` timed frames of
each path (fewer later, :meth:`CostPolicy.measurement_length`). When the two medians are not clear-cut (neither
path ``CLEAR`` cheaper) both paths are timed once more in the other order (``WARM_AGAIN`` + ``TIMED`` frames
each), and each path's estimate is the lowest of its blocks' medians; if foveation then wins by ``MARGIN``, the
full path is timed a third time before the choice. Foveation is chosen only when its estimate is at least
``MARGIN`` below full resolution's (within the margin the exact full-resolution frame wins). Between
measurements the chosen path's frames are watched; when the median of ``WATCH`` of them contradicts the choice
(foveated frames no cheaper than the full path's pooled median, or full frames dearer than the foveated one's by
the margin), the next measurement starts at once, at most once per ``RECHECK_MIN`` frames.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from .config import check_choice, show

__all__ = ["CostPolicy", "POLICIES", "PATHS"]

POLICIES = ("auto", "foveated", "full")
PATHS = ("foveated", "full")


def _check_ms(name: str, ms) -> float:
    """A frame time in milliseconds: a finite real number >= 0."""
    try:
        v = float(ms)
    except (TypeError, ValueError):
        v = float("nan")
    if isinstance(ms, (bool, str, bytes)) or not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"{name} must be a finite number of milliseconds >= 0, got {show(ms)}")
    return v


class CostPolicy:
    """The state machine of the cost policy ``mode`` ("auto", "foveated" or "full").

    Args:
        mode: "foveated" always renders the foveated frame, "full" always full resolution, "auto" the cheaper
            path by the rule in this module's docstring.
        by_events: the watch samples one frame in ``WATCH_EVERY`` (CUDA without timing: each watched frame's
            two timing events cost host time) and compares GPU spans (``record(span_ms=...)``) instead of wall
            times; False: every frame of the chosen path is watched by its wall time.
    """

    PERIOD = 600  # frames between two measurements
    WARM = 4  # untimed frames before each timed run of a path (compile, graph capture)
    TIMED = 8  # timed frames per path; the median counts
    MARGIN = 0.05  # foveation is chosen only when at least this fraction cheaper than full resolution
    # later measurements (kernels compiled, graphs captured): 1 untimed frame per path, and only TIMED_CLEAR timed
    # ones when the last measurement was clear-cut (the cheaper path at least CLEAR cheaper): fewer frames of the
    # dearer path each period (a visible stutter at 3x a frame's cost)
    WARM_AGAIN = 1
    TIMED_CLEAR = 4
    CLEAR = 0.25
    WATCH = 16  # watched frames of the chosen path per check
    # by events, one frame in this many is watched: watching every frame made the policy's full frames 1.03-1.07x
    # the reference's (1920x1080, H100)
    WATCH_EVERY = 8
    RECHECK_MIN = 120  # frames after a measurement began before a failed check starts the next one

    def __init__(self, mode: str = "auto", *, by_events: bool = False):
        self.mode = mode
        self.by_events = bool(by_events)
        self.frame = 0  # frames since the last measurement began
        self.samples = {"foveated": [], "full": []}  # (block, ms) of the measurement's timed frames
        self.spans = {"foveated": [], "full": []}  # (block, GPU ms) of the same frames, when given
        self.choice = "foveated"
        self.estimates: dict = {}  # the last decision: estimates, frame, trigger, rechecks, blocks
        # the watch's yardsticks: each path's median over all its timed frames (the decision's estimates take
        # the lower of its blocks' medians, which runs low; the watch's own median of WATCH frames does not)
        self.reference: dict = {}
        self.watched: list = []  # watched frame times of the chosen path since the last check
        self.rechecks = 0
        self._next_trigger: Optional[str] = None
        self.trigger = "first frames"
        self.length = (self.WARM, self.TIMED)  # (untimed, timed) frames per path of this measurement
        self._set_schedule([("foveated", *self.length), ("full", *self.length)])
        self.block = 0  # the schedule's block of the frame next_frame last scheduled

    @property
    def mode(self) -> str:
        return self._mode

    @mode.setter
    def mode(self, value) -> None:
        self._mode = check_choice("policy", value, POLICIES)

    @classmethod
    def measurement_frames(cls) -> int:
        """The most frames the first measurement renders (with its confirmation)."""
        return 2 * (cls.WARM + cls.TIMED) + 3 * (cls.WARM_AGAIN + cls.TIMED)

    # -- per frame -----------------------------------------------------------------------------------------------
    def next_frame(self, frame_index: int, foveation: bool = True) -> tuple:
        """(path of this frame, whether to time it synchronized, whether to watch it). ``frame_index``: the
        loop's frame counter (reported with the decision); ``foveation``: False when the configuration has no
        foveated path (every frame is then full resolution, and nothing is timed)."""
        if self._mode != "auto" or not foveation:
            return ("full" if self._mode == "full" else "foveated"), False, False
        f = self.frame
        self.frame = (f + 1) % self.PERIOD
        if f > self.total and len(self.watched) < self.WATCH:
            # the steady state between measurements with no check due (most frames): the choice, as below
            return self.choice, False, (not self.by_events) or f % self.WATCH_EVERY == 0
        if f == 0:
            self.samples = {"foveated": [], "full": []}
            self.spans = {"foveated": [], "full": []}
            self.watched = []
            self.length = self.measurement_length()
            self._set_schedule([("foveated", *self.length), ("full", *self.length)])
            self.trigger = self._next_trigger or ("first frames" if frame_index == 0 else
                                                  f"every {self.PERIOD} frames")
            self._next_trigger = None
        estimates = None  # the estimates when a block pair ends, computed once
        again = (self.WARM_AGAIN, self.TIMED)
        if f == self.total and len(self.schedule) == 2:
            estimates = self.block_estimates(self.samples)
            if not self.clear_cut(*estimates[0]):
                # not clear-cut: both paths once more, in the other order, before the choice
                self._set_schedule(self.schedule + [("full", *again), ("foveated", *again)])
        elif f == self.total and len(self.schedule) == 4:
            estimates = self.block_estimates(self.samples)
            if self.foveation_wins(*estimates[0]):
                # a close win of foveation: the full path a third time, apart from its back-to-back pair (one
                # transient can slow two adjacent blocks alike: nefertiti 3840x2160 on the H100, 2.01 ms against
                # the reference loop's 1.68)
                self._set_schedule(self.schedule + [("full", *again)])
        if f < self.total:
            k = f
            for b, (path, warm, timed) in enumerate(self.schedule):
                if k < warm + timed:
                    self.block = b
                    return path, k >= warm, False
                k -= warm + timed
        if f == self.total:
            (fov_ms, full_ms), ref = estimates or self.block_estimates(self.samples)
            self.reference = {"foveated_ms": ref[0], "full_ms": ref[1]}
            self.choice = "foveated" if self.foveation_wins(fov_ms, full_ms) else "full"
            self.estimates = {"foveated_ms": fov_ms, "full_ms": full_ms, "measured_at_frame": frame_index,
                              "trigger": self.trigger, "rechecks": self.rechecks, "blocks": len(self.schedule)}
            if self.spans["foveated"] and self.spans["full"]:
                g, ref = self.block_estimates(self.spans)
                self.estimates["foveated_gpu_ms"], self.estimates["full_gpu_ms"] = g
                self.reference["foveated_gpu_ms"], self.reference["full_gpu_ms"] = ref
        # the watch's samples and the estimates it compares them with: GPU spans by events, else wall times
        sfx = "_gpu_ms" if self.by_events else "_ms"
        est = self.reference
        if len(self.watched) >= self.WATCH and "full" + sfx in est:
            m = float(np.median(self.watched))
            self.watched = []
            if self.choice == "foveated":
                wrong, other = m >= est["full" + sfx], ("full", est["full" + sfx])
            else:
                wrong, other = (1.0 - self.MARGIN) * m > est["foveated" + sfx], ("foveated", est["foveated" + sfx])
            if wrong and f >= self.RECHECK_MIN:
                self.rechecks += 1
                self._next_trigger = (f"check: the {self.choice} frames measured {m:.3f} ms (median of "
                                      f"{self.WATCH}) against {other[1]:.3f} ms estimated {other[0]}")
                self.frame = 0
                return self.next_frame(frame_index, foveation)  # the measurement begins with this frame
        return self.choice, False, (not self.by_events) or f % self.WATCH_EVERY == 0

    def record(self, path: str, ms: float, span_ms: Optional[float] = None) -> None:
        """Keep a timed measurement frame of ``path``: its synchronized wall time ``ms`` and (by events) its GPU
        span ``span_ms``, with the schedule's block it belongs to. Times are finite milliseconds >= 0."""
        path = check_choice("path", path, PATHS)
        ms = _check_ms("ms", ms)
        span_ms = None if span_ms is None else _check_ms("span_ms", span_ms)  # both checked before either is kept
        self.samples[path].append((self.block, ms))
        if span_ms is not None:
            self.spans[path].append((self.block, span_ms))

    def watch(self, ms: float) -> None:
        """Add the time of a watched frame of the chosen path (finite milliseconds >= 0)."""
        self.watched.append(_check_ms("ms", ms))

    def skip_reason(self) -> str:
        """Why a full-resolution frame skipped foveation (``stats["skipped"]["foveation"]``)."""
        est = self.estimates
        if self._mode == "full":
            return "policy 'full': every pixel traced"
        if est and self.choice == "full":
            return (f"policy 'auto': full resolution is cheaper here (measured {est['full_ms']:.3f} ms full vs "
                    f"{est['foveated_ms']:.3f} ms foveated)")
        return "policy 'auto': timing the full-resolution path"

    # -- the rule ------------------------------------------------------------------------------------------------
    @property
    def total(self) -> int:
        """Frames of the measurement's schedule in all."""
        return self._total

    def _set_schedule(self, blocks: list) -> None:
        """Make ``blocks`` ((path, untimed, timed frames) in order) the measurement's schedule; its frames in all
        are kept beside it for the per-frame test of whether the measurement is over."""
        self.schedule = blocks
        self._total = sum(w + t for _, w, t in blocks)

    def foveation_wins(self, fov_ms: float, full_ms: float) -> bool:
        """Whether the foveated estimate is at least ``MARGIN`` below full resolution's."""
        return fov_ms < (1.0 - self.MARGIN) * full_ms

    def clear_cut(self, a_ms: float, b_ms: float) -> bool:
        """Whether the cheaper of two estimates is at least ``CLEAR`` cheaper than the other."""
        lo, hi = sorted((a_ms, b_ms))
        return lo < (1.0 - self.CLEAR) * hi

    def measurement_length(self) -> tuple:
        """(untimed, timed) frames per path of the measurement that begins: ``WARM``, ``TIMED`` the first time;
        later ``WARM_AGAIN`` and, when the last estimates were clear-cut, ``TIMED_CLEAR`` timed frames, else
        ``TIMED``."""
        est = self.estimates
        if not est:
            return self.WARM, self.TIMED
        clear = self.clear_cut(est["foveated_ms"], est["full_ms"])
        return self.WARM_AGAIN, (self.TIMED_CLEAR if clear else self.TIMED)

    @staticmethod
    def block_estimates(samples: dict) -> tuple:
        """((foveated, full) decision estimates, (foveated, full) pooled medians) from timed ``samples`` ((block,
        ms) pairs per path): per path the lowest of its blocks' medians, and the median of all its frames (NaN
        for a path without samples)."""
        est, pooled = [], []
        for path in PATHS:
            by_block: dict = {}
            for b, v in samples[path]:
                by_block.setdefault(b, []).append(v)
            est.append(min(float(np.median(v)) for v in by_block.values()) if by_block else float("nan"))
            pooled.append(float(np.median([v for _, v in samples[path]])) if by_block else float("nan"))
        return tuple(est), tuple(pooled)
