"""Hair files: Cem Yuksel's binary `.hair` format and OBJ polylines.

`.hair` (cemyuksel.com/research/hairmodels), little-endian:

    128-byte header: char[4] "HAIR", uint32 strands, uint32 points, uint32 flags,
                     uint32 default segments, float32 default thickness,
                     float32 default transparency, float32[3] default colour, char[88] info
    then the arrays whose flag bit is set, in this order:
      bit 0  segments      uint16  [strands]     (points per strand - 1)
      bit 1  points        float32 [points, 3]
      bit 2  thickness     float32 [points]
      bit 3  transparency  float32 [points]
      bit 4  colour        float32 [points, 3]

The format has no unit: check a model's extent (Yuksel's published models are head-sized in
centimetre-scale units) and scale to the metres the simulator uses with
`HairFile.strands(scale=0.01)`; no axis convention is imposed either. Readers keep the
float32 values and the raw header bytes as stored, so `write_hair(read_hair(f))` rewrites `f`
byte for byte.

Any file that does not follow the format exactly raises `HairFileError` naming the file and the
problem; the reader checks every count the header promises against the file size before reading
or allocating any array, so a corrupt count cannot make it allocate or read past the end, and it
reads regular files only (a device such as /dev/zero is refused). Both readers also refuse
non-finite values (points, per-point arrays, the header's defaults) and coordinates beyond
+-MAX_COORDINATE (1e6 file units). Writers raise HairFileError naming the path for anything the
operating system refuses (a missing directory, no permission, a full disk).
"""

from dataclasses import dataclass, field
import os
import stat
import struct

import numpy as np

SIGNATURE = b"HAIR"
HEADER_SIZE = 128
INFO_SIZE = 88
_HEADER = struct.Struct("<4sIIII f f 3f 88s")
assert _HEADER.size == HEADER_SIZE  # layout constant, not user input

SEGMENTS_BIT, POINTS_BIT, THICKNESS_BIT, TRANSPARENCY_BIT, COLOUR_BIT = 1, 2, 4, 8, 16
_KNOWN_BITS = SEGMENTS_BIT | POINTS_BIT | THICKNESS_BIT | TRANSPARENCY_BIT | COLOUR_BIT
MAX_SEGMENTS = 65535  # segments are stored as uint16
MAX_COORDINATE = 1e6  # file units: 10 km in centimetres; beyond it float32 distances lose the hair


class HairFileError(ValueError):
    """A hair file that cannot be read or written; the message names the file and the problem."""


