"""Stress-strain curve of a loading-unloading-reloading cycle with plasticity; writes docs/plasticity_curve.png.

    python benchmarks/plot_plasticity.py [--out docs/plasticity_curve.png]

A bar of 4 x 1 x 1 voxels (0.1 x 0.025 x 0.025 m; Hooke with the linear
strain, E = 200 GPa, nu = 0.3) wrapped in
:class:`voxflex.deform.layers.plasticity.PlasticMaterial` (von Mises on the strain,
yield strain eps_y = sigma_y / (3 mu) for sigma_y = 250 MPa, hardening
H = 0.05) lies on the symmetry planes x = 0, y = 0, z = 0 and is stretched
by its end face x = L (displacement control), so the stress is uniaxial and
uniform.  The end goes 0 -> 3 eps_1 -> back to the strain where the force
vanishes -> 4.5 eps_1 -> back to where it vanishes again (eps_1 = sigma_y / E
the axial strain at first yield), then is released (no end condition): the
bar keeps its permanent set.  Each level is solved by the library's static solver with
the plastic state fixed, return-mapped, and re-solved until the plastic
strain stops changing (the staggered scheme of the module), then committed.

The closed form (drawn as a line): elastic slope E up to sigma_y, then the
elastic-plastic tangent E 3 mu H / (E + 3 mu H); unloading with slope E; the
permanent set eps_max - sigma_max / E; reloading elastic up to sigma_max,
then hardening again.  The script prints the computed and closed-form figures.
"""

from __future__ import annotations

import argparse
import os
import platform
from pathlib import Path

import numpy as np

from voxflex.deform.layers.plasticity import PlasticMaterial
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import FixedRegion
from voxflex.deform.solve.equilibrium import equilibrate
from voxflex.image.label_image import LabelImage

E, NU, SIGMA_Y, H = 200e9, 0.3, 250e6, 0.05
MU = E / (2 * (1 + NU))
EPS_Y = SIGMA_Y / (3 * MU)  # von Mises yield strain of the law (equivalent strain)
DX = 0.025
L, AREA = 4 * DX, DX * DX
ET = E * 3 * MU * H / (E + 3 * MU * H)  # elastic-plastic tangent in uniaxial stress
INF = np.inf


def _supports():
    tiny = 1e-12
    return [FixedRegion([-INF, -INF, -INF], [tiny, INF, INF], "x"),
            FixedRegion([-INF, -INF, -INF], [INF, tiny, INF], "y"),
            FixedRegion([-INF, -INF, -INF], [INF, INF, tiny], "z")]


def _end(eps):
    T = np.zeros((3, 4))
    T[:, :3] = np.diag([1.0 + eps, 1.0, 1.0])
    return FixedRegion([L - 1e-12, -INF, -INF], [INF, INF, INF], "x", T)


def _stress(model, q):
    end = model.rest[:, 0] > L - 1e-12
    return float(model.gradient(q)[end, 0].sum()) / AREA  # end-face reaction / area (Pa)


def closed_form(path):
    """Uniaxial stress (Pa) along a strain path (eps,) of the bilinear hardening model."""
    out, sig, eps_prev, peak = [], 0.0, 0.0, SIGMA_Y  # peak: the current yield stress in tension
    for eps in path:
        trial = sig + E * (eps - eps_prev)
        if trial > peak:  # loading past the current yield stress: harden along ET
            sig = peak + ET * (eps - eps_prev - (peak - sig) / E)
            peak = sig
        else:
            sig = trial
        out.append(sig)
        eps_prev = eps
    return np.array(out)


