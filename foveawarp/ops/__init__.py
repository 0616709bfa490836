"""Stage functions: NumPy (or Warp) arrays in, NumPy arrays out, running the same kernels as FrameLoop.

Each submodule holds the ops of one stage; this package re-exports them.
"""

from __future__ import annotations

import importlib
import importlib.util

__all__: list[str] = []

for _name in ("geometry", "sampling", "reorder", "reconstruct", "dof", "indirect", "path"):
    if importlib.util.find_spec(f"{__name__}.{_name}") is not None:
        _mod = importlib.import_module(f"{__name__}.{_name}")
        for _sym in getattr(_mod, "__all__", []):
            globals()[_sym] = getattr(_mod, _sym)
            __all__.append(_sym)
