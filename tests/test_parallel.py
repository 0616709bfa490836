"""Band-parallel CPU launches (``foveawarp.parallel``): the band split, bit-identical output for every
thread count (kernels, stages, whole frames), a stress test for races between concurrent CPU launches, and
the thread-count settings."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest
import warp as wp
from hypothesis import given, settings
from hypothesis import strategies as st

import foveawarp as fw
from foveawarp import parallel
from foveawarp.kernels.saliency import gradient_kernel, lab_kernel
from foveawarp.kernels.tonemap import tonemap_kernel

DEV = "cpu"


@pytest.fixture
def every_band(monkeypatch):
    """Split even tiny launches (the default keeps >= MIN_ITEMS_PER_BAND work items per band)."""
    monkeypatch.setattr(parallel, "MIN_ITEMS_PER_BAND", 0)


# -- the split ---------------------------------------------------------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 5000), st.integers(1, 64), st.integers(0, 300), st.integers(0, 5000))
def test_bands_cover_rows_once(rows, threads, row_items, min_items):
    b = parallel.bands(rows, threads, row_items, min_items)
    assert 1 <= len(b) <= min(threads, rows)
    assert b[0][0] == 0 and b[-1][1] == rows
    for (s0, e0), (s1, _) in zip(b, b[1:]):
        assert e0 == s1
    sizes = [e - s for s, e in b]
    assert min(sizes) >= 1 and max(sizes) - min(sizes) <= 1
    if min_items > 0 and len(b) > 1:
        assert rows * row_items // len(b) >= min_items


# -- kernels: N threads == 1 thread, bit for bit -------------------------------------------------------------------


def _rand_vec3(rng, h, w, scale=4.0):
    return wp.array((rng.random((h, w, 3)) * scale).astype(np.float32), dtype=wp.vec3, device=DEV)


@pytest.mark.parametrize("h, w", [(1, 1), (5, 3), (17, 11), (64, 48)])
def test_kernels_bit_identical(every_band, rng, h, w):
    """A per-pixel kernel (tone map), one with a neighbourhood read across band borders (Sobel gradient) and
    the Lab prepass at N in {2, 3, 7, rows + 5} equal one thread byte for byte."""
    hdr = _rand_vec3(rng, h, w)
    ref = {}
    for n in (1, 2, 3, 7, h + 5):
        tm = wp.zeros((h, w), dtype=wp.vec3, device=DEV)
        lab = wp.zeros((h, w), dtype=wp.vec3, device=DEV)
        grad = wp.zeros((h, w), dtype=float, device=DEV)
        parallel.launch(tonemap_kernel, (h, w), [hdr, 1.5, 11.2], [tm], DEV, threads=n)
        parallel.launch(lab_kernel, (h, w), [hdr], [lab], DEV, threads=n)
        parallel.launch(gradient_kernel, (h, w), [lab], [grad], DEV, threads=n)
        got = {"tm": tm.numpy(), "lab": lab.numpy(), "grad": grad.numpy()}
        if n == 1:
            ref = got
        for k in got:
            assert got[k].tobytes() == ref[k].tobytes(), (k, n)


def test_launch_without_row0_is_refused():
    from foveawarp.kernels.shade import set_shade_params_kernel

    with pytest.raises(TypeError, match="row0"):
        parallel.launch(set_shade_params_kernel, 1, [], [], DEV)


def test_launch_on_a_stream_is_cuda_only():
    """``stream=`` (the CUDA stream of a launch) on the CPU device: ValueError naming it, nothing launched."""
    a = wp.zeros((4, 4), dtype=wp.vec3, device="cpu")
    out = wp.full((4, 4), wp.vec3(7.0, 7.0, 7.0), dtype=wp.vec3, device="cpu")
    with pytest.raises(ValueError, match="stream must be None on the CPU"):
        parallel.launch(lab_kernel, (4, 4), [a], [out], "cpu", stream="not-a-stream")
    assert np.all(out.numpy() == 7.0)


@pytest.mark.parametrize("bad", [16, 33, 1056, -32, True, 128.0, "128"])
def test_launch_block_dim_checked(bad):
    """``block_dim=``: 0 or a multiple of 32 in [32, 1024], else ValueError naming it and the range, nothing
    launched (on every device: the CPU ignores a valid one)."""
    a = wp.zeros((4, 4), dtype=wp.vec3, device="cpu")
    out = wp.full((4, 4), wp.vec3(7.0, 7.0, 7.0), dtype=wp.vec3, device="cpu")
    with pytest.raises(ValueError, match=r"block_dim must be 0 \(Warp's default\) or a multiple of 32 in \[32, 1024\]"):
        parallel.launch(lab_kernel, (4, 4), [a], [out], "cpu", block_dim=bad)
    assert np.all(out.numpy() == 7.0)


def test_launch_block_dim_same_values(device, every_band):
    """A launch in 32-, 128- or 1024-thread blocks (CUDA; with a grid cap too, so threads take several rows) writes
    what the default launch writes; on the CPU the bands ignore it."""
    rng = np.random.default_rng(5)
    a = wp.array(rng.random((37, 29, 3)).astype(np.float32), dtype=wp.vec3, device=device)
    want = wp.zeros((37, 29), dtype=wp.vec3, device=device)
    parallel.launch(lab_kernel, (37, 29), [a], [want], device)
    for bd, mb in ((32, 0), (128, 0), (1024, 0), (32, 3), (128, 2)):
        out = wp.zeros((37, 29), dtype=wp.vec3, device=device)
        parallel.launch(lab_kernel, (37, 29), [a], [out], device, block_dim=bd, max_blocks=mb)
        np.testing.assert_array_equal(out.numpy(), want.numpy())


def test_work_list_count(every_band):
    """A work list launched with ``count``: only the live entries are split, the rest stay untouched."""
    loops = {n: fw.FrameLoop("cornell", 24, 16, device=DEV, cpu_threads=n, timing=False, policy="foveated")
             for n in (1, 3, 40)}
    outs = {}
    for n, fl in loops.items():
        cam = fl.scene.camera_at(0.0)
        g = fl.gbuffer
        fl._gbuffer(fl._contexts.build(cam, cam, (12.0, 8.0), fl.frame_index, fl._max_t(cam)))
        work = wp.array(np.arange(24 * 16, dtype=np.int32)[::-1].copy(), dtype=wp.int32, device=DEV)
        count = wp.array([100], dtype=wp.int32, device=DEV)
        out = wp.full((16, 24), wp.vec3(-1.0, -1.0, -1.0), dtype=wp.vec3, device=DEV)
        fl.shade_list(cam, work, count, out)
        outs[n] = out.numpy()
        assert g is fl.gbuffer
    for n in (3, 40):
        assert outs[n].tobytes() == outs[1].tobytes()
    flat = outs[1].reshape(-1, 3)
    assert (flat[: 24 * 16 - 100] == -1.0).all() and (flat[24 * 16 - 100:] != -1.0).any()


# -- whole frames ---------------------------------------------------------------------------------------------------


def _frames(n, config, size=(40, 24), frames=4, scene="cornell"):
    w, h = size
    fl = fw.FrameLoop(scene, w, h, config=config, device=DEV, cpu_threads=n, timing=False, policy="foveated")
    out = []
    for i in range(frames):
        cam = fl.scene.camera_at(0.1 * i)
        fr = fl.render(cam, gaze_px=(w * (0.3 + 0.1 * i), h * 0.5), time=0.1 * i)
        out.append((fr.numpy().copy(), fr.sampling_map.numpy().copy()))
        ref = fl.render_reference(cam, time=0.1 * i)
        out.append((ref.numpy().copy(),))
    return out


@pytest.mark.parametrize("config", [
    fw.Config(), fw.Config().with_(shading={"ao_samples": 2}),
    fw.Config(dof=fw.DofConfig(aperture_m=0.01, focus_depth_m=None)),
    fw.Config().with_(shading={"indirect": "lighttree"}),
], ids=["default", "ao2", "dof", "indirect"])
def test_frames_bit_identical(every_band, config):
    """Foveated and reference frames (image and sampling map) with N in {2, 3, 7, rows + 5} threads equal
    one thread byte for byte, over a moving camera and gaze (temporal reuse, reconstruction, shading lists),
    with Monte Carlo AO, depth of field (gather) and light-tree indirect light."""
    base = _frames(1, config)
    for n in (2, 3, 7, 24 + 5):
        got = _frames(n, config)
        for i, (a, b) in enumerate(zip(base, got)):
            for x, y in zip(a, b):
                assert x.tobytes() == y.tobytes(), (n, i)


def test_stage_outputs_bit_identical(every_band):
    """Every G-buffer field, the sampling stage's outputs and the temporal history after a few frames."""
    def state(n):
        fl = fw.FrameLoop("bunny", 33, 19, device=DEV, cpu_threads=n, timing=False, policy="foveated")
        for i in range(3):
            fl.render(fl.scene.camera_at(0.2 * i), gaze_px=(5.0 + 9.0 * i, 9.0))
        g = fl.gbuffer
        arrs = [g.position, g.normal, g.depth, g.albedo, g.face, g.hit, g.velocity, g.reproj_uv,
                fl.sampling.probability, fl.sampling.saliency, fl.sampling.sample_map, fl.sampling.prev_index,
                fl.recon, fl.radiance]
        return [a.numpy().tobytes() for a in arrs]

    base = state(1)
    for n in (2, 7, 24):
        assert state(n) == base


