"""Recorded eye-tracking traces: a CSV with the columns ``t_s,x_px,y_px``, replayed by time.

Used by ``foveawarp view --gaze-trace`` (instead of the mouse) and by ``render`` / ``demo`` (instead of their
built-in moving gaze).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .config import check_finite, show

__all__ = ["GazeTrace", "load_gaze_trace"]

COLUMNS = ("t_s", "x_px", "y_px")
MAX_ROWS = 10_000_000


class GazeTrace:
    """Gaze samples ``(t_s, x_px, y_px)`` with non-decreasing, finite times and finite positions.

    ``at(t)`` interpolates linearly between samples; before the first sample it holds the first position.
    With ``loop=True`` (the default) a time past the last sample wraps around (period = last - first time);
    with ``loop=False`` it holds the last position.
    """

    def __init__(self, t_s, x_px, y_px, *, source: str = "trace"):
        t = np.asarray(t_s, dtype=np.float64).reshape(-1)
        x = np.asarray(x_px, dtype=np.float64).reshape(-1)
        y = np.asarray(y_px, dtype=np.float64).reshape(-1)
        if not (t.shape == x.shape == y.shape) or t.size == 0:
            raise ValueError(f"gaze trace {source} must hold at least one row of t_s,x_px,y_px, "
                             f"got {t.size} rows")
        for name, a in (("t_s", t), ("x_px", x), ("y_px", y)):
            bad = ~np.isfinite(a)
            if bad.any():
                i = int(np.argmax(bad))
                raise ValueError(f"gaze trace {source} column {name} must hold finite numbers, got {show(a[i])} "
                                 f"at row {i + 1}")
        if t.size > 1 and np.any(np.diff(t) < 0):
            i = int(np.argmax(np.diff(t) < 0)) + 1
            raise ValueError(f"gaze trace {source} column t_s must be non-decreasing, got {t[i]!r} after "
                             f"{t[i - 1]!r} at row {i + 1}")
        self.t, self.x, self.y = t, x, y
        self.source = source

    def __len__(self) -> int:
        return int(self.t.size)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    def at(self, t: float, *, loop: bool = True) -> tuple:
        """The gaze ``(x_px, y_px)`` at time ``t`` seconds (finite)."""
        t = check_finite("t", t)
        if loop and self.duration_s > 0.0:
            t = self.t[0] + math.fmod(t - self.t[0], self.duration_s)
            if t < self.t[0]:
                t += self.duration_s
        return float(np.interp(t, self.t, self.x)), float(np.interp(t, self.t, self.y))


def load_gaze_trace(path) -> GazeTrace:
    """Read a CSV gaze trace. The first line may be the header ``t_s,x_px,y_px`` (columns in any order when a
    header names them); without a header the three columns are taken in that order. Blank lines and lines
    starting with ``#`` are ignored. Raises ``ValueError`` naming the file and row for anything else."""
    if not isinstance(path, (str, os.PathLike)):
        raise ValueError(f"gaze trace path must be a file path, got {show(path)}")
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"gaze trace {str(path)!r} does not exist or is not a file")
    order = [0, 1, 2]
    rows = []
    first = True
    with p.open("r", encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = [c.strip() for c in s.split(",")]
            header = first and not _is_number(parts[0])
            first = False
            if header:
                names = [c.lower() for c in parts]
                missing = [c for c in COLUMNS if c not in names]
                if missing:
                    raise ValueError(f"gaze trace {str(path)!r} header must name the columns {list(COLUMNS)}, "
                                     f"got {parts}")
                order = [names.index(c) for c in COLUMNS]
                continue
            if len(parts) < 3:
                raise ValueError(f"gaze trace {str(path)!r} row {lineno} must have 3 columns t_s,x_px,y_px, "
                                 f"got {s!r}")
            try:
                rows.append([float(parts[i]) for i in order])
            except (ValueError, IndexError):
                raise ValueError(f"gaze trace {str(path)!r} row {lineno} must hold numbers, got {s!r}") from None
            if len(rows) > MAX_ROWS:
                raise ValueError(f"gaze trace {str(path)!r} must have at most {MAX_ROWS} rows")
    if not rows:
        raise ValueError(f"gaze trace {str(path)!r} holds no samples")
    a = np.asarray(rows, dtype=np.float64)
    return GazeTrace(a[:, 0], a[:, 1], a[:, 2], source=repr(str(path)))


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False
