"""Band-parallel launches on the CPU device: the one place that splits a launch over threads.

Warp runs a CPU launch in the calling thread. :func:`launch` runs a kernel whose last argument is
``row0: int`` (its first launch index is ``wp.tid()[0] + row0``) as bands of its first dimension (image rows or
ranges of a work list), one call of the kernel's CPU entry point per band on a team of threads: the native team
(:class:`_NativeTeam`, ``kernels/team.py``: workers that wait for bands in native code, so a launch reaches them
without a lock, a wake-up or the GIL) where the launch's threads fit the usable cores, else the Python team
(:class:`_Team`: the Warp CPU call releases the GIL, so its bands run on several cores too). On CUDA, or with one
thread, it is one ``wp.launch`` with ``row0 = 0``.

Which kernels may be split: each thread of the kernel writes only its own element(s) of its band (reads may
be anywhere: JFA, Sibson and Sobel neighbourhoods read the whole arrays, which no band writes in the same
launch). Warp's CPU atomics are plain read-modify-writes (the CPU device was single-threaded), so kernels that
accumulate with atomics into shared locations (counters, scatter sums) and tile kernels (``launch_tiled``: on
x86-64 Warp keeps the CPU tile storage in a per-module static) are not split: their stages call
``wp.launch`` / ``wp.launch_tiled`` directly. A band's results do not depend on the band bounds, so the output
is bit-identical for every thread count (tests/test_parallel.py).

Thread-safety of concurrent CPU launches (Warp 1.19): the generated CPU entry point receives the launch index
as an argument (no static thread index; the old "Using Warp with python threading" crash came from one), and
its only static is the tile-storage pointer that non-tile kernels store but never read. The module is loaded
on the calling thread before the bands start.

Thread count: ``threads=`` of :func:`launch`; else the innermost :func:`cpu_threads` context (FrameLoop's
``cpu_threads``); else the environment variable ``FOVEAWARP_CPU_THREADS``; else the usable cores.
"""

from __future__ import annotations

import _thread
import contextlib
import contextvars
import functools
import os
import threading
import weakref
from typing import Optional, Sequence

import numpy as np
import warp as wp

try:  # Warp internals for cheap band launches (argument packing once per launch, not once per band)
    from warp._src.context import _build_launch_bounds_from_tuple as _bounds_of
    from warp._src.context import invoke as _invoke
except ImportError:  # another Warp layout: every band is a full wp.launch (slower, same results)
    _bounds_of = _invoke = None
import ctypes

__all__ = ["launch", "launch_rows", "use_row_kernels", "ROW_KERNELS", "Relaunch", "cpu_threads", "default_cpu_threads",
           "resolve_cpu_threads", "bands", "MAX_THREADS", "ENV_VAR", "shutdown_native_team", "record", "recording_active", "CpuProgram"]

ENV_VAR = "FOVEAWARP_CPU_THREADS"
MAX_THREADS = 1024
# launches with fewer work items than this per band run in fewer bands (a band's Python launch costs ~20 us)
MIN_ITEMS_PER_BAND = int(os.environ.get("FOVEAWARP_CPU_MIN_BAND_ITEMS", "2048") or 2048)  # 0: split every launch
# pack a launch's arguments once and run the bands through Warp's CPU entry point (False: one wp.launch per band)
FAST_BANDS = True
# run the bands on the native team (kernels/team.py: workers that wait in native code, no lock, wake-up or GIL
# per launch) when the launch's threads fit the usable cores; False, or FOVEAWARP_CPU_NATIVE_TEAM=0: the Python
# team (_Team). Set to False by the first launch if the native team cannot be built.
NATIVE_TEAM = os.environ.get("FOVEAWARP_CPU_NATIVE_TEAM", "1").strip() != "0"
# spin iterations (a pause instruction each) a native worker waits after a job before it naps in 50 us sleeps
NATIVE_SPIN = 50000
# bands per thread: the threads take bands from a shared queue, so rows of unequal cost (sky above, geometry
# below) even out; each band costs a few microseconds of Python under the GIL. None: 4 (16 cores, cornell
# 640x360 at 3264d20: 8.23 ms a frame with 4 bands per thread, 8.96 ms with 2)
OVERSPLIT: Optional[int] = None


def bands_per_thread(n: int) -> int:
    return int(OVERSPLIT) if OVERSPLIT is not None else 4

_context: contextvars.ContextVar[Optional[int]] = contextvars.ContextVar("foveawarp_cpu_threads", default=None)
_teams: dict = {}
_team_lock = threading.Lock()
_checked: dict = {}


def usable_cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def resolve_cpu_threads(value, name: str = "cpu_threads") -> int:
    """``value`` as a thread count in [1, MAX_THREADS]; None = the default (env var, else usable cores)."""
    from .config import check_int_range

    if value is None:
        return default_cpu_threads()
    return check_int_range(name, value, 1, MAX_THREADS)


def default_cpu_threads() -> int:
    """``FOVEAWARP_CPU_THREADS`` (an integer in [1, MAX_THREADS]) when set and not empty, else the usable
    cores. A bad value raises ValueError naming the variable."""
    raw = os.environ.get(ENV_VAR, "").strip()
    if not raw:
        return usable_cores()
    try:
        v = int(raw)
    except ValueError:
        v = None
    if v is None or not 1 <= v <= MAX_THREADS:
        raise ValueError(f"{ENV_VAR} must be an integer in [1, {MAX_THREADS}], got {raw!r}")
    return v


