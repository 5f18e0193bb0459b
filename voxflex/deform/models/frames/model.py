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
assembled once; per sample it is a constant table G (``_kernels``).  Mass,
gravity, probes, loads and the visual surface are further point mappings of
the same frames (mass points: the voxel centres, weighted by density and
occupancy; their shape values are evaluated only when mass or gravity is
needed).

Quadratures (``samples.kind``; :mod:`voxflex.deform.models.frames.quadrature`)
------------------------------------------------------------------------------
* ``"gauss-legendre"``: 2x2x2 Gauss points per voxel (the exact rule the
  others are measured against).
* ``"elaston"``: the sampler's regions, each integrated by a moment-fitted
  sub-rule -- at most 10 of its Gauss points whose non-negative weights
  reproduce its volume moments to degree 2.  They are point samples, so every
  material works with its own stress and tangent (exact gradient and Hessian).
* ``"midpoint"``: one sample per region.  With ``hourglass="stiffness"`` (the
  scenes' default) the sample's F is the exact mean of F over the region's
  Gauss points and the fluctuation about it gets its linearised energy
  (:mod:`voxflex.deform.models.frames.stabilise`): linear materials give the
  Gauss-Legendre answer to round-off, other materials an objective
  approximation of it; ``hourglass="none"`` is the bare one-point rule at the
  region's centroid (shape values fitted over the region), which
  under-integrates (soft modes: :mod:`voxflex.deform.models.frames.modes`).

Volumetric locking (``volumetric``)
-----------------------------------
``volumetric="reduced"`` projects each sample's volume ratio onto the span of the
frames' weights (F-bar, B-bar for constant-tangent materials; ``"auto"`` for the
nearly incompressible labels, with the remainder of the volume change at a capped bulk modulus where the weights
are linearly precise and the samples are points):
:mod:`voxflex.deform.models.frames.volumetric` says how and what it measures.

The model satisfies the protocol of :mod:`voxflex.deform.models.protocol`, so the same
solvers, loads, result files and renders run it.

Mass: ``consistent`` is ``J^T diag(m) J`` over the 2x2x2 Gauss points of
every voxel (dense 12x12 blocks between frames that share material);
``lumped`` gives every voxel centre's mass to its frames in proportion to
their weights, each frame carrying its share as its own affine body
(block-diagonal, symmetric positive definite, exact total mass and momentum).
With weights that are negative somewhere (reproducing kernels) such blocks are
indefinite (35 of 40 frames on the cantilever), and made positive (the positive
part of the weights) they no longer move the material by g under its own weight
where a held frame's weight is negative (1.8 g at the tip of a clamped beam in the
first implicit-Euler step): ``lumped`` is then ``J^T diag(m) J`` over the voxel
centres, the points gravity acts on (one per voxel instead of the consistent
mass's eight), so free fall is exact and the matrix positive semi-definite.
Linearly precise weights make 18 motions of the frames move nothing
(:func:`~voxflex.deform.models.frames.modes.gauge_modes`): either mass is singular
along them, so they get the frames' mean matrix-entry mass (no force excites them:
every force is ``J^T f`` and ``J`` vanishes on them).

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
from ....sampling.voxel import voxel_samples
from ...chain.mappings import DeformationGradientMapping
from ...chain.nodes import AffineFrames
from ...materials.constitutive import Material, project_psd
from ...materials.fbar import VOLUMETRIC, capped_bulk, nearly_incompressible
from ..protocol import OnePass
from ..voxel.kind import HOURGLASS
from . import _kernels as K
from .kind import AFFINE
from .attachments import FrameAttachments
from .volumetric import projected_pass, volumetric_projection

__all__ = ["FrameModel"]


def _rest_tangent(material) -> np.ndarray:
    """The tangent dP/dF (3, 3, 3, 3) of ``material`` at F = I, from one material point: a function of F alone,
    the same at every sample of a label (evaluating it at each of the bunny's 92k samples took 0.12 s)."""
    return np.asarray(material.evaluate(np.eye(3)[None].copy(), tangent=True)[2][0])


