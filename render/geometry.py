"""Scene inputs as validated numpy data: hair polylines and triangle meshes.

Colours are sRGB in [0, 1] as users pick them; they are converted to linear light here,
because shading and the blending of thin fibres are only correct in linear light.
"""

from dataclasses import dataclass, field

import numpy as np

from .colour import sigma_for_colour, srgb_to_linear
from .fibre import HairMaterial, colour_from_sigma


# grooms of this many vertices or more are drawn in a spatial order (`Hair.subset`); tests
# change it to compare orders
SPATIAL_ORDER_VERTICES = 1_000_000


def _topology(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Strands of counts (S,) vertices stored one after another -> (the first vertex of each
    segment (E,), each vertex's previous and next vertex on its strand (V, 2), the vertex
    itself at the ends), int32, read-only. The last result is kept: a simulation's frames
    have the same strands every time, and the renderer then finds the very arrays it
    uploaded last and does not upload them again."""
    global _last_topology
    if _last_topology is not None and np.array_equal(_last_topology[0], counts):
        return _last_topology[1], _last_topology[2]
    n = int(counts.sum())
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    ends = starts + counts - 1
    idx = np.arange(n, dtype=np.int32)   # the renderer's index type, built in it
    neighbours = np.empty((n, 2), dtype=np.int32)
    neighbours[:, 0], neighbours[:, 1] = idx - 1, idx + 1
    neighbours[starts, 0], neighbours[ends, 1] = starts, ends
    is_last = np.zeros(n, dtype=bool)
    is_last[ends] = True
    segments = idx[~is_last]
    for a in (segments, neighbours):
        a.flags.writeable = False
    _last_topology = (np.array(counts), segments, neighbours)
    return segments, neighbours


_last_topology = None   # (counts, segments, neighbours) of `_topology`'s last call


def _morton(p: np.ndarray) -> np.ndarray:
    """Morton (Z-order) codes (N,) uint64 of points p (N, 3), 10 bits per axis over their
    bounding box: sorted by them, points near in space are mostly near in the order."""
    lo, hi = p.min(axis=0), p.max(axis=0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-12) * 1023.0).astype(np.uint64)
    code = np.zeros(len(p), np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return code


def _strands(points) -> tuple[np.ndarray, np.ndarray]:
    """[S, N, 3] array or a sequence of [N_i, 3] arrays -> (the vertices of all strands one
    after another (V, 3), vertices per strand (S,) int64)."""
    if isinstance(points, np.ndarray) and points.ndim == 3:
        # one block already: checked and reshaped whole, not gathered strand by strand (a
        # frame of 20k x 31 vertices spent ~6 ms on that)
        if len(points) == 0:
            raise ValueError("points must hold at least one strand, got none")
        if points.shape[1] < 2 or points.shape[2] != 3:
            raise ValueError(f"points: strand 0 must have shape [N >= 2, 3], got {points.shape[1:]}")
        return points.reshape(-1, 3), np.full(len(points), points.shape[1], dtype=np.int64)
    if isinstance(points, (list, tuple)):
        strands = [np.asarray(p, dtype=np.float64) for p in points]
    else:
        shape = getattr(points, "shape", type(points).__name__)
        raise ValueError(f"points must be an [S, N, 3] array or a list of [N_i, 3] arrays, got {shape}")
    if not strands:
        raise ValueError("points must hold at least one strand, got none")
    for i, p in enumerate(strands):
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 2:
            raise ValueError(f"points: strand {i} must have shape [N >= 2, 3], got {p.shape}")
    return np.concatenate(strands), np.array([len(p) for p in strands], dtype=np.int64)


def _per_vertex(name: str, value, counts: np.ndarray, tail: tuple, convert=None) -> np.ndarray:
    """Broadcast a per-hair, per-strand or per-vertex attribute to all V vertices, (V, *tail).
    convert (optional): applied to the values as given, before broadcasting (so a colour per
    strand is converted once per strand, not once per vertex)."""
    conv = (lambda a: a) if convert is None else convert
    n_strands, n_vertices = len(counts), int(counts.sum())
    if isinstance(value, (list, tuple)) and len(value) == n_strands and n_strands > 0 \
            and np.ndim(value[0]) == 1 + len(tail) and np.shape(value[0])[0] == counts[0]:
        parts = [np.asarray(v, dtype=np.float64) for v in value]
        if any(p.shape != (c, *tail) for p, c in zip(parts, counts)):
            raise ValueError(f"{name}: per-vertex list entries must have shape [N_i, *{tail}]")
        return conv(np.concatenate(parts))
    a = np.asarray(value, dtype=np.float64)
    if a.shape == tail:
        c = conv(a)
        return np.broadcast_to(c, (n_vertices, *c.shape))
    if a.shape == (n_strands, *tail):
        return np.repeat(conv(a), counts, axis=0)
    if a.ndim == 2 + len(tail) and a.shape[:2] == (n_strands, counts[0]) and np.all(counts == counts[0]):
        return conv(a.reshape(n_vertices, *tail))
    raise ValueError(f"{name} must have shape {tail}, (S, *{tail}) or (S, N, *{tail}) "
                     f"with S={n_strands}, got {a.shape}")


def _linear_colours(c: np.ndarray) -> np.ndarray:
    """Checked sRGB colours in [0, 1] -> linear light."""
    if c.size and not np.all((c >= 0.0) & (c <= 1.0)):
        raise ValueError(f"colours must be sRGB in [0, 1], got range [{c.min():.3g}, {c.max():.3g}]")
    return srgb_to_linear(c)


_UNIFORM = ("vertex_colours", "vertex_widths", "vertex_sigma", "vertex_beta_m", "fibre")
_last_uniform = None   # (key, {name: value}) of the last Hair of one colour and one width


def _uniform_key(colours, widths, material, counts: np.ndarray):
    """What a Hair's per-vertex colours, widths and optics depend on when one colour (3,) and
    one width serve all its fibres and no material is given: (colour, width, counts); None
    otherwise."""
    if material is not None or np.shape(colours) != (3,) or np.shape(widths) != ():
        return None
    c, w = np.asarray(colours, dtype=np.float64), np.asarray(widths, dtype=np.float64)
    return c.tobytes(), w.tobytes(), counts


def _reuse_uniform(hair, key) -> bool:
    """Give `hair` the per-vertex arrays of the last Hair of the same key (`_uniform_key`), if
    any: a simulation's frames draw the same strands in the same colour every time, and the
    renderer then finds the very arrays it uploaded last and does not upload them again."""
    if key is None or _last_uniform is None:
        return False
    last, values = _last_uniform
    if last[:2] != key[:2] or not np.array_equal(last[2], key[2]):
        return False
    for name in _UNIFORM:
        object.__setattr__(hair, name, values[name])
    return True


def _keep_uniform(hair, key) -> None:
    """Remember `hair`'s per-vertex arrays under `key` for `_reuse_uniform` (one Hair kept)."""
    global _last_uniform
    if key is not None:
        _last_uniform = ((key[0], key[1], np.array(key[2])),
                         {name: getattr(hair, name) for name in _UNIFORM})


@dataclass(frozen=True, kw_only=True, eq=False)
class Hair:
    """Hair as polylines.

    points [m]: array [S, N, 3], or a list of S arrays [N_i, 3] (ragged), N >= 2.
    colours: sRGB in [0, 1]; shape (3,) for all hair, (S, 3) per strand, or per vertex
        ((S, N, 3) or a list of [N_i, 3]). Without a material the fibres' absorption is chosen
        so that the hair renders as this colour: the body colour of the reference swatch
        (`render.swatch`; within Delta E2000 3), highlights on top.
    widths [m] > 0: fibre (or ribbon) width; a scalar, (S,) per strand, or per vertex
        ((S, N) or a list of [N_i]). Real hair is 50-100 um wide.
    opacity in (0, 1]: alpha of a fibre covering a whole pixel.
    material: a `HairMaterial` for the physically based fibre shading (per-strand variation
        drawn from its seed). None: the absorption is inverted from `colours` per vertex
        (`HairMaterial.from_colour`, beta_n = 0.3) and the other parameters are the defaults.
        With a material, `colours` is ignored and Kajiya-Kay uses the material's colour.

    Derived at construction (float32 / int32, V vertices, E segments): `vertices` (V, 3),
    `vertex_colours` (V, 3) linear, `vertex_widths` (V,), `segments` (E,) index of each
    segment's first vertex, `neighbours` (V, 2) previous and next vertex on the strand (the
    vertex itself at the ends), used for tangents. They are read-only (the renderer keeps
    device copies of a groom it renders again).
    """

    points: object
    colours: object = (0.30, 0.18, 0.10)
    widths: object = 1e-4
    opacity: float = 1.0
    material: HairMaterial | None = None
    vertices: np.ndarray = field(init=False, repr=False)
    vertex_colours: np.ndarray = field(init=False, repr=False)
    vertex_widths: np.ndarray = field(init=False, repr=False)
    segments: np.ndarray = field(init=False, repr=False)
    neighbours: np.ndarray = field(init=False, repr=False)
    vertex_sigma: np.ndarray = field(init=False, repr=False)
    vertex_beta_m: np.ndarray = field(init=False, repr=False)
    fibre: HairMaterial = field(init=False, repr=False)
    strand_starts: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        x, counts = _strands(self.points)
        if not np.all(np.isfinite(x)):
            raise ValueError("points must be finite, got NaN or inf")
        if not 0.0 < self.opacity <= 1.0:
            raise ValueError(f"opacity must be in (0, 1], got {self.opacity}")
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
        segments, neighbours = _topology(counts)
        set_ = lambda n, v: object.__setattr__(self, n, v)
        set_("vertices", x.astype(np.float32))
        set_("segments", segments)
        set_("neighbours", neighbours)
        set_("strand_starts", np.concatenate([starts, [len(x)]]).astype(np.int64))
        uniform = _uniform_key(self.colours, self.widths, self.material, counts)
        fresh = not _reuse_uniform(self, uniform)
        if fresh:
            self._set_appearance(counts)
        # derived once and never changed: read-only, so the renderer may keep device copies
        for name in ("vertices", "vertex_colours", "vertex_widths", "segments", "neighbours",
                     "strand_starts", "vertex_sigma", "vertex_beta_m"):
            a = getattr(self, name)
            if a.base is not None:   # a view could change through its base: own the data
                a = a.copy()
                set_(name, a)
            a.flags.writeable = False
        if fresh:
            _keep_uniform(self, uniform)

    def _set_appearance(self, counts: np.ndarray) -> None:
        """vertex_colours, vertex_widths, vertex_sigma, vertex_beta_m and fibre from the
        colours, widths and material, checked."""
        # without a material the absorption is inverted from the colours: per colour as given
        # (one per hair or strand, usually), before broadcasting to the vertices
        invert = self.material is None

        def colour_terms(c):
            # float32 before broadcasting: the per-vertex copies below then convert nothing
            lin = _linear_colours(c)
            terms = np.concatenate([lin, sigma_for_colour(lin)], axis=-1) if invert else lin
            return terms.astype(np.float32)

        terms = _per_vertex("colours", self.colours, counts, (3,), convert=colour_terms)
        linear, sigma = terms[:, :3], (terms[:, 3:] if invert else None)
        widths = _per_vertex("widths", self.widths, counts, ())
        if widths.size and not (np.all(np.isfinite(widths)) and widths.min() > 0.0):
            raise ValueError(f"widths must be > 0 m, got minimum {widths.min():.3g}")
        set_ = lambda n, v: object.__setattr__(self, n, v)
        set_("vertex_colours", linear.astype(np.float32))
        set_("vertex_widths", np.ascontiguousarray(widths, dtype=np.float32))
        self._set_optics(counts, linear, sigma)

    def subset(self, fraction: float) -> dict:
        """The strands the renderer draws: a fixed, seeded `fraction` of them (level of
        detail; the same strands for every frame of the same groom, nested as the fraction
        grows; all of them for 1), as arrays shaped like the derived fields: x, widths, seg,
        nbr, colour, sigma, beta_m, and order (V',): each vertex's index in `vertices`.
        Widths are not changed. Grooms of SPATIAL_ORDER_VERTICES vertices or more come in the
        order of their roots along a Morton curve: strands near in space near in memory, so
        that the splats', the binning's and the compositor's reads of the segments' vertices
        hit the caches (the 1280 x 720, 100k-strand benchmark, whose strands come in random
        order, on a loaded 2-core machine: the opacity splat 737 -> 410 ms, the binning 654 ->
        363, the frame 4.5 -> 3.6 s; the main job's 20k strands of 31 vertices gained about
        what the gathering costs). Cached."""
        cache = self.__dict__.setdefault("_lod_cache", {})
        if fraction in cache:
            return cache[fraction]
        n_strands = len(self.strand_starts) - 1
        if fraction < 1.0:
            rank = np.random.default_rng(12345).permutation(n_strands)
            keep = np.nonzero(rank < max(1, round(fraction * n_strands)))[0]
        else:
            keep = np.arange(n_strands)
        lo = self.strand_starts[keep]
        if len(keep) > 1 and len(self.vertices) * len(keep) >= SPATIAL_ORDER_VERTICES * n_strands:
            keep = keep[np.argsort(_morton(self.vertices[lo]), kind="stable")]
            lo = self.strand_starts[keep]
        counts = self.strand_starts[keep + 1] - lo
        per_strand = np.diff(self.strand_starts)
        if np.array_equal(keep, np.arange(n_strands)):
            idx = np.arange(len(self.vertices))
            take = lambda a: a   # all strands as they are: the arrays themselves
        elif n_strands and np.all(per_strand == per_strand[0]):
            # strands of one length (the usual (S, N, 3) input): whole rows move, much faster
            # than gathering vertex by vertex
            n = int(per_strand[0])
            take = lambda a: np.take(a.reshape(n_strands, -1), keep, axis=0).reshape(-1, *a.shape[1:])
            idx = (keep[:, None] * n + np.arange(n)).ravel()
        else:
            idx = np.repeat(lo - np.cumsum(np.concatenate([[0], counts[:-1]])), counts) + np.arange(counts.sum())
            take = lambda a: np.take(a, idx, axis=0)
        if len(keep) == n_strands and np.array_equal(counts, per_strand):
            seg, nbr = self.segments, self.neighbours   # the same lengths in the same places
        else:
            seg, nbr = _topology(counts)
        cache.clear()   # one level kept per groom
        cache[fraction] = dict(x=take(self.vertices), widths=take(self.vertex_widths), seg=seg,
                               nbr=nbr, colour=take(self.vertex_colours),
                               sigma=take(self.vertex_sigma), beta_m=take(self.vertex_beta_m),
                               order=idx)
        for a in cache[fraction].values():
            a.flags.writeable = False
        return cache[fraction]

    def _set_optics(self, counts: np.ndarray, linear: np.ndarray, sigma) -> None:
        """sigma: the absorption inverted from the colours (V, 3) when there is no material."""
        set_ = lambda n, v: object.__setattr__(self, n, v)
        m = self.material
        if m is None:
            fibre = HairMaterial()
            beta_m = np.full(len(linear), fibre.beta_m)
        elif isinstance(m, HairMaterial):
            fibre = m
            s_strand, b_strand = m.strands(len(counts))
            sigma, beta_m = np.repeat(s_strand, counts, axis=0), np.repeat(b_strand, counts)
            set_("vertex_colours", np.repeat(colour_from_sigma(s_strand, m.beta_n).astype(np.float32),
                                             counts, axis=0))
        else:
            raise ValueError(f"material must be a render.HairMaterial or None, got {type(m).__name__}")
        set_("fibre", fibre)
        set_("vertex_sigma", np.ascontiguousarray(sigma, dtype=np.float32))
        set_("vertex_beta_m", np.ascontiguousarray(beta_m, dtype=np.float32))


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals, (V, 3), of a triangle mesh (V, 3) [m], (F, 3)."""
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0.0, length, 1.0)


@dataclass(frozen=True, kw_only=True, eq=False)
class Mesh:
    """Triangle mesh, shaded Lambert + Blinn and shadowed by hair.

    vertices [m]: (V, 3). faces: (F, 3) integer indices into vertices.
    colours: sRGB in [0, 1], (3,) or per vertex (V, 3).
    normals: (V, 3) or None for smooth area-weighted normals. Lighting is two-sided.
    specular >= 0: Blinn highlight strength; shininess >= 1: Blinn exponent.
    """

    vertices: object
    faces: object
    colours: object = (0.80, 0.62, 0.52)
    normals: object = None
    specular: float = 0.15
    shininess: float = 30.0

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=np.float64)
        f = np.asarray(self.faces)
        if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
            raise ValueError(f"vertices must be a finite (V, 3) array, got shape {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
            raise ValueError(f"faces must be an integer (F, 3) array, got {f.dtype} {f.shape}")
        if f.size and (f.min() < 0 or f.max() >= len(v)):
            raise ValueError(f"faces must index vertices in [0, {len(v) - 1}], "
                             f"got [{f.min()}, {f.max()}]")
        c = np.asarray(self.colours, dtype=np.float64)
        if c.shape not in ((3,), (len(v), 3)) or not np.all((c >= 0.0) & (c <= 1.0)):
            raise ValueError(f"colours must be sRGB in [0, 1] of shape (3,) or ({len(v)}, 3), "
                             f"got shape {c.shape}")
        n = vertex_normals(v, f) if self.normals is None else np.asarray(self.normals, float)
        if n.shape != v.shape:
            raise ValueError(f"normals must have shape {v.shape}, got {n.shape}")
        if not self.specular >= 0.0:
            raise ValueError(f"specular must be >= 0, got {self.specular}")
        if not self.shininess >= 1.0:
            raise ValueError(f"shininess must be >= 1, got {self.shininess}")
        set_ = lambda name, val: object.__setattr__(self, name, val)
        set_("vertices", v)
        set_("faces", f.astype(np.int64))
        set_("colours", np.broadcast_to(c, v.shape))
        set_("normals", n)


def merge_meshes(meshes) -> dict:
    """Concatenate meshes for the kernels. Returns float32/int32 arrays: x (V, 3) [m],
    normal (V, 3), colour (V, 3) linear, faces (F, 3), material (F, 2) (specular, shininess),
    part (F,) the index in `meshes` of each face's mesh."""
    meshes = list(meshes)
    for i, m in enumerate(meshes):
        if not isinstance(m, Mesh):
            raise ValueError(f"meshes[{i}] must be a render.Mesh, got {type(m).__name__}")
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])
    cat = lambda parts, shape: np.concatenate(parts) if parts else np.zeros(shape)
    return dict(
        x=cat([m.vertices for m in meshes], (0, 3)).astype(np.float32),
        normal=cat([m.normals for m in meshes], (0, 3)).astype(np.float32),
        colour=srgb_to_linear(cat([m.colours for m in meshes], (0, 3))).astype(np.float32),
        faces=cat([m.faces + o for m, o in zip(meshes, offsets)], (0, 3)).astype(np.int32),
        material=cat([np.tile([m.specular, m.shininess], (len(m.faces), 1)) for m in meshes],
                     (0, 2)).astype(np.float32),
        part=np.repeat(np.arange(len(meshes)), [len(m.faces) for m in meshes]).astype(np.int32),
    )


