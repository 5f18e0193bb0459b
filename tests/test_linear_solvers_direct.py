"""Sparse LU with the fill-reducing ordering reused across matrices of one pattern (Newton's tangents)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from voxflex.deform import linear_solvers as ls
from voxflex.deform.materials import material
from voxflex.deform.voxel_model import VoxelModel
from voxflex.image.label_image import LabelImage


def _tangents(count=3):
    model = VoxelModel.from_image(LabelImage(np.ones((6, 2, 2)), spacing=(0.5, 0.5, 0.5)),
                                  {1: material("neo-hookean", young=1e3, poisson=0.3)})
    free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
    rng = np.random.default_rng(1)
    out = []
    for _ in range(count):
        q = model.rest + 0.01 * rng.standard_normal(model.rest.shape)
        out.append(model.hessian(q)[free][:, free])
    return out


def test_direct_reuses_the_ordering_and_matches_dense_solves():
    ls._ORDERING.clear()
    rng = np.random.default_rng(2)
    Ks = _tangents(3)
    for i, K in enumerate(Ks):
        b = rng.standard_normal(K.shape[0])
        x, info = ls.solve_linear(K, b, method="direct")
        ref = np.linalg.solve(K.toarray(), b)
        # LU with partial pivoting on a well-conditioned (cond ~1e3) system: agreement to ~1e-12 relative
        assert np.max(np.abs(x - ref)) <= 1e-10 * np.max(np.abs(ref))
        assert info.residual <= 1e-12
        if i == 0:
            key = ls._ORDERING["key"]
        else:
            assert ls._ORDERING["key"] == key  # same pattern: the ordering was reused, not recomputed
    # the reused ordering gives the factors of a fresh MMD factorisation: same fill
    K = Ks[-1].tocsc()
    p = ls._ORDERING["perm"]
    fresh = sp.linalg.splu(K, permc_spec="MMD_AT_PLUS_A")
    reused = sp.linalg.splu(K[p][:, p].tocsc(), permc_spec="NATURAL")
    assert reused.L.nnz + reused.U.nnz == fresh.L.nnz + fresh.U.nnz


def test_direct_with_a_new_pattern_orders_afresh():
    ls._ORDERING.clear()
    K = _tangents(1)[0]
    ls.solve_linear(K, np.ones(K.shape[0]), method="direct")
    first = ls._ORDERING["key"]
    # a different pattern (a smaller system with its own pattern): new digest, correct answer
    A = sp.csr_matrix(K.toarray()[:30, :30])
    b = np.arange(30, dtype=float) + 1.0
    x, _ = ls.solve_linear(A, b, method="direct")
    assert ls._ORDERING["key"] != first
    np.testing.assert_allclose(A @ x, b, rtol=0, atol=1e-10 * np.abs(b).max())
    # a matrix with unsorted / duplicate entries factorises its summed form
    dup = sp.csr_matrix((np.repeat(A.data / 2, 2), np.repeat(A.indices, 2), 2 * A.indptr), shape=A.shape)
    assert not dup.has_canonical_format  # every entry stored twice, halves
    x2, _ = ls.solve_linear(dup, b, method="direct")
    np.testing.assert_allclose(x2, x, rtol=1e-10, atol=1e-12)