class FrameModel(FrameAttachments, OnePass):
    """Affine frames over a label image (see the module docstring).

    Build with :meth:`from_image`.  The state ``q`` is ``(n, 12)``; energies
    in J, generalised forces in N (translations) and N m (matrix entries).

    Attributes
    ----------
    image : LabelImage
    frames : (n, 3) float, rest positions X_a (m)
    samples : VoxelSamples (or the sampling stage's Samples): the point samples integrated (for
        elastons, the sub-rules' points; for stabilised mid-point regions, the regions)
    regions : the sampling regions (Samples) of elastons and mid-point regions, else None
    materials : {label: Material}
    """

    kind = AFFINE
    node_kind = AFFINE.name
    dofs_per_node = 12

    def __init__(self, image, frames, shape_function, samples, materials, *, info=None, use_occupancy=True,
                 volumetric="full", hourglass="none", region_tables=None):
        from .quadrature import elaston_samples, midpoint_tables

        self.image = image
        self.frames = np.asarray(frames, dtype=float)
        self.nodes = AffineFrames(self.frames)
        self.rest = self.nodes.rest
        self.rest.setflags(write=False)
        self.shape_function = shape_function
        self.materials = dict(materials)
        self.use_occupancy = bool(use_occupancy)
        self.info = dict(info or {})
        check_choice("volumetric", volumetric, VOLUMETRIC)
        check_choice("hourglass", hourglass, HOURGLASS)
        self.regions = None
        if samples.kind == "elaston" and getattr(samples, "moments", None) is not None:
            # regions of the sampler: integrate each by its moment-fitted sub-rule
            self.regions = samples
            samples = elaston_samples(image, shape_function, samples, use_occupancy=use_occupancy)
        self.samples = samples
        self.hourglass = hourglass if samples.kind == "midpoint" else "none"
        self.tables = None
        if self.hourglass == "stiffness":
            self.regions = samples
            self.tables = region_tables if region_tables is not None else \
                midpoint_tables(image, shape_function, samples, self.frames, use_occupancy=use_occupancy)[0]
            if self.tables.n_regions != len(samples.volume):
                raise InputError(f"region tables of {self.tables.n_regions} regions for {len(samples.volume)} samples")
            index, G, wtab = self.tables.index, self.tables.G, self.tables.w
        else:
            values = samples.values
            index, by_frame = K.sorted_parents(values)  # what the pair tables want: parents in frame order
            G = None
        # the structured kernels: F = (I3 (x) G) d, forces and stiffness per sample (_kernels); parents
        # sorted by frame and the coupled frame pairs, once.  Point samples keep (w, dw, X) per parent
        # instead of G's 12 numbers (F, the forces and the stiffness read them: a third of the memory;
        # G is made only if asked for, :attr:`_G`); regions' tables are averages over their Gauss points
        self._points = None
        if G is None:
            self._index, self._Gtab = index, None
            self._pairs, self._pair_id = K.pair_list(index, len(self.frames))
            self._points = K.point_arrays(values, self.frames, by_frame)
            self._w = self._points[0]  # the weights in frame order, 0 where padded
        else:
            self._index, self._Gtab, self._pairs, self._pair_id = K.frame_pairs(index, G, len(self.frames))
            order = np.argsort(np.where(np.asarray(index) >= 0, index, np.iinfo(np.int64).max), axis=1, kind="stable")
            self._w = np.take_along_axis(np.where(np.asarray(index) >= 0, wtab, 0.0), order, axis=1)
        self.volumetric_option = volumetric
        # auto: project for nearly incompressible labels; with linearly precise weights on point samples the
        # remainder of the volume change keeps the capped bulk modulus; with them on stabilised regions the
        # term stays full (module docstring of .volumetric)
        precise = bool(getattr(shape_function, "linearly_precise", False))
        point = region_tables is None
        self.volumetric_cap = {}
        if volumetric == "auto" and precise and point:
            for lab, mat in self.materials.items():
                cap = capped_bulk(mat)
                if cap is not None:
                    self.volumetric_cap[int(lab)] = cap
        self.volumetric = {int(lab): volumetric == "reduced" or int(lab) in self.volumetric_cap or (
            volumetric == "auto" and not precise and nearly_incompressible(mat)) for lab, mat in self.materials.items()}
        self._fluct = None
        if self.tables is not None:
            from .stabilise import Fluctuation

            self._fluct = Fluctuation(self.tables, samples.label, self.materials, self.volumetric, self.rest)
        self._proj = None
        self._J = None
        self._groups = [(int(lab), np.flatnonzero(samples.label == lab)) for lab in np.unique(samples.label)]
        self._volume = np.ascontiguousarray(samples.volume, dtype=float)
        self._surface = None
        self._mass_map_cache = None
        self._mass_points_cache = None
        self._project = False  # per-sample tangents projected to PSD in the Hessians (set_tangent_projection)
        self._last_F = None  # (q or u, F, whether q) of the last state evaluated
        self._quadratic = None  # (materials, E0, g0, K) of a constant-tangent model at F = I (the displacement form)
        self._strain_lengths = None
        self._pin = None  # () or (G, alpha): the gauge motions' pin (_gauge_pin)
        self._last_P = None  # (F, materials, energy, P) of the last point pass: see _point_pass

    # -- construction -------------------------------------------------------
    @classmethod
    def from_image(cls, image, frames, shape_function, materials: Mapping[int, object], *, samples=None,
                   quadrature: str = "gauss-legendre", use_occupancy: bool = True, info=None,
                   volumetric: str = "full", hourglass: str = "none", region_tables=None) -> "FrameModel":
        """Frame model of ``image`` with frames at ``frames`` (n, 3) and shape functions ``shape_function``.

        Parameters
        ----------
        image : LabelImage
        frames : (n, 3) float, world rest positions of the frames (m)
        shape_function : callable
            ``shape_function(points (m, 3)) -> ShapeValues`` over the frames.
        materials : mapping label -> Material
        samples : optional
            Quadrature samples (attributes of :class:`VoxelSamples`, or the sampler's
            :class:`~voxflex.sampling.samples.Samples`: elaston regions get their sub-rules);
            default: ``quadrature`` per voxel (``"gauss-legendre"`` or ``"midpoint"``).
        use_occupancy : bool
            Weight volumes and masses by the image's occupancy fractions.
        volumetric : {"full", "reduced", "auto"}
            Integration of the volumetric term (module docstring): every sample
            (``"full"``), projected onto the frames' weights (``"reduced"``), or
            projected for labels with an effective Poisson ratio >= 0.4 when the
            weights are not linearly precise (``"auto"``, the scenes' default; module
            docstring).
        hourglass : {"none", "stiffness"}
            Mid-point samples: the bare one-point rule, or each region's mean F plus its
            fluctuation energy (module docstring; the scenes' default).
        region_tables : RegionTables, optional
            The mid-point regions' tables when the caller has them (a cache).

        Raises
        ------
        InputError
            No frame, a label without material, shape functions that do not fit the frames,
            an unknown ``volumetric`` or ``hourglass``.
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
                   info=info, use_occupancy=use_occupancy, volumetric=volumetric, hourglass=hourglass,
                   region_tables=region_tables)

    @property
    def _G(self) -> np.ndarray:
        """The tables G (m, P, 4, 3) of the samples (made from the point arrays when first asked for)."""
        if self._Gtab is None:
            self._Gtab = K.tables_from_points(self._index, self._points)
        return self._Gtab

    # -- sizes -----------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return self.nodes.n

    @property
    def n_samples(self) -> int:
        return len(self.samples.volume)

    @property
    def elaston(self) -> bool:
        return self.samples.kind == "elaston"

    @property
    def constant_tangent(self) -> bool:
        return all(bool(getattr(m, "constant_tangent", False)) for m in self.materials.values())

    def _check_q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n_nodes, 12):
            raise InputError(f"q must have shape ({self.n_nodes}, 12) (A row-major, then t, per frame), got {q.shape}")
        return q

    # -- energy ----------------------------------------------------------------
    def _dofs(self) -> np.ndarray:
        """(m, P, 3, 4) DOF of (sample, parent, row i, column c) (0 where padded)."""
        return K._dofs(self._index)

    def jacobian(self) -> sp.csr_matrix:
        """dF/dq at the samples (9m, 12n), constant for affine frames (assembled once from the tables:
        ``dF_ij / d d[a_p, i, c] = G[p, c, j]``)."""
        if self._J is None:
            m, P = self._index.shape
            ok = np.broadcast_to((self._index >= 0)[:, :, None, :, None], (m, P, 3, 4, 3))
            rows = np.broadcast_to(9 * np.arange(m)[:, None, None, None, None]
                                   + 3 * np.arange(3)[None, None, :, None, None]
                                   + np.arange(3)[None, None, None, None, :], (m, P, 3, 4, 3))
            cols = np.broadcast_to(self._dofs()[..., None], (m, P, 3, 4, 3))
            vals = np.broadcast_to(self._G[:, :, None, :, :], (m, P, 3, 4, 3))
            J = sp.csr_matrix((vals[ok], (rows[ok], cols[ok])), shape=(9 * m, 12 * self.n_nodes))
            J.sum_duplicates()
            self._J = J
        return self._J

    def deformation_gradients(self, q) -> np.ndarray:
        """F (m, 3, 3) at the samples (for stabilised mid-point regions: each region's mean F)."""
        return self._gradients_at(self._check_q(q)).copy()

    def _gradients_at(self, q, u=None) -> np.ndarray:
        """F at the samples for the state q (read-only), the last state's kept: a line search's accepted trial
        is evaluated again with its gradient, and F streams the whole (m, P, 4, 3) table (17 ms of a 60-frame
        bunny step's 30 ms gradient).  With the displacement ``u = q - rest`` given, ``F = I + J u`` (F is
        linear in the state and I at rest, the weights being a partition of unity): no round-off of the
        positions (eps |x|) in the strain."""
        state = q if u is None else u
        last = self._last_F
        if (last is not None and last[2] == (u is None) and last[0].shape == state.shape
                and np.array_equal(last[0], state)):
            return last[1]
        F = np.empty((self.n_samples, 3, 3))
        if self._points is not None:
            K.points_F(self._index, self._points, np.ascontiguousarray(state, dtype=np.float64), F)
        else:
            K.frame_F(self._index, self._G, np.ascontiguousarray(state, dtype=np.float64), F)
        if u is not None:
            for i in range(3):  # the diagonal only: a third of the time of adding np.eye(3) (14k samples: 34 us)
                F[:, i, i] += 1.0
        F.setflags(write=False)
        self._last_F = (np.array(state, copy=True), F, u is None)
        return F

    def _fields_F(self, q) -> np.ndarray:
        """F at the samples for the fields of state ``q`` (read-only): the solver's last F when it was formed from
        the displacement of this very state (``rest + u == q`` bit for bit: the recorder's state is the solver's
        answer), which is the more accurate one (no round-off of the positions) and costs no pass; else
        :meth:`_gradients_at`."""
        last = self._last_F
        if (last is not None and not last[2] and last[0].shape == q.shape
                and np.array_equal(self.rest + last[0], q)):
            return last[1]
        return self._gradients_at(q)

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
        q = self._check_q(q)
        fmap = self._surface_fmap[0]
        # F read-only as the model keeps it (no copy); the surface layer's F only when a field asks for it
        # (every recorded step checks the samples' det F, few scenes record fields)
        return {"F": self._fields_F(q), "volume": s.volume, "label": s.label,
                "cell": np.arange(len(s.volume)), "n_cells": len(s.volume), "cell_kind": "samples",
                "materials": self.materials, "surface_F": lambda: fmap.apply(q),
                "surface_label": self._surface_fmap[1], "triangle_point": np.tile(np.arange(nf), 2)}

    def set_tangent_projection(self, on: bool) -> bool:
        """Project the per-sample tangents dP/dF to positive semi-definite in later Hessians (``on``), or not.

        F is linear in the affine frames' DOFs, so the samples' Hessian is then positive
        semi-definite.  Samples with every volumetric term in full only (projected labels keep
        their exact Hessian); the mid-point regions' fluctuation term keeps its exact Hessian
        (positive semi-definite at rest).  Returns whether the tangents are projected.
        """
        self._project = bool(on) and not any(self.volumetric.values())
        return self._project and not self.constant_tangent

    def rest_stiffness(self, materials=None) -> np.ndarray:
        """The Hessian at rest (12n, 12n) with ``materials`` (default: the model's) at every sample,
        fluctuation included, volumetric terms in full (a sound quadrature's free body has six
        zero-energy modes: :mod:`voxflex.deform.models.frames.modes`)."""
        mats = self.materials if materials is None else {int(k): v for k, v in dict(materials).items()}
        tangents = [_rest_tangent(mats[label]) for label, _ in self._groups]
        moduli = [K.isotropic_moduli(A) for A in tangents]
        if all(x is not None for x in moduli) and K.isotropic_worth_dense(self._index, self.n_nodes):
            # isotropic at rest (every material this package has): dense products, not the pair blocks
            H = np.zeros((12 * self.n_nodes, 12 * self.n_nodes))
            one = len(self._groups) == 1
            for (label, ids), (mu, lam) in zip(self._groups, moduli):
                sub = slice(None) if one else ids
                pts = None if self._points is None else tuple(a[sub] for a in self._points[:3]) + (self._points[3],)
                K.isotropic_stiffness_dense(self._index[sub], self.n_nodes, self._volume[sub], mu, lam,
                                            G=None if pts is not None else self._Gtab[sub], points=pts, H=H)
        else:
            A = np.empty((self.n_samples, 3, 3, 3, 3))
            for (label, ids), At in zip(self._groups, tangents):
                A[ids] = At
            H = K.frame_stiffness_dense(self._index, self._Gtab, A, self.n_nodes, self._volume,
                                        (self._index, self._Gtab, self._pairs, self._pair_id), self._points)
        if self.tables is not None:
            from .stabilise import Fluctuation

            H += Fluctuation(self.tables, self.samples.label, mats, {}, self.rest).rest_matrix()
        return 0.5 * (H + H.T)

    def energy_gradient_hessian(self, q, *, gradient: bool = True, hessian: bool = True):
        """Energy (J), gradient (n, 12) and Hessian (12n, 12n) in one pass over the samples.

        The Hessian is a dense ndarray (frames sharing material couple, so it is nearly full)."""
        q = self._check_q(q)
        return self._evaluate(q, None, q - self.rest, gradient, hessian)

    def energy_gradient_hessian_u(self, u, *, gradient: bool = True, hessian: bool = True):
        """:meth:`energy_gradient_hessian` at the displacement ``u = q - rest`` (n, 12): F = I + J u, the
        regions' fluctuation from u, and a constant-tangent model's forces K u from the rest state's terms
        (see :class:`~voxflex.deform.models.protocol.FromDisplacement`)."""
        u = self._check_q(u)
        if self.constant_tangent:
            # a quadratic energy: E0 + g0 . u + u K u / 2 from the terms at F = I exactly (made once per set of
            # materials), so a linear material's forces keep u's digits (F = I + J u rounds the strain to eps)
            mats = tuple(self.materials.values())
            kept = self._quadratic
            if kept is None or len(kept[0]) != len(mats) or not all(a is b for a, b in zip(kept[0], mats)):
                zero = np.zeros_like(self.rest)
                E0, g0, K0 = self._evaluate(self.rest, zero, zero, True, True)
                K0.setflags(write=False)
                self._quadratic = kept = (mats, E0, g0.ravel(), K0)
            _, E0, g0, K0 = kept
            flat = u.ravel()
            Ku = K0 @ flat
            grad = (g0 + Ku).reshape(u.shape) if gradient else None
            return float(E0 + vdot(g0, flat) + 0.5 * vdot(flat, Ku)), grad, (K0.copy() if hessian else None)
        return self._evaluate(self.rest + u, u, u, gradient, hessian)

    def strain_lengths(self) -> np.ndarray:
        """(n, 12): per DOF, the motion that changes some sample's F by 1 (the inverse of the largest
        ``|dF/dq_j|``): F is known to eps, so eps times this is what the forces resolve along that DOF.
        A row entry ``3 i + c`` moves ``F[i, :]`` by ``r_c dw + w e_c``, a translation ``9 + i`` by ``dw``.
        Zero for a constant-tangent model: :meth:`energy_gradient_hessian_u` then never forms F."""
        if self.constant_tangent:
            return np.zeros((self.n_nodes, 12))
        if self._strain_lengths is None:
            top = np.zeros((self.n_nodes, 4))
            step = max(1, (1 << 20) // max(self._index.shape[1], 1))
            for a in range(0, self._index.shape[0], step):
                idx = self._index[a:a + step]
                ok = idx >= 0
                if self._Gtab is not None:
                    norms = np.linalg.norm(self._Gtab[a:a + step], axis=-1)  # (c, P, 4)
                else:
                    w, dw, rest = (arr[a:a + step] for arr in self._points[:3])
                    r = rest[:, None, :] - self._points[3][np.where(ok, idx, 0)]  # (c, P, 3)
                    norms = np.empty(idx.shape + (4,))
                    for c in range(3):
                        g = r[..., c, None] * dw
                        g[..., c] += w
                        norms[..., c] = np.linalg.norm(g, axis=-1)
                    norms[..., 3] = np.linalg.norm(dw, axis=-1)
                for c in range(4):
                    np.maximum.at(top[:, c], idx[ok], norms[..., c][ok])
            inv = np.where(top > 0, 1.0 / np.where(top > 0, top, 1.0), 0.0)
            self._strain_lengths = np.concatenate([np.tile(inv[:, :3], 3), inv[:, 3:].repeat(3, axis=1)], axis=1)
        return self._strain_lengths

    def gauge_modes(self) -> np.ndarray:
        """(12n, g) the gauge motions of the model's weights: those of the 18 candidates that move no voxel
        centre and deform none (:func:`~voxflex.deform.models.frames.modes.gauge_modes`); empty unless the
        weights are linearly precise (reproducing kernels; eigenmode weights of a body without fixed regions).
        Read at every voxel centre, not at the samples: a stabilised mid-point region integrates Gauss points
        its centre does not show.  Cached in the weights (the checks, the mass and the gauge pin ask for them)."""
        from .modes import weights_gauge_modes

        sf = self.shape_function
        if not getattr(sf, "linearly_precise", False):
            return np.zeros((12 * self.n_nodes, 0))
        vv = sf.voxel_values() if hasattr(sf, "voxel_values") else None
        if vv is None:
            vv = sf(self.image.index_to_world(np.argwhere(self.image.labels > 0) + 0.5))
        return weights_gauge_modes(sf, self.frames, vv)

    def _gauge_pin(self):
        """``(G, alpha)``: the gauge motions of linearly precise weights (12n, g), which move no point and deform
        nothing, and the stiffness that pins them (the mean matrix-entry diagonal of the rest stiffness), or
        None when there are none.  Without it the static tangent is singular to round-off along them (smallest
        eigenvalues ~1e-17 of the largest diagonal entry), and whether a Cholesky of it passes is decided by
        round-off; with it the energy gains ``alpha |G^T (q - rest)|^2 / 2``, which no force excites (every
        force is ``J^T f``, and J vanishes on them) and no point sees."""
        if self._pin is None:
            G = self.gauge_modes()
            if G.shape[1] == 0:
                self._pin = ()
            else:
                alpha = self._rest_entry_diagonal()
                if alpha is None:
                    a_ = (np.arange(12 * self.n_nodes) % 12) < 9
                    alpha = float(np.abs(np.diagonal(self.rest_stiffness()))[a_].mean())
                self._pin = (G, alpha)
        return self._pin or None

    def _rest_entry_diagonal(self) -> float | None:
        """The mean matrix-entry diagonal of :meth:`rest_stiffness` from the point samples' weights alone, no
        stiffness assembled (the bunny's 40 RK frames: a dense stiffness of 92,846 samples x 35 parents, 0.7-1.4 s).

        Frame a's entry ``A_ij`` moves F by ``e_i (x) M_j`` with ``M = w I + r g^T`` (``r = X_s - X_a``, ``g``
        the weight's gradient), so its diagonal is ``vol M_j^T C_i M_j`` and the sum over i, j is
        ``vol tr(M^T M D)`` with ``D_lm = sum_i C_iliml`` (the rest tangent traced over the component):
        ``vol (w^2 tr D + 2 w r.D g + |r|^2 g.D g)`` per parent.  None (the caller assembles) for region tables
        (their fluctuation term adds to the diagonal) or a rest tangent whose traced part is not positive
        semi-definite (the diagonal's absolute values would differ)."""
        if self._points is None or self.tables is not None:
            return None
        w, dw, rest, frames = self._points
        total = 0.0
        for label, ids in self._groups:
            D = np.einsum("ilim->lm", _rest_tangent(self.materials[label]))
            D = 0.5 * (D + D.T)
            if np.linalg.eigvalsh(D).min() < -1e-12 * max(float(np.abs(D).max()), 1e-300):
                return None
            for chunk in np.array_split(ids, max(1, len(ids) // 8192)):
                idx = self._index[chunk]
                r = rest[chunk, None, :] - frames[np.where(idx >= 0, idx, 0)]  # padded parents: w = g = 0
                wc, g = w[chunk], dw[chunk]
                Dg = g @ D
                per = (wc * wc * np.trace(D) + 2.0 * wc * np.einsum("spk,spk->sp", r, Dg)
                       + np.einsum("spk,spk->sp", r, r) * np.einsum("spk,spk->sp", g, Dg))
                total += float(self._volume[chunk] @ per.sum(axis=1))
        return total / (9 * self.n_nodes)

    def _evaluate(self, q, u, d, gradient, hessian):
        """Energy, gradient, Hessian at q; F from the displacement ``u`` when given; ``d`` = q - rest (the gauge pin)."""
        F = self._gradients_at(q, u)
        if any(self.volumetric.values()):
            energy, grad, H = self._projected_pass(F, gradient, hessian, d)
        else:
            energy, grad, H = self._point_pass(F, gradient, hessian)
        if self._fluct is not None and np.isfinite(energy):
            e, g, h = self._fluct.evaluate(q, F, gradient=gradient, hessian=hessian, dq=u)
            energy += e
            if gradient:
                grad = grad + g
            if hessian:
                H += h
        pin = self._gauge_pin() if np.isfinite(energy) else None
        if pin is not None:
            G, alpha = pin
            c = G.T @ np.asarray(d, dtype=float).ravel()
            energy += 0.5 * alpha * vdot(c, c)
            if gradient:
                grad = grad + (alpha * (G @ c)).reshape(grad.shape)
            if hessian:
                H += alpha * (G @ G.T)
        return float(energy), grad, H

    def _point_pass(self, F, gradient, hessian):
        """``sum_s v_s W(F_s)`` with its gradient and Hessian by the compiled kernels.

        The materials give the stress with the energy, so a pass without the Hessian keeps both for
        the state's F (the read-only array :meth:`_gradients_at` hands out for that state): a line
        search's accepted trial, evaluated for its energy, then needs only the forces (the strains and
        the law are not evaluated again; 2.5 of a 60-frame step iteration's 7.5 ms).  Only while every
        material is a plain :class:`~voxflex.deform.materials.constitutive.Material` (frozen: no state
        that a step could change, unlike plastic materials)."""
        mats = tuple(self.materials.values())
        last = self._last_P
        if not hessian and last is not None and last[0] is F and len(last[1]) == len(mats) and all(
                a is b for a, b in zip(last[1], mats)):
            return last[2], self._forces(last[3]) if gradient else None, None
        energy, P, A = self._constitutive(F, hessian)
        stateless = all(type(mat) is Material for mat in mats)
        self._last_P = (F, mats, energy, P) if stateless and not F.flags.writeable else None
        return energy, self._forces(P) if gradient else None, self._stiffness(A) if hessian else None

    def _constitutive(self, F, hessian):
        """(energy, P (m, 3, 3), A or None) of every sample at F."""
        vol = self._volume
        m = len(vol)
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
        return energy, P, A

    def _forces(self, P) -> np.ndarray:
        grad = np.zeros((self.n_nodes, 12))
        if self._points is not None:
            K.points_forces(self._index, self._points, P, self._volume, grad)
        else:
            K.frame_forces(self._index, self._G, np.ascontiguousarray(P), self._volume, grad)
        return grad

    def _stiffness(self, A) -> np.ndarray:
        # a dense Hessian: frames sharing material couple (the solver takes it as is)
        return K.frame_stiffness_dense(self._index, self._Gtab, np.ascontiguousarray(A), self.n_nodes, self._volume,
                                       (self._index, self._Gtab, self._pairs, self._pair_id), self._points)

    # -- the volumetric term projected onto the frames' weights (frames/volumetric.py) ------------
    def _projection(self):
        """Per projected label, the projection's operators (:func:`.volumetric.volumetric_projection`), made once."""
        return volumetric_projection(self)

    def _projected_pass(self, F, gradient, hessian, d=None):
        """Energy, gradient and Hessian with the projected labels' volumetric term
        (:func:`.volumetric.projected_pass`; ``d`` = q - rest)."""
        return projected_pass(self, F, gradient, hessian, d)

    # -- description -------------------------------------------------------------
    supported_by_contact = False  # no obstacles: static scenes must be held by fixed regions

    def begin_step(self, fraction: float, q_prev, q_start):
        """The state a step starts from: ``q_start`` itself (models with obstacles may move it)."""
        return q_start


    def advice(self) -> str:
        if self.samples.kind == "midpoint" and self.hourglass == "none":
            return ("bare mid-point samples under-integrate and may leave spurious zero-energy modes between "
                    'frames; use [elasticity] hourglass = "stiffness", quadrature = "elaston" or "gauss-legendre"')
        return ""

    def describe(self) -> dict:
        reduced = sorted(lab for lab, red in self.volumetric.items() if red)
        vol = "full" if not reduced else ("reduced" if len(reduced) == len(self.volumetric) else
                                          "reduced for label(s) " + ", ".join(map(str, reduced)))
        if self.volumetric_cap:  # the remainder of the volume change at the capped bulk modulus (.volumetric)
            vol += ", remainder capped"
        out = {"node_kind": self.node_kind, "count": self.n_nodes, "dofs": 12 * self.n_nodes,
               "quadrature": self.samples.kind, "samples": self.n_samples, "volumetric": vol}
        if self.regions is not None:
            out["regions"] = len(self.regions.volume)
        if self.samples.kind == "midpoint":
            out["hourglass"] = self.hourglass
        out.update(self.info)
        return out
