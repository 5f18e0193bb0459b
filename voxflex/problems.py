"""The one translation of a scene into a :class:`~voxflex.deform.solve.problem.Problem`.

It lives below :mod:`voxflex.build` (which imports it) so that building a model can solve a coarse
problem of the same scene first (``[nodes] placement = "strain"``); :mod:`voxflex.simulation` re-exports it.
"""

from __future__ import annotations

import numpy as np

from .scene import Scene

__all__ = ["problem_of"]


def problem_of(scene: Scene, model):
    """The :class:`~voxflex.deform.solve.problem.Problem` of ``scene`` on ``model``: the one translation of
    the scene's fixed regions, loads, solver, probes and obstacles into what the solver and the recorder read."""
    from .deform.solve.boundary import FORCE_KINDS, FixedRegion, ForceRegion
    from .deform.solve.problem import Problem

    fixed = [FixedRegion(np.array(f.min), np.array(f.max), components=f.components,
                         transform=None if f.transform is None else np.array(f.transform)) for f in scene.fixed]
    # gravity is a body load; a membrane's pressure is in its energy
    forces = [ForceRegion(np.array(ld.min), np.array(ld.max), np.array(ld.vector), kind=ld.kind)
              for ld in scene.loads if ld.kind in FORCE_KINDS]
    gravity = scene.gravity
    dynamic = scene.solver.kind == "implicit-euler"
    densities = {m.label: m.density for m in scene.materials} if (gravity is not None or dynamic) else None
    obstacles = tuple({"kind": o.kind, **o.parameters()} for o in scene.obstacles)
    return Problem(model=model, fixed=fixed, forces=forces, gravity=None if gravity is None else np.array(gravity),
                   densities=densities, options=scene.solver, probes=tuple((p.name, p.point) for p in scene.probes),
                   obstacles=obstacles, title=scene.title or "")
