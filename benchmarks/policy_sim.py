"""The default policy's choices under synthetic frame times: its state machine (``FrameLoop._policy_mode``) driven
without rendering, each frame's time drawn from a model, to compare versions of the policy on noise and transients.

Model per frame: the path's cost (1.0 for full resolution, ``--fov-cost`` for the foveated frame) times a lognormal
factor (sigma ``--sigma``) times 1.3 during a slow episode (one starts with probability ``--episode`` per frame and
lasts 10 frames: a transient such as a clock dip). Reported per case over ``--seeds`` loops of ``--frames`` frames
(the first 100 not counted): the re-measurements started by the policy's watch, the mean cost per frame, and the
share of frames rendered on the dearer path. No GPU; the FrameLoop is a tiny CPU one that never renders.

To compare with another version of the policy, pass ``--foveawarp-root`` a folder holding that version's
``foveawarp`` package (e.g. ``git archive 8d61a32 foveawarp | tar -x -C /tmp/old``); versions before 64687b3
record timed frames in ``_pol_ms`` directly, and both are handled.

Results: ``policy-sim[-NAME]-cpu.{json,md}``.
"""

from __future__ import annotations

import random
import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

from benchmarks._common import base_parser, md_table, write_results  # noqa: E402


def simulate(fw, fov_cost: float, sigma: float, episode: float, seeds: int, frames: int) -> dict:
    rechecks = 0
    total = 0.0
    n = 0
    dearer = 0
    for seed in range(seeds):
        rnd = random.Random(seed)
        loop = fw.FrameLoop("cornell", 16, 8, device="cpu", policy="auto")
        slow = 0
        for frame in range(frames):
            if slow == 0 and rnd.random() < episode:
                slow = 10
            path, timed, watch = loop._policy_mode()
            factor = 1.3 if slow > 0 else 1.0
            slow = max(0, slow - 1)
            cost = fov_cost if path == "foveated" else 1.0
            t = cost * rnd.lognormvariate(0.0, sigma) * factor
            if timed:
                if hasattr(loop, "_policy_record"):
                    loop._policy_record(path, t)
                else:
                    loop._pol_ms[path].append(t)
            elif watch:
                loop._pol_watch_ms.append(t)
            loop.frame_index += 1
            if frame >= 100:
                total += cost
                n += 1
                dearer += cost > min(fov_cost, 1.0)
        rechecks += loop._pol_rechecks
    return {"fov_cost": fov_cost, "sigma": sigma, "episode": episode, "seeds": seeds, "frames": frames,
            "rechecks": rechecks, "mean_cost": total / n, "dearer_pct": 100.0 * dearer / n}


def main(argv=None) -> int:
    p = base_parser(__doc__.split("\n")[0])
    p.add_argument("--cases", default="1.1:0.03:0.005,0.9:0.03:0.005,1.1:0.05:0.01,0.9:0.05:0.01,1.0:0.1:0,"
                                      "0.97:0.1:0,0.93:0.1:0,1.2:0.1:0",
                   help="fov_cost:sigma:episode, comma-separated")
    p.add_argument("--seeds", type=int, default=40)
    p.add_argument("--frames", type=int, default=3000)
    p.add_argument("--name", default="", help="suffix of the results file stem")
    p.add_argument("--foveawarp-root", default=None, help="folder whose foveawarp package to simulate")
    a = p.parse_args(argv)
    if a.foveawarp_root:
        sys.path.insert(0, str(Path(a.foveawarp_root).resolve()))
    import warp as wp

    wp.config.quiet = True
    import foveawarp as fw

    print(f"foveawarp from {Path(fw.__file__).resolve().parent}", flush=True)
    cases = []
    for case in a.cases.split(","):
        try:
            c, s, e = (float(v) for v in case.split(":"))
        except ValueError:
            c = s = e = float("nan")
        if not (c > 0.0 and s >= 0.0 and 0.0 <= e <= 1.0):
            p.error(f"--cases: each case is fov_cost:sigma:episode with fov_cost > 0, sigma >= 0 and episode in "
                    f"[0, 1], got {case!r}")
        cases.append((c, s, e))
    rows = []
    for c, s, e in cases:
        rows.append(simulate(fw, c, s, e, 2 if a.quick else a.seeds, 400 if a.quick else a.frames))
        print(rows[-1], flush=True)
    md = md_table(rows, ["fov_cost", "sigma", "episode", "rechecks", "mean_cost", "dearer_pct"])
    write_results("policy-sim" + (f"-{a.name}" if a.name else ""), "cpu", {"rows": rows}, md, a.out)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
