"""The solvers' post-convergence hook (voxflex.deform.models.protocol.end_step).

Oracle: a layer over a linear voxel bar that asks for ``k`` re-solves of every
step (its hook returns True k times, then False) must see the hook called
k + 1 times per step, at the converged state each time (the residual there is
below the solver's tolerance: checked against the model's own gradient); a
layer that never settles ends in a ConvergenceError naming the re-solves;
models without the method (the bare voxel model) get the no-op default.
"""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.layers.base import ModelLayer
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.protocol import END_STEP_PASSES, end_step
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import FixedRegion
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.errors import ConvergenceError
from voxflex.image.label_image import LabelImage


class _Asks(ModelLayer):
    layer = "test"

    def __init__(self, inner, passes):
        self.inner = inner
        self.passes = passes
        self.calls = []  # (state, hook answer)
        self._left = passes

    def end_step(self, q):
        again = self._left > 0
        self._left = self._left - 1 if again else self.passes  # the next step asks again
        self.calls.append((np.array(q), again))
        return again


def _bar():
    return VoxelModel.from_image(LabelImage(np.ones((3, 1, 1), dtype=np.uint8)),
                                 {1: material("neo-hookean", young=1.0, poisson=0.3)})


def _fixed():
    clamp = FixedRegion([-np.inf] * 3, [1e-9, np.inf, np.inf])
    T = np.hstack([np.eye(3), [[0.0], [0.0], [-0.3]]])
    return [clamp, FixedRegion([3 - 1e-9, -np.inf, -np.inf], [np.inf] * 3, transform=T)]


@pytest.mark.parametrize("kind", ["static", "implicit-euler"])
def test_hook_called_until_settled_at_converged_states(kind):
    layer = _Asks(_bar(), 2)
    opts = SolverOptions(kind=kind, steps=3, dt=0.1, tolerance=1e-10)
    dens = {1: 1.0} if kind != "static" else None
    records = solve(layer, fixed=_fixed(), options=opts, densities=dens)
    assert len(layer.calls) == 3 * (2 + 1)
    assert [a for _, a in layer.calls] == [True, True, False] * 3
    free = layer.rest[:, 0] > 1e-9
    free &= layer.rest[:, 0] < 3 - 1e-9
    for (q, _), rec in zip(layer.calls[2::3], records[1:]):
        np.testing.assert_array_equal(q, rec.q)  # the settled call saw the recorded state
        if kind == "static":
            g = layer.gradient(rec.q)[free]  # equilibrium: no force on the free nodes (tolerance 1e-10 x scale)
            assert np.abs(g).max() < 1e-9


def test_unsettled_hook_raises():
    layer = _Asks(_bar(), 10 ** 9)
    with pytest.raises(ConvergenceError, match=f"after {END_STEP_PASSES} re-solves"):
        solve(layer, fixed=_fixed(), options=SolverOptions(steps=1))


def test_default_is_no_op():
    model = _bar()
    assert not hasattr(model, "end_step")
    assert end_step(model, model.rest) is False
