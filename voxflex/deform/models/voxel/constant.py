"""The voxel model's constant-tangent path: what a linear (constant-tangent) label assembles once.

At rest F = I at every sample of a regular grid, so one evaluation of a constant-tangent material per label
gives every voxel's stiffness up to its volume (:meth:`unit_stiffness`, the element terms with B-bar and the
hourglass stiffness); from it the model builds its quadratic energy (forces ``g0 + K u``), the assembled
free-DOF block of the lean static path (:meth:`constant_stiffness_block`), the matrix-free operator that
replaces it at millions of DOF (:meth:`constant_stiffness_operator`) and the element matrices multigrid forms
its first coarse level from (:meth:`stiffness_elements`).  A mixin of
:class:`~voxflex.deform.models.voxel.model.VoxelModel` (its grid, materials, quadrature and caches).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ....errors import InputError
from ....sampling.quadrature import unit_cube_rule
from . import _kernels as kern
from .fbar import _b_matrices, _deviatoric

__all__ = ["CHUNK_ELEMENTS", "ConstantTangentPath", "tangent_is_constant"]

CHUNK_ELEMENTS = 16384
"""Voxels evaluated per batch (bounds the memory of F, P, A: ~80 MB of tangents with 8 samples each)."""


def tangent_is_constant(material) -> bool:
    """Whether ``material``'s tangent dP/dF does not depend on F (then its stiffness is cached).

    Reads ``material.constant_tangent``; objects that do not declare it are
    treated as nonlinear (their stiffness is reassembled every iteration).
    """
    return bool(getattr(material, "constant_tangent", False))


def _as_slice(ids):
    """A slice for a run of consecutive element ids (views instead of copies), else ``ids``."""
    if len(ids) and int(ids[-1]) - int(ids[0]) + 1 == len(ids):
        return slice(int(ids[0]), int(ids[-1]) + 1)
    return ids


class ConstantTangentPath:
    """The constant-tangent machinery of :class:`~voxflex.deform.models.voxel.model.VoxelModel` (module
    docstring)."""

    def _ensure_pattern(self):
        if self._pattern is None:
            self._pattern = kern.grid_block_pattern(self.grid.element_nodes, self.n_nodes)

    def unit_stiffness(self, label) -> np.ndarray:
        """Stiffness (24, 24) of one voxel of constant-tangent ``label`` per unit volume weight (N/m^4).

        Every voxel of the label has ``element_volume * unit_stiffness``
        (DOF ``3 * corner + component``): the tangent and the gradient table
        are the same in every voxel of a regular grid.
        """
        return self._unit_terms(label)[2]

    def _unit_terms(self, label):
        """Energy (J/m^3), forces (8, 3) (N/m^3) and stiffness (24, 24) of one voxel at rest per unit volume.

        At rest F = I at every sample, so one evaluation of the material at the
        Q quadrature points serves every voxel of the label.  With a reduced
        volumetric term the samples see B-bar, ``B_bar_q = B_q + vec(I) g_q^T``
        with ``g_q = (B_c - B_q)^T vec(I) / 3`` (the dilatation replaced by the
        voxel mean); with mid-point quadrature the hourglass stiffness is added.
        """
        label = int(label)
        if label not in self.materials or not tangent_is_constant(self.materials[label]):
            consts = [lab for lab, _, c in self._groups if c]
            raise InputError(f"label {label} has no constant-tangent material; labels with one: {consts}")
        nq = len(self._qweights)
        F = np.broadcast_to(np.eye(3), (nq, 3, 3)).copy()
        W, P, A = self.materials[label].evaluate(F, tangent=True)
        w0 = float(self._qweights @ W)
        if not (self.volumetric[label] and nq > 1):
            f0 = np.einsum("q,qij,qaj->ai", self._qweights, P, self._G)
            Ku = kern.element_stiffness(self._G, A, self._qweights)[0]
        else:
            B = _b_matrices(self._G)  # (Q, 9, 24)
            i9 = np.eye(3).reshape(9)
            bI = np.einsum("i,qia->qa", i9, B)  # B_q^T vec(I)
            g = (self._qweights @ bI - bI) / 3.0
            B = B + i9[None, :, None] * g[:, None, :]
            f0 = np.einsum("q,qia,qi->a", self._qweights, B, P.reshape(nq, 9)).reshape(8, 3)
            Ku = np.einsum("q,qia,qij,qjb->ab", self._qweights, B, A.reshape(nq, 9, 9), B)
            Ku = 0.5 * (Ku + Ku.T)
        if self.quadrature == "midpoint" and self.hourglass == "stiffness":
            Ku = Ku + self._hourglass_unit(label)
        return w0, f0, Ku

    def _hourglass_unit(self, label) -> np.ndarray:
        """Hourglass stiffness (24, 24) per unit volume (N/m^4): Gauss minus mid-point stiffness of the rest tangent.

        ``sum_q w_q B_q^T C B_q - B_c^T C B_c`` with ``C`` the material's
        tangent at F = I (deviatoric part ``P C P`` when the label's volumetric
        term is reduced); positive semi-definite for a positive semi-definite
        ``C`` and zero on affine displacements.
        """
        C = self.materials[int(label)].evaluate(np.eye(3)[None], tangent=True)[2][0].reshape(9, 9)
        C = 0.5 * (C + C.T)
        if self.volumetric[int(label)]:
            C = _deviatoric(C)
        local, weights = unit_cube_rule("gauss-legendre")
        Bg = _b_matrices(self.grid.reference_gradients(local))
        Bc = np.einsum("q,qia->ia", weights, Bg)
        K = np.einsum("q,qia,ij,qjb->ab", weights, Bg, C, Bg) - Bc.T @ C @ Bc
        return 0.5 * (K + K.T)

    def _quadratic_terms(self):
        """Energy (J) and gradient (n, 3) (N) at rest and unit stiffness per label of the quadratic terms (cached).

        The constant-tangent groups have a quadratic energy
        ``E(q) = E0 + g0 . u + u^T K u / 2`` exactly, with ``E0``, ``g0`` the
        energy and gradient at rest (zero for a stress-free rest state); the
        hourglass stabilisation of nonlinear mid-point groups adds its own
        ``u^T K_hg u / 2``.  ``K`` itself is ``element_volume * unit`` per voxel.
        """
        if self._quadratic is None:
            conn = self.grid.element_nodes
            n = self.n_nodes
            E0 = 0.0
            g0 = np.zeros(3 * n)
            units = {}
            for label, ids, const in self._groups:
                if const:
                    w0, f0, Ku = self._unit_terms(label)
                elif label in self._stabilised:
                    w0, f0, Ku = 0.0, np.zeros((8, 3)), self._hourglass_unit(label)
                else:
                    continue
                units[label] = Ku
                for start in range(0, len(ids), 4 * CHUNK_ELEMENTS):
                    el = _as_slice(ids[start : start + 4 * CHUNK_ELEMENTS])
                    vol = self.element_volume[el]
                    E0 += w0 * float(vol.sum())
                    if np.any(f0 != 0.0):
                        dof = (3 * conn[el])[:, :, None] + np.arange(3)
                        g0 += np.bincount(dof.ravel(), weights=(vol[:, None, None] * f0).ravel(), minlength=3 * n)
            self._quadratic = (E0, g0.reshape(n, 3), units)
        return self._quadratic

    def _constant_data(self, pattern) -> np.ndarray:
        """CSR data (nnz,) of the quadratic terms' stiffness on ``pattern`` (a fresh array, N/m)."""
        _, indices, indptr_b, blockmap = pattern
        data = np.zeros(len(indices))
        conn = self.grid.element_nodes
        units = self._quadratic_terms()[2]
        for label, ids, _ in self._groups:
            if label not in units:
                continue
            for start in range(0, len(ids), 4 * CHUNK_ELEMENTS):
                el = _as_slice(ids[start : start + 4 * CHUNK_ELEMENTS])
                kern.scatter_blocks(units[label][None], conn[el], blockmap[el], indptr_b, data,
                                    scale=self.element_volume[el])
        return data

    def _constant_part(self):
        """Stiffness data, energy and gradient at rest, unit stiffness per label of the quadratic terms (cached).

        See :meth:`_quadratic_terms`; the stiffness data (on the model's
        pattern) is assembled once and shared, read-only, by every Hessian.
        """
        if self._constant is None:
            self._ensure_pattern()
            E0, g0, units = self._quadratic_terms()
            data = self._constant_data(self._pattern)
            data.setflags(write=False)  # shared by every Hessian of an all-constant model
            self._constant = (data, E0, g0, units)
        return self._constant

    def _constant_apply(self, u):
        """``K u`` (n, 3) (N) and ``u^T K u / 2`` (J) of the quadratic terms, in one pass over the voxels.

        Matrix-free: per voxel ``element_volume * unit @ (u_e - mean(u_e))`` (the units annihilate
        translations; taking each voxel's displacements relative to their mean keeps the round-off
        second order in the strain, so a translated, unstrained body has no energy or force of
        ``eps |K| |u|^2``).  The gradients and energies of every model with quadratic terms come from
        here, assembled stiffness or not (the compiled pass beats a product with the assembled matrix:
        23 against 40-50 ms at 418k DOF, and reads no matrix).
        """
        from ._kernels import element_matvec_energy

        u = np.asarray(u, dtype=np.float64).ravel()
        if not u.any():  # the rest state, where every solve starts: K 0 = 0 (a pass over the voxels saved)
            return np.zeros((len(u) // 3, 3)), 0.0
        stack, kind = self._quadratic_kinds()
        Ku, energy = element_matvec_energy(stack, kind, self.element_volume, self.grid.element_nodes, u)
        return Ku.reshape(-1, 3), energy

    def stiffness_elements(self):
        """The constant stiffness as voxel element matrices (:class:`~voxflex.deform.models.voxel.elements.ElementMatrices`).

        ``K = sum_e element_volume[e] * unit[label_e]``: what
        :meth:`constant_stiffness_block` assembles; geometric multigrid forms its
        first coarse level from it.  None unless every material has a constant
        tangent.
        """
        from .elements import ElementMatrices

        if not self.constant_tangent:
            return None
        stack, kind = self._quadratic_kinds()
        return ElementMatrices(stack, kind, self.element_volume)

    def _quadratic_kinds(self):
        """The quadratic terms' distinct unit matrices (k, 24, 24) and which one each voxel has (-1: none), cached."""
        if self._constant_kinds is None:
            units = self._quadratic_terms()[2]
            kind = np.full(len(self.element_volume), -1, dtype=np.int64)
            stack = []
            for label, ids, _ in self._groups:
                if label in units:
                    kind[ids] = len(stack)
                    stack.append(units[label])
            stack = np.array(stack).reshape(-1, 24, 24)
            stack.setflags(write=False)  # shared by every caller (stiffness_elements hands them out)
            kind.setflags(write=False)
            self._constant_kinds = (stack, kind)
        return self._constant_kinds

    def constant_stiffness_block(self, free) -> sp.csr_matrix:
        """The free-DOF block ``K[free][:, free]`` (F, F) of a constant-tangent model's stiffness (N/m), lean.

        For large linear static solves: when the model has no stiffness cached
        yet, the block is assembled on a fresh sparsity pattern and compacted
        in place (:func:`voxflex._linalg.free_block` with
        ``overwrite=True``), so the peak holds one matrix and the pattern's
        voxel block map instead of the full stiffness and its block (the
        model caches neither; its gradients stay matrix-free).  When a
        stiffness is cached (a Hessian was asked for before), the block is a
        copy taken from it.  Equal to ``hessian(q)[free][:, free]`` entry by entry.

        Parameters
        ----------
        free : (F,) int
            Sorted unique DOFs ``3 * node + component``.

        Returns
        -------
        (F, F) csr_matrix, sorted indices (its arrays may be views of larger buffers).

        Raises
        ------
        InputError
            A material without a constant tangent, or ``free`` not sorted unique DOFs.
        """
        from ...._linalg import free_block

        free = self._constant_free(free, "constant_stiffness_block")
        N = 3 * self.n_nodes
        if self._constant is not None:
            data, _, _, _ = self._constant
            H = sp.csr_matrix((data, self._pattern[1], self._pattern[0]), shape=(N, N))
            return free_block(H, free)
        pattern = self._pattern if self._pattern is not None else kern.grid_block_pattern(
            self.grid.element_nodes, self.n_nodes)
        data = self._constant_data(pattern)
        indptr, indices = pattern[:2]
        if pattern is self._pattern:
            indptr, indices = indptr.copy(), indices.copy()  # the cached pattern stays intact
        del pattern  # the block map goes before the compaction
        H = sp.csr_matrix((data, indices, indptr), shape=(N, N))
        return free_block(H, free, overwrite=True)

    def _constant_free(self, free, what: str) -> np.ndarray:
        """``free`` checked for the constant-stiffness accessors: a constant-tangent model and sorted unique
        DOFs ``3 * node + component`` (InputError naming ``what`` otherwise)."""
        if not self.constant_tangent:
            raise InputError(f"{what} needs constant-tangent materials (linear Hooke); use hessian(q) for "
                             "nonlinear ones")
        N = 3 * self.n_nodes
        free = np.asarray(free)
        if free.ndim != 1 or free.dtype.kind not in "iu" or (len(free) and (free[0] < 0 or free[-1] >= N)) or \
                np.any(np.diff(free) <= 0):
            raise InputError(f"free must be sorted unique DOF indices in [0, {N}) (3 * node + component)")
        return free

    def constant_stiffness_operator(self, free):
        """The free-DOF block ``K[free][:, free]`` of a constant-tangent model as a matrix-free operator.

        :class:`~voxflex.deform.models.voxel.elements.FreeStiffness`: its
        element matrices (:meth:`stiffness_elements`) applied voxel by voxel;
        multigrid-CG solves with it through the voxel stencil without a stored
        finest matrix (the lean static path above the direct-solve limit).

        Parameters
        ----------
        free : (F,) int
            Sorted unique DOFs ``3 * node + component``.

        Raises
        ------
        InputError
            A material without a constant tangent, or ``free`` not sorted unique DOFs.
        """
        from .elements import FreeStiffness

        free = self._constant_free(free, "constant_stiffness_operator")
        return FreeStiffness(self.stiffness_elements(), self.grid.element_nodes, self.n_nodes, free)
