"""A default head the project builds itself, and OBJ triangle-mesh I/O.

Head-local coordinates, metres: origin at the centre of the cranium ellipsoid, +z up, +x toward
the head's left ear (viewer's right when facing it), the face looks along +y (so "back", the
default comb direction of `taichi_hair.hair.roots.scalp_groom`, is -y). The neck hangs below the
origin toward -z; a neck pivot for `taichi_hair.world.motion` sits near (0, -0.01, -0.10).

`default_head(resolution)` deforms a subdivided icosahedron: every unit direction u maps to a
point on an ellipsoid (semi-axes 0.08 x 0.10 x 0.115 m: 0.16 m wide, 0.20 m deep, 0.23 m tall),
then smooth bumps and tapers (jaw, chin, nose, brows, eye sockets, lips, ears) move it. Each
deformation is small against the local radius and acts along the surface's outward side, so
the map from the sphere stays one-to-one: the mesh is closed, 2-manifold and outward-oriented
by construction (the tests check all three).
"""

from dataclasses import dataclass
import math
import os

import numpy as np

SEMI_AXES = (0.08, 0.10, 0.115)  # [m] cranium ellipsoid (x: half width, y: half depth, z: half height)
NECK_CAPSULE = ((0.0, -0.015, -0.05), (0.0, -0.03, -0.22), 0.055)  # [m] (p0, p1, radius), turns with the head


@dataclass(frozen=True, kw_only=True, eq=False)
class HeadModel:
    """A closed triangle mesh with a marked scalp and capsule colliders (neck, shoulders).

    vertices: float64 [V, 3], m, head-local (+z up, face along +y).
    faces: int32 [F, 3], counter-clockwise seen from outside (right-hand normals point out).
    scalp: bool [V], True where hair grows.
    capsules: tuple of (p0 [3] m, p1 [3] m, radius m): segments swept by a sphere.
    """

    vertices: np.ndarray
    faces: np.ndarray
    scalp: np.ndarray
    capsules: tuple = ()

    def __post_init__(self):
        v = np.array(self.vertices, dtype=np.float64)
        f = np.array(self.faces)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or not np.all(np.isfinite(v)):
            raise ValueError(f"vertices must be a finite [V >= 4, 3] array of metres, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4 or not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"faces must be an integer [F >= 4, 3] array, got shape {f.shape} dtype {f.dtype}")
        if f.min() < 0 or f.max() >= len(v):
            raise ValueError(f"faces must index vertices in [0, {len(v) - 1}], got range [{f.min()}, {f.max()}]")
        s = np.array(self.scalp)
        if s.shape != (len(v),) or s.dtype != np.bool_:
            raise ValueError(f"scalp must be a bool array of shape [{len(v)}], got {s.dtype} {s.shape}")
        capsules = tuple(_capsule(i, c) for i, c in enumerate(self.capsules))
        for name, value in (("vertices", v), ("faces", f.astype(np.int32)), ("scalp", s)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "capsules", capsules)

    def face_normals(self) -> np.ndarray:
        """Unit outward normals [F, 3] of the faces."""
        n = _face_cross(self.vertices, self.faces)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def face_areas(self) -> np.ndarray:
        """Triangle areas [F], m^2."""
        return 0.5 * np.linalg.norm(_face_cross(self.vertices, self.faces), axis=1)

    def vertex_normals(self) -> np.ndarray:
        """Unit outward vertex normals [V, 3]: area-weighted sums of the incident face normals."""
        n = np.zeros_like(self.vertices)
        cross = _face_cross(self.vertices, self.faces)  # |cross| = 2 area: area-weighted
        for k in range(3):
            np.add.at(n, self.faces[:, k], cross)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def scalp_faces(self, min_vertices: int = 2) -> np.ndarray:
        """Indices [Fs] of faces with at least `min_vertices` (1..3) scalp vertices."""
        if min_vertices not in (1, 2, 3):
            raise ValueError(f"min_vertices must be 1, 2 or 3, got {min_vertices!r}")
        return np.flatnonzero(self.scalp[self.faces].sum(axis=1) >= min_vertices)

    def volume(self) -> float:
        """Enclosed volume [m^3] by the divergence theorem (positive for outward faces)."""
        return mesh_volume(self.vertices, self.faces)


def _capsule(i, c):
    try:
        p0, p1, r = c
        p0, p1 = (np.asarray(p, dtype=np.float64) for p in (p0, p1))
        r = float(r)
    except (TypeError, ValueError):
        raise ValueError(f"capsules[{i}] must be (p0 [3] m, p1 [3] m, radius m), got {c!r}") from None
    if p0.shape != (3,) or p1.shape != (3,) or not (np.all(np.isfinite(p0)) and np.all(np.isfinite(p1))):
        raise ValueError(f"capsules[{i}]: p0 and p1 must be finite 3-vectors [m], got {c!r}")
    if not (math.isfinite(r) and r > 0):
        raise ValueError(f"capsules[{i}]: radius must be a finite number > 0 m, got {r!r}")
    return tuple(float(x) for x in p0), tuple(float(x) for x in p1), r


def _face_cross(vertices, faces):
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return np.cross(b - a, c - a)


def mesh_volume(vertices, faces) -> float:
    """Signed enclosed volume [m^3] of a closed mesh: sum over faces of a . (b x c) / 6."""
    v = np.asarray(vertices, dtype=np.float64)
    a, b, c = (v[faces[:, k]] for k in range(3))
    return float(np.einsum("ij,ij->", a, np.cross(b, c)) / 6.0)


# ---- the default head --------------------------------------------------------------------------
def icosphere(subdivisions: int):
    """Unit icosphere: vertices [V, 3] on the unit sphere, faces int32 [F, 3] outward CCW;
    V = 10 4^n + 2, F = 20 4^n for n subdivisions."""
    g = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array([[-1, g, 0], [1, g, 0], [-1, -g, 0], [1, -g, 0], [0, -1, g], [0, 1, g],
                  [0, -1, -g], [0, 1, -g], [g, 0, -1], [g, 0, 1], [-g, 0, -1], [-g, 0, 1]], dtype=np.float64)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], dtype=np.int64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdivisions):
        v, f = _subdivide(v, f)
    return v, f.astype(np.int32)


