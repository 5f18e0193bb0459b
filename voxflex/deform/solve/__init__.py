"""Solvers: options, boundary conditions, Newton, load and time stepping, linear solvers, multigrid.

Everything here talks to a model through :mod:`voxflex.deform.models.protocol`.
"""

from ..._lazy import lazy

__getattr__, __dir__, __all__ = lazy(__name__, {
    "SolverOptions": "voxflex.deform.solve.options",
    "StepRecord": "voxflex.deform.solve.options",
    "solve": "voxflex.deform.solve.stepping",
    "FixedRegion": "voxflex.deform.solve.boundary",
    "ForceRegion": "voxflex.deform.solve.boundary",
    "solve_linear": "voxflex.deform.solve.linear",
})
