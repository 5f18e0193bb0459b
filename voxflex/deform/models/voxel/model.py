"""The full-resolution voxel model: trilinear nodes at the corners of occupied voxels.

This is the reference every reduced model is measured against.  Nodes sit at
the corners of the voxels with label > 0; inside each voxel the motion is
trilinear; each voxel is integrated with a quadrature rule on the unit cube
(2x2x2 Gauss-Legendre, or the mid-point rule).  At each sample the chain is

    nodes q (n, 3) --J--> F = sum_a q_a (x) grad w_a --> material (W, P, A)

and the energy, forces and stiffness are ``E = sum vol W(F)``,
``dE/dq = sum vol J^T P`` and ``d2E/dq2 = sum vol J^T A J``.  On a regular grid
the weight gradients at the quadrature points are the same in every voxel, so
``J`` is never stored: a table ``G (Q, 8, 3)`` and the voxel connectivity
replace it.  The Hessian is assembled by a compiled kernel straight into a CSR
pattern computed once from the grid structure (no sort).  Materials whose
tangent does not depend on F (Hooke with linear strain) have a quadratic
energy: every voxel of such a label has the same unit stiffness (24, 24) times
its volume weight, assembled once and cached together with the energy and
gradient at rest, so that ``dE/dq = g0 + K u`` (u = q - rest) costs one sparse
product and ``E = E0 + g0 . u + u^T K u / 2`` one small product per voxel
(on displacements relative to the voxel's mean, so that a translated body
keeps round-off-free energy).

Volumetric locking (``volumetric``): trilinear voxels cannot bend without
changing volume at their Gauss points, so a nearly incompressible body is far
too stiff (a 16x4x4 cantilever bends 5.4x too little at nu = 0.4999).
``volumetric="reduced"`` lets the volumetric part of the energy see one
dilatation per voxel: the F-bar method, ``F_bar_q = (J_c / J_q)^(1/3) F_q`` with
``J_c = det F_c`` at the voxel centre (``F_c`` the mean of the Gauss-point
gradients), the energy ``sum vol W(F_bar)`` and its exact gradient and
Hessian (symmetric: the energy is a function of q).  Materials with a
constant tangent get its linearisation, B-bar (the Gauss-point dilatation
replaced by the voxel mean), which keeps their energy quadratic.  Affine
motions give ``F_bar = F`` (the patch test holds).  With F-bar a Gauss point
cannot pass through ``J = 0`` (its deviatoric part blows up there): samples
whose ``J_q`` and ``J_c`` differ in sign or vanish have infinite energy, and
inverted starts need ``volumetric="full"``.  ``"auto"`` (the scenes' default) chooses
"reduced" for the labels whose material has an effective Poisson ratio
>= 0.4 at rest (read from its rest tangent) and "full" otherwise, so the
peer-library reference numbers at nu = 0.3 are untouched.

Mid-point quadrature: one sample per voxel cannot see the voxel's hourglass
motions (bilinear "checkerboard" modes), so the stiffness has zero modes
besides the 6 rigid motions.  ``hourglass="stiffness"`` adds to every voxel the
Gauss-minus-mid-point difference of its material's stiffness at rest,
``K_hg = sum_q w_q B_q^T C B_q - B_c^T C B_c`` (positive semi-definite, zero
on affine motions, finite rotations included), with ``C`` the rest tangent,
deviatoric part only (``P C P``, P the deviatoric projector) where the
volumetric term is reduced.  For linear elasticity mid-point plus ``K_hg`` is
then exactly the Gauss stiffness (full) or B-bar (reduced); for nonlinear
materials the stabilisation is that linear stiffness on the displacement's
non-affine part (not objective under large rotations of a voxel's hourglass
shape: use Gauss-Legendre for those).  ``hourglass="none"`` keeps the bare
one-point rule (static problems with it are often singular).

Defaults: this class builds the plain rules (``volumetric="full"``,
``hourglass="none"``), the discretisation the peer libraries share and the
tests pin; scenes default to the remedies (``[elasticity] volumetric =
"auto"``, ``hourglass = "stiffness"``).

>>> import numpy as np
>>> from voxflex.image.label_image import LabelImage
>>> from voxflex.deform.materials.constitutive import material
>>> image = LabelImage(np.ones((4, 1, 1)))
>>> model = VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
>>> model.n_nodes, model.n_elements
(20, 4)
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp

from ...._linalg import vdot
from ....errors import InputError, check_choice
from ....image.grid import TrilinearGrid, trilinear_weights
from ....image.surface import boundary_quads, face_points, triangulate
from ....sampling.quadrature import RULES, unit_cube_rule
from ....voronoi.shape_functions import ShapeValues
from ....voronoi.trilinear import trilinear_values
from ...chain.mappings import PointMapping
from ...chain.nodes import Points
from ...materials.constitutive import project_psd
from ...materials.fbar import VOLUMETRIC, _energy_density, nearly_incompressible
from ..protocol import Part, SurfacePoints
from . import _kernels as kern
from .constant import CHUNK_ELEMENTS, ConstantTangentPath, _as_slice, tangent_is_constant
from .fbar import fbar_evaluate
from .kind import HOURGLASS, VOXEL

__all__ = ["VoxelModel", "tangent_is_constant"]

FBAR_CHUNK_ELEMENTS = 4096
"""Voxels per batch with F-bar (three tangent-sized arrays per sample instead of one)."""

I1J_TANGENT = True
"""Materials of the form ``W = a I1 + f(J)`` (neo-Hooke) get their element stiffness from F and three
coefficients per sample (:func:`~voxflex.deform.models.voxel._kernels.element_stiffness_i1j`) instead of
the (9, 9) tangent and the general kernel (False: always the general path; the answers agree to
round-off)."""






class VoxelModel(ConstantTangentPath):
    """Trilinear voxel model of a labelled image (see the module docstring).

    Build with :meth:`from_image`.  The state ``q`` is the (n, 3) array of node
    positions (m); energies are in J, forces in N, stiffness in N/m.

    Attributes
    ----------
    rest : (n, 3) float
        Node rest positions (voxel corners), numbered by sorted corner index.
    grid : TrilinearGrid
    element_label : (m,) int
    element_volume : (m,) float
        Voxel volume times occupancy (m^3).
    quadrature : str
    volumetric : dict label -> bool
        Whether the label's volumetric term is reduced (F-bar / B-bar).
    hourglass : str
        ``"stiffness"`` or ``"none"`` (only acts with mid-point quadrature).
    """

    kind = VOXEL
    node_kind = VOXEL.name
    dofs_per_node = 3

    @property
    def dof_grid(self) -> TrilinearGrid:  # OnVoxelGrid
        """The voxel grid whose corners are the nodes (geometric multigrid uses it)."""
        return self.grid

    def __init__(self, grid: TrilinearGrid, labels, volumes, materials, quadrature, mask, image=None, *,
                 volumetric="full", hourglass="none"):
        self.image = image
        self.grid = grid
        self.rest = grid.node_positions
        self.rest.setflags(write=False)
        self.element_label = np.asarray(labels)
        self.element_volume = np.asarray(volumes, dtype=float)
        self.materials = dict(materials)
        self.quadrature = quadrature
        self._mask = mask
        local, weights = unit_cube_rule(quadrature)
        self._local = local
        self._qweights = weights
        self._G = np.ascontiguousarray(grid.reference_gradients(local))  # (Q, 8, 3)
        nq = len(weights)
        # the same table as matrices for batched products: Gm[a, 3q + j] = Gf[3q + j, a] = G[q, a, j]
        self._Gm = np.ascontiguousarray(self._G.transpose(1, 0, 2).reshape(8, 3 * nq))
        self._Gf = np.ascontiguousarray(self._Gm.T)
        self._groups = []  # (label, element ids, constant tangent)
        for label in np.unique(self.element_label):
            ids = np.flatnonzero(self.element_label == label)
            self._groups.append((int(label), ids, tangent_is_constant(self.materials[int(label)])))
        self._pattern = None
        self._node_type = None
        self._constant = None  # (data, E0, g0, units) of the quadratic terms, built on first use
        self._quadratic = None  # (E0, g0, units) of the quadratic terms: what gradients need without the matrix
        self._constant_kinds = None  # (units stack, kind per voxel) of the quadratic terms (_constant_apply)
        self.volumetric_option = volumetric
        self.volumetric = {}
        for label, _, _ in self._groups:
            mat = self.materials[label]
            self.volumetric[label] = volumetric == "reduced" or (volumetric == "auto" and nearly_incompressible(mat))
        self.hourglass = hourglass
        # quadratic stabilisation of the mid-point rule on the nonlinear labels (constant ones fold it into their unit)
        self._stabilised = {label for label, _, const in self._groups
                            if quadrature == "midpoint" and hourglass == "stiffness" and not const}
        self._project = False  # per-sample tangents projected to PSD in the Hessians (set_tangent_projection)

    # -- construction -------------------------------------------------------
    @classmethod
    def from_image(
        cls,
        image,
        materials: Mapping[int, object],
        *,
        quadrature: str = "gauss-legendre",
        use_occupancy: bool = True,
        volumetric: str = "full",
        hourglass: str = "none",
    ) -> "VoxelModel":
        """Voxel model of ``image`` with one material per label.

        Parameters
        ----------
        image : LabelImage
        materials : mapping label -> Material
            Every label > 0 present in the image needs a material.
        quadrature : {"gauss-legendre", "midpoint"}
            2x2x2 Gauss-Legendre (exact stiffness for linear elasticity) or one
            point per voxel (hourglass modes, see the module docstring).
        use_occupancy : bool
            Scale each voxel's volume by ``image.occupancy`` when the image has one.
        volumetric : {"full", "reduced", "auto"}
            Integration of the volumetric term (see the module docstring):
            plain Gauss (this class's default, the discretisation the peer
            libraries share), F-bar / B-bar for ``"reduced"``; ``"auto"`` (the
            scenes' default, ``[elasticity] volumetric``) reduces it for the
            labels whose material has an effective Poisson ratio >= 0.4 at rest.
        hourglass : {"none", "stiffness"}
            Mid-point quadrature only: keep the bare one-point rule (this
            class's default, the rule itself as the tests and the peer
            libraries define it), or add the rest-stiffness hourglass
            stabilisation (the scenes' default, ``[elasticity] hourglass``).

        Raises
        ------
        InputError
            Empty image, a label without material, an unknown quadrature or option.
        """
        check_choice("quadrature", quadrature, RULES)
        check_choice("volumetric", volumetric, VOLUMETRIC)
        check_choice("hourglass", hourglass, HOURGLASS)
        labels = np.asarray(image.labels)
        mask = labels > 0
        if not np.any(mask):
            raise InputError("the image has no occupied voxel (all labels are 0); give at least one labelled voxel")
        try:
            materials = {int(k): v for k, v in dict(materials).items()}
        except (TypeError, ValueError):
            raise InputError("materials must map integer labels to materials, e.g. {1: material('hooke', ...)}") from None
        present = np.unique(labels[mask]).astype(int)
        missing = [int(lab) for lab in present if lab not in materials]
        if missing:
            raise InputError(
                f"label(s) {missing} in the image have no material; give one per label "
                f"(materials given for {sorted(materials)})"
            )
        for lab in present:
            if not hasattr(materials[int(lab)], "evaluate"):
                raise InputError(f"material for label {lab} has no evaluate(F) method; build it with vf.material(...)")
        grid = TrilinearGrid.from_image(image, mask)
        ijk = grid.element_ijk
        element_label = labels[ijk[:, 0], ijk[:, 1], ijk[:, 2]].astype(np.int64)
        volumes = np.full(len(ijk), float(image.voxel_volume))
        if use_occupancy and image.occupancy is not None:
            volumes *= np.asarray(image.occupancy, dtype=float)[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
        return cls(grid, element_label, volumes, {int(k): materials[int(k)] for k in present}, quadrature, mask, image,
                   volumetric=volumetric, hourglass=hourglass)

    # -- sizes -----------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return self.grid.n_nodes

    @property
    def n_elements(self) -> int:
        return self.grid.n_elements

    @property
    def n_samples(self) -> int:
        return self.n_elements * len(self._qweights)

    @property
    def constant_tangent(self) -> bool:
        """True when every material's tangent is constant (the energy is quadratic in q)."""
        return all(const for _, _, const in self._groups)

    def _check_q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_nodes, 3):
            raise InputError(f"q must have shape ({self.n_nodes}, 3) (node positions), got {q.shape}")
        return q

    # -- kinematics ------------------------------------------------------------
    def _fbar(self, label) -> bool:
        """Whether ``label``'s nonlinear samples use F-bar (reduced volumetric term, several samples per voxel)."""
        return self.volumetric[label] and len(self._qweights) > 1

    def _chunks(self, only_variable=False, only_constant=False, labels=None):
        for label, ids, const in self._groups:
            if (only_variable and const) or (only_constant and not const):
                continue
            if labels is not None and label not in labels:
                continue
            size = FBAR_CHUNK_ELEMENTS if (self._fbar(label) and not const) else CHUNK_ELEMENTS
            for start in range(0, len(ids), size):
                yield label, _as_slice(ids[start : start + size]), const

    def _deformation_gradient(self, q, elements, u=None):
        """F (k * Q, 3, 3) at the samples of ``elements`` (element-major): ``sum_a x_a G_a`` of the positions,
        or ``I + sum_a u_a G_a`` of the displacement ``u`` when given (the same in exact arithmetic, since
        the corner gradients sum to zero; without the round-off of the positions, eps |x| / h)."""
        F = self._gradients_of(q if u is None else u, elements)
        if u is not None:
            for i in range(3):  # in place, the diagonal only (no second (k * Q, 3, 3) array per chunk)
                F[:, i, i] += 1.0
        return F

    def _sample_volumes(self, elements):
        return (self.element_volume[elements][:, None] * self._qweights[None, :]).reshape(-1)

    def deformation_gradients(self, q) -> np.ndarray:
        """F (m * Q, 3, 3) at every sample, element-major (elements in C order of the image)."""
        q = self._check_q(q)
        return self._deformation_gradient(q, np.arange(self.n_elements))

    def _gradients_of(self, x, elements) -> np.ndarray:
        """``sum_a x_a G_a`` (k * Q, 3, 3) at the samples of ``elements`` of the node values x (n, 3), a fresh array."""
        X = x[self.grid.element_nodes[elements]]  # (k, 8, 3)
        # F[e, q] = X[e]^T G[q] as one batch of small products: each stays single-threaded in BLAS
        # (einsum's optimised path makes one large threaded product, 5-10x slower on a busy 2-core machine)
        k = len(X)
        return np.matmul(X.transpose(0, 2, 1), self._Gm).reshape(k, 3, -1, 3).transpose(0, 2, 1, 3).reshape(-1, 3, 3)

    def displacement_gradients(self, u) -> np.ndarray:
        """H = F - I (m * Q, 3, 3) at every sample, element-major, of the displacement ``u`` (n, 3), the identity
        never added (:class:`~voxflex.deform.models.protocol.DisplacementGradients`)."""
        return self._gradients_of(self._check_q(u), np.arange(self.n_elements))

    def sample_volumes(self) -> np.ndarray:
        """Volume weight (m * Q,) of every sample (m^3), element-major."""
        return self._sample_volumes(np.arange(self.n_elements))

    def sample_fields(self, q) -> dict:
        """What result fields are computed from (see :meth:`voxflex.deform.models.protocol.Model.sample_fields`):
        the Gauss points grouped by voxel (cells = voxels, C order), triangles -> the voxel behind them."""
        F = self.deformation_gradients(q)
        nq = len(self._qweights)
        m = self.n_elements
        if getattr(self, "_triangle_cell", None) is None:
            quads, _, normal = boundary_quads(self.grid, self._mask)
            # the voxel behind each face: its centre (index space) half a voxel inside along the normal
            centre = self.grid.world_to_index(self.rest[quads].mean(axis=1))
            ijk = np.floor(centre - 0.5 * normal @ self.grid.direction + 1e-9).astype(np.int64)
            nx, ny, nz = self.grid.shape
            keys = (self.grid.element_ijk[:, 0] * ny + self.grid.element_ijk[:, 1]) * nz + self.grid.element_ijk[:, 2]
            cell = np.searchsorted(keys, (ijk[:, 0] * ny + ijk[:, 1]) * nz + ijk[:, 2])
            self._triangle_cell = np.concatenate([cell, cell])  # triangulate(): two triangles per quad, in order
        return {"F": F, "volume": self.sample_volumes(), "label": np.repeat(self.element_label, nq),
                "cell": np.repeat(np.arange(m), nq), "n_cells": m, "cell_kind": "voxels",
                "materials": self.materials, "triangle_cell": self._triangle_cell}

    # -- energy and derivatives ------------------------------------------------
    def energy(self, q) -> float:
        """Elastic energy (J) at node positions ``q`` (n, 3); inf/NaN when a material is undefined there."""
        return self.energy_gradient_hessian(q, gradient=False, hessian=False)[0]

    def gradient(self, q) -> np.ndarray:
        """dE/dq (n, 3) in N; the internal force is its negative."""
        return self.energy_gradient_hessian(q, hessian=False)[1]

    def hessian(self, q) -> sp.csr_matrix:
        """d2E/dq2 as a (3n, 3n) CSR matrix, DOF ``3 * node + component`` (N/m)."""
        return self.energy_gradient_hessian(q)[2]

    def energy_gradient_hessian(self, q, *, gradient: bool = True, hessian: bool = True):
        """Energy, gradient and Hessian in one pass over the samples.

        Returns
        -------
        energy : float (J)
        gradient : (n, 3) float or None (N)
        hessian : (3n, 3n) csr_matrix or None (N/m)
        """
        return self._evaluate(self._check_q(q), None, gradient, hessian)

    def energy_gradient_hessian_u(self, u, *, gradient: bool = True, hessian: bool = True):
        """:meth:`energy_gradient_hessian` at the displacement ``u = q - rest`` (n, 3) (m): F = I + grad u
        and the quadratic terms' K u from u itself, so no digit of u is lost to the positions' round-off
        (eps |x|; see :class:`~voxflex.deform.models.protocol.FromDisplacement`)."""
        return self._evaluate(None, self._check_q(u), gradient, hessian)  # the positions are never read

    def strain_lengths(self) -> np.ndarray:
        """(n, 3): per DOF, the motion that changes some sample's F by 1 (the inverse of the largest corner
        gradient ``|G_qa|``, about a voxel): F is known to eps, so eps times this is what the forces resolve.
        Zero for a constant-tangent model: its forces are ``g0 + K u``, F is never formed."""
        if self.constant_tangent:
            return np.zeros((self.n_nodes, 3))
        return np.full((self.n_nodes, 3), 1.0 / float(np.linalg.norm(self._G, axis=2).max()))

    def _evaluate(self, q, u, gradient, hessian):
        """Energy, gradient, Hessian at positions q, or from the displacement ``u`` (= q - rest; q then None)."""
        n = self.n_nodes
        energy = 0.0
        grad = np.zeros((n, 3)) if gradient else None
        data = None
        has_constant = any(const for _, _, const in self._groups) or bool(self._stabilised)
        if hessian:
            self._ensure_pattern()
        if has_constant:
            E0, g0, _ = self._quadratic_terms()
            du = q - self.rest if u is None else u  # the displacement of the quadratic terms (the samples keep u)
            energy += E0
            if np.any(du):  # at rest (the first record, a step's start) no pass over the voxels
                Ku, quadratic = self._constant_apply(du)
                energy += vdot(g0.ravel(), du.ravel()) + quadratic
                if gradient:
                    grad += g0 + Ku
            elif gradient:
                grad += g0
            if hessian:
                data_c = self._constant_part()[0]
                # an all-constant model returns the cached (read-only) data itself: no copy per call
                all_constant = all(const for _, _, const in self._groups)
                data = data_c if all_constant else data_c.copy()
        if hessian and data is None:
            data = np.zeros(len(self._pattern[1]))
        if any(not const for _, _, const in self._groups):
            energy += self._sample_pass(q, grad, data, only_variable=True, u=u)
        H = None
        if hessian:
            indptr, indices = self._pattern[:2]
            H = sp.csr_matrix((data, indices, indptr), shape=(3 * n, 3 * n))
        return energy, grad, H

    def set_tangent_projection(self, on: bool) -> bool:
        """Project the per-sample tangents dP/dF to positive semi-definite in later Hessians (``on``), or not.

        F is linear in the node positions, so the assembled Hessian is then positive
        semi-definite (the solvers use it far from equilibrium, see
        :class:`~voxflex.deform.solve.options.SolverOptions`).  F-bar labels keep their exact
        stiffness (their F-bar map is not linear in the nodes).  Returns whether any label's
        tangent is projected (False for an all-constant or all-F-bar model).
        """
        self._project = bool(on)
        return self._project and any(not const and not self._fbar(label) for label, _, const in self._groups)

    def _sample_pass(self, q, grad, data, *, only_variable=False, only_constant=False, u=None):
        """Energy of the selected groups from their samples; adds their gradient into ``grad``
        (n, 3) and their stiffness into the CSR ``data`` when those are not None (F from the displacement
        ``u`` when given, else from the positions ``q``)."""
        energy = 0.0
        n = self.n_nodes
        conn = self.grid.element_nodes
        for label, elements, const in self._chunks(only_variable=only_variable, only_constant=only_constant):
            mat = self.materials[label]
            F = self._deformation_gradient(q, elements, u)
            vol = self._sample_volumes(elements)
            need_tangent = data is not None
            Ke = None
            if self._fbar(label):
                W, P, Ke = fbar_evaluate(mat, F, vol, self._G, self._qweights,
                                         gradient=grad is not None, tangent=need_tangent)
            elif grad is None and not need_tangent:
                W = _energy_density(mat, F)  # energy only (line-search trials)
            elif (need_tangent and I1J_TANGENT and getattr(mat, "linear_in_i1", False)
                  and not (self._project and not const)):
                # neo-Hooke: the element stiffness from F and three coefficients per sample, no (9, 9) tangent
                W, P, (s1, s3, k33, J) = mat.evaluate_i1j(F)
                Ke = kern.element_stiffness_i1j(self._G, F, J, s1, s3, k33, vol)
            else:
                W, P, A = mat.evaluate(F, tangent=need_tangent)
                if need_tangent and self._project and not const:
                    A = project_psd(A)
            energy += vdot(vol, W)
            if grad is not None:
                VP = (P * vol[:, None, None]).reshape(-1, len(self._qweights), 3, 3)
                k = len(VP)
                VP = VP.transpose(0, 2, 1, 3).reshape(k, 3, -1)  # [e, i, 3q + j]
                fe = np.matmul(VP, self._Gf).transpose(0, 2, 1)  # (k, 8, 3): sum_qj vol P_ij G_qaj
                dof = (3 * conn[elements])[:, :, None] + np.arange(3)
                grad += np.bincount(dof.ravel(), weights=fe.ravel(), minlength=3 * n).reshape(n, 3)
            if need_tangent:
                indptr_b, blockmap = self._pattern[2:]
                if Ke is None:
                    Ke = kern.element_stiffness(self._G, A, vol)
                kern.scatter_blocks(Ke, conn[elements], blockmap[elements], indptr_b, data,
                                    ijk=self.grid.element_ijk[elements])
        return energy

    # -- points, mass, loads ---------------------------------------------------
    def point_mapping(self, points) -> PointMapping:
        """Trilinear mapping of material points (m, 3) given at rest (world, m).

        ``x_p = sum_a w_pa q_a`` with the trilinear weights of the voxel
        holding point p (used for probes, loads and surface points).

        Raises
        ------
        InputError
            When a point lies outside the material (names the point).
        """
        return PointMapping(self._points, trilinear_values(self.grid, points))

    @property
    def _points(self) -> Points:
        if self._node_type is None:
            self._node_type = Points(self.rest)
        return self._node_type

    def _densities(self, densities) -> np.ndarray:
        """Density (kg/m^3) of each element from a mapping label -> density."""
        if densities is None:
            raise InputError("densities are needed (mass, gravity, dynamics); give a density per material label")
        try:
            dens = {int(k): float(v) for k, v in dict(densities).items()}
        except (TypeError, ValueError):
            raise InputError("densities must map integer labels to numbers, e.g. {1: 1000.0}") from None
        missing = [int(lab) for lab, _, _ in self._groups if lab not in dens]
        if missing:
            raise InputError(f"label(s) {missing} have no density; give a density per material label")
        bad = {k: v for k, v in dens.items() if not np.isfinite(v) or v < 0}
        if bad:
            raise InputError(f"densities must be finite and >= 0, got {bad}")
        table = np.zeros(int(self.element_label.max()) + 1)
        for lab, _, _ in self._groups:
            table[lab] = dens[lab]
        return table[self.element_label]

    def _mass_rule(self):
        """2x2x2 Gauss-Legendre mass points: exact for products of trilinear weights."""
        local, weights = unit_cube_rule("gauss-legendre")
        w, _, _ = trilinear_weights(local)
        return w, weights  # (Q, 8), (Q,)

    def element_masses(self, densities) -> np.ndarray:
        """Mass (kg) of each voxel: density x volume x occupancy."""
        return self._densities(densities) * self.element_volume

    def mass_matrix(self, densities: Mapping[int, float], *, lumped: bool = True) -> sp.csr_matrix:
        """Mass matrix (3n, 3n) in kg from mass points at the 2x2x2 Gauss points.

        ``M = J^T diag(m_s) J`` with the trilinear mapping J of the mass points
        (consistent, exact for trilinear voxels whatever the stiffness quadrature);
        ``lumped=True`` puts the row sums on the diagonal.
        """
        me = self.element_masses(densities)
        w, qw = self._mass_rule()
        Mref = np.einsum("q,qa,qb->ab", qw, w, w)  # (8, 8), sums to 1
        conn = self.grid.element_nodes
        n = self.n_nodes
        if lumped:
            node_mass = np.bincount(conn.ravel(), weights=(me[:, None] * Mref.sum(axis=1)[None, :]).ravel(), minlength=n)
            return sp.diags(np.repeat(node_mass, 3)).tocsr()
        rows = np.repeat(conn, 8, axis=1).ravel()
        cols = np.tile(conn, (1, 8)).ravel()
        vals = (me[:, None] * Mref.ravel()[None, :]).ravel()
        Mn = sp.coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsr()
        return sp.kron(Mn, sp.identity(3, format="csr"), format="csr")

    def gravity_force(self, densities: Mapping[int, float], g) -> np.ndarray:
        """Nodal gravity force (n, 3) in N: ``J^T (rho g vol)`` at the mass points."""
        g = np.asarray(g, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"gravity must be 3 finite numbers (m/s^2), got {np.asarray(g).tolist()}")
        me = self.element_masses(densities)
        w, qw = self._mass_rule()
        share = qw @ w  # (8,) integral of each weight over the unit cube
        conn = self.grid.element_nodes
        node_mass = np.bincount(conn.ravel(), weights=(me[:, None] * share[None, :]).ravel(), minlength=self.n_nodes)
        return node_mass[:, None] * g[None, :]

    # -- boundary ----------------------------------------------------------------
    def boundary_quads(self):
        """Voxel faces exposed to empty space.

        Returns
        -------
        quads : (F, 4) int64
            Nodes of each face, counter-clockwise seen from outside.
        area : (F,) float (m^2)
        centre : (F, 3) float, rest position (m)
        normal : (F, 3) float, outward unit normal at rest
        """
        quads, area, normal = boundary_quads(self.grid, self._mask)
        return quads, area, self.rest[quads].mean(axis=1), normal

    def boundary_faces(self):
        """Voxel faces exposed to empty space at rest.

        Returns
        -------
        corners : (F, 4, 3) float, counter-clockwise seen from outside (m)
        area : (F,) float (m^2)
        normal : (F, 3) float, outward unit normals
        """
        quads, area, _, normal = self.boundary_quads()
        return self.rest[quads], area, normal

    def boundary_surface(self):
        """Triangulated boundary (faces exposed to empty space), outward orientation.

        Returns
        -------
        vertices_rest : (V, 3) float
        faces : (F, 3) int64, counter-clockwise seen from outside
        mapping : PointMapping
            The vertices' mapping: every vertex is a node, so it selects
            ``q[vertex_node]`` (``mapping.shape.index[:, 0]``).
        """
        vertex_node, faces = triangulate(self.boundary_quads()[0])
        V = self.rest[vertex_node].copy()
        m = len(vertex_node)
        values = ShapeValues(index=vertex_node[:, None], w=np.ones((m, 1)), dw=np.zeros((m, 1, 3)), ddw=None,
                             rest=V, n_nodes=self.n_nodes)
        return V, faces, PointMapping(self._points, values)

    def volume_points(self):
        """The 2x2x2 Gauss points of every voxel and their volumes (m^3, occupancy-weighted)."""
        local, weights = unit_cube_rule("gauss-legendre")
        ijk = self.grid.element_ijk
        pts = (ijk[:, None, :] + local[None, :, :]).reshape(-1, 3)
        vol = (self.element_volume[:, None] * weights[None, :]).reshape(-1)
        return self.grid.index_to_world(pts), vol

    def held_dofs(self, lo, hi, components: str = "xyz") -> np.ndarray:
        """DOFs ``3 * node + c`` of the nodes whose rest position lies in [lo, hi], components ``c`` in ``components``."""
        nodes = self.nodes_in_box(lo, hi)
        comps = np.array(["xyz".index(c) for c in components], dtype=np.int64)
        return np.sort((3 * nodes[:, None] + comps[None, :]).ravel())

    def moved_state(self, transform) -> np.ndarray:
        """Node positions (n, 3) of the body moved by ``[A | t]`` (3, 4)."""
        T = np.asarray(transform, dtype=float)
        return self.rest @ T[:, :3].T + T[:, 3]

    def parts(self) -> list:
        """Material components by face connectivity (voxels sharing only an edge or a corner form a
        hinge), each with the corner nodes of its voxels (:class:`~voxflex.deform.models.protocol.Part`).
        Computed once (a run's guards and its support check both ask: 0.2 s each at 2.4M voxels)."""
        if self.__dict__.get("_parts") is None:
            self._parts = self._find_parts()
        return list(self._parts)

    def _find_parts(self) -> list:
        comps, n = self.image.connected_components(connectivity="face")
        ijk = self.grid.element_ijk
        of_element = comps[ijk[:, 0], ijk[:, 1], ijk[:, 2]] - 1
        order = np.argsort(of_element, kind="stable")
        bounds = np.searchsorted(of_element[order], np.arange(n + 1))
        nodes = []
        seen = np.zeros(self.n_nodes, dtype=bool)
        for c in range(n):
            corners = self.grid.element_nodes[order[bounds[c]:bounds[c + 1]]].ravel()
            if 16 * len(corners) < self.n_nodes:
                nodes.append(np.unique(corners))  # a small island
            else:  # a large component: a mask, O(nodes) (np.unique's hashing took 0.1 s at 131k voxels)
                seen[corners] = True
                nodes.append(np.flatnonzero(seen))
                seen[corners] = False
        for a in nodes:
            a.setflags(write=False)  # shared by every caller of parts()
        return Part.of_components(self.image, comps, nodes)

    def load_surface(self, order: int = 2) -> SurfacePoints:
        """``order`` x ``order`` Gauss points of every voxel face exposed to empty space."""
        corners, area, normal = self.boundary_faces()
        pts, w, face = face_points(corners, area, order)
        return SurfacePoints(pts, w, normal[face], face, corners.mean(axis=1))

    def node_points(self, q):
        """None: voxel corners are not drawn (the surface shows them)."""
        return None

    def point_sample_refusal(self, labels) -> str:
        """Plasticity (internal variables per Gauss point) is evaluated per label in one call: refused on a
        label with F-bar (its map is not per point) or of more than :data:`CHUNK_ELEMENTS` voxels."""
        reduced = sorted(int(lab) for lab in labels if self.volumetric.get(int(lab), False))
        if reduced:
            return (f"plasticity needs the full volumetric term, but label(s) {reduced} use F-bar; [elasticity] "
                    'volumetric = "full" (or a Poisson ratio below 0.4 under "auto")')
        for lab in labels:
            per = int(np.count_nonzero(self.element_label == lab))
            if per > CHUNK_ELEMENTS:
                return (f"plasticity on a voxel label of more than {CHUNK_ELEMENTS} voxels is not supported (label "
                        f"{lab} has {per}); use coarser voxels or affine frames")
        return ""

    supported_by_contact = False  # no obstacles: static scenes must be held by fixed regions

    def begin_step(self, fraction: float, q_prev, q_start):
        """The state a step starts from: ``q_start`` itself (models with obstacles may move it)."""
        return q_start

    def advice(self) -> str:
        """Model-specific advice appended to a solver failure ('' when none)."""
        if self.quadrature == "midpoint" and self.hourglass == "none":
            return ("mid-point quadrature leaves hourglass (zero-energy) modes in trilinear voxels, "
                    'use [elasticity] hourglass = "stiffness" or quadrature = "gauss-legendre"')
        return ""

    def describe(self) -> dict:
        """Attributes of the result file's ``/model`` group."""
        return {"node_kind": self.node_kind, "count": self.n_nodes, "dofs": 3 * self.n_nodes,
                "quadrature": self.quadrature, "samples": self.n_samples, "shape_function": "trilinear",
                "voxels": self.n_elements, "volumetric": self.volumetric_summary(), "hourglass": self.hourglass}

    def volumetric_summary(self) -> str:
        """``"full"``, ``"reduced"``, or ``"reduced for labels [..]"`` when the labels differ."""
        reduced = sorted(lab for lab, red in self.volumetric.items() if red)
        if not reduced:
            return "full"
        if len(reduced) == len(self.volumetric):
            return "reduced"
        return f"reduced for labels {reduced}"

    def nodes_in_box(self, lo, hi) -> np.ndarray:
        """Indices of the nodes whose rest position lies in the box [lo, hi] (inclusive, to 1e-11 of the largest
        voxel edge: a box that ends on a layer of corners holds it in every unit of length, whatever the
        round-off of the corners' coordinates, about 1e-16 of the coordinate; a margin written on purpose,
        ``max = 1 - 1e-9`` on 1 m voxels, still leaves the layer out)."""
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        tol = 1e-11 * float(np.max(self.image.spacing))
        return np.flatnonzero(np.all((self.rest >= lo - tol) & (self.rest <= hi + tol), axis=1))

    def rigid_modes(self) -> np.ndarray:
        """(3n, 6) rigid-body modes (3 translations, 3 infinitesimal rotations about the centroid)."""
        from ...chain.rigid_modes import rigid_body_modes

        return rigid_body_modes(self.rest)
