"""Checks of dense hair's inputs (taichi_hair.hair.interpolate.Interpolator) and the seeded
per-strand variation: each raises ValueError naming the argument and what it got."""

import math

import numpy as np

from ..validation import choice, is_real

MODES = ("barycentric", "clump", "blend")


def _as_points(name, value, rows=None):
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or (rows is not None and len(arr) != rows):
        raise ValueError(f"{name} must have shape [{'M' if rows is None else rows}, 3], got {list(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got NaN or inf")
    return arr


def check_setup(guide_roots, guide_normals, dense_roots, n_nodes):
    roots = _as_points("guide_roots", guide_roots)
    if len(roots) < 3:
        raise ValueError(f"guide_roots must hold at least 3 guides, got {len(roots)}")
    normals = _as_points("guide_normals", guide_normals, len(roots))
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("guide_normals must be non-zero vectors, got a zero normal")
    dense = _as_points("dense_roots", dense_roots)
    if len(dense) < 1:
        raise ValueError("dense_roots must hold at least 1 root, got 0")
    if not (isinstance(n_nodes, (int, np.integer)) and n_nodes >= 3):
        raise ValueError(f"n_nodes must be an integer >= 3, got {n_nodes!r}")
    return roots, normals / norm, dense


def check_rest(rest_guides, rest_shapes, roots, dense, n_nodes):
    """(rest_guides [G, n, 3], rest_shapes [D, n, 3]) float64, or None when neither is given."""
    if rest_guides is None and rest_shapes is None:
        return None
    if rest_guides is None or rest_shapes is None:
        raise ValueError("rest_guides and rest_shapes must be given together (or neither), got "
                         f"only {'rest_guides' if rest_shapes is None else 'rest_shapes'}")
    out = []
    for name, value, r in (("rest_guides", rest_guides, roots), ("rest_shapes", rest_shapes, dense)):
        arr = np.asarray(value, dtype=np.float64)
        if arr.shape != (len(r), n_nodes, 3):
            raise ValueError(f"{name} must have shape [{len(r)}, {n_nodes}, 3], got {list(arr.shape)}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite, got NaN or inf")
        gap = np.linalg.norm(arr[:, 0] - r, axis=1).max()
        if gap > 1e-6:
            root_name = "guide_roots" if name == "rest_guides" else "dense_roots"
            raise ValueError(f"{name}[:, 0] must be {root_name} (within 1e-6 m), got {gap:.3g} m away")
        out.append(arr)
    return out


def check_directors(name, directors, rest_guides, dtype, shape=None):
    """Directors [G, n - 1, 3] as a contiguous array of dtype. With rest_guides [G, n, 3] (the
    construction's check) each must also stand off its rest edge: a director along its edge
    defines no frame."""
    arr = np.asarray(directors, dtype=np.float64)
    if rest_guides is not None:
        edges = np.diff(np.asarray(rest_guides, dtype=np.float64), axis=1)
        shape = edges.shape[:2]
    if arr.shape != tuple(shape) + (3,):
        raise ValueError(f"{name} must have shape [{shape[0]}, {shape[1]}, 3], got {list(arr.shape)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got NaN or inf")
    if rest_guides is not None:
        t = edges / np.maximum(np.linalg.norm(edges, axis=2, keepdims=True), 1e-300)
        normal = np.linalg.norm(arr - (arr * t).sum(2, keepdims=True) * t, axis=2)
        if normal.min() < 1e-3 * max(np.linalg.norm(arr, axis=2).max(), 1e-300):
            g, j = np.unravel_index(np.argmin(normal), normal.shape)
            raise ValueError(f"{name}[{g}, {j}] must stand off its rest edge (a director normal to "
                             f"the edge), got one along it")
    return np.ascontiguousarray(arr, dtype=dtype)


def check_head(head, margin):
    if not (is_real(margin) and math.isfinite(margin) and margin >= 0):
        raise ValueError(f"head_margin must be a finite number >= 0 m, got {margin!r}")
    if head is None or callable(head):
        return head, None
    try:
        centre, radii = head
        centre = np.asarray(centre, dtype=np.float64).reshape(3)
        radii = np.broadcast_to(np.asarray(radii, dtype=np.float64), (3,)).copy()
    except (TypeError, ValueError):
        raise ValueError(f"head must be None, a callable or (centre [3] m, radius or radii [3] m), "
                         f"got {head!r}") from None
    if not (np.all(np.isfinite(centre)) and np.all(np.isfinite(radii)) and np.all(radii > 0)):
        raise ValueError(f"head centre must be finite and its radii > 0 m, got {centre}, {radii}")
    return None, (centre, radii)


def check_rotation(rotation):
    if rotation is None:
        return np.eye(3)
    rot = np.asarray(rotation, dtype=np.float64)
    if rot.shape != (3, 3) or not np.allclose(rot.T @ rot, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise ValueError(f"head_rotation must be a 3x3 rotation matrix (orthonormal, det +1), got {rotation!r}")
    return rot


def strand_variation(n_dense, n_nodes, mode, blend, clump_radius, frizz, length_variation,
               curl_phase_variation, seed, offset_length):
    """Per-strand parameters [D, 5] (see `dense_nodes`) and frizz keys [D], all seeded."""
    choice("mode", mode, MODES)
    beta = np.asarray(blend, dtype=np.float64) if mode == "blend" else np.asarray(float(mode == "clump"))
    beta = np.full(n_dense, beta) if beta.ndim == 0 else beta
    if beta.shape != (n_dense,) or not np.all((beta >= 0) & (beta <= 1)):
        raise ValueError(f"blend must be a scalar or an array [{n_dense}] with values in [0, 1], got {blend!r}")
    for name, value, lo, hi, unit in (("frizz", frizz, 0.0, math.inf, "m"),
                                      ("length_variation", length_variation, 0.0, 1.0, ""),
                                      ("curl_phase_variation", curl_phase_variation, 0.0,
                                       (n_nodes - 1) / 2, "edges")):
        if not (is_real(value) and lo <= value <= hi and not (hi == 1.0 and value == 1.0)):
            raise ValueError(f"{name} must be a number in [{lo:g}, {hi:g}{')' if hi == 1.0 else ']'} "
                             f"{unit}, got {value!r}".replace(" ,", ","))
    if clump_radius is not None and not (is_real(clump_radius) and 0 <= clump_radius < math.inf):
        raise ValueError(f"clump_radius must be None or a finite number >= 0 m, got {clump_radius!r}")
    rng = np.random.default_rng(seed)
    u_len, u_phase, u_frizz = rng.random(n_dense), rng.random(n_dense), rng.random(n_dense)
    keys = rng.integers(0, 2**31 - 1, n_dense)
    phase = curl_phase_variation * u_phase
    step = (1.0 - length_variation * u_len) * (n_nodes - 1 - phase) / (n_nodes - 1)
    tip = np.ones(n_dense)
    if clump_radius is not None:
        tip = np.minimum(1.0, clump_radius / np.maximum(offset_length, 1e-12))
    par = np.stack([beta, phase, step, frizz * (0.5 + u_frizz), tip], axis=1)
    return par, keys
