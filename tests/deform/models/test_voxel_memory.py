"""Lean linear static solves of the voxel model: the free-DOF stiffness block without the full matrix,
matrix-free application of the constant stiffness."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage


def _model(**kw):
    labels = np.ones((6, 3, 2), dtype=np.uint8)
    labels[3:, :, 1] = 2  # two constant-tangent labels
    mats = {1: material("hooke", young=1e4, poisson=0.3, strain="linear"),
            2: material("hooke", young=3e5, poisson=0.45, strain="linear")}
    return VoxelModel.from_image(LabelImage(labels, spacing=(0.5, 0.3, 0.2)), mats, **kw)


@pytest.mark.parametrize("kw", [{}, {"volumetric": "reduced"}, {"quadrature": "midpoint", "hourglass": "stiffness"}])
def test_constant_stiffness_block_equals_the_hessian_block(kw):
    """Assembled in the same order as the cached Hessian, so equal bitwise; the model caches nothing."""
    free = np.flatnonzero(np.repeat(_model(**kw).rest[:, 0] > 1e-9, 3))
    fresh = _model(**kw)
    B = fresh.constant_stiffness_block(free)
    assert fresh._constant is None and fresh._pattern is None  # neither the matrix nor its pattern is kept
    ref_model = _model(**kw)
    ref = ref_model.hessian(ref_model.rest)[free][:, free]
    assert np.array_equal(B.toarray(), ref.toarray())
    # a model with a cached stiffness gives a copy and keeps its cache intact
    C = ref_model.constant_stiffness_block(free)
    assert np.array_equal(C.toarray(), ref.toarray())
    assert np.array_equal(ref_model.hessian(ref_model.rest)[free][:, free].toarray(), ref.toarray())


def test_matrix_free_gradient_equals_the_assembled_one_and_the_energy_derivative():
    """Without a cached stiffness the gradient is applied voxel by voxel: equal to the CSR product to
    round-off (1e-12 of the largest component: sums of ~200 terms in another order), and to central
    differences of the energy (quadratic energy: the difference is exact up to round-off, 1e-6 relative
    with a step of 1e-4 of the voxel size and energies summed over voxels)."""
    rng = np.random.default_rng(5)
    m1 = _model()
    q = m1.rest + 0.01 * rng.standard_normal(m1.rest.shape)
    g_free = m1.gradient(q)
    assert m1._constant is None  # the gradient did not assemble a matrix
    m2 = _model()
    m2.hessian(m2.rest)
    g_csr = m2.gradient(q)
    assert np.abs(g_free - g_csr).max() <= 1e-12 * np.abs(g_csr).max()
    h = 1e-4 * 0.2
    for i in rng.choice(q.size, 6, replace=False):
        dq = np.zeros(q.size)
        dq[i] = h
        fd = (m1.energy(q + dq.reshape(q.shape)) - m1.energy(q - dq.reshape(q.shape))) / (2 * h)
        assert fd == pytest.approx(g_free.ravel()[i], rel=1e-6, abs=1e-9 * np.abs(g_free).max())


def test_constant_stiffness_block_errors():
    m = _model()
    with pytest.raises(InputError, match="sorted unique"):
        m.constant_stiffness_block(np.array([3, 1]))
    nh = VoxelModel.from_image(LabelImage(np.ones((2, 1, 1))), {1: material("neo-hookean", young=1e3, poisson=0.3)})
    with pytest.raises(InputError, match="constant-tangent"):
        nh.constant_stiffness_block(np.arange(3))
