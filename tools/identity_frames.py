"""Frame identity across a code change: every output of foveated, full and reference frames, saved or compared.

Renders a short sequence of a moving camera and gaze per scene and case (deterministic shading, 2 AO rays, a
small fovea, a still view that reaches the refresh budget, depth of field with the light-tree indirect term, the
sparse G-buffer, the full-resolution policy, the default "auto" policy through its first measurement, and the
full-resolution reference frame) and saves, or compares against a saved run byte for byte, every output: image,
temporal sparse colour and filled mask, sampling map, cache hits, previous-pixel index, the rates, and the
G-buffer's channels (position, normal, depth, face, hit, reprojection UV, velocity, albedo).

    # the old code, imported through PYTHONPATH (a worktree of the old commit), this file from the new tree:
    PYTHONPATH=OLD_TREE python tools/identity_frames.py --device cpu --save old.npz
    # the new code:
    python tools/identity_frames.py --device cpu --compare old.npz

Runs on ``--device cuda:0`` too (compared the same way). ``--compare`` prints one line per case (scene.case: max
abs difference, differing pixels of the images and differing values of all arrays) and exits with status 1 when
any array differs or is missing.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

# depth of field (a lens of 4 mm, focused at the gaze) with the light-tree indirect term
DOF_INDIRECT = {"dof": {"aperture_m": 0.004}, "shading": {"indirect": "lighttree"}}
# case -> (config overrides, policy, frames: None = --frames; "reference": render_reference)
CASES = {
    "default": ({}, "foveated", None),
    "ao2": ({"shading": {"ao_samples": 2}}, "foveated", None),
    # a small fovea (more pixels resolved from history), and a still view that reaches the refresh budget
    "periphery": ({"foveation": {"fovea_deg": 1.0, "falloff_deg": 4.0}}, "foveated", None),
    "periphery-ao2": ({"foveation": {"fovea_deg": 1.0, "falloff_deg": 4.0}, "shading": {"ao_samples": 2}},
                      "foveated", None),
    "still-ao2": ({"foveation": {"block": 2}, "temporal": {"max_history_frames": 3}, "shading": {"ao_samples": 2}},
                  "foveated", None),
    "dof-indirect": (DOF_INDIRECT, "foveated", None),
    "sparse-ao2": ({"foveation": {"gbuffer": "sparse"}, "shading": {"ao_samples": 2}}, "foveated", None),
    "full": ({}, "full", None),
    "full-dof-indirect": (DOF_INDIRECT, "full", None),
    # the default policy: its first measurement renders 12 foveated frames, then 12 full ones, whatever the times
    "auto": ({}, None, 16),
    "reference": ({}, "reference", None),
    "reference-dof-indirect": (DOF_INDIRECT, "reference", None),
}
STILL_FROM = 3  # "still" cases: the camera and gaze stop moving at this frame
SCENES = ("cornell", "city", "earth")
GBUFFER = ("position", "normal", "depth", "face", "hit", "reproj_uv", "velocity", "albedo")


def render_all(device: str, width: int, height: int, frames: int, bvh=None) -> dict:
    import foveawarp as fw

    print(f"foveawarp from {fw.__file__}", flush=True)
    out = {}
    for scene_name in SCENES:
        scene = fw.load_scene(scene_name)
        if bvh is not None:  # (constructor, leaf size): the Scene fields (trees from 1f42f5e on)
            scene.bvh_constructor, scene.bvh_leaf_size = bvh
        for cname, (over, policy, n) in CASES.items():
            cfg = fw.Config().with_(**over) if over else fw.Config()
            reference = policy == "reference"
            loop = fw.FrameLoop(scene, width, height, config=cfg, device=device, timing=False, graph=False,
                                policy="full" if reference else policy, cpu_threads=1)
            for i in range(frames if n is None else n):
                j = i  # the frame's number in the sequence (render_reference does not count frames)
                if cname.startswith("still"):
                    i = min(i, STILL_FROM)
                t = i / 20.0
                cam = scene.camera_at(t)
                if not scene.is_animated:  # a camera that moves (orbit-ish shift of the eye along x)
                    cam = fw.Camera(eye=tuple(e + (0.03 * i if k == 0 else 0.0) for k, e in enumerate(cam.eye)),
                                    target=cam.target, up=cam.up, fov_y_deg=cam.fov_y_deg)
                gaze = (width * (0.5 + 0.25 * np.sin(0.7 * i)), height * (0.5 + 0.2 * np.cos(0.5 * i)))
                if reference:
                    f = loop.render_reference(cam, gaze_px=gaze, time=t)
                    key = f"{scene_name}.{cname}.{j}"
                else:
                    f = loop.render(cam, gaze_px=gaze, time=t)
                    key = f"{scene_name}.{cname}.{loop.frame_index - 1}"
                out[key + ".image"] = f.numpy().copy()
                out[key + ".sample_map"] = f.sampling_map.numpy().copy()
                out[key + ".rates"] = np.array([f.stats["sampling_rate"], f.stats["cache_hit_rate"]])
                if "sparse" in f.extras:  # foveated frames
                    out[key + ".sparse"] = f.extras["sparse"].numpy().copy()
                    out[key + ".filled"] = f.extras["filled"].numpy().copy()
                    out[key + ".cache_hit"] = loop.sampling.cache_hit.numpy().copy()
                    out[key + ".prev_index"] = loop.sampling.prev_index.numpy().copy()
                for name in GBUFFER:  # velocity and albedo derived on read, the others stored
                    out[key + ".gbuffer_" + name] = getattr(f.gbuffer, name).numpy().copy()
                out[key + ".skipped"] = np.array(sorted(f.stats["skipped"]))
    return out


def compare(ref: dict, got: dict) -> tuple:
    """One line per case (scene.case) of ``ref``: arrays compared, max abs difference, differing image pixels and
    differing values, marked DIFFERS where any array differs or is missing. Returns (lines, whether any differs)."""
    cases: dict = {}
    for k in sorted(ref):
        cases.setdefault(".".join(k.split(".")[:2]), []).append(k)
    lines, any_bad = [], False
    for case, keys in cases.items():
        worst, pixels, values, bad = 0.0, 0, 0, []
        for k in keys:
            a, b = ref[k], got.get(k)
            if b is None or a.shape != b.shape or a.dtype != b.dtype:
                bad.append(k.split(".", 2)[2] + (" missing" if b is None else " shape/dtype"))
                continue
            if a.tobytes() == b.tobytes():
                continue
            bad.append(k.split(".", 2)[2])
            if a.dtype.kind in "fiub":
                d = np.abs(a.astype(np.float64) - b.astype(np.float64))
                d = np.where(np.isnan(d), np.inf, d)
                worst = max(worst, float(d.max()))
                values += int((a != b).sum())
                if k.endswith(".image"):
                    pixels += int((a != b).reshape(a.shape[0], a.shape[1], -1).any(axis=-1).sum())
            else:
                values += int((a != b).sum())
        any_bad |= bool(bad)
        line = (f"{case}: {len(keys)} arrays, {'DIFFERS' if bad else 'identical'}: max abs {worst:.3g}, "
                f"{pixels} image pixels, {values} values differ")
        if bad:
            line += " (" + ", ".join(bad[:6]) + (", ..." if len(bad) > 6 else "") + ")"
        lines.append(line)
    extra = sorted(set(got) - set(ref))
    if extra:
        more = ", ..." if len(extra) > 4 else ""
        lines.append(f"not in the saved run: {len(extra)} arrays ({', '.join(extra[:4])}{more})")
    return lines, any_bad


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cpu")
    p.add_argument("--size", default="96x64")
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--bvh", default=None, help="the scenes' BVH as CTOR or CTOR-LEAF, e.g. sah-4 (default: theirs)")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", help="write the arrays to this .npz")
    g.add_argument("--compare", help="compare against this .npz")
    a = p.parse_args(argv)
    w, h = (int(v) for v in a.size.split("x"))
    bvh = None
    if a.bvh:  # trees from 1f42f5e on (older ones have no BVH fields; run them without --bvh)
        from foveawarp.scene import BVH_CONSTRUCTORS, BVH_MAX_LEAF

        ctor, dash, leaf = a.bvh.partition("-")
        if ctor not in BVH_CONSTRUCTORS or (dash and not (leaf.isdigit() and 1 <= int(leaf) <= BVH_MAX_LEAF)):
            p.error(f"--bvh must be CTOR or CTOR-LEAF with CTOR in {list(BVH_CONSTRUCTORS)} and LEAF in "
                    f"[1, {BVH_MAX_LEAF}], got {a.bvh!r}")
        bvh = (ctor, int(leaf) if leaf else None)
    got = render_all(a.device, w, h, a.frames, bvh)
    if a.save:
        np.savez_compressed(a.save, **got)
        print(f"saved {len(got)} arrays to {a.save}")
        return 0
    lines, bad = compare(dict(np.load(a.compare)), got)
    for line in lines:
        print(line)
    print("frames differ" if bad else "all frames identical")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
