"""The reduced frame model: a few affine frames skinned over a label image.

``n`` affine frames (12 DOF each: the matrix A row-major, then the origin t;
rest A = I, t = X_a) move the material through shape functions ``w_a(X)``:

    x(X) = sum_a w_a(X) [A_a (X - X_a) + t_a].

The chain of mappings is the deformation core's: at each quadrature sample
``F = sum_a [w_a A_a + (A_a (X - X_a) + t_a) (x) grad w_a]``
(:class:`~voxflex.deform.chain.mappings.DeformationGradientMapping`), then the
material ``W(F)``; the energy is ``E = sum_s vol_s W(F_s)``, the gradient
``J^T (vol P)`` and the Hessian ``J^T blockdiag(vol A) J``.  For affine
frames J does not depend on the state (no geometric stiffness), so it is
assembled once.  Mass, gravity, probes, loads and the visual surface are
further point mappings of the same frames (mass points: the voxel centres,
weighted by density and occupancy; their shape values are evaluated only
when mass or gravity is needed).

Volumetric locking (``volumetric``): a few frames bending a nearly
incompressible body cannot keep every sample's volume, so the body is far too
stiff (a 16x4x4 cantilever with 20 frames bends 10x too little at nu = 0.4999,
``benchmarks/bench_locking.py``).  ``volumetric="reduced"`` integrates the
volumetric term over coarser groups of samples: the samples of one label whose
largest weight is on the same frame (the frame's cell) share the group's
volume-weighted mean ``F_g = sum_s vol_s F_s / sum_s vol_s`` (linear in q), and each
sample sees F-bar, ``F~_s = (det F_g / det F_s)^(1/3) F_s``, or for materials with
a constant tangent its linearisation B-bar, ``F~_s = F_s + (tr F_g - tr F_s) I / 3``.
The energy is ``sum_s vol_s W(F~_s)``, with its exact gradient and Hessian (every
sample of a group couples with the group's mean: dense within a group, numpy,
sparse products ``J^T C J_g``; one energy, gradient and Hessian pass of a neo-Hooke
cantilever with 20 frames and 200 samples takes about 30 ms against 0.9 ms in
full, 76 ms against 7.5 ms with 50 frames and 2048 Gauss samples, 2 CPUs: no
compiled kernel yet).  Affine motions give ``F~ = F`` (the patch
test holds).  As with the voxel model a sample cannot pass through zero volume
(infinite energy where ``det F_s det F_g <= 0``).  ``"auto"`` reduces the labels
whose effective Poisson ratio at rest is >= 0.4
(:func:`~voxflex.deform.materials.fbar.nearly_incompressible`); elastons always
integrate it in full (``"reduced"`` is refused there).  The class default is
``"full"``; scenes build frames with ``"full"`` unless they say ``[elasticity]
volumetric = "reduced"`` (their ``"auto"`` stays ``"full"`` for frames).  Measured
(``benchmarks/bench_locking.py``): the reduced term removes the locking (the tip
changes by < 10 % from nu = 0.3 to 0.4999, against 90 % with ``"full"`` and 20
frames) but the groups span the beam's section, the affine frames cannot give the
Poisson contraction's variation across it, and the cantilever comes out 12-74 %
softer than the beam-theory trend from the full nu = 0.3 value.

The model satisfies the protocol of :mod:`voxflex.deform.models.protocol`, so the same
solvers, loads, result files and renders run it.

Mass: ``consistent`` is ``J^T diag(m) J`` over the 2x2x2 Gauss points of
every voxel (dense 12x12 blocks between frames that share material);
``lumped`` gives every voxel centre's mass to its frames in proportion to
their weights, each frame carrying its share as its own affine body
(block-diagonal, symmetric positive definite, exact total mass and momentum).

Example
-------
>>> import numpy as np
>>> from voxflex.image.label_image import LabelImage
>>> from voxflex.deform.materials.constitutive import material
>>> from voxflex.voronoi.shape_functions import shepard
>>> image = LabelImage(np.ones((4, 2, 2)))
>>> frames = np.array([[0.5, 1.0, 1.0], [3.5, 1.0, 1.0]])
>>> model = FrameModel.from_image(image, frames, lambda p: shepard(p, frames),
...                               {1: material("hooke", young=1e3, poisson=0.3)})
>>> model.rest.shape, model.node_kind
((2, 12), 'affine')
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp

from ...._linalg import vdot
from ....errors import InputError, check_choice
from ....image.grid import TrilinearGrid
from ....image.surface import boundary_quads, face_points, triangulate
from ....sampling.voxel import voxel_samples
from ...chain.mappings import (
    DeformationGradientMapping,
    DeformationGradientWithGradientMapping,
    PointMapping,
)
from ...chain.nodes import AffineFrames
from ...materials.constitutive import project_psd
from ...materials.fbar import VOLUMETRIC, _bar_evaluate, nearly_incompressible
from ..protocol import OnePass, Part, SurfacePoints
from . import _kernels as K
from ._kernels import frame_tables
from .kind import AFFINE

__all__ = ["FrameModel"]

ELASTON_CHUNK = 1 << 22
"""Entries of the elastons' dense Hessian blocks ``J_e^T D_e J_e`` formed at a time (32 MB)."""



