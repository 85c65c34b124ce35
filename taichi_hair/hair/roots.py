"""Guide roots on a head's scalp and a groom grown from them.

`sample_scalp` spreads n roots as blue noise over the scalp triangles (farthest-point sampling
of a dense, area-uniform, seeded candidate set: deterministic for a seed, and no two roots
closer than the final coverage radius). `scalp_groom` grows one strand per root: it leaves the
scalp along the normal blended with the comb direction, then bends smoothly toward
down + comb (gravity-combed hair), with optional waves or curls added sideways, and is
resampled to evenly spaced nodes. Head-local coordinates as in `taichi_hair.world.headmesh`
(+z up, face along +y): the default comb (0, -1, 0) combs the hair back.
"""

import math

import numpy as np

from ..diskcache import cached_arrays
from ..rods.groom import Groom
from ..validation import choice, integer, real, vector3
from ..world.headmesh import HeadModel

STYLES = ("straight", "wavy", "curly")
CANDIDATES_PER_ROOT = 24  # dense candidates per requested root for farthest-point sampling
MIN_CANDIDATES = 4000


COVERED_CLEARANCE = 0.003  # [m] scalp this close to a capsule's surface (or inside) is covered


def _scalp_triangles(head):
    """Scalp faces: at least two scalp vertices, and none of the three inside or within
    COVERED_CLEARANCE of one of the head model's capsules (skin the neck covers grows no hair:
    a root there would sit inside the neck collider and the hair could not collide with it)."""
    if not isinstance(head, HeadModel):
        raise ValueError(f"head must be a taichi_hair.world.headmesh.HeadModel, got {type(head).__name__}")
    faces = head.scalp_faces(min_vertices=2)  # "most" of a triangle's vertices are scalp
    covered = np.zeros(len(head.vertices), dtype=bool)
    for p0, p1, radius in head.capsules:
        covered |= _capsule_distance(head.vertices, np.asarray(p0), np.asarray(p1)) < radius + COVERED_CLEARANCE
    faces = faces[~covered[head.faces[faces]].any(axis=1)]
    if len(faces) == 0:
        raise ValueError("head.scalp marks no triangle clear of the capsules (need >= 2 scalp "
                         "vertices in some face)")
    return faces


def _capsule_distance(points, p0, p1):
    """Distance [m] of points [K, 3] from the segment p0-p1 (a capsule's axis)."""
    axis = p1 - p0
    t = np.clip((points - p0) @ axis / max(axis @ axis, 1e-300), 0.0, 1.0)
    return np.linalg.norm(points - (p0 + t[:, None] * axis), axis=1)


def sample_scalp(head: HeadModel, n: int, *, seed: int = 0, min_distance: float | None = None,
                 blue_noise: bool = True):
    """n blue-noise roots on the scalp: points [n, 3] m and unit outward normals [n, 3].

    A triangle is scalp when at least two of its vertices are. Candidates (24 per root, at
    least 4,000) are drawn uniformly by area with `seed`; farthest-point sampling from a seeded
    start keeps n of them, so every pair is at least the last chosen distance apart and every
    candidate lies within it of a root. Normals interpolate the area-weighted vertex normals.
    min_distance [m]: if given, ValueError when the n roots cannot all be that far apart.
    blue_noise=False keeps the first n uniform candidates instead: O(n), for the tens of
    thousands of dense-hair roots, where farthest-point sampling (O(n^2)) is too slow.
    """
    faces = _scalp_triangles(head)
    integer("n", n, low=1)
    integer("seed", seed, low=0)
    if min_distance is not None:
        real("min_distance", min_distance, "m", low=0.0)
    rng = np.random.default_rng(seed)
    tri = head.faces[faces]
    areas = head.face_areas()[faces]
    m = max(CANDIDATES_PER_ROOT * n, MIN_CANDIDATES) if blue_noise else n
    pick = rng.choice(len(faces), size=m, p=areas / areas.sum())
    r1, r2 = np.sqrt(rng.random(m)), rng.random(m)  # uniform on a triangle
    bary = np.stack([1.0 - r1, r1 * (1.0 - r2), r1 * r2], axis=1)
    corners = head.vertices[tri[pick]]  # [m, 3 corners, 3]
    cand = np.einsum("mc,mck->mk", bary, corners)
    if blue_noise:
        chosen, spread = _farthest_points(cand, n, int(rng.integers(m)))
    else:
        chosen, spread = np.arange(n), 0.0
    if min_distance is not None and blue_noise and spread < min_distance:
        raise ValueError(f"min_distance = {min_distance!r} m cannot be met by {n} roots on this scalp "
                         f"(blue-noise spacing reached {spread:.4g} m); ask for fewer roots")
    vn = head.vertex_normals()[tri[pick[chosen]]]
    normals = np.einsum("mc,mck->mk", bary[chosen], vn)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return cand[chosen], normals


