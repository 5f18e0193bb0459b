"""The chord of Newton's method with dense tangents: a factorised Hessian kept while it contracts.

A frame model's Hessian costs far more than its gradient, so a dense tangent factorised once serves later
Newton iterations, load steps and time steps while the steps solved with it (chord steps) cut the residual
by :data:`CHORD_RATE` each; the secants of those steps correct it (limited-memory BFGS, :data:`CHORD_MEMORY`
pairs), and a factor that has served :data:`CHORD_INVERSE_AFTER` solves is turned into its explicit
inverse.  :func:`voxflex.deform.solve.newton._newton` decides when to take a chord step;
:func:`voxflex.deform.solve.stepping.solve` keeps one :class:`_Chord` over the steps.
"""

from __future__ import annotations

import numpy as np

from ..._linalg import vdot

CHORD_MEMORY = 8
"""Secant pairs of chord steps that correct the kept factor (limited-memory BFGS; see :class:`_Chord`)."""

CHORD_INVERSE_AFTER = 8
"""A kept factor that has served this many chord solves is turned into the explicit inverse of its matrix
(LAPACK ``potri``, about twice a factorisation), and later chord solves multiply by it: a pair of triangular
solves is bound by its dependencies, a product by bandwidth (720 unknowns: 0.22 against 0.05 ms; ``potri``
7.7 ms, repaid after ~45 solves).  Implicit Euler keeps one factor over many steps (the 60-frame bunny: one
for 20 steps, 105 solves); a static load step rarely uses one this often.  The chord is an approximate
tangent corrected by the secants and judged by the true residual, so the inverse's round-off (``cond eps``,
as the solves') changes no answer."""

CHORD_INVERSE_MAX = 3000
"""Unknowns up to which :data:`CHORD_INVERSE_AFTER` applies (the inverse is a second dense matrix: 72 MB at 3000)."""

CHORD_RATE = 0.5
"""A dense tangent (frame models): a step solved with an earlier iteration's (or load or time step's) factorised
Hessian (a chord step) is kept on while each such step cuts the residual at least this much, and only in the
first half of ``max_iterations`` (full Newton keeps the rest); then the next iterate builds its Hessian
afresh.  The answer is judged by the same residual test either way; only the work changes: the 60-frame
reproducing-kernel bunny at 3 mm (27k elaston points, 47 parents each: a Hessian costs 0.74 s, a gradient
0.03 s), 5 steps of 5 ms: 15 Hessians in 13 iterations, 14.1 s; with chord steps at rate 0.25: 4 Hessians,
22 iterations, 5.3 s; at 0.5: 3.96 s; at 0.1: 5.8 s.  Statics likewise: 40 RK frames on the bunny at 2 mm,
one load step, 6.2-7.2 s with 3 fresh tangents, 4.3-4.9 s with chord steps (4 iterations; the answers
7e-8 of the largest displacement apart).  With the secant correction (:data:`CHORD_MEMORY`), the frame
model's kept stress and the extrapolated start, ``benchmarks/bench_real_frames.py --part dynamics`` (20
steps, bunny 3 mm, 60 frames): 12.4 -> 9.9 model passes per step for natural neighbours."""


class _Chord:
    """A factorised dense Hessian of the free DOFs kept over Newton iterations, load steps and time steps
    (:data:`CHORD_RATE`), corrected by the secants of the chord steps taken since it was built (limited-memory
    BFGS on top of it, :data:`CHORD_MEMORY` pairs): ``solve(rhs)`` for ``H d = rhs``; ``good`` False once a
    chord step contracted too little (the next iterate then builds a fresh Hessian and :meth:`store`
    replaces this one, forgetting the secants)."""

    def __init__(self):
        self.factor = None
        self.inverse = None  # the factor's explicit inverse once it has served CHORD_INVERSE_AFTER solves
        self.uses = 0
        self.Hff = None
        self.n = -1
        self.good = False
        self.elastic = None  # the elastic diagonal of the free DOFs where it was built (Newton's round-off floor)
        self.pairs = []  # (s, y, 1 / y.s) of the latest chord steps, oldest first

    def ready(self, n: int) -> bool:
        return self.factor is not None and self.n == n

    def store(self, Hff, elastic) -> None:
        import scipy.linalg as sla

        self.pairs = []
        self.inverse, self.uses = None, 0
        try:
            self.factor = sla.cho_factor(Hff, check_finite=False)
        except np.linalg.LinAlgError:  # indefinite: no chord steps with it (Newton's remedies take over)
            self.factor = None
            return
        self.Hff, self.n, self.good, self.elastic = Hff, Hff.shape[0], True, elastic

    def secant(self, s, y) -> bool:
        """Keep the secant pair of a chord step ``s`` and its residual change ``y``; False (nothing kept)
        when its curvature ``y . s`` is not positive (the true tangent is not positive definite along s)."""
        ys = vdot(y, s)
        if not ys > 0.0:
            return False
        self.pairs = [*self.pairs, (s, y, 1.0 / ys)][-CHORD_MEMORY:]
        return True

    def solve(self, rhs) -> np.ndarray:
        """``H d = rhs`` with the factor as L-BFGS's initial Hessian and the kept secants (two-loop recursion:
        positive definite whenever the factor is, since every pair has ``y . s > 0``)."""
        import scipy.linalg as sla

        q = np.array(rhs, dtype=float)
        a = []
        for s, y, rho in reversed(self.pairs):
            ai = rho * vdot(s, q)
            q -= ai * y
            a.append(ai)
        self.uses += 1
        if self.uses == CHORD_INVERSE_AFTER and self.n <= CHORD_INVERSE_MAX:  # once per factor
            self.inverse = _inverse_of(self.factor)
        z = self.inverse @ q if self.inverse is not None else sla.cho_solve(self.factor, q, check_finite=False)
        for (s, y, rho), ai in zip(self.pairs, reversed(a)):
            z += (ai - rho * vdot(y, z)) * s
        return z


def _inverse_of(factor) -> np.ndarray | None:
    """The symmetric inverse (n, n) of the matrix whose ``scipy.linalg.cho_factor`` is ``factor``, or ``None``
    where LAPACK reports a zero pivot."""
    from scipy.linalg import lapack

    c, lower = factor
    inv, info = lapack.dpotri(c, lower=lower)
    if info != 0:
        return None
    tri = np.tril(inv) if lower else np.triu(inv)
    return tri + (np.tril(inv, -1).T if lower else np.triu(inv, 1).T)