def run():
    base = material("hooke", young=E, poisson=NU, strain="linear")
    image = LabelImage(np.ones((4, 1, 1), dtype=np.uint8), spacing=(DX, DX, DX))
    mat = PlasticMaterial(base, 4 * 8, yield_strain=EPS_Y, hardening=H)
    model = VoxelModel.from_image(image, {1: mat})
    eps1 = SIGMA_Y / E  # axial strain at first yield
    eps_max = 3 * eps1
    sig_max = float(closed_form([eps_max])[0])
    eps_zero = eps_max - sig_max / E  # where the force vanishes on unloading
    eps_top = 4.5 * eps1
    eps_zero2 = eps_top - float(closed_form([eps_max, eps_zero, eps_top])[-1]) / E
    path = np.concatenate([np.linspace(0, eps_max, 13)[1:], np.linspace(eps_max, eps_zero, 7)[1:],
                           np.linspace(eps_zero, eps_top, 13)[1:], np.linspace(eps_top, eps_zero2, 7)[1:]])
    q = model.rest.copy()
    stress = []
    for eps in path:
        q = equilibrate(model, mat, q, _supports() + [_end(eps)])
        stress.append(_stress(model, q))
    q = equilibrate(model, mat, q, _supports())  # release the end: the permanent set
    end = model.rest[:, 0] > L - 1e-12
    permanent = float(np.mean(q[end, 0] - model.rest[end, 0])) / L
    return np.concatenate([[0.0], path]), np.array([0.0, *stress]), permanent, (eps1, eps_max, sig_max, eps_zero)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "plasticity_curve.png"))
    args = parser.parse_args(argv)
    eps, sig, permanent, (eps1, eps_max, sig_max, eps_zero) = run()
    exact = closed_form(eps[1:])
    err = np.max(np.abs(sig[1:] - exact)) / SIGMA_Y
    # the release state of the second cycle: the peak of reloading
    sig_peak2 = float(closed_form([eps_max, eps_zero, 4.5 * eps1])[-1])
    set2 = 4.5 * eps1 - sig_peak2 / E
    print(f"# plasticity cycle, {platform.platform()}, {os.cpu_count()} CPUs")
    print("| figure | computed | closed form |")
    print("|---|---|---|")
    print(f"| first yield (axial strain, stress) | ({eps1:.4e}, {SIGMA_Y / 1e6:.1f} MPa) | same (input) |")
    print(f"| stress at eps = {eps_max:.3e} | {sig[12] / 1e6:.4f} MPa | {sig_max / 1e6:.4f} MPa |")
    print(f"| stress on unloading at eps_max - sigma_max / E = {eps_zero:.5e} (the set of cycle 1) | "
          f"{sig[18]:.1e} Pa | 0 |")
    print(f"| permanent set after reloading to {4.5 * eps1:.3e} and release | {permanent:.5e} | {set2:.5e} |")
    print(f"| largest stress error along the path / sigma_y | {err:.1e} | |")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fine = np.concatenate([np.linspace(0, eps_max, 200), np.linspace(eps_max, eps_zero, 100)[1:],
                           np.linspace(eps_zero, 4.5 * eps1, 200)[1:], np.linspace(4.5 * eps1, set2, 100)[1:]])
    fig, ax = plt.subplots(figsize=(6.4, 3.8), dpi=100)
    ax.plot(fine * 1e3, np.concatenate([[0.0], closed_form(fine[1:])]) / 1e6, "-", color="0.6", lw=2,
            label="closed form (bilinear hardening)")
    ax.plot(eps * 1e3, sig / 1e6, "o", ms=4, color="C0", label="voxflex (voxel bar, staggered return mapping)")
    ax.plot([eps_zero * 1e3, permanent * 1e3], [0.0, 0.0], "s", color="C3", ms=6,
            label=f"permanent sets: {eps_zero:.3e}, {permanent:.3e}")
    ax.annotate("yield", (eps1 * 1e3, SIGMA_Y / 1e6), xytext=(eps1 * 1e3 + 0.4, SIGMA_Y / 1e6 - 90),
                arrowprops=dict(arrowstyle="->"))
    ax.set_xlabel("axial strain (x 1e-3)")
    ax.set_ylabel("axial stress (MPa)")
    ax.set_title("von Mises plasticity, E = 200 GPa, sigma_y = 250 MPa, H = 0.05: load, unload, reload")
    ax.title.set_fontsize(9)
    ax.grid(alpha=0.3)
    ax.set_ylim(-15, 420)  # room for the legend above the curve
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(args.out)
    print(f"wrote {args.out} ({Path(args.out).stat().st_size // 1024} kB)")


if __name__ == "__main__":
    main()
