"""Throughput of Material.evaluate (energy + stress + tangent): numba kernels vs numpy twins.

Run:  python benchmarks/bench_materials.py [--n 100000] [--repeat 3]

Prints one row per material: samples/s of the fused pass with the compiled
kernels and with the numpy twins (strain + law + chain rule), the speed-up,
and the share of the numba time spent outside the strain (law + chain rule).
F are random: rotations times stretches in [0.6, 1.8] (det F > 0).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numpy as np

from voxflex.deform.materials.constitutive import material

ORTHO = dict(E1=1.2e4, E2=0.8e4, E3=0.5e4, nu12=0.25, nu13=0.2, nu23=0.3, G12=4e3, G23=2.5e3, G13=3e3)
CASES = {
    "hooke/linear": ("hooke", dict(young=1e4, poisson=0.3, strain="linear")),
    "hooke/corotational": ("hooke", dict(young=1e4, poisson=0.3)),
    "hooke/corotational-svd": ("hooke", dict(young=1e4, poisson=0.3, strain="corotational-svd")),
    "hooke/corotational-qr": ("hooke", dict(young=1e4, poisson=0.3, strain="corotational-qr")),
    "hooke-orthotropic": ("hooke-orthotropic", ORTHO),
    "stvk": ("stvk", dict(young=1e4, poisson=0.3)),
    "neo-hookean": ("neo-hookean", dict(young=1e4, poisson=0.3)),
    "stable-neo-hookean": ("stable-neo-hookean", dict(young=1e4, poisson=0.3)),
    "mooney-rivlin": ("mooney-rivlin", dict(young=1e4, poisson=0.3)),
    "arruda-boyce": ("arruda-boyce", dict(young=1e4, poisson=0.3)),
    "veronda-westmann": ("veronda-westmann", dict(young=1e4, poisson=0.3)),
    "volume-log": ("volume-log", dict(young=1e4, poisson=0.3)),
    "volume-quadratic": ("volume-quadratic", dict(young=1e4, poisson=0.3)),
    "ogden": ("ogden", dict(young=1e4, poisson=0.3)),
}


def random_F(n, seed=0):
    rng = np.random.default_rng(seed)

    def rotations(k):
        q, r = np.linalg.qr(rng.standard_normal((k, 3, 3)))
        q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
        q[np.linalg.det(q) < 0] *= -1
        return q

    d = rng.uniform(0.6, 1.8, (n, 3))
    return rotations(n) @ (d[:, :, None] * np.eye(3)) @ rotations(n)


def best_time(fun, repeat):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fun()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    n = args.n
    F = random_F(n)
    print(
        f"# machine: {platform.machine()} {platform.processor() or ''}, {os.cpu_count()} cores, "
        f"NUMBA_NUM_THREADS={os.environ.get('NUMBA_NUM_THREADS', 'default')}, python {sys.version.split()[0]}, "
        f"numpy {np.__version__}; n = {n}, best of {args.repeat}"
    )
    print(f"{'material':26s} {'numba [samples/s]':>18s} {'numpy [samples/s]':>18s} {'speed-up':>9s} {'law+chain':>10s}")
    for label, (name, kw) in CASES.items():
        mat = material(name, **kw)
        mat.evaluate(F[:8])  # compile / warm up
        t_nb = best_time(lambda: mat.evaluate(F), args.repeat)
        t_np = best_time(lambda: mat.evaluate(F, backend="numpy"), max(1, args.repeat - 2))
        t_strain = best_time(lambda: (mat.strain.evaluate(F), mat.strain.geometric(F, np.zeros((n, mat.strain.size)))),
                             args.repeat)
        share = max(0.0, 1.0 - t_strain / t_nb)
        print(f"{label:26s} {n / t_nb:18.3e} {n / t_np:18.3e} {t_np / t_nb:9.1f} {share:10.0%}")


if __name__ == "__main__":
    main()
