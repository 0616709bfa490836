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


@wp.func_native(f"*(wp::vec2*){_ADDR} = v;")
def store_vec2(a: wp.array2d(dtype=wp.vec2), y: int, x: int, v: wp.vec2):
    """``a[y, x] = v`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


@wp.func_native(f"return *(const unsigned char*){_ADDR1};")
def load1_u8(a: wp.array(dtype=wp.uint8), i: int) -> wp.uint8:
    """``a[i]`` for 0 <= i < N (unchecked)."""
    ...


@wp.func_native(f"*(float*){_ADDR} = v;")
def store_f32(a: wp.array2d(dtype=float), y: int, x: int, v: float):
    """``a[y, x] = v`` for 0 <= y < H, 0 <= x < W (unchecked)."""
    ...


# -- the 3x3 "all nine taps equal" tests of the Sobel terms, on the CPU ------------------------------------------
# At an interior pixel of a row-contiguous array the three rows' taps are 3 contiguous elements each: compared as
# 64-bit words against the centre repeated, instead of 8 element loads and compares. Where the test does not
# apply (CUDA, a border pixel, other strides) it answers 0 and the caller compares the taps itself.

_ROWS3 = """
#if defined(__CUDA_ARCH__)
    return 0;
#else
    const int W = a.shape[1], H = a.shape[0];
    if (a.strides[1] != {size} || x <= 0 || x >= W - 1 || y < 0 || y >= H) return 0;
    const int ym = y > 0 ? y - 1 : 0;
    const int yp = y < H - 1 ? y + 1 : H - 1;
    const char* base = (const char*)a.data + (size_t)(x - 1) * {size};
    const char* r0 = base + (size_t)ym * (size_t)a.strides[0];
    const char* r1 = base + (size_t)y * (size_t)a.strides[0];
    const char* r2 = base + (size_t)yp * (size_t)a.strides[0];
{body}
#endif
"""

_EQ_VEC3 = _ROWS3.format(size=12, body="""
    const float* c = (const float*)(r1 + 12);
    if (!(c[0] == c[0] && c[1] == c[1] && c[2] == c[2])) return 0;  // NaN: the caller's float compares decide
    unsigned int b0, b1, b2;
    __builtin_memcpy(&b0, r1 + 12, 4);
    __builtin_memcpy(&b1, r1 + 16, 4);
    __builtin_memcpy(&b2, r1 + 20, 4);
    const unsigned long long p0 = (unsigned long long)b0 | ((unsigned long long)b1 << 32);
    const unsigned long long p1 = (unsigned long long)b2 | ((unsigned long long)b0 << 32);
    const unsigned long long p2 = (unsigned long long)b1 | ((unsigned long long)b2 << 32);
    unsigned long long d = 0;
    const char* rows[3] = {r0, r1, r2};
    for (int k = 0; k < 3; ++k) {
        unsigned long long u0, u1, u2, u3;
        unsigned int u4;
        __builtin_memcpy(&u0, rows[k], 8);
        __builtin_memcpy(&u1, rows[k] + 8, 8);
        __builtin_memcpy(&u2, rows[k] + 16, 8);
        __builtin_memcpy(&u3, rows[k] + 24, 8);
        __builtin_memcpy(&u4, rows[k] + 32, 4);
        d |= (u0 ^ p0) | (u1 ^ p1) | (u2 ^ p2) | (u3 ^ p0) | (unsigned long long)(u4 ^ b2);
    }
    return d == 0 ? 1 : 0;""")

_EQ_I32 = _ROWS3.format(size=4, body="""
    unsigned int f;
    __builtin_memcpy(&f, r1 + 4, 4);
    const unsigned long long p = (unsigned long long)f | ((unsigned long long)f << 32);
    unsigned long long d = 0;
    const char* rows[3] = {r0, r1, r2};
    for (int k = 0; k < 3; ++k) {
        unsigned long long u0;
        unsigned int u1;
        __builtin_memcpy(&u0, rows[k], 8);
        __builtin_memcpy(&u1, rows[k] + 8, 4);
        d |= (u0 ^ p) | (unsigned long long)(u1 ^ f);
    }
    return d == 0 ? 1 : 0;""")


@wp.func_native(_EQ_VEC3)
def nine_equal_vec3(a: wp.array2d(dtype=wp.vec3), y: int, x: int) -> int:
    """1 when pixel (x, y) is inside the image's interior columns and its 3x3 neighbourhood (rows clamped) holds
    nine bitwise-equal, non-NaN values, so that every float compare of them with the centre is true; 0 otherwise
    (including always on CUDA and wherever the test does not apply: the caller then compares the taps)."""
    ...


@wp.func_native(_EQ_I32)
def nine_equal_i32(a: wp.array2d(dtype=wp.int32), y: int, x: int) -> int:
    """1 when pixel (x, y) is inside the image's interior columns and its 3x3 neighbourhood (rows clamped) holds
    nine equal values; 0 otherwise (including always on CUDA and wherever the test does not apply)."""
    ...


# -- the same tests for 64 pixels of a row at once (the CPU's sampling rows kernel) ------------------------------
# Bit i of the mask: pixel (x0 + i, y) passes the nine-equal test above (bitwise-equal taps, rows clamped, an
# interior column; for vec3 also a non-NaN centre). Each pixel's test is branch-free over contiguous rows, so the
# compiler runs the loop in SIMD lanes; the bytes are then packed into the mask. A pixel whose bit is 0 is left to
# the per-pixel test, which answers the same for it, so a bit may only be 1 where that test gives 1.

_MASK64 = """
#if defined(__CUDA_ARCH__)
    return 0;
