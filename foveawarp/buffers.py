"""Per-frame state holders: the G-buffer and the temporal history (ping-pong)."""

from __future__ import annotations

import numpy as np
import warp as wp

__all__ = ["GBuffer", "Frame"]


class GBuffer:
    """Full-resolution surface attributes of the primary hits; every array is (H, W[, C]).

    position (vec3, world), normal (vec3, unit, facing the viewer; 0 on misses), depth (float, distance from
    the eye; the ray's max distance on misses), albedo (vec3), face (int32, -1 on misses), hit (uint8),
    velocity (vec2, pixels moved since the previous frame: current - previous position),
    reproj_uv (vec2, this point's pixel position in the previous frame; -1e4 when it has none),
    prev_dist (float, the same surface point's distance from the previous eye at the previous frame's object
    transforms, metres: what the previous frame's depth at ``reproj_uv`` must be when the point was visible
    there; 0 on misses), moved (uint8, 1 where the surface point moved in world space since the previous
    frame: object motion).

    The G-buffer pass stores neither ``velocity`` nor ``albedo`` (20 of its 66 bytes a pixel): the kernels that
    need them compute them from ``reproj_uv`` and ``face``, and reading these attributes computes them on the
    device, with the same values (``kernels.gbuffer.reproj_velocity``, ``surface_albedo``). ``velocity`` is
    that of a ray through the centre of the entry's pixel, or with ``cell`` > 1 (the sparse mode's coarse
    G-buffer, one entry per ``cell`` x ``cell`` cell of an ``image_size`` image) through its cell's middle
    pixel. ``albedo`` looks the face up in the table given to :meth:`bind_albedo` (a :class:`FrameLoop` binds
    its scene's); unbound, it is a plain array that the caller fills (hand-made G-buffers for the stages).
    Each read of either attribute launches its kernel into the one array it returns.

    A textured scene's G-buffer (:meth:`store_surface`, called by its G-buffer pass) stores the material of each
    hit: ``albedo`` is then a stored array, the linear base colour after the texture lookup (texture x
    ``baseColorFactor``), ``normal`` the shading normal (normal map applied), and two fields are added:
    ``material`` ((H, W) vec4h: roughness, metallic, occlusion, specular scale, half floats, 8 bytes a pixel;
    (1, 0, 1, 1) on misses) and ``emission`` (vec3 emitted radiance). ``roughness`` and ``metallic`` ((H, W)
    float32) are read from ``material`` on request; on an untextured scene's G-buffer they are 1 and 0 (its
    Lambert + Blinn-Phong shading reads neither).
    """

    FIELDS = ("position", "normal", "depth", "albedo", "face", "hit", "velocity", "reproj_uv", "prev_dist", "moved",
              "roughness", "metallic")

    def __init__(self, width: int, height: int, device, *, cell: int = 1, image_size=None):
        from ._util import check_image_size, get_device
        from .config import check_int_range

        width, height = check_image_size(width, height)
        device = get_device(device)
        cell = check_int_range("cell", cell, 1, 64)
        if image_size is None:
            image_size = (width * cell, height * cell)
        if not (isinstance(image_size, (tuple, list)) and len(image_size) == 2):
            raise ValueError(f"image_size must be a (width, height) pair, got {image_size!r}")
        iw = check_int_range("image_size[0]", image_size[0], 1, 16384)
        ih = check_int_range("image_size[1]", image_size[1], 1, 16384)
        shape = (height, width)
        self.width, self.height, self.cell, self.image_size = width, height, cell, (iw, ih)
        self.device = device
        self.position = wp.zeros(shape, dtype=wp.vec3, device=device)
        self.normal = wp.zeros(shape, dtype=wp.vec3, device=device)
        self.depth = wp.zeros(shape, dtype=float, device=device)
        self.face = wp.zeros(shape, dtype=wp.int32, device=device)
        self.hit = wp.zeros(shape, dtype=wp.uint8, device=device)
        self.reproj_uv = wp.zeros(shape, dtype=wp.vec2, device=device)
        self.prev_dist = wp.zeros(shape, dtype=float, device=device)
        self.moved = wp.zeros(shape, dtype=wp.uint8, device=device)
        self._albedo = wp.zeros(shape, dtype=wp.vec3, device=device)
        self._velocity = wp.zeros(shape, dtype=wp.vec2, device=device)
        self._face_albedo = None
        self.textured = False
        self.material = self.emission = None
        self._roughness = self._metallic = None

    def store_surface(self) -> None:
        """Make this the G-buffer of a textured scene: ``albedo`` stored (no longer looked up by face), and the
        ``material`` and ``emission`` arrays allocated (once)."""
        self._face_albedo = None
        if self.material is None:
            shape = (self.height, self.width)
            self.material = wp.zeros(shape, dtype=wp.vec4h, device=self.device)
            self.emission = wp.zeros(shape, dtype=wp.vec3, device=self.device)
        self.textured = True

    def _material_fields(self) -> tuple:
        """(roughness, metallic) (H, W) float32: split from ``material``, or 1 and 0 without one."""
        if self._roughness is None:
            shape = (self.height, self.width)
            self._roughness = wp.full(shape, 1.0, dtype=float, device=self.device)
            self._metallic = wp.zeros(shape, dtype=float, device=self.device)
        if self.textured:
            from .kernels.gbuffer_textured import split_material_kernel

            wp.launch(split_material_kernel, dim=(self.height, self.width), inputs=[self.material],
                      outputs=[self._roughness, self._metallic], device=self.device)
        return self._roughness, self._metallic

    @property
    def roughness(self) -> wp.array:
        return self._material_fields()[0]

    @property
    def metallic(self) -> wp.array:
        return self._material_fields()[1]

    def bind_albedo(self, face_albedo) -> None:
        """Make ``albedo`` the per-face table ``face_albedo`` ((F,) vec3 on this device) looked up by ``face``."""
        if not isinstance(face_albedo, wp.array) or face_albedo.dtype != wp.vec3 or face_albedo.ndim != 1:
            raise ValueError(f"face_albedo must be a 1-D wp.array of vec3, got {type(face_albedo).__name__}"
                             + (f" of {face_albedo.dtype} with {face_albedo.ndim} dims"
                                if isinstance(face_albedo, wp.array) else ""))
        if face_albedo.device != self.device:
            raise ValueError(f"face_albedo must be on {self.device}, got {face_albedo.device}")
        self._face_albedo = face_albedo
        self.textured = False

    @property
    def velocity(self) -> wp.array:
        from .kernels.gbuffer import derive_velocity_kernel

        wp.launch(derive_velocity_kernel, dim=(self.height, self.width),
                  inputs=[self.reproj_uv, self.cell, self.image_size[0], self.image_size[1]],
                  outputs=[self._velocity], device=self.device)
        return self._velocity

    @property
    def albedo(self) -> wp.array:
        if self._face_albedo is not None:
            from .kernels.gbuffer import derive_albedo_kernel

            wp.launch(derive_albedo_kernel, dim=(self.height, self.width), inputs=[self.face, self._face_albedo],
                      outputs=[self._albedo], device=self.device)
        return self._albedo

    def numpy(self) -> dict:
        """Every field as a NumPy array of its own (a copy: on the CPU device ``wp.array.numpy()`` is a view of
        the buffer the next frame overwrites)."""
        return {k: np.array(getattr(self, k).numpy(), copy=True) for k in self.FIELDS}


class Frame:
    """One rendered frame: ``image`` (H, W, 3) float32 wp.array in [0, 1], ``sampling_map`` (H, W) uint8,
    ``gbuffer``, ``stats`` (dict). The arrays belong to the FrameLoop and are overwritten by the next
    frame: ``numpy()`` returns a copy that keeps the image."""

    def __init__(self, image, sampling_map, gbuffer, stats, extras=None):
        self.image = image
        self.sampling_map = sampling_map
        self.gbuffer = gbuffer
        self.stats = stats
        self.extras = extras or {}

    def numpy(self) -> np.ndarray:
        """The display image as an (H, W, 3) float32 NumPy array of its own: a copy, which the next frame does not
        change (on the CPU device ``wp.array.numpy()`` is a view of the loop's buffer)."""
        return np.array(self.image.numpy(), dtype=np.float32, copy=True).reshape(self.image.shape[0],
                                                                                 self.image.shape[1], 3)

    def to_uint8(self) -> np.ndarray:
        return (np.clip(self.numpy(), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
