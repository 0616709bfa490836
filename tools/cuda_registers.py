"""Registers, local-memory (spill) bytes and occupancy of the CUDA kernels of the frame path, without a GPU:
Warp compiles the kernel modules ahead of time with its bundled NVRTC for one architecture (default sm_90,
the H100), and this script reads each kernel's register count and frame size from the cubin's ELF notes.

A per-pixel kernel that is limited by memory latency needs many resident warps; an SM has 65,536 registers,
so with 256-thread blocks (Warp's default) it holds ``floor(65536 / (256 * registers))`` blocks (at most 8).
A kernel with 136 registers holds one block (8 warps of 64); one with 32 holds eight.

    python tools/cuda_registers.py [--arch 90] [--modules foveawarp.kernels.temporal,...]

(default: every module of foveawarp.kernels that holds kernels). Writes cuda-registers-sm<arch>.{json,md} under
``--out`` (default benchmarks/out); it runs on the host, the figures are for the named architecture.
"""

from __future__ import annotations

import importlib
import struct
import sys
import tempfile
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, write_results  # noqa: E402

REGS_PER_SM = 65536
MAX_THREADS_PER_SM = 2048
BLOCK = 256
# .nv.info attribute codes (EIATTR_*) and formats
EIFMT_SVAL, EIFMT_HVAL, EIFMT_BVAL = 4, 3, 2
EIATTR_FRAME_SIZE, EIATTR_REGCOUNT = 0x11, 0x2F


def _sections(b: bytes) -> list:
    shoff, = struct.unpack_from("<Q", b, 0x28)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", b, 0x3A)
    secs = [struct.unpack_from("<IIQQQQIIQQ", b, shoff + i * shentsize) for i in range(shnum)]
    stroff = secs[shstrndx][4]

    def name(o):
        return b[stroff + o:b.index(b"\0", stroff + o)].decode()

    return [(name(s[0]), s[1], s[4], s[5], s[6]) for s in secs]  # name, type, offset, size, link


def _symbols(b: bytes, secs: list) -> dict:
    out = {}
    for _, typ, off, size, link in secs:
        if typ == 2:  # SHT_SYMTAB
            stroff = secs[link][2]
            for i in range(size // 24):
                st_name, = struct.unpack_from("<I", b, off + 24 * i)
                out[i] = b[stroff + st_name:b.index(b"\0", stroff + st_name)].decode()
    return out


def cubin_kernels(path) -> dict:
    """{kernel symbol: {"registers": n, "frame_bytes": n}} of the entry points in a cubin."""
    b = Path(path).read_bytes()
    if b[:4] != b"\x7fELF":
        raise ValueError(f"{path} is not an ELF cubin")
    secs = _sections(b)
    syms = _symbols(b, secs)
    out: dict = {}
    for name, _, off, size, _ in secs:
        if not name.startswith(".nv.info"):
            continue
        p, end = off, off + size
        while p < end:
            fmt, attr = b[p], b[p + 1]
            p += 2
            if fmt == EIFMT_SVAL:
                n, = struct.unpack_from("<H", b, p)
                data = b[p + 2:p + 2 + n]
                p += 2 + n
                if attr in (EIATTR_REGCOUNT, EIATTR_FRAME_SIZE) and n == 8:
                    fi, val = struct.unpack_from("<II", data)
                    sym = syms.get(fi, str(fi))
                    if sym.endswith("_cuda_kernel_forward"):
                        key = "registers" if attr == EIATTR_REGCOUNT else "frame_bytes"
                        out.setdefault(sym[: -len("_cuda_kernel_forward")], {})[key] = val
            elif fmt == EIFMT_HVAL:
                p += 2
            elif fmt == EIFMT_BVAL:
                p += 1
    return out


def blocks_per_sm(registers: int, block: int = BLOCK) -> int:
    regs = max(8, (registers + 7) // 8 * 8)  # allocation granularity
    return max(0, min(MAX_THREADS_PER_SM // block, REGS_PER_SM // (regs * block)))


def main(argv=None):
    p = base_parser(__doc__)
    p.add_argument("--arch", type=int, default=90)
    p.add_argument("--modules", default="", help="comma-separated module names (default: foveawarp.kernels.*)")
    args = p.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    if args.modules:
        modules = args.modules.split(",")
    else:
        import pkgutil

        import foveawarp.kernels as fk

        modules = [f"foveawarp.kernels.{i.name}" for i in pkgutil.iter_modules(fk.__path__)]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for m in modules:
            mod = importlib.import_module(m)
            if not any(isinstance(v, wp.Kernel) for v in vars(mod).values()):
                continue  # functions only
            for path in wp.compile_aot_module(m, device=None, arch=args.arch, module_dir=tmp, use_ptx=False):
                for k, v in sorted(cubin_kernels(path).items()):
                    r = v.get("registers", 0)
                    nb = blocks_per_sm(r)
                    rows.append({"scene": None, "width": None, "height": None, "module": m.split(".")[-1],
                                 "kernel": k, "registers": r,
                                 "frame_bytes": v.get("frame_bytes", 0), "blocks_per_sm": nb,
                                 "occupancy": nb * BLOCK / MAX_THREADS_PER_SM})
    for r in rows:
        print(f"{r['kernel']:<45} regs {r['registers']:4d}  spill/stack {r['frame_bytes']:4d} B  "
              f"blocks/SM {r['blocks_per_sm']}  occupancy {r['occupancy']:.0%}")
    write_results("cuda-registers", "cpu", rows,
                  md_table(rows, ["module", "kernel", "registers", "frame_bytes", "blocks_per_sm", "occupancy"]),
                  args.out, args.tag or f"sm{args.arch}", extra={"arch": args.arch, "block": BLOCK})


if __name__ == "__main__":
    main()