@dataclass(eq=False)
class HairFile:
    """Contents of a `.hair` file, in file units (see the module docstring).

    points: float32 [P, 3], every strand's nodes one after the other, root first.
    counts: int64 [S], nodes per strand (>= 2); sum(counts) == P.
    thickness, transparency: float32 [P] or None (then the defaults apply to every point).
    colour: float32 [P, 3] or None (RGB in [0, 1] by convention, not enforced).
    default_segments, default_thickness, default_transparency, default_colour: header values.
    info: the 88 raw info bytes of the header (text, NUL-padded); see `info_text`.
    has_segments: whether the file stores the segments array; without it every strand has
        default_segments + 1 nodes.
    """

    points: np.ndarray
    counts: np.ndarray
    thickness: np.ndarray | None = None
    transparency: np.ndarray | None = None
    colour: np.ndarray | None = None
    default_segments: int = 0
    default_thickness: float = 1.0
    default_transparency: float = 0.0
    default_colour: tuple = (1.0, 1.0, 1.0)
    info: bytes = field(default=b"\0" * INFO_SIZE)
    has_segments: bool = True

    @property
    def n_strands(self) -> int:
        return int(len(self.counts))

    @property
    def info_text(self) -> str:
        """The info field up to its first NUL, decoded as Latin-1 (never fails)."""
        return self.info.split(b"\0", 1)[0].decode("latin-1")

    def offsets(self) -> np.ndarray:
        """Index of each strand's first point in `points`, int64 [S + 1] (last = P)."""
        return np.concatenate([[0], np.cumsum(self.counts, dtype=np.int64)])

    def strands(self, scale: float = 1.0) -> list:
        """Strands as a list of float64 [N_i, 3] arrays, multiplied by `scale` (0.01: cm to m)."""
        o = self.offsets()
        pts = self.points.astype(np.float64) * scale
        return [pts[o[s]:o[s + 1]] for s in range(self.n_strands)]

    @classmethod
    def from_strands(cls, strands, *, thickness=None, transparency=None, colour=None,
                     info: str = "", default_thickness: float = 1.0,
                     default_transparency: float = 0.0, default_colour=(1.0, 1.0, 1.0)) -> "HairFile":
        """HairFile from a list of [N_i, 3] arrays (or an [S, N, 3] array); per-point arrays are
        flat over all points ([P] or [P, 3]). Stores a segments array unless all strands have the
        same node count."""
        strands = [np.asarray(s, dtype=np.float32) for s in strands]
        for i, s in enumerate(strands):
            if s.ndim != 2 or s.shape[1] != 3:
                raise ValueError(f"strands[{i}] must have shape [N, 3], got {s.shape}")
        counts = np.array([len(s) for s in strands], dtype=np.int64)
        points = np.concatenate(strands) if strands else np.zeros((0, 3), np.float32)
        uniform = len(counts) > 0 and bool(np.all(counts == counts[0]))
        text = info.encode("latin-1")
        if len(text) >= INFO_SIZE:
            raise ValueError(f"info must be at most {INFO_SIZE - 1} Latin-1 characters, got {len(text)}")

        def opt(a, shape):
            return None if a is None else np.asarray(a, dtype=np.float32).reshape(shape)
        return cls(points, counts, opt(thickness, (-1,)), opt(transparency, (-1,)), opt(colour, (-1, 3)),
                   default_segments=int(counts[0] - 1) if uniform else 0,
                   default_thickness=float(default_thickness),
                   default_transparency=float(default_transparency),
                   default_colour=tuple(float(c) for c in default_colour),
                   info=text.ljust(INFO_SIZE, b"\0"), has_segments=not uniform)


def read_hair(path) -> HairFile:
    """Read a `.hair` file; raises HairFileError naming `path` and the problem. Every count in
    the header is checked against the file's size before anything is allocated, and only
    regular files are read (a device such as /dev/zero is refused, not read forever)."""
    path = os.fspath(path)
    try:
        with open(path, "rb") as f:
            size = _regular_file_size(path, f)
            header = f.read(HEADER_SIZE)
            if len(header) < HEADER_SIZE:
                raise HairFileError(f"{path}: truncated header: the file has {len(header)} bytes, "
                                    f"a .hair header needs {HEADER_SIZE}")
            (sig, n_strands, n_points, flags, d_seg, d_thick, d_transp, c0, c1, c2,
             info) = _HEADER.unpack(header)
            _check_header(path, size, sig, n_strands, n_points, flags, d_seg)
            data = header + f.read(size - HEADER_SIZE)
    except OSError as exc:
        raise HairFileError(f"{path}: cannot read the file ({exc.strerror or exc})") from exc
    if len(data) != size:
        raise HairFileError(f"{path}: the file changed size while being read")
    layout = _layout(flags, n_strands, n_points)
    arrays, offset = {}, HEADER_SIZE
    for name, dtype, size in layout:
        arrays[name] = np.frombuffer(data, dtype=dtype, count=size // np.dtype(dtype).itemsize,
                                     offset=offset).copy()
        offset += size
    if "segments" in arrays:
        counts = arrays["segments"].astype(np.int64) + 1
    else:
        counts = np.full(n_strands, d_seg + 1, dtype=np.int64)
    hair = HairFile(arrays["points"].reshape(-1, 3), counts, arrays.get("thickness"),
                    arrays.get("transparency"),
                    None if "colour" not in arrays else arrays["colour"].reshape(-1, 3),
                    default_segments=d_seg, default_thickness=d_thick,
                    default_transparency=d_transp, default_colour=(c0, c1, c2), info=info,
                    has_segments="segments" in arrays)
    problem = _check(hair, n_points)
    if problem:
        raise HairFileError(f"{path}: {problem}")
    return hair


