"""G-buffer stage (ALGORITHMS.md A1): one primary ray per pixel, against the scene BVH or against the triangles
listed in its 8 x 8-pixel screen bin (``GBufferStage.primary``)."""

from __future__ import annotations

import math

import warp as wp

from .. import parallel
from ..camera import Camera
from ..kernels.binning import BIG_THREADS, BIN, bin_big_triangles_kernel, bin_triangles_kernel
from ..kernels.gbuffer import gbuffer_binned_kernel, gbuffer_kernel, gbuffer_rows_kernel, gbuffer_tiles_kernel
from .._util import check_order_width, tile_order_threads
from ..config import check_choice, check_int_range

PRIMARY_MODES = ("bvh", "bins")

__all__ = ["GBufferStage"]


class GBufferStage:
    """Traces the primary rays of ``width`` x ``height`` pixels of a :class:`DeviceScene` into a
    :class:`GBuffer` (owned by the caller). ``run`` only launches; nothing is allocated per frame."""

    # CUDA: each warp traces a block of pixels this wide (kernels/order.py: 8 x 4, 16 x 2, ...); 0: the (H, W)
    # launch, 32 pixels of a row. The same values in every order
    order_width = 8

    def __init__(self, dscene, width: int, height: int, device, *, primary: str = "bvh", bin_cap: int = 64):
        """``primary``: "bvh" (each ray walks the scene's BVH: ``wp.mesh_query_ray``) or "bins" (each triangle is
        listed in the 8 x 8-pixel screen bins it can cover, and each ray tests its bin's list: kernels/binning.py;
        the same hits but for ties between faces at the same distance). ``bin_cap`` in [1, 4096]: triangles a bin's
        list holds; the pixels of a bin with more are traced through the BVH."""
        self.dscene, self.width, self.height, self.device = dscene, width, height, device
        self.primary = check_choice("primary", primary, PRIMARY_MODES)
        self.bin_cap = check_int_range("bin_cap", bin_cap, 1, 4096)
        self._order_key = None  # (type, value) of the order_width the launch was made for
        self._set_order()
        self._bins = None
        if self.primary == "bins":
            tx, ty = -(-width // BIN), -(-height // BIN)
            nf = max(1, int(dscene.indices.shape[0]) // 3)
            self._bins = dict(
                tiles_x=tx, tiles_y=ty, num_faces=nf,
                count=wp.zeros(tx * ty, dtype=wp.int32, device=device),
                faces=wp.zeros(tx * ty * self.bin_cap, dtype=wp.int32, device=device),
                big_count=wp.zeros(1, dtype=wp.int32, device=device),
                big_faces=wp.zeros(nf, dtype=wp.int32, device=device),
                groups=256 if wp.get_device(device).is_cuda else 1,
                dim=tile_order_threads(height, width, 8),
            )

    def bin_counts(self):
        """(tiles_y, tiles_x) int32 host copy of the last frame's triangles per screen bin ("bins" mode; reads
        the device), or None in "bvh" mode. A count above ``bin_cap`` marks a bin traced through the BVH."""
        if self._bins is None:
            return None
        b = self._bins
        return b["count"].numpy().reshape(b["tiles_y"], b["tiles_x"])

    def _set_order(self) -> None:
        """The launch for ``order_width`` (checked), made again when the attribute changed: recorded once on CUDA
        (per-frame head)."""
        key = (type(self.order_width), self.order_width)
        if key == self._order_key:
            return
        wlog2 = check_order_width("GBufferStage.order_width", self.order_width)
        self._wlog2 = 0 if wlog2 is None else wlog2
        self._kernel = gbuffer_kernel if wlog2 is None else gbuffer_tiles_kernel
        self._launch = parallel.Relaunch(self._kernel, bands=True)
        self._dim = (self.height, self.width) if wlog2 is None else tile_order_threads(self.height, self.width,
                                                                                       self.order_width)
        self._order_key = key

    def max_t(self, camera: Camera) -> float:
        """Ray length that reaches past the whole scene from ``camera``'s eye (finite, >= 1)."""
        sc = self.dscene.scene
        c, e = sc.centre, camera.eye  # plain floats: this runs before every frame's G-buffer
        far = math.sqrt((e[0] - c[0]) ** 2 + (e[1] - c[1]) ** 2 + (e[2] - c[2]) ** 2) + sc.extent
        return float(min(max(2.0 * far, 1.0), 1.0e30))

    def run(self, gbuffer, camera: Camera, prev_camera: Camera) -> None:
        """Fill every stored field of ``gbuffer`` for ``camera`` (``GBuffer``: albedo and velocity follow from
        them; its albedo is bound to the scene's per-face table); reprojection fields refer to ``prev_camera``
        and the scene's previous vertex positions."""
        self._set_order()
        g, ds = gbuffer, self.dscene
        if g._face_albedo is not ds.face_albedo:
            g.bind_albedo(ds.face_albedo)
        w, h = self.width, self.height
        inputs = [ds.mesh.id, ds.indices, ds.points_prev, ds.vertex_normals, ds.face_smooth,
                  camera.params(w, h), prev_camera.params(w, h), self.max_t(camera)]
        outputs = [g.position, g.normal, g.depth, g.face, g.hit, g.reproj_uv, g.prev_dist, g.moved, self._wlog2]
        if self._bins is not None:
            self._run_bins(inputs, outputs[:-1], camera)
            return
        if parallel.use_row_kernels(self.device):  # CPU: a thread per row; CUDA: the recorded per-pixel launch
            parallel.launch_rows(gbuffer_kernel, gbuffer_rows_kernel, (h, w), inputs, outputs, self.device)
        else:
            self._launch(dim=self._dim, inputs=inputs, outputs=outputs, device=self.device)

    def _run_bins(self, inputs, outputs, camera: Camera) -> None:
        """The "bins" mode: list the triangles in their screen bins, then trace each pixel's ray against its bin."""
        b, ds, dev = self._bins, self.dscene, self.device
        cam = inputs[5]
        b["count"].zero_()
        b["big_count"].zero_()
        common = [ds.points, ds.indices, cam, b["tiles_x"], b["tiles_y"], self.bin_cap]
        # the bin counts are atomics: one thread on the CPU (Warp's CPU atomics are not shared between threads)
        wp.launch(bin_triangles_kernel, b["num_faces"], inputs=common,
                  outputs=[b["count"], b["faces"], b["big_count"], b["big_faces"]], device=dev)
        groups = b["groups"]
        wp.launch(bin_big_triangles_kernel, dim=groups * BIG_THREADS,
                  inputs=[*common, groups, b["big_count"], b["big_faces"]], outputs=[b["count"], b["faces"]],
                  device=dev)
        parallel.launch(gbuffer_binned_kernel, b["dim"], inputs=[*inputs, b["count"], b["faces"], self.bin_cap,
                                                                 b["tiles_x"]],
                        outputs=[*outputs, 3], device=dev)
