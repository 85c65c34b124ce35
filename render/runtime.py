"""Taichi start-up and device buffers for the renderer.

The renderer never re-initialises Taichi: if the process (or taichi_hair's `th.init`, or the
test suite) already called `ti.init`, that runtime is used as it is. Every render kernel types
its floats as `ti.f32` explicitly, so the process's `default_fp` does not matter here.

Per-frame inputs and buffers are `ti.ndarray`s cached by (name, dtype, shape): ndarray kernels
compile once per process, whereas kernels taking fields as templates recompile for every new
field.
"""

import os
import weakref

import numpy as np
import taichi as ti

_ARCHES = {"cpu": ti.cpu, "cuda": ti.cuda, "gpu": ti.gpu, "vulkan": ti.vulkan, "metal": ti.metal}
_buffers: dict = {}
_sources: dict = {}   # buffer key -> weak reference to the read-only array last copied in


def is_initialized() -> bool:
    """True once `ti.init` has run in this process, by anyone."""
    return ti.lang.impl.get_runtime().prog is not None


def init(arch: str = "cpu", **kwargs) -> None:
    """Initialise Taichi for rendering unless it is already initialised (then a no-op).

    arch: "cpu" (default), "cuda", "gpu", "vulkan" or "metal". Extra keyword arguments go to
    `ti.init`. To use taichi_hair in the same process, call `taichi_hair.init` first: it refuses
    to run after another `ti.init`.
    """
    if arch not in _ARCHES:
        raise ValueError(f"arch must be one of {sorted(_ARCHES)}, got {arch!r}")
    if is_initialized():
        return
    options = dict(arch=_ARCHES[arch], default_fp=ti.f32, log_level=ti.WARN)
    options.update(kwargs)
    # no version check thread (unless asked for): a Python thread that loads modules while the
    # main thread loads pxr can deadlock the two (taichi_hair.runtime.skip_version_check)
    os.environ.setdefault("TI_SKIP_VERSION_CHECK", "ON")
    ti.init(**options)


def ensure_init() -> None:
    """Initialise on the CPU with defaults if nobody has initialised Taichi yet."""
    if not is_initialized():
        init()


def on_cpu() -> bool:
    """True when Taichi runs on the CPU (x64 or arm64).

    Kernels over an image or map loop over its rows in parallel and along each row serially on
    the CPU (`threads.spread_rows`): Taichi's 2-D loop (`for i, j in a`) decodes every
    element's (i, j) with integer divisions, ~12 ns an element on the CPU, ten times a clear's
    own work (512 x 512 int64 clear: 3.5 -> 0.37 ms). GPUs keep one thread per element."""
    return ti.lang.impl.current_cfg().arch in (ti.x64, ti.arm64)


def chunks(n: int, cpu: int, per_thread_gpu: int) -> int:
    """Threads for a kernel whose threads each walk a contiguous run of n items: `cpu` on the
    CPU (a few per core, long runs), else one per `per_thread_gpu` items (GPUs want many)."""
    return max(1, cpu if on_cpu() else -(-int(n) // per_thread_gpu))


def buffer(name: str, dtype, shape: tuple, n: int = 0) -> ti.Ndarray:
    """A cached `ti.ndarray` of `dtype` (a Taichi scalar or vector type) and `shape`.

    `n` is the vector length for vector dtypes (0 for scalars); it only keys the cache.
    The contents are whatever the last user left: callers clear or overwrite them.
    """
    shape = tuple(int(s) for s in shape)
    key = (name, str(dtype), n, shape)
    if key not in _buffers:
        # drop stale buffers of the same name so a resolution sweep does not pile up memory
        for old in [k for k in _buffers if k[0] == name]:
            del _buffers[old]
            _sources.pop(old, None)
        _buffers[key] = ti.ndarray(dtype, shape)
    return _buffers[key]


def upload(name: str, array: np.ndarray, dtype, n: int = 0) -> ti.Ndarray:
    """Copy a numpy array into the cached ndarray `name` (scalar: shape of array; vector of
    length n: shape of array without its last axis) and return it.

    A read-only array (a `Hair`'s derived arrays are) that is the very object last copied
    into this buffer is not copied again: rendering the same groom again (a turntable, a
    benchmark) skips the upload. Writeable arrays are always copied."""
    shape = array.shape[:-1] if n else array.shape
    nd = buffer(name, dtype, shape, n)
    key = (name, str(dtype), n, tuple(int(s) for s in shape))
    last = _sources.get(key)
    if last is not None and last() is array and not array.flags.writeable:
        return nd
    nd.from_numpy(array)
    _sources[key] = None if array.flags.writeable else weakref.ref(array)
    return nd
