"""Every Warp kernel of the package compiles for CUDA (sm_90 PTX through Warp's NVRTC), also on machines without a
GPU: the native snippets (``kernels/load.py``, the disc scan, the Sibson tap loop) are C++ that the CPU build and
the CUDA build compile separately, so a CPU-only test run would not see a CUDA-only error."""

import concurrent.futures
import importlib
import multiprocessing
import os
import pkgutil

import pytest
import warp as wp

import foveawarp
import foveawarp.kernels


def _kernel_modules():
    """The Warp modules of every kernel defined in foveawarp's kernel modules (``module="unique"`` ones included)."""
    mods = {}
    for info in pkgutil.iter_modules(foveawarp.kernels.__path__):
        py = importlib.import_module(f"foveawarp.kernels.{info.name}")
        for obj in vars(py).values():
            if isinstance(obj, wp.Kernel):
                mods[obj.module.name] = obj.module
    return mods


# the largest modules first, so that the others fill the other workers meanwhile (PTX on 2 cores: path 38 s,
# gbuffer_textured 20 s, shade_textured 18 s, the other 25 together 19 s)
_FIRST = ("foveawarp.kernels.path", "foveawarp.kernels.gbuffer_textured", "foveawarp.kernels.shade_textured")


def _compile_one(name: str, module_dir: str) -> list:
    """Worker: the PTX of kernel module ``name`` (a fresh process finds it again by name)."""
    wp.config.quiet = True
    mods = _kernel_modules()
    assert name in mods, f"{name} not found in a fresh process: {sorted(mods)}"
    return [str(p) for p in wp.compile_aot_module(mods[name], arch=90, module_dir=module_dir, use_ptx=True)]


@wp.kernel(enable_backward=False)
def _probe_kernel(a: wp.array(dtype=float)):
    a[wp.tid()] = 1.0


def test_every_kernel_module_compiles_for_cuda(tmp_path):
    mods = _kernel_modules()
    assert len(mods) >= 15  # every kernels/ file with kernels, and the unique-module ones
    # Whether this Warp build can compile CUDA at all is decided on a one-line kernel of this file, so that a
    # failing package module can never be mistaken for a missing compiler: it always fails the test.
    try:
        wp.compile_aot_module(_probe_kernel.module, arch=90, module_dir=str(tmp_path / "probe"), use_ptx=True)
    except Exception as e:
        pytest.skip(f"this Warp build cannot compile CUDA without a GPU (a one-line probe kernel failed: {e})")
    names = [n for n in _FIRST if n in mods] + sorted(set(mods) - set(_FIRST))
    workers = max(1, min(len(os.sched_getaffinity(0)), 4))
    with concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as ex:
        outs = list(ex.map(_compile_one, names, [str(tmp_path / "m")] * len(names)))
    for name, out in zip(names, outs):
        assert out, name


def test_shading_register_caps_reach_the_cubin(tmp_path):
    """The CUDA register caps of the shading kernels (kernels/shade.py, as measured on the H100) are in the
    compiled sm_90 code: the AO full-frame twin and the list's AO pass at most 64 registers, the other full-frame
    shading at most 80; the uncapped list shading above 80 (the cap is what lowers the others)."""
    from tools.cuda_registers import cubin_kernels

    import foveawarp.kernels.shade as sh

    # As above, whether this Warp build can make a cubin at all is decided on the one-line probe kernel, so that a
    # failing shade module always fails the test instead of skipping it.
    try:
        wp.compile_aot_module(_probe_kernel.module, arch=90, module_dir=str(tmp_path / "probe"), use_ptx=False)
    except Exception as e:
        pytest.skip(f"this Warp build cannot compile CUDA cubins without a GPU (a one-line probe kernel failed: {e})")
    paths = wp.compile_aot_module(sh.shade_list_kernel.module, arch=90, module_dir=str(tmp_path), use_ptx=False)
    regs = {}
    for p in paths:
        for k, v in cubin_kernels(p).items():
            regs[k.rsplit("_", 1)[0]] = v["registers"]
    assert 0 < regs["shade_full_tiles_ao_kernel"] <= 64
    assert 0 < regs["shade_ao_list_kernel"] <= 64
    assert 64 < regs["shade_full_tiles_kernel"] <= 80
    assert regs["shade_list_kernel"] > 80
