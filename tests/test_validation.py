"""Input validation of every public entry point: a table of (entry point, bad input) cases.

Each case calls a public function, constructor or method with one bad argument (NaN, +-Inf, a wrong type, a
wrong shape or dtype, an array holding NaN / Inf, a size <= 0, a value outside its range, an empty or
non-triangle mesh, an unreadable file) and expects a ``ValueError`` whose message names the parameter, the
offending value and the allowed range: all three substrings of the case must appear in the message.

Every case must pass: there are no expected failures.

The table is built at import time from small generators (one per kind of parameter); ``case_families()``
counts the cases per entry point family (docs/robustness.md quotes these counts).
"""

from __future__ import annotations

import functools
import math
import re
from collections import Counter

import numpy as np
import pytest
import warp as wp

import foveawarp as fw
from foveawarp import meshio, metrics, ops, scenes
from foveawarp.buffers import GBuffer
from foveawarp.scene import DeviceScene, SceneObject, register_builtin_scenes
from foveawarp.stages.dof import DofStage
from foveawarp.stages.indirect import IndirectStage
from foveawarp.stages.reconstruct import ReconstructStage
from foveawarp.stages.reorder import ReorderStage
from foveawarp.stages.sampling import SamplingStage

NAN, INF = float("nan"), float("inf")
DEV = "cpu"  # validation happens on the host before any launch: one device is enough
W, H = 8, 6

CASES: list = []
_IDS: Counter = Counter()


def case(family, cid, fn, kwargs, param, value, allowed):
    """One table row: ``fn(**kwargs)`` must raise ValueError naming ``param``, ``value`` and ``allowed``."""
    _IDS[cid] += 1
    if _IDS[cid] > 1:
        cid = f"{cid}#{_IDS[cid]}"
    CASES.append(pytest.param(family, fn, kwargs, param, value, allowed, id=cid))


# -- lazily built shared objects (tiny, CPU) ---------------------------------------------------------------------


@functools.lru_cache(maxsize=None)
def _loop(dof=False):
    cfg = fw.Config(dof=fw.DofConfig(aperture_m=0.01, focus_depth_m=None)) if dof else fw.Config()
    return fw.FrameLoop("cornell", W, H, config=cfg, device=DEV)


@functools.lru_cache(maxsize=None)
def _scene():
    return fw.load_scene("cornell")


@functools.lru_cache(maxsize=None)
def _ds():
    return DeviceScene(_scene(), DEV)


@functools.lru_cache(maxsize=None)
def _sampling():
    return SamplingStage(W, H, fw.Config(), DEV)


@functools.lru_cache(maxsize=None)
def _dof_stage():
    return DofStage(W, H, fw.DofConfig(aperture_m=0.01), DEV)


@functools.lru_cache(maxsize=None)
def _recon():
    return ReconstructStage(W, H, fw.ReconstructionConfig(), 4, DEV)


@functools.lru_cache(maxsize=None)
def _indirect():
    return IndirectStage(_ds(), fw.IndirectConfig(rsm_size=8, start_level=1, limit_level=2), max_receivers=4)


@functools.lru_cache(maxsize=None)
def _reorder():
    return ReorderStage(W, H, fw.ReorderConfig(), DEV)


def _warr(shape, dtype, fill=0):
    return wp.full(shape, value=fill, dtype=dtype, device=DEV) if fill else wp.zeros(shape, dtype=dtype, device=DEV)


def _with(arr, idx, v):
    a = np.array(arr, dtype=np.float64, copy=True)
    a[idx] = v
    return a


# -- generators per kind of parameter ----------------------------------------------------------------------------


def field(cls, name, allowed, out_of_range=(), *, kind="real", none_ok=False, base=None):
    """A config / dataclass field: the message names ``Class.field``."""
    base = base or {}
    label = f"{cls.__name__}.{name}"
    fam = "Config fields" if cls.__name__.endswith("Config") else f"{cls.__name__}"
    if kind == "real":
        bad = [(NAN, "nan"), (INF, "inf"), (-INF, "-inf"), ("0.5", "'0.5'"), (True, "True")]
    elif kind == "int":
        bad = [(NAN, "nan"), (2.5, "2.5"), ("4", "'4'"), (True, "True")]
    elif kind == "bool":
        bad = [("yes", "'yes'"), (1, "1"), (None, "None")]
    elif kind == "choice":
        bad = [("bogus", "'bogus'"), (3, "3")]
    else:
        raise AssertionError(kind)
    if kind in ("real", "int", "choice") and not none_ok:
        bad.append((None, "None"))
    bad += [(v, repr(v)) for v in out_of_range]
    for v, vs in bad:
        case(fam, f"{label}={vs}", cls, {**base, name: v}, label, vs, allowed)


def arg(family, fname, fn, base, name, allowed, bad, *, param=None):
    """Explicit bad values of one argument: ``bad`` = [(value, value substring), ...]."""
    for v, vs in bad:
        case(family, f"{fname}:{name}={vs}", fn, {**base, name: v}, param or name, vs, allowed)


REAL_BAD = [(NAN, "nan"), (INF, "inf"), (-INF, "-inf"), ("0.5", "'0.5'"), (None, "None"), (True, "True")]
INT_BAD = [(NAN, "nan"), (2.5, "2.5"), ("4", "'4'"), (None, "None"), (True, "True")]
BOOL_BAD = [("yes", "'yes'"), (1, "1"), (None, "None")]


def real_arg(family, fname, fn, base, name, allowed, out_of_range=(), *, none_ok=False, param=None):
    bad = [b for b in REAL_BAD if not (none_ok and b[0] is None)] + [(v, repr(v)) for v in out_of_range]
    arg(family, fname, fn, base, name, allowed, bad, param=param)


def int_arg(family, fname, fn, base, name, allowed, out_of_range=(), *, none_ok=False, param=None):
    bad = [b for b in INT_BAD if not (none_ok and b[0] is None)] + [(v, repr(v)) for v in out_of_range]
    arg(family, fname, fn, base, name, allowed, bad, param=param)


def choice_arg(family, fname, fn, base, name, allowed, *, none_ok=False, param=None):
    bad = [("bogus", "'bogus'"), (3, "3")] + ([] if none_ok else [(None, "None")])
    arg(family, fname, fn, base, name, allowed, bad, param=param)


def vec_arg(family, fname, fn, base, name, n=3, allowed_each="finite real number", lo_bad=None, *, param=None,
            none_ok=False):
    """An ``n``-vector: NaN / Inf in one component (named ``name[i]``), a string, the wrong length, None."""
    p = param or name
    good = [1.0] * n
    for i, (v, vs) in enumerate([(NAN, "nan"), (INF, "inf"), (-INF, "-inf")]):
        j = i % n
        case(family, f"{fname}:{name}[{j}]={vs}", fn, {**base, name: tuple(_with(good, j, v))}, f"{p}[{j}]", vs,
             allowed_each)
    case(family, f"{fname}:{name}='abc'", fn, {**base, name: "abc"}, p, "'abc'", f"{n} finite numbers")
    short = tuple(good[:-1])
    case(family, f"{fname}:{name}=short", fn, {**base, name: short}, p, repr(short), f"{n} finite numbers")
    if not none_ok:
        case(family, f"{fname}:{name}=None", fn, {**base, name: None}, p, "None", f"{n} finite numbers")
    if lo_bad is not None:
        v = tuple(_with(good, 0, lo_bad))
        case(family, f"{fname}:{name}[0]={lo_bad!r}", fn, {**base, name: v}, f"{p}[0]", repr(lo_bad), allowed_each)


def array_arg(family, fname, fn, base, name, good, allowed="finite real numbers", *, extra=(), shape_bad=None,
              shape_allowed=None, param=None):
    """An array: NaN, +Inf, -Inf at one element (the message names the value and its index), a string array,
    and (``shape_bad``) a wrong shape."""
    p = param or name
    g = np.asarray(good)
    idx = tuple(s - 1 for s in g.shape)
    for v, vs in [(NAN, "nan"), (INF, "inf"), (-INF, "-inf")] + list(extra):
        a = _with(g, idx, v)
        case(family, f"{fname}:{name}[{idx}]={vs}", fn, {**base, name: a}, p, f"got {vs} at index {idx}", allowed)
    case(family, f"{fname}:{name}=strings", fn, {**base, name: np.full(g.shape, "a")}, p, "<U1",
         "array of real numbers")
    if shape_bad is not None:
        case(family, f"{fname}:{name}=shape{shape_bad}", fn, {**base, name: np.zeros(shape_bad)}, p,
             repr(tuple(shape_bad)), shape_allowed)


# ================================================================================================================
# Config fields

for n in ("mar_slope", "mar_fovea_deg"):
    field(fw.FoveationConfig, n, "(0.0, 1.0]", [0.0, -0.1, 1.5])
field(fw.FoveationConfig, "min_probability", "[0.0, 1.0]", [-0.1, 1.1])
field(fw.FoveationConfig, "block", "[1, 64]", [0, -3, 65], kind="int")
field(fw.FoveationConfig, "enabled", "True or False", kind="bool")
for n in ("albedo_scale", "normal_scale", "sigma1_m"):
    field(fw.SaliencyConfig, n, "[0.0, inf]", [-1.0])
for n in ("velocity_scale_px", "sigma2_m"):
    field(fw.SaliencyConfig, n, "(0.0, inf]", [0.0, -1.0])
field(fw.SaliencyConfig, "dof_floor", "[0.0, 1.0]", [-0.5, 2.0])
for n in ("use_albedo", "use_normal", "use_velocity", "use_dof"):
    field(fw.SaliencyConfig, n, "True or False", kind="bool")
field(fw.ReorderConfig, "strategy", "'tile'", kind="choice")
field(fw.ReorderConfig, "balance_rows", "[1, 1024]", [0, 1025], kind="int")
field(fw.ReorderConfig, "tile", "[2, 64]", [1, 3, 128], kind="int")
field(fw.ReorderConfig, "skip_misses", "True or False", kind="bool")
field(fw.ShadingConfig, "specular", "[0.0, 1.0]", [-0.1, 1.5])
field(fw.ShadingConfig, "shininess", "[1.0, 4096.0]", [0.5, 5000.0])
field(fw.ShadingConfig, "ao_samples", "[0, 256]", [-1, 257], kind="int")
field(fw.ShadingConfig, "ao_radius_rel", "(0.0, 10.0]", [0.0, 11.0])
field(fw.ShadingConfig, "ao_lanes", "[1, 16]", [0, -1, 17], kind="int")
field(fw.ShadingConfig, "area_light_samples", "[1, 256]", [0, 300], kind="int")
field(fw.ShadingConfig, "indirect", "'lighttree'", kind="choice")
for n in ("exposure", "white_point"):  # bounded by float32's largest value (the kernels hold them in float32)
    field(fw.ShadingConfig, n, "(0.0, 3.4028234663852886e+38]", [0.0, -2.0, 1e39])
field(fw.ShadingConfig, "seed", "[0, 2147483647]", [-1, 2**31], kind="int")
field(fw.ShadingConfig, "shadows", "True or False", kind="bool")
field(fw.ShadingConfig, "env_mis", "True or False", kind="bool")
field(fw.ShadingConfig, "path_history", "[0.0, 0.95]", [-0.1, 0.96])
field(fw.ShadingConfig, "path_filter_guide", "'variance'", kind="choice")
for n in ("ambient", "background"):
    vec_arg("Config fields", "ShadingConfig", fw.ShadingConfig, {}, n, 3, "[0.0, inf]", -0.5,
            param=f"ShadingConfig.{n}")
