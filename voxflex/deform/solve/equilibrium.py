"""Static equilibrium with plasticity at one load level (a convenience over :func:`~voxflex.deform.solve.stepping.solve`)."""

from __future__ import annotations

from ...errors import InputError
from ..layers.plasticity import PlasticModel

__all__ = ["equilibrate"]


def equilibrate(model, material, q, fixed, *, tolerance: float = 1e-10):
    """Static equilibrium with plasticity for one load level from the state ``q``, then commit.

    One static step of :func:`~voxflex.deform.solve.stepping.solve` on ``model``
    wrapped in :class:`PlasticModel` (unless it already is one): the solver's
    post-convergence hook re-solves until ``material``'s plastic strains settle.
    Returns the state (n, d).

    Raises
    ------
    ConvergenceError
        The plastic strains still change after
        :data:`~voxflex.deform.models.protocol.END_STEP_PASSES` re-solves.
    """
    from .options import SolverOptions
    from .stepping import solve

    layer = model if isinstance(model, PlasticModel) else PlasticModel(model)
    if not any(m is material for m, _ in layer.plastic.values()):
        raise InputError("material is not one of the model's plastic materials")
    return solve(layer, fixed=fixed, options=SolverOptions(steps=1, tolerance=tolerance), q0=q)[-1].q
