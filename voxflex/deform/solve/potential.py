"""The potential of one step that Newton minimises: elastic energy, work, inertia and damping.

:class:`_Problem` evaluates the potential of a static step or an implicit-Euler step over the increment
from the step's start (energy, gradient, Hessian and the magnitude of the terms, the scale of its
round-off), from the displacement where the model takes it (:class:`FromDisplacement`), with projected
tangents on demand; :class:`_PatternAdd` adds the step's fixed inertia and damping matrix to each Hessian
inside the Hessians' shared sparsity pattern.  :func:`voxflex.deform.solve.newton._newton` minimises it.
"""

from __future__ import annotations

from functools import partial

import numpy as np
import scipy.sparse as sp

from ..._linalg import diagonal, vdot
from ..models.protocol import ConstantStiffness, FromDisplacement, TangentProjection


class _Problem:
    """The potential of one step over the increment ``delta`` (N,) from the step's start ``base``.

    The state is ``base + delta``.  Inertia and damping see ``delta`` plus the
    differences ``base - xhat`` and ``base - xn`` computed once, never the
    difference of two absolute states: with tiny time steps ``M / h^2`` would
    otherwise amplify the round-off of the positions (eps |x|) into forces
    that swamp the physics.
    """

    def __init__(self, model, f, base, M=None, h=None, xhat=None, xn=None, D=None, *, block=None, adder=None,
                 u_base=None, uhat=None, un=None):
        self.model = model
        self.f = f
        self.M = M
        self.h = h
        self.base = base
        self.rest = np.asarray(model.rest, dtype=float).ravel()
        # the solver's state is the displacement from rest (q - X, its digits kept whatever |X|): given as
        # u_base (and uhat, un: the inertial prediction and the previous state), the inertia, damping and
        # work read differences of displacements; without it, of the positions (callers of the former form)
        # the models that form their strains from the displacement get u_base + delta, not the positions
        self.u_base = None if u_base is None or not isinstance(model, FromDisplacement) else u_base
        if u_base is not None:
            self.off_hat = None if uhat is None else u_base - uhat
            self.off_n = None if un is None else u_base - un
            self.work0 = vdot(f, u_base)
        else:
            self.off_hat = None if xhat is None else base - xhat
            self.off_n = None if xn is None else base - xn
            self.work0 = vdot(f, base - self.rest)
        self.D = D
        self.shape = np.shape(model.rest)
        self.constant = bool(model.constant_tangent)
        self.elastic_diagonal = None
        self._bulk = None  # bulk_ratio(), once
        self.negative_curvature = False  # set by Newton when a direction of negative curvature was met
        self.on_iteration = None  # optional callable(dict) told about every Newton iterate (progress, logs)
        # the lean static path of constant-tangent models: the free-DOF block (F, F) assembled once by the
        # model, no full Hessian ever built (gradients then matrix-free); Newton solves with it
        self.block = block
        self.elements = None
        if block is not None:
            self.elastic_diagonal = block.diagonal()  # of the free DOFs only (what the round-off floor reads)
            # the block's matrix as voxel element matrices: multigrid forms its first coarse level from them
            self.elements = model.stiffness_elements() if isinstance(model, ConstantStiffness) else None
        # the inertia (and damping) matrix of the step, M / h^2 + D / h, built once, added to each Hessian
        self.inertia = None
        if M is not None:
            self.inertia = sp.csr_matrix(M / h**2 if D is None else M / h**2 + D / h)
        self._adder = adder if adder is not None else _PatternAdd()
        # waste counters (benchmarks, tests): model evaluations, Hessians assembled, Hessians solved (Newton
        # counts them) and the iterates whose Hessian the line search skipped but which needed one after all
        self.evaluations = 0
        self.energy_only = 0
        self.hessians = 0
        self.solves = 0
        self.hessian_misses = 0
        self.projected = 0  # Hessians built from projected tangents
        self.chord = None  # a _Chord kept over the load or time steps (dense tangents), or None
        self.solution_energy = None  # the model's energy at the answer, once Newton has converged (_newton)

    def bulk_ratio(self) -> float:
        """The largest lambda / mu of the model's materials at rest (0 when none is known): a nearly
        incompressible material's forces are sums of volumetric terms lambda / mu times larger than what they
        add up to, so they lose that factor of digits (Newton's round-off floor, :data:`BULK_FLOOR`)."""
        if self._bulk is None:
            from ..materials.fbar import rest_lame

            ratio = 0.0
            # layers (contact, cables) forward `materials` to the model they wrap, at any depth
            for mat in dict(getattr(self.model, "materials", None) or {}).values():
                try:
                    lame = rest_lame(mat)
                except Exception:  # noqa: BLE001 - a material without a rest tangent tells nothing here
                    continue
                if lame is not None and lame[0] > 0 and lame[1] > 0:
                    ratio = max(ratio, lame[0] / lame[1])
            self._bulk = ratio
        return self._bulk

    def roundoff_lengths(self, free) -> np.ndarray:
        """Per free DOF, the motion below which the elastic forces are round-off at the step's start
        (Newton's floor is ``16 eps |diag(K) * this|``): the position ``|x|`` when the forces come from
        positions (known to eps |x|); the displacement ``|u|`` plus the model's strain length (F = I + grad u
        is known to eps) when they come from the displacement (:class:`FromDisplacement`)."""
        if self.u_base is None:
            return np.abs(self.base[free])
        return np.abs(self.u_base.ravel()[free]) + np.asarray(self.model.strain_lengths(), dtype=float).ravel()[free]

    def __call__(self, delta, hessian=True, gradient=True, project=False):
        q = (self.base + delta).reshape(self.shape)
        hessian = hessian and self.block is None
        self.evaluations += 1
        self.hessians += bool(hessian and gradient)
        self.energy_only += not gradient
        setter = self.model.set_tangent_projection if (
            project and hessian and gradient and isinstance(self.model, TangentProjection)) else None
        if self.u_base is not None:  # the strains from the displacement, its digits kept (FromDisplacement)
            evaluate = partial(self.model.energy_gradient_hessian_u, (self.u_base + delta).reshape(self.shape))
        else:
            evaluate = partial(self.model.energy_gradient_hessian, q)
        if setter is not None:
            self.projected += bool(setter(True))
            try:
                E, g, H = evaluate(hessian=True)
            finally:
                setter(False)  # the model's Hessians stay exact outside this call (stability check, damping)
        elif self.u_base is not None:
            E, g, H = evaluate(gradient=gradient, hessian=hessian and gradient)
        else:
            E, g, H = evaluate(hessian=hessian) if gradient else (self.model.energy(q), None, None)
        work = self.work0 + vdot(self.f, delta)
        pot = E - work
        mag = abs(E) + abs(work)
        if H is not None and self.elastic_diagonal is None:
            self.elastic_diagonal = diagonal(H)  # read once, at the step's start (the round-off floor)
        if g is not None:
            g = g.ravel() - self.f
        if self.M is not None:
            dx = delta + self.off_hat
            Mdx = self.M @ dx
            kin = 0.5 * vdot(dx, Mdx) / self.h**2
            pot += kin
            mag += kin
            if g is not None:
                g = g + Mdx / self.h**2
            if self.D is not None:
                dn = delta + self.off_n
                Ddn = self.D @ dn
                damp = 0.5 * vdot(dn, Ddn) / self.h
                pot += damp
                mag += damp
                if g is not None:
                    g = g + Ddn / self.h
            if H is not None:
                H = self._adder(H, self.inertia)
        if H is not None and not isinstance(H, np.ndarray):
            H = sp.csr_matrix(H)
        return pot, E, g, H, mag


