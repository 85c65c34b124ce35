"""Dense hair from guide strands.

Setup (once): the scalp chart, the Delaunay triangulation of the guide roots and the location of
every dense root in it come from `taichi_hair.hair.scalp`; each dense root also gets its nearest
guide for clumping and seeded per-strand variation, or, when rest shapes are given, its rest
edges and the guides' rest frames (see `Interpolator`).

Per frame (Taichi, ndarray arguments so each kernel compiles once per process; the head pose
travels as a [4] vec3 ndarray, rows of R then t, never as a scalar matrix argument, whose
type could be fixed at float32 before `taichi_hair.init` chose the precision):
  1. `guide_frames`: Bishop frame of every guide edge by parallel transport from the root
     (one thread per guide: the transport is serial along the strand); for an imported style
     built with the guides' material directors, `director_frames` (edge and director) instead.
  2. `dense_nodes`: one thread per dense strand: barycentric interpolation of the three guides'
     root-relative shapes, clump interpolation (one guide plus an offset carried in its Bishop
     frame, so it follows the guide's bending and twist), the per-strand blend of both, and
     frizz growing toward the tip.
     With rest shapes (an imported style), `dense_from_edges` replaces it: one thread per
     dense strand: each rest edge turned by the blend of the rotations of the same edge of its
     guides (the clump guide and the triangle's three; `guide_rotations` gives them as unit
     quaternions, one thread per guide edge) and laid end to end from the root.
  3. `push_out_of_ellipsoid`: one thread per node: nodes closer to the head than a margin move
     out along the surface normal (only when the head is a sphere or ellipsoid).

Positions are metres; arrays are [strand, node, xyz]; node 0 is the root.
"""

import math
import time

import numpy as np
import taichi as ti

from ..runtime import ensure_init, precision
from .interpolate_inputs import (check_directors, check_head, check_rest, check_rotation, check_setup,
                                 strand_variation)
from .interpolate_kernels import (dense_from_edges, dense_nodes, director_frames, guide_frames, guide_rotations,
                                  ivec5, push_out_of_ellipsoid, vec3, vec4)
from .scalp import (ScalpChart, delaunay, locate, nearest, perpendicular,  # noqa: F401
                    sample_scalp_roots)


# ---------------------------------------------------------------- the interpolator