# -- races ---------------------------------------------------------------------------------------------------------


def test_concurrent_launches_stress(every_band, rng):
    """Many band-parallel launches of several kernels from several Python threads at once, repeated: every
    result equals the one-thread result (a static launch index or shared state in the generated CPU code would
    mix up rows or crash here)."""
    _concurrent_launches(rng)


def _concurrent_launches(rng):
    h, w = 37, 29
    inputs = [_rand_vec3(rng, h, w) for _ in range(6)]
    expect = []
    for a in inputs:
        lab = wp.zeros((h, w), dtype=wp.vec3, device=DEV)
        grad = wp.zeros((h, w), dtype=float, device=DEV)
        wp.launch(lab_kernel, (h, w), inputs=[a], outputs=[lab, 0], device=DEV)
        wp.launch(gradient_kernel, (h, w), inputs=[lab], outputs=[grad, 0], device=DEV)
        expect.append((lab.numpy().tobytes(), grad.numpy().tobytes()))
    errors = []

    def worker(k):
        try:
            for rep in range(15):
                a = inputs[(k + rep) % len(inputs)]
                lab = wp.zeros((h, w), dtype=wp.vec3, device=DEV)
                grad = wp.zeros((h, w), dtype=float, device=DEV)
                parallel.launch(lab_kernel, (h, w), [a], [lab], DEV, threads=1 + (k + rep) % 7)
                parallel.launch(gradient_kernel, (h, w), [lab], [grad], DEV, threads=1 + (k * rep) % 9)
                if (lab.numpy().tobytes(), grad.numpy().tobytes()) != expect[(k + rep) % len(inputs)]:
                    errors.append((k, rep))
        except Exception as e:  # pragma: no cover - reported below
            errors.append(repr(e))

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []


# -- settings --------------------------------------------------------------------------------------------------------


def test_thread_count_settings(monkeypatch):
    monkeypatch.delenv(parallel.ENV_VAR, raising=False)
    assert parallel.default_cpu_threads() == parallel.usable_cores()
    monkeypatch.setenv(parallel.ENV_VAR, "3")
    assert parallel.default_cpu_threads() == 3
    assert fw.FrameLoop("cornell", 8, 6, device=DEV).cpu_threads == 3
    assert fw.FrameLoop("cornell", 8, 6, device=DEV, cpu_threads=5).cpu_threads == 5
    with parallel.cpu_threads(2):
        assert parallel.current_cpu_threads() == 2
    assert parallel.current_cpu_threads() == 3
    for bad in ("0", "abc", "2.5", "1025"):
        monkeypatch.setenv(parallel.ENV_VAR, bad)
        with pytest.raises(ValueError, match=rf"FOVEAWARP_CPU_THREADS.*\[1, 1024\].*{bad}"):
            parallel.default_cpu_threads()
        with pytest.raises(ValueError, match="FOVEAWARP_CPU_THREADS"):
            fw.FrameLoop("cornell", 8, 6, device=DEV)


@pytest.mark.parametrize("size", [(33, 19), (64, 48), (16, 16), (1, 1)])
@pytest.mark.parametrize("threads", [1, 2, 5])
@pytest.mark.parametrize("variant", ["1+jfa", "disc"])
def test_jfa_last_pass_bands_equals_tiled(every_band, rng, size, threads, variant):
    """The three forms of the last JFA pass write exactly the same: the CPU's bands (no tiles, no atomics), the
    tiled kernel (block reductions), and the per-pixel launch with atomic tile maxima (``few_holes``): nearest
    seeds, radii, tile radii, Voronoi colours and the statistics, for sparse, dense and empty seed masks (the
    empty one leaves every pixel unreached), with the 1+JFA schedule and the disc scan; the stage reused on a
    second mask (the tile maxima start again from zero)."""
    from foveawarp.stages.reconstruct import ReconstructStage

    w, h = size
    color = wp.array(rng.random((h, w, 3)).astype(np.float32), dtype=wp.vec3, device=DEV)
    masks = [wp.array((rng.random((h, w)) < d).astype(np.uint8), dtype=wp.uint8, device=DEV) for d in (0.0, 0.02, 0.3)]
    got = {}
    for form in ("tiled", "bands", "atomic", "lanes"):
        st = ReconstructStage(w, h, fw.ReconstructionConfig(jfa_variant=variant), device=DEV,
                              few_holes=form == "atomic")
        st.cpu_bands = form == "bands"
        if form == "lanes":
            st.last_pass = "lanes"
        got[form] = []
        for mask in masks[::-1] + masks:
            out = wp.zeros((h, w), dtype=wp.vec3, device=DEV)
            with parallel.cpu_threads(threads):
                st.run_jfa(mask, color_in=color)
                st.run_interpolate(color, out)
            got[form] += [a.numpy().tobytes() for a in (st.nearest, st.radius_sq, st.tile_radius_sq,
                                                         st.voronoi_color, st.max_radius, st.max_radius_sq,
                                                         st.unreached, out)]
    assert got["bands"] == got["tiled"] == got["atomic"] == got["lanes"]