@contextlib.contextmanager
def cpu_threads(n: Optional[int]):
    """Within the block, :func:`launch` calls without ``threads=`` use ``n`` threads (None: the default)."""
    token = _context.set(None if n is None else resolve_cpu_threads(n))
    try:
        yield
    finally:
        _context.reset(token)


def current_cpu_threads() -> int:
    n = _context.get()
    return default_cpu_threads() if n is None else n


class _Team:
    """``n - 1`` daemon threads that run one job at a time beside the calling thread.

    A job is a callable each member calls once (it takes bands from a shared iterator until none is left: a
    list iterator's ``next`` holds the GIL, so no lock is needed). The hand-off is plain ``_thread`` locks: the
    caller releases each member's start lock, and the last member to finish releases the done lock (a
    ``ThreadPoolExecutor`` submit + ``result`` per member cost ~10-20 us of Python each, at 16 threads a few
    hundred microseconds per launch). ``busy`` keeps concurrent launches from different Python threads apart:
    a launch that finds the team busy runs its bands in its own thread."""

    def __init__(self, n: int):
        self.busy = _thread.allocate_lock()
        self._go = []
        self._done = _thread.allocate_lock()
        self._done.acquire()
        self._count_lock = _thread.allocate_lock()
        self._active = 0
        self._job = None
        self._error = None
        for i in range(max(0, n - 1)):
            go = _thread.allocate_lock()
            go.acquire()
            self._go.append(go)
            t = threading.Thread(target=self._member, args=(go,), name=f"foveawarp-cpu-{i}", daemon=True)
            t.start()

    def _member(self, go) -> None:
        while True:
            go.acquire()
            try:
                self._job()
            except BaseException as e:  # noqa: BLE001 - handed to the caller
                self._error = e
            with self._count_lock:
                self._active -= 1
                last = self._active == 0
            if last:
                self._done.release()

    def run(self, job, members: int) -> None:
        """``job()`` on ``members`` threads (the caller and ``members - 1`` team threads); returns when all
        are done, raising the first error a team thread met."""
        members = min(members, len(self._go) + 1)
        self._job, self._error = job, None
        self._active = members - 1
        for go in self._go[:members - 1]:
            go.release()
        try:
            job()
        finally:
            if members > 1:
                self._done.acquire()
            self._job = None
        if self._error is not None:
            e, self._error = self._error, None
            raise e


def _team(n: int) -> _Team:
    """The team of ``n - 1`` threads that work beside the calling thread at ``n`` threads."""
    with _team_lock:
        t = _teams.get(n)
        if t is None:
            t = _teams[n] = _Team(n)
        return t


class _NativeTeam:
    """``size`` worker threads that each made one call into native code (``kernels/team.py``) and wait there
    for jobs; :meth:`run` posts one from the calling thread, which runs bands too. One team serves launches of
    any thread count up to ``size + 1``; ``busy`` keeps concurrent launches from different Python threads
    apart, as with :class:`_Team`."""

    def __init__(self, size: int, dev):
        from .kernels.team import team_run_kernel, team_worker_kernel

        self.busy = _thread.allocate_lock()
        self.size = int(size)
        self.ctl = (ctypes.c_int64 * 64)()
        libc = ctypes.CDLL(None)
        self.ctl[32] = ctypes.cast(libc.usleep, ctypes.c_void_p).value
        self.ctl[40] = int(NATIVE_SPIN)
        addr = ctypes.addressof(self.ctl)
        for k in (team_run_kernel, team_worker_kernel):
            k.module.load(dev, 1)
        fwd, _, args, kdim = _record(team_run_kernel, (1,), [addr, 0, 0, 0, 0, 0], [], dev)
        self._run = (fwd, ctypes.byref(_bounds_of((1,), kdim)), args, ctypes.byref(args))
        self._keep = [self._run]
        self.threads = []
        try:
            for slot in range(self.size):
                wf, _, wargs, wdim = _record(team_worker_kernel, (1,), [addr, slot], [], dev)
                bounds = _bounds_of((1,), wdim)
                self._keep.append((bounds, wargs))
                t = threading.Thread(target=wf, args=(ctypes.byref(bounds), ctypes.byref(wargs)), daemon=True,
                                     name=f"foveawarp-native-{slot}")
                t.start()
                self.threads.append(t)
        except BaseException:  # e.g. no more threads: the started workers return, the block outlives them
            self.shutdown()
            raise

    def run(self, tables, workers: int) -> None:
        """Run the bands of ``tables`` (``_Bands.tables``) on this thread and ``workers`` team workers."""
        fwd, bounds, args, args_ref = self._run
        args.fn, args.bounds, args.args, args.count = tables[2], tables[3], tables[4], tables[5]
        args.workers = int(workers)
        fwd(bounds, args_ref)

    def shutdown(self, timeout: float = 2.0) -> None:
        """Ask the workers to return and wait for them (at exit, before Warp unloads its modules). A team whose
        workers have not all returned within ``timeout`` is kept alive (``_retired``): they still read its
        control block."""
        self.ctl[16] = 1
        for t in self.threads:
            t.join(timeout)
        if any(t.is_alive() for t in self.threads):
            _retired.append(self)


