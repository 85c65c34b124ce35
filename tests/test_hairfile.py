"""`.hair` and OBJ polyline files: exact round trips, and every malformed file rejected clearly.

The reference bytes are packed here with `struct` field by field from the published layout, not
with the module's own header struct, so a layout mistake in the module cannot hide."""

import struct
import time
import tracemalloc

import numpy as np
import pytest

import taichi_hair as th
from taichi_hair.hair.hairfile import (HairFile, HairFileError, read_hair, read_obj_polylines,
                                       write_hair, write_obj_polylines)

BITS = {"segments": 1, "points": 2, "thickness": 4, "transparency": 8, "colour": 16}


def reference_bytes(counts, optional=("segments", "thickness", "transparency", "colour"), seed=0):
    """A valid .hair file built independently: header fields packed one by one."""
    rng = np.random.default_rng(seed)
    counts = np.asarray(counts)
    n_points = int(counts.sum())
    arrays = {"segments": (counts - 1).astype("<u2"),
              "points": rng.normal(size=(n_points, 3)).astype("<f4"),
              "thickness": rng.uniform(0.01, 0.1, n_points).astype("<f4"),
              "transparency": rng.uniform(0, 1, n_points).astype("<f4"),
              "colour": rng.uniform(0, 1, (n_points, 3)).astype("<f4")}
    present = ["points"] + [k for k in optional]
    flags = sum(BITS[k] for k in present)
    info = b"test model: 3 strands\0" + bytes(range(1, 67))  # bytes after the NUL must survive
    header = (b"HAIR" + struct.pack("<I", len(counts)) + struct.pack("<I", n_points)
              + struct.pack("<I", flags) + struct.pack("<I", int(counts[0]) - 1)
              + struct.pack("<f", 0.25) + struct.pack("<f", 0.5) + struct.pack("<3f", 0.1, 0.2, 0.3)
              + info)
    assert len(header) == 128
    body = b"".join(arrays[k].tobytes() for k in BITS if k in present)
    return header + body, arrays


@pytest.mark.parametrize("optional", [
    (), ("segments",), ("thickness",), ("transparency",), ("colour",),
    ("segments", "thickness", "transparency", "colour"),
])
def test_hair_round_trip_is_bit_exact(tmp_path, optional):
    counts = [5, 5, 5] if "segments" not in optional else [2, 7, 4]
    data, arrays = reference_bytes(counts, optional)
    src, dst = tmp_path / "in.hair", tmp_path / "out.hair"
    src.write_bytes(data)
    hair = read_hair(src)
    assert hair.n_strands == 3 and list(hair.counts) == counts
    assert hair.info_text == "test model: 3 strands"
    np.testing.assert_array_equal(hair.points, arrays["points"])
    for name in ("thickness", "transparency", "colour"):
        got = getattr(hair, name)
        if name in optional:
            np.testing.assert_array_equal(got.reshape(arrays[name].shape), arrays[name])
        else:
            assert got is None
    write_hair(dst, hair)
    assert dst.read_bytes() == data


def test_strands_split_points_by_counts(tmp_path):
    data, arrays = reference_bytes([2, 7, 4])
    (tmp_path / "a.hair").write_bytes(data)
    strands = read_hair(tmp_path / "a.hair").strands(scale=0.01)
    assert [len(s) for s in strands] == [2, 7, 4]
    np.testing.assert_allclose(strands[1], arrays["points"][2:9].astype(np.float64) * 0.01)


def test_from_strands_writes_a_readable_file(tmp_path):
    rng = np.random.default_rng(1)
    strands = [rng.normal(size=(n, 3)) for n in (3, 8, 5)]
    write_hair(tmp_path / "s.hair", strands)
    back = read_hair(tmp_path / "s.hair").strands()
    for a, b in zip(strands, back):
        np.testing.assert_array_equal(b, a.astype(np.float32).astype(np.float64))


def _corrupt(data, offset, fmt, value):
    b = bytearray(data)
    struct.pack_into(fmt, b, offset, value)
    return bytes(b)


