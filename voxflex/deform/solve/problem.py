"""A problem: a model with everything a run fixes — held regions, loads, options, probes — built once.

The scene is translated into a :class:`Problem` in one place
(:func:`voxflex.problems.problem_of`); the solver reads it
(:meth:`Problem.solve`) and so does the recorder of the result (the run
fraction of a state, the reactions' regions, what a render needs), so that
no two parts of a run read the scene differently.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .options import SolverOptions

__all__ = ["Problem"]


@dataclass(frozen=True, eq=False)
class Problem:
    """What one run solves.

    Attributes
    ----------
    model : Model
    fixed : tuple of FixedRegion
    forces : tuple of ForceRegion
        Region loads (force, traction); gravity is a body load, a membrane's pressure is in its energy.
    gravity : (3,) float or None, m/s^2
    densities : dict label -> kg/m^3, or None (needed for gravity and dynamics)
    options : SolverOptions
    probes : tuple of (name, (3,) point at rest)
    obstacles : tuple of dict
        The obstacles as the result records them (``kind``, its parameters, ``friction``, ``motion``).
    title : str
    """

    model: object
    fixed: tuple = ()
    forces: tuple = ()
    gravity: np.ndarray | None = None
    densities: dict | None = None
    options: SolverOptions = field(default_factory=SolverOptions)
    probes: tuple = ()
    obstacles: tuple = ()
    title: str = ""

    def __post_init__(self):
        object.__setattr__(self, "fixed", tuple(self.fixed))
        object.__setattr__(self, "forces", tuple(self.forces))
        if self.gravity is not None:
            object.__setattr__(self, "gravity", np.asarray(self.gravity, dtype=float).reshape(3))

    @property
    def dynamic(self) -> bool:
        return self.options.kind == "implicit-euler"

    def fraction(self, time) -> float:
        """The run fraction of a state at ``time`` (:meth:`SolverOptions.fraction`)."""
        return self.options.fraction(time)

    @cached_property
    def held(self) -> tuple:
        """``(dofs, owner)``: the flat DOFs the fixed regions hold, sorted, and the region holding each
        (:func:`~voxflex.deform.solve.boundary.fixed_dofs`), found once for the guards, the solver and the
        recorder of the reactions."""
        from .boundary import fixed_dofs

        return fixed_dofs(self.model, self.fixed)

    @cached_property
    def loads(self) -> np.ndarray:
        """The full external load (N,) flat, at load factor 1: region forces and gravity (N)."""
        from .boundary import load_vector

        return load_vector(self.model, self.forces, self.gravity, self.densities)

    @cached_property
    def mass(self):
        """The mass matrix the options ask for (implicit Euler), or None (statics)."""
        if not self.dynamic:
            return None
        return self.model.mass_matrix(self.densities, lumped=self.options.mass == "lumped")

    def solve(self, **kwargs):
        """:func:`~voxflex.deform.solve.stepping.solve` of this problem (``kwargs``: callbacks, sink, q0, v0), with
        its held DOFs, loads and mass (:attr:`held`, :attr:`loads`, :attr:`mass`) as computed here."""
        from .stepping import solve

        known = {}
        if self.densities is not None or (self.gravity is None and not self.dynamic):
            # (without the densities gravity and dynamics are refused by stepping.solve's own check)
            known = {"held": self.held, "loads": self.loads, "mass": self.mass}
        return solve(self.model, fixed=self.fixed, forces=self.forces, gravity=self.gravity,
                     densities=self.densities, options=self.options, **known, **kwargs)

    def record(self) -> dict:
        """What a result stores of the problem for renders and readers (plain values, no scene text)."""
        return {
            "title": self.title,
            "solver_kind": self.options.kind,
            "end_time": self.options.end_time,
            "gravity": None if self.gravity is None else self.gravity.copy(),
            "obstacles": [dict(o) for o in self.obstacles],
            "fixed": [{"min": np.asarray(f.min, dtype=float), "max": np.asarray(f.max, dtype=float),
                       "components": f.components,
                       **({} if f.transform is None else {"transform": np.asarray(f.transform, dtype=float)})}
                      for f in self.fixed],
        }