_native = None
_exit_hook = False
_retired: list = []  # shut-down native teams with a worker still running (never freed)


def _after_fork_in_child() -> None:
    """A forked child has none of the parent's team threads: forget the teams and their locks (a lock held by a
    parent thread at the fork would stay held); the child's first band launch starts its own."""
    global _teams, _team_lock, _native
    _teams, _team_lock, _native = {}, threading.Lock(), None
    # a parent thread's recording (parallel.record) does not exist here: drop it and restore the Warp calls
    _recs.clear()
    _remove_patches()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def shutdown_native_team() -> None:
    """Stop the native team's workers (they return from native code and their threads end) and wait for them;
    a later launch that uses the native team starts a new one. For a program that wants its cores back while it
    does not render, and for benchmarks comparing the two teams. Runs at exit too."""
    global _native
    with _team_lock:
        team, _native = _native, None
    if team is not None:
        with team.busy:  # after a launch running on it from another Python thread
            team.shutdown()


def _native_team(dev) -> Optional[_NativeTeam]:
    """The process's native team (``usable_cores() - 1`` workers), built by the first call; None when it
    cannot be built (then ``NATIVE_TEAM`` is turned off and the Python team runs the bands)."""
    global _native, NATIVE_TEAM, _exit_hook
    if _native is not None:
        return _native
    with _team_lock:
        if _native is None and NATIVE_TEAM:
            try:
                team = _NativeTeam(usable_cores() - 1, dev)
            except Exception:  # noqa: BLE001 - no native team on this platform: the Python team stays
                NATIVE_TEAM = False
                return None
            if not _exit_hook:
                import atexit

                atexit.register(shutdown_native_team)  # after Warp's own exit handlers, so it runs before them
                _exit_hook = True
            _native = team
    return _native


