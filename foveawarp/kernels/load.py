"""Element loads and stores for the hot per-pixel and tap loops, in native code.

Warp's ``a[y, x]`` forms the address with a negative-index wrap and a 64-bit signed multiply per index (about ten
instructions on the H100; Nsight Compute's instruction counts put most of the Sobel, disc-scan and gather loops
there). These take indices the caller has already bounded to ``0 <= y < shape[0]``, ``0 <= x < shape[1]`` and
form ``data + y * strides[0] + x * strides[1]`` with unsigned 32 x 32 -> 64-bit multiplies: any strides, no wrap.
The element read or written is the same, so results do not change. Not for indices that may be negative or out of
range (no check is made).
"""

import warp as wp

_ADDR1 = "((char*)a.data + (size_t)(unsigned)i * (size_t)(unsigned)a.strides[0])"
_ADDR = "((char*)a.data + (size_t)(unsigned)y * (size_t)(unsigned)a.strides[0] " \
        "+ (size_t)(unsigned)x * (size_t)(unsigned)a.strides[1])"


@wp.func_native(f"return *(const wp::vec3*){_ADDR};")
def load_vec3(a: wp.array2d(dtype=wp.vec3), y: int, x: int) -> wp.vec3:
    """``a[y, x]`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"return *(const int*){_ADDR};")
def load_i32(a: wp.array2d(dtype=wp.int32), y: int, x: int) -> int:
    """``a[y, x]`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"return *(const float*){_ADDR};")
def load_f32(a: wp.array2d(dtype=float), y: int, x: int) -> float:
    """``a[y, x]`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"return *(const wp::vec2*){_ADDR};")
def load_vec2(a: wp.array2d(dtype=wp.vec2), y: int, x: int) -> wp.vec2:
    """``a[y, x]`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"return *(const unsigned char*){_ADDR};")
def load_u8(a: wp.array2d(dtype=wp.uint8), y: int, x: int) -> wp.uint8:
    """``a[y, x]`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"return *(const wp::vec3*){_ADDR1};")
def load1_vec3(a: wp.array(dtype=wp.vec3), i: int) -> wp.vec3:
    """``a[i]`` for 0 <= i < N (unchecked)."""
    ...


@wp.func_native(f"*(wp::vec3*){_ADDR} = v;")
def store_vec3(a: wp.array2d(dtype=wp.vec3), y: int, x: int, v: wp.vec3):
    """``a[y, x] = v`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"*(wp::vec2i*){_ADDR} = v;")
def store_vec2i(a: wp.array2d(dtype=wp.vec2i), y: int, x: int, v: wp.vec2i):
    """``a[y, x] = v`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"*(int*){_ADDR} = v;")
def store_i32(a: wp.array2d(dtype=wp.int32), y: int, x: int, v: int):
    """``a[y, x] = v`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"*(unsigned char*){_ADDR} = v;")
def store_u8(a: wp.array2d(dtype=wp.uint8), y: int, x: int, v: wp.uint8):
    """``a[y, x] = v`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"return *(const int*){_ADDR1};")
def load1_i32(a: wp.array(dtype=wp.int32), i: int) -> int:
    """``a[i]`` for 0 <= i < N (unchecked)."""
    ...


@wp.func_native(f"*(wp::vec3*){_ADDR1} = v;")
def store1_vec3(a: wp.array(dtype=wp.vec3), i: int, v: wp.vec3):
    """``a[i] = v`` for 0 <= i < N (unchecked)."""
    ...


@wp.func_native(f"*(int*){_ADDR1} = v;")
def store1_i32(a: wp.array(dtype=wp.int32), i: int, v: int):
    """``a[i] = v`` for 0 <= i < N (unchecked)."""
    ...


@wp.func_native(f"*(float*){_ADDR} = v;")
def store_f32(a: wp.array2d(dtype=float), y: int, x: int, v: float):
    """``a[y, x] = v`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...
