"""IndirectStage: one-bounce indirect light from a light quad-tree over a reflective shadow map (Ki & Oh,
ALGORITHMS.md C), with the exact all-VPL sum and the Poisson-sampled RSM as baselines on the same RSM.

All buffers are allocated in ``__init__``; ``update`` (re)builds the RSM / pyramid / light cut with kernel
launches only when the light or the geometry moved, and ``run_*`` only launch the gather kernel. The build
is view independent ("buffer use" in the paper): a static light over static geometry costs nothing per
frame but the gather.

Methods (``method=``):
    "lighttree": the light cut. Validity is view independent, so the clusters a top-down descent selects
        are the same for every receiver: they are extracted ONCE per build (flags per node of the levels
        start..limit, an exclusive scan, a scatter: deterministic order) and every receiver sums that list,
        each cluster an extended emitter (``IndirectConfig.cluster_radius_scale``); with
        ``IndirectConfig.refine_budget > 0`` each receiver also splits, in list order, the clusters wider than
        ``refine_min_radius`` x d_min, seen under more than ``refine_min_ratio``, whose estimated error
        exceeds ``refine_threshold`` x its estimate (a stackless descent of that cluster's subtree), up to
        ``refine_budget`` splits (``kernels/lighttree.py``). The build also packs every node into three
        16-byte words for the gather and takes the exact bounding radius of the nodes it may split.
    "traverse": the paper's per-receiver traversal (a stackless Morton-order descent per pixel), with the same
        emitters and split rule. Without refinement it gives the same clusters and result as "lighttree" up
        to float summation order; with it, a receiver whose budget runs out may have split other clusters
        (depth-first order instead of list order).
    "exact": the sum over all N^2 VPLs (the reference).
    "sampled": RSM sampling with a fixed Poisson-disk pattern of ``samples`` texels, each standing for
        N^2 / samples VPLs.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Optional

import numpy as np
import warp as wp

from .. import parallel
from .._util import get_device
from ..config import IndirectConfig, check_array, check_choice, check_int_range, show
from ..kernels.lighttree import (
    IndirectParams,
    cut_flags_kernel,
    cut_scatter_kernel,
    gather_samples_kernel,
    indirect_full_kernel,
    indirect_list_kernel,
    indirect_points_kernel,
    pack_nodes_kernel,
    pyramid_level_kernel,
    tight_radius_kernel,
    rsm_kernel,
    rsm_textured_kernel,
)
from ..kernels.shade import LightParams
from ..kernels.surface import SurfaceData
from ..surface import is_textured, surface_data

__all__ = ["IndirectStage", "poisson_disk", "morton_index", "level_offset", "METHODS"]

METHODS = ("lighttree", "traverse", "exact", "sampled")


def level_offset(level: int) -> int:
    """First index of ``level`` in the flat pyramid arrays: (4^L - 1) / 3."""
    return ((1 << (2 * level)) - 1) // 3


def morton_index(row, col) -> np.ndarray:
    """Morton index of (row, col) (column bits on even positions), vectorized; the host twin of
    ``kernels.lighttree.morton2``."""
    row = np.asarray(row, dtype=np.int64)
    col = np.asarray(col, dtype=np.int64)
    out = np.zeros(np.broadcast(row, col).shape, dtype=np.int64)
    for b in range(16):
        out |= ((col >> b) & 1) << (2 * b)
        out |= ((row >> b) & 1) << (2 * b + 1)
    return out


@lru_cache(maxsize=32)
def _poisson_disk_cached(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    # start near the random-sequential-adsorption limit (~0.55 coverage); shrink when darts keep failing
    r = 0.72 * math.sqrt(2.0 / (math.sqrt(3.0) * n))
    pts: list = []
    max_fail = 2000
    while True:
        cell = r / math.sqrt(2.0)
        g = int(math.ceil(1.0 / cell))
        grid = -np.ones((g, g), dtype=np.int64)
        for k, (x, y) in enumerate(pts):  # re-bin the points kept so far
            grid[min(int(y / cell), g - 1), min(int(x / cell), g - 1)] = k
        fails = 0
        r2 = r * r
        while len(pts) < n and fails < max_fail:
            cand = rng.random(2)
            cx, cy = min(int(cand[0] / cell), g - 1), min(int(cand[1] / cell), g - 1)
            ok = True
            for yy in range(max(cy - 2, 0), min(cy + 3, g)):
                for xx in range(max(cx - 2, 0), min(cx + 3, g)):
                    k = grid[yy, xx]
                    if k >= 0:
                        dx = pts[k][0] - cand[0]
                        dy = pts[k][1] - cand[1]
                        if dx * dx + dy * dy < r2:
                            ok = False
                            break
                if not ok:
                    break
            if ok and grid[cy, cx] < 0:
                grid[cy, cx] = len(pts)
                pts.append((float(cand[0]), float(cand[1])))
                fails = 0
            else:
                fails += 1
        if len(pts) >= n:
            break
        r *= 0.95
    out = np.asarray(pts, dtype=np.float64)
    out.setflags(write=False)
    return out


def poisson_disk(n: int, seed: int = 0) -> np.ndarray:
    """(n, 2) points in [0, 1)^2 by dart throwing with a minimum distance (deterministic for ``seed``).

    The minimum distance starts at 0.72 x the hexagonal-packing spacing of n points and shrinks by 5% whenever
    2,000 darts in a row fail, so exactly n points are returned."""
    n = check_int_range("samples", n, 1, 1 << 22)
    seed = check_int_range("seed", seed, 0, 2**63 - 1)
    return _poisson_disk_cached(n, seed).copy()


def _light_key(light) -> tuple:
    return (light.kind, tuple(light.position), tuple(light.direction), float(light.cone_deg),
            tuple(light.intensity), float(light.penumbra))


class IndirectStage:
    """One-bounce diffuse indirect light of one light of ``dscene`` (ALGORITHMS.md C).

    Args:
        dscene: the :class:`~foveawarp.scene.DeviceScene` (its ``mesh``, materials and ``lights``).
        config: an :class:`~foveawarp.config.IndirectConfig` (defaults if None).
        device: must be ``dscene``'s device (None: that device).
        max_receivers: capacity of the stage's own receiver buffers (``receiver_pos``, ``receiver_normal``,
            ``receiver_albedo``, ``receiver_out``) used by :meth:`run_points`; None allocates none.
        light_index: which light of ``dscene.scene.lights`` makes the RSM; None: the first spot light, else
            light 0. A point light uses the whole sphere of directions. The light is read from the host
            ``Light`` (a replaced Light is picked up by the next ``update``; a CUDA graph holding ``build``
            must then be recaptured, as the light is a kernel argument).
        method: "lighttree" (default), "traverse", "exact" or "sampled" (see the module docstring).
        samples: Poisson-disk samples of the "sampled" method, in [1, rsm_size^2].
        seed: seed of the Poisson-disk pattern.

    Attributes after :meth:`update`: ``rebuilt`` (bool), ``skipped`` (dict stage -> reason), ``builds``
    (number of builds so far).
    """

    def __init__(self, dscene, config: Optional[IndirectConfig] = None, device=None,
                 max_receivers: Optional[int] = None, *, light_index: Optional[int] = None,
                 method: str = "lighttree", samples: int = 1024, seed: int = 0):
        if config is None:
            config = IndirectConfig()
        if not isinstance(config, IndirectConfig):
            raise ValueError(f"config must be an IndirectConfig, got {show(config)} ({type(config).__name__})")
        from ..scene import DeviceScene

        if not isinstance(dscene, DeviceScene):
            raise ValueError(f"dscene must be a foveawarp.DeviceScene, got {show(dscene)} ({type(dscene).__name__})")
        self.config = config
        self.dscene = dscene
        self.device = get_device(device if device is not None else dscene.device)
        if self.device != dscene.device:
            raise ValueError(f"device must be the scene's device {dscene.device.alias!r}, got {self.device.alias!r}")
        self._no_albedo = wp.zeros((1, 1), dtype=wp.vec3, device=self.device)  # the gathers' untextured placeholder
        # a scene with materials: the RSM's VPLs take the hit's textured base colour (kernels/surface.py)
        self._surface = surface_data(dscene) if is_textured(dscene) else None
        self._no_sd = SurfaceData()  # not read by the untextured trace
        self.method = check_choice("method", method, METHODS)
        lights = list(dscene.scene.lights)
        if light_index is None:
            spots = [i for i, l in enumerate(lights) if l.kind == "spot"]
            light_index = spots[0] if spots else 0
        n_lights = len(lights)
        if n_lights:
            light_index = check_int_range("light_index", light_index, 0, n_lights - 1)
        self.light_index = int(light_index)
        self.enabled = n_lights > 0

        n = config.rsm_size
        self.rsm_size = n
        self.leaf_level = int(round(math.log2(n)))
        self.start_level = int(config.start_level)
        self.limit_level = int(config.limit_level)
        if method == "sampled":
            self.samples = check_int_range("samples", samples, 1, n * n)
        else:
            self.samples = check_int_range("samples", samples, 1, None)
        self.seed = check_int_range("seed", seed, 0, 2**63 - 1)

        dev = self.device
        total = level_offset(self.leaf_level + 1)
        self.tree_flux = wp.zeros(total, dtype=wp.vec3, device=dev)
        self.tree_pos = wp.zeros(total, dtype=wp.vec3, device=dev)
        self.tree_normal = wp.zeros(total, dtype=wp.vec3, device=dev)
        self.tree_depth = wp.zeros(total, dtype=float, device=dev)
        self.tree_valid = wp.zeros(total, dtype=wp.uint8, device=dev)
        self.tree_spread2 = wp.zeros(total, dtype=float, device=dev)
        self.tree_radius = wp.zeros(total, dtype=float, device=dev)
        self._levels = []  # per level: views (flux, pos, normal, depth, valid, spread2, radius)
        for lv in range(self.leaf_level + 1):
            a, b = level_offset(lv), level_offset(lv + 1)
            self._levels.append(tuple(arr[a:b] for arr in (self.tree_flux, self.tree_pos, self.tree_normal,
                                                             self.tree_depth, self.tree_valid, self.tree_spread2,
                                                             self.tree_radius)))
        leaf = self._levels[self.leaf_level]
        self._tight_radius = self.tree_radius[level_offset(min(self.start_level, self.leaf_level)):
                                              level_offset(self.leaf_level)]

        self.list_count = wp.zeros(1, dtype=wp.int32, device=dev)
        self.list_node = wp.zeros(1, dtype=wp.int32, device=dev)
        tree = method in ("lighttree", "traverse")
        n_nodes = total if tree else 1
        self.node_a = wp.zeros(n_nodes, dtype=wp.vec4, device=dev)  # packed nodes for the gather
        self.node_b = wp.zeros(n_nodes, dtype=wp.vec4, device=dev)
        self.node_c = wp.zeros(n_nodes, dtype=wp.vec4, device=dev)
        self.cut_a = wp.zeros(1, dtype=wp.vec4, device=dev)
        self.cut_b = wp.zeros(1, dtype=wp.vec4, device=dev)
        self.cut_c = wp.zeros(1, dtype=wp.vec4, device=dev)
        if method == "lighttree":
            cap = 1 << (2 * self.limit_level)  # a cut is a partition of the leaves into nodes of level <= limit
            n_flags = level_offset(self.limit_level + 1) - level_offset(self.start_level)
            self._flags = wp.zeros(n_flags, dtype=wp.int32, device=dev)
            self._slots = wp.zeros(n_flags, dtype=wp.int32, device=dev)
            self.list_flux = wp.zeros(cap, dtype=wp.vec3, device=dev)
            self.list_pos = wp.zeros(cap, dtype=wp.vec3, device=dev)
            self.list_normal = wp.zeros(cap, dtype=wp.vec3, device=dev)
            self.list_spread2 = wp.zeros(cap, dtype=float, device=dev)
            self.list_node = wp.zeros(cap, dtype=wp.int32, device=dev)
            self.cut_a = wp.zeros(cap, dtype=wp.vec4, device=dev)
            self.cut_b = wp.zeros(cap, dtype=wp.vec4, device=dev)
            self.cut_c = wp.zeros(cap, dtype=wp.vec4, device=dev)
        elif method == "exact":
            self.list_flux, self.list_pos, self.list_normal, self.list_spread2 = leaf[0], leaf[1], leaf[2], leaf[5]
            self.list_count.fill_(n * n)
        elif method == "sampled":
            pts = poisson_disk(self.samples, self.seed)
            col = np.minimum((pts[:, 0] * n).astype(np.int64), n - 1)
            row = np.minimum((pts[:, 1] * n).astype(np.int64), n - 1)
            self.sample_texels = np.stack([row, col], axis=1)
            self._texels = wp.array(morton_index(row, col).astype(np.int32), dtype=wp.int32, device=dev)
            self.sample_weight = float(n * n) / float(self.samples)
            self.list_flux = wp.zeros(self.samples, dtype=wp.vec3, device=dev)
            self.list_pos = wp.zeros(self.samples, dtype=wp.vec3, device=dev)
            self.list_normal = wp.zeros(self.samples, dtype=wp.vec3, device=dev)
            self.list_spread2 = wp.zeros(self.samples, dtype=float, device=dev)
            self.list_count.fill_(self.samples)
        else:  # traverse: the list is unused; give the struct valid (tiny) arrays
            self.list_flux = wp.zeros(1, dtype=wp.vec3, device=dev)
            self.list_pos = wp.zeros(1, dtype=wp.vec3, device=dev)
            self.list_normal = wp.zeros(1, dtype=wp.vec3, device=dev)
            self.list_spread2 = wp.zeros(1, dtype=float, device=dev)

        ext = float(dscene.extent)
        self.depth_tol = float(config.depth_threshold) * ext
        d_min = float(config.d_min_rel) * ext
        ip = IndirectParams()
        ip.tree_flux, ip.tree_pos, ip.tree_normal, ip.tree_valid = (self.tree_flux, self.tree_pos,
                                                                   self.tree_normal, self.tree_valid)
        ip.list_flux, ip.list_pos, ip.list_normal = self.list_flux, self.list_pos, self.list_normal
        ip.tree_spread2, ip.tree_radius = self.tree_spread2, self.tree_radius
        ip.list_spread2, ip.list_node = self.list_spread2, self.list_node
        ip.node_a, ip.node_b, ip.node_c = self.node_a, self.node_b, self.node_c
        ip.cut_a, ip.cut_b, ip.cut_c = self.cut_a, self.cut_b, self.cut_c
        ip.list_count = self.list_count
        ip.use_tree = 1 if method == "traverse" else 0
        ip.start_level = self.start_level
        ip.limit_level = self.limit_level
        ip.leaf_level = self.leaf_level
        ip.extended = 1 if tree else 0
        ip.radius_scale2 = float(config.cluster_radius_scale) ** 2 if tree else 0.0
        ip.refine_threshold = float(config.refine_threshold)
        ip.refine_budget = int(config.refine_budget) if tree else 0
        ip.refine_ratio2 = float(config.refine_min_ratio) ** 2
        ip.refine_min_radius = float(config.refine_min_radius) * d_min
        # a receiver whose estimate is below 1e-6 of the total flux per extent^2 splits as if it were that
        ip.floor_per_flux = 1.0e-6 / max(ext * ext, 1.0e-30)
        ip.d_min2 = max(d_min * d_min, 1.0e-30)
        ip.scale = float(config.strength) / (math.pi * math.pi)
        ip.enabled = 1 if self.enabled else 0
        self.params = ip
        # RSM rays start at the light and may go anywhere in the scene's box
        self._max_t = 1.0e20

        if max_receivers is not None:
            m = check_int_range("max_receivers", max_receivers, 1, 1 << 30)
            self.receiver_pos = wp.zeros(m, dtype=wp.vec3, device=dev)
            self.receiver_normal = wp.zeros(m, dtype=wp.vec3, device=dev)
            self.receiver_albedo = wp.zeros(m, dtype=wp.vec3, device=dev)
            self.receiver_out = wp.zeros(m, dtype=wp.vec3, device=dev)
        self.max_receivers = max_receivers

        self._built_light = None
        self._built_time = None
        self._lp, self._lp_key = None, None
        self.builds = 0
        self.rebuilt = False
        self.skipped: dict = {}

    # -- build --------------------------------------------------------------------------------------------
    def _light_params(self) -> LightParams:
        """The light as a kernel argument, from the host Light (rebuilt only when the Light changed; the same
        conversion as DeviceScene)."""
        l = self.light
        key = _light_key(l)
        if self._lp_key != key:
            from ..scene import light_params

            self._lp, self._lp_key = light_params(l), key
        return self._lp

    @property
    def light(self):
        """The host :class:`~foveawarp.scene.Light` that makes the RSM (None when the scene has none)."""
        return self.dscene.scene.lights[self.light_index] if self.enabled else None

    def update(self, force: bool = False) -> bool:
        """Rebuild the RSM (and pyramid, cut or sample list) when forced, on first use, when the scene's
        geometry moved in its last ``set_time`` (``dscene.moved_last_update``, once per scene time: a second
        call at the same time does not rebuild again) or when the host light changed.
        Sets ``rebuilt``, ``skipped`` and ``rebuild_reason``; returns ``rebuilt``."""
        if not self.enabled:
            self.rebuilt = False
            self.skipped = {"indirect": "scene has no lights"}
            return False
        key = _light_key(self.light)
        reason = None
        if force:
            reason = "forced"
        elif self._built_light is None:
            reason = "first use"
        elif self.dscene.moved_last_update and self.dscene.time != self._built_time:
            reason = "geometry moved"
        elif key != self._built_light:
            reason = "light changed"
        if reason is None:
            self.rebuilt = False
            self.skipped = {"indirect_build": "light and geometry static"}
            return False
        self.build()
        self._built_light = key
        self._built_time = self.dscene.time
        self.rebuilt = True
        self.rebuild_reason = reason
        self.skipped = {}
        return True

    def build(self) -> None:
        """Launch the RSM trace and everything the method needs (no host synchronization)."""
        self.trace_rsm()
        self.build_tree()

    def trace_rsm(self) -> None:
        """Trace the RSM of the light into the leaf level."""
        ds, n = self.dscene, self.rsm_size
        kernel, sd = (rsm_textured_kernel, self._surface) if self._surface is not None else (rsm_kernel, self._no_sd)
        parallel.launch(kernel, dim=(n, n),
                        inputs=[ds.mesh.id, ds.indices, ds.vertex_normals, ds.face_smooth, ds.face_albedo, sd,
                                self._light_params(), n, self._max_t],
                        outputs=list(self._levels[self.leaf_level]), device=self.device)

    def load_rsm(self, flux, position, normal, depth) -> None:
        """Replace the leaf level by a given RSM ((N, N, 3) flux, position, normal; (N, N) depth, row-major
        images; e.g. a rasterized one) and mark it built; call :meth:`build_tree` next. Host copies: not
        for per-frame use."""
        n = self.rsm_size
        rows, cols = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        order = np.argsort(morton_index(rows, cols).reshape(-1))  # Morton slot -> flat image index
        leaf = self._levels[self.leaf_level]
        for name, arr, dst, ch in (("flux", flux, leaf[0], 3), ("position", position, leaf[1], 3),
                                   ("normal", normal, leaf[2], 3), ("depth", depth, leaf[3], 1)):
            a = check_array(name, arr, lo=0.0 if name == "flux" else None)
            want = (n, n, 3) if ch == 3 else (n, n)
            if a.shape != want:
                raise ValueError(f"{name} must have shape {want}, got {a.shape}")
            a = a.astype(np.float32)
            dst.assign(np.ascontiguousarray(a.reshape(n * n, -1)[order].reshape((n * n, 3) if ch == 3 else -1)))
        leaf[4].fill_(1)
        leaf[5].zero_()
        leaf[6].zero_()
        self._built_light = _light_key(self.light) if self.enabled else ("loaded",)

    def build_tree(self) -> None:
        """From the leaf level: the pyramid, and the light cut ("lighttree") or sample list ("sampled")."""
        dev = self.device
        leaf = self._levels[self.leaf_level]
        if self.method in ("lighttree", "traverse"):
            for lv in range(self.leaf_level - 1, -1, -1):
                wp.launch(pyramid_level_kernel, dim=1 << (2 * lv),
                          inputs=[*self._levels[lv + 1], self.depth_tol, float(self.config.normal_threshold)],
                          outputs=list(self._levels[lv]), device=dev)
            self._tight_radius.zero_()  # the levels start .. leaf - 1, re-taken exactly from the leaves
            wp.launch(tight_radius_kernel, dim=self.rsm_size * self.rsm_size,
                      inputs=[self.tree_flux, self.tree_pos, min(self.start_level, self.leaf_level), self.leaf_level],
                      outputs=[self.tree_radius], device=dev)
            wp.launch(pack_nodes_kernel, dim=self.node_a.shape[0],
                      inputs=[self.tree_flux, self.tree_pos, self.tree_normal, self.tree_valid, self.tree_spread2,
                              self.tree_radius, self.params.radius_scale2],
                      outputs=[self.node_a, self.node_b, self.node_c], device=dev)
        if self.method == "lighttree":
            nf = self._flags.shape[0]
            wp.launch(cut_flags_kernel, dim=nf, inputs=[self.tree_valid, self.tree_flux, self.start_level,
                                                        self.limit_level], outputs=[self._flags], device=dev)
            wp.utils.array_scan(self._flags, self._slots, inclusive=False)
            wp.launch(cut_scatter_kernel, dim=nf,
                      inputs=[self._flags, self._slots, level_offset(self.start_level), self.tree_flux,
                              self.tree_pos, self.tree_normal, self.tree_spread2, self.node_a, self.node_b,
                              self.node_c],
                      outputs=[self.list_flux, self.list_pos, self.list_normal, self.list_spread2, self.list_node,
                               self.cut_a, self.cut_b, self.cut_c, self.list_count], device=dev)
        elif self.method == "sampled":
            wp.launch(gather_samples_kernel, dim=self.samples,
                      inputs=[self._texels, self.sample_weight, leaf[0], leaf[1], leaf[2]],
                      outputs=[self.list_flux, self.list_pos, self.list_normal], device=dev)
        self.builds += 1

    # -- gather -------------------------------------------------------------------------------------------
    def _check(self, name, arr, dtype, shape=None, ndim=None):
        """Host-side attribute checks only (no sync): a wp.array of ``dtype`` on the stage's device."""
        ok = (isinstance(arr, wp.array) and arr.dtype == dtype and arr.device == self.device
              and (shape is None or tuple(arr.shape) == tuple(shape)) and (ndim is None or arr.ndim == ndim))
        if not ok:
            want = f"{shape if shape is not None else f'{ndim}-D'} {getattr(dtype, '__name__', dtype)} wp.array"
            raise ValueError(f"{name} must be a {want} on {self.device}, got {type(arr).__name__} "
                             f"{getattr(arr, 'dtype', None)} {tuple(getattr(arr, 'shape', ()))} on "
                             f"{getattr(arr, 'device', None)}")
        return arr

    def _check_gbuffer(self, gbuffer):
        from ..buffers import GBuffer

        if not isinstance(gbuffer, GBuffer):
            raise ValueError(f"gbuffer must be a foveawarp.GBuffer, got {show(gbuffer)} ({type(gbuffer).__name__})")
        if gbuffer.position.device != self.device:
            raise ValueError(f"gbuffer must be on {self.device}, got {gbuffer.position.device}")
        return gbuffer

    def _receiver_args(self, g) -> list:
        """(textured, per-pixel albedo) of the gather kernels: a textured G-buffer's stored base colour, else a
        placeholder (the face table is read)."""
        return [1, g.albedo] if g.textured else [0, self._no_albedo]

    def run_full(self, gbuffer, radiance) -> None:
        """``radiance[y, x] += indirect`` at every hit pixel of ``gbuffer`` (reads position, normal, face, hit;
        the receiver's albedo is a textured G-buffer's per-pixel base colour, else the scene's per face)."""
        g = self._check_gbuffer(gbuffer)
        self._check("radiance", radiance, wp.vec3, shape=tuple(g.position.shape))
        if not self.enabled:
            return
        parallel.launch(indirect_full_kernel, dim=(g.position.shape[0], g.position.shape[1]),
                        inputs=[self.params, g.position, g.normal, self.dscene.face_albedo, g.face, g.hit,
                                *self._receiver_args(g)],
                        outputs=[radiance], device=self.device)

    def run_list(self, gbuffer, work, count, radiance, width: int) -> None:
        """``radiance += indirect`` at the flat pixel indices ``work[0:count[0]]`` (y * width + x; count stays
        on the device), like ``kernels.shade.shade_list_kernel``."""
        g = self._check_gbuffer(gbuffer)
        self._check("work", work, wp.int32, ndim=1)
        self._check("count", count, wp.int32, shape=(1,))
        self._check("radiance", radiance, wp.vec3, shape=tuple(g.position.shape))
        width = check_int_range("width", width, 1, 16384)
        if width != g.position.shape[1]:
            raise ValueError(f"width must be the G-buffer width {g.position.shape[1]}, got {width}")
        if not self.enabled:
            return
        parallel.launch(indirect_list_kernel, dim=work.shape[0],
                        inputs=[self.params, work, count, int(width), g.position, g.normal, self.dscene.face_albedo,
                                g.face, g.hit, *self._receiver_args(g)],
                        outputs=[radiance], device=self.device, count=count)

    def run_points(self, pos=None, normal=None, albedo=None, out=None) -> None:
        """``out[i] = indirect`` radiance at receivers (1-D vec3 arrays; default: the stage's receiver
        buffers, which need ``max_receivers``). Overwrites ``out``."""
        if pos is None:
            if self.max_receivers is None:
                raise ValueError("run_points without arrays needs the stage built with max_receivers")
            pos, normal, albedo, out = (self.receiver_pos, self.receiver_normal, self.receiver_albedo,
                                        self.receiver_out)
        self._check("pos", pos, wp.vec3, ndim=1)
        n = (pos.shape[0],)
        self._check("normal", normal, wp.vec3, shape=n)
        self._check("albedo", albedo, wp.vec3, shape=n)
        self._check("out", out, wp.vec3, shape=n)
        if not self.enabled:
            out.zero_()
            return
        parallel.launch(indirect_points_kernel, dim=pos.shape[0], inputs=[self.params, pos, normal, albedo],
                        outputs=[out], device=self.device)

    # -- inspection (host reads; not for per-frame use) -----------------------------------------------------
    def cluster_count(self) -> int:
        """Number of VPLs / clusters a receiver sums (the cut size for "lighttree" and "traverse")."""
        if self.method == "traverse":
            return int(self._cut_from_flags().sum())
        return int(self.list_count.numpy()[0])

    def _cut_from_flags(self) -> np.ndarray:
        valid = self.tree_valid.numpy()
        w = self.tree_flux.numpy().sum(axis=1)
        flags = []
        for lv in range(self.start_level, self.limit_level + 1):
            a, b = level_offset(lv), level_offset(lv + 1)
            f = (w[a:b] > 0) & ((valid[a:b] != 0) | (lv == self.limit_level))
            if lv > self.start_level:
                pa = level_offset(lv - 1)
                f &= valid[pa + (np.arange(b - a) >> 2)] == 0
            flags.append(f)
        return np.concatenate(flags)

    def level_numpy(self, level: int) -> dict:
        """Level ``level`` of the pyramid as (2^L, 2^L[, 3]) images (row, column order)."""
        level = check_int_range("level", level, 0, self.leaf_level)
        side = 1 << level
        rows, cols = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
        k = morton_index(rows, cols)
        names = ("flux", "position", "normal", "depth", "valid", "spread2", "radius")
        return {nm: arr.numpy()[k] for nm, arr in zip(names, self._levels[level])}

    def rsm_numpy(self) -> dict:
        """The RSM as (N, N[, 3]) images: flux, position, normal, depth; and the texel ``solid_angle``."""
        d = self.level_numpy(self.leaf_level)
        for k in ("valid", "spread2", "radius"):
            d.pop(k)
        l = self.light
        cos_outer = -1.0 if l is None or l.kind == "point" else math.cos(math.radians(min(l.cone_deg, 180.0)))
        d["solid_angle"] = 2.0 * math.pi * (1.0 - cos_outer) / float(self.rsm_size ** 2)
        return d

    def cut_numpy(self) -> dict:
        """The VPL list a receiver sums ("lighttree": the light cut; "exact": all VPLs; "sampled": the
        weighted samples) as (K, 3) arrays flux, position, normal, and (K,) ``spread2`` (the clusters'
        flux-weighted mean squared extent; 0 for single VPLs)."""
        if self.method == "traverse":
            raise ValueError("method 'traverse' keeps no list; use method 'lighttree' for the cut")
        k = int(self.list_count.numpy()[0])
        return {"flux": self.list_flux.numpy()[:k], "position": self.list_pos.numpy()[:k],
                "normal": self.list_normal.numpy()[:k], "spread2": self.list_spread2.numpy()[:k]}
