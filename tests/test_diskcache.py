"""The geometry disk cache (taichi_hair/diskcache.py): an entry comes back byte for byte what
computing gives, any changed input computes afresh, and a cache that is off, unwritable or
corrupt only means computing again."""

import dataclasses
import warnings

import numpy as np
import pytest

from taichi_hair import diskcache
from taichi_hair.diskcache import cached_arrays, fingerprint
from taichi_hair.hair.roots import scalp_groom
from taichi_hair.world.colliders import MeshCollider, Sphere
from taichi_hair.world.headmesh import default_head, icosphere
from taichi_hair.world.scene import ColliderUnion
from taichi_hair.world.sdf import SignedDistanceGrid


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv(diskcache.CACHE_ENV, str(tmp_path / "cache"))
    return tmp_path / "cache"


def counted(arrays):
    """compute() returning `arrays`, and the list its calls are counted in."""
    calls = []

    def compute():
        calls.append(1)
        return {k: v.copy() for k, v in arrays.items()}
    return compute, calls


@dataclasses.dataclass(frozen=True)
class Thing:
    values: np.ndarray
    scale: float
    inner: tuple = ()


def test_every_changed_input_changes_the_key():
    a = np.arange(6.0).reshape(2, 3)
    base = fingerprint("k", Thing(a, 1.0, (Thing(a, 2.0),)), 3, "x", None)
    assert base == fingerprint("k", Thing(a.copy(), 1.0, (Thing(a.copy(), 2.0),)), 3, "x", None)
    b = a.copy()
    b[1, 2] = np.nextafter(b[1, 2], 10.0)  # one ulp in one element
    changed = [
        fingerprint("other", Thing(a, 1.0, (Thing(a, 2.0),)), 3, "x", None),
        fingerprint("k", Thing(b, 1.0, (Thing(a, 2.0),)), 3, "x", None),
        fingerprint("k", Thing(a, 1.0, (Thing(b, 2.0),)), 3, "x", None),  # nested dataclass
        fingerprint("k", Thing(a.astype(np.float32), 1.0, (Thing(a, 2.0),)), 3, "x", None),  # dtype
        fingerprint("k", Thing(a.reshape(3, 2), 1.0, (Thing(a, 2.0),)), 3, "x", None),  # shape
        fingerprint("k", Thing(a, 1.0 + 1e-15, (Thing(a, 2.0),)), 3, "x", None),
        fingerprint("k", Thing(a, 1.0, (Thing(a, 2.0),)), 3.0, "x", None),  # int vs float
        fingerprint("k", Thing(a, 1.0, (Thing(a, 2.0),)), 3, "y", None),
        fingerprint("k", Thing(a, 1.0, ()), 3, "x", None),
    ]
    assert len(set(changed + [base])) == len(changed) + 1


def test_an_entry_comes_back_byte_for_byte_without_computing(cache):
    arrays = {"values": np.random.default_rng(0).normal(size=(5, 4, 3)), "ids": np.arange(7, dtype=np.int32)}
    compute, calls = counted(arrays)
    first = cached_arrays("test", (1.5, np.ones(3)), compute)
    second = cached_arrays("test", (1.5, np.ones(3)), compute)
    assert len(calls) == 1
    for name, a in arrays.items():
        assert second[name].dtype == a.dtype and second[name].tobytes() == a.tobytes()
        assert first[name].tobytes() == a.tobytes()
    cached_arrays("test", (1.5, np.zeros(3)), compute)  # another input: computed
    assert len(calls) == 2


def test_off_uncacheable_corrupt_and_unwritable_only_compute(cache, monkeypatch, tmp_path):
    arrays = {"x": np.arange(4.0)}
    compute, calls = counted(arrays)
    monkeypatch.setenv(diskcache.CACHE_ENV, "off")
    cached_arrays("test", (1,), compute)
    cached_arrays("test", (1,), compute)
    assert len(calls) == 2 and not cache.exists()

    monkeypatch.setenv(diskcache.CACHE_ENV, str(cache))
    cached_arrays("test", (object(),), compute)  # cannot be fingerprinted
    assert len(calls) == 3 and not cache.exists()

    cached_arrays("test", (2,), compute)
    (entry,) = (cache / "test").glob("*.npz")
    entry.write_bytes(entry.read_bytes()[:20])  # truncated
    healed = cached_arrays("test", (2,), compute)
    assert len(calls) == 5 and np.array_equal(healed["x"], arrays["x"])
    cached_arrays("test", (2,), compute)
    assert len(calls) == 5  # the entry was written again

    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv(diskcache.CACHE_ENV, str(blocker / "cache"))  # a folder that cannot be made
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = cached_arrays("test", (3,), compute)
    assert len(calls) == 6 and np.array_equal(out["x"], arrays["x"])


def test_cached_distance_grid_and_groom_equal_computed_ones(cache, monkeypatch):
    v, f = icosphere(3)
    v = 0.1 * v
    head = default_head(3)
    collider = ColliderUnion((MeshCollider(grid=SignedDistanceGrid.from_mesh(v, f, spacing=0.01, padding=0.02)),
                              Sphere(centre=(0.0, 0.0, -0.12), radius=0.04)))

    def build():
        grid = SignedDistanceGrid.from_mesh(v, f, spacing=0.01, padding=0.02)
        groom = scalp_groom(head, 12, style="curly", length=0.1, n_nodes=9, collider=collider, seed=3)
        return grid.values, groom.positions

    computed = [build() for _ in range(2)]  # the second comes from the cache
    assert len(list(cache.rglob("*.npz"))) == 2
    monkeypatch.setenv(diskcache.CACHE_ENV, "off")
    fresh = build()
    for grid, nodes in computed:
        assert grid.tobytes() == fresh[0].tobytes() and nodes.tobytes() == fresh[1].tobytes()
