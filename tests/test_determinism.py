"""Every linear solver option gives bitwise identical answers run to run.

Oracle: the same computation done twice in one process must give the same
bits (``np.array_equal``, no tolerance).  ``"amg"`` used to differ by ~1e-11
between runs (pyamg draws a random start vector from numpy's global generator
for its spectral-radius estimate); it is now seeded, and the caller's global
generator state must come back unchanged.
"""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.chain.rigid_modes import rigid_body_modes
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.linear import METHODS, solve_linear
from voxflex.image.label_image import LabelImage


@pytest.fixture(scope="module", autouse=True)
def one_blas_thread():
    """Dense Cholesky with threaded OpenBLAS stalls for seconds on a busy 2-core machine (measured)."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # only slower without it
        yield
        return
    with threadpool_limits(1, user_api="blas"):
        yield


@pytest.fixture(scope="module")
def system():
    # 12x3x3 clamped beam: 13*4*4*3 - 48 = 576 unknowns, above pyamg's
    # max_coarse = 500 so AMG builds a real hierarchy (the random part)
    image = LabelImage(np.ones((12, 3, 3)), spacing=(1 / 3, 1 / 3, 1 / 3))
    model = VoxelModel.from_image(image, {1: material("hooke", young=1e4, poisson=0.3, strain="linear")})
    K = model.hessian(model.rest)
    free = np.flatnonzero(np.repeat(model.rest[:, 0] > 1e-9, 3))
    b = np.random.default_rng(3).standard_normal(len(free))
    return K[free][:, free].tocsr(), b, rigid_body_modes(model.rest)[free], model, free


@pytest.mark.parametrize("method", METHODS)
def test_linear_solve_is_bitwise_reproducible(system, method):
    A, b, nn, model, free = system
    assert A.shape[0] > 500
    # geometric multigrid (where it exists) needs the voxel grid and the free DOFs
    extra = dict(grid=model.grid, free=free) if method == "multigrid" else {}
    x1, info1 = solve_linear(A, b, method=method, rtol=1e-8, near_null=nn, **extra)
    x2, info2 = solve_linear(A, b, method=method, rtol=1e-8, near_null=nn, **extra)
    assert np.array_equal(x1, x2), np.abs(x1 - x2).max()
    assert info1.iterations == info2.iterations and info1.method == info2.method


def test_amg_leaves_the_global_generator_alone(system):
    A, b, nn, _, _ = system
    np.random.seed(12345)
    expected = np.random.rand(4)
    np.random.seed(12345)
    solve_linear(A, b, method="amg", rtol=1e-8, near_null=nn)
    assert np.array_equal(np.random.rand(4), expected)


_SCENE = """
[object]
shape = "box"
size = [3.0, 0.75, 0.75]
voxel_size = 0.25

[nodes]
kind = "voxel"
[[material]]
label = 1
model = "neo-hookean"
young = 1.0e4
poisson = 0.3
density = 1.0

[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [1.0e-6, 2.0, 2.0]

[[load]]
kind = "gravity"
vector = [0.0, 0.0, -50.0]

[solver]
kind = "static"
steps = 1
linear_solver = "{method}"
"""


@pytest.mark.parametrize("method", METHODS)
def test_simulation_is_bitwise_reproducible_for_every_linear_solver(method):
    """Whole Newton runs (12x3x3 voxels, 576 free unknowns, neo-Hooke) repeat bit for bit."""
    from voxflex.scene import Scene
    from voxflex.simulation import simulate

    scene = Scene.from_toml_text(_SCENE.format(method=method))
    first = simulate(scene, progress=False)
    second = simulate(scene, progress=False)
    assert np.array_equal(first.nodes_state, second.nodes_state)
    assert np.array_equal(first.newton_iterations, second.newton_iterations)
    # the run moved: a non-trivial state is being compared
    assert np.abs(first.nodes_state[-1] - first.nodes_state[0]).max() > 1e-3