field(fw.ReconstructionConfig, "jfa_variant", "'1+jfa'", kind="choice")
field(fw.ReconstructionConfig, "sibson_window", "[1, 256]", [0, 257], kind="int", none_ok=True)
field(fw.ReconstructionConfig, "sibson", "True or False", kind="bool")
field(fw.ReconstructionConfig, "bounded_jfa_start", "True or False", kind="bool")
field(fw.DofConfig, "aperture_m", "[0.0, 10.0]", [-0.01, 11.0])
field(fw.DofConfig, "focal_length_m", "(0.0, 10.0]", [0.0, 20.0])
field(fw.DofConfig, "focus_depth_m", "(0.05, inf]", [0.05, 0.01, -3.0], none_ok=True)
field(fw.DofConfig, "px_per_m", "(0.0, inf]", [0.0])
field(fw.DofConfig, "gamma", "[0.0, 16.0]", [-1.0, 17.0])
field(fw.DofConfig, "eps_px", "(0.0, inf]", [0.0])
field(fw.DofConfig, "max_coc_px", "[1.0, 128.0]", [0.5, 129.0])
field(fw.DofConfig, "foreground_fix", "True or False", kind="bool")
field(fw.DofConfig, "background_fix", "True or False", kind="bool")
field(fw.IndirectConfig, "rsm_size", "[8, 2048]", [4, 100, 4096, 0], kind="int")
field(fw.IndirectConfig, "depth_threshold", "(0.0, 1.0]", [0.0, 1.5])
field(fw.IndirectConfig, "normal_threshold", "[-1.0, 1.0]", [-1.5, 1.5])
field(fw.IndirectConfig, "start_level", "[0, 8]", [-1, 9], kind="int")
field(fw.IndirectConfig, "limit_level", "[4, 8]", [3, 9], kind="int")
field(fw.IndirectConfig, "d_min_rel", "(0.0, 1.0]", [0.0, 2.0])
field(fw.IndirectConfig, "strength", "[0.0, inf]", [-1.0])
field(fw.IndirectConfig, "cluster_radius_scale", "[0.0, 16.0]", [-0.5, 17.0])
field(fw.IndirectConfig, "refine_threshold", "(0.0, 1000000.0]", [0.0, -1.0, 2e6])
field(fw.IndirectConfig, "refine_budget", "[0, 65536]", [-1, 65537], kind="int")
field(fw.IndirectConfig, "refine_min_ratio", "[0.0, 1.0]", [-0.1, 1.5])
field(fw.IndirectConfig, "refine_min_radius", "[0.0, 1000.0]", [-0.1, 1001.0])
field(fw.TemporalConfig, "max_history_frames", "[1, 1024]", [0, 2000], kind="int")
field(fw.TemporalConfig, "depth_eps_rel", "(0.0, 1.0]", [0.0, 1.5])
field(fw.TemporalConfig, "cut_threshold_deg", "(0.0, 180.0]", [0.0, 181.0])
field(fw.TemporalConfig, "refresh_fraction", "[0.0, 1.0]", [-0.1, 1.1])
field(fw.TemporalConfig, "enabled", "True or False", kind="bool")
field(fw.FoveationConfig, "fovea_deg", "[0.0, 180.0]", [-0.1, 181.0])
field(fw.FoveationConfig, "gbuffer", "'sparse'", kind="choice")
field(fw.FoveationConfig, "coarse_cell", "[1, 64]", [0, -2, 65], kind="int")
field(fw.TemporalConfig, "normal_cos_min", "[-1.0, 1.0]", [-1.5, 1.5])
field(fw.TemporalConfig, "clamp_gamma", "[0.0, 100.0]", [-0.1, 101.0])
field(fw.TemporalConfig, "motion_alpha_per_px", "[0.0, 1.0]", [-0.1, 1.1])
field(fw.TemporalConfig, "still_min_probability", "[0.0, 1.0]", [-0.1, 1.1])
field(fw.TemporalConfig, "stochastic_min_samples", "[1, 4096]", [0, -1, 4097], kind="int")
for st in ("foveation", "saliency", "reorder", "shading", "reconstruction", "dof", "indirect", "temporal"):
    case("Config fields", f"Config.{st}=5", fw.Config, {st: 5}, f"Config.{st}", "5", "Config")
case("Config fields", "Config.with_:unknown stage", lambda **kw: fw.Config().with_(**kw), {"bogus": {}},
     "Config.with_", "'bogus'", "'foveation'")
case("Config fields", "Config.with_:unknown field", lambda **kw: fw.Config().with_(**kw), {"foveation": {"blok": 8}},
     "Config.with_(foveation=...)", "'blok'", "'block'")
case("Config fields", "Config.with_:bad value", lambda **kw: fw.Config().with_(**kw), {"foveation": {"block": 0}},
     "FoveationConfig.block", "0", "[1, 64]")

# ================================================================================================================
# Camera

for n in ("eye", "target", "up"):
    vec_arg("Camera", "Camera", fw.Camera, {}, n, 3, "finite real number", param=f"Camera.{n}")
field(fw.Camera, "fov_y_deg", "(0.0, 180.0)", [0.0, -5.0, 180.0, 200.0])
case("Camera", "Camera:target==eye", fw.Camera, {"eye": (0, 1, 0), "target": (0, 1, 0)}, "Camera.target",
     "(0.0, 1.0, 0.0)", "must differ from Camera.eye")
case("Camera", "Camera:up=0", fw.Camera, {"up": (0, 0, 0)}, "Camera.up", "(0.0, 0.0, 0.0)", "non-zero vector")
case("Camera", "Camera:up parallel", fw.Camera, {"eye": (0, 0, 0), "target": (0, 1, 0), "up": (0, 2, 0)},
     "Camera.up", "(0.0, 2.0, 0.0)", "must not be parallel")
_cam = fw.Camera()
_pm = {"aspect": 1.5, "near": 0.01, "far": 100.0}
real_arg("Camera", "projection_matrix", _cam.projection_matrix, _pm, "aspect", "(0.0, inf]", [0.0, -1.0])
real_arg("Camera", "projection_matrix", _cam.projection_matrix, _pm, "near", "(0.0, inf]", [0.0])
real_arg("Camera", "projection_matrix", _cam.projection_matrix, _pm, "far", "(0.01, inf]", [0.01, 0.001])
_rd = {"px": np.array([1.0, 2.0]), "py": np.array([1.0, 2.0]), "width": W, "height": H}
for n in ("px", "py"):
    array_arg("Camera", "ray_dirs", _cam.ray_dirs, _rd, n, _rd[n])
for fname, f, base in (("ray_dirs", _cam.ray_dirs, _rd),
                       ("project", _cam.project, {"points": np.zeros((2, 3)), "width": W, "height": H}),
                       ("gaze_to_dir", _cam.gaze_to_dir, {"gaze_px": (1.0, 2.0), "width": W, "height": H}),
                       ("dir_to_gaze", _cam.dir_to_gaze, {"direction": (0.0, 0.0, -1.0), "width": W, "height": H}),
                       ("params", _cam.params, {"width": W, "height": H})):
    for n in ("width", "height"):
        int_arg("Camera", fname, f, base, n, "[1, 16384]", [0, -4, 20000])
array_arg("Camera", "project", _cam.project, {"points": np.zeros((2, 3)), "width": W, "height": H}, "points",
          np.zeros((2, 3)), shape_bad=(2, 2), shape_allowed="(..., 3)")
vec_arg("Camera", "gaze_to_dir", _cam.gaze_to_dir, {"width": W, "height": H}, "gaze_px", 2, "finite real number")
vec_arg("Camera", "dir_to_gaze", _cam.dir_to_gaze, {"width": W, "height": H}, "direction", 3, "finite real number")
case("Camera", "dir_to_gaze:direction=0", _cam.dir_to_gaze, {"direction": (0, 0, 0), "width": W, "height": H},
     "direction", "(0, 0, 0)", "non-zero vector")
arg("Camera", "rotation_deg_to", _cam.rotation_deg_to, {}, "other", "foveawarp.Camera",
    [("x", "'x'"), (None, "None"), (5, "5")])

# ================================================================================================================
# Scene, Light, AreaLight, SceneObject, DeviceScene

field(fw.Light, "kind", "'spot'", kind="choice")
vec_arg("Light", "Light", fw.Light, {}, "position", 3, param="Light.position")
vec_arg("Light", "Light", fw.Light, {}, "direction", 3, param="Light.direction")
case("Light", "Light:direction=0", fw.Light, {"direction": (0, 0, 0)}, "Light.direction", "(0, 0, 0)", "non-zero")
field(fw.Light, "cone_deg", "(0.0, 180.0]", [0.0, -10.0, 190.0])
vec_arg("Light", "Light", fw.Light, {}, "intensity", 3, "[0.0, inf]", -1.0, param="Light.intensity")
field(fw.Light, "penumbra", "[0.0, 1.0]", [-0.1, 1.1])
for n in ("corner", "edge_u", "edge_v"):
    vec_arg("Light", "AreaLight", fw.AreaLight, {}, n, 3, param=f"AreaLight.{n}")
vec_arg("Light", "AreaLight", fw.AreaLight, {}, "radiance", 3, "[0.0, inf]", -1.0, param="AreaLight.radiance")
case("Light", "AreaLight:edges parallel", fw.AreaLight, {"edge_u": (1, 0, 0), "edge_v": (2, 0, 0)},
     "AreaLight.edge_u", "(2.0, 0.0, 0.0)", "must span an area in (0, inf)")

_so = {"name": "o", "vertex_range": (0, 3)}
arg("Scene", "SceneObject", SceneObject, _so, "name", "a str", [(5, "5"), (None, "None")], param="SceneObject.name")
arg("Scene", "SceneObject", SceneObject, _so, "vertex_range", "(start, end) integers",
    [("ab", "'ab'"), (None, "None"), ((1, 2, 3), "(1, 2, 3)")], param="SceneObject.vertex_range")
arg("Scene", "SceneObject", SceneObject, _so, "vertex_range", "[0, inf]", [((-1, 2), "-1")],
    param="SceneObject.vertex_range[0]")
arg("Scene", "SceneObject", SceneObject, _so, "vertex_range", "[3, inf]", [((3, 1), "1")],
    param="SceneObject.vertex_range[1]")
arg("Scene", "SceneObject", SceneObject, _so, "vertex_range", "[0, inf]", [((0.5, 3), "0.5")],
    param="SceneObject.vertex_range[0]")
arg("Scene", "SceneObject", SceneObject, _so, "motion", "callable", [(5, "5"), ("m", "'m'")], param="SceneObject.motion")

_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
_F = np.array([[0, 1, 2], [0, 2, 3]])
_sc = {"vertices": _V, "faces": _F, "face_albedo": (0.5, 0.5, 0.5)}
array_arg("Scene", "Scene", fw.Scene, _sc, "vertices", _V, param="Scene.vertices", shape_bad=(2, 3),
          shape_allowed="(V >= 3, 3)")
case("Scene", "Scene:vertices=(4, 2)", fw.Scene, {**_sc, "vertices": _V[:, :2]}, "Scene.vertices", "(4, 2)",
     "(V >= 3, 3)")
case("Scene", "Scene:faces=empty", fw.Scene, {**_sc, "faces": np.zeros((0, 3), int)}, "Scene.faces", "(0, 3)",
     "(F >= 1, 3)")
case("Scene", "Scene:faces=quads", fw.Scene, {**_sc, "faces": [[0, 1, 2, 3]]}, "Scene.faces", "(1, 4)",
     "(F >= 1, 3)")
