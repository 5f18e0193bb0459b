"""Throughput of the strain measures: compiled kernels vs their numpy twins.

For every measure, times ``evaluate(F)`` (E + dE/dF) and ``evaluate(F, s)``
(+ geometric term) on n samples (default 1e5) of random F near identity, and
prints samples per second for the numba kernel and the numpy twin; then the
3x3 SVD alone (``voxflex.deform.materials._svd3``, Jacobi rotations, used by the polar,
signed-SVD and principal-stretch kernels) against numpy's batched LAPACK SVD,
with their worst reconstruction and orthogonality errors.

Run:  python benchmarks/bench_strains.py [--n 100000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

from voxflex.deform.materials._svd3 import svd3
from voxflex.deform.materials.strains import STRAINS


def _best(fn, repeat):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def _cpu_name():
    name = platform.processor()
    try:  # platform.processor() is empty on many Linux builds
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return f"{name or platform.machine()} ({line.split(':', 1)[1].strip()})"
    except OSError:
        pass
    return name or platform.machine()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    n = args.n
    F = np.eye(3) + 0.2 * rng.standard_normal((n, 3, 3))
    F[np.linalg.det(F) < 0, :, 0] *= -1  # keep det F > 0 (polar is defined there)
    print(f"machine: {_cpu_name()}, {os.cpu_count()} cores, "
          f"numba threads: {os.environ.get('NUMBA_NUM_THREADS', 'default')} (kernels are serial)")
    print(f"n = {n} samples, best of {args.repeat}; throughput in samples/s")
    head = f"{'measure':22s} {'E+J numba':>12s} {'E+J numpy':>12s} {'E+J+G numba':>12s} {'E+J+G numpy':>12s} {'speed-up G':>10s}"
    print(head)
    print("-" * len(head))
    for name, st in STRAINS.items():
        s = rng.standard_normal((n, st.size))
        st.evaluate(F[:2], s[:2])  # compile outside the timing
        t_j = _best(lambda: st.evaluate(F), args.repeat)
        t_g = _best(lambda: st.evaluate(F, s), args.repeat)
        t_jr = _best(lambda: st.evaluate_reference(F), 1)
        t_gr = _best(lambda: st.evaluate_reference(F, s), 1)
        print(f"{name:22s} {n / t_j:12.3g} {n / t_jr:12.3g} {n / t_g:12.3g} {n / t_gr:12.3g} {t_gr / t_g:10.1f}")
    print()
    svd_table(F, args.repeat)


def _errors(F, U, sig, V):
    """Worst |U diag(sig) V^T - F| / max|F| and worst |Q^T Q - I| of U and V."""
    rec = np.abs(U * sig[:, None, :] @ np.swapaxes(V, 1, 2) - F).max(axis=(1, 2)) / np.abs(F).max(axis=(1, 2))
    orth = max(np.abs(np.swapaxes(Q, 1, 2) @ Q - np.eye(3)).max() for Q in (U, V))
    return rec.max(), orth


def svd_table(F, repeat):
    n = F.shape[0]
    svd3(F[:2])  # compile outside the timing
    head = f"{'3x3 SVD':28s} {'samples/s':>12s} {'max rec err':>12s} {'max orth err':>12s}"
    print(head)
    print("-" * len(head))
    t = _best(lambda: svd3(F), repeat)
    print(f"{'svd3 (Jacobi, numba)':28s} {n / t:12.3g} {_errors(F, *svd3(F))[0]:12.2g} {_errors(F, *svd3(F))[1]:12.2g}")
    t = _best(lambda: np.linalg.svd(F), repeat)
    U, sig, Vh = np.linalg.svd(F)
    rec, orth = _errors(F, U, sig, np.swapaxes(Vh, 1, 2))
    print(f"{'numpy.linalg.svd (batched)':28s} {n / t:12.3g} {rec:12.2g} {orth:12.2g}")


if __name__ == "__main__":
    main()
