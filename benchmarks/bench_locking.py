"""Volumetric locking of the voxel model: cantilever tip deflection against Poisson's ratio.

Linear Hooke cantilever [0,4]x[0,1]x[0,1], face x = 0 clamped, rho g = 9.81 along -z,
u_z at the tip-face centre; full 2x2x2 Gauss, the reduced volumetric term
(B-bar) and the "auto" default (reduced for nu >= 0.4), with the beam-theory trend
from the full nu = 0.3 value (Timoshenko, Cowper's shear factor 10(1+nu)/(12+11nu)).

Frame rows: the same cantilever as a scene with ``[nodes] kind = "affine"`` (20 and
50 frames, natural-neighbour weights, the scene default of stabilised mid-point regions,
clamp box at x = 0), u_z at the same tip point through the frames; the precompute is
built once per grid and frame count, the material swapped per nu.  Columns: the
frame model's full integration of the volumetric term, the reduced one (B-bar with the
trace projected onto the frames' weights, ``FrameModel(volumetric="reduced")``), "auto"
(reduced for nu >= 0.4, the scenes' default) and its ratio to the beam-theory trend
from the full nu = 0.3 value.

    python benchmarks/bench_locking.py          # 16x4x4 and 32x8x8 (about 30 s)
    python benchmarks/bench_locking.py --quick  # 16x4x4 only
    python benchmarks/bench_locking.py --frames # the frame rows only
"""

from __future__ import annotations

import os
import platform
import sys

import numpy as np

from voxflex import build
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.frames.model import FrameModel
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import FixedRegion
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.image.label_image import LabelImage
from voxflex.scene import ElasticitySpec, FixedSpec, MaterialSpec, NodesSpec, ObjectSpec, Scene

TIP = np.array([4.0, 0.5, 0.5])
CLAMP = FixedRegion([-1.0, -1.0, -1.0], [1e-9, 2.0, 2.0])
NUS = (0.3, 0.4, 0.45, 0.49, 0.499, 0.4999)
FRAME_NUS = (0.3, 0.45, 0.49, 0.499, 0.4999)
FRAME_COUNTS = (20, 50)


def tip(nx, nu, volumetric):
    ny = nx // 4
    image = LabelImage(np.ones((nx, ny, ny)), spacing=(4 / nx, 1 / ny, 1 / ny))
    model = VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=nu, strain="linear")},
                                  volumetric=volumetric)
    rec = solve(model, fixed=[CLAMP], gravity=[0, 0, -9.81], densities={1: 1.0}, options=SolverOptions(tolerance=1e-10))
    return float((model.point_mapping([TIP]).apply(rec[-1].q)[0] - TIP)[2])


def frame_layout(nx, count):
    """The frame model of the cantilever scene (frames, weights, mid-point samples), built once."""
    scene = Scene(object=ObjectSpec(shape="box", size=(4.0, 1.0, 1.0), voxel_size=4.0 / nx),
                  materials=(MaterialSpec(model="hooke", young=1e4, poisson=0.3, strain="linear", density=1.0),),
                  nodes=NodesSpec(kind="affine", count=count, shape_function="natural-neighbour"),
                  elasticity=ElasticitySpec(strain="linear", quadrature="midpoint"),
                  fixed=(FixedSpec(min=(-1e9, -1e9, -1e9), max=(1e-6, 1e9, 1e9)),))
    return build.model(scene, cache=False)


def frame_tip(layout, nu, **kw):
    """Tip u_z of the frame cantilever with Poisson ratio nu on ``layout``'s frames and samples."""
    model = FrameModel(layout.image, layout.frames, layout.shape_function, layout.samples,
                       {1: material("hooke", young=1e4, poisson=nu, strain="linear")}, hourglass=layout.hourglass,
                       region_tables=layout.tables, **kw)
    rec = solve(model, fixed=[FixedRegion([-1e9, -1e9, -1e9], [1e-6, 1e9, 1e9])], gravity=[0, 0, -9.81],
                densities={1: 1.0}, options=SolverOptions(tolerance=1e-10))
    return float((model.point_mapping([TIP]).apply(rec[-1].q)[0] - TIP)[2])


def beam(nu, E=1e4, q=9.81, L=4.0):
    """Timoshenko tip deflection of the uniformly loaded cantilever (unit square section)."""
    kappa = 10 * (1 + nu) / (12 + 11 * nu)
    return -(q * L**4 / (8 * E / 12) + q * L**2 / (2 * kappa * E / (2 * (1 + nu))))


def frame_rows(sizes):
    print(f"{'grid':<8} {'frames':>6} {'nu':>7} {'full':>9} {'reduced':>9} {'auto':>9} {'beam trend':>10} "
          f"{'full/trend':>10} {'auto/trend':>10}")
    for nx in sizes:
        for count in FRAME_COUNTS:
            layout = frame_layout(nx, count)
            ref = None
            for nu in FRAME_NUS:
                full, red = frame_tip(layout, nu), frame_tip(layout, nu, volumetric="reduced")
                auto = red if nu >= 0.4 else full
                ref = full if ref is None else ref
                trend = ref * beam(nu) / beam(0.3)
                print(f"{nx}x{nx // 4}x{nx // 4:<3} {count:>6} {nu:>7} {full:>9.5f} {red:>9.5f} {auto:>9.5f} "
                      f"{trend:>10.5f} {full / trend - 1:>+10.2%} {auto / trend - 1:>+10.2%}")


def main():
    sizes = (16,) if "--quick" in sys.argv else (16, 32)
    print(f"machine: {platform.platform()}, {os.cpu_count()} CPUs")
    if "--frames" in sys.argv:
        frame_rows(sizes)
        return
    print(f"{'grid':<8} {'nu':>7} {'full':>9} {'reduced':>9} {'auto':>9} {'beam trend':>10} {'auto/trend':>10}")
    for nx in sizes:
        ref = tip(nx, 0.3, "full")
        for nu in NUS:
            full, red = tip(nx, nu, "full"), tip(nx, nu, "reduced")
            auto = red if nu >= 0.4 else full
            trend = ref * beam(nu) / beam(0.3)
            print(f"{nx}x{nx // 4}x{nx // 4:<3} {nu:>7} {full:>9.5f} {red:>9.5f} {auto:>9.5f} {trend:>10.5f} "
                  f"{auto / trend - 1:>+10.2%}")
    print()
    frame_rows(sizes)


if __name__ == "__main__":
    main()
