"""Summarise a per-kernel A/B of two library versions: the JSON that collects ``kernel_profile.py`` runs of each
version (alternating, several rounds) into ``{"new_commit", "old_commit", "runs": [{"code": "new"|"old", "round",
"shading", "records": [kernel_profile records]}]}``. Prints (and writes next to the JSON as .md) per scene, size and
shading: each version's time of the kernels whose name contains ``--kernel`` (mean over rounds, with the rounds'
spread), the foveated frame's GPU kernel sum and the reference's, and the speed-up of the sums.

How the runs are made (one machine session; see benchmarks/results/kernels-e44-*-cuda.log): each version's
``kernel_profile.py`` runs in turn, the old library extracted to a folder of its own and given first on
``PYTHONPATH`` (the benchmark scripts add the repository after ``PYTHONPATH``; before 542eca4 they put it first, so
the old library had to have the benchmarks copied beside it and be run from there). The kernel names' hashes in
the log show which library ran. (A check by ``python -c "import foveawarp"`` run inside the repository is no
proof: ``-c`` puts the working directory first on ``sys.path``.)

    python benchmarks/kernel_ab.py benchmarks/results/kernels-e44-38ddef7-vs-1346653-cuda.json --kernel resolve
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from benchmarks._common import md_table  # noqa: E402

# the table's columns (md_table formats floats to 3 decimals: the kernel times are given as 4-decimal strings)
COLUMNS = ["scene", "size", "shading", "old kernel ms", "new kernel ms", "new / old", "old fov sum", "new fov sum",
           "ref sum (old run / new run)", "speed-up of the sums old / new"]


def summarise(payload: dict, kernel: str) -> list[dict]:
    acc = defaultdict(lambda: defaultdict(list))
    for run in payload["runs"]:
        for rec in run["records"]:
            key = (rec["scene"], f"{rec['width']}x{rec['height']}", run["shading"])
            k_ms = sum(v for name, v in rec["foveated_kernels_ms"].items() if kernel in name)
            a = acc[key]
            a[f"{run['code']}_kernel"].append(k_ms)
            a[f"{run['code']}_fov"].append(rec["foveated_gpu_ms"])
            a[f"{run['code']}_ref"].append(rec["reference_gpu_ms"])
    rows = []
    for (scene, size, shading), a in acc.items():
        row = {"scene": scene, "size": size, "shading": shading}
        for code in ("old", "new"):
            for part in ("kernel", "fov", "ref"):
                v = np.asarray(a[f"{code}_{part}"], float)
                row[f"{code}_{part}_ms"] = float(v.mean()) if v.size else float("nan")
                row[f"{code}_{part}_spread_ms"] = float(v.max() - v.min()) if v.size else float("nan")
            row[f"{code}_speedup"] = row[f"{code}_ref_ms"] / row[f"{code}_fov_ms"]
        row["kernel_ratio"] = row["new_kernel_ms"] / row["old_kernel_ms"]
        row["fov_delta_ms"] = row["new_fov_ms"] - row["old_fov_ms"]
        rows.append(row)
    return rows


def to_markdown(rows: list[dict], payload: dict, kernel: str) -> str:
    head = (f"Per-kernel GPU times (CUDA activity timing, mean of {len({r['round'] for r in payload['runs']})} "
            f"alternating rounds of 20 frames each), {payload.get('device_name', '?')}: kernels matching "
            f"'{kernel}' at {payload['old_commit']} (old) and {payload['new_commit']} (new); the foveated frame's and "
            "the reference's kernel sums and their ratio.\n\n")
    cells = [dict(zip(COLUMNS, (r["scene"], r["size"], r["shading"], f"{r['old_kernel_ms']:.4f}",
                                f"{r['new_kernel_ms']:.4f}", r["kernel_ratio"], r["old_fov_ms"], r["new_fov_ms"],
                                f"{r['old_ref_ms']:.3f} / {r['new_ref_ms']:.3f}",
                                f"{r['old_speedup']:.3f} / {r['new_speedup']:.3f}"))) for r in rows]
    spread = max(max(r["old_kernel_spread_ms"], r["new_kernel_spread_ms"]) for r in rows)
    return head + md_table(cells, COLUMNS) + f"\nLargest spread of a kernel time between rounds: {spread:.4f} ms.\n"


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("json", help="the collected A/B JSON")
    p.add_argument("--kernel", default="resolve", help="substring of the kernel names to compare (default: resolve)")
    a = p.parse_args(argv)
    path = Path(a.json)
    payload = json.loads(path.read_text())
    if not payload.get("runs"):
        p.error(f"{path} holds no runs")
    rows = summarise(payload, a.kernel)
    md = to_markdown(rows, payload, a.kernel)
    path.with_suffix(".md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
