"""The native thread team of ``foveawarp.parallel`` (the CPU device): workers that wait for bands in native code.

A band-parallel CPU launch is a list of bands, each a call of the kernel's CPU entry point with its own launch
bounds and argument struct. With Python threads, every launch wakes the team's threads through locks, and every
band takes the GIL: at 16 threads a launch that does nothing costs 0.2-0.45 ms (16 cores), several times a
light kernel's own work. Here each worker thread of the team makes one call into native code when it starts
(``team_worker_kernel``) and stays there: it watches a control block for jobs, spinning for a while after its
last job and then napping in short sleeps, so a launch reaches it without a lock, a wake-up or the GIL. The
launching thread posts a job and runs bands itself (``team_run_kernel``), then waits until every band is done.

The control block is 64 int64 words (the caller keeps it alive as long as the workers run):

* word 0: ``generation << 32 | next band`` (the generation counts jobs modulo 2**31). Posting a job first closes
  the word (the new generation with band index 0xffffffff, which no claim accepts and no worker takes for a job),
  then writes the job's fields, then stores the new generation with band 0 (release);
  a thread claims band k of generation g by a compare-and-swap from ``g << 32 | k`` to ``g << 32 | k + 1``, so a
  thread that still holds an older generation can never claim a band of a newer job.
* word 8: bands finished in the current job (the poster resets it before posting and waits until it reaches
  the band count).
* word 16: non-zero asks the workers to return (the team's shutdown).
* words 24-28: the job: entry point, addresses of the arrays of n band bounds and n argument-struct pointers,
  n, and how many workers take part (worker ``slot`` takes part when ``slot`` < that count: one team serves
  launches of any thread count up to its size).
* word 32: the address of a ``usleep``-like function (``int(unsigned int microseconds)``) the workers nap with.
* word 40: how many spin iterations a worker waits after its last job before it starts napping: 50 us naps,
  and after 2000 of them (~0.1-0.2 s without a job) 1 ms naps, so an idle team costs little; the thread that
  posts a job never waits for a napping worker (it runs the bands itself, and a worker joins when it wakes).
* word 48: a testing aid, 0 in use: microseconds the poster naps between writing a job and publishing it (the
  tests hold it up there, as a preempted poster would be, to check that no worker runs a band of the new job with
  the old generation).

The code is for the CPU only: compiled for CUDA (every kernel module is, in the tests) the functions are empty.

Which thread runs a band does not change what the band writes, so the output is the same for every thread
count and schedule (tests/test_parallel.py).
"""

import warp as wp

_PAUSE = """
#if defined(__x86_64__) || defined(__i386__)
        __builtin_ia32_pause();
#elif defined(__aarch64__) || defined(__arm__)
        __asm__ __volatile__("yield");
#endif
"""

_CLAIM = """
        for (;;) {
            long long v = __atomic_load_n(&c[0], __ATOMIC_ACQUIRE);
            if ((v >> 32) != g) break;
            long long k = v & 0xffffffffLL;
            if (k >= n) break;
            if (__atomic_compare_exchange_n(&c[0], &v, v + 1, false, __ATOMIC_ACQ_REL, __ATOMIC_ACQUIRE)) {
                f((void*)b[k], (void*)a[k]);
                __atomic_fetch_add(&c[8], 1LL, __ATOMIC_RELEASE);
            }
        }
"""