def elastons_take(material) -> bool:
    """Whether elaston quadrature takes ``material``: its strain's second derivative must be constant (an exact
    Hessian of the strain's gradient term).  The one definition the model's check and every piece of advice
    that suggests elastons read."""
    return bool(getattr(getattr(material, "strain", None), "constant_hessian", False))

class FrameModel(OnePass):
    """Affine frames over a label image (see the module docstring).

    Build with :meth:`from_image`.  The state ``q`` is ``(n, 12)``; energies
    in J, generalised forces in N (translations) and N m (matrix entries).

    Attributes
    ----------
    image : LabelImage
    frames : (n, 3) float, rest positions X_a (m)
    samples : VoxelSamples (or the sampling stage's Samples)
    materials : {label: Material}
    """

    kind = AFFINE
    node_kind = AFFINE.name
    dofs_per_node = 12

    def __init__(self, image, frames, shape_function, samples, materials, *, info=None, use_occupancy=True,
                 volumetric="full"):
        self.image = image
        self.frames = np.asarray(frames, dtype=float)
        self.nodes = AffineFrames(self.frames)
        self.rest = self.nodes.rest
        self.rest.setflags(write=False)
        self.shape_function = shape_function
        self.samples = samples
        self.materials = dict(materials)
        self.use_occupancy = bool(use_occupancy)
        self.info = dict(info or {})
        self.elaston = samples.kind == "elaston"
        if self.elaston:
            self._fmap = DeformationGradientWithGradientMapping(self.nodes, samples.values)
            for label, mat in self.materials.items():
                if not elastons_take(mat):
                    raise InputError(
                        f"elaston quadrature integrates the strain's gradient and needs a strain whose second "
                        f"derivative is constant for an exact Hessian (linear, green, corotational-small); label "
                        f"{label} uses '{getattr(getattr(mat, 'strain', None), 'name', type(mat).__name__)}': use quadrature = \"midpoint\" or \"gauss-legendre\", "
                        f"or one of those strains"
                    )
        else:
            self._fmap = DeformationGradientMapping(self.nodes, samples.values)
            # the structured kernels: F = (I3 (x) G) d, forces and stiffness per sample (_frame_kernels);
            # parents sorted by frame and the coupled frame pairs, once
            self._index, self._G, self._pairs, self._pair_id = K.frame_pairs(
                samples.values.index, frame_tables(samples.values, self.frames), len(self.frames))
        check_choice("volumetric", volumetric, VOLUMETRIC)
        if self.elaston and volumetric == "reduced":
            raise InputError('volumetric = "reduced" needs point samples (F-bar over groups of samples); elaston '
                             'quadrature integrates the volumetric term in full: use "auto" or "full", or '
                             'quadrature = "midpoint" or "gauss-legendre"')
        self.volumetric_option = volumetric
        self.volumetric = {int(lab): (not self.elaston) and (volumetric == "reduced" or (
            volumetric == "auto" and nearly_incompressible(mat))) for lab, mat in self.materials.items()}
        self._bar = None
        self._J = None
        self._elaston_gather = None
        self._groups = [(int(lab), np.flatnonzero(samples.label == lab)) for lab in np.unique(samples.label)]
        self._volume = np.ascontiguousarray(samples.volume, dtype=float)
        self._surface = None
        self._mass_map_cache = None
        self._mass_points_cache = None
        self._project = False  # per-sample tangents projected to PSD in the Hessians (set_tangent_projection)

    # -- construction -------------------------------------------------------
    @classmethod
    def from_image(cls, image, frames, shape_function, materials: Mapping[int, object], *, samples=None,
                   quadrature: str = "gauss-legendre", use_occupancy: bool = True, info=None,
                   volumetric: str = "full") -> "FrameModel":
        """Frame model of ``image`` with frames at ``frames`` (n, 3) and shape functions ``shape_function``.

        Parameters
        ----------
        image : LabelImage
        frames : (n, 3) float, world rest positions of the frames (m)
        shape_function : callable
            ``shape_function(points (m, 3)) -> ShapeValues`` over the frames.
        materials : mapping label -> Material
        samples : optional
            Quadrature samples (attributes of :class:`VoxelSamples`); default:
            ``quadrature`` per voxel (``"gauss-legendre"`` or ``"midpoint"``).
        use_occupancy : bool
            Weight volumes and masses by the image's occupancy fractions.
        volumetric : {"full", "reduced", "auto"}
            Integration of the volumetric term (module docstring): every sample
            (``"full"``), F-bar / B-bar over the samples of each frame's cell
            (``"reduced"``), or reduced for labels with an effective Poisson
            ratio >= 0.4 (``"auto"``, the scenes' default).

        Raises
        ------
        InputError
            No frame, a label without material, shape functions that do not fit the frames,
            an unknown ``volumetric`` or ``"reduced"`` with elastons.
        """
        frames = np.asarray(frames, dtype=float)
        if frames.ndim != 2 or frames.shape[1] != 3 or len(frames) == 0:
            raise InputError(f"frames must be a non-empty (n, 3) array of world positions, got shape {frames.shape}")
        labels = np.asarray(image.labels)
        present = np.unique(labels[labels > 0]).astype(int)
        if len(present) == 0:
            raise InputError("the image has no material (every label is 0); voxelize a non-empty object")
        materials = {int(k): v for k, v in dict(materials).items()}
        missing = [int(lab) for lab in present if lab not in materials]
        if missing:
            raise InputError(f"label(s) {missing} in the image have no material; give one per label")
        if samples is None:
            samples = voxel_samples(image, shape_function, rule=quadrature, use_occupancy=use_occupancy)
        if samples.values.n_nodes is not None and samples.values.n_nodes != len(frames):
            raise InputError(
                f"the samples' shape functions were built for {samples.values.n_nodes} frames, not {len(frames)}"
            )
        return cls(image, frames, shape_function, samples, {int(k): materials[int(k)] for k in present},
                   info=info, use_occupancy=use_occupancy, volumetric=volumetric)

    # -- sizes -----------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return self.nodes.n

    @property
    def n_samples(self) -> int:
        return len(self.samples.volume)

    @property
    def constant_tangent(self) -> bool:
        return all(bool(getattr(m, "constant_tangent", False)) for m in self.materials.values())

    def _check_q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_nodes, 12):
            raise InputError(f"q must have shape ({self.n_nodes}, 12) (A row-major, then t, per frame), got {q.shape}")
        return q

    # -- energy ----------------------------------------------------------------
    def jacobian(self) -> sp.csr_matrix:
        """dF/dq at the samples (9m, 12n) — or d(F, grad F)/dq (36m, 12n) for elastons — constant for
        affine frames (assembled once)."""
        if self._J is None:
            self._J = self._fmap.jacobian(self.rest).tocsr()
        return self._J

    def deformation_gradients(self, q) -> np.ndarray:
        """F (m, 3, 3) at the samples."""
        q = self._check_q(q)
        if self.elaston:
            return self._fmap.apply(q)[0]
        F = np.empty((self.n_samples, 3, 3))
        K.frame_F(self._index, self._G, np.ascontiguousarray(q), F)
        return F

    def sample_fields(self, q) -> dict:
        """What result fields are computed from (see :meth:`voxflex.deform.models.protocol.Model.sample_fields`): every
        sample its own cell; on the surface, F through the frames at the centre of the voxel behind each face."""
        if getattr(self, "_surface_fmap", None) is None:
            corners, _, normal = self.boundary_faces()
            half = 0.5 * np.abs(normal @ self.image.direction) @ self.image.spacing  # half a voxel along the normal
            pts = corners.mean(axis=1) - half[:, None] * normal
            ijk = np.floor(self._grid().world_to_index(pts)).astype(np.int64)
            self._surface_fmap = (DeformationGradientMapping(self.nodes, self.shape_function(pts)),
                                  self.image.labels[ijk[:, 0], ijk[:, 1], ijk[:, 2]].astype(np.int64))
        nf = len(self._surface["quads"][0])
        s = self.samples
        return {"F": self.deformation_gradients(q), "volume": s.volume, "label": s.label,
                "cell": np.arange(len(s.volume)), "n_cells": len(s.volume), "cell_kind": "samples",
                "materials": self.materials, "surface_F": self._surface_fmap[0].apply(self._check_q(q)),
                "surface_label": self._surface_fmap[1], "triangle_point": np.tile(np.arange(nf), 2)}

    def set_tangent_projection(self, on: bool) -> bool:
        """Project the per-sample tangents dP/dF to positive semi-definite in later Hessians (``on``), or not.

        F is linear in the affine frames' DOFs, so the Hessian is then positive
        semi-definite.  Point samples with every volumetric term in full only: elastons
        and reduced (F-bar) volumetric labels keep their exact Hessian.  Returns whether
        the tangents are projected.
        """
        self._project = bool(on) and not self.elaston and not any(self.volumetric.values())
        return self._project and not self.constant_tangent

    def energy_gradient_hessian(self, q, *, gradient: bool = True, hessian: bool = True):
        """Energy (J), gradient (n, 12) and Hessian (12n, 12n) in one pass over the samples.

        The Hessian is a dense ndarray (frames sharing material couple, so it is nearly full)."""
        q = self._check_q(q)
        if self.elaston:
            return self._elaston_pass(q, gradient, hessian)
        if any(self.volumetric.values()):
            return self._reduced_pass(q, gradient, hessian)
        vol = self._volume
        m = len(vol)
        F = np.empty((m, 3, 3))
        K.frame_F(self._index, self._G, np.ascontiguousarray(q), F)
        if len(self._groups) == 1:  # one material: its arrays as they come, no gather or scatter
            label = self._groups[0][0]
            W, P, A = self.materials[label].evaluate(F, tangent=hessian)
            energy = vdot(vol, W)
            if hessian and self._project and not self.constant_tangent:
                A = project_psd(A)
        else:
            energy = 0.0
            P = np.empty((m, 3, 3))
            A = np.empty((m, 3, 3, 3, 3)) if hessian else None
            for label, ids in self._groups:
                Wg, P[ids], Ag = self.materials[label].evaluate(F[ids], tangent=hessian)
                energy += vdot(vol[ids], Wg)
                if hessian:
                    A[ids] = project_psd(Ag) if self._project and not self.materials[label].constant_tangent else Ag
        grad = None
        if gradient:
            grad = np.zeros((self.n_nodes, 12))
            K.frame_forces(self._index, self._G, P, vol, grad)
        H = None
        if hessian:
            # a dense Hessian: frames sharing material couple (the solver takes it as is)
            H = K.frame_stiffness_dense(self._index, self._G, A, self.n_nodes, vol,
                                        (self._index, self._G, self._pairs, self._pair_id))
        return float(energy), grad, H

    def _bar_tables(self):
        """Groups of the reduced samples (label, largest-weight frame), their averaging matrix
        ``vec F_g = Avg vec F`` (9 ng, 9 m) and ``J_g = Avg J`` (9 ng, 12 n), once."""
        if self._bar is None:
            v = self.samples.values
            m = self.n_samples
            red_labels = [lab for lab, red in self.volumetric.items() if red]
            ids = np.flatnonzero(np.isin(self.samples.label, red_labels))
            wmax = np.where(v.index[ids] >= 0, v.w[ids], -np.inf)
            dom = v.index[ids, np.argmax(wmax, axis=1)].astype(np.int64)
            key = self.samples.label[ids].astype(np.int64) * self.n_nodes + dom
            _, gid = np.unique(key, return_inverse=True)
            gid = gid.reshape(-1)
            vol = self._volume[ids]
            Vg = np.bincount(gid, vol)
            wts = np.divide(vol, Vg[gid], out=np.zeros_like(vol), where=Vg[gid] > 0)
            ng = len(Vg)
            group = np.full(m, -1, dtype=np.int64)
            group[ids] = gid
            rows = (9 * gid[:, None] + np.arange(9)).ravel()
            cols = (9 * ids[:, None] + np.arange(9)).ravel()
            Avg = sp.csr_matrix((np.repeat(wts, 9), (rows, cols)), shape=(9 * ng, 9 * m))
            self._bar = {"group": group, "Vg": Vg, "ng": ng, "Avg": Avg, "Jg": (Avg @ self.jacobian()).tocsr()}
        return self._bar

    def _reduced_pass(self, q, gradient, hessian):
        """Point samples with the volumetric term of some labels reduced over groups (F-bar / B-bar).

        Per sample ``W(Phi(F_s, F_g))``: its derivatives in (F_s, F_g) from :func:`_bar_evaluate`,
        chained through ``F_g = Avg F``; the Hessian is the dense kernel on the (F_s, F_s) blocks
        plus ``J^T C J_g + (J^T C J_g)^T + J_g^T D J_g`` (C: the (F_s, F_g) blocks, D: the (F_g, F_g)
        blocks summed per group), numpy and scipy.sparse.
        """
        tab = self._bar_tables()
        vol = self._volume
        m, n, ng = len(vol), self.n_nodes, tab["ng"]
        group = tab["group"]
        F = np.empty((m, 3, 3))
        K.frame_F(self._index, self._G, np.ascontiguousarray(q), F)
        Fg = (tab["Avg"] @ F.reshape(-1)).reshape(ng, 3, 3)
        want = gradient or hessian
        energy = 0.0
        P = np.zeros((m, 9)) if want else None
        A = np.zeros((m, 9, 9)) if hessian else None
        SB = np.zeros((ng, 9))
        C = np.zeros((m, 9, 9)) if hessian else None
        D = np.zeros((ng, 9, 9)) if hessian else None
        for label, ids in self._groups:
            mat = self.materials[label]
            if not self.volumetric[label]:
                W, Pl, Al = mat.evaluate(F[ids], tangent=hessian)
                energy += vdot(vol[ids], W)
                if want:
                    P[ids] = Pl.reshape(-1, 9)
                if hessian:
                    A[ids] = Al.reshape(-1, 9, 9)
                continue
            g = group[ids]
            out = _bar_evaluate(mat, F[ids], Fg[g], linear=bool(getattr(mat, "constant_tangent", False)),
                                gradient=want, tangent=hessian)
            energy += vdot(vol[ids], out[0])
            if want:
                P[ids] = out[1]
                np.add.at(SB, g, vol[ids, None] * out[2])
            if hessian:
                A[ids] = out[3]
                C[ids] = vol[ids, None, None] * out[4]
                np.add.at(D, g, vol[ids, None, None] * out[5])
        if not want:
            return float(energy), None, None
        Vg = tab["Vg"]
        red = group >= 0
        P[red] += np.divide(SB, Vg[:, None], out=np.zeros_like(SB), where=Vg[:, None] > 0)[group[red]]
        grad = None
        if gradient:
            grad = np.zeros((n, 12))
            K.frame_forces(self._index, self._G, P.reshape(m, 3, 3), vol, grad)
        H = None
        if hessian:
            H = K.frame_stiffness_dense(self._index, self._G, A.reshape(m, 3, 3, 3, 3), n, vol,
                                        (self._index, self._G, self._pairs, self._pair_id))
            J, Jg = self.jacobian(), tab["Jg"]
            rid = np.flatnonzero(red)
            Cm = sp.bsr_matrix((C[rid], group[rid], np.searchsorted(rid, np.arange(m + 1))),
                               shape=(9 * m, 9 * ng)).tocsr()
            X = ((J.T @ Cm) @ Jg).toarray()
            Dm = sp.bsr_matrix((D, np.arange(ng), np.arange(ng + 1)), shape=(9 * ng, 9 * ng)).tocsr()
            H += X + X.T + (Jg.T @ (Dm @ Jg)).toarray()
        return float(energy), grad, H

    def _elaston_pass(self, q, gradient, hessian):
        """Elastons: the energy of the strain's linear variation over each region from (F, grad F)
        and the region's moments (:func:`voxflex.deform.materials.elaston.material_elaston_energy`)."""
        from ...materials.elaston import material_elaston_energy

        F, dF = self._fmap.apply(q)
        s = self.samples
        m = len(s.volume)
        energy = 0.0
        gF = np.zeros((m, 3, 3))
        gdF = np.zeros((m, 3, 3, 3))
        blocks = np.zeros((m, 36, 36)) if hessian else None
        M1, M2 = s.M1, s.M2
        for label, ids in self._groups:
            out = material_elaston_energy(self.materials[label], F[ids], dF[ids], s.volume[ids], M1[ids], M2[ids],
                                          hessian=hessian)
            energy += float(out.energy.sum())
            gF[ids], gdF[ids] = out.grad_F, out.grad_dF
            if hessian:
                h = out.hessian
                k = len(ids)
                b = np.zeros((k, 36, 36))
                b[:, :9, :9] = h.FF.reshape(k, 9, 9)
                b[:, :9, 9:] = h.FdF.reshape(k, 9, 27)
                b[:, 9:, :9] = b[:, :9, 9:].transpose(0, 2, 1)
                b[:, 9:, 9:] = h.dFdF.reshape(k, 27, 27)
                blocks[ids] = b
        grad = self._fmap.vjp(q, (gF, gdF)) if gradient else None
        H = None
        if hessian:
            # sum_e J_e^T D_e J_e with J_e the elaston's 36 rows on the columns they touch (its parents'
            # DOFs), dense, by chunks of at most 2^22 entries (32 MB) so that many elastons of many
            # parents stay lean: 400 elastons of 6 parents (capsule, 20 frames) in 21 ms against 120 ms
            # for the sparse J^T (D J) (min of 20, one run; with np.add.at in place of bincount, twice as long)
            Je, idx, flat_all = self._elaston_rows()
            N = 12 * self.n_nodes
            H = np.zeros(N * N)
            C = Je.shape[2]
            step = max(1, ELASTON_CHUNK // (C * C))
            for a in range(0, m, step):
                b = slice(a, a + step)
                He = np.matmul(Je[b].transpose(0, 2, 1), np.matmul(blocks[b], Je[b]))
                single = flat_all is not None and step >= m  # one chunk: the index kept at build
                flat = flat_all if single else (idx[b, :, None] * N + idx[b, None, :]).ravel()
                if N * N <= ELASTON_CHUNK:  # a dense count of the small Hessian is the fastest sum
                    H += np.bincount(flat, weights=He.ravel(), minlength=N * N)
                else:
                    np.add.at(H, flat, He.ravel())
            H = H.reshape(N, N)
            H = 0.5 * (H + H.T)
        return float(energy), grad, H

    def _elaston_rows(self):
        """``Je (m, 36, C)``: each elaston's rows of the (F, grad F) Jacobian on the C columns it touches
        (padded with zero columns), those columns ``(m, C)`` (0 for the padding) and, when the blocks
        fit one chunk (``m C^2 <=`` :data:`ELASTON_CHUNK`), the flat index ``(m C^2,)`` of each block
        entry in the (12n, 12n) Hessian (else None: each chunk computes its own); built once from
        :meth:`jacobian` (constant for affine frames)."""
        if self._elaston_gather is None:
            J = self.jacobian().copy()
            J.sum_duplicates()  # one entry per (row, column): the gather below assigns
            m, N = J.shape[0] // 36, J.shape[1]
            row = np.repeat(np.arange(J.shape[0]), np.diff(J.indptr))
            key = (row // 36) * N + J.indices  # (elaston, column) of every entry
            cols, inv = np.unique(key, return_inverse=True)
            first = np.searchsorted(cols, np.arange(m) * N)  # where each elaston's columns start
            count = np.diff(np.append(first, len(cols)))
            C = max(int(count.max()), 1) if m else 1
            Je = np.zeros((m, 36, C))
            pos = inv - first[row // 36]
            Je[row // 36, row % 36, pos] = J.data
            idx = np.zeros((m, C), dtype=np.int64)
            e = np.repeat(np.arange(m), count)
            idx[e, np.arange(len(cols)) - first[e]] = cols % N
            flat = None
            if m * C * C <= ELASTON_CHUNK:
                dt = np.int32 if N * N < np.iinfo(np.int32).max else np.int64
                flat = (idx[:, :, None] * N + idx[:, None, :]).astype(dt).ravel()
            self._elaston_gather = (Je, idx, flat)
        return self._elaston_gather

    # -- mass and gravity --------------------------------------------------------
    def _mass_points(self):
        """Mass points: the voxel centres, their volumes (occupancy-weighted) and labels (no shape values)."""
        if self._mass_points_cache is None:
            ijk = np.argwhere(self.image.labels > 0)
            vol = np.full(len(ijk), float(self.image.voxel_volume))
            if self.use_occupancy and self.image.occupancy is not None:
                vol = vol * np.asarray(self.image.occupancy, dtype=float)[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
            label = self.image.labels[ijk[:, 0], ijk[:, 1], ijk[:, 2]].astype(np.int64)
            self._mass_points_cache = (self.image.index_to_world(ijk + 0.5), vol, label)
        return self._mass_points_cache

    def _mass_layer(self):
        """Mass points' volumes, labels and their mapping (shape functions evaluated once, on demand)."""
        if self._mass_map_cache is None:
            pts, vol, label = self._mass_points()
            self._mass_map_cache = (vol, label, PointMapping(self.nodes, self.shape_function(pts)))
        return self._mass_map_cache

    def _point_masses(self, densities) -> np.ndarray:
        if densities is None:
            raise InputError("densities are needed (mass, gravity, dynamics); give a density per material label")
        _, vol, label = self._mass_points()
        dens = {int(k): float(v) for k, v in dict(densities).items()}
        missing = sorted({int(x) for x in np.unique(label)} - set(dens))
        if missing:
            raise InputError(f"label(s) {missing} have no density; give a density per material label")
        table = np.zeros(int(label.max()) + 1)
        for k, v in dens.items():
            if k < len(table):
                table[k] = v
        return table[label] * vol

    def mass_matrix(self, densities: Mapping[int, float], *, lumped: bool = True) -> sp.csr_matrix:
        """Mass matrix (12n, 12n): consistent ``J^T diag(m) J`` or lumped per frame (see the module docstring)."""
        mp = self._point_masses(densities)
        if not lumped:
            # one point per voxel can leave the consistent mass singular on thin parts (few voxels
            # across a frame's support): the 2x2x2 Gauss points of every voxel integrate it
            s = voxel_samples(self.image, self.shape_function, rule="gauss-legendre", use_occupancy=self.use_occupancy)
            m8 = np.repeat(mp / self._mass_points()[1], 8) * s.volume  # density of each voxel x Gauss volumes
            J = PointMapping(self.nodes, s.values).jacobian(self.rest)
            return (J.T @ sp.diags(np.repeat(m8, 3)) @ J).tocsr()
        _, _, pmap = self._mass_layer()
        v = pmap.shape
        n = self.n_nodes
        X = v.rest
        ok = v.index >= 0
        blocks = np.zeros((n, 4, 4))  # per frame: sum m w [r; 1][r; 1]^T with r = X - X_a
        idx = np.where(ok, v.index, 0)
        r = np.concatenate([X[:, None, :] - self.frames[idx], np.ones(idx.shape + (1,))], axis=2)  # (m, P, 4)
        mw = np.where(ok, v.w, 0.0) * mp[:, None]
        contrib = mw[..., None, None] * r[..., :, None] * r[..., None, :]
        np.add.at(blocks, idx[ok], contrib[ok])
        # DOF layout: A row i (3 entries) then t_i; x_i = sum_j A_ij r_j + t_i couples A_i. with t_i
        full = np.zeros((n, 12, 12))
        for i in range(3):
            dofs = [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
            full[:, np.ix_(dofs, dofs)[0], np.ix_(dofs, dofs)[1]] = blocks
        return sp.block_diag(list(full), format="csr")

    def gravity_force(self, densities: Mapping[int, float], g) -> np.ndarray:
        """Generalised gravity force (n, 12): ``J^T (m g)`` at the mass points."""
        g = np.asarray(g, dtype=float)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise InputError(f"gravity must be 3 finite numbers (m/s^2), got {np.asarray(g).tolist()}")
        mp = self._point_masses(densities)
        _, _, pmap = self._mass_layer()
        return pmap.vjp(self.rest, mp[:, None] * g[None, :])

    # -- layers ----------------------------------------------------------------
    def point_mapping(self, points) -> PointMapping:
        """Mapping of material points (m, 3) given at rest; InputError outside the material."""
        pts = np.asarray(points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InputError(f"points must be an (m, 3) array, got shape {pts.shape}")
        self._check_inside(pts)
        return PointMapping(self.nodes, self.shape_function(pts))

    def _check_inside(self, pts):
        """Points must lie in (the closure of) a material voxel: a point on a face or a corner
        belongs to every voxel touching it."""
        f = self._grid().world_to_index(pts)
        labels = self.image.labels
        shape = np.asarray(labels.shape)
        ok = np.zeros(len(pts), dtype=bool)
        lo = np.floor(f + 1e-9).astype(np.int64)
        for d in np.array([[a, b, c] for a in (0, -1) for b in (0, -1) for c in (0, -1)]):
            cell = lo + d
            inside = np.all((cell >= 0) & (cell < shape), axis=1)
            near = np.all((f >= cell - 1e-9) & (f <= cell + 1 + 1e-9), axis=1)
            c = np.clip(cell, 0, shape - 1)
            ok |= inside & near & (labels[c[:, 0], c[:, 1], c[:, 2]] > 0)
        if not np.all(ok):
            bad = int(np.flatnonzero(~ok)[0])
            raise InputError(f"point {pts[bad].tolist()} lies outside the material; give points inside the object")

    def _grid(self) -> TrilinearGrid:
        if self._surface is None:
            self._surface = {"grid": TrilinearGrid.from_image(self.image)}
        return self._surface["grid"]

    def boundary_faces(self):
        """Voxel faces exposed to empty space: corners (F, 4, 3), area (F,), outward normal (F, 3)."""
        grid = self._grid()
        if "quads" not in self._surface:
            self._surface["quads"] = boundary_quads(grid, self.image.labels > 0)
        quads, area, normal = self._surface["quads"]
        return grid.node_positions[quads], area, normal

    def boundary_surface(self):
        """The visual layer: the voxelized boundary (rest vertices, triangles) and its frame mapping."""
        grid = self._grid()
        self.boundary_faces()
        if "surface" not in self._surface:
            vertex_node, faces = triangulate(self._surface["quads"][0])
            V = grid.node_positions[vertex_node]
            self._surface["surface"] = (V, faces, PointMapping(self.nodes, self.shape_function(V)))
        V, faces, pmap = self._surface["surface"]
        return V.copy(), faces, pmap

    def volume_points(self):
        """Material points integrating the volume: the voxel centres and their volumes (m^3)."""
        pts, vol, _ = self._mass_points()
        return pts, vol

    # -- boundary conditions -----------------------------------------------------
    def held_dofs(self, lo, hi, components: str = "xyz") -> np.ndarray:
        """DOFs a fixed box [lo, hi] holds: those of the frames in the box or in a voxel the box
        touches (a thin box around a face holds the frames of the first voxel layer); for component c,
        row c of A and t_c.  Material points without a frame follow the frames."""
        from ....voronoi.placement import voxels_touching_box

        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        in_box = np.all((self.frames >= lo) & (self.frames <= hi), axis=1)
        f = np.floor(self._grid().world_to_index(self.frames) + 1e-9).astype(np.int64)
        f = np.clip(f, 0, np.asarray(self.image.shape) - 1)
        touched = voxels_touching_box(self.image, lo, hi)[f[:, 0], f[:, 1], f[:, 2]]
        frames = np.flatnonzero(in_box | touched)
        local = []
        for c in components:
            i = "xyz".index(c)
            local += [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
        local = np.array(sorted(local), dtype=np.int64)
        return np.sort((12 * frames[:, None] + local[None, :]).ravel())

    def moved_state(self, transform) -> np.ndarray:
        """State (n, 12) of the body moved by ``[A | t]``: every frame's matrix A, origin A X_a + t."""
        T = np.asarray(transform, dtype=float)
        A, t = T[:, :3], T[:, 3]
        out = np.empty((self.n_nodes, 12))
        out[:, :9] = A.reshape(9)
        out[:, 9:] = self.frames @ A.T + t
        return out

    def rigid_modes(self) -> np.ndarray:
        """(12n, 6): translations (dt = e_k) and rotations about the frames' centroid (dA = [e_k]x, dt = e_k x (X_a - c))."""
        return self.nodes.rigid_modes()

    def parts(self) -> list:
        """Material components as the shape functions couple them (voxels touching by a face, an edge
        or a corner: the connectivity of the geodesic distances), each moved by the frames in it."""
        comps, n = self.image.connected_components(connectivity="vertex")
        f = np.floor(self._grid().world_to_index(self.frames) + 1e-9).astype(np.int64)
        f = np.clip(f, 0, np.asarray(comps.shape) - 1)
        of_frame = comps[f[:, 0], f[:, 1], f[:, 2]] - 1
        return Part.of_components(self.image, comps, [np.flatnonzero(of_frame == c) for c in range(n)])

    def load_surface(self, order: int = 2) -> SurfacePoints:
        """``order`` x ``order`` Gauss points of every voxel face exposed to empty space."""
        corners, area, normal = self.boundary_faces()
        pts, w, face = face_points(corners, area, order)
        return SurfacePoints(pts, w, normal[face], face, corners.mean(axis=1))

    def node_points(self, q) -> np.ndarray:
        """Each frame's origin t (n, 3) at state q."""
        return np.asarray(q, dtype=float).reshape(self.n_nodes, 12)[:, 9:12].copy()

    def point_sample_refusal(self, labels) -> str:
        """Internal variables need point samples with the full volumetric term: refused with elastons
        (a region's moments, not points) or F-bar / B-bar labels."""
        if self.elaston:
            return ('plasticity needs point samples; give the plastic label(s) elastic behaviour, or use '
                    '[elasticity] quadrature = "midpoint" or "gauss-legendre" instead of elastons')
        reduced = sorted(int(lab) for lab in labels if self.volumetric.get(int(lab), False))
        if reduced:
            return (f"plasticity needs the full volumetric term, but label(s) {reduced} use F-bar; [elasticity] "
                    'volumetric = "full" (or a Poisson ratio below 0.4 under "auto")')
        return ""

    # -- description -------------------------------------------------------------
    supported_by_contact = False  # no obstacles: static scenes must be held by fixed regions

    def begin_step(self, fraction: float, q_prev, q_start):
        """The state a step starts from: ``q_start`` itself (models with obstacles may move it)."""
        return q_start

    def advice(self) -> str:
        if self.samples.kind == "midpoint":
            # elastons only where they take every material of the model (a neo-Hookean run was told to use them)
            other = ('quadrature = "elaston" or "gauss-legendre"' if all(elastons_take(m) for m in self.materials.values())
                     else 'quadrature = "gauss-legendre"')
            return f"mid-point samples may leave spurious zero-energy modes between frames; add samples or use {other}"
        return ""

    def describe(self) -> dict:
        reduced = sorted(lab for lab, red in self.volumetric.items() if red)
        vol = "full" if not reduced else ("reduced" if len(reduced) == len(self.volumetric) else
                                          "reduced for label(s) " + ", ".join(map(str, reduced)))
        out = {"node_kind": self.node_kind, "count": self.n_nodes, "dofs": 12 * self.n_nodes,
               "quadrature": self.samples.kind, "samples": self.n_samples, "volumetric": vol}
        out.update(self.info)
        return out
