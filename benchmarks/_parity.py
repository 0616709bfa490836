"""The parity part of ``robustness.py``: CPU/CUDA parity and same-device determinism of the whole FrameLoop.

A fixed, seeded sequence: scene ``cornell`` with object motion (the short block slides), 256x144, 6 frames of
``FrameLoop.render`` along the scene's camera path (``time = i / 10`` s) with a fixed gaze path (frame 2's gaze is
off screen), AO on (4 rays per shaded pixel, so the per-pixel random streams are used), then
``render_reference`` of the last camera. After the last frame every stage output is read back: the G-buffer
(position, normal, depth, albedo, face, hit, velocity, reproj_uv), the sampling stage (probability, saliency,
sample_map, cache_hit, prev_index, sample/cache-hit counters), the fresh shading buffer, the temporal output
(``Frame.extras``: sparse color and filled mask), the reconstruction before tone mapping, the display image of
every frame, and the reference image.

A Warp build without a CPU compiler cannot render the CPU half on the GPU's machine, so the comparison runs in
two steps (on one machine or two):

    python benchmarks/robustness.py --parts parity --device cpu --save parity-cpu.npz       # the CPU arrays
    python benchmarks/robustness.py --parts parity --device cuda:0 --compare parity-cpu.npz  # CUDA against them

``--compare`` re-renders the sequence stored in the file's settings (scene, size, frames, AO) on its device and
compares every array. Every mode also renders the sequence twice on its own device, in two fresh FrameLoops, and
checks that every array is bit-identical (byte equality). With neither ``--save`` nor ``--compare`` only that
determinism check runs.

Tolerances (CPU vs CUDA; the exit status is 1 when one fails, or when two runs on one device differ):

- G-buffer depth and position: |a - b| / scene extent <= 1e-4; normal: |a - b| <= 1e-4; on every pixel where both
  devices hit the same triangle (a ray through a silhouette or a shared triangle edge may hit a different
  triangle or nothing on the other device: those pixels are counted, and the fraction whose hit flag differs must
  be <= 1e-3).
- Sampling probability (eccentricity / MAR, thesis eq. 2): |a - b| <= 1e-4 at every pixel.
- Sample map: the fraction of equal entries is reported and must be >= 0.99. The map is binarized from thresholds,
  so float differences of a few ulps in the saliency can flip pixels whose value sits on a threshold, and a flip
  changes which pixels are traced and reused in later frames.
- Final display image of the last frame and the reference image: PSNR >= 40 dB (the actual value is reported).
- Everything else (saliency, velocity, temporal, reconstruction, ...) is reported without a tolerance: max / mean /
  p99 absolute and relative differences and the fraction of exactly equal values.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import warp as wp

from benchmarks._common import device_info, device_name, git_commit, md_table

# -- the sequence (defaults; the saved file's settings win in --compare) ---------------------------------------------
DEFAULT_SETTINGS = {"scene": "cornell", "motion": True, "width": 256, "height": 144, "frames": 6, "ao_samples": 4,
                    "dt": 0.1}
QUICK_SETTINGS = {**DEFAULT_SETTINGS, "width": 64, "height": 48, "frames": 4}

# -- tolerances ---------------------------------------------------------------------------------------------------
TOL_GBUFFER_REL = 1e-4  # depth, position: |a - b| / scene extent, on same-triangle pixels
TOL_NORMAL = 1e-4  # normal: |a - b| on same-triangle pixels
TOL_HIT_MISMATCH = 1e-3  # fraction of pixels whose hit flag differs
TOL_PROBABILITY = 1e-4  # |a - b| everywhere
TOL_SAMPLE_MAP_EQUAL = 0.99  # fraction of equal sample-map entries
TOL_PSNR_DB = 40.0  # final image of the last frame, and the reference image
TOLERANCES = {"gbuffer_depth_position_rel_extent": TOL_GBUFFER_REL, "gbuffer_normal_abs": TOL_NORMAL,
              "gbuffer_hit_mismatch_fraction_max": TOL_HIT_MISMATCH, "probability_abs": TOL_PROBABILITY,
              "sample_map_equal_fraction_min": TOL_SAMPLE_MAP_EQUAL, "image_psnr_db_min": TOL_PSNR_DB}


def gaze_at(i: int, w: int, h: int) -> tuple:
    """Fixed gaze path in pixels; frame 2 looks off screen (left of the image)."""
    if i == 2:
        return (-0.3 * w, 0.5 * h)
    return (w * (0.35 + 0.06 * i), h * (0.45 + 0.04 * i))


def _copy(a) -> np.ndarray:
    # np.array(copy=True): on the CPU device wp.array.numpy() is a view of memory the next frame overwrites
    return np.array(a.numpy() if isinstance(a, wp.array) else a, copy=True)


def render_sequence(fw, device, s: dict) -> dict:
    """Render the sequence of settings ``s`` in a fresh scene and FrameLoop on ``device``; every array by name."""
    scene = fw.load_scene(s["scene"], motion=True) if s["motion"] else fw.load_scene(s["scene"])
    cfg = fw.Config().with_(shading={"ao_samples": int(s["ao_samples"])})
    w, h = int(s["width"]), int(s["height"])
    loop = fw.FrameLoop(scene, w, h, config=cfg, device=device, timing=False, policy="foveated")
    out = {}
    rates = []
    frame = cam = t = None
    for i in range(int(s["frames"])):
        t = i * float(s["dt"])
        cam = scene.camera_at(t)
        frame = loop.render(cam, gaze_px=gaze_at(i, w, h), time=t)
        out[f"image.frame{i}"] = _copy(frame.image)
        out[f"sample_map.frame{i}"] = _copy(frame.sampling_map)
        rates.append(frame.stats["sampling_rate"])
    wp.synchronize_device(device)
    for k in frame.gbuffer.FIELDS:
        out[f"gbuffer.{k}"] = _copy(getattr(frame.gbuffer, k))
    smp = loop.sampling
    for k in ("probability", "saliency", "sample_map", "cache_hit", "prev_index", "num_samples", "num_cache_hits"):
        if isinstance(getattr(smp, k, None), wp.array):
            out[f"sampling.{k}"] = _copy(getattr(smp, k))
    out["shade.radiance"] = _copy(loop.radiance)
    for k, v in frame.extras.items():
        if isinstance(v, wp.array):
            out[f"temporal.{k}"] = _copy(v)
    if isinstance(getattr(loop, "recon", None), wp.array):
        out["reconstruct.hdr"] = _copy(loop.recon)
    out["image"] = _copy(frame.image)
    out["stats.sampling_rate"] = np.asarray(rates, dtype=np.float64)
    ref = loop.render_reference(cam, time=t)
    out["reference.image"] = _copy(ref.image)
    out["reference.depth"] = _copy(ref.gbuffer.depth)
    out["scene.extent"] = np.asarray([scene.extent], dtype=np.float64)
    return out


# -- comparison ---------------------------------------------------------------------------------------------------
def bit_identical(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def determinism(r1: dict, r2: dict) -> dict:
    keys = sorted(set(r1) | set(r2))
    diff = [k for k in keys if k not in r1 or k not in r2 or not bit_identical(r1[k], r2[k])]
    return {"arrays": len(keys), "bit_identical": not diff, "differing": diff}


def _psnr(a, b) -> float:
    from foveawarp.metrics import psnr

    return float(psnr(np.clip(a, 0, 1), np.clip(b, 0, 1)))


def diff_stats(a: np.ndarray, b: np.ndarray, mask=None) -> dict:
    """Absolute and relative differences of two arrays (over ``mask`` pixels when given)."""
    x, y = a.astype(np.float64), b.astype(np.float64)
    if mask is not None:
        x, y = x[mask], y[mask]
    if x.size == 0:
        return {"n": 0}
    d = np.abs(x - y)
    if d.ndim > 1:  # vectors: per-element
        d = d.reshape(-1)
    mag = np.maximum(np.abs(x), np.abs(y)).reshape(-1)
    floor = max(1e-6, 1e-3 * float(mag.max()))
    rel = d / np.maximum(mag, floor)
    return {"n": int(d.size), "max_abs": float(d.max()), "mean_abs": float(d.mean()),
            "p99_abs": float(np.percentile(d, 99)), "max_rel": float(rel.max()),
            "p99_rel": float(np.percentile(rel, 99)),
            "equal_fraction": float(np.mean(d == 0))}


def compare(ref: dict, cur: dict) -> tuple:
    """(per-array stats, list of checks) of the current device's arrays ``cur`` against the saved ``ref``."""
    arrays = {}
    for k in sorted(ref):
        if k.startswith("scene.") or k not in cur:
            continue
        a, b = ref[k], cur[k]
        if a.shape != b.shape:
            arrays[k] = {"error": f"shape {a.shape} vs {b.shape}"}
            continue
        st = diff_stats(a, b)
        st["bit_identical"] = bit_identical(a, b)
        if k.startswith("image") or k == "reference.image":
            p = _psnr(a, b)
            st["psnr_db"] = p
        arrays[k] = st
    missing = sorted(set(ref) ^ set(cur))
    extent = float(ref["scene.extent"][0])
    hit_a, hit_b = ref["gbuffer.hit"].astype(bool), cur["gbuffer.hit"].astype(bool)
    same = (hit_a == hit_b) & (ref["gbuffer.face"] == cur["gbuffer.face"])
    n = same.size
    hit_mismatch = float(np.mean(hit_a != hit_b))
    face_mismatch = float(np.mean(ref["gbuffer.face"] != cur["gbuffer.face"]))
    checks = []

    def check(name, value, limit, ok, note=""):
        checks.append({"check": name, "value": value, "limit": limit, "pass": bool(ok), "note": note})

    for k, scale, tol in (("gbuffer.depth", extent, TOL_GBUFFER_REL), ("gbuffer.position", extent, TOL_GBUFFER_REL),
                          ("gbuffer.normal", 1.0, TOL_NORMAL)):
        st = diff_stats(ref[k], cur[k], same)
        v = st.get("max_abs", 0.0) / scale
        arrays[k]["same_triangle"] = st
        check(f"{k} max abs diff{' / extent' if scale != 1.0 else ''} (same-triangle pixels)", v, tol, v <= tol,
              f"{int(same.sum())} of {n} pixels hit the same triangle on both devices")
    check("gbuffer.hit mismatch fraction", hit_mismatch, TOL_HIT_MISMATCH, hit_mismatch <= TOL_HIT_MISMATCH,
          f"face id differs at {face_mismatch:.2e} of pixels (silhouettes, shared edges)")
    v = arrays["sampling.probability"]["max_abs"]
    check("sampling.probability max abs diff", v, TOL_PROBABILITY, v <= TOL_PROBABILITY)
    eq = float(np.mean(ref["sampling.sample_map"] == cur["sampling.sample_map"]))
    check("sampling.sample_map equal fraction", eq, TOL_SAMPLE_MAP_EQUAL, eq >= TOL_SAMPLE_MAP_EQUAL,
          f"{int(np.sum(ref['sampling.sample_map'] != cur['sampling.sample_map']))} of "
          f"{ref['sampling.sample_map'].size} entries differ")
    for k in ("image", "reference.image"):
        p = arrays[k]["psnr_db"]
        check(f"{k} PSNR dB", p, TOL_PSNR_DB, p >= TOL_PSNR_DB)
    if missing:
        check("same array names", len(missing), 0, False, f"only on one side: {missing}")
    return arrays, checks


