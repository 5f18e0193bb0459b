"""Volumetric locking of the voxel model: cantilever tip deflection against Poisson's ratio.

Linear Hooke cantilever [0,4]x[0,1]x[0,1], face x = 0 clamped, rho g = 9.81 along -z,
u_z at the tip-face centre; full 2x2x2 Gauss, the reduced volumetric term
(B-bar) and the "auto" default (reduced for nu >= 0.4), with the beam-theory trend
from the full nu = 0.3 value (Timoshenko, Cowper's shear factor 10(1+nu)/(12+11nu)).

    python benchmarks/bench_locking.py          # 16x4x4 and 32x8x8 (about 30 s)
    python benchmarks/bench_locking.py --quick  # 16x4x4 only
"""

from __future__ import annotations

import os
import platform
import sys

import numpy as np

from voxflex.deform.boundary import FixedRegion
from voxflex.deform.materials import material
from voxflex.deform.solvers import SolverOptions, solve
from voxflex.deform.voxel_model import VoxelModel
from voxflex.image.label_image import LabelImage

TIP = np.array([4.0, 0.5, 0.5])
CLAMP = FixedRegion([-1.0, -1.0, -1.0], [1e-9, 2.0, 2.0])
NUS = (0.3, 0.4, 0.45, 0.49, 0.499, 0.4999)


def tip(nx, nu, volumetric):
    ny = nx // 4
    image = LabelImage(np.ones((nx, ny, ny)), spacing=(4 / nx, 1 / ny, 1 / ny))
    model = VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=nu, strain="linear")},
                                  volumetric=volumetric)
    rec = solve(model, fixed=[CLAMP], gravity=[0, 0, -9.81], densities={1: 1.0}, options=SolverOptions(tolerance=1e-10))
    return float((model.point_mapping([TIP]).apply(rec[-1].q)[0] - TIP)[2])


def beam(nu, E=1e4, q=9.81, L=4.0):
    """Timoshenko tip deflection of the uniformly loaded cantilever (unit square section)."""
    kappa = 10 * (1 + nu) / (12 + 11 * nu)
    return -(q * L**4 / (8 * E / 12) + q * L**2 / (2 * kappa * E / (2 * (1 + nu))))


def main():
    sizes = (16,) if "--quick" in sys.argv else (16, 32)
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs")
    print(f"{'grid':<8} {'nu':>7} {'full':>9} {'reduced':>9} {'auto':>9} {'beam trend':>10} {'auto/trend':>10}")
    for nx in sizes:
        ref = tip(nx, 0.3, "full")
        for nu in NUS:
            full, red = tip(nx, nu, "full"), tip(nx, nu, "reduced")
            auto = red if nu >= 0.4 else full
            trend = ref * beam(nu) / beam(0.3)
            print(f"{nx}x{nx // 4}x{nx // 4:<3} {nu:>7} {full:>9.5f} {red:>9.5f} {auto:>9.5f} {trend:>10.5f} "
                  f"{auto / trend - 1:>+10.2%}")


if __name__ == "__main__":
    main()