#else
    const int W = a.shape[1], H = a.shape[0];
    if (a.strides[1] != {size} || y < 0 || y >= H) return 0;
    const int ym = y > 0 ? y - 1 : 0;
    const int yp = y < H - 1 ? y + 1 : H - 1;
    const int lo = x0 > 1 ? x0 : 1;
    const int hi = x0 + 63 < W - 2 ? x0 + 63 : W - 2;
    unsigned char fl[64];
    for (int i = 0; i < 64; ++i) fl[i] = 0;
    const {word}* r0 = (const {word}*)((const char*)a.data + (size_t)ym * (size_t)a.strides[0]);
    const {word}* r1 = (const {word}*)((const char*)a.data + (size_t)y * (size_t)a.strides[0]);
    const {word}* r2 = (const {word}*)((const char*)a.data + (size_t)yp * (size_t)a.strides[0]);
{pre}
    for (int x = lo; x <= hi; ++x) {
{body}
    }
    unsigned long long m = 0;
#if defined(__BMI2__)
    for (int i = 0; i < 8; ++i) {
        unsigned long long v;
        __builtin_memcpy(&v, fl + 8 * i, 8);
        m |= (unsigned long long)__builtin_ia32_pext_di(v, 0x0101010101010101ULL) << (8 * i);
    }
#else
    for (int i = 0; i < 64; ++i) m |= (unsigned long long)fl[i] << i;
#endif
    return m;
#endif
"""

_MASK64_I32 = _MASK64.replace("{size}", "4").replace("{word}", "int").replace("{pre}", "").replace("{body}", """
        const int c = r1[x];
        fl[x - x0] = (unsigned char)((r0[x - 1] == c) & (r0[x] == c) & (r0[x + 1] == c) & (r1[x - 1] == c)
                                     & (r1[x + 1] == c) & (r2[x - 1] == c) & (r2[x] == c) & (r2[x + 1] == c));""")

_MASK64_VEC3 = _MASK64.replace("{size}", "12").replace("{word}", "unsigned int").replace("{pre}", """
    // each float word of the pixels lo..hi against its 8 neighbours' same word (3 words apart), non-NaN: one
    // unit-stride loop; a pixel passes when its 3 words do
    unsigned char eq[192];
    const int j0 = 3 * lo, j1 = 3 * hi + 2;
    for (int j = j0; j <= j1; ++j) {
        const unsigned int c = r1[j];
        eq[j - 3 * x0] = (unsigned char)(((c & 0x7fffffffu) <= 0x7f800000u) & (r0[j - 3] == c) & (r0[j] == c)
                                         & (r0[j + 3] == c) & (r1[j - 3] == c) & (r1[j + 3] == c)
                                         & (r2[j - 3] == c) & (r2[j] == c) & (r2[j + 3] == c));
    }""").replace("{body}", """
        fl[x - x0] = (unsigned char)(eq[3 * (x - x0)] & eq[3 * (x - x0) + 1] & eq[3 * (x - x0) + 2]);""")


@wp.func_native(_MASK64_I32)
def nine_equal_mask64_i32(a: wp.array2d(dtype=wp.int32), y: int, x0: int) -> wp.uint64:
    """Bit i: ``nine_equal_i32(a, y, x0 + i)`` for the 64 pixels from ``x0`` (0 past the row, and always on CUDA)."""
    ...


@wp.func_native(_MASK64_VEC3)
def nine_equal_mask64_vec3(a: wp.array2d(dtype=wp.vec3), y: int, x0: int) -> wp.uint64:
    """Bit i: ``nine_equal_vec3(a, y, x0 + i)`` for the 64 pixels from ``x0`` (0 past the row, and always on
    CUDA)."""
    ...