# -- i/o ----------------------------------------------------------------------------------------------------------
def save_npz(path: Path, arrays: dict, meta: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, __meta__=np.asarray(json.dumps(meta)), **arrays)


def load_npz(path: Path) -> tuple:
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["__meta__"]))
        arrays = {k: z[k] for k in z.files if k != "__meta__"}
    return arrays, meta


def _fmt(v):
    if isinstance(v, float):
        return "inf" if math.isinf(v) else f"{v:.4g}"
    return str(v)


def _json_safe(o):
    if isinstance(o, dict):
        return {k: _json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_json_safe(v) for v in o]
    if isinstance(o, float) and not math.isfinite(o):
        return str(o)  # "inf" for identical images
    return o


def add_options(p) -> None:
    """The parity part's options on ``robustness.py``'s parser."""
    g = p.add_argument_group("parity").add_mutually_exclusive_group()
    g.add_argument("--save", default=None, help="parity: render on --device and save every array to this .npz")
    g.add_argument("--compare", default=None, help="parity: render on --device and compare with this saved .npz")


def run(fw, dev, args) -> tuple:
    """Determinism on ``dev`` and, with ``--save`` / ``--compare``, the saved arrays or the comparison with them:
    (record, markdown, passed)."""
    if args.compare:
        saved, saved_meta = load_npz(Path(args.compare))
        settings = saved_meta["settings"]
    else:
        saved = saved_meta = None
        settings = dict(QUICK_SETTINGS if args.quick else DEFAULT_SETTINGS)
    run1 = render_sequence(fw, dev, settings)
    run2 = render_sequence(fw, dev, settings)
    det = determinism(run1, run2)
    scene = settings["scene"] + ("+motion" if settings["motion"] else "")
    rec = {"part": "parity", "mode": "compare" if args.compare else ("save" if args.save else "determinism"),
           "settings": settings, "scene": scene, "width": int(settings["width"]), "height": int(settings["height"]),
           "frames": settings["frames"], "tolerances": TOLERANCES, "determinism": det}
    ok = det["bit_identical"]
    md = [f"## Parity: {scene} {settings['width']}x{settings['height']}, {settings['frames']} frames, "
          f"AO {settings['ao_samples']}",
          "",
          f"Same device, two fresh FrameLoops: {det['arrays']} arrays, bit-identical: **{det['bit_identical']}**"
          + (f"; differing: {', '.join(det['differing'])}" if det["differing"] else "")]
    if args.save:
        meta = {"settings": settings, "commit": git_commit(), **device_info(dev)}
        save_npz(Path(args.save), run1, meta)
        rec["saved"] = Path(args.save).name
        md.append(f"\nSaved {len(run1)} arrays to `{Path(args.save).name}`.")
    if args.compare:
        arrays, checks = compare(saved, run1)
        ok = ok and all(c["pass"] for c in checks)
        all_equal = all(a.get("bit_identical", False) for a in arrays.values())
        rec.update(against={k: saved_meta.get(k) for k in ("device", "device_alias", "commit", "warp")},
                   checks=checks, arrays=arrays, all_bit_identical_to_saved=all_equal,
                   frame_psnr_db=[arrays[f"image.frame{i}"]["psnr_db"] for i in range(settings["frames"])],
                   sample_map_equal_fraction_per_frame=[arrays[f"sample_map.frame{i}"]["equal_fraction"]
                                                       for i in range(settings["frames"])])
        md.append(f"\nAgainst `{Path(args.compare).name}` (rendered on {saved_meta.get('device')}, "
                  f"{saved_meta.get('device_alias')}, commit {saved_meta.get('commit')}); every array "
                  f"bit-identical: **{all_equal}**\n")
        md.append(md_table([{k: _fmt(v) for k, v in c.items()} for c in checks],
                           ["check", "value", "limit", "pass", "note"]))
        rows = [{"array": k, **{c: _fmt(a.get(c, "")) for c in ("max_abs", "mean_abs", "p99_abs", "max_rel",
                                                                  "equal_fraction", "psnr_db")}}
                for k, a in arrays.items()]
        md.append("\nPer array (max / mean / p99 absolute difference, max relative difference, fraction of equal "
                  "values, PSNR for images):\n")
        md.append(md_table(rows, ["array", "max_abs", "mean_abs", "p99_abs", "max_rel", "equal_fraction", "psnr_db"]))
    rec["pass"] = bool(ok)
    md.append(f"\nParity: **{'PASS' if ok else 'FAIL'}** on {device_name(dev)}\n")
    return _json_safe(rec), "\n".join(md), bool(ok)
