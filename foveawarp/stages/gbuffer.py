"""G-buffer stage (ALGORITHMS.md A1): one primary ray per pixel against the scene BVH."""

from __future__ import annotations

import math

import warp as wp

from .. import parallel
from ..camera import Camera
from ..frame_context import FrameContextBuilder, FrameView
from ..kernels.gbuffer import gbuffer_kernel, gbuffer_rows_kernel, gbuffer_tiles_kernel
from ..kernels.gbuffer_textured import gbuffer_textured_kernel, gbuffer_textured_tiles_kernel
from ..surface import environment_map, is_textured, surface_data
from .._util import check_order_width, tile_order_threads

__all__ = ["GBufferStage"]


class GBufferStage:
    """Traces the primary rays of ``width`` x ``height`` pixels of a :class:`DeviceScene` into a
    :class:`GBuffer` (owned by the caller). ``run`` only launches; nothing is allocated per frame."""

    # CUDA: each warp traces a block of pixels this wide (kernels/order.py: 8 x 4, 16 x 2, ...); 0: the (H, W)
    # launch, 32 pixels of a row. The same values in every order
    order_width = 8

    # a textured scene's texture LOD (ShadingConfig.texture_lod: "ray_cone" or "none"); FrameLoop sets it
    texture_lod = "ray_cone"

    def __init__(self, dscene, width: int, height: int, device):
        self.dscene, self.width, self.height, self.device = dscene, width, height, device
        self._order_key = None  # (type, value) of the order_width the launch was made for
        self._set_order()
        self._contexts = None  # run's frame contexts (made on first use)

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
        and the scene's previous vertex positions. ``run_frame`` with a context of these cameras."""
        if self._contexts is None:
            self._contexts = FrameContextBuilder(self.width, self.height)
        self.run_frame(gbuffer, self._contexts.build(camera, prev_camera, (0.0, 0.0), 0, self.max_t(camera)))

    def run_frame(self, gbuffer, frame: FrameView) -> None:
        """``run`` for the frame context ``frame`` (its cameras and ray length; ``FrameContextBuilder`` of this
        stage's width and height)."""
        self._set_order()
        g, ds = gbuffer, self.dscene
        if is_textured(ds):
            self._run_textured(g, frame)
            return
        if g._face_albedo is not ds.face_albedo:
            g.bind_albedo(ds.face_albedo)
        w, h = self.width, self.height
        inputs = [ds.mesh.id, ds.indices, ds.points_prev, ds.vertex_normals, ds.face_smooth, frame.struct]
        outputs = [g.position, g.normal, g.depth, g.face, g.hit, g.reproj_uv, g.prev_dist, g.moved, self._wlog2]
        if parallel.use_row_kernels(self.device):  # CPU: a thread per row; CUDA: the recorded per-pixel launch
            parallel.launch_rows(gbuffer_kernel, gbuffer_rows_kernel, (h, w), inputs, outputs, self.device)
        else:
            self._launch(dim=self._dim, inputs=inputs, outputs=outputs, device=self.device)

    def _run_textured(self, g, frame) -> None:
        """``run_frame`` of a textured scene (kernels/gbuffer_textured.py): ``g`` stores the material per pixel
        (``GBuffer.store_surface``), the texture LOD of ``texture_lod``, the environment seen by misses."""
        ds = self.dscene
        g.store_surface()
        env, has_env = environment_map(ds)
        inputs = [ds.mesh.id, surface_data(ds, self.texture_lod), env, int(has_env), ds.points_prev, frame.struct]
        outputs = [g.position, g.normal, g.depth, g.face, g.hit, g.reproj_uv, g.prev_dist, g.moved, g._albedo,
                   g.material, g.emission]
        if self._kernel is gbuffer_tiles_kernel and not parallel.use_row_kernels(self.device):
            # warps on 8 x 4 blocks, as the untextured launch
            parallel.launch(gbuffer_textured_tiles_kernel, dim=self._dim, inputs=inputs,
                            outputs=outputs + [self._wlog2], device=self.device)
        else:
            parallel.launch(gbuffer_textured_kernel, dim=(self.height, self.width), inputs=inputs,
                            outputs=outputs + [0], device=self.device)