def _subdivide(v, f):
    """Split every triangle into four at its edge midpoints (shared midpoints made once)."""
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    unique, inverse = np.unique(edges, axis=0, return_inverse=True)
    mid = v[unique[:, 0]] + v[unique[:, 1]]
    v = np.vstack([v, mid / np.linalg.norm(mid, axis=1, keepdims=True)])
    m = len(v) - len(unique) + inverse.reshape(3, len(f)).T  # midpoints of edges ab, bc, ca
    a, b, c, ab, bc, ca = f[:, 0], f[:, 1], f[:, 2], m[:, 0], m[:, 1], m[:, 2]
    f = np.concatenate([np.stack(t, axis=1) for t in ((a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca))])
    return v, f


def _bump(x, y, z, centre, sigma):
    """Gaussian exp(-sum ((coord - centre) / sigma)^2) [1] over the (x, y, z) arrays."""
    return np.exp(-sum(((q - c) / s) ** 2 for q, c, s in zip((x, y, z), centre, sigma) if s is not None))


def smoothstep(edge0, edge1, x):
    """0 below edge0, 1 beyond edge1, Hermite 3u^2 - 2u^3 between (edge1 < edge0 runs downward)."""
    u = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def head_surface(u: np.ndarray) -> np.ndarray:
    """Head surface point [m] for each unit direction u [V, 3] (see the module docstring)."""
    a, b, c = SEMI_AXES
    x, y, z = a * u[:, 0], b * u[:, 1], c * u[:, 2]
    front = smoothstep(0.2, 0.6, u[:, 1])  # 1 on the face, 0 on the sides and back
    lower = smoothstep(-0.02, -0.11, z)  # 0 above the cheekbones, 1 at the chin
    # jaw: the lower head shifts forward (chin ahead of the neck) and narrows toward the chin
    y = y + 0.04 * lower
    x = x * (1.0 - 0.3 * lower * smoothstep(-0.2, 0.5, u[:, 1]))
    # occiput to nape: the back of the skull curves in toward the neck
    y = y * (1.0 - 0.45 * smoothstep(-0.02, -0.1, z) * smoothstep(0.0, -0.4, u[:, 1]))
    # face relief along +y: brow ridge, eye sockets, nose (tip low, bridge narrow), lips, chin
    nose_width = 0.007 + 0.006 * smoothstep(0.02, -0.035, z)  # narrow bridge, wide nostrils
    nose_fall = np.where(z < -0.026, 0.012, 0.045)  # long slope above the tip, short below
    nose = 0.024 * np.exp(-(x / nose_width) ** 2 - ((z + 0.026) / nose_fall) ** 2)
    brow = 0.005 * _bump(x, None, z, (0.0, None, 0.032), (0.05, None, 0.009))
    eyes = 0.009 * (_bump(x, None, z, (0.033, None, 0.014), (0.013, None, 0.009))
                    + _bump(x, None, z, (-0.033, None, 0.014), (0.013, None, 0.009)))
    lips = 0.006 * _bump(x, None, z, (0.0, None, -0.062), (0.02, None, 0.009))
    chin = 0.007 * _bump(x, None, z, (0.0, None, -0.097), (0.022, None, 0.012))
    y = y + front * (nose + brow - eyes + lips + chin)
    # ears: flattened bumps on the sides at eye-to-nose height, slightly behind the centre
    side = smoothstep(0.55, 0.85, np.abs(u[:, 0]))
    ear_r2 = ((y + 0.008) / 0.013) ** 2 + ((z + 0.008) / 0.026) ** 2
    ear = 0.012 * side * np.exp(-ear_r2 ** 2)  # super-Gaussian: a flat-topped disc, not a blob
    x = x + np.sign(x) * ear
    return np.stack([x, y, z], axis=1)