def _farthest_points(points, n, start):
    """Indices [n] chosen greedily, each the candidate farthest from those before, and the
    distance [m] at which the last one was taken (the set's minimum pairwise distance bound)."""
    if n > len(points):
        raise ValueError(f"n must be <= {len(points)} candidates, got {n}")
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = start
    d2 = ((points - points[start]) ** 2).sum(axis=1)
    last = math.inf
    for i in range(1, n):
        k = int(np.argmax(d2))
        chosen[i], last = k, math.sqrt(d2[k])
        np.minimum(d2, ((points - points[k]) ** 2).sum(axis=1), out=d2)
    return chosen, last


def _smoothstep(u):
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _centrelines(roots, growth, flow, lengths, droop_length, samples, collider=None, keep_out=0.0,
                 free_length=None):
    """Fine centrelines [S, M, 3] with arc length s [S, M], their unit tangents [S, M, 3] and a
    side vector [S, 3] normal to each strand's plane (span of growth and flow). With a collider,
    the centreline is integrated step by step and slides over the head instead of entering it:
    where a step would come within keep_out [m] of the surface its inward part is removed and
    the point is set back out, so the strand lies on the head as combed hair does, without the
    kinks a per-node push-out would leave. The first free_length [S] metres (the root edge)
    grow freely along the growth direction."""
    s = np.linspace(0.0, 1.0, samples)[None] * lengths[:, None]
    w = _smoothstep(s / droop_length)[..., None]
    d = (1.0 - w) * growth[:, None] + w * flow[:, None]
    d /= np.maximum(np.linalg.norm(d, axis=2, keepdims=True), 1e-12)
    ds = np.diff(s, axis=1)[..., None]
    steps = 0.5 * (d[:, 1:] + d[:, :-1]) * ds
    if collider is None:
        x = roots[:, None] + np.concatenate([np.zeros_like(roots[:, None]), np.cumsum(steps, axis=1)], axis=1)
    else:
        x = np.empty(d.shape)
        x[:, 0] = roots
        rooted = s < free_length[:, None]
        for m in range(samples - 1):
            slid = _slide(collider, x[:, m], steps[:, m], keep_out)
            x[:, m + 1] = np.where(rooted[:, m + 1, None], x[:, m] + steps[:, m], slid)
        x = _smooth_off_surface(x, rooted, collider, keep_out, lengths / samples)
        tangent = np.gradient(x, axis=1)
        d = tangent / np.maximum(np.linalg.norm(tangent, axis=2, keepdims=True), 1e-12)
    side = np.cross(growth, flow)
    fallback = np.cross(growth, np.where(np.abs(growth[:, [0]]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    side = np.where(np.linalg.norm(side, axis=1, keepdims=True) > 1e-6, side, fallback)
    return x, s, d, side / np.linalg.norm(side, axis=1, keepdims=True)


def _smooth_off_surface(x, keep, collider, keep_out, ds, window=0.03, passes=3):
    """Round off the corners where a centreline meets the head and starts sliding: moving
    averages over `window` [m] of arc length, then points set back out to keep_out. Samples
    marked in keep [S, M] (the root edge) are left alone."""
    half = max(1, int(round(0.5 * window / ds.min())))
    for _ in range(passes):
        padded = np.concatenate([np.repeat(x[:, :1], half, axis=1), x, np.repeat(x[:, -1:], half, axis=1)], axis=1)
        csum = np.cumsum(padded, axis=1)
        csum = np.concatenate([np.zeros_like(csum[:, :1]), csum], axis=1)
        averaged = (csum[:, 2 * half + 1:] - csum[:, :-2 * half - 1]) / (2 * half + 1)
        x = np.where(keep[..., None], x, averaged)
        flat = x.reshape(-1, 3)
        gap = keep_out - collider.sample(flat)
        out = (gap > 0) & ~keep.reshape(-1)
        if out.any():
            g = collider.gradient(flat[out])
            flat[out] += gap[out, None] * g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        x = flat.reshape(x.shape)
    return x


def _slide(collider, p, step, keep_out):
    """p + step, with the part of step that heads into the collider removed where the new point
    would be closer than keep_out [m] to it, and set back out to keep_out; the step's length is
    kept so arc length stays arc length."""
    q = p + step
    near = collider.sample(q) < keep_out
    if near.any():
        g = collider.gradient(p[near])
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        st = step[near]
        inward = np.minimum(np.sum(st * g, axis=1, keepdims=True), 0.0)
        tangential = st - inward * g
        tangential *= np.linalg.norm(st, axis=1, keepdims=True) / np.maximum(
            np.linalg.norm(tangential, axis=1, keepdims=True), 1e-12)
        moved = p[near] + tangential
        gap = keep_out - collider.sample(moved)
        gq = collider.gradient(moved)
        gq /= np.maximum(np.linalg.norm(gq, axis=1, keepdims=True), 1e-12)
        q[near] = moved + np.maximum(gap, 0.0)[:, None] * gq
    return q


def _offsets(style, s, d, side, params, rng):
    """Sideways offsets [S, M, 3] of waves or curls, zero over the root edges so the strand
    leaves the scalp along its growth direction, ramped in by `ramp` [m]."""
    count = len(s)
    if style == "straight":
        return np.zeros(s.shape + (3,))
    start, ramp, variation = params["start"], params["ramp"], params["variation"]
    envelope = _smoothstep((s - start[:, None]) / ramp)[..., None]
    vary = 1.0 + variation * rng.uniform(-1.0, 1.0, (count, 2))
    phase = rng.uniform(0.0, 2.0 * math.pi, count)[:, None]
    if style == "wavy":
        amp = params["wave_amplitude"] * vary[:, 0, None]
        k = 2.0 * math.pi / (params["wave_wavelength"] * vary[:, 1, None])
        return envelope * (amp * np.sin(k * s + phase))[..., None] * side[:, None]
    radius = params["curl_radius"] * vary[:, 0, None, None]
    k = 2.0 * math.pi / (params["curl_pitch"] * vary[:, 1, None])
    normal2 = np.cross(d, side[:, None])  # in the strand's plane, perpendicular to the tangent
    angle = (k * s + phase)[..., None]
    return envelope * radius * (np.cos(angle) * side[:, None] + np.sin(angle) * normal2)


def _resample(curve, lengths, n_nodes):
    """Nodes [S, n_nodes, 3] along each fine curve [S, M, 3], every edge a chord of
    lengths[s] / (n_nodes - 1): the polyline is the strand's length and its edges are equal.
    Equal arc lengths would leave shorter chords where the curve turns (a bend near the root
    shortened an edge by up to 20 %), and the explicit step's bound goes with the shortest
    edge squared."""
    count, samples = curve.shape[:2]
    edge = lengths / (n_nodes - 1)
    out = np.empty((count, n_nodes, 3))
    out[:, 0] = curve[:, 0]
    strands = np.arange(count)
    after = np.zeros(count, dtype=np.int64)  # the fine segment (after, after + 1) holds the last node
    for k in range(1, n_nodes):
        start = out[:, k - 1]
        # the first fine point at least an edge from the last node, past the segment it lies on
        reach = after + 1
        while True:
            short = np.linalg.norm(curve[strands, np.minimum(reach, samples - 1)] - start, axis=1) < edge
            short &= reach < samples
            if not short.any():
                break
            reach[short] += 1
        if np.any(reach >= samples):
            raise RuntimeError("fine curve shorter than its strand; the length bound is wrong")
        # the sphere of radius edge about the last node meets the fine segment (reach - 1, reach)
        a, b = curve[strands, reach - 1], curve[strands, reach]
        d, f = b - a, a - start
        qa, qb, qc = np.sum(d * d, axis=1), 2.0 * np.sum(d * f, axis=1), np.sum(f * f, axis=1) - edge**2
        t = (-qb + np.sqrt(np.maximum(qb * qb - 4.0 * qa * qc, 0.0))) / (2.0 * np.maximum(qa, 1e-300))
        out[:, k] = a + np.clip(t, 0.0, 1.0)[:, None] * d
        after = reach - 1
    return out


def _push_out(nodes, collider, clearance):
    """Walk each strand from node 2 on: a node closer than `clearance` [m] to the collider moves
    out along the SDF gradient, its edge keeps its length, and the rest of the strand follows
    rigidly (so waves and curls keep their shape). The root edge is never moved."""
    for k in range(2, nodes.shape[1]):
        p = nodes[:, k]
        phi = collider.sample(p)
        inside = phi < clearance
        if not inside.any():
            continue
        g = collider.gradient(p[inside])
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        target = p[inside] + (clearance - phi[inside])[:, None] * g
        prev = nodes[inside, k - 1]
        edge = np.linalg.norm(nodes[inside, k] - prev, axis=1, keepdims=True)
        step = target - prev
        new = prev + edge * step / np.maximum(np.linalg.norm(step, axis=1, keepdims=True), 1e-12)
        nodes[inside, k:] += (new - p[inside])[:, None]
    return nodes


def scalp_groom(head: HeadModel, n_guides: int, *, style: str = "straight", length: float = 0.25,
                length_variation: float = 0.1, n_nodes: int = 32, comb=(0.0, -1.0, 0.0),
                comb_strength: float = 1.0, droop_length: float = 0.08, wave_amplitude: float = 0.008,
                wave_wavelength: float = 0.05, curl_radius: float = 0.008, curl_pitch: float = 0.025,
                shape_variation: float = 0.15, root_offset: float = 0.0005, collider=None,
                clearance: float = 0.002, seed: int = 0) -> Groom:
    """A groom of n_guides strands rooted on the scalp (roots from `sample_scalp(head, n_guides,
    seed=seed)`), each with n_nodes nodes.

    length [m], varied per strand by a uniform factor 1 +- length_variation (relative, [0, 1)).
    Growth direction at the root: normalise(normal + comb_strength * comb projected on the
    tangent plane); along arc length s the direction turns to normalise(down + comb) by a
    smoothstep over droop_length [m] (down = -z). style: "straight"; "wavy" (sideways sine of
    wave_amplitude [m], wave_wavelength [m]); "curly" (helix of curl_radius [m], curl_pitch [m]
    of centreline per turn about the centreline). Amplitude/radius and wavelength/pitch vary per
    strand by 1 +- shape_variation, with a random phase. Waves and curls start after the root
    edge, which leaves the scalp along the growth direction from root_offset [m] above it.
    collider: optional `taichi_hair.world.sdf.SignedDistanceGrid` of the head: the centreline slides
    over it (kept clearance plus the wave or curl amplitude away), and any node past the root
    edge still closer than clearance [m] is pushed out. seed: roots, lengths and shapes.
    """
    choice("style", style, STYLES)
    integer("n_nodes", n_nodes, low=3)
    real("length", length, "m", low=0.0, low_open=True)
    real("length_variation", length_variation, "(relative)", low=0.0, high=0.95)
    real("comb_strength", comb_strength, "", low=0.0)
    real("droop_length", droop_length, "m", low=0.0, low_open=True)
    real("root_offset", root_offset, "m", low=0.0)
    real("clearance", clearance, "m", low=0.0)
    real("shape_variation", shape_variation, "(relative)", low=0.0, high=0.9)
    for name, value in (("wave_amplitude", wave_amplitude), ("wave_wavelength", wave_wavelength),
                        ("curl_radius", curl_radius), ("curl_pitch", curl_pitch)):
        real(name, value, "m", low=0.0, low_open=name != "wave_amplitude")
    comb = vector3("comb", comb, normalise=True)
    if collider is not None and not all(hasattr(collider, a) for a in ("sample", "gradient")):
        raise ValueError(f"collider must be a SignedDistanceGrid or None, got {type(collider).__name__}")
    inputs = (head, n_guides, style, length, length_variation, n_nodes, comb, comb_strength, droop_length,
              wave_amplitude, wave_wavelength, curl_radius, curl_pitch, shape_variation, root_offset,
              collider, clearance, seed)
    nodes = cached_arrays("scalp_groom", inputs, lambda: {"nodes": _grow(*inputs)})["nodes"]
    return Groom.from_polylines(nodes)


def _grow(head, n_guides, style, length, length_variation, n_nodes, comb, comb_strength, droop_length,
          wave_amplitude, wave_wavelength, curl_radius, curl_pitch, shape_variation, root_offset,
          collider, clearance, seed):
    """scalp_groom's nodes [S, n_nodes, 3] m from its validated arguments."""
    roots, normals = sample_scalp(head, n_guides, seed=seed)
    rng = np.random.default_rng([seed, 1])  # a stream apart from the root sampling
    lengths = length * (1.0 + length_variation * rng.uniform(-1.0, 1.0, n_guides))
    tangent_comb = comb - (normals @ comb)[:, None] * normals
    growth = normals + comb_strength * tangent_comb
    growth /= np.linalg.norm(growth, axis=1, keepdims=True)
    flow = np.array([0.0, 0.0, -1.0]) + comb
    flow = np.tile(flow / np.linalg.norm(flow), (n_guides, 1)) if np.linalg.norm(flow) > 1e-6 else growth
    edge = lengths / (n_nodes - 1)
    params = dict(start=1.5 * edge, ramp=np.maximum(0.02, 2.0 * edge)[:, None], variation=shape_variation,
                  wave_amplitude=wave_amplitude, wave_wavelength=wave_wavelength,
                  curl_radius=curl_radius, curl_pitch=curl_pitch)
    stretch = {"straight": 1.0, "wavy": math.hypot(1.0, 2 * math.pi * wave_amplitude / wave_wavelength),
               "curly": math.hypot(1.0, 2 * math.pi * curl_radius / curl_pitch)}[style]
    stretch *= (1.0 + shape_variation) / (1.0 - shape_variation) if style != "straight" else 1.0
    samples = int(min(64 * n_nodes * stretch, 8192))
    base = roots + root_offset * normals
    amplitude = {"straight": 0.0, "wavy": wave_amplitude, "curly": curl_radius}[style] * (1.0 + shape_variation)
    centre, s, d, side = _centrelines(base, growth, flow, lengths * stretch * 1.05 + 0.1, droop_length, samples,
                                      collider, clearance + amplitude, 1.5 * edge)
    curve = centre + _offsets(style, s, d, side, params, rng)
    nodes = _resample(curve, lengths, n_nodes)
    if collider is not None:
        nodes = _push_out(nodes, collider, clearance)
    return nodes
