"""Bit-identity check of the foveated frame path across a code change: render a short sequence of a moving
camera and gaze (deterministic shading, and 2 AO rays) and save, or compare against a saved run, every
per-frame output: image, temporal sparse colour and filled mask, sampling map, cache hits, previous-pixel
index, reconstruction input counts, the G-buffer's velocity and albedo.

    # on the old code (its checkout as the working directory, this file copied anywhere):
    python identity_frames.py --device cpu --save old.npz
    # on the new code:
    python benchmarks/identity_frames.py --device cpu --compare old.npz

Runs on ``--device cuda:0`` too (CUDA results are compared the same way, byte for byte). Exit status 1 when
any array differs.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

CONFIGS = {
    "default": {},
    "ao2": {"shading": {"ao_samples": 2}},
    # a small fovea (more pixels resolved from history), and a still view that reaches the refresh budget
    "periphery": {"foveation": {"fovea_deg": 1.0, "falloff_deg": 4.0}},
    "periphery-ao2": {"foveation": {"fovea_deg": 1.0, "falloff_deg": 4.0}, "shading": {"ao_samples": 2}},
    "still-ao2": {"foveation": {"block": 2}, "temporal": {"max_history_frames": 3}, "shading": {"ao_samples": 2}},
}
STILL_FROM = 3  # "still" configs: the camera and gaze stop moving at this frame
SCENES = ("cornell", "city", "earth")


def render_all(device: str, width: int, height: int, frames: int, bvh=None) -> dict:
    import foveawarp as fw

    print(f"foveawarp from {fw.__file__}", flush=True)
    out = {}
    for scene_name in SCENES:
        scene = fw.load_scene(scene_name)
        if bvh is not None:  # (constructor, leaf size): the Scene fields (trees from 1f42f5e on)
            scene.bvh_constructor, scene.bvh_leaf_size = bvh
        for cname, over in CONFIGS.items():
            cfg = fw.Config().with_(**over) if over else fw.Config()
            loop = fw.FrameLoop(scene, width, height, config=cfg, device=device, timing=False, graph=False,
                                policy="foveated", cpu_threads=1)
            for i in range(frames):
                if cname.startswith("still"):
                    i = min(i, STILL_FROM)
                t = i / 20.0
                cam = scene.camera_at(t)
                if not scene.is_animated:  # a camera that moves (orbit-ish shift of the eye along x)
                    cam = fw.Camera(eye=tuple(e + (0.03 * i if k == 0 else 0.0) for k, e in enumerate(cam.eye)),
                                    target=cam.target, up=cam.up, fov_y_deg=cam.fov_y_deg)
                gaze = (width * (0.5 + 0.25 * np.sin(0.7 * i)), height * (0.5 + 0.2 * np.cos(0.5 * i)))
                f = loop.render(cam, gaze_px=gaze, time=t)
                key = f"{scene_name}.{cname}.{loop.frame_index - 1}"
                out[key + ".image"] = f.numpy().copy()
                out[key + ".sparse"] = f.extras["sparse"].numpy().copy()
                out[key + ".filled"] = f.extras["filled"].numpy().copy()
                out[key + ".sample_map"] = f.sampling_map.numpy().copy()
                out[key + ".cache_hit"] = loop.sampling.cache_hit.numpy().copy()
                out[key + ".prev_index"] = loop.sampling.prev_index.numpy().copy()
                out[key + ".rates"] = np.array([f.stats["sampling_rate"], f.stats["cache_hit_rate"]])
                out[key + ".hit"] = f.gbuffer.hit.numpy().copy()
                for name in ("velocity", "albedo"):  # derived on read (session 22), stored before
                    out[key + ".gbuffer_" + name] = getattr(f.gbuffer, name).numpy().copy()
                out[key + ".skipped"] = np.array(sorted(f.stats["skipped"]))
    return out


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
    ref = dict(np.load(a.compare))
    bad = []
    for k in sorted(ref):
        if k not in got:
            bad.append(f"{k}: missing")
        elif ref[k].shape != got[k].shape or ref[k].tobytes() != got[k].tobytes():
            d = np.abs(ref[k].astype(np.float64) - got[k].astype(np.float64)) if ref[k].shape == got[k].shape else None
            bad.append(f"{k}: differs" + ("" if d is None else f" (max abs {d.max():.3g}, {int((d > 0).sum())} values)"))
    print(f"{len(ref)} arrays compared, {len(bad)} differ")
    for b in bad[:40]:
        print("  ", b)
    if bad:  # per scene: arrays that differ, and how far the displayed images moved
        for scene in sorted({k.split(".")[0] for k in ref}):
            keys = [k for k in ref if k.split(".")[0] == scene and k in got and ref[k].shape == got[k].shape]
            diff = [k for k in keys if ref[k].tobytes() != got[k].tobytes()]
            img = [np.abs(ref[k].astype(np.float64) - got[k].astype(np.float64)) for k in diff
                   if k.endswith(".image")]
            n_img = sum(1 for k in keys if k.endswith(".image"))
            print(f"   {scene}: {len(diff)} of {len(keys)} arrays differ; {len(img)} of {n_img} images, "
                  f"{max((int((d > 0).any(axis=-1).sum()) for d in img), default=0)} pixels at most, "
                  f"max abs {max((float(d.max()) for d in img), default=0.0):.3g}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
