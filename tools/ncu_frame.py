"""Hardware counters of every kernel of one foveated frame and one reference frame (Nsight Compute), against
the memory bound: how far each pass is from the time its DRAM traffic needs at the GPU's copy bandwidth.

A pass over every pixel costs about 0.1 ms at 3840x2160 when it is bound by memory bandwidth (H100).
``kernel_profile.py`` gives each kernel's time; this gives the bytes it moved, so each time can be set against
its own floor: ``floor_ms = (DRAM bytes read + written) / copy bandwidth``, the copy bandwidth measured in the
same run by a device-to-device copy of 1 GiB (read + write bytes over its time). A kernel near its floor can only
get faster by moving fewer bytes; one far above it is bound by something else (latency, instructions,
occupancy), which the SM throughput and achieved occupancy columns hint at.

Run (a CUDA machine with ``ncu`` on the PATH; ``--clock-control none`` leaves the clocks alone)::

    python tools/ncu_frame.py --device cuda:0 --scenes cornell,bunny --sizes 1920x1080,3840x2160

It starts ``ncu`` on itself with ``--drive``: the driver renders warm-up frames untimed (eager launches, no
graphs, so every kernel is its own launch), then brackets a marker kernel, one foveated frame, a second marker and one
reference frame with cuProfilerStart / cuProfilerStop. The kernels of both frames are then read back from the report.
Results: ``ncu-frame-<tag>.{json,md}`` under ``--out`` (default benchmarks/out); each record names the device,
scene, size and shading, the file the commit.
"""

from __future__ import annotations

import argparse
import csv
import ctypes
import io
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import (base_parser, checked_shadings_sizes, md_table, scenes_present,  # noqa: E402
                                shading_config, write_results)

METRICS = (
    "gpu__time_duration.sum",
    "dram__bytes_read.sum",
    "dram__bytes_write.sum",
    "dram__throughput.avg.pct_of_peak_sustained_elapsed",
    "lts__t_bytes.sum",
    "sm__throughput.avg.pct_of_peak_sustained_elapsed",
    "sm__warps_active.avg.pct_of_peak_sustained_active",
    "launch__registers_per_thread",
)


@wp.kernel(enable_backward=False)
def ncu_foveated_marker_kernel(a: wp.array(dtype=int)):
    """Launched before each profiled foveated frame: the kernels after it are that frame's."""
    a[0] = 1


@wp.kernel(enable_backward=False)
def ncu_reference_marker_kernel(a: wp.array(dtype=int)):
    """Launched before each profiled reference frame: the kernels after it are that frame's."""
    a[0] = 2


def _profiler(on: bool, device) -> None:
    """cuProfilerStart / cuProfilerStop (nothing on the CPU, where the driver runs only as a smoke test)."""
    if not device.is_cuda:
        return
    lib = ctypes.CDLL("libcuda.so.1")
    rc = (lib.cuProfilerStart if on else lib.cuProfilerStop)()
    if rc != 0:
        raise RuntimeError(f"cuProfiler{'Start' if on else 'Stop'} returned {rc}")


def drive(args) -> None:
    """Under ncu: per (scene, size, shading) warm up, then profile one foveated and one reference frame."""
    import foveawarp as fw

    dev = wp.get_device(args.device)
    marker = wp.zeros(1, dtype=int, device=dev)
    for k in (ncu_foveated_marker_kernel, ncu_reference_marker_kernel):  # loaded before the profiled ranges
        wp.launch(k, dim=1, inputs=[marker], device=dev)
    for scene in scenes_present(fw, args.scenes):
        for size in args.sizes.split(","):
            w, h = (int(v) for v in size.split("x"))
            for shading in args.shadings.split(","):
                loop = fw.FrameLoop(scene, w, h, config=shading_config(fw, shading), device=dev, timing=False,
                                    graph=False, policy="foveated")
                for i in range(args.warmup_frames):  # along the camera path, as the profiled frame is
                    t = i / 30.0
                    loop.render(scene.camera_at(t), time=t)
                    loop.render_reference(scene.camera_at(t), time=t)
                t = args.warmup_frames / 30.0
                cam = scene.camera_at(t)
                wp.synchronize_device(dev)
                print(f"CONFIG {scene.name} {w} {h} {shading}", flush=True)
                _profiler(True, dev)
                wp.launch(ncu_foveated_marker_kernel, dim=1, inputs=[marker], device=dev)
                f = loop.render(cam, time=t)
                wp.launch(ncu_reference_marker_kernel, dim=1, inputs=[marker], device=dev)
                loop.render_reference(cam, time=t)
                wp.synchronize_device(dev)
                _profiler(False, dev)
                print(f"RATE {f.stats['sampling_rate']:.4f}", flush=True)


