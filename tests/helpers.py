"""Independent numpy references shared by tests (no taichi_hair imports of physics)."""

import numpy as np


def rotation_matrix(axis, angle):
    """Rodrigues rotation [3, 3] about unit `axis` by `angle` radians."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def central_difference_gradient(energy, x0, nodes, h=1e-6):
    """dE/dx [S, N, 3] by central differences over the listed (strand, node) pairs."""
    grad = np.zeros_like(x0)
    for s, i in nodes:
        for k in range(3):
            for sign in (1.0, -1.0):
                x = x0.copy()
                x[s, i, k] += sign * h
                grad[s, i, k] += sign * energy(x) / (2 * h)
    return grad


def perturbed(x, scale, seed, keep_root=True):
    """x plus Gaussian noise of `scale` metres; the clamped root node stays where it is."""
    rng = np.random.default_rng(seed)
    out = x + scale * rng.standard_normal(x.shape)
    if keep_root:
        out[:, 0] = x[:, 0]
    return out
