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
    """

    FIELDS = ("position", "normal", "depth", "albedo", "face", "hit", "velocity", "reproj_uv", "prev_dist", "moved")

    def __init__(self, width: int, height: int, device):
        from ._util import check_image_size, get_device

        width, height = check_image_size(width, height)
        device = get_device(device)
        shape = (height, width)
        self.width, self.height = width, height
        self.position = wp.zeros(shape, dtype=wp.vec3, device=device)
        self.normal = wp.zeros(shape, dtype=wp.vec3, device=device)
        self.depth = wp.zeros(shape, dtype=float, device=device)
        self.albedo = wp.zeros(shape, dtype=wp.vec3, device=device)
        self.face = wp.zeros(shape, dtype=wp.int32, device=device)
        self.hit = wp.zeros(shape, dtype=wp.uint8, device=device)
        self.velocity = wp.zeros(shape, dtype=wp.vec2, device=device)
        self.reproj_uv = wp.zeros(shape, dtype=wp.vec2, device=device)
        self.prev_dist = wp.zeros(shape, dtype=float, device=device)
        self.moved = wp.zeros(shape, dtype=wp.uint8, device=device)

    def numpy(self) -> dict:
        return {k: getattr(self, k).numpy() for k in self.FIELDS}


class Frame:
    """One rendered frame: ``image`` (H, W, 3) float32 wp.array in [0, 1], ``sampling_map`` (H, W) uint8,
    ``gbuffer``, ``stats`` (dict). The arrays belong to the FrameLoop and are overwritten by the next
    frame: call ``numpy()`` (or copy) to keep them."""

    def __init__(self, image, sampling_map, gbuffer, stats, extras=None):
        self.image = image
        self.sampling_map = sampling_map
        self.gbuffer = gbuffer
        self.stats = stats
        self.extras = extras or {}

    def numpy(self) -> np.ndarray:
        """The display image as an (H, W, 3) float32 NumPy array."""
        return self.image.numpy().reshape(self.image.shape[0], self.image.shape[1], 3)

    def to_uint8(self) -> np.ndarray:
        return (np.clip(self.numpy(), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