class _PatternAdd:
    """``H + S`` for Hessians H that share one sparsity pattern and a fixed sparse S inside it.

    scipy's sparse sum merges the two patterns on every call (a new CSR per
    Newton iteration of implicit Euler); here the positions of S's entries in
    H's pattern are found once per (pattern, S) and each call is a copy of
    H's values plus a scatter-add.  Dense Hessians (frame models) get S's dense
    form, made once.  Falls back to the plain sum when S has an entry outside H's pattern.
    """

    def __init__(self):
        self._key = None
        self._pos = None
        self._dense = None

    def __call__(self, H, S):
        if isinstance(H, np.ndarray):
            if self._dense is None or self._dense[0] is not S:
                self._dense = (S, S.toarray())
            return H + self._dense[1]
        H = sp.csr_matrix(H)
        if not H.has_canonical_format:
            return H + S
        if not self._same(H, S):
            self._pos = _positions_in(H, S)
            self._key = (H.indptr, H.indices, S.indptr.copy(), S.indices.copy())
        if self._pos is None:
            return H + S
        data = H.data.copy()  # never write into the model's arrays (a constant model shares its cached data)
        np.add.at(data, self._pos, S.data)
        return sp.csr_matrix((data, H.indices, H.indptr), shape=H.shape)


    def _same(self, H, S) -> bool:
        """Whether H and S have the patterns the cached positions were found for (S's may be a new matrix)."""
        if self._key is None:
            return False
        hp, hi, sp_, si = self._key
        if len(hi) != len(H.indices) or len(hp) != len(H.indptr) or len(si) != len(S.indices) or \
                len(sp_) != len(S.indptr):
            return False
        same_h = (hp is H.indptr and hi is H.indices) or (np.array_equal(hp, H.indptr) and np.array_equal(hi, H.indices))
        return same_h and np.array_equal(sp_, S.indptr) and np.array_equal(si, S.indices)


def _positions_in(H, S):
    """Index (S.nnz,) of each stored entry of the CSR S in the canonical CSR H's data, or None when one is missing."""
    S = sp.csr_matrix(S)
    rows = np.repeat(np.arange(S.shape[0]), np.diff(S.indptr))
    cols = S.indices
    starts, ends = H.indptr[rows], H.indptr[rows + 1]
    # binary search of each column inside its row of H (indices sorted per row): global offsets into H.indices
    keys = rows.astype(np.int64) * H.shape[1] + cols
    hrows = np.repeat(np.arange(H.shape[0], dtype=np.int64), np.diff(H.indptr))
    hkeys = hrows * H.shape[1] + H.indices
    pos = np.searchsorted(hkeys, keys)
    ok = (pos < len(hkeys)) & (pos >= starts) & (pos < ends)
    ok[ok] = hkeys[pos[ok]] == keys[ok]
    return pos if bool(np.all(ok)) else None
