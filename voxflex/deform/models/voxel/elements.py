"""The voxel model's constant stiffness as element matrices (what multigrid's fast path reads)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class ElementMatrices:
    """A voxel stiffness as element matrices: ``K = sum_e scale[e] * units[kind[e]]`` over the grid's voxels.

    Attributes
    ----------
    units : (k, 24, 24) float
        The distinct element matrices (node-major DOFs ``3 * corner + component``).
    kind : (m,) int
        Which one each voxel has (-1: none).
    scale : (m,) float
        Each voxel's factor (its volume).
    """

    units: np.ndarray
    kind: np.ndarray
    scale: np.ndarray


class FreeStiffness:
    """``K[free][:, free]`` of a voxel stiffness given as :class:`ElementMatrices`, never assembled.

    The operator the lean static path solves with above
    :data:`~voxflex.deform.solve.linear.DIRECT_FALLBACK_MAX` unknowns, where
    no direct factorisation would read a stored matrix: multigrid applies its
    finest level through the voxel stencil (built from the same element
    matrices, see :mod:`voxflex.deform.solve.multigrid.stencil`) and forms the
    first coarse level from them, and ``A @ x`` here is the true operator,
    voxel by voxel (576 multiply-adds per voxel), against which multigrid-CG's
    answer is checked.  The stored free block it replaces took 930 bytes per
    DOF (81 entries per row, value and index).

    Parameters
    ----------
    elements : ElementMatrices
    conn : (m, 8) int
        The voxels' nodes (``grid.element_nodes``).
    n_nodes : int
    free : (F,) int
        Sorted unique DOFs ``3 * node + component``.
    """

    def __init__(self, elements: ElementMatrices, conn, n_nodes: int, free):
        self.elements = elements
        self.conn = conn
        self.n_nodes = int(n_nodes)
        self.free = np.asarray(free)
        F = len(self.free)
        self.shape = (F, F)
        self.dtype = np.dtype(np.float64)
        self._diagonal = None

    def __matmul__(self, x):
        from ._kernels import element_matvec

        full = np.zeros(3 * self.n_nodes)
        full[self.free] = x
        e = self.elements
        return element_matvec(e.units, e.kind, e.scale, self.conn, full)[self.free]

    def matvec(self, x):
        """``A @ x`` (for scipy's LinearOperator protocol)."""
        return self @ np.asarray(x, dtype=float).ravel()

    def diagonal(self) -> np.ndarray:
        """The diagonal (F,) of the block (cached)."""
        if self._diagonal is None:
            from ._kernels import element_diagonal

            e = self.elements
            full = element_diagonal(e.units, e.kind, e.scale, self.conn, 3 * self.n_nodes)
            self._diagonal = full[self.free]
        return self._diagonal
