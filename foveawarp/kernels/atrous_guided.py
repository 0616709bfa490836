"""The variance-guided a-trous iteration (``ShadingConfig.path_filter_guide = "variance"``; the formulas in
:mod:`foveawarp.kernels.atrous`), in a module of its own for its compile options."""

import warp as wp

from .atrous import atrous_pixel

# its 5 x 5 tap loops stay rolled: 72 registers a thread instead of 255 unrolled (sm_90, compiled by NVRTC,
# tools/cuda_registers.py), 3 resident blocks of 256 threads an SM instead of 1
wp.set_module_options({"max_unroll": 1})


@wp.kernel(enable_backward=False)
def atrous_guided_kernel(src: wp.array2d(dtype=wp.vec3), var: wp.array2d(dtype=float),
                         depth: wp.array2d(dtype=float), normal: wp.array2d(dtype=wp.vec3),
                         hit: wp.array2d(dtype=wp.uint8), step: int, dst: wp.array2d(dtype=wp.vec3),
                         var_dst: wp.array2d(dtype=float), row0: int):
    """One variance-guided a-trous iteration (``path_filter_guide = "variance"``): ``src``, ``var`` ->
    ``dst``, ``var_dst`` (the module docstring)."""
    y, x = wp.tid()
    y += row0  # band offset (foveawarp.parallel)
    c, v = atrous_pixel(src, depth, normal, hit, step, x, y, var, 1)
    dst[y, x] = c
    var_dst[y, x] = v
