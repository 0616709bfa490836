"""TemporalStage: the ping-pong history of shaded radiance (thesis A4)."""

from __future__ import annotations

import warp as wp

from ..config import TemporalConfig
from ..kernels.temporal import refresh_thin_kernel, resolve_kernel

__all__ = ["TemporalStage"]


class TemporalStage:
    """History buffers for one image size. Per frame: ``run(sample_map, cache_hit, prev_index, fresh)`` writes
    ``color`` (H, W) vec3 (linear radiance; 0 where empty) and ``filled`` (H, W) uint8 (the seeds of the
    reconstruction), then swaps the history.

    ``prev_index`` holds, per pixel, the flat index (y * W + x) of its reprojected pixel in the previous frame
    (-1 when none); ``cache_hit`` says whether that reuse passed the cache test.
    """

    def __init__(self, width: int, height: int, config: TemporalConfig, device):
        self.width, self.height, self.config, self.device = width, height, config, device
        n = width * height
        self.color = wp.zeros((height, width), dtype=wp.vec3, device=device)
        self.filled = wp.zeros((height, width), dtype=wp.uint8, device=device)
        self._hc = [wp.zeros(n, dtype=wp.vec3, device=device) for _ in range(2)]
        self._ha = [wp.zeros(n, dtype=wp.int32, device=device) for _ in range(2)]
        self._hs = [wp.zeros(n, dtype=wp.int32, device=device) for _ in range(2)]
        self._cur = 0

    def reset(self) -> None:
        """Forget all history (camera cut, resize of the content)."""
        for a in self._ha:
            a.zero_()

    @property
    def age(self):
        """(H*W,) int32: frames accumulated in the current history (0 = empty)."""
        return self._ha[self._cur]

    def run(self, sample_map, cache_hit, prev_index, fresh, *, use_history: bool = True) -> None:
        prev, cur = self._cur, 1 - self._cur
        wp.launch(
            resolve_kernel,
            dim=(self.height, self.width),
            inputs=[sample_map, cache_hit, prev_index, fresh, self._hc[prev], self._ha[prev], self._hs[prev],
                    int(self.config.max_history_frames), 1 if (use_history and self.config.enabled) else 0],
            outputs=[self.color, self.filled, self._hc[cur], self._ha[cur], self._hs[cur]],
            device=self.device,
        )
        self.swap()

    def swap(self) -> None:
        """Make the history just written the current one (``run`` does it; a replayed CUDA graph of ``run``
        does not run Python, so its caller swaps)."""
        self._cur = 1 - self._cur

    def refresh(self, sample_map, cache_hit, prev_index, frame_params, num_samples, fraction: float) -> None:
        """Thin ``sample_map`` (in place; ``num_samples`` decremented on the device) to the refresh budget of a
        static, converged view: samples with usable history are kept with probability ``fraction``; those
        without history, or unrefreshed for half of ``max_history_frames`` or more, are always kept. Call
        before ``run`` of the same frame."""
        prev = self._cur
        keep_stale = max(1, int(self.config.max_history_frames) // 2)
        wp.launch(refresh_thin_kernel, dim=(self.height, self.width),
                  inputs=[cache_hit, prev_index, self._ha[prev], self._hs[prev], frame_params, float(fraction),
                          keep_stale],
                  outputs=[sample_map, num_samples], device=self.device)