def scalp_mask(points: np.ndarray) -> np.ndarray:
    """True [V] where hair grows: above a hairline that is high on the forehead (z = 0.058 m),
    lower over the temples and above the ears (0.036 m), and drops behind the ears to the nape
    (-0.07 m at the back). The hairline height depends on the azimuth |atan2(x, y)| from the
    face (0 front, pi/2 ears, pi back)."""
    azimuth = np.abs(np.arctan2(points[:, 0], points[:, 1]))
    temple = 0.058 - 0.022 * smoothstep(0.5, 1.2, azimuth)
    hairline = temple + (-0.07 - temple) * smoothstep(1.75, 2.7, azimuth)
    return points[:, 2] > hairline


def default_head(resolution: int = 4) -> HeadModel:
    """The project's stylised human head (see the module docstring for axes and sizes).

    resolution: icosphere subdivisions, 2..6: 20 4^n faces (4: 5,120 faces, ~7 mm edges;
    5: 20,480 faces, ~3.5 mm edges). capsules: the neck, from inside the head down into the
    bust below it (radius 0.055 m; taichi_hair.world.bust).
    """
    if not (isinstance(resolution, (int, np.integer)) and 2 <= resolution <= 6):
        raise ValueError(f"resolution must be an integer subdivision count in [2, 6], got {resolution!r}")
    u, faces = icosphere(int(resolution))
    vertices = head_surface(u)
    capsules = (NECK_CAPSULE,)
    return HeadModel(vertices=vertices, faces=faces, scalp=scalp_mask(vertices), capsules=capsules)


# ---- OBJ ---------------------------------------------------------------------------------------
_IGNORED = {"vt", "vn", "vp", "o", "g", "s", "usemtl", "mtllib", "l", "p"}


def read_obj_mesh(path):
    """Vertices float64 [V, 3] and triangles int32 [F, 3] (0-based) of a Wavefront OBJ file.

    Reads `v x y z [w or r g b]` (extra values ignored) and `f` lines with 1-based or negative
    (relative) indices in any of the forms i, i/t, i//n, i/t/n; polygons are fan-triangulated
    (v0, vk, vk+1). Comments and vt/vn/vp/o/g/s/usemtl/mtllib/l/p lines are ignored. Raises
    ValueError naming the file and line on anything else malformed.
    """
    vertices, faces = [], []
    with open(path, "r", encoding="utf-8", errors="replace") as fh:
        for lineno, raw in enumerate(fh, start=1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            key, *rest = line.split()
            where = f"{os.fspath(path)}:{lineno}"
            if key == "v":
                vertices.append(_obj_vertex(rest, where, raw))
            elif key == "f":
                faces.extend(_obj_face(rest, len(vertices), where, raw))
            elif key not in _IGNORED:
                raise ValueError(f"{where}: unknown OBJ statement {key!r} in line {raw.strip()!r}")
    if not faces:
        raise ValueError(f"{os.fspath(path)}: no faces (f lines) found; a triangle mesh needs at least one")
    return np.array(vertices, dtype=np.float64).reshape(-1, 3), np.array(faces, dtype=np.int32)


def _obj_vertex(rest, where, raw):
    try:
        xyz = [float(t) for t in rest[:3]]
    except ValueError:
        xyz = []
    if len(xyz) != 3 or not all(math.isfinite(c) for c in xyz):
        raise ValueError(f"{where}: a vertex needs three finite coordinates, got {raw.strip()!r}")
    return xyz


def _obj_face(rest, n_vertices, where, raw):
    if len(rest) < 3:
        raise ValueError(f"{where}: a face needs at least 3 vertices, got {raw.strip()!r}")
    idx = []
    for token in rest:
        try:
            i = int(token.split("/", 1)[0])
        except ValueError:
            raise ValueError(f"{where}: bad vertex index {token!r} in {raw.strip()!r}") from None
        j = i - 1 if i > 0 else n_vertices + i  # negative indices count back from the last vertex
        if i == 0 or not 0 <= j < n_vertices:
            raise ValueError(f"{where}: vertex index {i} out of range (1..{n_vertices} or "
                             f"-{n_vertices}..-1 at this line) in {raw.strip()!r}")
        idx.append(j)
    return [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]


def write_obj_mesh(path, vertices, faces) -> None:
    """Write vertices [V, 3] and triangles [F, 3] (0-based) as OBJ with 17 significant digits,
    so `read_obj_mesh` gives back the same float64 values."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape [V, 3], got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and (f.min() < 0 or f.max() >= len(v))):
        raise ValueError(f"faces must be [F, 3] indices into the {len(v)} vertices, got shape {f.shape}")
    lines = ["# taichi_hair triangle mesh, metres"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f.tolist()]
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
