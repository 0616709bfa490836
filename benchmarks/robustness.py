"""Does the frame loop stay sound over many frames, and does it render the same on every run and device?

Parts (``--parts``, comma list; default both):

* ``soak``: one foveated FrameLoop renders ``--frames`` frames (10,000 at 1920x1080; ``--quick`` 200 at 128x72)
  with the camera on the scene's path, a gaze that leaves the screen a third of the time, moving objects and
  forced camera cuts: frame-time percentiles and drift, NaN / Inf checks of the display image, memory after the
  warm-up (Warp's mempool on CUDA, the process RSS on the CPU). Passes when memory stays flat and no value is
  non-finite (``benchmarks/_soak.py``).
* ``parity``: a fixed, seeded 6-frame sequence (cornell with motion, 256x144, 4 AO rays) rendered twice in fresh
  loops on ``--device`` (every array bit-identical) and, with ``--compare FILE.npz``, against the arrays another
  device saved with ``--save`` (per-array differences, the tolerances of ``benchmarks/_parity.py``).

The exit status is 1 when a part fails. Writes robustness-<tag>.json / .md and robustness-<tag>.png (the soak's
frame time per check window and its memory samples).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks import _parity, _soak  # noqa: E402
from benchmarks._common import base_parser, plot_path, progress, pyplot, write_results  # noqa: E402

PARTS = ("soak", "parity")
# after the CPU half: robustness.py --parts parity --device cpu --save benchmarks/out/parity-cpu.npz
CANONICAL = ("python benchmarks/robustness.py --device cuda:0 --out benchmarks/results --tag h200 "
             "--compare benchmarks/out/parity-cpu.npz")


def main(argv=None) -> int:
    p = base_parser(__doc__, CANONICAL)
    p.set_defaults(warmup=None)
    p.add_argument("--parts", default=",".join(PARTS), help=f"comma list of {', '.join(PARTS)}")
    _soak.add_options(p)
    _parity.add_options(p)
    args = p.parse_args(argv)
    parts = [s for s in args.parts.split(",") if s]
    if not parts or any(s not in PARTS for s in parts) or len(set(parts)) != len(parts):
        p.error(f"--parts must be a comma list of distinct items of {', '.join(PARTS)}, got {args.parts!r}")
    if (args.save or args.compare) and "parity" not in parts:
        p.error("--save and --compare belong to the parity part: add parity to --parts")
    if args.compare and not Path(args.compare).is_file():
        p.error(f"--compare must name a .npz file saved with --save, got {args.compare!r} (no such file)")
    soak_settings = _soak.settings(p, args) if "soak" in parts else None
    import foveawarp as fw

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device)
    records, mds, passed = [], [], True
    total = (soak_settings["frames"] if soak_settings else 0) + ("parity" in parts)
    with progress(None, "robustness", total=total) as bar:
        for part in parts:
            if part == "soak":
                rec, md, ok = _soak.run(fw, dev, args, soak_settings, bar)
            else:
                rec, md, ok = _parity.run(fw, dev, args)
                bar.update(1)
            records.append(rec)
            mds.append(md)
            passed = passed and ok
    md = "\n".join(mds) + f"\nRobustness: **{'PASS' if passed else 'FAIL'}** ({', '.join(parts)})\n"
    write_results("robustness", dev, records, md, args.out, args.tag, extra={"parts": parts, "pass": passed})
    soak = next((r for r in records if r["part"] == "soak"), None)
    if soak is not None:
        plot(soak, plot_path("robustness", dev, args.out, args.tag), dev)
    print(md)
    return 0 if passed else 1


def plot(rec: dict, path: Path, dev) -> None:
    """The soak at a glance: median frame ms per check window (left) and the memory samples (right)."""
    plt = pyplot()
    if plt is None:
        return
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.2))
    every = rec["check_every"]
    a.plot([rec["warmup"] + k * every for k in range(len(rec["window_median_ms"]))], rec["window_median_ms"], ".-")
    a.set_xlabel("frame")
    a.set_ylabel(f"median frame ms per {every} frames")
    a.set_ylim(bottom=0)
    key = "mempool_used" if any("mempool_used" in s for s in rec["memory_samples"]) else "host_rss"
    b.plot([s["frame"] for s in rec["memory_samples"]], [s[key] / _soak.MIB for s in rec["memory_samples"]], ".-")
    b.set_xlabel("frame")
    b.set_ylabel(f"{'Warp mempool in use' if key == 'mempool_used' else 'process RSS'} MiB")
    fig.suptitle(f"soak: {rec['scene']} {rec['width']}x{rec['height']}, {rec['frames']} frames "
                 f"({wp.get_device(dev).alias})", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
