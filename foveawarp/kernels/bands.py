"""The CPU band dispatcher of ``foveawarp.parallel``: one call per thread that runs bands until none is left.

A band-parallel CPU launch is a list of bands, each a call of the kernel's CPU entry point with its own launch
bounds and argument struct. Taking each band from Python costs every band two hand-offs of the GIL (the ctypes
call releases it; the next Python step takes it back): at 16 threads, with four bands per thread, 0.44 ms per
launch for an empty kernel (``benchmarks/cpu_launches.py``'s machine, session 18). ``band_dispatch_kernel`` is
called once per thread and launch instead: it claims band indices from a shared counter with an atomic
fetch-and-add, in native code, and calls the entry point for each, so a thread takes the GIL once per launch.
Which thread runs a band does not change what the band writes, so the output is the same for every thread count
and schedule.
"""

import warp as wp


@wp.func_native("""
    typedef void (*entry_t)(void*, void*);
    entry_t f = (entry_t)fn;
    const unsigned long long* b = (const unsigned long long*)bounds;
    const unsigned long long* a = (const unsigned long long*)args;
    int* c = (int*)counter;
    for (;;) {
        int k = __atomic_fetch_add(c, 1, __ATOMIC_RELAXED);
        if (k >= n) break;
        f((void*)b[k], (void*)a[k]);
    }
""")
def run_bands(fn: wp.uint64, bounds: wp.uint64, args: wp.uint64, n: int, counter: wp.uint64):
    """Call entry point ``fn`` with (``bounds[k]``, ``args[k]``) for every band index k in [0, n) that this thread
    claims from ``*counter`` (an int32 set to 0 before the threads start); ``bounds`` and ``args`` are the
    addresses of arrays of n pointers."""
    ...


@wp.kernel(enable_backward=False)
def band_dispatch_kernel(fn: wp.uint64, bounds: wp.uint64, args: wp.uint64, n: int, counter: wp.uint64, row0: int):
    """One thread's share of a band-parallel CPU launch (``run_bands``); launched with dim 1 on the CPU device only
    (``row0``, unused, is the trailing argument ``parallel``'s packing expects)."""
    run_bands(fn, bounds, args, n, counter)