@pytest.mark.parametrize("size", [(100, 37), (64, 48), (1, 1), (257, 33)])
def test_jfa_last_pass_forms_agree_on_every_device(device, rng, size):
    """On each device (CUDA: warps fold their lanes before the atomics), the tiled last pass, the per-pixel one
    with an atomic per pixel, and the per-pixel one with an atomic per warp and tile (``last_pass="lanes"``) write
    the same nearest seeds, radii, tile radii, colours and statistics, for empty, sparse and dense masks, the
    stage reused."""
    from foveawarp.stages.reconstruct import ReconstructStage

    w, h = size
    color = wp.array(rng.random((h, w, 3)).astype(np.float32), dtype=wp.vec3, device=device)
    masks = [wp.array((rng.random((h, w)) < d).astype(np.uint8), dtype=wp.uint8, device=device)
             for d in (0.0, 0.01, 0.12, 0.6)]
    got = {}
    for form in ("tiled", "atomic", "lanes"):
        st = ReconstructStage(w, h, fw.ReconstructionConfig(jfa_variant="disc"), device=device, guaranteed=True)
        st.cpu_bands = False
        st.last_pass = form
        got[form] = []
        for mask in masks[::-1] + masks:
            st.run_jfa(mask, color_in=color)
            got[form] += [a.numpy().tobytes() for a in (st.nearest, st.radius_sq, st.tile_radius_sq,
                                                         st.voronoi_color, st.max_radius, st.max_radius_sq,
                                                         st.unreached)]
    assert got["tiled"] == got["atomic"] == got["lanes"]


def test_few_holes_follows_the_shading_and_is_checked():
    """A FrameLoop asks for the atomic last pass with deterministic shading only (stochastic shading leaves many
    holes); ``few_holes`` must be a bool."""
    from foveawarp.stages.reconstruct import ReconstructStage

    for cfg, few in ((fw.Config(), True), (fw.Config().with_(shading={"ao_samples": 2}), False)):
        fl = fw.FrameLoop("cornell", 16, 8, config=cfg, device=DEV, timing=False, policy="foveated")
        fl.render(fl.scene.camera_at(0.0), gaze_px=(8, 4))  # the foveated stages exist from the first render
        assert fl.reconstruct.few_holes is few
    with pytest.raises(ValueError, match="few_holes"):
        ReconstructStage(16, 8, device=DEV, few_holes="yes")
    saved = ReconstructStage.last_pass
    try:
        ReconstructStage.last_pass = "warp"
        with pytest.raises(ValueError, match=r"ReconstructStage\.last_pass.*'tiled'.*'warp'"):
            ReconstructStage(16, 8, device=DEV)
    finally:
        ReconstructStage.last_pass = saved
    st = ReconstructStage(16, 8, device=DEV)
    st.last_pass = "atomc"  # set on the instance after construction: refused at the run
    with pytest.raises(ValueError, match=r"ReconstructStage\.last_pass.*'atomc'"):
        st.run_jfa(wp.zeros((8, 16), dtype=wp.uint8, device=DEV))


