"""The warp-lane reductions (kernels/lanes.py) against NumPy: whatever the grouping of lanes the device makes
(a whole warp on CUDA sm_80+, one lane on the CPU), the values folded by the leaders' atomics are the per-key
maxima and the count of flags."""

import numpy as np
import pytest
import warp as wp
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from foveawarp.kernels.lanes import LANE_NONE, lane_count, lane_group_max


@wp.kernel(enable_backward=False)
def _fold_kernel(keys: wp.array(dtype=wp.int32), values: wp.array(dtype=wp.int32), flags: wp.array(dtype=wp.int32),
                 active: wp.array(dtype=wp.int32), out_max: wp.array(dtype=wp.int32),
                 out_count: wp.array(dtype=wp.int32), leaders: wp.array(dtype=wp.int32)):
    i = wp.tid()
    if active[i] == 0:  # diverged lanes: the others reduce without them
        return
    m = lane_group_max(keys[i], values[i])
    if m != LANE_NONE:
        wp.atomic_max(out_max, keys[i], m)
        wp.atomic_add(leaders, 0, 1)
    c = lane_count(flags[i])
    if c > 0:
        wp.atomic_add(out_count, 0, c)


def _run(device, keys, values, flags, active, nkeys):
    arr = lambda a: wp.array(np.asarray(a, np.int32), dtype=wp.int32, device=device)  # noqa: E731
    out_max = wp.full(nkeys, LANE_NONE, dtype=wp.int32, device=device)
    out_count = wp.zeros(1, dtype=wp.int32, device=device)
    leaders = wp.zeros(1, dtype=wp.int32, device=device)
    wp.launch(_fold_kernel, dim=len(keys), inputs=[arr(keys), arr(values), arr(flags), arr(active)],
              outputs=[out_max, out_count, leaders], device=device)
    return out_max.numpy(), int(out_count.numpy()[0]), int(leaders.numpy()[0])


def _expected(keys, values, flags, active, nkeys):
    keys, values, flags, active = (np.asarray(a) for a in (keys, values, flags, active))
    on = active != 0
    want = np.full(nkeys, int(LANE_NONE), np.int64)
    np.maximum.at(want, keys[on], values[on])
    return want.astype(np.int32), int(np.count_nonzero(flags[on]))


def test_lane_reductions_fold_to_the_per_key_maxima(device, rng):
    """Random keys (few: many lanes share one), values across the int32 range, a quarter of the lanes returned
    early; 1000 threads (not a multiple of the warp)."""
    n, nkeys = 1000, 7
    keys = rng.integers(0, nkeys, n)
    values = rng.integers(-2**31 + 1, 2**31 - 1, n)
    values[:5] = [-2**31 + 1, 2**31 - 1, 0, -1, -2]
    flags = rng.integers(0, 3, n) * (rng.random(n) < 0.3)
    active = (rng.random(n) >= 0.25).astype(np.int32)
    got_max, got_count, leaders = _run(device, keys, values, flags, active, nkeys)
    want_max, want_count = _expected(keys, values, flags, active, nkeys)
    np.testing.assert_array_equal(got_max, want_max)
    assert got_count == want_count
    # a group has one leader: at most one per (warp, key) on CUDA, one per lane on the CPU
    assert 1 <= leaders <= int(active.sum())
    if wp.get_device(device).is_cpu:
        assert leaders == int(active.sum())


def test_lanes_in_rows_of_tiles_make_one_leader_per_warp_and_tile(device):
    """The last JFA pass's keys: a warp along a row of 16-pixel tiles. On CUDA (sm_80+) 32 lanes over two tiles
    make two leaders per warp; on the CPU every lane leads."""
    n = 32 * 64
    keys = (np.arange(n) // 16) % 5
    values = np.arange(n) % 97
    flags = (np.arange(n) % 3 == 0).astype(np.int32)
    active = np.ones(n, np.int32)
    got_max, got_count, leaders = _run(device, keys, values, flags, active, 5)
    want_max, want_count = _expected(keys, values, flags, active, 5)
    np.testing.assert_array_equal(got_max, want_max)
    assert got_count == want_count
    dev = wp.get_device(device)
    if dev.is_cpu:
        assert leaders == n
    elif dev.arch >= 80:
        assert leaders == 2 * (n // 32)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(n=st.integers(1, 300), nkeys=st.integers(1, 40), seed=st.integers(0, 2**31 - 1))
def test_lane_reductions_property(device, n, nkeys, seed):
    """Any thread count and key count, on each device (the fixture is only the device's name)."""
    rng = np.random.default_rng(seed)
    keys = rng.integers(0, nkeys, n)
    values = rng.integers(-2**31 + 1, 2**31 - 1, n)
    flags = rng.integers(0, 2, n)
    active = rng.integers(0, 2, n)
    want = _expected(keys, values, flags, active, nkeys)
    got_max, got_count, _ = _run(device, keys, values, flags, active, nkeys)
    np.testing.assert_array_equal(got_max, want[0])
    assert got_count == want[1]


@pytest.mark.parametrize("value", [-2**31 + 1, -1, 0, 2**31 - 1])
def test_a_lone_lane_gets_its_own_value(device, value):
    got_max, got_count, leaders = _run(device, [0], [value], [1], [1], 1)
    assert got_max[0] == value and got_count == 1 and leaders == 1