def write_hair(path, hair) -> None:
    """Write `hair` (a HairFile, or a list of [N_i, 3] strands) to `path` as a `.hair` file.

    Raises HairFileError naming `path` if the data cannot be stored in the format (strands with
    fewer than 2 or more than 65536 nodes, non-finite values, array sizes that disagree) or
    the operating system refuses the write (OSError)."""
    path = os.fspath(path)
    if not isinstance(hair, HairFile):
        hair = HairFile.from_strands(hair)
    counts = np.asarray(hair.counts, dtype=np.int64)
    points = np.asarray(hair.points, dtype=np.float32).reshape(-1, 3)
    problem = _check(HairFile(points, counts, hair.thickness, hair.transparency, hair.colour,
                              hair.default_segments, hair.default_thickness, hair.default_transparency,
                              tuple(hair.default_colour), has_segments=hair.has_segments), len(points))
    if problem is None and len(hair.info) != INFO_SIZE:
        problem = f"info must be exactly {INFO_SIZE} bytes, got {len(hair.info)}"
    if problem:
        raise HairFileError(f"{path}: cannot write: {problem}")
    flags = POINTS_BIT
    chunks = [points.astype("<f4").tobytes()]
    if hair.has_segments:
        flags |= SEGMENTS_BIT
        chunks.insert(0, (counts - 1).astype("<u2").tobytes())
    for bit, arr in ((THICKNESS_BIT, hair.thickness), (TRANSPARENCY_BIT, hair.transparency),
                     (COLOUR_BIT, hair.colour)):
        if arr is not None:
            flags |= bit
            chunks.append(np.asarray(arr, dtype="<f4").tobytes())
    header = _HEADER.pack(SIGNATURE, len(counts), len(points), flags, int(hair.default_segments),
                          float(hair.default_thickness), float(hair.default_transparency),
                          *(float(c) for c in hair.default_colour), bytes(hair.info))
    try:
        with open(path, "wb") as f:
            f.write(header)
            for chunk in chunks:
                f.write(chunk)
    except OSError as exc:
        raise HairFileError(f"{path}: cannot write the file ({exc.strerror or exc})") from exc


def _regular_file_size(path, f) -> int:
    """Size [bytes] of the open file f, or HairFileError when it is not a regular file."""
    info = os.fstat(f.fileno())
    if not stat.S_ISREG(info.st_mode):
        raise HairFileError(f"{path}: not a regular file (a device, pipe or directory); "
                            f"give the path of a .hair file")
    return info.st_size


def _check_header(path, size, sig, n_strands, n_points, flags, d_seg):
    """Raise HairFileError unless the header's signature, flags and counts fit a file of `size`
    bytes: checked with Python integers before any array is allocated."""
    if sig != SIGNATURE:
        raise HairFileError(f"{path}: bad signature {sig!r}, expected {SIGNATURE!r}: not a .hair file")
    if flags & ~_KNOWN_BITS:
        raise HairFileError(f"{path}: unknown flag bits {flags & ~_KNOWN_BITS:#x} in the header "
                            f"(flags {flags:#x}); only bits 0-4 are defined")
    if not flags & POINTS_BIT:
        raise HairFileError(f"{path}: the header has no points array (flags {flags:#x}); nothing to load")
    expected = HEADER_SIZE + sum(n for _, _, n in _layout(flags, n_strands, n_points))
    if size < expected:
        raise HairFileError(f"{path}: truncated arrays: the header promises {n_strands} strands and "
                            f"{n_points} points ({expected} bytes), the file has {size} bytes")
    if size > expected:
        raise HairFileError(f"{path}: the file has {size - expected} bytes more than the header "
                            f"describes ({expected} bytes for {n_strands} strands, {n_points} points)")
    if 2 * n_strands > n_points:
        raise HairFileError(f"{path}: the header promises {n_strands} strands but only {n_points} "
                            f"points; every strand needs at least 2 points")
    if not flags & SEGMENTS_BIT and n_strands * (d_seg + 1) != n_points:
        raise HairFileError(f"{path}: without a segments array every strand has default_segments + 1 = "
                            f"{d_seg + 1} points: {n_strands} strands need {n_strands * (d_seg + 1)} "
                            f"points, the header gives {n_points}")


