"""The bit-test float classification of kernels/fpbits.py against NumPy's isfinite / isnan, over every special
class of float32 (signed zeros, subnormals, the largest finite values, infinities, quiet and signalling NaNs with
payloads) and random bit patterns."""

import numpy as np
import warp as wp

from foveawarp.kernels.fpbits import finite_f32, finite_vec3, nan_f32


@wp.kernel(enable_backward=False)
def _classify(v: wp.array(dtype=wp.float32), fin: wp.array(dtype=wp.int32), nan: wp.array(dtype=wp.int32),
              fin3: wp.array(dtype=wp.int32)):
    i = wp.tid()
    fin[i] = wp.where(finite_f32(v[i]), 1, 0)
    nan[i] = wp.where(nan_f32(v[i]), 1, 0)
    n = v.shape[0]
    fin3[i] = wp.where(finite_vec3(wp.vec3(v[i], v[(i + 1) % n], v[(i + 2) % n])), 1, 0)


def test_bit_tests_equal_numpy(device):
    special = np.array([0x00000000, 0x80000000, 0x00000001, 0x807FFFFF, 0x00800000, 0x7F7FFFFF, 0xFF7FFFFF,
                        0x7F800000, 0xFF800000, 0x7FC00000, 0xFFC00000, 0x7F800001, 0x7FBFFFFF, 0xFF800001,
                        0x7FFFFFFF, 0x3F800000], dtype=np.uint32)
    bits = np.concatenate([special, np.random.default_rng(3).integers(0, 2**32, size=4000, dtype=np.uint64)
                           .astype(np.uint32)])
    vals = bits.view(np.float32)
    n = vals.size
    fin = wp.zeros(n, dtype=wp.int32, device=device)
    nan = wp.zeros(n, dtype=wp.int32, device=device)
    fin3 = wp.zeros(n, dtype=wp.int32, device=device)
    wp.launch(_classify, dim=n, inputs=[wp.array(vals, dtype=wp.float32, device=device)], outputs=[fin, nan, fin3],
              device=device)
    with np.errstate(invalid="ignore"):
        np.testing.assert_array_equal(fin.numpy(), np.isfinite(vals).astype(np.int32))
        np.testing.assert_array_equal(nan.numpy(), np.isnan(vals).astype(np.int32))
        trip = np.stack([vals, np.roll(vals, -1), np.roll(vals, -2)], 1)
        np.testing.assert_array_equal(fin3.numpy(), np.isfinite(trip).all(1).astype(np.int32))