class Interpolator:
    """Dense strands [D, n_nodes] from guides [G, n_nodes] (all in metres).

    guide_roots, guide_normals: [G, 3] rest root positions and outward scalp normals (G >= 3).
    dense_roots: [D, 3] rest root positions of the dense strands on the scalp.
    mode: "barycentric" (three guides of the enclosing triangle), "clump" (nearest guide plus
        the root offset carried in its Bishop frame) or "blend" (per-strand mix, `blend`).
    blend: weight of the clump result in [0, 1], a scalar or an array [D] (mode "blend" only).
    clump_radius: distance [m] from its guide a clumped strand narrows to at the tip (None:
        keep the root offset all along).
    frizz: mean amplitude [m] of per-node noise at the tip (grows as (i / (N-1))^2; per-strand
        amplitude uniform in [0.5, 1.5] x frizz), fixed across frames.
    length_variation: strands are shortened by a factor uniform in [1 - length_variation, 1]
        (in [0, 1)); curl_phase_variation: each strand starts up to this many edges into the
        guides' shape (in [0, (n_nodes - 1) / 2]), which shifts the phase of curls.
    seed: seeds all per-strand variation.
    Keep clump offsets (root spacing, clump_radius) well below the guides' radius of curvature:
    an offset d carried in the frame of a curve of curvature k scales the strand's curvature
    by 1 / (1 - k d cos(angle)), so a clump wider than a curl is no longer a ringlet.
    head: None; a sphere or ellipsoid (centre [3] m, radius m or semi-axes [3] m, axis-aligned
        at rest), which pushes non-root nodes out to its surface + head_margin [m] in a kernel;
        or a callable mapping points [M, 3] to pushed points [M, 3] (runs on the host).
    rest_guides [G, n_nodes, 3], rest_shapes [D, n_nodes, 3] (m), given together: the guides'
        rest positions and the shapes the dense strands must have when the guides are there
        (an imported hairstyle). The root is placed as in the modes above; every rest edge j
        then turns as edge j of the strand's guides turns (the rotation of their frames
        from rest, Bishop frames or with rest_directors material frames, blended with the
        mode's weights) and keeps its rest length, and the
        edges are laid end to end: at rest the output is rest_shapes (to round-off), a rigid
        head motion moves it rigidly, and dense strands are inextensible however far they lie
        from their guides. Node 0 of rest_shapes must be dense_roots (within 1e-6 m); frizz,
        length_variation, curl_phase_variation and clump_radius do not apply. A head collider
        still acts on top: rest nodes within head_margin of it are moved.
    rest_directors [G, n_nodes - 1, 3] (with rest shapes only): the guides' first material
        directors at rest (`Simulator.material_directors()` before the first step). The edges
        then turn with the guides' material frames (edge tangent, director) instead of Bishop
        frames recomputed from the positions, and every `interpolate` call takes the guides'
        directors now (`directors=`). A Bishop frame transported along a bent wavy guide spins
        about the edges by tens of degrees per edge relative to its rest (the holonomy of the
        changed curve), and that spin swings the dense strands' own waves into kinks; the
        material frame turns only as far as the guide is strained. `style_interpolator` sets
        this up from a simulator.
    """

    def __init__(self, guide_roots, guide_normals, dense_roots, n_nodes, *, mode="blend",
                 blend=0.5, clump_radius=None, frizz=0.0, length_variation=0.0,
                 curl_phase_variation=0.0, seed=0, head=None, head_margin=0.002,
                 rest_guides=None, rest_shapes=None, rest_directors=None):
        ensure_init()
        roots, normals, dense = check_setup(guide_roots, guide_normals, dense_roots, n_nodes)
        self.n_guides, self.n_dense, self.n_nodes = len(roots), len(dense), int(n_nodes)
        rest = check_rest(rest_guides, rest_shapes, roots, dense, self.n_nodes)
        if rest_directors is not None and rest is None:
            raise ValueError("rest_directors needs rest_guides and rest_shapes (it describes the rest guides)")
        varied = frizz or length_variation or curl_phase_variation or clump_radius is not None
        if rest is not None and varied:
            raise ValueError("frizz, length_variation, curl_phase_variation and clump_radius must keep "
                             "their defaults with rest_shapes (the rest shapes fix every strand)")
        self._head, self._ellipsoid = check_head(head, head_margin)
        self._dtype = np.float32 if precision() == "float32" else np.float64
        centre = None if self._ellipsoid is None else self._ellipsoid[0]
        chart = ScalpChart.fit(roots, normals, centre)
        try:
            self.triangles = delaunay(chart.project(roots, "guide_roots"))
        except ValueError as exc:
            raise ValueError(f"guide_roots cannot be triangulated on the scalp: {exc}") from None
        tri_of, self.weights = locate(chart.project(dense, "dense_roots"), chart.project(roots),
                                      self.triangles)
        self.corners, self.guide_of = self.triangles[tri_of], nearest(dense, roots)
        par, keys = strand_variation(self.n_dense, self.n_nodes, mode, blend, clump_radius, frizz,
                               length_variation, curl_phase_variation, seed,
                               np.linalg.norm(dense - roots[self.guide_of], axis=1))
        self._upload_strands(roots, normals, dense, par, keys)
        self._pose = _upload(np.vstack([np.eye(3), np.zeros(3)]), vec3, (4,), self._dtype)
        if self._ellipsoid is not None:
            c, r = self._ellipsoid
            self._shape = _upload([c, r, (float(head_margin), 0.0, 0.0)], vec3, (3,), self._dtype)
        g, d, n = self.n_guides, self.n_dense, self.n_nodes
        self._t, self._u = ti.ndarray(vec3, (g, n - 1)), ti.ndarray(vec3, (g, n - 1))
        self._out = ti.ndarray(vec3, (d, n))
        self._edges, self._directors = None, None
        if rest is not None:
            self._fit_rest_edges(*rest, rest_directors)

    @property
    def needs_directors(self) -> bool:
        """True when built with rest_directors: `interpolate` then needs the guides' directors."""
        return self._directors is not None

    def _upload_strands(self, roots, normals, dense, par, keys):
        """Upload the per-strand geometry and parameters (see `dense_nodes`)."""
        d, g = self.n_dense, self.n_guides
        u_rest = perpendicular(normals)
        offset = dense - roots[self.guide_of]
        frame = np.stack([u_rest, np.cross(normals, u_rest), normals], axis=1)[self.guide_of]
        local = np.einsum("dj,dkj->dk", offset, frame)  # offset in the guide's (u, v, normal)
        rel = dense[:, None, :] - roots[np.concatenate([self.corners, self.guide_of[:, None]], axis=1)]
        self._w = _upload(self.weights, vec3, (d,), self._dtype)
        self._rel = _upload(rel, vec3, (d, 4), self._dtype)
        self._local = _upload(local, vec3, (d,), self._dtype)
        self._normal = _upload(normals, vec3, (g,), self._dtype)
        self._u_rest = _upload(u_rest, vec3, (g,), self._dtype)
        self._idx = _upload(np.concatenate([self.corners, self.guide_of[:, None], keys[:, None]], axis=1),
                            ivec5, (d,), np.int32)
        self._par = ti.ndarray(float, (d, 5))  # `float` resolves to the precision now, not at import
        self._par.from_numpy(np.ascontiguousarray(par, dtype=self._dtype))

    def _fit_rest_edges(self, rest_guides, rest_shapes, rest_directors):
        """Store the dense rest edges [D, n_nodes - 1] and the guides' rest frames (material
        frames with rest_directors, else Bishop frames)."""
        g, n = self.n_guides, self.n_nodes
        self._t_rest, self._u_rest_frames = ti.ndarray(vec3, (g, n - 1)), ti.ndarray(vec3, (g, n - 1))
        if rest_directors is None:
            guide_frames(self._guides_in(rest_guides), self._normal, self._u_rest, self._pose,
                          self._t_rest, self._u_rest_frames)  # the pose is still the identity
        else:
            self._directors = ti.ndarray(vec3, (g, n - 1))
            self._directors.from_numpy(check_directors("rest_directors", rest_directors, rest_guides,
                                                       self._dtype))
            director_frames(self._guides_in(rest_guides), self._directors, self._t_rest,
                             self._u_rest_frames)
        self._edges = _upload(np.diff(rest_shapes, axis=1), vec3, (self.n_dense, n - 1), self._dtype)
        self._q = ti.ndarray(vec4, (g, n - 1))

    def interpolate(self, guide_positions, head_rotation=None, head_translation=None, out=None,
                    directors=None):
        """Dense node positions [D, n_nodes, 3] (m) as numpy.

        guide_positions: numpy [G, n_nodes, 3] (m) or a ti.ndarray of vec3 [G, n_nodes] in this
            process's precision. Node 0 is the root.
        head_rotation [3, 3], head_translation [3] (m): the head's rigid motion from rest
            (default identity); it carries the root frames and the head collider.
        out: optional numpy [D, n_nodes, 3] of this precision's dtype to fill (else a new array).
        directors [G, n_nodes - 1, 3]: the guides' material directors now
            (`Simulator.material_directors()`); required when built with rest_directors,
            ignored otherwise.
        On the CPU the kernels write straight into the numpy array (no copy)."""
        shape = (self.n_dense, self.n_nodes, 3)
        if out is None:
            out = np.empty(shape, dtype=self._dtype)
        elif not (isinstance(out, np.ndarray) and out.shape == shape and out.dtype == self._dtype
                  and out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous {np.dtype(self._dtype).name} array "
                             f"{list(shape)}, got {getattr(out, 'dtype', None)} {list(np.shape(out))}")
        self._run(guide_positions, out, head_rotation, head_translation, directors)
        if self._head is not None:
            out[:, 1:] = self._collide_on_host(out[:, 1:])
        return out

    def interpolate_ndarray(self, guide_positions, head_rotation=None, head_translation=None,
                            directors=None):
        """As `interpolate`, into this interpolator's ti.ndarray of vec3 [D, n_nodes] (m), which
        stays on the device and is overwritten by the next call. A callable head collider makes
        a round trip through numpy."""
        self._run(guide_positions, self._out, head_rotation, head_translation, directors)
        if self._head is not None:
            pts = self._out.to_numpy()
            pts[:, 1:] = self._collide_on_host(pts[:, 1:])
            self._out.from_numpy(pts)
        return self._out

    def _run(self, guide_positions, out, head_rotation, head_translation, directors):
        x = self._guides_in(guide_positions)
        if self._directors is not None:
            if directors is None:
                raise ValueError("directors must be given: this interpolator was built with rest_directors "
                                 "(pass directors=simulator.material_directors())")
            self._directors.from_numpy(check_directors("directors", directors, None, self._dtype,
                                                       (self.n_guides, self.n_nodes - 1)))
        rot = check_rotation(head_rotation)
        trans = np.zeros(3) if head_translation is None else np.asarray(head_translation, np.float64)
        if trans.shape != (3,) or not np.all(np.isfinite(trans)):
            raise ValueError(f"head_translation must be 3 finite numbers (m), got {head_translation!r}")
        self._pose.from_numpy(np.vstack([rot, trans]).astype(self._dtype))
        if self._directors is None:
            guide_frames(x, self._normal, self._u_rest, self._pose, self._t, self._u)
        else:
            director_frames(x, self._directors, self._t, self._u)
        if self._edges is None:
            dense_nodes(x, self._t, self._u, self._idx, self._w, self._rel, self._local, self._par,
                         self._pose, out)
        else:
            guide_rotations(self._t, self._u, self._t_rest, self._u_rest_frames, self._q)
            dense_from_edges(x, self._q, self._idx, self._w, self._rel, self._par, self._pose, self._edges,
                              out)
        if self._ellipsoid is not None:
            push_out_of_ellipsoid(out, self._pose, self._shape)

    def _collide_on_host(self, pts):
        moved = np.asarray(self._head(pts.reshape(-1, 3)), dtype=pts.dtype)
        if moved.shape != (pts.size // 3, 3):
            raise ValueError(f"head collider must return an array [M, 3] like its input [{pts.size // 3}, 3], "
                             f"got {list(moved.shape)}")
        return moved.reshape(pts.shape)

    def _guides_in(self, guide_positions):
        want = (self.n_guides, self.n_nodes)
        if isinstance(guide_positions, ti.Ndarray):
            if tuple(guide_positions.shape) != want:
                raise ValueError(f"guide_positions must have shape {list(want)} (vec3), got "
                                 f"{list(guide_positions.shape)}")
            return guide_positions
        arr = np.asarray(guide_positions)
        if arr.shape != want + (3,):
            raise ValueError(f"guide_positions must have shape {list(want + (3,))}, got {list(arr.shape)}")
        if not np.all(np.isfinite(arr)):
            raise ValueError("guide_positions must be finite, got NaN or inf")
        return np.ascontiguousarray(arr, dtype=self._dtype)


def _upload(array, dtype, shape, np_dtype):
    nd = ti.ndarray(dtype, shape)
    nd.from_numpy(np.ascontiguousarray(np.asarray(array).reshape(shape + (-1,)), dtype=np_dtype))
    return nd

# ---------------------------------------------------------------- small helpers and benchmark

def _curly_guides(roots, normals, n_nodes, length=0.2, curl_radius=0.01, pitch=0.02):
    """Helices [G, n_nodes, 3] (m) growing along the normals from the roots (benchmark data)."""
    rise = pitch / (2 * math.pi)
    s = (np.linspace(0.0, length, n_nodes) / math.hypot(curl_radius, rise))[None, :, None]
    side = perpendicular(normals)[:, None]
    return (roots[:, None] + curl_radius * (np.cos(s) - 1.0) * side + rise * s * normals[:, None]
            + curl_radius * np.sin(s) * np.cross(normals[:, None], side))


def bench_interpolation(n_dense=100_000, n_nodes=32, n_guides=1000, repeats=5) -> dict:
    """Time one interpolation frame (blend mode, frizz, sphere head). Returns setup seconds,
    first-call seconds (kernel compilation included), compile seconds (first call minus a
    steady frame) and the median ms per frame over `repeats` after a warm-up, both for the
    ti.ndarray result and with the copy to numpy."""
    ensure_init()
    g_roots, g_normals = sample_scalp_roots(n_guides)
    d_roots, _ = sample_scalp_roots(n_dense)
    guides = _curly_guides(g_roots, g_normals, n_nodes)
    start = time.perf_counter()
    interp = Interpolator(g_roots, g_normals, d_roots, n_nodes, mode="blend", blend=0.5,
                          clump_radius=0.003, frizz=0.001, length_variation=0.1,
                          head=((0.0, 0.0, 0.0), 0.1))
    setup = time.perf_counter() - start

    def frame(numpy):
        t0 = time.perf_counter()
        out = interp.interpolate(guides) if numpy else interp.interpolate_ndarray(guides)
        ti.sync()
        return time.perf_counter() - t0, out

    first, _ = frame(False)
    frame(True)
    device = float(np.median([frame(False)[0] for _ in range(repeats)]))
    host = float(np.median([frame(True)[0] for _ in range(repeats)]))
    return {"n_dense": n_dense, "n_nodes": n_nodes, "n_guides": n_guides,
            "precision": precision(), "setup_s": setup, "first_call_s": first,
            "compile_s": max(first - device, 0.0), "ms_per_frame_ndarray": 1e3 * device,
            "ms_per_frame_numpy": 1e3 * host}


def _main(argv=None):
    from ..runtime import init
    from ..validation import cli_int, one_line_parser_class
    parser = one_line_parser_class()(description="Benchmark dense hair interpolation.")
    for name, default, low, high in (("n-dense", 100_000, 1, 10_000_000), ("n-nodes", 32, 3, 10_000),
                                     ("n-guides", 1000, 1, 1_000_000), ("repeats", 5, 1, 1000)):
        parser.add_argument(f"--{name}", type=cli_int(f"--{name}", low, high), default=default)
    parser.add_argument("--arch", default="cpu")
    parser.add_argument("--precision", default="float32", choices=["float32", "float64"])
    args = parser.parse_args(argv)
    init(args.arch, args.precision)
    result = bench_interpolation(args.n_dense, args.n_nodes, args.n_guides, args.repeats)
    width = max(len(k) for k in result)
    for key, value in result.items():
        print(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}")


if __name__ == "__main__":
    _main()
