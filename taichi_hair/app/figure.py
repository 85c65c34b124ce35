"""The figure as the frame writer draws it: the body mesh's vertices, faces and normals, shaded
so that the places where separately built surfaces meet do not show as edges of light.

numpy only: `runner.FrameWriter` hands the result to `render.Mesh`. The colliders are not
touched: these are the drawn normals only.
"""

import numpy as np

from ..world.headmesh import smoothstep

# [m] how far outside a capsule (its radius exceeded by this much) the body's normals have
# turned back from the capsule's to their own: on the default bust 2 cm of neck below the
# seam at the front, 1.3 cm at the sides (the neck flares faster there)
SEAM_BAND = 0.015


def hard_base(vertices, faces) -> dict:
    """A body mesh (vertices [V, 3] m, faces [F, 3]) as render.Mesh arguments with its flat
    base (the faces lying in the plane of its lowest vertices) on vertices of its own: smooth
    normals would average the base with the sides, and the sides' lowest ring, shaded as if
    it faced half down, would show as a band unlike the surface above it."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces)
    z = v[:, 2]
    on_base = np.abs(z - z.min()) < 1e-9 * max(1.0, float(np.ptp(z)))
    base = on_base[f].all(axis=1)
    used = np.unique(f[base])
    copy = np.full(len(v), -1)
    copy[used] = len(v) + np.arange(len(used))
    f = f.copy()
    f[base] = copy[f[base]]
    return dict(vertices=np.vstack([v, v[used]]), faces=f)


def capsule_normals(points, capsule) -> tuple:
    """(the capsule's outward unit normal at the nearest point of its surface (K, 3); zero for
    a point on its axis, which has none, each point's distance outside it [m] (K,), negative
    inside) for points [K, 3] m and a capsule (p0 [3], p1 [3], radius) [m]."""
    p0, p1, radius = np.asarray(capsule[0], float), np.asarray(capsule[1], float), float(capsule[2])
    axis = p1 - p0
    t = np.clip((points - p0) @ axis / max(float(axis @ axis), 1e-300), 0.0, 1.0)
    off = points - (p0 + t[:, None] * axis)
    d = np.linalg.norm(off, axis=1)
    return np.where((d > 1e-12)[:, None], off / np.maximum(d, 1e-12)[:, None], 0.0), d - radius


def seam_normals(vertices, normals, capsules, band: float = SEAM_BAND) -> np.ndarray:
    """A body's vertex normals (V, 3) blended, where it meets capsules drawn on it (the neck
    capsule on the bust), towards the capsule's own normal: all the way at the seam (and inside
    the capsule, hidden), back to the body's own by `band` [m] outside it (a smoothstep).
    The two surfaces meet at an angle (the neck widens into the shoulders below the capsule),
    and shaded each with its own normals the seam is a step in brightness; this turns it into
    a gradient over the band. vertices [V, 3] m, normals [V, 3] unit; returns unit normals
    (zero where `normals` are: vertices no face uses)."""
    n = np.array(normals, dtype=np.float64)
    v = np.asarray(vertices, dtype=np.float64)
    for capsule in capsules:
        towards, outside = capsule_normals(v, capsule)
        w = np.where(towards.any(axis=1), 1.0 - smoothstep(0.0, band, outside), 0.0)[:, None]
        n = w * towards + (1.0 - w) * n
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
