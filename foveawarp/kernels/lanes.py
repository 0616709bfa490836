"""Reductions across the lanes of a CUDA warp, in native code, for folding per-pixel values into a few atomics.

A per-pixel kernel that folds a value into a per-tile entry (the largest radius of each screen tile) with one
atomic per pixel queues up to 256 atomics on one address per tile. These reduce first over the lanes of the warp
that are active together and share a key (``__match_any_sync``, then ``__reduce_max_sync`` on sm_80 and later),
and hand the result to one lane of each group (the lowest), so a warp spanning two tiles makes two atomics.

On the CPU (one thread at a time) and on CUDA architectures before sm_80 every lane is its own group: the value
comes back unchanged, and the caller's atomics see the same values one by one. The folded results (maxima, sums)
are the same either way. ``value`` must be above ``LANE_NONE`` (the int32 minimum), which marks the lanes that
are not a group's leader.
"""

import warp as wp

LANE_NONE = wp.constant(-2147483647 - 1)  # what a lane that is not its group's leader gets from lane_group_max


@wp.func_native("""
#if defined(__CUDA_ARCH__) && (__CUDA_ARCH__ >= 800)
    const unsigned active = __activemask();
    const unsigned peers = __match_any_sync(active, key);
    const int m = __reduce_max_sync(peers, value);
    return ((int)(threadIdx.x & 31u) == __ffs(peers) - 1) ? m : (-2147483647 - 1);
#else
    return value;
#endif
""")
def lane_group_max(key: int, value: int) -> int:
    """The largest ``value`` over the lanes of this warp that run this call together and pass the same ``key``,
    returned at the lowest such lane, ``LANE_NONE`` at the others (CUDA, sm_80+). Elsewhere: ``value``."""
    ...


@wp.func_native("""
#if defined(__CUDA_ARCH__) && (__CUDA_ARCH__ >= 800)
    const unsigned active = __activemask();
    const unsigned set = __ballot_sync(active, flag != 0);
    return ((int)(threadIdx.x & 31u) == __ffs(active) - 1) ? __popc(set) : 0;
#else
    return flag != 0 ? 1 : 0;
#endif
""")
def lane_count(flag: int) -> int:
    """How many lanes of this warp that run this call together pass a nonzero ``flag``, returned at the lowest
    of them, 0 at the others (CUDA, sm_80+). Elsewhere: 1 for a nonzero ``flag``, else 0."""
    ...
