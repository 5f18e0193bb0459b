"""Trilinear shape functions on voxel corners and the unit-cube quadrature rules."""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.errors import InputError
from voxflex.image.grid import CORNER_OFFSETS, TrilinearGrid, trilinear_weights
from voxflex.image.label_image import LabelImage
from voxflex.sampling.quadrature import (
    gauss_legendre_cube,
    midpoint_cube,
    unit_cube_rule,
)
from voxflex.voronoi.trilinear import trilinear_quadrature_values, trilinear_values


def _rotation(angle=0.3):
    c, s = np.cos(angle), np.sin(angle)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    Rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return Rz @ Rx


def _grid():
    labels = np.zeros((3, 2, 2), dtype=np.uint8)
    labels[:, 0, 0] = 1
    labels[1, 1, 0] = 2
    labels[2, 1, 1] = 1
    image = LabelImage(labels, spacing=(0.5, 0.7, 0.3), origin=(1.0, -2.0, 0.5), direction=_rotation())
    return image, TrilinearGrid.from_image(image)


def test_quadrature_rules_integrate_polynomials_exactly():
    p, w = gauss_legendre_cube(2)
    assert w.sum() == pytest.approx(1.0, abs=1e-15)
    # degree 3 per axis is exact: int_0^1 x^3 y^2 z dx dy dz = 1/4 * 1/3 * 1/2
    assert np.dot(w, p[:, 0] ** 3 * p[:, 1] ** 2 * p[:, 2]) == pytest.approx(1 / 24, rel=1e-14)
    pm, wm = midpoint_cube()
    assert np.dot(wm, pm[:, 0] * pm[:, 1]) == pytest.approx(1 / 4, rel=1e-14)  # degree 1 per axis exact
    with pytest.raises(InputError, match="gauss-legendre"):
        unit_cube_rule("gauss")


def test_weights_partition_of_unity_nonnegative_and_affine_reproduction():
    rng = np.random.default_rng(0)
    xi = rng.random((50, 3))
    w, dw, ddw = trilinear_weights(xi, hessian=True)
    assert np.allclose(w.sum(axis=1), 1.0, atol=1e-15) and w.min() >= 0
    assert np.allclose(dw.sum(axis=1), 0.0, atol=1e-15)
    # affine reproduction: sum_a w_a X_a = xi and sum_a X_a (x) grad w_a = I
    X = CORNER_OFFSETS.astype(float)
    assert np.allclose(w @ X, xi, atol=1e-15)
    assert np.allclose(np.einsum("ai,mak->mik", X, dw), np.eye(3), atol=1e-14)
    # derivatives against central differences (h = 1e-6: error ~1e-12 on O(1) values; trilinear
    # weights are linear along each axis so the truncation error vanishes and 1e-9 is round-off margin)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        wp, dwp, _ = trilinear_weights(xi + e)
        wm, dwm, _ = trilinear_weights(xi - e)
        assert np.allclose((wp - wm) / (2 * h), dw[..., k], atol=1e-9)
        assert np.allclose((dwp - dwm) / (2 * h), ddw[..., k], atol=1e-9)


def test_node_numbering_and_world_gradients():
    image, grid = _grid()
    assert grid.n_elements == int((image.labels > 0).sum())
    # nodes are the unique corners, sorted by linear corner index
    assert np.all(np.diff(grid.node_key) > 0)
    corners = grid.element_ijk[:, None, :] + CORNER_OFFSETS[None]
    assert np.array_equal(grid.node_ijk[grid.element_nodes], corners)
    assert np.allclose(grid.node_positions, image.index_to_world(grid.node_ijk))
    # world gradients at quadrature points reproduce the gradient of any affine field exactly
    local, qw = unit_cube_rule("gauss-legendre")
    sv = trilinear_quadrature_values(grid, local, hessian=True)
    A = np.array([[1.0, 2.0, -1.0], [0.5, -3.0, 0.2], [0.0, 1.0, 4.0]])
    field = grid.node_positions @ A.T + 0.7
    grad = np.einsum("mai,maj->mij", field[sv.index], sv.dw)
    assert np.allclose(grad, A, atol=1e-12)
    assert np.allclose(np.einsum("ma,mai->mi", sv.w, grid.node_positions[sv.index]), sv.rest, atol=1e-13)
    # second derivatives: finite differences of the world gradient along world directions
    pts = sv.rest[:5]
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        sp, sm = trilinear_values(grid, pts + e), trilinear_values(grid, pts - e)
        assert np.array_equal(sp.index, sv.index[:5])
        assert np.allclose((sp.dw - sm.dw) / (2 * h), sv.ddw[:5, :, :, k], atol=1e-6 * np.abs(sv.ddw).max())


def test_locate_points_on_faces_and_outside():
    image, grid = _grid()
    # a point on the far face of the last voxel of the x row (outside the image box's interior)
    tip = image.index_to_world([[3.0, 0.5, 0.5]])
    sv = trilinear_values(grid, tip)
    assert np.allclose(np.einsum("ma,mai->mi", sv.w, grid.node_positions[sv.index]), tip, atol=1e-12)
    # a corner node shared by several voxels
    node = grid.node_positions[[7]]
    sv = trilinear_values(grid, node)
    assert np.isclose(sv.w.max(), 1.0, atol=1e-12)
    # (0, 1.5, 1.5) is in an empty voxel
    with pytest.raises(InputError, match="outside the material"):
        trilinear_values(grid, image.index_to_world([[0.5, 1.5, 1.5]]))
    with pytest.raises(InputError, match="outside the material"):
        trilinear_values(grid, image.index_to_world([[-0.5, 0.5, 0.5]]))