case("Scene", "Scene:faces=float", fw.Scene, {**_sc, "faces": _F.astype(float)}, "Scene.faces", "float64",
     "integers in [0, 3]")
case("Scene", "Scene:faces=nan", fw.Scene, {**_sc, "faces": _with(_F, (0, 0), NAN)}, "Scene.faces",
     "got nan at index (0, 0)", "finite real numbers")
case("Scene", "Scene:faces index 4", fw.Scene, {**_sc, "faces": [[0, 1, 4]]}, "Scene.faces", "[0, 4]", "[0, 3]")
case("Scene", "Scene:faces index -1", fw.Scene, {**_sc, "faces": [[0, 1, -1]]}, "Scene.faces", "[-1, 1]", "[0, 3]")
case("Scene", "Scene:faces=strings", fw.Scene, {**_sc, "faces": np.full((2, 3), "a")}, "Scene.faces", "<U1",
     "array of real numbers")
for n, lo_hi, oob, oob_s in (("face_albedo", "[0.0, 1.0]", 1.5, "1.5"), ("face_emission", "[0.0, inf]", -1.0,
                                                                          "-1.0")):
    g = np.full((2, 3), 0.5)
    for v, vs in ((NAN, "nan"), (INF, "inf"), (oob, oob_s)):
        case("Scene", f"Scene:{n}={vs}", fw.Scene, {**_sc, n: _with(g, (1, 2), v)}, f"Scene.{n}",
             f"got {vs} at index (1, 2)", lo_hi)
    case("Scene", f"Scene:{n}=strings", fw.Scene, {**_sc, n: ("a", "b", "c")}, f"Scene.{n}", "<U1",
         "array of real numbers")
    case("Scene", f"Scene:{n}=shape", fw.Scene, {**_sc, n: np.zeros((3, 3))}, f"Scene.{n}", "(3, 3)", "(2, 3)")
case("Scene", "Scene:vertex_normals=shape", fw.Scene, {**_sc, "vertex_normals": np.zeros((3, 3))},
     "Scene.vertex_normals", "(3, 3)", "(4, 3)")
case("Scene", "Scene:vertex_normals=strings", fw.Scene, {**_sc, "vertex_normals": np.full((4, 3), "a")},
     "Scene.vertex_normals", "<U1", "array of real numbers")
case("Scene", "Scene:face_smooth=2", fw.Scene, {**_sc, "vertex_normals": _V, "face_smooth": [2, 0]},
     "Scene.face_smooth", "got 2 at index (0,)", "[0, 1]")
case("Scene", "Scene:face_smooth=nan", fw.Scene, {**_sc, "vertex_normals": _V, "face_smooth": [NAN, 0]},
     "Scene.face_smooth", "got nan at index (0,)", "[0, 1]")
case("Scene", "Scene:face_smooth=shape", fw.Scene, {**_sc, "vertex_normals": _V, "face_smooth": [1, 0, 1]},
     "Scene.face_smooth", "(3,)", "(2,)")
case("Scene", "Scene:face_smooth without normals", fw.Scene, {**_sc, "face_smooth": [1, 0]}, "Scene.face_smooth",
     "smooth faces", "Scene.vertex_normals is None")
for n, typ in (("lights", "Light"), ("area_lights", "AreaLight"), ("objects", "SceneObject")):
    case("Scene", f"Scene:{n}=[5]", fw.Scene, {**_sc, n: [5]}, f"Scene.{n}[0]", "5", typ)
    case("Scene", f"Scene:{n}=None", fw.Scene, {**_sc, n: None}, f"Scene.{n}", "None", f"list of {typ}")
case("Scene", "Scene:objects range", fw.Scene, {**_sc, "objects": [SceneObject("o", (0, 9))]}, "vertex_range",
     "(0, 9)", "[0, 4]")
case("Scene", "Scene:camera", fw.Scene, {**_sc, "camera": "cam"}, "Scene.camera", "'cam'", "foveawarp.Camera")
case("Scene", "Scene:camera_path", fw.Scene, {**_sc, "camera_path": 5}, "Scene.camera_path", "5", "callable")
case("Scene", "Scene:name", fw.Scene, {**_sc, "name": 5}, "Scene.name", "5", "a str")
case("Scene", "Scene:bvh_constructor", fw.Scene, {**_sc, "bvh_constructor": "kd"}, "Scene.bvh_constructor", "'kd'",
     "'sah'")
for v in (0, 65, 2.5, "4", True):
    case("Scene", f"Scene:bvh_leaf_size={v!r}", fw.Scene, {**_sc, "bvh_leaf_size": v}, "Scene.bvh_leaf_size",
         repr(v), "[1, 64]")


def _moving_scene(matrix):
    return fw.Scene(_V, _F, (0.5, 0.5, 0.5), objects=[SceneObject("o", (0, 4), lambda t: matrix)])


for f_name in ("vertices_at", "normals_at", "camera_at"):
    real_arg("Scene", f"Scene.{f_name}", lambda t, _f=f_name: getattr(_scene(), _f)(t), {}, "t", "finite real number",
             param="time")
case("Scene", "Scene.vertices_at:motion NaN", lambda t: _moving_scene(np.full((4, 4), NAN)).vertices_at(t), {"t": 0.0},
     "motion(0.0)", "got nan at index (0, 0)", "finite real numbers")
case("Scene", "Scene.vertices_at:motion 3x3", lambda t: _moving_scene(np.eye(3)).vertices_at(t), {"t": 0.0},
     "motion(0.0)", "(3, 3)", "4x4 matrix")
case("Scene", "Scene.camera_at:path returns str",
     lambda t: fw.Scene(_V, _F, (0.5, 0.5, 0.5), camera_path=lambda t: "cam").camera_at(t), {"t": 0.0},
     "Scene.camera_path(0.0)", "'cam'", "foveawarp.Camera")
arg("Scene", "DeviceScene", DeviceScene, {}, "scene", "foveawarp.Scene", [("cornell", "'cornell'"), (None, "None")])
DeviceScene_scene = functools.partial(lambda **kw: DeviceScene(_scene(), **kw))
arg("Scene", "DeviceScene", DeviceScene_scene, {}, "device", "or None for the default", [("tpu:9", "'tpu:9'")])
arg("Scene", "DeviceScene", DeviceScene_scene, {}, "bvh_constructor", "'sah'", [("kd", "'kd'"), (3, "3")])
int_arg("Scene", "DeviceScene", DeviceScene_scene, {}, "bvh_leaf_size", "[1, 64]", [0, 65, -2], none_ok=True)
real_arg("Scene", "DeviceScene.set_time", lambda t: _ds().set_time(t), {}, "t", "finite real number", param="time")

# ================================================================================================================
# load_scene and the scene builders (foveawarp/scenes.py)