@pytest.mark.parametrize("size", [(33, 19), (64, 48), (5, 3), (1, 1)])
@pytest.mark.parametrize("block", [1, 4, 8])
def test_tile_pass_bands_equals_tiled(every_band, rng, size, block):
    """The CPU's band form of the sampling tile pass (per-tile counts, then a one-thread sum) writes exactly what
    the tiled kernel (block sums + atomics) writes: the guaranteed samples and both counters, which also equal a
    NumPy count of the resulting maps; every aligned tile ends with a sample."""
    from foveawarp.config import Config, FoveationConfig
    from foveawarp.ops.sampling import _frame
    from foveawarp.stages.sampling import dither_ranks, launch_tile_pass, sampling_params

    w, h = size
    tiles = ((h + block - 1) // block, (w + block - 1) // block)
    sp = sampling_params(Config(foveation=FoveationConfig(block=block)), w, h, 7)
    frame, _, _ = _frame(w, h, (0.0, 0.0), 60.0, wp.get_device(DEV), frame_index=3, block=block)
    ranks = wp.array(dither_ranks(block), dtype=wp.int32, device=DEV)
    for density in (0.0, 0.02, 0.3):
        s0 = (rng.random((h, w)) < density).astype(np.uint8)
        c0 = (rng.random((h, w)) < 0.5).astype(np.uint8)
        got = {}
        for threads in (1, 3):
            sample = wp.array(s0, dtype=wp.uint8, device=DEV)
            hit = wp.array(c0, dtype=wp.uint8, device=DEV)
            n = wp.full(1, 5, dtype=wp.int32, device=DEV)  # the pass adds to the counters
            nc = wp.full(1, 2, dtype=wp.int32, device=DEV)
            with parallel.cpu_threads(threads):
                launch_tile_pass(ranks, sp, frame, tiles, sample, hit, n, nc, wp.get_device(DEV))
            got[threads] = (sample.numpy(), int(n.numpy()[0]), int(nc.numpy()[0]))
        (m1, n1, c1), (m3, n3, c3) = got[1], got[3]
        np.testing.assert_array_equal(m3, m1)
        assert (n3, c3) == (n1, c1)
        assert n1 == 5 + int(m1.sum()) and c1 == 2 + int(c0.sum())
        np.testing.assert_array_equal(m1 >= s0, True)  # only adds samples
        for ty in range(tiles[0]):
            for tx in range(tiles[1]):
                assert m1[ty * block:(ty + 1) * block, tx * block:(tx + 1) * block].any(), (ty, tx)


@wp.struct
class _RelaunchParams:
    scale: float
    offset: wp.vec3


@wp.kernel(enable_backward=False)
def _relaunch_kernel(a: wp.array(dtype=wp.vec3), p: _RelaunchParams, k: int, out: wp.array(dtype=wp.vec3),
                     row0: int):
    i = wp.tid() + row0
    out[i] = a[i] * p.scale + p.offset + wp.vec3(float(k), 0.0, 0.0)


@wp.kernel(enable_backward=False)
def _relaunch_one_kernel(p: _RelaunchParams, k: int, out: wp.array(dtype=wp.vec3)):
    out[0] = p.offset * p.scale + wp.vec3(float(k), 0.0, 0.0)


@pytest.mark.parametrize("bands", [True, False])
def test_relaunch_replays_with_changed_arguments(device, bands, rng):
    """parallel.Relaunch (the recorded per-frame head launches) gives what a fresh wp.launch gives on every call:
    changed numbers and new structs are re-set, unchanged ones kept, a new array object or dim re-records."""
    n = 37
    a1 = wp.array(rng.random((n, 3)).astype(np.float32), dtype=wp.vec3, device=device)
    a2 = wp.array(rng.random((n, 3)).astype(np.float32), dtype=wp.vec3, device=device)
    out = wp.zeros(n, dtype=wp.vec3, device=device)
    ref = wp.zeros(n, dtype=wp.vec3, device=device)
    kern = _relaunch_kernel if bands else _relaunch_one_kernel
    rl = parallel.Relaunch(kern, bands=bands)
    calls = [(a1, 2.0, (0.0, 0.0, 0.0), 3), (a1, 2.0, (0.0, 0.0, 0.0), 3), (a1, 0.5, (1.0, 2.0, 3.0), 3),
             (a1, 0.5, (1.0, 2.0, 3.0), -4), (a2, 0.5, (1.0, 2.0, 3.0), -4), (a2, 7.0, (0.0, -1.0, 0.0), 0)]
    for arr, scale, off, k in calls:
        p = _RelaunchParams()
        p.scale = scale
        p.offset = wp.vec3(*off)
        out.zero_()
        if bands:
            rl(n, inputs=[arr, p, k], outputs=[out], device=device)
            wp.launch(kern, dim=n, inputs=[arr, p, k], outputs=[ref, 0], device=device)
            np.testing.assert_array_equal(out.numpy(), ref.numpy())
            want = arr.numpy() * np.float32(scale) + np.asarray(off, np.float32) + np.array([k, 0, 0], np.float32)
            np.testing.assert_allclose(out.numpy(), want, rtol=1e-6, atol=1e-6)
        else:
            rl(1, inputs=[p, k], outputs=[out], device=device)
            want = np.asarray(off, np.float32) * np.float32(scale) + np.array([k, 0, 0], np.float32)
            np.testing.assert_allclose(out.numpy()[0], want, rtol=1e-6, atol=1e-6)


@wp.kernel(enable_backward=False)
def _relaunch_arr_kernel(a: wp.array(dtype=wp.vec3), p: _RelaunchParams, k: int, out: wp.array(dtype=wp.vec3)):
    i = wp.tid()
    out[i] = a[i] * p.scale + p.offset + wp.vec3(float(k), 0.0, 0.0)


def test_relaunch_recorded_replay_follows_every_change(device):
    """The recorded replay (bands=False: recorded on every device) against a fresh wp.launch over random call
    sequences: arrays swapped for other objects (and back), another output, another dim, numbers of another
    type or value, a struct changed in place or replaced. Each call's output must equal the fresh launch's."""
    rng = np.random.default_rng(7)
    n = 29
    arrs = [wp.array(rng.random((n, 3)).astype(np.float32), dtype=wp.vec3, device=device) for _ in range(3)]
    outs = [wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(2)]
    ref = wp.zeros(n, dtype=wp.vec3, device=device)
    rl = parallel.Relaunch(_relaunch_arr_kernel, bands=False)
    p = _RelaunchParams()
    for step in range(60):
        a = arrs[int(rng.integers(3))]
        o = outs[int(rng.integers(2))]
        dim = int(rng.choice([n, n - 5, 1]))
        if rng.random() < 0.5:
            p = _RelaunchParams()  # a new struct object ...
        p.scale = float(rng.choice([0.5, 2.0, -1.0]))  # ... or the same one changed in place
        p.offset = wp.vec3(*(float(v) for v in rng.integers(-3, 4, 3)))
        k = int(rng.integers(-2, 3))
        o.zero_()
        ref.zero_()
        rl(dim, inputs=[a, p, k], outputs=[o], device=device)
        wp.launch(_relaunch_arr_kernel, dim=dim, inputs=[a, p, k], outputs=[ref], device=device)
        np.testing.assert_array_equal(o.numpy(), ref.numpy(), err_msg=f"step {step}")


# -- the kept packed arguments and the thread team ------------------------------------------------------------


def test_band_launch_sees_changed_arguments(every_band, rng):
    """parallel.launch keeps each launch's packed arguments: the same kernel launched again with a struct changed
    in place, another vector, another number, another array (and a new array in a freed one's place) computes
    with the new values every time (NumPy reference)."""
    n = 257
    out = wp.zeros(n, dtype=wp.vec3, device=DEV)
    p = _RelaunchParams()
    a_np = rng.random((n, 3)).astype(np.float32)
    a = wp.array(a_np, dtype=wp.vec3, device=DEV)
    for i in range(8):
        if i >= 4:  # a new array each time; the previous one is freed, so its id may come back
            del a
            a_np = rng.random((n, 3)).astype(np.float32)
            a = wp.array(a_np, dtype=wp.vec3, device=DEV)
        p.scale = float(i) * 0.5 - 1.0  # the same struct object, changed in place
        p.offset = wp.vec3(float(i), -1.0, 2.0)
        k = i % 3
        for _ in range(2):  # the second launch takes the kept arguments
            out.zero_()
            with parallel.cpu_threads(3):
                parallel.launch(_relaunch_kernel, n, inputs=[a, p, k], outputs=[out], device=DEV)
            want = a_np * np.float32(p.scale) + np.array([i + k, -1.0, 2.0], np.float32)
            np.testing.assert_allclose(out.numpy(), want, rtol=1e-6, atol=1e-6)


def test_team_raises_a_member_error_and_stays_usable():
    team = parallel._Team(4)
    seen = []
    lock = threading.Lock()

    def job():
        with lock:
            seen.append(threading.get_ident())
            if len(seen) == 2:
                raise RuntimeError("band failed")

    with pytest.raises(RuntimeError, match="band failed"):
        team.run(job, 4)
    assert len(seen) == 4
    seen.clear()
    team.run(lambda: seen.append(1), 4)
    assert len(seen) == 4
    team.run(lambda: seen.append(2), 2)  # fewer members than the team has
    assert seen.count(2) == 2


def test_launches_from_two_python_threads(every_band, rng):
    """Two Python threads launching at once share one team: the one that finds it busy runs its bands itself;
    both results are exact."""
    n = 4099
    srcs = [rng.random((n, 3)).astype(np.float32) for _ in range(2)]
    outs = [wp.zeros(n, dtype=wp.vec3, device=DEV) for _ in range(2)]
    ins = [wp.array(s, dtype=wp.vec3, device=DEV) for s in srcs]
    p = _RelaunchParams()
    p.scale, p.offset = 2.0, wp.vec3(0.0, 1.0, 0.0)
    errors = []

    def go(j):
        try:
            with parallel.cpu_threads(4):
                for _ in range(20):
                    parallel.launch(_relaunch_kernel, n, inputs=[ins[j], p, j], outputs=[outs[j]], device=DEV)
        except Exception as e:  # noqa: BLE001
            errors.append(e)

    ts = [threading.Thread(target=go, args=(j,)) for j in range(2)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert not errors
    for j in range(2):
        np.testing.assert_allclose(outs[j].numpy(), srcs[j] * 2.0 + np.array([j, 1.0, 0.0], np.float32),
                                   rtol=1e-6, atol=1e-6)


@wp.kernel(enable_backward=False)
def _count_rows_kernel(out: wp.array2d(dtype=wp.int32), row0: int):
    """Adds 1 to every element of its row: a band run twice (or never) leaves 2 (or 0) there."""
    y, x = wp.tid()
    y += row0
    out[y, x] = out[y, x] + 1


def _native_team_or_skip() -> None:
    """Skip where this platform has no native team: ``parallel`` turns it off when it cannot be built (no
    ``usleep`` in the C library, e.g. Windows) or when ``FOVEAWARP_CPU_NATIVE_TEAM=0`` is set; launches then run
    on the Python team, which the other tests of this file cover. On Linux and macOS these tests run (CI: Linux)."""
    if not parallel.NATIVE_TEAM or parallel._native_team(wp.get_device(DEV)) is None:
        pytest.skip("no native team on this platform (parallel.NATIVE_TEAM is off)")


@pytest.fixture
def native_team(monkeypatch):
    """A private native team of 5 workers serving every launch of up to 6 threads (the machine may have fewer
    cores: the workers then share them, which is slower but must stay exact); shut down after the test."""
    _native_team_or_skip()
    team = parallel._NativeTeam(5, wp.get_device(DEV))
    monkeypatch.setattr(parallel, "_native", team)
    monkeypatch.setattr(parallel, "usable_cores", lambda: 6)
    yield team
    team.shutdown()
    assert not any(t.is_alive() for t in team.threads)


def test_native_team_runs_every_band_once(every_band, native_team):
    """Launches of 2-6 threads and 1-24 bands on the native team, one after another: every row's band ran exactly
    once per launch (the claims are tagged with the job's generation, so a worker late from one job cannot
    take a band of the next); the Python team gives the same counts."""
    h, w = 23, 5
    out = wp.zeros((h, w), dtype=wp.int32, device=DEV)
    launches = 0
    for rep in range(120):
        n = 2 + rep % 5
        parallel.OVERSPLIT = 1 + rep % 4
        try:
            parallel.launch(_count_rows_kernel, (h, w), [], [out], DEV, threads=n)
        finally:
            parallel.OVERSPLIT = None
        launches += 1
        if rep % 17 == 0:
            np.testing.assert_array_equal(out.numpy(), np.full((h, w), launches, np.int32))
    np.testing.assert_array_equal(out.numpy(), np.full((h, w), launches, np.int32))
    parallel.NATIVE_TEAM = False
    try:
        parallel.launch(_count_rows_kernel, (h, w), [], [out], DEV, threads=4)
    finally:
        parallel.NATIVE_TEAM = True
    np.testing.assert_array_equal(out.numpy(), np.full((h, w), launches + 1, np.int32))


def test_native_team_concurrent_launches(every_band, native_team, rng):
    """The race test of ``test_concurrent_launches_stress`` with every launch of up to 6 threads on the native
    team: launches from six Python threads at once (one holds the team, the others run their bands in their own
    thread) all equal the one-thread results."""
    _concurrent_launches(rng)


def test_native_team_frames_bit_identical(every_band, native_team):
    """Whole foveated and reference frames with 2 AO rays, rendered with 4 threads on the native team, equal
    those of one thread byte for byte."""
    cfg = fw.Config().with_(shading={"ao_samples": 2})
    one = _frame_state(1, cfg, "cornell", (48, 32), frames=3)
    four = _frame_state(4, cfg, "cornell", (48, 32), frames=3)
    for k, (a, b) in enumerate(zip(one, four)):
        assert a.tobytes() == b.tobytes(), k


def test_native_team_shutdown_returns_its_workers():
    _native_team_or_skip()
    team = parallel._NativeTeam(3, wp.get_device(DEV))
    assert all(t.is_alive() for t in team.threads)
    team.shutdown()
    assert not any(t.is_alive() for t in team.threads)


def _frame_state(n, config, scene, size, frames=5):
    """Every per-frame output of a foveated + reference loop: images, sampling maps, temporal history, G-buffer."""
    w, h = size
    fl = fw.FrameLoop(scene, w, h, config=config, device=DEV, cpu_threads=n, timing=False, policy="foveated")
    out = []
    for i in range(frames):
        cam = fl.scene.camera_at(0.07 * i)
        fr = fl.render(cam, gaze_px=(w * (0.25 + 0.1 * i), h * 0.5), time=0.07 * i)
        out += [fr.numpy().copy(), fr.sampling_map.numpy().copy(), fl.temporal.color.numpy().copy(),
                fl.temporal.filled.numpy().copy(), fl.sampling.cache_hit.numpy().copy(),
                fl.sampling.prev_index.numpy().copy(), fl.sampling.num_samples.numpy().copy(),
                fl.gbuffer.depth.numpy().copy(), fl.gbuffer.reproj_uv.numpy().copy(), fl.recon.numpy().copy()]
        ref = fl.render_reference(cam, time=0.07 * i)
        out += [ref.numpy().copy(), fl.radiance.numpy().copy()]
    return out


@pytest.mark.parametrize("config", [fw.Config(), fw.Config().with_(shading={"ao_samples": 2}),
                                    fw.Config().with_(foveation={"block": 3})], ids=["default", "ao2", "block3"])
@pytest.mark.parametrize("scene", ["cornell", "eyechart"])
def test_row_kernels_equal_pixel_kernels(monkeypatch, config, scene):
    """The CPU's rows variants (a thread per row: G-buffer, sampling pass with its tile pass, masked and full
    shading, temporal resolve, Sibson gather) against the per-pixel kernels CUDA launches, run on the CPU
    (``parallel.ROW_KERNELS = False``): whole moving-camera frames, foveated and reference, byte for byte, at
    1 and 3 threads. CI has no GPU: this is where the per-pixel kernels' frame path is checked."""
    _rows_equal_pixels(monkeypatch, config, scene, (53, 37))  # partial tiles on both edges


def test_row_kernels_equal_pixel_kernels_wide(monkeypatch):
    """The same at 150 pixels wide: the sampling rows kernel's Sobel masks cover 64 pixels each (two whole and a
    partial one per row, ``nine_equal_mask64_*``)."""
    _rows_equal_pixels(monkeypatch, fw.Config(), "cornell", (150, 29))


def _rows_equal_pixels(monkeypatch, config, scene, size):
    rows = _frame_state(1, config, scene, size)
    assert any(a.any() for a in rows)
    monkeypatch.setattr(parallel, "ROW_KERNELS", False)
    for n in (1, 3):
        pix = _frame_state(n, config, scene, size)
        for i, (a, b) in enumerate(zip(rows, pix)):
            assert a.tobytes() == b.tobytes(), (n, i)


def test_shutdown_native_team_and_start_again(every_band):
    """``parallel.shutdown_native_team`` ends the workers; the next launch starts a new team and stays exact."""
    _native_team_or_skip()
    old = parallel._native
    parallel.shutdown_native_team()
    assert parallel._native is None and not any(t.is_alive() for t in old.threads)
    h, w = 9, 4
    out = wp.zeros((h, w), dtype=wp.int32, device=DEV)
    parallel.launch(_count_rows_kernel, (h, w), [], [out], DEV, threads=2)
    np.testing.assert_array_equal(out.numpy(), np.ones((h, w), np.int32))
    if parallel.usable_cores() > 1:  # 2 threads fit: the launch started a new native team
        assert parallel._native is not None and parallel._native is not old


def test_native_team_that_cannot_be_built_turns_itself_off(every_band, monkeypatch):
    """Where the native team cannot be built (e.g. no ``usleep`` in the C library), the first launch turns
    ``NATIVE_TEAM`` off and runs on the Python team, with the same result."""

    def broken(*a, **k):
        raise OSError("no usleep here")

    monkeypatch.setattr(parallel, "_native", None)
    monkeypatch.setattr(parallel, "NATIVE_TEAM", True)
    monkeypatch.setattr(parallel, "_NativeTeam", broken)
    monkeypatch.setattr(parallel, "usable_cores", lambda: 4)
    h, w = 11, 3
    out = wp.zeros((h, w), dtype=wp.int32, device=DEV)
    parallel.launch(_count_rows_kernel, (h, w), [], [out], DEV, threads=3)
    assert parallel.NATIVE_TEAM is False and parallel._native is None
    np.testing.assert_array_equal(out.numpy(), np.ones((h, w), np.int32))


def test_native_team_poster_held_up_between_jobs(every_band, monkeypatch):
    """A worker that wakes while the next job is being written must not claim a band of it under the finished
    job's generation (that would run bands twice, and let a launch return before its bands are done, unless
    the poster closes the word first). The poster is held up between writing a job and publishing it (the control
    block's testing word 48), the worker naps at once after a job, and 2- and 8-band launches alternate: every
    band runs exactly once per launch."""
    _native_team_or_skip()
    monkeypatch.setattr(parallel, "NATIVE_SPIN", 0)
    team = parallel._NativeTeam(1, wp.get_device(DEV))
    team.ctl[48] = 300
    monkeypatch.setattr(parallel, "_native", team)
    monkeypatch.setattr(parallel, "usable_cores", lambda: 2)
    h, w = 16, 2
    out = wp.zeros((h, w), dtype=wp.int32, device=DEV)
    try:
        for rep in range(1500):
            parallel.OVERSPLIT = 1 if rep % 2 == 0 else 4  # 2 or 8 bands on 2 threads
            parallel.launch(_count_rows_kernel, (h, w), [], [out], DEV, threads=2)
            if rep % 100 == 99:
                np.testing.assert_array_equal(out.numpy(), np.full((h, w), rep + 1, np.int32))
    finally:
        parallel.OVERSPLIT = None
        team.shutdown()
    np.testing.assert_array_equal(out.numpy(), np.full((h, w), 1500, np.int32))


_ROWS_SCRIPT = """
import os, sys, time
import warp as wp
wp.config.quiet = True
from foveawarp import parallel

@wp.kernel
def fill(a: wp.array(dtype=float), row0: int):
    i = wp.tid() + row0
    a[i] = float(i)

a = wp.zeros(50000, dtype=float, device="cpu")
"""


def _run_script(tmp_path, body: str) -> str:
    import subprocess
    import sys

    script = tmp_path / "script.py"
    script.write_text(_ROWS_SCRIPT + body)
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    return r.stdout


def test_band_launch_after_its_module_was_rebuilt(tmp_path):
    """Warp rebuilds a loaded module when a kernel is added to it, and frees the old code: a band launch of a
    kernel of that module packed before must not call its old entry point (that would crash the process)."""
    out = _run_script(tmp_path, """
parallel.launch(fill, a.shape[0], [a], threads=2, device="cpu", min_band_items=1)
def factory(c):
    @wp.kernel
    def late(a: wp.array(dtype=float), row0: int):
        a[wp.tid() + row0] = float(c)
    return late
wp.launch(factory(3.0), 10, [a, 0], device="cpu")  # the module is rebuilt with the new kernel
import gc; gc.collect()
a.zero_()
parallel.launch(fill, a.shape[0], [a], threads=2, device="cpu", min_band_items=1)
assert (a.numpy() == range(a.shape[0])).all()
# the entry point the band launches call is the rebuilt module's (calling the freed one may or may not crash)
import ctypes
dev = wp.get_device("cpu")
packed = parallel._packed_args(fill, (a.shape[0],), [a], [], dev, fill.module.load(dev, 1))
now = fill.module.load(dev, 1).get_kernel_hooks(fill).forward
assert ctypes.cast(packed[0], ctypes.c_void_p).value == ctypes.cast(now, ctypes.c_void_p).value
print("ok")
""")
    assert out.strip().endswith("ok")


@pytest.mark.skipif(not hasattr(os, "fork"), reason="no os.fork on this platform")
@pytest.mark.parametrize("threads", [2, 3])
def test_band_launch_in_a_forked_child(tmp_path, threads):
    """A child forked after band launches has none of the parent's team threads: its own band launches (the
    Python team at 3 threads on 2 cores, the native team where the threads fit) finish, with the right values
    (the Python team's launch waited forever for threads that were not there)."""
    out = _run_script(tmp_path, f"""
parallel.launch(fill, a.shape[0], [a], threads={threads}, device="cpu", min_band_items=1)
pid = os.fork()
if pid == 0:
    a.zero_()
    parallel.launch(fill, a.shape[0], [a], threads={threads}, device="cpu", min_band_items=1)
    os._exit(0 if (a.numpy() == range(a.shape[0])).all() else 3)
t0 = time.time()
while time.time() - t0 < 60:
    done, status = os.waitpid(pid, os.WNOHANG)
    if done:
        print("child", os.waitstatus_to_exitcode(status))
        break
    time.sleep(0.05)
else:
    os.kill(pid, 9)
    print("child hung")
""")
    assert out.strip().endswith("child 0"), out


# -- recording and replaying a body's CPU work (parallel.record, FrameLoop's CPU counterpart of a CUDA graph) -----


@wp.kernel(enable_backward=False)
def _count_sum_kernel(a: wp.array(dtype=wp.vec3), count: wp.array(dtype=wp.int32), out: wp.array(dtype=float),
                      row0: int):
    i = wp.tid() + row0
    if i < count[0]:
        out[i] = a[i][0] + a[i][1] + a[i][2]


@wp.kernel(enable_backward=False)
def _twice_index_kernel(out: wp.array(dtype=float), row0: int):
    i = wp.tid() + row0
    out[i] = 2.0 * float(i)


@wp.kernel(enable_backward=False)
def _total_kernel(x: wp.array(dtype=float), k: int, total: wp.array(dtype=float)):
    s = float(0.0)
    for i in range(x.shape[0]):
        s += x[i]
    total[0] = s + float(k)


def _recorded_body(a, p, out, sums, count, total, copy_dst, rl_one):
    """A body like a frame's: a memset, a band launch with a struct argument, a recorded one-thread launch
    command, a launch over a counted work list, a plain wp.launch, a fill and a copy."""
    out.zero_()
    parallel.launch(_relaunch_kernel, out.shape[0], inputs=[a, p, 2], outputs=[out], device=DEV)
    rl_one(1, inputs=[p, 5], outputs=[copy_dst], device=DEV)  # parallel.Relaunch(bands=False): a launch command
    sums.fill_(-1.0)
    parallel.launch(_count_sum_kernel, out.shape[0], inputs=[out, count], outputs=[sums], device=DEV, count=count)
    wp.launch(_total_kernel, dim=1, inputs=[sums, 3], outputs=[total], device=DEV)
    wp.copy(copy_dst, out, dest_offset=1, src_offset=0, count=out.shape[0] - 1)


def _body_want(a_np, scale, off, live):
    out = a_np * np.float32(scale) + np.asarray(off, np.float32) + np.array([2, 0, 0], np.float32)
    sums = np.full(a_np.shape[0], -1.0, np.float32)
    sums[:live] = out[:live].sum(axis=1)
    return out, sums


@pytest.mark.parametrize("threads", [1, 3])
def test_record_replays_the_body(every_band, rng, threads):
    """The replay runs the recorded launches, memsets, fills and copies again, in order, with the arguments they
    had when recorded, on the arrays' current contents (NumPy reference): a struct changed after the recording,
    and a launch of the same kernel with other values in between, do not reach it; a counted launch reads the
    count again."""
    n = 53
    a_np = rng.random((n, 3)).astype(np.float32)
    a = wp.array(a_np, dtype=wp.vec3, device=DEV)
    out, copy_dst = wp.zeros(n, dtype=wp.vec3, device=DEV), wp.zeros(n, dtype=wp.vec3, device=DEV)
    sums, total = wp.zeros(n, dtype=float, device=DEV), wp.zeros(1, dtype=float, device=DEV)
    count = wp.array([20], dtype=wp.int32, device=DEV)
    rl_one = parallel.Relaunch(_relaunch_one_kernel, bands=False)
    p = _RelaunchParams()
    p.scale, p.offset = 1.5, wp.vec3(1.0, -2.0, 0.5)
    with parallel.cpu_threads(threads):
        with parallel.record() as prog:
            _recorded_body(a, p, out, sums, count, total, copy_dst, rl_one)
        assert prog.problem is None and prog.threads == threads and len(prog.ops) == 7
        # the same kernels with other values (the packed-argument caches are shared with the recording)
        p.scale, p.offset = -4.0, wp.vec3(9.0, 9.0, 9.0)
        _recorded_body(a, p, out, sums, count, total, copy_dst, rl_one)
        # new contents and a new count, then the replay
        a_np = rng.random((n, 3)).astype(np.float32)
        a.assign(a_np)
        count.assign(np.array([n - 3], np.int32))
        out.fill_(wp.vec3(7.0, 7.0, 7.0))
        prog.replay()
    want_out, want_sums = _body_want(a_np, 1.5, (1.0, -2.0, 0.5), n - 3)
    np.testing.assert_allclose(out.numpy(), want_out, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(sums.numpy(), want_sums, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(total.numpy()[0], np.float32(want_sums.astype(np.float64).sum() + 3.0), rtol=1e-5)
    cd = copy_dst.numpy()
    np.testing.assert_allclose(cd[0], np.array([1.0, -2.0, 0.5], np.float32) * np.float32(1.5) + [5, 0, 0], rtol=1e-6)
    np.testing.assert_allclose(cd[1:], want_out[:-1], rtol=1e-6, atol=1e-6)


def test_record_marks_what_it_cannot_replay():
    """A host read, a host write or a vector fill inside the recording sets ``problem`` (the replay would keep
    what the Python decided then); recordings do not nest; and only the recording thread is recorded."""
    x = wp.zeros(8, dtype=float, device=DEV)
    v = wp.zeros(8, dtype=wp.vec3, device=DEV)
    for body, word in ((lambda: x.numpy(), "read"), (lambda: x.assign(np.ones(8, np.float32)), "write"),
                       (lambda: v.fill_(wp.vec3(1.0, 2.0, 3.0)), "fill_")):
        with parallel.record() as prog:
            x.zero_()
            body()
        assert prog.problem is not None and word in prog.problem
    with parallel.record() as prog:
        with pytest.raises(RuntimeError, match="does not nest"):
            with parallel.record():
                pass
        t = threading.Thread(target=lambda: (x.fill_(3.0), x.numpy(),
                                             parallel.launch(_twice_index_kernel, 8, outputs=[x], device=DEV)))
        t.start()
        t.join()
    assert prog.problem is None and prog.ops == []
    np.testing.assert_array_equal(x.numpy(), np.arange(8, dtype=np.float32) * 2.0)
    # the patched Warp calls are restored
    from warp._src.context import Launch
    assert wp.launch.__module__.startswith("warp") and Launch.launch.__qualname__ == "Launch.launch"
    assert wp.array.zero_.__qualname__ == "array.zero_"


def test_record_keeps_code_and_struct_arrays_alive(every_band, tmp_path):
    """A recorded band launch keeps its loaded module: after the module is rebuilt (a kernel added to it) and the
    same launch made eagerly again, the replay still runs (it called unloaded code before). A recorded launch
    keeps the arrays a Warp struct argument pointed to when recorded, after the field is reassigned."""
    out = _run_script(tmp_path, _RECORD_RELOAD_SCRIPT)
    assert "replayed [4. 4. 4.]" in out and "struct array kept True" in out, out


_RECORD_RELOAD_SCRIPT = """
import gc, weakref
import numpy as np
import warp as wp
wp.config.quiet = True
from foveawarp import parallel
parallel.MIN_ITEMS_PER_BAND = 0

@wp.kernel
def add_one(a: wp.array(dtype=float), row0: int):
    i = wp.tid() + row0
    a[i] = a[i] + 1.0

@wp.struct
class Holder:
    out: wp.array(dtype=float)

@wp.kernel
def put_seven(h: Holder, row0: int):
    i = wp.tid() + row0
    h.out[i] = 7.0

a = wp.zeros(64, dtype=float, device="cpu")
with parallel.cpu_threads(2):
    parallel.launch(add_one, 64, inputs=[a], device="cpu")
    with parallel.record() as prog:
        parallel.launch(add_one, 64, inputs=[a], device="cpu")

def _sub(b: wp.array(dtype=float), row0: int):
    i = wp.tid() + row0
    b[i] = b[i] - 1.0

k2 = wp.Kernel(_sub, key="sub_one", module=add_one.module)
wp.launch(k2, 8, inputs=[wp.zeros(8, dtype=float, device="cpu"), 0], device="cpu")  # the module is rebuilt
with parallel.cpu_threads(2):
    parallel.launch(add_one, 64, inputs=[a], device="cpu")  # the same launch, packed anew for the new module
    gc.collect()
    prog.replay()
print("replayed", a.numpy()[:3])

h = Holder()
h.out = wp.zeros(64, dtype=float, device="cpu")
ref = weakref.ref(h.out)
with parallel.cpu_threads(2):
    with parallel.record() as prog2:
        parallel.launch(put_seven, 64, inputs=[h], device="cpu")
h.out = wp.zeros(64, dtype=float, device="cpu")  # the recorded array's last outside reference
gc.collect()
with parallel.cpu_threads(2):
    prog2.replay()
print("struct array kept", ref() is not None and bool((ref().numpy() == 7.0).all()))
"""


def test_record_in_several_threads_and_inside_frames():
    """Two threads record at once, each into its own program; a FrameLoop rendered inside the caller's own
    recording runs its body eagerly (so the caller's program holds the frame's work, and replays it); recordings
    do not nest within a thread."""
    x = [wp.zeros(8, dtype=float, device=DEV) for _ in range(2)]
    progs, barrier = [None, None], threading.Barrier(2)

    def body(k):
        with parallel.record() as prog:
            barrier.wait()  # both recordings open at once
            parallel.launch(_twice_index_kernel, 8, outputs=[x[k]], device=DEV)
            barrier.wait()
        progs[k] = prog

    ts = [threading.Thread(target=body, args=(k,)) for k in range(2)]
    [t.start() for t in ts]
    [t.join() for t in ts]
    assert [p.problem for p in progs] == [None, None] and [len(p.ops) for p in progs] == [1, 1]
    assert not parallel.recording_active() and wp.launch.__module__.startswith("warp")
    for k in range(2):
        x[k].zero_()
        progs[k].replay()
        np.testing.assert_array_equal(x[k].numpy(), np.arange(8, dtype=np.float32) * 2.0)

    scene = fw.load_scene("cornell")
    loop = fw.FrameLoop(scene, 40, 24, device=DEV, timing=False, policy="foveated", cpu_threads=2)
    for i in range(5):
        loop.render(scene.camera_at(i / 60.0), gaze_px=(20.0, 12.0))
    cam = scene.camera_at(5 / 60.0)
    with parallel.record() as prog:
        f = loop.render(cam, gaze_px=(20.0, 12.0))
        with pytest.raises(RuntimeError, match="does not nest"):
            with parallel.record():
                pass
    assert f.stats["graph"].startswith("eager (inside") and prog.problem is None and prog.ops
    want = f.numpy().copy()
    loop.image.zero_()
    prog.replay()  # the frame body's work, recorded by the caller
    np.testing.assert_array_equal(loop.image.numpy(), want)


@pytest.mark.parametrize("case", ["asarray", "utils", "raises", "positional"])
def test_record_refuses_unseen_work_and_accepts_call_forms(case):
    """A NumPy view of an array, a warp.utils call running native code, or an exception leaving the block set
    ``problem``; wp.launch with its arguments given positionally (record_cmd among them) is recorded."""
    a = wp.zeros(8, dtype=float, device=DEV)
    if case == "raises":
        with pytest.raises(ValueError):
            with parallel.record() as prog:
                a.zero_()
                raise ValueError("half-way")
        assert "raised ValueError" in prog.problem
    elif case == "positional":
        with parallel.record() as prog:
            wp.launch(_twice_index_kernel, 8, [], [a, 0], [], [], DEV, None, False, True, False)
        assert prog.problem is None and len(prog.ops) == 1
        a.zero_()
        prog.replay()
        np.testing.assert_array_equal(a.numpy(), np.arange(8, dtype=np.float32) * 2.0)
    else:
        with parallel.record() as prog:
            if case == "asarray":
                np.asarray(a)
            else:
                wp.utils.array_sum(a)
        assert prog.problem is not None and ("__array_interface__" in prog.problem or "warp.utils" in prog.problem)
    assert wp.launch.__module__.startswith("warp") and not parallel.recording_active()


@pytest.mark.parametrize("threads", [1, 3])
def test_sampling_in_the_resolve_launch_equals_separate_launches(threads):
    """The CPU frame without timing runs the sampling pass inside the shading and resolve launch
    (``sample_shade_resolve_rows_kernel``); with ``timing=True`` (stage times wanted) the two stay apart. Whole
    moving frames, foveated, byte for byte: the image, the sample map, cache hits, previous indices, the sample
    count, the history."""
    size = (70, 41)  # partial tiles, more than one 64-pixel mask per row
    runs = []
    for timing in (False, True):
        fl = fw.FrameLoop("cornell", *size, device=DEV, cpu_threads=threads, timing=timing, policy="foveated")
        out = []
        for i in range(4):
            fr = fl.render(fl.scene.camera_at(0.08 * i), gaze_px=(size[0] * (0.3 + 0.1 * i), size[1] * 0.5),
                           time=0.08 * i)
            out += [fr.numpy().copy(), fr.sampling_map.numpy().copy(), fl.sampling.cache_hit.numpy().copy(),
                    fl.sampling.prev_index.numpy().copy(), fl.sampling.num_samples.numpy().copy(),
                    fl.sampling.num_cache_hits.numpy().copy(), fl.temporal.color.numpy().copy(),
                    fl.temporal.filled.numpy().copy()]
        runs.append(out)
    for i, (a, b) in enumerate(zip(*runs)):
        assert a.tobytes() == b.tobytes(), i


def test_sampling_in_the_resolve_launch_refuses_wrong_buffers():
    """``TemporalStage.run(sampling=...)`` names the mistakes that would race or write the wrong map: no shading
    stage, another sample map than the sampling stage's, and a cache-test history that the resolve writes."""
    w, h = 40, 24
    fl = fw.FrameLoop("cornell", w, h, device=DEV, cpu_threads=1, timing=False, policy="foveated")
    fl.render(fl.scene.camera_at(0.0))
    fl.render(fl.scene.camera_at(0.05))  # the stages have a frame set up
    t, s, g = fl.temporal, fl.sampling, fl.gbuffer
    good = s.rows_pass_args(g, depth_prev=t.depth, valid_prev=t.filled, face_lab=fl.dscene.face_lab)
    with pytest.raises(ValueError, match="needs shade"):
        t.run(s.sample_map, g, fl.radiance, fl.radiance_stoch, sampling=good)
    other = wp.zeros((h, w), dtype=wp.uint8, device=DEV)
    with pytest.raises(ValueError, match="sample_map must be"):
        t.run(other, g, fl.radiance, fl.radiance_stoch, shade=fl.shade, sampling=good)
    cur = 1 - t._cur
    bad = s.rows_pass_args(g, depth_prev=t._depth[cur], valid_prev=t.filled, face_lab=fl.dscene.face_lab)
    with pytest.raises(ValueError, match="must not be the history"):
        t.run(s.sample_map, g, fl.radiance, fl.radiance_stoch, shade=fl.shade, sampling=bad)
