"""Stage runners: each allocates its buffers once in ``__init__`` and launches kernels in ``run``;
FrameLoop owns one of each. ``ops`` wraps them (or the kernels) for one-off NumPy calls."""
