"""Numerical stress suite: profiles, the executed-case counter and shared checks.

Profiles (environment variable ``FOVEAWARP_STRESS``):

* ``short`` (default; CI): deterministic examples (``derandomize=True``, no example database), sized so the
  whole suite runs in well under 3 minutes on one CPU core while still executing more than 10,000 cases.
* ``long``: random examples (a new draw every run, failures kept in the example database), about ten times
  as many examples and larger batches. Run it explicitly::

      FOVEAWARP_STRESS=long python -m pytest -m stress tests/stress

Every test is marked ``stress`` (``-m stress`` selects the suite, ``-m "not stress"`` skips it). A "case" is
one independently generated input whose outputs a test checked (a gaze, a cache-test pixel with its own
inputs, a seed mask, a lens + depth pair, a receiver point, a rendered frame); cheap cases are packed many to
a kernel launch. Each test adds the number it actually checked to a session counter, and the terminal
summary prints the total per family, e.g. ``stress: 12345 cases executed (profile short)``. On CUDA devices
the batches are larger (``batch``).
"""

from __future__ import annotations

import json
import os

import pytest

from stress_util import CASES, PROFILE


class CaseRecorder:
    """``cases.add(family, n)`` after a test has checked ``n`` cases of ``family``."""

    def add(self, family: str, n: int = 1) -> None:
        CASES[family] += int(n)


@pytest.fixture
def cases() -> CaseRecorder:
    return CaseRecorder()


def pytest_collection_modifyitems(config, items):
    here = os.path.dirname(os.path.abspath(__file__))
    for item in items:
        if str(item.path).startswith(here + os.sep):
            item.add_marker(pytest.mark.stress)


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    total = sum(CASES.values())
    if not CASES:
        return
    tr = terminalreporter
    tr.write_line("")
    for fam in sorted(CASES):
        tr.write_line(f"stress:   {fam:<40s} {CASES[fam]:>8d}")
    tr.write_line(f"stress: {total} cases executed (profile {PROFILE})")
    path = os.environ.get("FOVEAWARP_STRESS_REPORT")
    if path:
        with open(path, "w") as f:
            json.dump({"profile": PROFILE, "total": total, "families": dict(sorted(CASES.items()))}, f, indent=1)
