"""The lean static path without a stored finest matrix: FreeStiffness, its stencil and the solve through it."""

from __future__ import annotations

import numpy as np
import pytest

import voxflex.deform.solve.stepping as stepping
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel import _kernels as kern
from voxflex.deform.models.voxel.elements import FreeStiffness
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import FixedRegion, fixed_dofs
from voxflex.deform.solve.linear import solve_linear
from voxflex.deform.solve.multigrid import hierarchy as mg
from voxflex.deform.solve.stepping import solve
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage

CLAMP = FixedRegion([-1, -1, -1], [1e-9, 9, 9])


def _two_material_body():
    """An L-shaped body of two Hooke materials (an interface, a re-entrant corner, surface rows)."""
    lab = np.zeros((16, 6, 5), dtype=np.uint8)
    lab[:, :3] = 1
    lab[:4, 3:] = 1
    lab[8:, :3, 2:] = 2
    model = VoxelModel.from_image(LabelImage(lab, spacing=(0.25, 0.25, 0.25)), {
        1: material("hooke", young=1e4, poisson=0.3, strain="linear"),
        2: material("hooke", young=5e4, poisson=0.45, strain="linear")}, volumetric="auto")
    dofs, _ = fixed_dofs(model, [CLAMP])
    return model, np.setdiff1d(np.arange(3 * model.n_nodes), dofs)


def test_element_product_equals_its_numpy_twin_and_the_assembled_block():
    model, free = _two_material_body()
    e = model.stiffness_elements()
    rng = np.random.default_rng(3)
    x = rng.standard_normal(3 * model.n_nodes)
    y = kern.element_matvec(e.units, e.kind, e.scale, model.grid.element_nodes, x)
    ref = kern.element_matvec_numpy(e.units, e.kind, e.scale, model.grid.element_nodes, x)
    assert np.allclose(y, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    A = model.constant_stiffness_block(free)
    op = model.constant_stiffness_operator(free)
    assert isinstance(op, FreeStiffness) and op.shape == A.shape
    xf = x[free]
    assert np.allclose(op @ xf, A @ xf, rtol=0, atol=1e-12 * np.abs(A @ xf).max())
    assert np.allclose(op.diagonal(), A.diagonal(), rtol=1e-13, atol=0)


def test_element_product_with_its_energy_is_centred():
    """The fused pass returns K x and x^T K x / 2 of the assembled matrix (1e-12), and with each voxel's values
    taken relative to their mean a body translated by 1e8 times its strain keeps its strain energy and forces to
    1e-6, where the global product x . K x loses them to the translation's round-off."""
    model, _ = _two_material_body()
    e = model.stiffness_elements()
    conn = model.grid.element_nodes
    rng = np.random.default_rng(4)
    x = rng.standard_normal(3 * model.n_nodes)
    K = model.hessian(model.rest)
    y, energy = kern.element_matvec_energy(e.units, e.kind, e.scale, conn, x)
    assert np.allclose(y, K @ x, rtol=0, atol=1e-12 * np.abs(K @ x).max())
    assert energy == pytest.approx(0.5 * x @ (K @ x), rel=1e-12)
    shift = np.tile([3e7, -2e7, 1e7], model.n_nodes)  # a translation 1e7-3e7 times the strain's size
    ys, es = kern.element_matvec_energy(e.units, e.kind, e.scale, conn, x + shift)
    assert es == pytest.approx(energy, rel=1e-6)
    assert np.allclose(ys, y, rtol=0, atol=1e-6 * np.abs(y).max())
    plain = 0.5 * (x + shift) @ (K @ (x + shift))
    assert abs(plain - energy) > 1e-3 * energy  # what the centring saves


def test_stencil_rows_from_the_elements_equal_the_stored_ones():
    """The stencil of the matrix-free block stores the rows it does not cover assembled from the element
    matrices of their voxels only: equal to the assembled block's rows, entry by entry (1e-13)."""
    model, free = _two_material_body()
    A = model.constant_stiffness_block(free)
    op = model.constant_stiffness_operator(free)
    mg.clear_cache()
    h = mg.hierarchy(model.grid, free, max_coarse=40)
    s_matrix = h.stencil(A, model.stiffness_elements())
    s_free = h.stencil(op, model.stiffness_elements())
    assert s_matrix.interior_rows == s_free.interior_rows > 0
    assert np.array_equal(s_matrix.b_ptr, s_free.b_ptr) and np.array_equal(s_matrix.b_idx, s_free.b_idx)
    assert np.allclose(s_free.b_val, s_matrix.b_val, rtol=0, atol=1e-13 * np.abs(s_matrix.b_val).max())
    x = np.random.default_rng(0).standard_normal(len(free))
    assert np.allclose(s_free @ x, A @ x, rtol=0, atol=1e-12 * np.abs(A @ x).max())


def test_multigrid_on_the_matrix_free_block_meets_rtol_against_the_true_operator():
    model, free = _two_material_body()
    A = model.constant_stiffness_block(free)
    op = model.constant_stiffness_operator(free)
    b = model.gravity_force({1: 1.0, 2: 1.0}, [0, 0, -9.81]).ravel()[free]
    mg.clear_cache()
    x, info = solve_linear(op, b, method="auto", rtol=1e-10, grid=model.grid, free=free)
    assert info.method == "multigrid" and info.converged
    assert np.linalg.norm(A @ x - b) <= 1.01e-10 * np.linalg.norm(b)
    with pytest.raises(InputError, match="matrix-free"):
        solve_linear(op, b, method="direct")


def test_solve_takes_the_matrix_free_path_above_the_limit_with_the_same_answer(monkeypatch):
    """solve() on a linear static beam: with the direct limit under its DOF count it never assembles the
    free block (constant_stiffness_block is not called), and the tip equals the assembled path's to the
    solver tolerance."""
    image = LabelImage(np.ones((32, 8, 8), dtype=np.uint8), spacing=(0.125, 0.125, 0.125))
    hooke = material("hooke", young=1e4, poisson=0.3, strain="linear")
    kw = dict(fixed=[CLAMP], gravity=[0, 0, -9.81], densities={1: 1.0})
    ref_model = VoxelModel.from_image(image, {1: hooke})
    mg.clear_cache()
    ref = solve(ref_model, **kw)
    monkeypatch.setattr(stepping, "DIRECT_FALLBACK_MAX", 1000)
    model = VoxelModel.from_image(image, {1: hooke})

    def refuse(free):
        raise AssertionError("the matrix-free path assembled the block")

    monkeypatch.setattr(model, "constant_stiffness_block", refuse)
    mg.clear_cache()
    got = solve(model, **kw)
    assert "multigrid" in got[-1].linear_solver
    tip = np.array([[4.0, 0.5, 0.5]])
    u_ref = ref_model.point_mapping(tip).apply(ref[-1].q) - tip
    u = model.point_mapping(tip).apply(got[-1].q) - tip
    assert u_ref[0, 2] < -0.3
    assert np.allclose(u, u_ref, rtol=0, atol=1e-7 * abs(u_ref[0, 2]))
