"""From one voxel level to the next: coarsened occupancy and the trilinear prolongations between levels.

Level ``l + 1`` coarsens the occupancy image of level ``l`` by 2 along every axis longer than one voxel
(:func:`coarsen_mask`: a coarse voxel is material when any of its fine voxels is); the prolongation maps
coarse-node displacements to the fine nodes by trilinear interpolation inside the coarse voxel holding
each fine node (:func:`node_prolongation`), the same for each of the 3 components and restricted to the
free DOFs (:func:`dof_prolongation`); :func:`_child_transfers` is the same interpolation from one coarse
voxel to each of its children.  Depends on the grid and the free DOFs only, never on a matrix;
:mod:`voxflex.deform.solve.multigrid.hierarchy` stacks the levels.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ....image.grid import CORNER_OFFSETS


# -- one level of the voxel hierarchy -----------------------------------------
def coarsen_mask(mask) -> np.ndarray:
    """Occupancy (cx, cy, cz) of the 2x-coarsened grid: a coarse voxel is material if any fine one is.

    Axes of length 1 are kept (factor 1); odd lengths round up.

    Parameters
    ----------
    mask : (nx, ny, nz) bool

    Returns
    -------
    (ceil(nx / fx), ceil(ny / fy), ceil(nz / fz)) bool, with f = 2 on axes longer than 1, else 1.
    """
    mask = np.asarray(mask, dtype=bool)
    f = _factors(mask.shape)
    cshape = tuple(-(-n // fa) for n, fa in zip(mask.shape, f))
    padded = np.zeros(tuple(c * fa for c, fa in zip(cshape, f)), dtype=bool)
    padded[: mask.shape[0], : mask.shape[1], : mask.shape[2]] = mask
    return padded.reshape(cshape[0], f[0], cshape[1], f[1], cshape[2], f[2]).any(axis=(1, 3, 5))


def _factors(shape):
    return tuple(2 if n > 1 else 1 for n in shape)


def _nodes(element_ijk, shape):
    """Sorted corner keys (n,) and element nodes (m, 8) of occupied voxels (as TrilinearGrid numbers them)."""
    ny, nz = shape[1], shape[2]
    corners = element_ijk[:, None, :] + CORNER_OFFSETS[None, :, :]
    keys = (corners[..., 0] * (ny + 1) + corners[..., 1]) * (nz + 1) + corners[..., 2]
    node_key = np.unique(keys)
    return node_key, np.searchsorted(node_key, keys).astype(np.int64)


def node_prolongation(element_ijk, element_nodes, n_nodes, shape):
    """Trilinear prolongation from the coarsened grid to the nodes of a voxel grid.

    Parameters
    ----------
    element_ijk : (m, 3) int
        Occupied fine voxels.
    element_nodes : (m, 8) int
        Their nodes (corner order of :data:`~voxflex.image.grid.CORNER_OFFSETS`).
    n_nodes : int
        Number of fine nodes.
    shape : (3,) int
        Fine image shape.

    Returns
    -------
    P : (n_nodes, n_coarse) CSR float, rows sum to 1
    coarse_ijk : (mc, 3) int64, occupied coarse voxels (C order)
    coarse_nodes : (mc, 8) int64, their nodes
    coarse_shape : (3,) tuple
    """
    f = np.array(_factors(shape))
    coarse_shape = tuple(int(-(-n // fa)) for n, fa in zip(shape, f))
    cvox = element_ijk // f
    ckey = np.unique((cvox[:, 0] * coarse_shape[1] + cvox[:, 1]) * coarse_shape[2] + cvox[:, 2])
    coarse_ijk = np.stack([ckey // (coarse_shape[1] * coarse_shape[2]), (ckey // coarse_shape[2]) % coarse_shape[1],
                           ckey % coarse_shape[2]], axis=1).astype(np.int64)
    coarse_key, coarse_nodes = _nodes(coarse_ijk, coarse_shape)
    # one occupied fine voxel per fine node (any will do: interpolation is continuous across coarse faces)
    owner = np.empty(n_nodes, dtype=np.int64)
    corner = np.empty(n_nodes, dtype=np.int64)
    m = len(element_ijk)
    owner[element_nodes.ravel()] = np.repeat(np.arange(m), 8)
    corner[element_nodes.ravel()] = np.tile(np.arange(8), m)
    fine_corner = element_ijk[owner] + CORNER_OFFSETS[corner]  # (n, 3) fine corner index
    base = element_ijk[owner] // f  # (n, 3) coarse voxel holding the node (occupied)
    xi = fine_corner / f - base  # (n, 3) in [0, 1]
    # weight of coarse corner d: the product over the axes of xi (d = 1) or 1 - xi (d = 0)
    lo, hi = 1.0 - xi, xi
    w = np.empty((n_nodes, 8))
    for k, (dx, dy, dz) in enumerate(CORNER_OFFSETS):
        w[:, k] = (hi if dx else lo)[:, 0] * (hi if dy else lo)[:, 1] * (hi if dz else lo)[:, 2]
    # coarse corner node ids through a dense table of the coarse corner grid (keys of base + d)
    stride = np.array([(coarse_shape[1] + 1) * (coarse_shape[2] + 1), coarse_shape[2] + 1, 1])
    table = np.full(int(np.prod(np.array(coarse_shape) + 1)), -1, dtype=np.int64)
    table[coarse_key] = np.arange(len(coarse_key))
    cols = table[(base @ stride)[:, None] + CORNER_OFFSETS @ stride]  # (n, 8), increasing along each row
    keep = w > 0
    # rows in order, their columns increasing (corner keys grow with d in this order): CSR directly
    indptr = np.zeros(n_nodes + 1, dtype=np.int64)
    np.cumsum(keep.sum(axis=1), out=indptr[1:])
    P = sp.csr_matrix((w[keep], cols[keep], indptr), shape=(n_nodes, len(coarse_key)))
    return P, coarse_ijk, coarse_nodes, coarse_shape


def dof_prolongation(P_nodes, free, n_coarse_nodes):
    """``P_nodes`` (n, nc) acting on each of 3 components, restricted to free DOFs.

    Parameters
    ----------
    P_nodes : (n, nc) sparse
    free : (F,) int, sorted free DOFs of the fine level (``3 * node + component``)
    n_coarse_nodes : int

    Returns
    -------
    P : (F, Fc) CSR, the rows at ``free``, the empty columns dropped
    coarse_free : (Fc,) int, the coarse DOFs kept (sorted)
    """
    Pn = sp.csr_matrix(P_nodes)
    node = free // 3
    comp = free % 3
    starts = Pn.indptr[node]
    counts = Pn.indptr[node + 1] - starts
    idx = np.repeat(starts - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts) + np.arange(counts.sum())
    cols = 3 * Pn.indices[idx] + np.repeat(comp, counts)
    vals = Pn.data[idx]
    used = np.zeros(3 * n_coarse_nodes, dtype=bool)
    used[cols] = True
    coarse_free = np.flatnonzero(used)
    place = np.cumsum(used) - 1  # column of a kept coarse DOF (monotone: each row stays sorted)
    indptr = np.zeros(len(free) + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    P = sp.csr_matrix((vals, place[cols], indptr), shape=(len(free), len(coarse_free)))
    return P, coarse_free


def _child_transfers(f):
    """(8, 24, 24): the trilinear prolongation ``T_c`` from a coarse voxel's 24 DOFs to those of its child
    at position ``c = (4 i + 2 j + k)`` (``(i, j, k) < f``; positions beyond f are unused)."""
    T = np.zeros((8, 24, 24))
    for c in range(8):
        p = np.array([(c >> 2) & 1, (c >> 1) & 1, c & 1])
        if np.any(p >= f):
            continue
        xi = (p[None, :] + CORNER_OFFSETS) / f  # (8 fine corners, 3) in the coarse voxel
        w = np.prod(np.where(CORNER_OFFSETS[None, :, :] > 0, xi[:, None, :], 1.0 - xi[:, None, :]), axis=2)
        T[c] = np.kron(w, np.eye(3))
    return T
