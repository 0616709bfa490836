"""Indirect light ops (ALGORITHMS.md C): the light quad-tree, the exact all-VPL sum and the Poisson-sampled
RSM, on the same RSM and the same receiver points. They run :class:`~foveawarp.stages.indirect.IndirectStage`.

Common signature::

    indirect_xxx(scene, positions, normals, albedos, *, config=None, light_index=None, device=None, ...)
        -> (..., 3) float32 radiance

``scene``: a :class:`~foveawarp.scene.Scene`, a built-in scene name / mesh path, a
:class:`~foveawarp.scene.DeviceScene` or a :class:`~foveawarp.frame_loop.FrameLoop` (its ``dscene``).
``positions``, ``normals``: (..., 3) world receiver points and unit normals (a zero normal receives nothing);
``albedos``: (..., 3) or (3,) linear RGB. The result is the one-bounce diffuse radiance
``albedo / pi * E(x) * strength`` (visibility ignored), with ``E`` the RSM irradiance form including the
Lambertian VPL's ``1 / pi`` (see ``kernels/lighttree.py``). ``light_index=None`` picks the first spot light.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import warp as wp

from .._util import as_wp, get_device
from ..config import IndirectConfig, check_array
from ..stages.indirect import IndirectStage, poisson_disk

__all__ = [
    "indirect_light_tree",
    "indirect_vpl_exact",
    "indirect_rsm_sampled",
    "reflective_shadow_map",
    "light_quadtree",
    "poisson_disk",
]


def _device_scene(scene, device):
    from ..scene import DeviceScene, Scene, load_scene

    if hasattr(scene, "dscene"):  # a FrameLoop
        ds = scene.dscene
    elif isinstance(scene, DeviceScene):
        ds = scene
    else:
        if not isinstance(scene, Scene):
            scene = load_scene(scene)
        return DeviceScene(scene, get_device(device))
    if device is not None and get_device(device) != ds.device:
        raise ValueError(f"device must be the scene's device {ds.device.alias!r}, got {device!r}")
    return ds


def _receivers(positions, normals, albedos, device):
    p = check_array("positions", positions).astype(np.float32)
    n = check_array("normals", normals).astype(np.float32)
    a = check_array("albedos", albedos, lo=0.0).astype(np.float32)
    if p.ndim < 1 or p.shape[-1] != 3:
        raise ValueError(f"positions must have shape (..., 3), got {p.shape}")
    if n.shape != p.shape:
        raise ValueError(f"normals must have the shape of positions {p.shape}, got {n.shape}")
    if a.shape == (3,):
        a = np.broadcast_to(a, p.shape)
    if a.shape != p.shape:
        raise ValueError(f"albedos must have shape (3,) or the shape of positions {p.shape}, got {a.shape}")
    for name, arr in (("positions", p), ("normals", n), ("albedos", a)):  # float64 values beyond float32
        check_array(name, arr)
    lead = p.shape[:-1]
    flat = [as_wp(x.reshape(-1, 3), wp.vec3, device, name=nm) for x, nm in
            ((p, "positions"), (n, "normals"), (a, "albedos"))]
    return lead, flat


def _run(method, scene, positions, normals, albedos, config, light_index, device, **kw) -> np.ndarray:
    ds = _device_scene(scene, device)
    lead, (p, n, a) = _receivers(positions, normals, albedos, ds.device)
    stage = IndirectStage(ds, config, light_index=light_index, method=method, **kw)
    stage.update(force=True)
    out = wp.zeros(p.shape[0], dtype=wp.vec3, device=ds.device)
    if p.shape[0]:
        stage.run_points(p, n, a, out)
    return out.numpy().reshape(*lead, 3).astype(np.float32)


def indirect_light_tree(scene, positions, normals, albedos, *, config: Optional[IndirectConfig] = None,
                        light_index: Optional[int] = None, traversal: str = "cut", device=None) -> np.ndarray:
    """Indirect radiance from the light quad-tree (the clusters a top-down descent from
    ``config.start_level`` selects, down to ``config.limit_level``), each an extended emitter of radius
    ``config.cluster_radius_scale`` x its RMS extent, refined per receiver up to ``config.refine_budget``
    splits (``refine_threshold``; see ``kernels/lighttree.py``).

    ``traversal="cut"`` extracts the view-independent cluster list once and sums it per receiver (refining
    in list order); ``"per-receiver"`` descends the tree for every receiver (the paper's scheme; refining in
    depth-first order). Without refinement both select the same clusters."""
    from ..config import check_choice

    check_choice("traversal", traversal, ("cut", "per-receiver"))
    method = "lighttree" if traversal == "cut" else "traverse"
    return _run(method, scene, positions, normals, albedos, config, light_index, device)


def indirect_vpl_exact(scene, positions, normals, albedos, *, config: Optional[IndirectConfig] = None,
                       light_index: Optional[int] = None, device=None) -> np.ndarray:
    """Indirect radiance summed over all ``rsm_size^2`` VPLs (the reference; only ``rsm_size``,
    ``d_min_rel`` and ``strength`` of ``config`` matter)."""
    return _run("exact", scene, positions, normals, albedos, config, light_index, device)


def indirect_rsm_sampled(scene, positions, normals, albedos, *, config: Optional[IndirectConfig] = None,
                         light_index: Optional[int] = None, samples: int = 1024, seed: int = 0,
                         device=None) -> np.ndarray:
    """Indirect radiance from ``samples`` VPLs picked by a fixed Poisson-disk pattern over the RSM
    (:func:`poisson_disk` with ``seed``, scaled to the texel grid); each stands for
    ``rsm_size^2 / samples`` VPLs (its flux is scaled by that)."""
    return _run("sampled", scene, positions, normals, albedos, config, light_index, device, samples=samples,
                seed=seed)


def reflective_shadow_map(scene, *, config: Optional[IndirectConfig] = None, light_index: Optional[int] = None,
                          device=None) -> dict:
    """The RSM of the light: (N, N, 3) ``flux``, ``position``, ``normal`` (facing the light), (N, N)
    ``depth`` (distance from the light), and ``solid_angle`` (steradians per texel, the same for all)."""
    ds = _device_scene(scene, device)
    stage = IndirectStage(ds, config, light_index=light_index, method="exact")
    stage.update(force=True)
    return stage.rsm_numpy()


def light_quadtree(scene, *, config: Optional[IndirectConfig] = None, light_index: Optional[int] = None,
                   device=None) -> dict:
    """The light quad-tree: ``levels`` (list, index L: dict of (2^L, 2^L[, 3]) ``flux`` (sum), ``position``,
    ``normal``, ``depth`` (flux-weighted averages), ``valid`` (uint8), ``spread2`` (flux-weighted mean squared
    distance of the node's VPLs from its position), ``radius`` (a bounding sphere's radius about it)) and
    ``cut`` (dict of (K, 3) ``flux``, ``position``, ``normal`` and (K,) ``spread2``: the view-independent
    clusters every receiver starts from)."""
    ds = _device_scene(scene, device)
    stage = IndirectStage(ds, config, light_index=light_index, method="lighttree")
    stage.update(force=True)
    return {"levels": [stage.level_numpy(lv) for lv in range(stage.leaf_level + 1)], "cut": stage.cut_numpy()}