@functools.lru_cache(maxsize=None)
def _files():
    import tempfile
    from pathlib import Path

    d = Path(tempfile.mkdtemp(prefix="fw-validation-"))
    (d / "garbage.obj").write_bytes(b"\x00\x01 not a mesh \xff" * 10)
    (d / "empty.obj").write_text("")
    (d / "points.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    (d / "lines.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2\nl 2 3\n")
    (d / "nan.obj").write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    (d / "flat.obj").write_text("v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 3\n")
    (d / "data.bin").write_bytes(b"\x00" * 64)
    (d / "sub").mkdir(exist_ok=True)
    return d


def _load_file(name, **kw):
    return fw.load_scene(str(_files() / name), **kw)


arg("load_scene", "load_scene", fw.load_scene, {}, "name_or_path", "a scene name or a file path",
    [(5, "5"), (None, "None"), (3.5, "3.5")])
case("load_scene", "load_scene:unknown name", fw.load_scene, {"name_or_path": "nope"}, "scene", "'nope'",
     "'cornell'")
case("load_scene", "load_scene:missing file", fw.load_scene, {"name_or_path": "/nonexistent/x.obj"}, "scene",
     "'/nonexistent/x.obj'", "nor an existing file")
case("load_scene", "load_scene:directory", lambda: _load_file("sub"), {}, "scene path", "sub'", "is not a file")
for fname, what in (("garbage.obj", "holds no triangle mesh|could not be read"),
                    ("empty.obj", "holds no triangle mesh|could not be read"),
                    ("points.obj", "holds no triangle mesh|could not be read"),
                    ("lines.obj", "holds no triangle mesh|could not be read"),
                    ("data.bin", "could not be read|holds no triangle mesh")):
    case("load_scene", f"load_scene:{fname}", lambda _n=fname: _load_file(_n), {}, "scene file", fname,
         re.compile(what))
case("load_scene", "load_scene:nan vertex", lambda: _load_file("nan.obj"), {}, "scene file", "nan.obj",
     "non-finite vertex coordinates")
case("load_scene", "load_scene:degenerate bbox", lambda: _load_file("flat.obj"), {}, "scene file", "flat.obj",
     "degenerate bounding box")
case("load_scene", "load_scene:unknown keyword", lambda **kw: fw.load_scene("cornell", **kw), {"seeed": 1},
     "load_scene keyword", "'seeed'", "'area_light'")
case("load_scene", "load_scene:file keyword", lambda **kw: fw.load_scene(str(_files() / "flat.obj"), **kw),
     {"motion": True}, "load_scene keyword", "'motion'", "'albedo'")
case("load_scene", "load_scene:cornell area_light", lambda **kw: fw.load_scene("cornell", **kw),
     {"area_light": "yes"}, "area_light", "'yes'", "True or False")
for b in ("area_light", "motion"):
    arg("scene builders", "cornell", scenes.cornell, {}, b, "True or False", BOOL_BAD)
for fname, f in (("cornell", scenes.cornell), ("eyechart", scenes.eyechart), ("earth", scenes.earth),
                 ("city", functools.partial(scenes.city, size=16)), ("bunny_in_box", scenes.bunny_in_box)):
    choice_arg("scene builders", fname, f, {}, "bvh_constructor", "'sah'")
    int_arg("scene builders", fname, f, {}, "bvh_leaf_size", "[1, 64]", [0, 65], none_ok=True)
int_arg("scene builders", "city", scenes.city, {}, "seed", "[0, 4294967295]", [-1, 2**32])
int_arg("scene builders", "city", scenes.city, {}, "size", "[1, 1024]", [0, -5, 5000])
int_arg("scene builders", "city", scenes.city, {}, "block", "[9, 256]", [0, 8])
int_arg("scene builders", "city", scenes.city, {}, "street", "[0, 256]", [-1])
int_arg("scene builders", "city", scenes.city, {}, "max_height", "[5, 128]", [0, 4, 1000])
int_arg("scene builders", "eyechart", scenes.eyechart, {}, "seed", "[0, 4294967293]", [-1])
arg("scene builders", "earth", scenes.earth, {}, "spin", "True or False", BOOL_BAD)
arg("scene builders", "mesh_on_ground", scenes.mesh_on_ground, {}, "path", "a file path",
    [(None, "None"), (5, "5")], param="scene path")
arg("scene builders", "bunny_in_box", scenes.bunny_in_box, {}, "path", "does not exist",
    [("/nonexistent/bunny.obj", "'/nonexistent/bunny.obj'")], param="scene path")
arg("scene builders", "mesh_on_ground", lambda **kw: scenes.mesh_on_ground(_files() / "flat.obj", **kw), {},
    "name", "None or a str", [(5, "5")])
vec_arg("scene builders", "mesh_on_ground", lambda **kw: scenes.mesh_on_ground(_files() / "flat.obj", **kw), {},
        "albedo", 3, "[0.0, 1.0]", 1.5)
_b = scenes.SceneBuilder
_am = {"vertices": _V, "faces": _F, "albedo": (0.5, 0.5, 0.5)}
array_arg("scene builders", "SceneBuilder.add_mesh", lambda **kw: _b().add_mesh(**kw), _am, "vertices", _V,
          shape_bad=(4, 2), shape_allowed="(V >= 3, 3)")
case("scene builders", "SceneBuilder.add_mesh:faces index", lambda **kw: _b().add_mesh(**kw), {**_am, "faces": [[0, 1, 7]]},
     "faces", "got 7 at index (0, 2)", "[0, 3]")
case("scene builders", "SceneBuilder.add_mesh:faces float", lambda **kw: _b().add_mesh(**kw),
     {**_am, "faces": [[0.0, 1.0, 2.0]]}, "faces", "float64", "(F >= 1, 3) integer array")
case("scene builders", "SceneBuilder.add_mesh:albedo", lambda **kw: _b().add_mesh(**kw), {**_am, "albedo": (2, 0, 0)},
     "albedo", "got 2 at index (0,)", "[0.0, 1.0]")
case("scene builders", "SceneBuilder.add_mesh:albedo shape", lambda **kw: _b().add_mesh(**kw),
     {**_am, "albedo": np.zeros((5, 3))}, "albedo", "(5, 3)", "(2, 3)")
vec_arg("scene builders", "SceneBuilder.add_mesh", lambda **kw: _b().add_mesh(**kw), _am, "emission", 3,
        "[0.0, inf]", -1.0)
arg("scene builders", "SceneBuilder.add_mesh", lambda **kw: _b().add_mesh(**kw), _am, "smooth", "True or False",
    BOOL_BAD[:2])
arg("scene builders", "SceneBuilder.add_mesh", lambda **kw: _b().add_mesh(**kw), _am, "motion", "callable",
    [(5, "5")])
arg("scene builders", "SceneBuilder.add_mesh", lambda **kw: _b().add_mesh(**kw), _am, "normals", "(4, 3)",
    [(np.zeros((2, 3)), "(2, 3)")])
_aq = {"corner": (0, 0, 0), "edge_u": (1, 0, 0), "edge_v": (0, 1, 0), "albedo": (0.5, 0.5, 0.5)}
for n in ("corner", "edge_u", "edge_v"):
    vec_arg("scene builders", "SceneBuilder.add_quad", lambda **kw: _b().add_quad(**kw), _aq, n, 3)
_ab = {"center": (0, 0, 0), "size": (1, 1, 1), "albedo": (0.5, 0.5, 0.5)}
vec_arg("scene builders", "SceneBuilder.add_box", lambda **kw: _b().add_box(**kw), _ab, "size", 3, "[0.0, inf]", -1.0)
vec_arg("scene builders", "SceneBuilder.add_box", lambda **kw: _b().add_box(**kw), _ab, "center", 3)
real_arg("scene builders", "SceneBuilder.add_box", lambda **kw: _b().add_box(**kw), _ab, "yaw_rad",
         "finite real number")
_as = {"center": (0, 0, 0), "radius": 1.0}
real_arg("scene builders", "SceneBuilder.add_sphere", lambda **kw: _b().add_sphere(**kw), _as, "radius",
         "(0.0, inf]", [0.0, -1.0])
int_arg("scene builders", "SceneBuilder.add_sphere", lambda **kw: _b().add_sphere(**kw), _as, "n_lon", "[3, 4096]",
        [2, 0])
int_arg("scene builders", "SceneBuilder.add_sphere", lambda **kw: _b().add_sphere(**kw), _as, "n_lat", "[2, 4096]",
        [1])
arg("scene builders", "SceneBuilder.add_sphere", lambda **kw: _b().add_sphere(**kw), _as, "albedo_fn", "callable",
    [(5, "5")])

# ================================================================================================================
# mesh files (foveawarp/meshio.py) and the scene registry


@functools.lru_cache(maxsize=None)
def _ply_files():
    import tempfile
    from pathlib import Path

    d = Path(tempfile.mkdtemp(prefix="fw-validation-ply-"))
    head = "ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n" \
           "element tristrips 1\nproperty list int int vertex_indices\nend_header\n"
    asc = head.format(fmt="ascii")
    (d / "range.ply").write_text(asc + "0 0 0\n1 0 0\n0 1 0\n4 0 1 2 7\n")
    (d / "low.ply").write_text(asc + "0 0 0\n1 0 0\n0 1 0\n4 0 1 -2 2\n")
    (d / "nanv.ply").write_text(asc + "0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n")
    (d / "words.ply").write_text(asc + "0 0 zero\n1 0 0\n0 1 0\n3 0 1 2\n")
    (d / "short.ply").write_text(asc + "0 0 0\n1 0 0\n0 1 0\n5 0 1 2\n")
    (d / "degen.ply").write_text(asc + "0 0 0\n1 0 0\n0 1 0\n3 0 1 1\n")
    (d / "fmt.ply").write_text(head.format(fmt="binary_middle_endian") + "")
    (d / "type.ply").write_text(asc.replace("property float z", "property float128 z"))
    (d / "novert.ply").write_text("ply\nformat ascii 1.0\nelement tristrips 1\n"
                                  "property list int int vertex_indices\nend_header\n3 0 1 2\n")
    (d / "notply.ply").write_text("solid nothing\nendsolid\n")
    (d / "trunc.ply").write_bytes(head.format(fmt="binary_little_endian").encode() + b"\x00" * 20)
    return d


def _ply(name):
    return str(_ply_files() / name)


arg("mesh files", "strips_to_triangles", meshio.strips_to_triangles, {}, "strips", "1-D index list",
    [(np.zeros((2, 3), dtype=int), "(2, 3)")])
arg("mesh files", "strips_to_triangles", meshio.strips_to_triangles, {}, "strips", "integer vertex indices",
    [(np.array([0.0, 1.0, 2.0]), "float64")])
arg("mesh files", "strips_to_triangles", meshio.strips_to_triangles, {}, "strips", ">= 0 or -1",
    [(np.array([0, -2, 1]), "got -2 at index (1,)")])
arg("mesh files", "strips_to_triangles", meshio.strips_to_triangles, {}, "strips", "finite real numbers",
    [(np.array([0.0, NAN, 1.0]), "got nan at index (1,)")])
arg("mesh files", "strips_to_triangles", meshio.strips_to_triangles, {}, "strips", "array of real numbers",
    [(np.array(["a", "b", "c"]), "<U1"), (None, "object")])
for fname, f in (("read_ply", meshio.read_ply), ("load_mesh_parts", meshio.load_mesh_parts),
                 ("load_mesh_arrays", meshio.load_mesh_arrays), ("ply_has_tristrips", meshio.ply_has_tristrips)):
    arg("mesh files", fname, f, {}, "path", "a file path", [(None, "None"), (5, "5")], param="scene path")
for fname, f in (("read_ply", meshio.read_ply), ("load_mesh_parts", meshio.load_mesh_parts)):
    arg("mesh files", fname, f, {}, "path", "does not exist", [("/nonexistent/m.ply", "'/nonexistent/m.ply'")],
        param="scene path")
for fname, f in (("read_ply", meshio.read_ply), ("load_scene", fw.load_scene)):
    case("mesh files", f"{fname}:tristrip index too high", lambda _f=f, _n="range.ply": _f(_ply(_n)), {},
         "tristrips[0].vertex_indices", "got 7 at index (3,)", "[-1, 2]")
    case("mesh files", f"{fname}:tristrip index below -1", lambda _f=f, _n="low.ply": _f(_ply(_n)), {},
         "tristrips[0].vertex_indices", "got -2 at index (2,)", "[-1, 2]")
    case("mesh files", f"{fname}:nan vertex", lambda _f=f, _n="nanv.ply": _f(_ply(_n)), {}, "scene file", "nanv.ply",
         "non-finite vertex coordinates")
    case("mesh files", f"{fname}:word in body", lambda _f=f, _n="words.ply": _f(_ply(_n)), {}, "scene file", "words.ply",
         "non-numeric value in PLY element 'vertex'")
    case("mesh files", f"{fname}:list past the end", lambda _f=f, _n="short.ply": _f(_ply(_n)), {}, "scene file",
         "short.ply", "truncated in PLY element 'tristrips'")
    case("mesh files", f"{fname}:binary truncated", lambda _f=f, _n="trunc.ply": _f(_ply(_n)), {}, "scene file",
         "trunc.ply", "truncated in PLY element 'vertex'")
    case("mesh files", f"{fname}:only degenerate triangles", lambda _f=f, _n="degen.ply": _f(_ply(_n)), {}, "scene file",
         "degen.ply", "holds no triangle mesh")
    case("mesh files", f"{fname}:unknown format", lambda _f=f, _n="fmt.ply": _f(_ply(_n)), {}, "PLY format",
         "'binary_middle_endian'", "['ascii', 'binary_little_endian', 'binary_big_endian']")
    case("mesh files", f"{fname}:unknown property type", lambda _f=f, _n="type.ply": _f(_ply(_n)), {}, "scene file",
         "float128", "unreadable PLY header line")
    case("mesh files", f"{fname}:no vertex element", lambda _f=f, _n="novert.ply": _f(_ply(_n)), {}, "scene file",
         "novert.ply", "no 'vertex' element with x, y, z")
case("mesh files", "read_ply:not a PLY file", lambda: meshio.read_ply(_ply("notply.ply")), {}, "scene file",
     "notply.ply", "not a PLY file")
vec_arg("mesh files", "load_mesh_arrays", lambda **kw: meshio.load_mesh_arrays(_ply("degen.ply"), **kw), {},
        "default_albedo", 3, "[0.0, 1.0]", 1.5)
arg("mesh files", "find_named_mesh", meshio.find_named_mesh, {}, "name", "a named mesh ['bunny'",
    [(5, "5"), (None, "None")])
arg("mesh files", "register_builtin_scenes", register_builtin_scenes, {"file_builder": scenes.mesh_on_ground},
    "builtin", "dict of scene name -> builder", [(None, "None"), ({"x": 5}, "{'x': 5}"), ({3: print}, "{3: ")])
arg("mesh files", "register_builtin_scenes", register_builtin_scenes, {"builtin": scenes.BUILTIN}, "file_builder",
    "callable (path, name=None, **kw) -> Scene", [(None, "None"), ("mesh", "'mesh'")])

# ================================================================================================================
# FrameLoop

_fl = {"scene": "cornell", "width": W, "height": H, "device": DEV}
for n in ("width", "height"):
    int_arg("FrameLoop", "FrameLoop", fw.FrameLoop, _fl, n, "[1, 16384]", [0, -1, 16385])
arg("FrameLoop", "FrameLoop", fw.FrameLoop, _fl, "config", "foveawarp.Config",
    [("cfg", "str"), (fw.FoveationConfig(), "FoveationConfig")])
arg("FrameLoop", "FrameLoop", fw.FrameLoop, _fl, "device", "or None for the default", [("tpu:9", "'tpu:9'"),
                                                                                        (5, "5")])
arg("FrameLoop", "FrameLoop", fw.FrameLoop, _fl, "scene", "a scene name or a file path", [(5, "5")],
    param="name_or_path")
arg("FrameLoop", "FrameLoop", fw.FrameLoop, _fl, "timing", "True, False or 'gpu'",
    [("no", "'no'"), ("GPU", "'GPU'"), (1, "1"), (None, "None")])
int_arg("FrameLoop", "FrameLoop", fw.FrameLoop, _fl, "cpu_threads", "[1, 1024]", [0, -2, 1025], none_ok=True)


def _render(**kw):
    return _loop().render(**kw)


def _render_ref(**kw):
    return _loop().render_reference(**kw)


def _render_ref_dof(**kw):
    return _loop(dof=True).render_reference(**kw)


for fname, f in (("render", _render), ("render_reference", _render_ref)):
    arg("FrameLoop", fname, f, {}, "camera", "foveawarp.Camera", [("cam", "str"), (5, "int")])
    real_arg("FrameLoop", fname, f, {}, "time", "finite real number", none_ok=True)
vec_arg("FrameLoop", "render", _render, {}, "gaze_px", 2, "finite real number", none_ok=True)
arg("FrameLoop", "render", _render, {}, "cut", "True or False", [("no", "'no'"), (None, "None")])
vec_arg("FrameLoop", "render_reference(dof on)", _render_ref_dof, {}, "gaze_px", 2, "finite real number",
        none_ok=True)
for v, vs in ((NAN, "nan"), (INF, "inf")):
    case("FrameLoop", f"render_reference(dof off):gaze_px[0]={vs}", _render_ref, {"gaze_px": (v, 1.0)},
         "gaze_px[0]", vs, "finite real number")
case("FrameLoop", "render_reference(dof off):gaze_px='ab'", _render_ref, {"gaze_px": "ab"}, "gaze_px", "'ab'",
     "2 finite numbers")
arg("FrameLoop", "render_reference", _render_ref, {}, "dof", "True or False", [("no", "'no'")])
def _shade(name, **kw):
    loop = _loop()
    kw.setdefault("camera", loop.scene.camera)
    if name == "shade_masked":
        kw.setdefault("mask", loop.full_map)
    if name == "shade_list":
        kw.setdefault("work", wp.zeros(W * H, dtype=wp.int32, device=DEV))
        kw.setdefault("count", wp.zeros(1, dtype=wp.int32, device=DEV))
    return getattr(loop, name)(**kw)


for fname in ("shade_full", "shade_masked", "shade_list", "shade_params"):
    f = functools.partial(_shade, fname)
    arg("FrameLoop", fname, f, {}, "camera", "foveawarp.Camera", [("cam", "str"), (None, "None")])
    arg("FrameLoop", fname, f, {}, "ao_samples", "[0, 256]", [(-1, "-1"), (NAN, "nan"), (257, "257")])
    if fname != "shade_params":
        arg("FrameLoop", fname, f, {}, "out", f"({H}, {W})", [(np.zeros((H, W, 3)), "ndarray")])
        arg("FrameLoop", fname, f, {}, "out", f"({H}, {W})", [(_warr((2, 2), wp.vec3), "(2, 2)")])
arg("FrameLoop", "shade_masked", functools.partial(_shade, "shade_masked"), {}, "mask", f"({H}, {W})",
    [(_warr((2, 2), wp.uint8), "(2, 2)")])
arg("FrameLoop", "shade_list", functools.partial(_shade, "shade_list"), {}, "work", "int32",
    [(_warr(4, wp.float32), "float32")])
arg("FrameLoop", "shade_list", functools.partial(_shade, "shade_list"), {}, "count", "(1,) int32",
    [(_warr(1, wp.float32), "float32")])

# ================================================================================================================
# Stages: SamplingStage, DofStage, ReconstructStage, IndirectStage, ReorderStage, GBuffer

for cls, base in ((SamplingStage, {"width": W, "height": H, "device": DEV}),
                  (DofStage, {"width": W, "height": H, "config": fw.DofConfig(), "device": DEV}),
                  (ReconstructStage, {"width": W, "height": H, "device": DEV}),
                  (ReorderStage, {"width": W, "height": H, "config": fw.ReorderConfig(), "device": DEV}),
                  (GBuffer, {"width": W, "height": H, "device": DEV})):
    for n in ("width", "height"):
        int_arg("stages", cls.__name__, cls, base, n, "[1, 16384]", [0, -2, 16385])
    arg("stages", cls.__name__, cls, base, "device", "or None for the default", [("tpu:9", "'tpu:9'")])
    if cls is not GBuffer:
        arg("stages", cls.__name__, cls, base, "config", "Config", [("cfg", "str"), (5, "int")])
int_arg("stages", "SamplingStage", SamplingStage, {"width": W, "height": H}, "seed", "[0, 2147483647]", [-1, 2**31])
choice_arg("stages", "DofStage", DofStage, {"width": W, "height": H, "config": fw.DofConfig()}, "method", "'gather'")
int_arg("stages", "DofStage", DofStage, {"width": W, "height": H, "config": fw.DofConfig()}, "tile_px", "[1, 64]",
        [0, 65])
int_arg("stages", "ReconstructStage", ReconstructStage, {"width": W, "height": H}, "block", "[1, 64]", [0, 65])
int_arg("stages", "ReconstructStage", ReconstructStage, {"width": W, "height": H}, "window", "[1, 256]", [0, 257],
        none_ok=True)
int_arg("stages", "ReconstructStage", ReconstructStage, {"width": W, "height": H}, "start_step", "[1, 16384]", [0],
        none_ok=True)


def _set_frame(**kw):
    loop = _loop()
    args = dict(gbuffer=loop.gbuffer, camera=loop.scene.camera, gaze_px=(1.0, 1.0), frame_index=0, moving=False,
                first_frame=True)
    args.update(kw)
    return _sampling().set_frame(**args)


vec_arg("stages", "SamplingStage.set_frame", _set_frame, {}, "gaze_px", 2, "finite real number")
int_arg("stages", "SamplingStage.set_frame", _set_frame, {}, "frame_index", "[0, inf]", [-1])
arg("stages", "SamplingStage.set_frame", _set_frame, {}, "camera", "foveawarp.Camera", [("cam", "str")])
for v, vs, p, a in ((NAN, "nan", "eye_prev[0]", "finite real number"), (INF, "inf", "eye_prev[0]",
                                                                       "finite real number"),
                   ((1.0, 2.0), "(1.0, 2.0)", "eye_prev", "3 finite numbers")):
    case("stages", f"SamplingStage.set_frame:eye_prev={vs}", _set_frame,
         {"first_frame": False, "eye_prev": v if isinstance(v, tuple) else (v, 0.0, 0.0)}, p, vs, a)
case("stages", "SamplingStage.set_frame:eye_prev='abc'", _set_frame, {"first_frame": False, "eye_prev": "abc"},
     "eye_prev", "'abc'", "3 finite numbers")
case("stages", "SamplingStage.set_frame:eye_prev=None", _set_frame, {"first_frame": False, "eye_prev": None},
     "eye_prev", "None", "3 finite numbers")
arg("stages", "SamplingStage.set_frame", _set_frame, {"moving": True}, "camera_prev", "foveawarp.Camera or None",
    [("cam", "str")])
arg("stages", "SamplingStage.set_frame", _set_frame, {}, "gbuffer", f"{W} x {H}",
    [(GBuffer(4, 4, DEV), "4 x 4")])
arg("stages", "SamplingStage.set_frame", _set_frame, {}, "gbuffer", "GBuffer", [("gb", "'gb'"), (None, "None")])
arg("stages", "SamplingStage.set_frame", _set_frame, {}, "moving", "True or False", [("no", "'no'")])
arg("stages", "SamplingStage.set_frame", _set_frame, {}, "first_frame", "True or False", [("no", "'no'")])
arg("stages", "SamplingStage.run", lambda **kw: _sampling().run(**{**dict(gbuffer=_loop().gbuffer,
    camera=_loop().scene.camera, gaze_px=(1.0, 1.0), frame_index=0, moving=False, first_frame=True), **kw}), {},
    "gaze_px", "2 finite numbers", [("ab", "'ab'")])
arg("stages", "SamplingStage.end_frame", lambda **kw: _sampling().end_frame(**{"gbuffer": _loop().gbuffer, **kw}), {},
    "valid_mask", f"({H}, {W}) uint8", [(_warr((H, W), wp.float32), "float32"), (_warr((2, 2), wp.uint8), "(2, 2)")])
arg("stages", "SamplingStage.end_frame", lambda **kw: _sampling().end_frame(**{"gbuffer": _loop().gbuffer, **kw}), {},
    "valid_mask", f"({H}, {W}) uint8", [(np.ones((H, W), np.uint8), "ndarray")])
arg("stages", "SamplingStage.end_frame", lambda **kw: _sampling().end_frame(**kw), {}, "gbuffer", "GBuffer",
    [("gb", "'gb'")])
for _n, _dt, _other in (("depth_prev", wp.float32, wp.uint8), ("valid_prev", wp.uint8, wp.float32)):
    arg("stages", "SamplingStage.launch", lambda **kw: _sampling().launch(**{"gbuffer": _loop().gbuffer, **kw}), {},
        _n, f"({H}, {W}) {_dt.__name__} wp.array", [(_warr((2, 2), _dt), "(2, 2)"), (_warr((H, W), _other),
                                                                                   _other.__name__),
                                                     (np.ones((H, W), np.float32), "ndarray")])
arg("stages", "SamplingStage.launch", lambda **kw: _sampling().launch(**kw), {}, "gbuffer", "GBuffer",
    [("gb", "'gb'")])
arg("stages", "SamplingStage.launch", lambda **kw: _sampling().launch(**kw), {}, "gbuffer", f"{W} x {H}",
    [(GBuffer(4, 4, DEV), "4 x 4")])


def _dof_run(**kw):
    args = dict(color_in=_warr((H, W), wp.vec3), depth=_warr((H, W), wp.float32, 1.0), hit=None, focus_depth_m=2.0,
                color_out=_warr((H, W), wp.vec3))
    args.update(kw)
    return _dof_stage().run(**args)


for n, dt in (("color_in", wp.vec3), ("depth", wp.float32), ("color_out", wp.vec3), ("hit", wp.uint8)):
    arg("stages", "DofStage.run", _dof_run, {}, n, f"({H}, {W}) wp.array",
        [(np.zeros((H, W)), "ndarray"), (_warr((H, 3), dt), "(6, 3)")])
real_arg("stages", "DofStage.run", _dof_run, {}, "focus_depth_m", "(0.05, inf]", [0.05, 0.0, -1.0], none_ok=True)
real_arg("stages", "DofStage.run", _dof_run, {}, "fov_y_deg", "(0.0, 180.0)", [0.0, 180.0], none_ok=True)
arg("stages", "DofStage.run", _dof_run, {}, "focus_depth_m", "(1,) float32 wp.array", [(_warr(2, wp.float32), "(2,)")])
real_arg("stages", "DofStage.set_focus", lambda **kw: _dof_stage().set_focus(**kw), {}, "focus_depth_m",
         "(0.05, inf]", [0.01])
vec_arg("stages", "DofStage.focus_at_pixel", lambda **kw: _dof_stage().focus_at_pixel(
    **{"depth": _warr((H, W), wp.float32), "hit": None, **kw}), {}, "gaze_px", 2, "finite real number")
arg("stages", "DofStage.focus_at_pixel", lambda **kw: _dof_stage().focus_at_pixel(
    **{"hit": None, "gaze_px": (1, 1), **kw}), {}, "depth", f"({H}, {W}) wp.array", [(np.zeros((H, W)), "ndarray")])

for fname, f, base in (
        ("ReconstructStage.run", lambda **kw: _recon().run(**kw),
         {"color_in": _warr((H, W), wp.vec3), "seed_mask": _warr((H, W), wp.uint8), "color_out": _warr((H, W), wp.vec3)}),
        ("ReconstructStage.run_interpolate", lambda **kw: _recon().run_interpolate(**kw),
         {"color_in": _warr((H, W), wp.vec3), "color_out": _warr((H, W), wp.vec3)})):
    for n in [k for k in base]:
        arg("stages", fname, f, base, n, f"({H}, {W}) wp.array", [(np.zeros((H, W, 3)), "ndarray"),
                                                                  (_warr((2, 2), base[n].dtype), "(2, 2)")])
arg("stages", "ReconstructStage.run_interpolate", lambda **kw: _recon().run_interpolate(**kw),
    {"color_in": _warr((H, W), wp.vec3), "color_out": _warr((H, W), wp.vec3)}, "nearest", "vec2i",
    [(_warr((H, W), wp.vec2), "vec2f")])
arg("stages", "ReconstructStage.run_jfa", lambda **kw: _recon().run_jfa(**kw), {}, "seed_mask",
    f"({H}, {W}) wp.array of uint8", [(np.ones((H, W)), "ndarray"), (_warr((H, W), wp.float32), "float32")])
for n in ("color_in", "color_out"):  # the optional Voronoi outputs of the last JFA pass
    arg("stages", "ReconstructStage.run_jfa", lambda **kw: _recon().run_jfa(**kw),
        {"seed_mask": _warr((H, W), wp.uint8), "color_in": _warr((H, W), wp.vec3)}, n, f"({H}, {W}) wp.array",
        [(np.zeros((H, W, 3)), "ndarray"), (_warr((2, 2), wp.vec3), "(2, 2)"), (_warr((H, W), wp.vec2), "vec2f")])
arg("stages", "ReconstructStage.run_jfa", lambda **kw: _recon().run_jfa(**kw),
    {"seed_mask": _warr((H, W), wp.uint8), "color_out": _warr((H, W), wp.vec3)}, "color_in", f"({H}, {W}) wp.array",
    [(None, "None")])


def _indirect_ctor(**kw):
    args = {"dscene": _ds(), **kw}
    return IndirectStage(**args)


arg("stages", "IndirectStage", _indirect_ctor, {}, "dscene", "foveawarp.DeviceScene",
    [("cornell", "'cornell'"), (None, "None")])
arg("stages", "IndirectStage", _indirect_ctor, {}, "config", "IndirectConfig", [("cfg", "str"), (fw.Config(), "Config")])
choice_arg("stages", "IndirectStage", _indirect_ctor, {}, "method", "'lighttree'")
int_arg("stages", "IndirectStage", _indirect_ctor, {}, "light_index", "[0, 0]", [1, -1], none_ok=True)
int_arg("stages", "IndirectStage", _indirect_ctor, {"method": "sampled"}, "samples", "[1, 65536]", [0, 70000])
int_arg("stages", "IndirectStage", _indirect_ctor, {}, "seed", "[0, 9223372036854775807]", [-1])
int_arg("stages", "IndirectStage", _indirect_ctor, {}, "max_receivers", "[1, 1073741824]", [0], none_ok=True)
arg("stages", "IndirectStage", _indirect_ctor, {}, "device", "or None for the default", [("tpu:9", "'tpu:9'")])
_rp = {"pos": _warr(4, wp.vec3), "normal": _warr(4, wp.vec3), "albedo": _warr(4, wp.vec3), "out": _warr(4, wp.vec3)}
for n in _rp:
    arg("stages", "IndirectStage.run_points", lambda **kw: _indirect().run_points(**kw), _rp, n, "vec3",
        [(np.zeros((4, 3)), "ndarray"), (_warr(4, wp.float32), "float32")])
arg("stages", "IndirectStage.run_points", lambda **kw: _indirect().run_points(**kw), _rp, "normal", "(4,)",
    [(_warr(3, wp.vec3), "(3,)")])
arg("stages", "IndirectStage.run_full", lambda **kw: _indirect().run_full(**kw), {"radiance": _warr((H, W), wp.vec3)},
    "gbuffer", "foveawarp.GBuffer", [("gb", "'gb'"), (None, "None")])
arg("stages", "IndirectStage.run_full", lambda **kw: _indirect().run_full(**{"gbuffer": _loop().gbuffer, **kw}), {},
    "radiance", f"({H}, {W})", [(np.zeros((H, W, 3)), "ndarray"), (_warr((2, 2), wp.vec3), "(2, 2)")])
_rl = {"work": _warr(W * H, wp.int32), "count": _warr(1, wp.int32), "radiance": _warr((H, W), wp.vec3), "width": W}
for n, bad in (("work", [(np.zeros(4, np.int32), "ndarray"), (_warr(4, wp.float32), "float32")]),
               ("count", [(_warr(2, wp.int32), "(2,)")]),
               ("radiance", [(_warr((2, 2), wp.vec3), "(2, 2)")])):
    arg("stages", "IndirectStage.run_list", lambda **kw: _indirect().run_list(**{"gbuffer": _loop().gbuffer, **kw}),
        _rl, n, n == "count" and "(1,)" or "wp.array", bad)
int_arg("stages", "IndirectStage.run_list", lambda **kw: _indirect().run_list(**{"gbuffer": _loop().gbuffer, **kw}),
        _rl, "width", "[1, 16384]", [0])
case("stages", "IndirectStage.run_list:width mismatch",
     lambda **kw: _indirect().run_list(**{"gbuffer": _loop().gbuffer, **kw}), {**_rl, "width": W + 1}, "width",
     str(W + 1), f"G-buffer width {W}")
int_arg("stages", "IndirectStage.level_numpy", lambda **kw: _indirect().level_numpy(**kw), {}, "level", "[0, 3]",
        [-1, 4])
_rsm = {k: np.zeros((8, 8, 3)) for k in ("flux", "position", "normal")}
_rsm["depth"] = np.zeros((8, 8))
for n in _rsm:
    arg("stages", "IndirectStage.load_rsm", lambda **kw: _indirect().load_rsm(**kw), _rsm, n, "finite",
        [(_with(_rsm[n], (0,) * _rsm[n].ndim, NAN), "nan")])
    arg("stages", "IndirectStage.load_rsm", lambda **kw: _indirect().load_rsm(**kw), _rsm, n, "(8, 8",
        [(np.zeros((4, 4, 3)), "(4, 4, 3)")])
arg("stages", "IndirectStage.load_rsm", lambda **kw: _indirect().load_rsm(**kw), _rsm, "flux", "[0.0, inf]",
    [(_with(_rsm["flux"], (0, 0, 0), -1.0), "-1.0")])
choice_arg("stages", "ReorderStage.run", lambda **kw: _reorder().run(**{"mask": _warr((H, W), wp.uint8), **kw}), {},
           "strategy", "'tile'", none_ok=True)
arg("stages", "ReorderStage.run", lambda **kw: _reorder().run(**kw), {}, "mask", f"({H}, {W}) uint8 wp.array",
    [(np.ones((H, W), np.uint8), "ndarray"), (_warr((H, W), wp.float32), "float32"), (_warr((2, 2), wp.uint8), "(2, 2)")])

# ================================================================================================================
# ops

_G = {"width": W, "height": H, "gaze_px": (4.0, 3.0), "fov_y_deg": 60.0, "device": DEV}
_FP = {**_G, "mar_slope": 0.03, "mar_fovea_deg": 0.02, "min_probability": 0.05}
for fname, f, base in (("eccentricity_deg", ops.eccentricity_deg, _G),
                       ("foveation_probability", ops.foveation_probability, _FP)):
    for n in ("width", "height"):
        int_arg("ops", fname, f, base, n, "[1, 16384]", [0, -1, 16385])
    vec_arg("ops", fname, f, base, "gaze_px", 2, "finite real number")
    real_arg("ops", fname, f, base, "fov_y_deg", "(0.0, 180.0)", [0.0, -5.0, 180.0, 360.0])
    arg("ops", fname, f, base, "device", "or None for the default", [("tpu:9", "'tpu:9'"), (3, "3")])
real_arg("ops", "foveation_probability", ops.foveation_probability, _FP, "mar_slope", "(0.0, 1.0]", [0.0, 1.5])
real_arg("ops", "foveation_probability", ops.foveation_probability, _FP, "mar_fovea_deg", "(0.0, 1.0]", [0.0, 2.0])
real_arg("ops", "foveation_probability", ops.foveation_probability, _FP, "min_probability", "[0.0, 1.0]", [-0.1, 1.1])
_P = np.full((H, W), 0.5)
_SM = {"probability": _P, "block": 2, "device": DEV}
array_arg("ops", "sample_map", ops.sample_map, _SM, "probability", _P, shape_bad=(H, W, 2),
          shape_allowed="(H, W) array")
case("ops", "sample_map:probability empty", ops.sample_map, {**_SM, "probability": np.zeros((0, 4))}, "probability",
     "(0, 4)", "non-empty (H, W)")
int_arg("ops", "sample_map", ops.sample_map, _SM, "block", "[1, 64]", [0, 65])
int_arg("ops", "sample_map", ops.sample_map, _SM, "frame_index", "[0, inf]", [-1])
int_arg("ops", "sample_map", ops.sample_map, _SM, "seed", "[0, 2147483647]", [-1, 2**31])
_ALB = np.full((H, W, 3), 0.5)
for fname, f, n in (("albedo_to_lab", ops.albedo_to_lab, "albedo"), ("albedo_gradient", ops.albedo_gradient, "albedo"),
                    ("normal_gradient", ops.normal_gradient, "normal")):
    array_arg("ops", fname, f, {"device": DEV}, n, _ALB, shape_bad=(H, W), shape_allowed="(H, W, 3)")
_DF = {"depth_m": np.full((H, W), 2.0), "focus_depth_m": 2.0, "sigma1_m": 0.5, "sigma2_m": 1.0, "dof_floor": 0.1,
       "device": DEV}
array_arg("ops", "dof_sampling_factor", ops.dof_sampling_factor, _DF, "depth_m", _DF["depth_m"], shape_bad=(H, W, 1),
          shape_allowed="(H, W) array")
real_arg("ops", "dof_sampling_factor", ops.dof_sampling_factor, _DF, "focus_depth_m", "(0.0, inf]", [0.0, -1.0])
real_arg("ops", "dof_sampling_factor", ops.dof_sampling_factor, _DF, "sigma1_m", "[0.0, inf]", [-0.1])
real_arg("ops", "dof_sampling_factor", ops.dof_sampling_factor, _DF, "sigma2_m", "(0.0, inf]", [0.0])
real_arg("ops", "dof_sampling_factor", ops.dof_sampling_factor, _DF, "dof_floor", "[0.0, 1.0]", [-0.1, 1.5])
_CT = {"reproj_uv": np.zeros((H, W, 2)), "position": np.zeros((H, W, 3)), "hit": np.ones((H, W), np.uint8),
       "depth": np.ones((H, W)), "depth_prev": np.ones((H, W)), "valid_prev": np.ones((H, W), np.uint8),
       "eye_prev": (0.0, 0.0, 0.0), "depth_eps_rel": 0.01, "device": DEV}
for n, sb, sa in (("reproj_uv", (H, W, 3), f"({H}, {W}, 2)"), ("position", (H, W, 2), f"({H}, {W}, 3)"),
                  ("hit", (H, W + 1), f"({H}, {W})"), ("depth", (H, W, 1), "(H, W) array"),
                  ("depth_prev", (H + 1, W), f"({H}, {W})"), ("valid_prev", (W, H), f"({H}, {W})")):
    rng_ = "[0.0, inf]" if n in ("depth", "depth_prev") else "finite real numbers"
    array_arg("ops", "cache_test", ops.cache_test, _CT, n, _CT[n], rng_, shape_bad=sb, shape_allowed=sa)
case("ops", "cache_test:depth=-1", ops.cache_test, {**_CT, "depth": _with(_CT["depth"], (0, 1), -1.0)}, "depth",
     "got -1.0 at index (0, 1)", "[0.0, inf]")
vec_arg("ops", "cache_test", ops.cache_test, _CT, "eye_prev", 3)
real_arg("ops", "cache_test", ops.cache_test, _CT, "depth_eps_rel", "(0.0, 1.0]", [0.0, 1.5])
int_arg("ops", "dither_ranks", ops.dither_ranks, {}, "block", "[1, 64]", [0, 65])
_M = (np.arange(H * W).reshape(H, W) % 3 == 0).astype(np.uint8)
array_arg("ops", "compact", ops.compact, {"device": DEV}, "mask", _M, shape_bad=(H * W,), shape_allowed="(H, W)")
choice_arg("ops", "compact", ops.compact, {"mask": _M, "device": DEV}, "order", "'tile'")
int_arg("ops", "compact", ops.compact, {"mask": _M, "device": DEV}, "tile", "[2, 64]", [0, 3, 128])
array_arg("ops", "reorder_rows", ops.reorder_rows, {"device": DEV}, "mask", _M, shape_bad=(2, H, W),
          shape_allowed="(H, W)")
int_arg("ops", "reorder_rows", ops.reorder_rows, {"mask": _M, "device": DEV}, "balance_rows", "[0, 1024]", [-1, 2000])
array_arg("ops", "jump_flood", ops.jump_flood, {"device": DEV}, "seed_mask", _M, shape_bad=(H, W, 1),
          shape_allowed="2-D (H, W)")
case("ops", "jump_flood:seed_mask width 0", ops.jump_flood, {"seed_mask": np.zeros((4, 0)), "device": DEV}, "width",
     "0", "[1, 16384]")
choice_arg("ops", "jump_flood", ops.jump_flood, {"seed_mask": _M, "device": DEV}, "variant", "'1+jfa'")
int_arg("ops", "jump_flood", ops.jump_flood, {"seed_mask": _M, "device": DEV}, "start_step", "[1, 16384]", [0, 20000],
        none_ok=True)
# the path integrator's converged reference: its arguments are checked before the scene is read
_RC = {"scene": None, "camera": None, "width": W, "height": H, "spp_total": 4, "device": DEV}
for n, allowed, oor in (("spp_total", "[1, 2147483647]", [0, -1]), ("spp_per_pass", "[1, 65536]", [0, 70000]),
                        ("max_depth", "[1, 4096]", [0]), ("rr_depth", "[1, 4096]", [0]),
                        ("seed", "[0, 2147483647]", [-1])):
    int_arg("ops", "render_converged", ops.render_converged, _RC, n, allowed, oor)
choice_arg("ops", "render_converged", ops.render_converged, _RC, "pixel_filter", "'box'")
_C = np.full((H, W, 3), 0.25)
for fname, f in (("voronoi", ops.voronoi), ("sibson", ops.sibson)):
    base = {"colors": _C, "seed_mask": _M, "device": DEV}
    array_arg("ops", fname, f, base, "colors", _C, shape_bad=(H, W), shape_allowed=f"({H}, {W}, 3)")
    array_arg("ops", fname, f, base, "seed_mask", _M, shape_bad=(H,), shape_allowed="2-D (H, W)")
    choice_arg("ops", fname, f, base, "variant", "'1+jfa'")
    array_arg("ops", fname, f, {**base, "seed_mask": np.ones((H, W))}, "nearest",
              np.stack(np.meshgrid(np.arange(W), np.arange(H)), -1), shape_bad=(H, W, 3),
              shape_allowed=f"({H}, {W}, 2)")
    case("ops", f"{fname}:nearest out of range", f, {**base, "nearest": np.full((H, W, 2), 99)}, "nearest",
         "(99, 99)", f"0 <= x < {W}")
    case("ops", f"{fname}:nearest float", f, {**base, "nearest": np.zeros((H, W, 2))}, "nearest", "float64",
         "integers")
int_arg("ops", "sibson", ops.sibson, {"colors": _C, "seed_mask": _M, "device": DEV}, "window", "[1, 256]", [0, 257],
        none_ok=True)
for fname, f in (("sibson_window_for_block", ops.sibson_window_for_block),
                 ("jfa_start_step_for_block", ops.jfa_start_step_for_block),
                 ("max_seed_distance_for_block", ops.max_seed_distance_for_block)):
    int_arg("ops", fname, f, {}, "block", "[1, 64]", [0, 65])
for n in ("width", "height"):
    int_arg("ops", "jfa_steps", ops.jfa_steps, {"width": W, "height": H}, n, "[1, 16384]", [0, -1])
choice_arg("ops", "jfa_steps", ops.jfa_steps, {"width": W, "height": H}, "variant", "'1+jfa'")
int_arg("ops", "jfa_steps", ops.jfa_steps, {"width": W, "height": H}, "start_step", "[1, 16384]", [0], none_ok=True)
_LENS = {"focal_length_m": 0.05, "focus_depth_m": 2.0, "aperture_m": 0.01, "px_per_m": 2e4}
_D = np.full((H, W), 3.0)
_COC = {"depth_m": _D, **_LENS, "device": DEV}
_DS = {"color": _C, "depth_m": _D, **_LENS, "device": DEV}
for fname, f, base in (("circle_of_confusion_px", ops.circle_of_confusion_px, _COC), ("dof_scatter", ops.dof_scatter,
                                                                                     _DS)):
    real_arg("ops", fname, f, base, "focal_length_m", "(0.0, inf]", [0.0, -0.05])
    real_arg("ops", fname, f, base, "focus_depth_m", "(0.05, inf]", [0.05, 0.01, -1.0])
    real_arg("ops", fname, f, base, "aperture_m", "[0.0, inf]", [-0.01])
    real_arg("ops", fname, f, base, "px_per_m", "(0.0, inf]", [0.0])
array_arg("ops", "circle_of_confusion_px", ops.circle_of_confusion_px, _COC, "depth_m", _D)
real_arg("ops", "circle_of_confusion_px", ops.circle_of_confusion_px, _COC, "max_coc_px", "(0.0, inf]", [0.0, -1.0],
         none_ok=True)
array_arg("ops", "dof_scatter", ops.dof_scatter, _DS, "color", _C, shape_bad=(H, W), shape_allowed="(H, W, 3)")
array_arg("ops", "dof_scatter", ops.dof_scatter, _DS, "depth_m", _D, shape_bad=(H, W + 1), shape_allowed=f"({H}, {W})")
array_arg("ops", "dof_scatter", ops.dof_scatter, _DS, "hit", np.ones((H, W)), shape_bad=(W, H),
          shape_allowed=f"({H}, {W})")
real_arg("ops", "dof_scatter", ops.dof_scatter, _DS, "gamma", "[0.0, 16.0]", [-1.0, 17.0])
real_arg("ops", "dof_scatter", ops.dof_scatter, _DS, "eps_px", "(0.0, inf]", [0.0])
real_arg("ops", "dof_scatter", ops.dof_scatter, _DS, "max_coc_px", "[1.0, 128.0]", [0.5, 200.0])
choice_arg("ops", "dof_scatter", ops.dof_scatter, _DS, "method", "'gather'")
int_arg("ops", "dof_scatter", ops.dof_scatter, _DS, "tile_px", "[1, 64]", [0, 65])
for n in ("foreground_fix", "background_fix"):
    arg("ops", "dof_scatter", ops.dof_scatter, _DS, n, "True or False", BOOL_BAD)
_RP = np.array([[0.0, 0.5, 0.0], [0.2, 1.0, -0.5]])
_RN = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
_IND = {"positions": _RP, "normals": _RN, "albedos": (0.5, 0.5, 0.5),
        "config": fw.IndirectConfig(rsm_size=8, start_level=1, limit_level=2), "device": DEV}


def _ind(f):
    return lambda **kw: f(**{"scene": _ds(), **kw})


for fname, f in (("indirect_light_tree", ops.indirect_light_tree), ("indirect_vpl_exact", ops.indirect_vpl_exact),
                 ("indirect_rsm_sampled", ops.indirect_rsm_sampled)):
    g = _ind(f)
    array_arg("ops", fname, g, _IND, "positions", _RP, shape_bad=(2, 2), shape_allowed="(..., 3)")
    array_arg("ops", fname, g, _IND, "normals", _RN, shape_bad=(3, 3), shape_allowed="(2, 3)")
    array_arg("ops", fname, g, _IND, "albedos", np.full((2, 3), 0.5), "[0.0, inf]", extra=[(-0.5, "-0.5")],
              shape_bad=(2, 2), shape_allowed="(3,) or the shape of positions")
    arg("ops", fname, f, _IND, "scene", "a scene name or a file path", [(5, "5")], param="name_or_path")
    arg("ops", fname, f, _IND, "scene", "'cornell'", [("nope", "'nope'")])
    arg("ops", fname, g, _IND, "config", "IndirectConfig", [("cfg", "str"), (fw.Config(), "Config")])
    int_arg("ops", fname, g, _IND, "light_index", "[0, 0]", [1, -1], none_ok=True)
    arg("ops", fname, g, {k: v for k, v in _IND.items() if k != "device"}, "device", "or None for the default",
        [("tpu:9", "'tpu:9'")])
choice_arg("ops", "indirect_light_tree", _ind(ops.indirect_light_tree), _IND, "traversal", "'cut'")
int_arg("ops", "indirect_rsm_sampled", _ind(ops.indirect_rsm_sampled), _IND, "samples", "[1, 64]", [0, 65])
int_arg("ops", "indirect_rsm_sampled", _ind(ops.indirect_rsm_sampled), {**_IND, "samples": 16}, "seed",
        "[0, 9223372036854775807]", [-1])
for fname, f in (("reflective_shadow_map", ops.reflective_shadow_map), ("light_quadtree", ops.light_quadtree)):
    arg("ops", fname, _ind(f), {}, "config", "IndirectConfig", [("cfg", "str")])
    int_arg("ops", fname, _ind(f), {}, "light_index", "[0, 0]", [3], none_ok=True)
    arg("ops", fname, f, {}, "scene", "'cornell'", [("nope", "'nope'")])
int_arg("ops", "poisson_disk", ops.poisson_disk, {"seed": 0}, "n", "[1, 4194304]", [0, -1], param="samples")
int_arg("ops", "poisson_disk", ops.poisson_disk, {"n": 4}, "seed", "[0, 9223372036854775807]", [-1])

# ================================================================================================================
# metrics

_IMG = np.full((12, 12, 3), 0.5)
for fname, f in (("psnr", metrics.psnr), ("ssim", metrics.ssim)):
    for n in ("a", "b"):
        base = {"a": _IMG, "b": _IMG}
        array_arg("metrics", fname, f, base, n, _IMG)
        case("metrics", f"{fname}:{n}=1-D", f, {**base, n: np.zeros(12)}, n, "(12,)", "(H, W) or (H, W, C)")
        case("metrics", f"{fname}:{n}=empty", f, {**base, n: np.zeros((0, 0))}, n, "(0, 0)", "non-empty")
    case("metrics", f"{fname}:shape mismatch", f, {"a": _IMG, "b": _IMG[:, :4]}, "a and b", "(12, 4, 3)",
         "same shape")
    array_arg("metrics", fname, f, {"a": _IMG, "b": _IMG}, "mask", np.ones((12, 12)), shape_bad=(4, 4),
              shape_allowed="(12, 12)")
real_arg("metrics", "psnr", metrics.psnr, {"a": _IMG, "b": _IMG}, "data_range", "(0.0, inf]", [0.0, -1.0])
for shp in ((4, 4), (10, 30)):
    case("metrics", f"ssim:too small {shp}", metrics.ssim, {"a": np.zeros(shp), "b": np.zeros(shp)}, "a and b",
         repr(shp), "at least 11 x 11")
_RM = {"img": _IMG, "ref": _IMG, "gaze_px": (4.0, 4.0), "fov_y_deg": 60.0}
case("metrics", "region_metrics:too small", metrics.region_metrics, {**_RM, "img": _IMG[:8, :8], "ref": _IMG[:8, :8]},
     "a and b", "(8, 8)", "at least 11 x 11")
for n in ("img", "ref"):
    array_arg("metrics", "region_metrics", metrics.region_metrics, _RM, n, _IMG)
vec_arg("metrics", "region_metrics", metrics.region_metrics, _RM, "gaze_px", 2, "finite real number")
real_arg("metrics", "region_metrics", metrics.region_metrics, _RM, "fov_y_deg", "(0.0, 180.0)", [0.0, 180.0])
_EC = {"width": 8, "height": 8, "gaze_px": (4.0, 4.0), "fov_y_deg": 60.0}
for fname, f in (("eccentricity_np", metrics.eccentricity_np), ("region_masks", metrics.region_masks)):
    for n in ("width", "height"):
        int_arg("metrics", fname, f, _EC, n, "[1, 16384]", [0, -1])
    vec_arg("metrics", fname, f, _EC, "gaze_px", 2, "finite real number")
    real_arg("metrics", fname, f, _EC, "fov_y_deg", "(0.0, 180.0)", [0.0, 200.0])
arg("metrics", "region_masks", metrics.region_masks, _EC, "regions", "non-empty dict", [("x", "'x'"), ({}, "{}")])
arg("metrics", "region_masks", metrics.region_masks, _EC, "regions", "(lo_deg, hi_deg)", [({"a": 5}, "5")],
    param="regions['a']")
arg("metrics", "region_masks", metrics.region_masks, _EC, "regions", "(5.0, inf]", [({"a": (5, 1)}, "1")],
    param="regions['a'][1]")
arg("metrics", "region_masks", metrics.region_masks, _EC, "regions", "[0.0, inf]", [({"a": (NAN, 1)}, "nan")],
    param="regions['a'][0]")

# device metrics: NumPy inputs are checked on the host like psnr's; Warp vec3 inputs on the device (count of
# non-finite values, reported after the one read)
class _AsWarp:
    """A NumPy image that ``_warp_call`` uploads as a (H, W) vec3 Warp array (or (N,) for a (N, 3) one)."""

    def __init__(self, v):
        self.v = np.asarray(v, dtype=np.float32)


def _warp_call(f):
    def call(**kw):
        return f(**{k: (wp.array(v.v, dtype=wp.vec3, device=DEV) if isinstance(v, _AsWarp) else v)
                    for k, v in kw.items()})
    return call


for fname, f in (("psnr_device", metrics.psnr_device), ("ssim_device", metrics.ssim_device)):
    base = {"a": _IMG, "b": _IMG, "device": DEV}
    for n in ("a", "b"):
        array_arg("metrics", fname, f, base, n, _IMG)
        case("metrics", f"{fname}:{n}=1-D", f, {**base, n: np.zeros(12)}, n, "(12,)", "(H, W) or (H, W, 3)")
        case("metrics", f"{fname}:{n}=4 channels", f, {**base, n: np.zeros((12, 12, 4))}, n, "(12, 12, 4)",
             "(H, W) or (H, W, 3)")
        case("metrics", f"{fname}:{n}=empty", f, {**base, n: np.zeros((0, 0))}, n, "(0, 0)", "non-empty")
        case("metrics", f"{fname}:{n}=1-D warp", _warp_call(f), {**base, n: _AsWarp(np.zeros((12, 3)))}, n,
             "(12, 3)", "(H, W) or (H, W, 3)")
        case("metrics", f"{fname}:{n}=warp nan", _warp_call(f), {**base, n: _AsWarp(_with(_IMG, (2, 3, 1), NAN))},
             n, "got 1 non-finite", "finite real numbers")
    case("metrics", f"{fname}:shape mismatch", f, {**base, "b": _IMG[:, :4]}, "a and b", "(12, 4, 3)", "same shape")
    array_arg("metrics", fname, f, base, "mask", np.ones((12, 12)), shape_bad=(4, 4), shape_allowed="(12, 12)")
    case("metrics", f"{fname}:mask=warp shape", f, {**base, "mask": wp.zeros((4, 4), dtype=wp.uint8, device=DEV)},
         "mask", "(4, 4)", "(12, 12)")
    arg("metrics", fname, f, base, "device", "or None for the default", [("tpu:9", "'tpu:9'")])
real_arg("metrics", "psnr_device", metrics.psnr_device, {"a": _IMG, "b": _IMG, "device": DEV}, "data_range",
         "(0.0, inf]", [0.0, -1.0])
for shp in ((4, 4), (10, 30), (1, 40), (40, 1)):
    case("metrics", f"ssim_device:too small {shp}", metrics.ssim_device,
         {"a": np.zeros(shp), "b": np.zeros(shp), "device": DEV}, "a and b", repr(shp), "at least 11 x 11")
_RMD = {**_RM, "device": DEV}
case("metrics", "region_metrics_device:too small", metrics.region_metrics_device,
     {**_RMD, "img": _IMG[:8, :8], "ref": _IMG[:8, :8]}, "img and ref", "(8, 8)", "at least 11 x 11")
for n in ("img", "ref"):
    array_arg("metrics", "region_metrics_device", metrics.region_metrics_device, _RMD, n, _IMG)
    case("metrics", f"region_metrics_device:{n}=warp inf", _warp_call(metrics.region_metrics_device),
         {**_RMD, n: _AsWarp(_with(_IMG, (0, 0, 0), INF))}, n, "got 1 non-finite", "finite real numbers")
case("metrics", "region_metrics_device:shape mismatch", metrics.region_metrics_device, {**_RMD, "ref": _IMG[:11]},
     "img and ref", "(11, 12, 3)", "same shape")
vec_arg("metrics", "region_metrics_device", metrics.region_metrics_device, _RMD, "gaze_px", 2, "finite real number")
real_arg("metrics", "region_metrics_device", metrics.region_metrics_device, _RMD, "fov_y_deg", "(0.0, 180.0)",
         [0.0, 180.0])
arg("metrics", "region_metrics_device", metrics.region_metrics_device, _RMD, "device", "or None for the default",
    [("tpu:9", "'tpu:9'")])


# ================================================================================================================
# live viewer session and gaze traces (the server itself needs the optional extra and is tested in test_viewer.py)

from foveawarp.gaze_trace import GazeTrace, load_gaze_trace  # noqa: E402
from foveawarp.viewer.session import ViewerSession  # noqa: E402

_VS = {"scenes": ["cornell"], "width": 8, "height": 6, "device": DEV}
for n in ("width", "height"):
    int_arg("viewer", "ViewerSession", ViewerSession, _VS, n, "[1, 16384]", [0, -1])
arg("viewer", "ViewerSession", ViewerSession, _VS, "quality", "[10, 100]",
    [(5, "5"), (101, "101"), (True, "True"), (80.5, "80.5")])
arg("viewer", "ViewerSession", ViewerSession, _VS, "scenes", "a scene name or a file path",
    [([5], "5"), ([""], "''")], param="scene")
case("viewer", "ViewerSession:device", ViewerSession, {**_VS, "device": "cuda:99"}, "device", "'cuda:99'", "one of")
_GT = {"t_s": [0.0, 1.0], "x_px": [1.0, 2.0], "y_px": [3.0, 4.0]}
for n in ("t_s", "x_px", "y_px"):
    for bad, shown in ((NAN, "nan"), (INF, "inf")):
        case("viewer", f"GazeTrace:{n}={shown}", GazeTrace, {**_GT, n: [0.0, bad]}, n, shown, "finite numbers")
case("viewer", "GazeTrace:t_s decreasing", GazeTrace, {**_GT, "t_s": [1.0, 0.5]}, "t_s", "0.5", "non-decreasing")
case("viewer", "GazeTrace:empty", GazeTrace, {"t_s": [], "x_px": [], "y_px": []}, "t_s,x_px,y_px", "0 rows",
     "at least one row")
for bad, shown in ((NAN, "nan"), (INF, "inf"), ("1", "'1'")):
    case("viewer", f"GazeTrace.at:t={shown}", GazeTrace(**_GT).at, {"t": bad}, "t", shown, "finite real number")
case("viewer", "load_gaze_trace:missing", load_gaze_trace, {"path": "no-such-trace.csv"}, "gaze trace",
     "no-such-trace.csv", "does not exist")
case("viewer", "load_gaze_trace:type", load_gaze_trace, {"path": 5}, "gaze trace path", "5", "a file path")


# ================================================================================================================


def case_families() -> Counter:
    """Number of cases per entry point family."""
    return Counter(p.values[0] for p in CASES)


@pytest.mark.parametrize("family, fn, kwargs, param, value, allowed", CASES)
def test_bad_input_raises_value_error_naming_parameter_value_and_range(family, fn, kwargs, param, value, allowed):
    with pytest.raises(ValueError, match=re.escape(param)) as ei:
        fn(**kwargs)
    msg = str(ei.value)
    assert value in msg, f"value {value!r} not in message {msg!r}"
    if isinstance(allowed, re.Pattern):
        assert allowed.search(msg), f"allowed range /{allowed.pattern}/ not in message {msg!r}"
    else:
        assert allowed in msg, f"allowed range {allowed!r} not in message {msg!r}"


def test_table_covers_every_public_entry_point():
    """Every name exported by foveawarp and foveawarp.ops has at least one bad-input case."""
    ids = " ".join(p.id for p in CASES)
    names = [n for n in ops.__all__]
    names += [n for n in fw.__all__ if n not in ("ops", "Frame", "GBuffer", "DeviceScene", "Config")]
    missing = [n for n in names if n not in ids]
    assert not missing, missing


def test_messages_quote_one_real_example():
    """The example quoted in README.md's Input validation section is the real message."""
    with pytest.raises(ValueError) as ei:
        fw.FoveationConfig(mar_slope=float("nan"))
    assert str(ei.value) == "FoveationConfig.mar_slope must be a finite number in (0.0, 1.0], got nan"
    with pytest.raises(ValueError) as ei:
        ops.sibson(np.full((2, 2, 3), np.nan), np.ones((2, 2)), device=DEV)
    assert str(ei.value) == "colors must hold finite real numbers, got nan at index (0, 0, 0)"


def test_kernels_see_no_nan_through_the_frame_loop():
    """Valid inputs at their range limits still give finite frames (the guards above do not over-reject)."""
    loop = fw.FrameLoop("cornell", W, H, device=DEV)
    for gaze in ((0.0, 0.0), (-1e9, 1e9), (W * 0.5, H * 0.5)):
        img = loop.render(gaze_px=gaze, time=0.0).numpy()
        assert np.isfinite(img).all()
    assert math.isfinite(metrics.psnr(img, img * 0.5))