@wp.func_native("""
#if !defined(__CUDACC__)
    typedef void (*entry_t)(void*, void*);
    typedef void (*nap_t)(unsigned);  // usleep (its int result unused; Warp defines "int" as a macro)
    long long* c = (long long*)ctl;
    nap_t nap = (nap_t)__atomic_load_n(&c[32], __ATOMIC_RELAXED);
    const long long spin = __atomic_load_n(&c[40], __ATOMIC_RELAXED);
    long long seen = __atomic_load_n(&c[0], __ATOMIC_ACQUIRE) >> 32;
    long long idle = 0;
    for (;;) {
        if (__atomic_load_n(&c[16], __ATOMIC_ACQUIRE) != 0) break;
        const long long w = __atomic_load_n(&c[0], __ATOMIC_ACQUIRE);
        const long long g = w >> 32;
        // nothing new, or a job being written (its word closed: the fields are not complete yet)
        if (g == seen || (w & 0xffffffffLL) == 0xffffffffLL) {
            if (idle < spin) {
""" + _PAUSE + """
            } else if (idle < spin + 2000) {
                nap(50u);
            } else {
                nap(1000u);
            }
            ++idle;
            continue;
        }
        seen = g;
        // the fields of job g (published before its word, release/acquire); if job g has ended and the next one is
        // being written, these reads may mix the two, but then no claim below can succeed (the word's generation
        // moved on when the poster closed it, before writing), so they are never used
        if ((long long)slot >= __atomic_load_n(&c[28], __ATOMIC_RELAXED)) continue;  // not in this job
        idle = 0;
        entry_t f = (entry_t)__atomic_load_n(&c[24], __ATOMIC_RELAXED);
        const unsigned long long* b = (const unsigned long long*)__atomic_load_n(&c[25], __ATOMIC_RELAXED);
        const unsigned long long* a = (const unsigned long long*)__atomic_load_n(&c[26], __ATOMIC_RELAXED);
        const long long n = __atomic_load_n(&c[27], __ATOMIC_RELAXED);
""" + _CLAIM + """
    }
#endif
""")
def team_wait(ctl: wp.uint64, slot: int):
    """Worker ``slot``'s loop: run the bands it claims of every job posted to the control block at ``ctl`` until
    the shutdown word is set (see the module docstring)."""
    ...


@wp.func_native("""
#if !defined(__CUDACC__)
    typedef void (*entry_t)(void*, void*);
    long long* c = (long long*)ctl;
    entry_t f = (entry_t)fn;
    const unsigned long long* b = (const unsigned long long*)bounds;
    const unsigned long long* a = (const unsigned long long*)args;
    const long long n = (long long)count;
    const long long g = ((__atomic_load_n(&c[0], __ATOMIC_RELAXED) >> 32) + 1) & 0x7fffffffLL;  // wraps, stays >= 0
    // close the word first: a worker still holding the previous generation (it may have read the fields just as
    // they change below) can no longer claim a band with it, and no worker takes the new generation until it is
    // published below (acq_rel: every claim of the previous job is ordered before the writes that follow)
    __atomic_exchange_n(&c[0], (g << 32) | 0xffffffffLL, __ATOMIC_ACQ_REL);
    __atomic_store_n(&c[24], (long long)fn, __ATOMIC_RELAXED);
    __atomic_store_n(&c[25], (long long)bounds, __ATOMIC_RELAXED);
    __atomic_store_n(&c[26], (long long)args, __ATOMIC_RELAXED);
    __atomic_store_n(&c[27], n, __ATOMIC_RELAXED);
    __atomic_store_n(&c[28], (long long)workers, __ATOMIC_RELAXED);
    __atomic_store_n(&c[8], 0LL, __ATOMIC_RELAXED);
    const long long delay = __atomic_load_n(&c[48], __ATOMIC_RELAXED);
    if (delay > 0) {  // a testing aid: the poster held up here, as if preempted (0 in use)
        typedef void (*nap_t)(unsigned);
        ((nap_t)__atomic_load_n(&c[32], __ATOMIC_RELAXED))((unsigned)delay);
    }
    __atomic_store_n(&c[0], g << 32, __ATOMIC_RELEASE);  // publish: band 0 of generation g
""" + _CLAIM + """
    while (__atomic_load_n(&c[8], __ATOMIC_ACQUIRE) < n) {
""" + _PAUSE + """
    }
#endif
""")
def team_post(ctl: wp.uint64, fn: wp.uint64, bounds: wp.uint64, args: wp.uint64, count: int, workers: int):
    """Post a job of ``count`` bands (entry point ``fn``; ``bounds`` and ``args``: addresses of arrays of
    ``count`` pointers) for the first ``workers`` workers, run the bands this thread claims, and return when
    every band is done."""
    ...


@wp.kernel(enable_backward=False)
def team_worker_kernel(ctl: wp.uint64, slot: int, row0: int):
    """A worker thread's one call (dim 1, the CPU device; ``row0``, unused, is the trailing argument
    ``parallel``'s packing expects): returns at the team's shutdown."""
    team_wait(ctl, slot)


@wp.kernel(enable_backward=False)
def team_run_kernel(ctl: wp.uint64, fn: wp.uint64, bounds: wp.uint64, args: wp.uint64, count: int, workers: int,
                    row0: int):
    """The launching thread's call for one band-parallel launch (dim 1, the CPU device)."""
    team_post(ctl, fn, bounds, args, count, workers)