def malformed_cases():
    good, _ = reference_bytes([2, 7, 4])
    pts = 128 + 2 * 3  # points array offset: after the header and 3 uint16 segments
    return {
        "bad signature": (b"HAIX" + good[4:], "signature"),
        "truncated header": (good[:100], "truncated header"),
        "truncated arrays": (good[:-5], "truncated arrays"),
        "segments disagree with points": (_corrupt(good, 128, "<H", 3), "add up to"),
        "NaN point": (_corrupt(good, pts + 4 * 4, "<f", float("nan")), "not finite"),
        "inf point": (_corrupt(good, pts, "<f", float("inf")), "not finite"),
        "strand with one point": (_corrupt(_corrupt(good, 128, "<H", 0), 130, "<H", 7),
                                  "strand 0 has 1 points"),
        "trailing bytes": (good + b"\0" * 8, "8 bytes more"),
        "huge point count": (_corrupt(good, 8, "<I", 2**31), "truncated arrays"),
        "unknown flag": (_corrupt(good, 12, "<I", 31 | 64), "unknown flag"),
        "no points array": (_corrupt(good, 12, "<I", 1), "no points array"),
    }


@pytest.mark.parametrize("case", list(malformed_cases()))
def test_malformed_hair_raises_naming_file_and_problem(tmp_path, case):
    data, phrase = malformed_cases()[case]
    path = tmp_path / "bad.hair"
    path.write_bytes(data)
    with pytest.raises(HairFileError) as info:
        read_hair(path)
    assert str(path) in str(info.value) and phrase in str(info.value)
    assert isinstance(info.value, ValueError)


def test_write_rejects_unstorable_strands(tmp_path):
    with pytest.raises(HairFileError, match="strand 1 has 1 points"):
        write_hair(tmp_path / "x.hair", [np.zeros((3, 3)), np.zeros((1, 3))])
    bad = HairFile.from_strands([np.ones((4, 3))])
    bad.points[2, 1] = np.nan
    with pytest.raises(HairFileError, match="not finite"):
        write_hair(tmp_path / "x.hair", bad)


def test_obj_round_trip_to_float_precision(tmp_path):
    rng = np.random.default_rng(2)
    strands = [rng.normal(scale=0.1, size=(n, 3)) for n in (2, 9, 33)]
    write_obj_polylines(tmp_path / "h.obj", strands)
    back = read_obj_polylines(tmp_path / "h.obj")
    assert [len(s) for s in back] == [2, 9, 33]
    for a, b in zip(strands, back):
        np.testing.assert_array_equal(a, b)


def test_obj_reader_tolerates_comments_groups_and_negative_indices(tmp_path):
    text = ("# exported by hand\nmtllib hair.mtl\no head\ng strands\n"
            "v 0 0 0\nv 1 0 0  # trailing comment\nv 1 1 0 1.0\nvt 0 0\n"
            "s off\nl 1 2 \\\n 3\n"
            "v 5 5 5\nv 6 6 6\nl -2 -1\nf 1 2 3\nl 4/1 2/1\n")
    (tmp_path / "t.obj").write_text(text)
    a, b, c = read_obj_polylines(tmp_path / "t.obj")
    np.testing.assert_array_equal(a, [[0, 0, 0], [1, 0, 0], [1, 1, 0]])
    np.testing.assert_array_equal(b, [[5, 5, 5], [6, 6, 6]])
    np.testing.assert_array_equal(c, [[5, 5, 5], [1, 0, 0]])


@pytest.mark.parametrize("text, phrase", [
    ("v 0 0 0\nv 1 1 1\nl 1 3\n", "line 3: vertex index 3 out of range"),
    ("v 0 0 0\nv 1 1 1\nl 0 1\n", "vertex index 0 out of range"),
    ("v 0 0 0\nv 1 1 1\nl -3 1\n", "vertex index -3 out of range"),
    ("v 0 0 0\nl 1\n", "at least 2 vertices"),
    ("v 0 nan 0\nv 1 1 1\nl 1 2\n", "line 1: vertex needs 3 finite"),
    ("v 0 0\nv 1 1 1\nl 1 2\n", "vertex needs 3 finite"),
    ("v 0 0 0\nv 1 x 1\nl 1 2\n", "line 2"),
    ("v 0 0 0\nv 1 1 1\n", "no polyline"),
])
def test_malformed_obj_raises(tmp_path, text, phrase):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(HairFileError) as info:
        read_obj_polylines(path)
    assert str(path) in str(info.value) and phrase in str(info.value)


