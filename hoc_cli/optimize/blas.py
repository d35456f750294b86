"""One BLAS thread while hoc solves, even when numpy loaded its BLAS before hoc could ask for one.

``import hoc_cli`` sets OPENBLAS_NUM_THREADS (and MKL's, OpenMP's) to 1 unless set, but OpenBLAS reads the
variable once, when numpy or scipy loads it: a program that imported numpy first runs hoc's many small dense
and banded solves on several BLAS threads, which on a busy machine made a 3 s plan (the UR5 catch of
docs/goals.md) take 38 s with two threads and over 200 s with the default. ``one_thread()`` sets every
OpenBLAS the process has loaded (numpy's and scipy's are two libraries) to one thread through its C API and
restores the previous counts on exit. Other BLAS libraries, and platforms without /proc/self/maps, are left
alone. Pure helper: no I/O beyond reading the process's own memory map.
"""
from __future__ import annotations

import ctypes
from collections.abc import Iterator
from contextlib import contextmanager

#: (set, get) symbol pairs of OpenBLAS builds: scipy-openblas (64- and 32-bit integers), plain OpenBLAS
SYMBOLS = (("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
           ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
           ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
           ("openblas_set_num_threads", "openblas_get_num_threads"))
_found: list | None = None


def _controls() -> list:
    """The (set, get) C functions of every OpenBLAS loaded in this process (found once)."""
    global _found
    if _found is not None:
        return _found
    found = []
    try:
        with open("/proc/self/maps") as f:
            paths = sorted({line.split()[-1] for line in f if "openblas" in line.lower() and ".so" in line})
    except OSError:
        paths = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for set_name, get_name in SYMBOLS:
            setter, getter = getattr(lib, set_name, None), getattr(lib, get_name, None)
            if setter is not None and getter is not None:
                setter.argtypes, setter.restype, getter.restype = [ctypes.c_int], None, ctypes.c_int
                found.append((setter, getter))
                break
    if paths:  # numpy is loaded: what was found stays (a later call would find the same libraries)
        _found = found
    return found


def thread_counts() -> list[int]:
    """The thread count of each loaded OpenBLAS (empty when none is found)."""
    return [int(get()) for _, get in _controls()]


@contextmanager
def one_thread() -> Iterator[None]:
    """Every loaded OpenBLAS on one thread inside the block, the previous counts restored after it."""
    controls = _controls()
    previous = [int(get()) for _, get in controls]
    for setter, _ in controls:
        setter(1)
    try:
        yield
    finally:
        for (setter, _), n in zip(controls, previous):
            setter(n)
