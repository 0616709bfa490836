"""Warp kernels only (``@wp.func`` / ``@wp.kernel``); orchestration lives outside this package."""
