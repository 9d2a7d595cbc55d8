"""One BLAS thread while a sequence is estimated.

The estimators' linear algebra works on small matrices: 3x3 rotations, the
9-column systems of the 5-point and homography fits, a tile stack's phase-plane
fit. On such matrices a BLAS thread pool costs more to wake than it saves, and
its threads wait busily for work, taking the cores from OpenCV's own threads
(remap, detectors) and from a frame prepared ahead. Limiting BLAS to one thread
for the duration of an estimate leaves the results as they are and the
process's BLAS settings as they were afterwards.
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

from threadpoolctl import threadpool_limits

__all__ = ["single_blas_thread"]


@contextmanager
def single_blas_thread() -> Iterator[None]:
    """Context in which every BLAS library loaded in the process (NumPy's and SciPy's OpenBLAS,
    MKL, ...) uses one thread; the previous thread counts come back on exit, also on an error.

    ``benchmarks/bench_blas_threads.py`` measures the limit against the library's default (one
    thread per core); on two cores it cut the wall time per frame by factors of 1.2-1.4 for ORB,
    1.2-1.3 for AKAZE at 512 px and 1.2-1.4 for iFMI at 1024 px, with the same estimates.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        yield