def capsule_mesh(p0, p1, radius: float, colours=(0.80, 0.62, 0.52), sectors: int = 32,
                 rings: int = 8) -> Mesh:
    """A capsule (the segment p0-p1 [m] swept by a sphere of `radius` [m]) as a closed
    triangle mesh: a cylinder with hemispherical caps, `sectors` around, `rings` per cap."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = p1 - p0
    length = np.linalg.norm(axis)
    if not (radius > 0 and length > 0):
        raise ValueError(f"capsule needs radius > 0 m and p0 != p1, got radius {radius}")
    w = axis / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(w[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(w, helper)
    u /= np.linalg.norm(u)
    v = np.cross(w, u)
    # latitude from -pi/2 (below p0) to +pi/2 (above p1); the cylinder joins the two equators
    lat = np.concatenate([np.linspace(-np.pi / 2, 0, rings + 1), np.linspace(0, np.pi / 2, rings + 1)])
    base = np.concatenate([np.zeros(rings + 1), np.full(rings + 1, length)])
    phi = np.linspace(0.0, 2 * np.pi, sectors + 1)[None, :]
    ring = np.cos(lat)[:, None, None] * (np.cos(phi)[..., None] * u + np.sin(phi)[..., None] * v)
    verts = (p0 + radius * ring + (base + radius * np.sin(lat))[:, None, None] * w).reshape(-1, 3)
    n_rows = len(lat)
    i, j = np.meshgrid(np.arange(n_rows - 1), np.arange(sectors), indexing="ij")
    a = (i * (sectors + 1) + j).ravel()
    b, c, d = a + sectors + 1, a + 1, a + sectors + 2
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([c, b, d], 1)])
    return Mesh(vertices=verts, faces=faces, colours=colours)