def test_missing_file_raises_hair_file_error(tmp_path):
    with pytest.raises(HairFileError, match="cannot read"):
        read_hair(tmp_path / "missing.hair")


# ---- hostile files: header counts, devices, non-finite defaults, write errors ----------------

def _tiny_hair(path, n_strands, n_points=1, flags=2, default_segments=0, **defaults):
    """A 128-byte header (fields packed one by one) and the points it promises, nothing more."""
    thickness = defaults.get("thickness", 1.0)
    header = (b"HAIR" + struct.pack("<IIII", n_strands, n_points, flags, default_segments)
              + struct.pack("<ff3f", thickness, 0.0, 1.0, 1.0, 1.0) + b"\0" * 88)
    body = b"".join(struct.pack("<3f", *p) for p in defaults.get("points", [(0, 0, 0)] * n_points))
    path.write_bytes(header + body)
    return path


@pytest.mark.parametrize("n_strands, flags, segments", [
    (2**24, 2, 0),            # no segments array: the strand count alone sized an array
    (2**31, 2, 0),            # (allocating what the header says: 2^28 takes 4.2 s and 1.7 GB; 2^31: MemoryError)
    (2**32 - 1, 2, 2**32 - 1),
    (2**32 - 1, 3, 0),        # a segments array the file cannot hold
])
def test_absurd_header_counts_fail_fast_without_allocating(tmp_path, n_strands, flags, segments):
    path = _tiny_hair(tmp_path / "tiny.hair", n_strands, flags=flags, default_segments=segments)
    tracemalloc.start()
    start = time.perf_counter()
    with pytest.raises(HairFileError) as info:
        th.read_hair(path)
    seconds = time.perf_counter() - start
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert str(path) in str(info.value)
    assert peak < 1e6, f"read_hair allocated {peak / 1e6:.0f} MB for a {path.stat().st_size}-byte file"
    assert seconds < 0.5


@pytest.mark.parametrize("reader", [th.read_hair, th.read_obj_polylines])
def test_readers_refuse_devices(reader):
    with pytest.raises(HairFileError, match="/dev/zero: not a regular file"):
        reader("/dev/zero")


def test_hair_file_with_nan_default_thickness_is_rejected(tmp_path):
    path = _tiny_hair(tmp_path / "nan.hair", 1, n_points=2, default_segments=1, thickness=float("nan"))
    with pytest.raises(HairFileError, match="default thickness, transparency and colour must be finite"):
        th.read_hair(path)
    hair = th.HairFile.from_strands([np.zeros((2, 3))], default_thickness=float("nan"))
    with pytest.raises(HairFileError, match="must be finite"):
        th.write_hair(tmp_path / "out.hair", hair)


def test_absurd_coordinates_are_rejected(tmp_path):
    obj = tmp_path / "far.obj"
    obj.write_text("v 0 0 0\nv 1e300 0 0\nl 1 2\n")
    with pytest.raises(HairFileError, match=r"line 2: vertex coordinates must lie within \+-1e\+06"):
        th.read_obj_polylines(obj)
    path = _tiny_hair(tmp_path / "far.hair", 1, n_points=2, default_segments=1,
                      points=[(0, 0, 0), (3e38, 0, 0)])
    with pytest.raises(HairFileError, match="point 1 has coordinates"):
        th.read_hair(path)


@pytest.mark.parametrize("write", [th.write_hair, th.write_obj_polylines])
def test_writers_wrap_os_errors_naming_the_path(tmp_path, write):
    path = tmp_path / "no such directory" / "out.file"
    with pytest.raises(HairFileError, match="no such directory/out.file: cannot write the file"):
        write(path, [np.zeros((2, 3)), np.ones((3, 3))])
