"""The solver's options (``[solver]`` in a scene) and the record of a converged step."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._checks import boolean, number, string
from ...errors import InputError

__all__ = ["SolverOptions", "StepRecord"]

METHODS = ("auto", "cholesky", "direct", "cg", "amg", "multigrid")
"""``linear_solver`` choices (:mod:`voxflex.deform.solve.linear`)."""

KINDS = ("static", "implicit-euler")


MASS_KINDS = ("lumped", "consistent")

TANGENT_PROJECTIONS = ("auto", "always", "never")
"""``tangent_projection`` choices: per-sample tangents projected to positive semi-definite after the
exact tangent was indefinite along a Newton step, until a full step (``auto``, see
:func:`_project_tangents`), at every iterate, or never."""


@dataclass(frozen=True)
class SolverOptions:
    """Solver settings: the ``[solver]`` table of a scene (its keys are these fields, validated here once).

    Parameters
    ----------
    kind : {"static", "implicit-euler"}
    steps : int
        Static: load increments; implicit Euler: time steps.
    dt : float (s)
        Time step (implicit Euler).
    tolerance : float
        Newton stops when ``|r_free| <= tolerance * scale``, with ``scale`` the
        largest of the external forces, the first residual of the step and the
        reactions on the fixed DOFs (N).
    max_iterations : int
        Newton iterations per attempt at a step (static attempts that run out after
        lowering the potential continue, see :data:`MAX_CONTINUATIONS`).
    line_search : bool
        Backtracking Armijo line search on the (incremental) potential.
    linear_solver : {"auto", "cholesky", "direct", "cg", "amg"}
        See :mod:`voxflex.deform.solve.linear`.
    rayleigh_mass, rayleigh_stiffness : float
        Damping ``D = rayleigh_mass * M + rayleigh_stiffness * K`` (1/s and s).
    mass : {"lumped", "consistent"}
        Mass matrix of implicit Euler.
    check_stability : bool
        Check every converged state for a negative eigenvalue of the free
        tangent (always done when Newton met negative curvature).
    tangent_projection : {"auto", "always", "never"}
        Hessians built from per-sample tangents dP/dF projected to positive
        semi-definite (negative eigenvalues set to 0; the assembled Hessian is
        then PSD and every Newton direction descends): ``auto`` uses the exact
        tangent until it is indefinite along a Newton step, then the projected
        one until a step is accepted in full (the exact tangent near the
        solution keeps quadratic convergence); models or labels without
        projection (rigid frames, F-bar labels, elastons) stay exact.
    """

    kind: str = "static"
    steps: int = 1
    dt: float = 0.01
    tolerance: float = 1e-8
    max_iterations: int = 50
    line_search: bool = True
    linear_solver: str = "auto"
    rayleigh_mass: float = 0.0
    rayleigh_stiffness: float = 0.0
    mass: str = "lumped"
    check_stability: bool = False
    tangent_projection: str = "auto"

    def __post_init__(self):
        t, s = "solver", object.__setattr__
        boolean(t, "check_stability", self.check_stability)
        boolean(t, "line_search", self.line_search)
        string(t, "kind", self.kind, KINDS)
        string(t, "linear_solver", self.linear_solver, METHODS)
        string(t, "mass", self.mass, MASS_KINDS)
        string(t, "tangent_projection", self.tangent_projection, TANGENT_PROJECTIONS)
        s(self, "dt", number(t, "dt", self.dt, positive=True))
        s(self, "steps", number(t, "steps", self.steps, integer=True, minimum=1))
        tol = number(t, "tolerance", self.tolerance, positive=True)
        if not tol < 1:
            raise InputError(f"[solver] tolerance (a relative residual) must be in (0, 1), got {self.tolerance!r}")
        s(self, "tolerance", tol)
        s(self, "max_iterations", number(t, "max_iterations", self.max_iterations, integer=True, minimum=1))
        s(self, "rayleigh_mass", number(t, "rayleigh_mass", self.rayleigh_mass, nonnegative=True))
        s(self, "rayleigh_stiffness", number(t, "rayleigh_stiffness", self.rayleigh_stiffness, nonnegative=True))

    @property
    def end_time(self) -> float:
        """The time of the last step: ``steps * dt`` (s) for implicit Euler, the load factor 1 for statics."""
        return self.steps * self.dt if self.kind == "implicit-euler" else 1.0

    def fraction(self, time) -> float:
        """The run fraction of a state at ``time`` (the load factor, or t / t_end in dynamics): 0 at rest,
        1 at the end; prescribed motions, moving obstacles and cables follow it."""
        return float(time) / self.end_time


@dataclass
class StepRecord:
    """State after one step (the first record is the rest state at time 0).

    ``time`` is the load factor for statics, seconds for dynamics; ``q`` (n, d)
    the node state (positions in m for point nodes); ``v`` (n, d) its velocity or None (statics);
    energies in J; ``residual`` the final relative residual; ``linear_iterations``
    summed over the step's Newton iterations (0 for direct solvers); ``displacement`` (n, d) ``q - X``
    as the solver carries it (its digits kept where ``q`` rounds them away: a step below eps |X|), or None
    from solvers that do not.
    """

    time: float
    q: np.ndarray
    v: np.ndarray | None
    newton_iterations: int
    seconds: float
    elastic_energy: float
    kinetic_energy: float
    residual: float
    linear_iterations: int = 0
    linear_solver: str = ""
    line_search_halvings: int = 0
    load_cuts: int = 0
    displacement: np.ndarray | None = None
