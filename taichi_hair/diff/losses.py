"""Losses for `Differentiable.value_and_grad`: each is called with node positions [K, S, N, 3]
at its `times` and returns (value, d value / d positions)."""

import numpy as np


class positions:  # noqa: N801  (a loss named as the quantity it compares, th.losses.positions)
    """Mean squared distance [m^2] between simulated and target node positions over the nodes
    where the target is finite: target [K, S, N, 3] m at `times` [K] s (NaN marks nodes to
    leave out, e.g. padding)."""

    def __init__(self, target, times):
        self.target = np.asarray(target, dtype=np.float64)
        self.times = np.atleast_1d(np.asarray(times, dtype=np.float64))
        if self.target.ndim != 4 or self.target.shape[-1] != 3 or self.target.shape[0] != len(self.times):
            raise ValueError(f"target must have shape [K, S, N, 3] with K = len(times) = {len(self.times)}, "
                             f"got {list(self.target.shape)}")
        self.mask = np.all(np.isfinite(self.target), axis=-1, keepdims=True)
        if not self.mask.any():
            raise ValueError("target must have at least one finite node position")

    def __call__(self, positions):
        diff = np.where(self.mask, np.asarray(positions, dtype=np.float64) - np.nan_to_num(self.target), 0.0)
        count = float(self.mask.sum())
        return float(np.sum(diff * diff) / count), 2.0 * diff / count
