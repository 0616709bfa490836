"""G-buffer stage (ALGORITHMS.md A1): one primary ray per pixel against the scene BVH."""

from __future__ import annotations

import numpy as np
import warp as wp

from .. import parallel
from ..camera import Camera
from ..kernels.gbuffer import gbuffer_kernel

__all__ = ["GBufferStage"]


class GBufferStage:
    """Traces the primary rays of ``width`` x ``height`` pixels of a :class:`DeviceScene` into a
    :class:`GBuffer` (owned by the caller). ``run`` only launches; nothing is allocated per frame."""

    def __init__(self, dscene, width: int, height: int, device):
        self.dscene, self.width, self.height, self.device = dscene, width, height, device
        self._launch = parallel.Relaunch(gbuffer_kernel, bands=True)  # recorded once on CUDA (per-frame head)
        self._no_lab = wp.zeros((1, 1), dtype=wp.vec3, device=device)
        self._no_face_lab = wp.zeros(1, dtype=wp.vec3, device=device)

    def max_t(self, camera: Camera) -> float:
        """Ray length that reaches past the whole scene from ``camera``'s eye (finite, >= 1)."""
        sc = self.dscene.scene
        lo, hi = sc.bounds
        far = float(np.linalg.norm(np.asarray(camera.eye) - (lo + hi) * 0.5)) + sc.extent
        return float(min(max(2.0 * far, 1.0), 1.0e30))

    def run(self, gbuffer, camera: Camera, prev_camera: Camera, lab=None, write_lab: bool = True) -> None:
        """Fill every field of ``gbuffer`` for ``camera``; reprojection fields refer to ``prev_camera`` and the
        scene's previous vertex positions.

        ``lab``: an (H, W) vec3 wp.array on this device, or None. Given (and ``write_lab`` true), it also
        receives each pixel's CIE-Lab albedo, gathered from the scene's per-face table: the values
        ``saliency.lab_kernel`` computes from ``gbuffer.albedo`` (a :class:`SamplingStage` whose ``lab`` was
        written here skips its prepass: ``launch(..., lab_ready=True)``). Passing the same array every frame
        and toggling ``write_lab`` keeps the recorded launch."""
        g, ds = gbuffer, self.dscene
        w, h = self.width, self.height
        if lab is None:
            lab, lab_on, face_lab = self._no_lab, 0, self._no_face_lab
        else:
            face_lab = ds.face_lab
            ok = (isinstance(lab, wp.array) and lab.dtype == wp.vec3 and tuple(lab.shape) == (h, w)
                  and lab.device == self.device)
            if not ok:
                raise ValueError(f"lab must be a ({h}, {w}) vec3 wp.array on {self.device}, got "
                                 f"{getattr(lab, 'shape', type(lab).__name__)}")
            lab_on = 1 if write_lab else 0
        self._launch(
            dim=(h, w),
            inputs=[ds.mesh.id, ds.indices, ds.points_prev, ds.vertex_normals, ds.face_smooth, ds.face_albedo,
                    camera.params(w, h), prev_camera.params(w, h), self.max_t(camera)],
            outputs=[g.position, g.normal, g.depth, g.albedo, g.face, g.hit, g.velocity, g.reproj_uv, g.prev_dist,
                     g.moved, face_lab, lab_on, lab],
            device=self.device,
        )
