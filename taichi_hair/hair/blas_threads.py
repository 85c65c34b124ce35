"""numpy's OpenBLAS held to one thread for a block of small dense solves."""

from contextlib import contextmanager
import ctypes

_BLAS_SYMBOLS = (("openblas_set_num_threads", "openblas_get_num_threads"),
                 ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
                 ("openblas_set_num_threads64_", "openblas_get_num_threads64_"))


@contextmanager
def single_threaded_blas():
    """Run numpy's OpenBLAS on one thread inside the block. The per-strand problems are small
    (about 100 x 150); with Taichi's CPU threads running beside it, a multithreaded OpenBLAS
    spends 10-200x longer waking threads than computing (measured: 0.9 s against 4 ms for
    one 240 x 150 lstsq on 2 cores). A no-op where no OpenBLAS is found."""
    handles = []
    try:
        with open("/proc/self/maps") as maps:
            paths = {line.split()[-1] for line in maps if "openblas" in line.lower() and "/" in line}
    except OSError:
        paths = set()
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for set_name, get_name in _BLAS_SYMBOLS:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                setter, getter = getattr(lib, set_name), getattr(lib, get_name)
                handles.append((setter, int(getter())))
                setter(1)
                break
    try:
        yield
    finally:
        for setter, threads in handles:
            setter(threads)
