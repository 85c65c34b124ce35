"""A content-addressed disk cache for slow, deterministic host computations: the signed
distance grid of a mesh (world/sdf.py) and a scalp groom (hair/roots.py). Building the default
head's and bust's grids and growing a groom over them takes 10-30 s of numpy per process; with
the cache a later run with the same inputs loads the arrays in milliseconds.

An entry's key is a SHA-256 over the inputs (arrays by dtype, shape and bytes; numbers by
repr; dataclasses field by field), over the source of every module of this package and over
numpy's version, so a changed input, a changed line of code or another numpy computes afresh: an entry is returned only where the
computation would give the same arrays, byte for byte.

Where: the folder in the environment variable TAICHI_HAIR_CACHE, else ~/.cache/taichi_hair;
TAICHI_HAIR_CACHE=off turns the cache off. The folder may be deleted at any time. A folder that
cannot be written, or an entry that cannot be read, only means computing again.
"""

import dataclasses
import hashlib
import os
import tempfile
import zipfile
from functools import lru_cache
from pathlib import Path

import numpy as np

CACHE_ENV = "TAICHI_HAIR_CACHE"


class Uncacheable(TypeError):
    """An input the cache cannot fingerprint (e.g. a user's own collider object)."""


def cache_folder() -> Path | None:
    """The cache's folder, or None when TAICHI_HAIR_CACHE=off."""
    setting = os.environ.get(CACHE_ENV, "")
    if setting.lower() == "off":
        return None
    return Path(setting) if setting else Path.home() / ".cache" / "taichi_hair"


@lru_cache(maxsize=1)
def source_digest() -> str:
    """SHA-256 over the path and bytes of every .py file of the taichi_hair package."""
    digest = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _feed(digest, value) -> None:
    """Add one input to the digest, tagged by its kind so that different inputs never collide."""
    if value is None or isinstance(value, (bool, int, float, complex, str, np.integer, np.floating)):
        digest.update(f"{type(value).__name__}:{value!r};".encode())
    elif isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        digest.update(f"ndarray:{a.dtype.str}:{a.shape};".encode())
        digest.update(a.tobytes())
    elif isinstance(value, (tuple, list)):
        digest.update(f"{type(value).__name__}:{len(value)}(".encode())
        for item in value:
            _feed(digest, item)
        digest.update(b")")
    elif isinstance(value, dict):
        digest.update(f"dict:{len(value)}(".encode())
        for key in sorted(value):
            _feed(digest, key)
            _feed(digest, value[key])
        digest.update(b")")
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        digest.update(f"{type(value).__module__}.{type(value).__qualname__}(".encode())
        for field in dataclasses.fields(value):
            _feed(digest, field.name)
            _feed(digest, getattr(value, field.name))
        digest.update(b")")
    else:
        raise Uncacheable(f"cannot fingerprint a {type(value).__name__}")


def fingerprint(kind: str, *inputs) -> str:
    """The hex key of computation `kind` on `inputs` with this package's source; Uncacheable if
    an input is of a kind the cache cannot fingerprint."""
    digest = hashlib.sha256(f"{kind};{source_digest()};numpy {np.__version__};".encode())
    for value in inputs:
        _feed(digest, value)
    return digest.hexdigest()


def cached_arrays(kind: str, inputs: tuple, compute) -> dict:
    """compute() -> {name: ndarray}, or the same arrays from an earlier run with equal inputs.
    Inputs the cache cannot fingerprint, or the cache turned off, just compute."""
    folder = cache_folder()
    if folder is None:
        return compute()
    try:
        path = folder / kind / f"{fingerprint(kind, *inputs)}.npz"
    except Uncacheable:
        return compute()
    try:
        with np.load(path, allow_pickle=False) as stored:
            return {name: stored[name] for name in stored.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile):  # absent or corrupt
        pass
    arrays = compute()
    temporary = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # written whole under a temporary name, then renamed: a reader never sees half an entry
        with tempfile.NamedTemporaryFile(dir=path.parent, suffix=".tmp", delete=False) as out:
            temporary = out.name
            np.savez(out, **arrays)
        os.replace(temporary, path)
    except OSError:
        if temporary is not None:
            Path(temporary).unlink(missing_ok=True)
    return arrays