def bands(n_rows: int, n_threads: int, row_items: int = 1, min_items: int = 0) -> list:
    """Split ``n_rows`` into at most ``n_threads`` contiguous (start, stop) bands of near-equal size, fewer when
    a band would hold under ``min_items`` work items (``row_items`` per row); never an empty band."""
    n = max(1, min(int(n_threads), int(n_rows)))
    if min_items > 0:
        n = max(1, min(n, (int(n_rows) * int(row_items)) // int(min_items)))
    base, extra = divmod(int(n_rows), n)
    out, r = [], 0
    for i in range(n):
        k = base + (1 if i < extra else 0)
        out.append((r, r + k))
        r += k
    return out


_structs: dict = {}


def _pack(cmd):
    """(entry point, argument struct type, packed arguments, kernel dims) of a recorded CPU launch: the struct
    Warp's ``invoke`` builds, one field per kernel argument in order (row0 last)."""
    k = cmd.kernel
    params = cmd.params
    key = (k.key, id(k), tuple(type(p) for p in params[1:]))
    st = _structs.get(key)
    if st is None:
        fields = [(a.label, type(params[1 + i])) for i, a in enumerate(k.adj.args)]
        st = _structs[key] = type("BandArgs", (ctypes.Structure,), {"_fields_": fields})
    args = st()
    for i, (name, _) in enumerate(st._fields_):
        setattr(args, name, params[1 + i])
    return cmd.hooks.forward, st, args, k.adj.kernel_dim


_pack_cache: dict = {}
_PACK_CACHE_MAX = 256


def _record(kernel, dims, inputs, outputs, dev):
    """``_pack`` of a fresh recording (``wp.launch(..., record_cmd=True)`` checks and packs, launches nothing)."""
    return _pack(wp.launch(kernel, dim=dims if len(dims) > 1 else dims[0], inputs=inputs, outputs=[*outputs, 0],
                           device=dev, record_cmd=True))


def _packed_args(kernel, dims, inputs, outputs, dev, mexec=None):
    """``_pack`` of this launch, reused when the same kernel is launched again with the same arrays (the same
    objects, checked through weak references, so a freed array's reused id cannot match) and the same numbers;
    Warp structs and vectors are set again in the kept argument struct on every call (their fields may have
    changed in place). Any other argument kind is packed afresh every time."""
    args = [*inputs, *outputs, 0]
    key = [id(kernel), len(dims)]
    arrays, reset = [], []
    for i, a in enumerate(args):
        if isinstance(a, wp.array):
            key.append(id(a))
            arrays.append(a)
        elif type(a) in (int, float, bool):
            key.append((type(a), a))
        elif hasattr(a, "__ctype__") or isinstance(a, ctypes.Array):
            key.append(None)
            reset.append(i)
        else:
            return _record(kernel, dims, inputs, outputs, dev)
    key = tuple(key)
    hit = _pack_cache.get(key)
    if hit is not None:
        refs, packed, kept_exec = hit
        # the same loaded module (Warp rebuilds a module when a kernel is added to it after loading, and frees
        # the old code: a kept entry point of the old one must not be called) and the same arrays
        if kept_exec is mexec and all(r() is a for r, a in zip(refs, arrays)):
            fields = packed[1]._fields_
            st = packed[2]
            for i in reset:
                a = args[i]
                setattr(st, fields[i][0], a.__ctype__() if hasattr(a, "__ctype__") else a)
            return packed
    packed = _record(kernel, dims, inputs, outputs, dev)
    if len(_pack_cache) >= _PACK_CACHE_MAX:
        _pack_cache.clear()
    _pack_cache[key] = ([weakref.ref(a) for a in arrays], packed, mexec)
    return packed


_band_cache: dict = {}


class _Bands:
    """The kept per-band launch state of one packed launch split one way."""

    __slots__ = ("master", "last", "structs", "bounds", "calls", "tables")


def _band_calls(packed, parts, dims):
    """An iterator over (entry point, bounds, arguments) per band of ``parts`` for ``packed`` (see ``launch``)."""
    forward, struct_type, master, kdim = packed
    key = (id(master), tuple(parts), tuple(dims[1:]))
    st = _band_cache.get(key)
    if st is None or st.master is not master:
        st = _Bands()
        st.master, st.last = master, None
        st.structs = [struct_type() for _ in parts]
        st.bounds = {r1 - r0: _bounds_of((r1 - r0, *dims[1:]), kdim) for r0, r1 in parts}  # at most two sizes
        st.calls = [(forward, ctypes.byref(st.bounds[r1 - r0]), ctypes.byref(a))
                    for a, (r0, r1) in zip(st.structs, parts)]
        st.tables = None  # the native team's pointer tables (_tables), made on first use
        if len(_band_cache) >= _PACK_CACHE_MAX:
            _band_cache.clear()
        _band_cache[key] = st
    cur = bytes(master)
    if cur != st.last:
        size, src = len(cur), ctypes.addressof(master)
        for a, (r0, _) in zip(st.structs, parts):
            ctypes.memmove(ctypes.addressof(a), src, size)
            a.row0 = r0
        st.last = cur
    return st


def _tables(st):
    """The native team's view of the bands of ``st``: arrays of the band bounds' and argument structs'
    addresses, kept with ``st`` (whose structs they point to), and (entry point, tables' addresses, count)."""
    if st.tables is None:
        n = len(st.calls)
        bptr = (ctypes.c_uint64 * n)(*[ctypes.addressof(b._obj) for _, b, _ in st.calls])
        aptr = (ctypes.c_uint64 * n)(*[ctypes.addressof(a) for a in st.structs])
        fn = ctypes.cast(st.calls[0][0], ctypes.c_void_p).value
        st.tables = (bptr, aptr, fn, ctypes.addressof(bptr), ctypes.addressof(aptr), n)
    return st.tables


def _check_kernel(kernel) -> None:
    ok = _checked.get(kernel.key)
    if ok is None:
        args = kernel.adj.args
        ok = _checked[kernel.key] = bool(args) and args[-1].label == "row0"
    if not ok:
        raise TypeError(f"kernel {kernel.key!r} has no trailing 'row0: int' argument; parallel.launch needs one")


def launch(kernel, dim, inputs: Sequence = (), outputs: Sequence = (), device=None, *,
           threads: Optional[int] = None, min_band_items: Optional[int] = None, count=None, per_count: int = 1,
           max_blocks: int = 0, stream=None, block_dim: int = 0) -> None:
    """Launch ``kernel`` (last argument ``row0: int``) over ``dim``; on the CPU split ``dim[0]`` into bands
    run on ``threads`` threads (see the module docstring). ``outputs`` must not include ``row0``.

    ``count``: for a work list whose live entries are ``[0, count[0])`` (a (1,) int32 array the kernel also
    reads, exiting past it): on the CPU only those rows are split into bands (the count is read straight from
    host memory, no ``.numpy()``: CPU launches are synchronous, so this costs no wait); on CUDA the full ``dim``
    is launched. ``per_count``: launch rows per live entry (a list launch with that many threads per entry: the
    CPU splits the first ``count[0] * per_count`` rows). ``max_blocks`` (CUDA; 0: no limit): at most this many
    thread blocks, each thread stepping over the ``dim`` indices a grid apart (``wp.launch(max_blocks=...)``): a
    capacity-sized list launch then costs its threads past the count a few instructions each, not a block each.
    ``stream`` (CUDA; None: the device's current stream): the ``wp.Stream`` to launch on; the CPU has none, and
    ValueError names it if one is given there. ``block_dim`` (CUDA; 0: Warp's default, 256): threads per block, a
    multiple of 32 in [32, 1024]; the CPU runs one thread per block whatever it is (checked on every device)."""
    _check_kernel(kernel)
    block_dim = _check_block_dim(block_dim)
    dims = (int(dim),) if isinstance(dim, int) else tuple(int(d) for d in dim)
    dev = wp.get_device(device)
    inputs, outputs = list(inputs), list(outputs)
    rec = _recording()
    if rec is not None and (count is not None or not dev.is_cpu or _invoke is None or not FAST_BANDS):
        # bands that depend on a count read now, or a launch that is not packed bands: the replay makes the whole
        # launch again (the same arguments), without the recording
        if not dev.is_cpu:
            rec.fail(f"a launch of {kernel.key} on {dev}")
        rec.add(launch, kernel, dim, inputs, outputs, dev, threads=threads, min_band_items=min_band_items,
                count=count, per_count=per_count)
        with rec.paused():
            launch(kernel, dim, inputs, outputs, dev, threads=threads, min_band_items=min_band_items, count=count,
                   per_count=per_count, max_blocks=max_blocks, stream=stream, block_dim=block_dim)
        return
    if stream is not None and not dev.is_cuda:
        raise ValueError(f"stream must be None on the CPU device (CPU launches have no streams), got {stream!r}")
    if dims[0] <= 0 or any(d <= 0 for d in dims):
        return
    n = 1
    if dev.is_cpu:
        n = current_cpu_threads() if threads is None else resolve_cpu_threads(threads, "threads")
        if count is not None and n > 1:
            if count.dtype != wp.int32 or count.size < 1:
                raise ValueError(f"count must be a wp.array of int32 with at least 1 element, got {count.dtype} "
                                 f"of size {count.size}")
            live = int(ctypes.c_int32.from_address(count.ptr).value)  # host memory on the CPU device
            if live <= 0:
                return
            dims = (min(dims[0], live * int(per_count)), *dims[1:])
    row_items = 1
    for d in dims[1:]:
        row_items *= d
    min_items = MIN_ITEMS_PER_BAND if min_band_items is None else int(min_band_items)
    parts = bands(dims[0], n * bands_per_thread(n), row_items, min_items) if n > 1 else [(0, dims[0])]
    fast = dev.is_cpu and _invoke is not None and FAST_BANDS
    if len(parts) == 1 and not fast:
        extra = {"block_dim": block_dim} if block_dim and dev.is_cuda else {}
        wp.launch(kernel, dim=dims if len(dims) > 1 else dims[0], inputs=inputs, outputs=[*outputs, 0], device=dev,
                  max_blocks=int(max_blocks) if dev.is_cuda else 0, stream=stream, **extra)
        return
    mexec = kernel.module.load(dev, 1)  # compile/load (CPU block_dim 1, as wp.launch) here, not in the bands
    packed = None
    if fast:
        # the arguments are checked and packed once (wp.launch with record_cmd=True launches nothing) into the
        # CPU entry point's argument struct; each band copies it with its own row0 and launch bounds and calls
        # the entry point (a ctypes call: it releases the GIL). The packed struct is kept per kernel and
        # arguments (_packed_args): a frame's launches repeat theirs, and packing ~20 arguments costs ~60 us.
        packed = _packed_args(kernel, dims, inputs, outputs, dev, mexec)

    if packed is not None:
        # every band's launch bounds and argument struct (a copy of the packed one with its row0) are kept with
        # the packed arguments and copied again only when those changed: a band is then one ctypes call, the
        # least Python a member thread runs under the GIL
        st = _band_calls(packed, parts, dims)
        if rec is not None:
            rec.add_bands(st, n, min(n, len(parts)), dev, (*inputs, *outputs), mexec)
        _run_bands(st.calls, st, n, min(n, len(parts)), dev)
        return
    queue = iter(parts)

    def worker():
        for r0, r1 in queue:
            d = (r1 - r0, *dims[1:])
            wp.launch(kernel, dim=d if len(d) > 1 else d[0], inputs=inputs, outputs=[*outputs, r0], device=dev)

    _run_on_team(worker, n, min(n, len(parts)))


def _check_block_dim(block_dim) -> int:
    """``launch``'s ``block_dim``: 0 (Warp's default) or a multiple of 32 in [32, 1024]; ValueError otherwise."""
    if isinstance(block_dim, (bool, np.bool_)) or not isinstance(block_dim, (int, np.integer)) or not (
            block_dim == 0 or (32 <= block_dim <= 1024 and block_dim % 32 == 0)):
        raise ValueError(f"block_dim must be 0 (Warp's default) or a multiple of 32 in [32, 1024], got {block_dim!r}")
    return int(block_dim)


def _run_bands(calls, st, n: int, workers: int, dev) -> None:
    """Run the band calls ``calls`` ((entry point, bounds, arguments) each; ``st`` the ``_Bands`` they are, or a
    recording's copy of one) on ``workers`` threads (the calling one included) of the native team when the
    launch's ``n`` threads fit the usable cores, else of the Python team; one band runs in this thread."""
    if len(calls) == 1:  # one band: this thread, with the kept arguments (no packing)
        f, b, a = calls[0]
        f(b, a)
        return
    if NATIVE_TEAM and n <= usable_cores():
        native = _native_team(dev)
        if native is not None:
            if not native.busy.acquire(blocking=False):  # another Python thread's launch holds it: run here
                for f, b, a in calls:
                    f(b, a)
                return
            try:
                native.run(_tables(st), workers - 1)
            finally:
                native.busy.release()
            return
    it = iter(calls)

    def worker():
        for f, b, a in it:  # the list iterator is shared: each band goes to one thread
            f(b, a)

    _run_on_team(worker, n, workers)


def _run_on_team(worker, n: int, workers: int) -> None:
    """``worker()`` on ``workers`` threads of the Python team of ``n`` threads (the calling one included); in
    this thread alone when another Python thread's launch holds the team."""
    team = _team(n)
    if not team.busy.acquire(blocking=False):  # another Python thread's launch holds the team: run here
        worker()
        return
    try:
        team.run(worker, workers)
    finally:
        team.busy.release()


# -- a frame body's CPU launches, recorded and replayed -------------------------------------------------------


class CpuProgram:
    """The CPU work of one recorded call (``record``): its launches, memsets and copies in order, each with the
    arguments it had then, to be run again by :meth:`replay` without the Python that made them (the stages'
    argument checks, the packing, the band split). The CPU's counterpart of a captured CUDA graph, with the same
    rule: what was recorded is what runs, so the recorded code must take its per-call values from device arrays
    (as ``FrameLoop``'s frame body does), not from Python.

    ``problem``: None, or why the recorded call cannot be replayed (a host read, an operation the recording does
    not know, an exception in the recorded block); ``threads``: the thread count the bands were split for. The
    program keeps alive what its operations point into: the arrays passed to them (also those held by a Warp
    struct's fields when recorded) and the loaded code they call."""

    __slots__ = ("ops", "threads", "problem", "_keep")

    def __init__(self, threads: int):
        self.ops: list = []
        self.threads = int(threads)
        self.problem: Optional[str] = None
        self._keep: list = []

    def replay(self) -> None:
        """Run the recorded operations again, in order. Inside a recording of this thread (``record``), they are
        recorded into it too."""
        if self.problem is not None:
            raise RuntimeError(f"this CpuProgram cannot be replayed: {self.problem}")
        rec = _recording()
        if rec is not None:
            rec.program.ops.extend(self.ops)
            rec.program._keep.append(self)
        for op in self.ops:
            op()


def _arrays_in(values) -> list:
    """The Warp arrays among ``values`` and in the fields of the Warp structs among them (nested structs too):
    what a recorded operation's copied arguments point into."""
    out, todo = [], list(values)
    while todo:
        v = todo.pop()
        if isinstance(v, wp.array):
            out.append(v)
        elif hasattr(v, "_cls") and hasattr(v._cls, "vars"):  # a Warp struct instance
            todo.extend(getattr(v, name, None) for name in v._cls.vars)
    return out


class _Recorder:
    __slots__ = ("program", "depth")

    def __init__(self, threads: int):
        self.program = CpuProgram(threads)
        self.depth = 0  # > 0: inside an operation being recorded (its inner calls are part of it)

    def add(self, fn, *args, **kwargs) -> None:
        self.program.ops.append(functools.partial(fn, *args, **kwargs))

    def fail(self, why: str) -> None:
        if self.program.problem is None:
            self.program.problem = why

    @contextlib.contextmanager
    def paused(self):
        self.depth += 1
        try:
            yield
        finally:
            self.depth -= 1

    def add_command(self, cmd, what: str) -> None:
        """A launch command (``wp.Launch``) as it is now (``_snapshot_launch``), or a failure naming ``what``."""
        snap = _snapshot_launch(cmd)
        if snap is None:
            self.fail(f"{what} of {cmd.kernel.key} (not a plain CPU launch)")
            return
        self.add(snap[0])
        self.program._keep.append((snap[1], _arrays_in(cmd.fwd_args or ())))

    def add_bands(self, st, n: int, workers: int, dev, args, mexec) -> None:
        """A band launch: its bands' argument structs copied (a later launch with the same packed arguments may
        change the kept ones), the bounds shared (fixed per band size, kept alive by the calls' references);
        ``args`` (its inputs and outputs) and the loaded module ``mexec`` whose entry point the bands call are kept."""
        cp = _Bands()
        cp.master = cp.last = cp.tables = None
        cp.structs = [type(a).from_buffer_copy(a) for a in st.structs]
        cp.bounds = st.bounds
        cp.calls = [(f, b, ctypes.byref(a)) for (f, b, _), a in zip(st.calls, cp.structs)]
        self.program._keep.append((_arrays_in(args), mexec))
        self.add(_run_bands, cp.calls, cp, n, workers, dev)


_recs: dict = {}  # thread id -> its active _Recorder
_patched: list = []  # (object, name, original) of the Warp calls patched while any recording runs


def _recording() -> Optional[_Recorder]:
    """This thread's active recording, unless the call comes from inside an operation being recorded."""
    r = _recs.get(_thread.get_ident())
    if r is None or r.depth:
        return None
    return r


def recording_active() -> bool:
    """Whether this thread is inside :func:`record` (``FrameLoop`` then runs its frame body eagerly, so that the
    outer recording sees its operations)."""
    return _thread.get_ident() in _recs


def _snapshot_launch(cmd):
    """A call that runs the CPU launch command ``cmd`` (a ``wp.Launch``) with its arguments as they are now
    (a copy: the command may be changed and launched again before the replay), or None if it is no plain CPU
    launch (a CUDA one, or a cooperative one with block_dim > 1)."""
    if not cmd.device.is_cpu or cmd.block_dim > 1 or cmd.adjoint or _invoke is None:
        return None
    forward, _, args, _ = _pack(cmd)
    bounds = type(cmd.params[0]).from_buffer_copy(cmd.params[0])
    return functools.partial(forward, ctypes.byref(bounds), ctypes.byref(args)), (bounds, args, cmd)


# warp.utils calls that run native code directly (no launch a recording could see): refused while recording
_UNRECORDED_UTILS = ("array_scan", "array_sum", "array_inner", "radix_sort_pairs", "segmented_sort_pairs",
                     "runlength_encode", "array_cast")


def _recording_patches():
    """(object, name, replacement) for the Warp calls a frame body can make besides :func:`launch`: launches and
    memsets are recorded; a host read, an operation not known here, or a launch while a ``wp.Tape`` records marks
    the recording as not replayable. Calls from threads that are not recording, and those made inside a recorded
    operation, pass through unchanged."""
    import inspect

    import warp._src.context as wctx
    import warp.utils as wu
    from warp._src.context import Launch

    o_launch, o_tiled, o_cmd = wp.launch, wp.launch_tiled, Launch.launch
    o_copy, o_zero, o_fill, o_numpy, o_assign = wp.copy, wp.array.zero_, wp.array.fill_, wp.array.numpy, wp.array.assign
    o_iface, o_dunder = wp.array.__dict__.get("__array_interface__"), wp.array.__dict__.get("__array__")
    launch_sig = inspect.signature(o_launch)

    def launch_any(orig, name):
        def patched(*args, **kwargs):
            rec = _recording()
            if rec is None:
                return orig(*args, **kwargs)
            if orig is o_launch:
                bound = launch_sig.bind(*args, **kwargs)
                if bound.arguments.get("record_cmd"):
                    return orig(*args, **kwargs)
                args, kwargs = (), dict(bound.arguments)
            elif kwargs.get("record_cmd"):
                return orig(*args, **kwargs)
            if getattr(wctx.runtime, "tape", None) is not None:
                rec.fail(f"{name} while a wp.Tape records (its launches are not recorded commands)")
                with rec.paused():
                    return orig(*args, **kwargs)
            with rec.paused():
                cmd = orig(*args, **{**kwargs, "record_cmd": True})
                rec.add_command(cmd, name)
                cmd.launch()
            return None
        return patched

    def cmd_launch(self, *args, **kwargs):
        rec = _recording()
        if rec is None:
            return o_cmd(self, *args, **kwargs)
        rec.add_command(self, "a launch command")
        with rec.paused():
            return o_cmd(self, *args, **kwargs)

    def paused_call(rec, fn, *args, **kwargs):
        with (rec.paused() if rec is not None else contextlib.nullcontext()):
            return fn(*args, **kwargs)

    def zero(self):
        rec = _recording()
        if rec is not None:
            if self.device.is_cpu and self.is_contiguous and self.ptr:
                rec.add(ctypes.memset, self.ptr, 0, self.size * wp.types.type_size_in_bytes(self.dtype))
                rec.program._keep.append(self)
            elif self.size:
                rec.fail(f"zero_ of a {'non-contiguous ' if self.device.is_cpu else ''}array on {self.device}")
        return paused_call(rec, o_zero, self)

    def fill(self, value):
        rec = _recording()
        if rec is not None:
            if type(value) in (int, float, bool) and self.device.is_cpu:
                rec.add(o_fill, self, value)
            else:
                rec.fail(f"fill_ with a {type(value).__name__}")
        return paused_call(rec, o_fill, self, value)

    def copy(dest, src, *args, **kwargs):
        rec = _recording()
        if rec is not None:
            if dest.device.is_cpu and src.device.is_cpu:
                rec.add(o_copy, dest, src, *args, **kwargs)
            else:
                rec.fail(f"a copy from {src.device} to {dest.device}")
        return paused_call(rec, o_copy, dest, src, *args, **kwargs)

    def refused(orig, what):
        def patched(*args, **kwargs):
            rec = _recording()
            if rec is not None:
                rec.fail(what)
            return paused_call(rec, orig, *args, **kwargs)
        return patched

    out = [(wp, "launch", launch_any(o_launch, "wp.launch")),
           (wp, "launch_tiled", launch_any(o_tiled, "wp.launch_tiled")),
           (Launch, "launch", cmd_launch), (wp, "copy", copy), (wp.array, "zero_", zero), (wp.array, "fill_", fill),
           (wp.array, "numpy", refused(o_numpy, "a host read of an array (the replay would keep its value)")),
           (wp.array, "assign", refused(o_assign, "a host write of an array (the replay would keep its value)"))]
    if o_dunder is not None:
        out.append((wp.array, "__array__", refused(o_dunder, "a host read of an array through __array__")))
    if isinstance(o_iface, property):
        out.append((wp.array, "__array_interface__",
                    property(refused(o_iface.fget, "a host view of an array (__array_interface__)"))))
    for name in _UNRECORDED_UTILS:
        fn = getattr(wu, name, None)
        if fn is not None:
            out.append((wu, name, refused(fn, f"warp.utils.{name} (native code no recording sees)")))
    return out


def _install_patches() -> None:
    """Patch the Warp calls for recording (``_team_lock`` held; once for any number of recording threads)."""
    if not _patched:
        patches = _recording_patches()
        _patched.extend((obj, name, obj.__dict__[name] if name in obj.__dict__ else getattr(obj, name))
                        for obj, name, _ in patches)
        for obj, name, fn in patches:
            setattr(obj, name, fn)


def _remove_patches() -> None:
    """Restore the patched Warp calls (``_team_lock`` held)."""
    while _patched:
        obj, name, orig = _patched.pop()
        setattr(obj, name, orig)


@contextlib.contextmanager
def record():
    """Within the block, this thread's CPU launches (:func:`launch`, ``wp.launch``, ``wp.launch_tiled``, launch
    commands), memsets and copies run as usual and are recorded into the :class:`CpuProgram` it yields, for
    ``FrameLoop`` to replay its frame body (the CPU's counterpart of a CUDA graph capture). A host read
    (``numpy``, ``assign``, a NumPy view), an operation the recording does not know, or an exception leaving the
    block sets the program's ``problem``. Several threads may record at once, each its own program; recordings do
    not nest within a thread. The Warp calls named are patched while any recording runs (other threads' calls pass
    through). What the recording cannot see (native code called directly, reads through raw pointers) is the
    caller's to keep out of the block."""
    tid = _thread.get_ident()
    with _team_lock:
        if tid in _recs:
            raise RuntimeError("a CPU recording is already running in this thread (parallel.record does not nest)")
        r = _Recorder(current_cpu_threads())
        try:
            _install_patches()
        except BaseException:
            if not _recs:
                _remove_patches()
            raise
        _recs[tid] = r
    try:
        yield r.program
    except BaseException as e:
        r.fail(f"the recorded block raised {type(e).__name__}: {e}")
        raise
    finally:
        with _team_lock:
            _recs.pop(tid, None)
            if not _recs:
                _remove_patches()


# the CPU runs the per-pixel passes that have a rows variant a row per thread (launch_rows); False: a thread per
# pixel as on CUDA (the same values: tests/test_parallel.py compares whole frames both ways)
ROW_KERNELS = True


def use_row_kernels(device) -> bool:
    """Whether per-pixel passes with a rows variant run it on ``device`` (the CPU, unless ROW_KERNELS is off)."""
    return bool(ROW_KERNELS) and not wp.get_device(device).is_cuda


def launch_rows(pixel_kernel, rows_kernel, shape, inputs: Sequence = (), outputs: Sequence = (),
                device=None) -> None:
    """A per-pixel pass over an image of ``shape`` = (H, W): on CUDA ``pixel_kernel`` over (H, W) (a thread per
    pixel); on the CPU ``rows_kernel`` over H (a thread per row, looping over its W pixels), in bands. Both take
    the same arguments (the last ``row0``) and compute the same values (one factory makes both around a
    shared per-pixel ``wp.func``; the rows form calls it for x in [0, W)). On the CPU a Warp launch thread
    costs its kernel's argument and struct loads every time: once per row instead of once per pixel is cheaper
    (the sampling pass with its tile pass: 18.8 against ~30 ms, cornell 640x360, one core of the development
    machine)."""
    h, w = int(shape[0]), int(shape[1])
    dev = wp.get_device(device)
    if use_row_kernels(dev):
        launch(rows_kernel, h, inputs, outputs, dev, min_band_items=max(1, -(-MIN_ITEMS_PER_BAND // max(w, 1))))
    else:
        launch(pixel_kernel, (h, w), inputs, outputs, dev)


class Relaunch:
    """One call site's launch of ``kernel``, recorded on CUDA and replayed: the first call records it
    (``wp.launch(..., record_cmd=True)``), later calls re-set the arguments that may have changed (every struct
    and vector, every number that differs from last time) and launch the recorded command, which skips packing
    every argument again (the per-frame head launches: G-buffer, frame setup, shading parameters). A different array object or
    a different ``dim`` records anew. ``bands=True`` (the kernel has ``row0``): on the CPU every call is a
    band-parallel :func:`launch`; ``bands=False``: recorded on every device (a CPU replay runs in this thread)."""

    def __init__(self, kernel, *, bands: bool):
        self.kernel, self.bands = kernel, bool(bands)
        if self.bands:
            _check_kernel(kernel)
        self._cmd = None
        self._key = None
        self._vals = None

    def __call__(self, dim, inputs: Sequence = (), outputs: Sequence = (), device=None) -> None:
        dev = wp.get_device(device)
        if self.bands and not dev.is_cuda:
            launch(self.kernel, dim, inputs, outputs, dev)
            return
        outs = [*outputs, 0] if self.bands else list(outputs)
        args = [*inputs, *outs]
        if not self._replay(dim, dev, args):
            self._cmd = wp.launch(self.kernel, dim=dim, inputs=list(inputs), outputs=outs, device=dev, record_cmd=True)
            self._key, self._vals = (dim, dev), list(args)
        self._cmd.launch()

    def _replay(self, dim, dev, args: list) -> bool:
        """Re-set the recorded command's changed arguments for ``args``, in one pass (this runs before every
        frame's G-buffer launch, on the frame's critical path); False when it must be recorded anew: none yet,
        another ``dim`` or device, or an array argument that is not the same object as when recorded (the
        recorded values hold the arrays, so identity is the test)."""
        vals = self._vals
        if self._cmd is None or self._key != (dim, dev) or len(args) != len(vals):
            return False
        for i, a in enumerate(args):
            b = vals[i]
            if isinstance(a, wp.array) or isinstance(b, wp.array):
                if a is not b:
                    return False
                continue
            # numbers are immutable: an equal one is kept; a struct or vector is re-set every call (the caller
            # may have changed its fields in place)
            if type(a) is type(b) and isinstance(a, (int, float)) and a == b:
                continue
            self._cmd.set_param_at_index(i, a)
            vals[i] = a
        return True
