"""The voxel model's fused kernels equal the generic chain of mappings.

The voxel model assembles forces and stiffness with its own fast kernel; here
the same quantities are built from the general pieces — trilinear
``ShapeValues`` at the quadrature points, the ``DeformationGradientMapping`` of
point nodes, the material's (W, P, dP/dF) — as  E = sum vol W(F),
f = J^T (vol P), K = J^T blockdiag(vol A) J.  Agreement to round-off (1e-12
relative; both sides sum the same products in a different order) shows that
the reference model is that chain and not a separate implementation.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from voxflex.deform.chain.mappings import DeformationGradientMapping
from voxflex.deform.chain.nodes import Points
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.image import LabelImage
from voxflex.sampling.quadrature import unit_cube_rule
from voxflex.voronoi.trilinear import trilinear_quadrature_values


def _model_and_chain(quadrature):
    labels = np.zeros((3, 2, 2), dtype=np.uint8)
    labels[:2] = 1
    labels[2, :, :1] = 2  # an L-shaped two-material body
    image = LabelImage(labels, spacing=(0.3, 0.2, 0.25), origin=(0.1, -0.2, 0.0))
    mats = {1: material("neo-hookean", young=1e4, poisson=0.3), 2: material("stvk", young=3e4, poisson=0.2)}
    model = VoxelModel.from_image(image, mats, quadrature=quadrature)
    local, weights = unit_cube_rule(quadrature)
    shape = trilinear_quadrature_values(model.grid, local)
    mapping = DeformationGradientMapping(Points(model.rest), shape)
    vol = (model.element_volume[:, None] * weights[None, :]).ravel()
    label = np.repeat(model.element_label, len(weights))
    return model, mapping, vol, label, mats


def _chain(q, mapping, vol, label, mats):
    F = mapping.apply(q)
    W = np.zeros(len(F))
    P = np.zeros_like(F)
    A = np.zeros((len(F), 9, 9))
    for lab, mat in mats.items():
        sel = label == lab
        w, p, a = mat.evaluate(F[sel])
        W[sel], P[sel], A[sel] = w, p, a.reshape(-1, 9, 9)
    J = mapping.jacobian(q)
    energy = float(vol @ W)
    force = mapping.vjp(q, vol[:, None, None] * P)
    K = J.T @ sp.block_diag(list(vol[:, None, None] * A), format="csr") @ J
    return energy, force, K


def _deformed(model, seed=0):
    rng = np.random.default_rng(seed)
    M = np.eye(3) + 0.15 * rng.standard_normal((3, 3))
    return model.rest @ M.T + 0.02 * rng.standard_normal(model.rest.shape)


def test_gauss_legendre_model_is_the_chain():
    model, mapping, vol, label, mats = _model_and_chain("gauss-legendre")
    q = _deformed(model)
    energy, force, K = _chain(q, mapping, vol, label, mats)
    assert abs(model.energy(q) - energy) <= 1e-12 * abs(energy)
    g = model.gradient(q)
    assert np.linalg.norm(g - force) <= 1e-12 * np.linalg.norm(force)
    H = model.hessian(q)
    assert sp.linalg.norm(H - K) <= 1e-12 * sp.linalg.norm(K)


def test_midpoint_model_is_the_chain():
    model, mapping, vol, label, mats = _model_and_chain("midpoint")
    q = _deformed(model, seed=1)
    energy, force, K = _chain(q, mapping, vol, label, mats)
    assert abs(model.energy(q) - energy) <= 1e-12 * abs(energy)
    assert np.linalg.norm(model.gradient(q) - force) <= 1e-12 * np.linalg.norm(force)
    assert sp.linalg.norm(model.hessian(q) - K) <= 1e-12 * sp.linalg.norm(K)
