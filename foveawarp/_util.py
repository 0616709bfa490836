"""Small shared helpers: device resolution, array conversion, warp init, launch shapes."""

from __future__ import annotations

import numpy as np
import warp as wp

_initialized = False


def init_warp(quiet: bool = True) -> None:
    """Initialise Warp once (quietly unless asked)."""
    global _initialized
    if not _initialized:
        if quiet:
            wp.config.quiet = True
        wp.init()
        _initialized = True


def get_device(device=None) -> "wp.context.Device":
    """Resolve ``device`` (None, a string such as "cpu" / "cuda:0", or a Warp device) to a Warp device.

    Raises ValueError naming the device and the available ones when it does not exist.
    """
    init_warp()
    if device is not None and not isinstance(device, str) and hasattr(device, "is_cuda"):
        return device
    try:
        return wp.get_device(device)
    except Exception:
        names = [d.alias for d in wp.get_devices()]
        raise ValueError(f"device must be one of {names} (or None for the default), got {device!r}") from None


def as_wp(a, dtype, device, *, name: str = "array", ndim: int | None = None, shape=None):
    """Convert a NumPy or Warp array to a Warp array of ``dtype`` on ``device`` (copy only when needed)."""
    dev = get_device(device)
    if isinstance(a, wp.array):
        if a.dtype == dtype and a.device == dev:
            return a
        a = a.numpy()
    arr = np.asarray(a)
    if shape is not None and tuple(arr.shape) != tuple(shape):
        raise ValueError(f"{name} must have shape {tuple(shape)}, got {tuple(arr.shape)}")
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name} must have {ndim} dimensions, got shape {tuple(arr.shape)}")
    np_dtype = wp.dtype_to_numpy(getattr(dtype, "_wp_scalar_type_", dtype))
    return wp.array(np.ascontiguousarray(arr, dtype=np_dtype), dtype=dtype, device=dev)


def to_numpy(a) -> np.ndarray:
    return a.numpy() if isinstance(a, wp.array) else np.asarray(a)


def check_image_size(width, height) -> tuple[int, int]:
    from .config import check_int_range

    w = check_int_range("width", width, 1, 16384)
    h = check_int_range("height", height, 1, 16384)
    return w, h


# -- the warp-block thread order of per-pixel CUDA launches (kernels/order.py) ----------------------------------
ORDER_WIDTHS = (1, 2, 4, 8, 16, 32)


def order_wlog2(block_width: int) -> int:
    """log2 of a block width in ``ORDER_WIDTHS`` (pixels; the block is 32 / width high)."""
    if not isinstance(block_width, int) or isinstance(block_width, bool) or block_width not in ORDER_WIDTHS:
        raise ValueError(f"block_width must be one of {ORDER_WIDTHS}, got {block_width!r}")
    return int(block_width).bit_length() - 1


def check_order_width(name: str, value) -> "int | None":
    """A stage's ``order_width`` (0: the plain (H, W) launch; else a block width of ``ORDER_WIDTHS``): the log2 of
    the width, None for 0; a ValueError naming ``name`` otherwise."""
    if isinstance(value, bool) or not isinstance(value, int) or (value != 0 and value not in ORDER_WIDTHS):
        raise ValueError(f"{name} must be 0 (the row launch) or one of {ORDER_WIDTHS}, got {value!r}")
    return None if value == 0 else order_wlog2(value)


def tile_order_threads(height: int, width: int, block_width: int = 8) -> int:
    """Threads of a "tiles" launch over an (height, width) image: whole blocks ``block_width`` x
    ``32 / block_width`` covering it."""
    bh = 32 // block_width
    return -(-int(height) // bh) * -(-int(width) // block_width) * 32
