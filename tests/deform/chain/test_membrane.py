"""Triangle deformation mapping and StVK membrane (voxflex.deform.chain.membrane); derivatives are in the contract."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.chain.membrane import StVKMembrane, TriangleDeformationMapping
from voxflex.errors import InputError


def _square_mesh(k, tilt):
    """A k x k grid of unit-area squares split in triangles, rotated out of the xy plane by ``tilt`` (rad)."""
    g = np.linspace(0.0, 1.0, k + 1)
    X = np.array([[x, y, 0.0] for y in g for x in g])
    tris = []
    for j in range(k):
        for i in range(k):
            a = j * (k + 1) + i
            tris += [[a, a + 1, a + k + 2], [a, a + k + 2, a + k + 1]]
    c, s = np.cos(tilt), np.sin(tilt)
    R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return X @ R.T, np.array(tris)


@pytest.mark.parametrize("tilt", [0.0, 0.7])
def test_uniform_biaxial_stretch_energy_closed_form(tilt):
    X, tris = _square_mesh(3, tilt)
    tri = TriangleDeformationMapping(X, tris)
    assert tri.area.sum() == pytest.approx(1.0, rel=1e-14)
    young, nu, h, s = 2.0e5, 0.3, 1e-3, 1.2
    mem = StVKMembrane(young=young, poisson=nu, thickness=h)
    c = X.mean(axis=0)
    F = tri.apply(c + s * (X - c))
    # F^T F = s^2 I in every triangle; total energy h A (mu/2 + lambda_bar/2) (s^2 - 1)^2 with plane-stress lambda_bar
    mu = young / (2 * (1 + nu))
    lam_bar = young * nu / (1 - nu**2)
    expected = h * 1.0 * (mu / 2 + lam_bar / 2) * (s**2 - 1) ** 2
    total = float(tri.area @ mem.energy(F))
    assert total == pytest.approx(expected, rel=1e-12)  # round-off only
    # in-plane rigid motion: zero energy and stress
    Rz = np.array([[0.6, -0.8, 0], [0.8, 0.6, 0], [0, 0, 1.0]])
    F_rigid = tri.apply(X @ Rz.T + 3.0)
    assert np.abs(mem.energy(F_rigid)).max() < 1e-12 * expected
    assert np.abs(mem.stress(F_rigid)).max() < 1e-9 * mu * h


def test_forces_of_uniform_tension_vanish_inside():
    """Jᵀ (area P) at uniform stretch: interior nodes get no force (patch test), edges get the tension."""
    X, tris = _square_mesh(4, 0.0)
    tri = TriangleDeformationMapping(X, tris)
    mem = StVKMembrane(young=1.0, poisson=0.25, thickness=1.0)
    F = tri.apply(1.1 * X)
    f = tri.vjp(1.1 * X, tri.area[:, None, None] * mem.stress(F))
    interior = np.all((X[:, :2] > 1e-9) & (X[:, :2] < 1 - 1e-9), axis=1)
    assert np.abs(f[interior]).max() < 1e-13
    assert np.abs(f.sum(axis=0)).max() < 1e-13  # equilibrium of the whole sheet
    # the x-force on the right edge equals the x tension resultant P_xx * edge length (1)
    right = X[:, 0] > 1 - 1e-9
    assert f[right, 0].sum() == pytest.approx(mem.stress(F)[0, 0, 0], rel=1e-12)


def test_bad_input():
    X = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    with pytest.raises(InputError, match="degenerate"):
        TriangleDeformationMapping(X, [[0, 1, 2]])
    with pytest.raises(InputError, match="thickness"):
        StVKMembrane(young=1.0, poisson=0.3, thickness=0.0)
    with pytest.raises(InputError, match=r"\(m, 3, 2\)"):
        StVKMembrane(young=1.0, poisson=0.3, thickness=1.0).energy(np.zeros((2, 3, 3)))