def _layout(flags, n_strands, n_points):
    """(name, little-endian dtype, byte size) of each array present, in file order."""
    table = ((SEGMENTS_BIT, "segments", "<u2", n_strands), (POINTS_BIT, "points", "<f4", 3 * n_points),
             (THICKNESS_BIT, "thickness", "<f4", n_points),
             (TRANSPARENCY_BIT, "transparency", "<f4", n_points),
             (COLOUR_BIT, "colour", "<f4", 3 * n_points))
    return [(name, dt, n * np.dtype(dt).itemsize) for bit, name, dt, n in table if flags & bit]


def _check(hair, n_points):
    """The first inconsistency in `hair` as a sentence, or None when it is a valid hair file."""
    counts = hair.counts
    if counts.ndim != 1:
        return f"counts must be one-dimensional, got shape {counts.shape}"
    if not hair.has_segments and len(counts) and np.any(counts != hair.default_segments + 1):
        return (f"without a segments array every strand must have default_segments + 1 = "
                f"{hair.default_segments + 1} points")
    if len(counts) and (counts.min() < 2 or counts.max() > MAX_SEGMENTS + 1):
        bad = int(np.flatnonzero((counts < 2) | (counts > MAX_SEGMENTS + 1))[0])
        return (f"strand {bad} has {int(counts[bad])} points; every strand needs 2 to "
                f"{MAX_SEGMENTS + 1} points")
    defaults = (hair.default_thickness, hair.default_transparency, *hair.default_colour)
    if not all(np.isfinite(np.float64(v)) for v in defaults):
        return (f"the header's default thickness, transparency and colour must be finite, got "
                f"{hair.default_thickness}, {hair.default_transparency}, {tuple(hair.default_colour)}")
    total = int(counts.sum())
    if total != n_points:
        return (f"the strand point counts (segments + 1) add up to {total} but the file holds "
                f"{n_points} points")
    for name, arr, width in (("points", hair.points, 3), ("thickness", hair.thickness, 1),
                             ("transparency", hair.transparency, 1), ("colour", hair.colour, 3)):
        if arr is None:
            continue
        if arr.size != width * n_points:
            return f"{name} has {arr.size} values, expected {width * n_points} ({width} per point)"
        bad = np.flatnonzero(~np.isfinite(np.asarray(arr).reshape(-1)))
        if len(bad):
            p = int(bad[0] // width)
            strand = int(np.searchsorted(np.cumsum(counts), p, side="right"))
            return f"{name} of point {p} (strand {strand}) is not finite (NaN or inf)"
    return coordinate_problem(np.asarray(hair.points, dtype=np.float64).reshape(-1, 3), "point")


def coordinate_problem(points, what):
    """A sentence if a coordinate of points [P, 3] is beyond +-MAX_COORDINATE, else None."""
    big = np.flatnonzero(np.abs(points).max(axis=1, initial=0.0) > MAX_COORDINATE) if len(points) else []
    if len(big):
        return (f"{what} {int(big[0])} has coordinates {points[big[0]].tolist()}; coordinates must lie "
                f"within +-{MAX_COORDINATE:g} file units")
    return None


def read_obj_polylines(path) -> list:
    """Polylines of a Wavefront OBJ file as a list of float64 [N_i, 3] arrays.

    Reads `v x y z [w]` vertices and `l i j k ...` polyline elements (1-based indices, negative
    ones counted back from the latest vertex, `i/t` texture suffixes ignored, `\\` line
    continuation). Comments and every other statement (o, g, s, usemtl, vn, vt, f, ...) are
    skipped: faces are meshes, not hair. Raises HairFileError naming `path`, the line and the
    problem for a bad number, an index out of range, a polyline with fewer than 2 vertices or a
    non-finite vertex, and when the file holds no polyline at all.
    """
    path = os.fspath(path)
    try:
        with open(path, "r", encoding="utf-8", errors="replace") as f:
            _regular_file_size(path, f)
            text = f.read()
    except OSError as exc:
        raise HairFileError(f"{path}: cannot read the file ({exc.strerror})") from exc
    vertices, lines = [], []
    for number, line in _logical_lines(text):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        try:
            if words[0] == "v":
                xyz = [float(w) for w in words[1:4]]
                if len(xyz) != 3 or not all(np.isfinite(xyz)):
                    raise ValueError(f"vertex needs 3 finite coordinates, got {words[1:]}")
                if max(abs(c) for c in xyz) > MAX_COORDINATE:
                    raise ValueError(f"vertex coordinates must lie within +-{MAX_COORDINATE:g} file units, "
                                     f"got {words[1:4]}")
                vertices.append(xyz)
            elif words[0] == "l":
                lines.append(_polyline_indices(words[1:], len(vertices)))
        except ValueError as exc:
            raise HairFileError(f"{path}, line {number}: {exc}") from None
    if not lines:
        raise HairFileError(f"{path}: no polyline ('l') elements found")
    verts = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    return [verts[idx] for idx in lines]


def _logical_lines(text):
    """(first physical line number, joined text) for each OBJ statement."""
    pending, start = "", 0
    for number, raw in enumerate(text.splitlines(), start=1):
        if not pending:
            start = number
        stripped = raw.rstrip()
        if stripped.endswith("\\"):
            pending += stripped[:-1] + " "
            continue
        yield start, pending + raw
        pending = ""
    if pending:
        yield start, pending


def _polyline_indices(words, n_vertices):
    """0-based vertex indices of one `l` element given the vertices defined so far."""
    if len(words) < 2:
        raise ValueError(f"a polyline needs at least 2 vertices, got {len(words)}")
    idx = []
    for w in words:
        i = int(w.split("/", 1)[0])
        j = i - 1 if i > 0 else n_vertices + i
        if i == 0 or not 0 <= j < n_vertices:
            raise ValueError(f"vertex index {i} out of range: {n_vertices} vertices defined so far "
                             f"(valid: 1..{n_vertices} or -{n_vertices}..-1)")
        idx.append(j)
    return idx


def write_obj_polylines(path, strands, comment: str = "taichi_hair polylines") -> None:
    """Write strands (list of [N_i, 3] arrays, or [S, N, 3]) as OBJ `v` + `l` lines.

    Coordinates are written with 17 significant digits, so float64 values read back exactly.
    Raises HairFileError naming `path` for a strand with fewer than 2 nodes or non-finite values,
    and for an OSError while writing.
    """
    path = os.fspath(path)
    arrays = [np.asarray(s, dtype=np.float64) for s in strands]
    for i, s in enumerate(arrays):
        if s.ndim != 2 or s.shape[1] != 3 or len(s) < 2:
            raise HairFileError(f"{path}: cannot write: strand {i} must have shape [N >= 2, 3], "
                                f"got {s.shape}")
        if not np.all(np.isfinite(s)):
            raise HairFileError(f"{path}: cannot write: strand {i} has non-finite coordinates")
    out, base = [f"# {comment}\n"], 1
    for s in arrays:
        out.extend(f"v {x!r} {y!r} {z!r}\n" for x, y, z in s.tolist())
        out.append("l " + " ".join(str(base + k) for k in range(len(s))) + "\n")
        base += len(s)
    try:
        with open(path, "w", encoding="utf-8") as f:
            f.writelines(out)
    except OSError as exc:
        raise HairFileError(f"{path}: cannot write the file ({exc.strerror or exc})") from exc