def copy_bandwidth(device) -> float:
    """Bytes per second of a device-to-device copy of 1 GiB, counting the bytes read and written."""
    n = (1 << 30) // 4
    a = wp.zeros(n, dtype=wp.float32, device=device)
    b = wp.zeros(n, dtype=wp.float32, device=device)
    for _ in range(3):
        wp.copy(b, a)
    wp.synchronize_device(device)
    ts = []
    for _ in range(10):
        t0 = time.perf_counter()
        wp.copy(b, a)
        wp.synchronize_device(device)
        ts.append(time.perf_counter() - t0)
    ts.sort()
    return 2.0 * n * 4 / ts[len(ts) // 2]


def _num(v: str) -> float:
    return float(v.replace(",", "")) if v not in ("", "n/a") else float("nan")


def kernel_name(mangled: str) -> str:
    """Warp's CUDA entry name without its module hash and suffix: ``sibson_gather_kernel_ce134398_cuda_kernel_forward``
    -> ``sibson_gather_kernel``."""
    m = re.match(r"(.*?)_[0-9a-f]{8}_cuda_kernel_forward", mangled.split("(")[0].strip())
    return m.group(1) if m else mangled.split("(")[0].strip()


def read_report(rep: Path, ncu: str) -> list:
    """The report's kernels in launch order, each with its metrics."""
    text = subprocess.run([ncu, "--import", str(rep), "--csv", "--page", "raw", "--print-units", "base"],
                          check=True, capture_output=True, text=True).stdout
    rows = []
    for r in csv.DictReader(io.StringIO(text)):
        if not r.get("ID", "").strip().isdigit():
            continue  # the units row
        rows.append({"kernel": kernel_name(r.get("Kernel Name", "")), **{m: _num(r.get(m, "")) for m in METRICS}})
    return rows


def summarize(rows: list) -> dict:
    """The frame's totals from its :func:`kernel_row` rows."""
    by = sum(r["dram_read_B"] + r["dram_write_B"] for r in rows)
    return {"gpu_ms": sum(r["ms"] for r in rows), "dram_bytes": by,
            "bytes_per_pixel": sum(r["bytes_per_pixel"] for r in rows), "floor_ms": sum(r["floor_ms"] for r in rows)}


def kernel_row(k: dict, bw: float, pixels: int) -> dict:
    ms = k["gpu__time_duration.sum"] * 1e-6
    by = k["dram__bytes_read.sum"] + k["dram__bytes_write.sum"]
    floor = by / bw * 1e3
    return {"kernel": k["kernel"], "ms": ms, "dram_read_B": k["dram__bytes_read.sum"],
            "dram_write_B": k["dram__bytes_write.sum"], "bytes_per_pixel": by / pixels, "floor_ms": floor,
            "x_floor": ms / floor if floor > 0 else float("inf"),
            "dram_pct": k["dram__throughput.avg.pct_of_peak_sustained_elapsed"],
            "l2_bytes_per_pixel": k["lts__t_bytes.sum"] / pixels,
            "sm_pct": k["sm__throughput.avg.pct_of_peak_sustained_elapsed"],
            "occupancy_pct": k["sm__warps_active.avg.pct_of_peak_sustained_active"],
            "registers": k["launch__registers_per_thread"]}


def main(argv=None) -> None:
    p = base_parser(__doc__.split("\n")[0])
    p.add_argument("--scenes", default="cornell,bunny,city")
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--shadings", default="default,ao8")
    p.add_argument("--warmup-frames", type=int, default=8, help="untimed frames before the profiled ones")
    p.add_argument("--drive", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--ncu", default=shutil.which("ncu") or "ncu", help="the ncu executable")
    args = p.parse_args(argv)
    checked_shadings_sizes(p, args)
    if args.drive:
        drive(args)
        return
    dev = wp.get_device(args.device)
    if not dev.is_cuda:
        p.error(f"--device must be a CUDA device (Nsight Compute profiles CUDA kernels), got {dev.alias}")
    if shutil.which(args.ncu) is None:
        p.error(f"--ncu: no executable {args.ncu!r} on this machine")
    bw = copy_bandwidth(dev)
    with tempfile.TemporaryDirectory() as tmp:
        rep = Path(tmp) / "frame"
        cmd = [args.ncu, "--clock-control", "none", "--profile-from-start", "off", "--metrics", ",".join(METRICS),
               "--export", str(rep), "--force-overwrite", sys.executable, str(Path(__file__).resolve()), "--drive",
               "--device", dev.alias, "--scenes", args.scenes, "--sizes", args.sizes, "--shadings", args.shadings,
               "--warmup-frames", str(args.warmup_frames)]
        t0 = time.perf_counter()
        run = subprocess.run(cmd, capture_output=True, text=True)
        print(run.stdout[-4000:], run.stderr[-4000:], sep="\n", flush=True)
        run.check_returncode()
        kernels = read_report(rep.with_suffix(".ncu-rep"), args.ncu)
        wall = time.perf_counter() - t0
    configs = [line.split()[1:] for line in run.stdout.splitlines() if line.startswith("CONFIG ")]
    rates = [float(line.split()[1]) for line in run.stdout.splitlines() if line.startswith("RATE ")]
    frames = _split(kernels)
    if len(frames) != len(configs):
        raise RuntimeError(f"{len(frames)} profiled frame pairs for {len(configs)} configurations")
    records, lines = [], []
    for (scene, w, h, shading), rate, (fov, ref) in zip(configs, rates, frames):
        w, h = int(w), int(h)
        n = w * h
        fk, rk = [kernel_row(k, bw, n) for k in fov], [kernel_row(k, bw, n) for k in ref]
        rec = {"scene": scene, "width": w, "height": h, "shading": shading, "sampling_rate": rate,
               "copy_bandwidth_GBps": bw / 1e9, "foveated": summarize(fk), "reference": summarize(rk),
               "foveated_kernels": fk, "reference_kernels": rk}
        records.append(rec)
        for part in ("foveated", "reference"):
            for k in rec[part + "_kernels"]:
                lines.append({"scene": scene, "size": f"{w}x{h}", "shading": shading, "frame": part[:3],
                              "kernel": k["kernel"], "ms": f"{k['ms']:.4f}",
                              "B/px": f"{k['bytes_per_pixel']:.1f}", "floor ms": f"{k['floor_ms']:.4f}",
                              "x floor": f"{k['x_floor']:.2f}", "DRAM %": f"{k['dram_pct']:.0f}",
                              "SM %": f"{k['sm_pct']:.0f}", "occ %": f"{k['occupancy_pct']:.0f}",
                              "regs": f"{k['registers']:.0f}"})
            s = rec[part]
            lines.append({"scene": scene, "size": f"{w}x{h}", "shading": shading, "frame": part[:3],
                          "kernel": "**all**", "ms": f"{s['gpu_ms']:.4f}", "B/px": f"{s['bytes_per_pixel']:.1f}",
                          "floor ms": f"{s['floor_ms']:.4f}", "x floor": f"{s['gpu_ms'] / s['floor_ms']:.2f}",
                          "DRAM %": "", "SM %": "", "occ %": "", "regs": ""})
    cols = ["scene", "size", "shading", "frame", "kernel", "ms", "B/px", "floor ms", "x floor", "DRAM %", "SM %",
            "occ %", "regs"]
    md = (f"Nsight Compute, one frame each, `--clock-control none`; copy bandwidth {bw / 1e9:.0f} GB/s "
          f"(1 GiB device copy, read + write); floor = DRAM bytes / copy bandwidth; profiling took {wall:.0f} s\n\n"
          + md_table(lines, cols))
    write_results("ncu-frame", dev, records, md, args.out, args.tag, extra={"config": {
        "scenes": args.scenes, "sizes": args.sizes, "shadings": args.shadings, "metrics": list(METRICS)}})
    print(md)


def _split(kernels: list) -> list:
    """Launch-ordered kernels -> [(foveated kernels, reference kernels)] per config, cut at the marker kernels
    (each foveated frame follows a foveated marker, each reference frame a reference marker)."""
    frames, part = [], None
    for k in kernels:
        if k["kernel"].startswith("ncu_foveated_marker"):
            frames.append(([], []))
            part = 0
        elif k["kernel"].startswith("ncu_reference_marker"):
            part = 1
        elif part is None:
            raise RuntimeError(f"kernel {k['kernel']} before the first marker")
        else:
            frames[-1][part].append(k)
    return frames


if __name__ == "__main__":
    main()
