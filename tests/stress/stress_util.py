"""Shared code of the stress suite (profiles, the case counter, checks); see conftest.py."""

from __future__ import annotations

import os
from collections import Counter

import numpy as np
from hypothesis import HealthCheck, settings

PROFILES = ("short", "long")
PROFILE = os.environ.get("FOVEAWARP_STRESS", "short").strip().lower() or "short"
if PROFILE not in PROFILES:
    raise ValueError(f"FOVEAWARP_STRESS must be one of {list(PROFILES)}, got {PROFILE!r}")
LONG = PROFILE == "long"

_SUPPRESS = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture,
             HealthCheck.filter_too_much]
settings.register_profile("foveawarp-stress-short", deadline=None, derandomize=True, database=None,
                          suppress_health_check=_SUPPRESS, print_blob=True)
settings.register_profile("foveawarp-stress-long", deadline=None, derandomize=False,
                          suppress_health_check=_SUPPRESS, print_blob=True)
_BASE = settings.get_profile(f"foveawarp-stress-{PROFILE}")

# family -> cases checked in this session (module level: one pytest session per process)
CASES: Counter = Counter()


def examples(short: int, long: int | None = None):
    """Hypothesis settings for a stress test: ``short`` examples in the short profile, ``long`` (default
    10 x short) in the long one. The profile's deadline / derandomize / health checks apply."""
    n = short if not LONG else (long if long is not None else 10 * short)
    return settings(_BASE, max_examples=int(n))


def batch(device, n: int, *, cuda_factor: int = 8, long_factor: int = 2) -> int:
    """Cases packed per launch: ``n`` on the CPU in the short profile, more in the long one and on CUDA."""
    m = int(n) * (long_factor if LONG else 1)
    if str(device).startswith("cuda"):
        m *= cuda_factor
    return m


# -- shared checks -------------------------------------------------------------------------------------------


def assert_finite(name: str, a) -> np.ndarray:
    """``a`` (NumPy or Warp array) holds no NaN / Inf; returns it as NumPy."""
    arr = a.numpy() if hasattr(a, "numpy") and not isinstance(a, np.ndarray) else np.asarray(a)
    if arr.dtype.kind == "f":
        bad = ~np.isfinite(arr)
        if bad.any():
            idx = np.argwhere(bad)[:5].tolist()
            raise AssertionError(f"{name}: {int(bad.sum())} non-finite values of {arr.size}, first at {idx}: "
                                 f"{arr[bad][:5]!r}")
    return arr


def assert_binary(name: str, a) -> np.ndarray:
    arr = np.asarray(a.numpy() if hasattr(a, "numpy") and not isinstance(a, np.ndarray) else a)
    vals = np.unique(arr)
    assert set(vals.tolist()) <= {0, 1}, f"{name}: values outside {{0, 1}}: {vals[:10]!r}"
    return arr


F32_MAX = float(np.finfo(np.float32).max)


def frame_size(device, size) -> tuple:
    """Image size for a frame test: as drawn on the CPU; on CUDA each side above 8 pixels grows 8x (odd sides
    stay odd, so the middle pixel's ray stays on the view axis)."""
    if not str(device).startswith("cuda"):
        return tuple(size)

    def grow(n):
        if n <= 8:
            return n
        return (n - 1) * 8 + 1 if n % 2 else n * 8

    return tuple(grow(int(n)) for n in size)
