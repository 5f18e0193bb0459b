"""Plasticity by a rest-strain mapping (voxflex.deform.layers.plasticity).

Oracle: a bar of 4 x 1 x 1 unit voxels (Hooke, linear strain, E = 1 Pa,
nu = 0.3, 2x2x2 Gauss) on symmetry planes x = 0 (x held), y = 0 (y held),
z = 0 (z held), stretched along x by its end face x = 4 (x prescribed).  The
stress is exactly uniaxial and uniform, so the von Mises model with linear
hardening has a closed form: yield at sigma_y = 3 mu eps_y, then
sigma = 3 mu (eps_y + H eps) / (1 + 3 mu H / E) in loading (eps the axial
strain), elastic unloading with slope E, and a permanent set eps_p = eps - sigma / E
when the end is released.

Each load level is solved by voxflex.deform.solve.equilibrium.equilibrate (one static step from
the previous state): the solver's post-convergence hook (PlasticModel.end_step)
return-maps the plastic state and re-solves the level until e_p stops changing
(the staggered scheme of the module); the fixed point is the exact incremental
solution, so the forces match the closed form to the solver's tolerance: 1e-7
relative (Newton stops at 1e-10 of the force scale; the staggered loop at a
change of e_p below 1e-10 of the yield strain).  The same holds for a load ramp
of several steps in one solve() call, and for implicit Euler with heavy damping
(its steps end at rest).
"""

from __future__ import annotations

import numpy as np
import pytest

from voxflex.deform.layers.plasticity import PlasticMaterial, von_mises_strain
from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import FixedRegion
from voxflex.deform.solve.equilibrium import equilibrate
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage

E, NU, EPS_Y, H, L = 1.0, 0.3, 1e-3, 0.5, 4.0
MU = E / (2 * (1 + NU))
INF = np.inf


def _bar():
    base = material("hooke", young=E, poisson=NU, strain="linear")
    image = LabelImage(np.ones((4, 1, 1), dtype=np.uint8))
    mat = PlasticMaterial(base, 4 * 8, yield_strain=EPS_Y, hardening=H)
    model = VoxelModel.from_image(image, {1: mat})
    return model, mat


def _supports():
    tiny = 1e-9
    return [FixedRegion([-INF, -INF, -INF], [tiny, INF, INF], "x"),
            FixedRegion([-INF, -INF, -INF], [INF, tiny, INF], "y"),
            FixedRegion([-INF, -INF, -INF], [INF, INF, tiny], "z")]


def _end(eps):
    T = np.zeros((3, 4))
    T[:, :3] = np.diag([1.0 + eps, 1.0, 1.0])
    return FixedRegion([L - 1e-9, -INF, -INF], [INF, INF, INF], "x", T)


def _force(model, q):
    end = model.rest[:, 0] > L - 1e-9
    return float(model.gradient(q)[end, 0].sum())  # reaction on the end face = sigma * area (area 1)


def _sigma_loading(eps):
    sig_e = E * eps
    if sig_e <= 3 * MU * EPS_Y:
        return sig_e
    return 3 * MU * (EPS_Y + H * eps) / (1 + 3 * MU * H / E)


def test_bar_loading_unloading_and_permanent_set():
    model, mat = _bar()
    eps_yield = 3 * MU * EPS_Y / E  # axial strain at first yield
    q = model.rest.copy()
    loading = np.array([0.5, 1.0, 1.5, 2.0, 3.0]) * eps_yield
    for eps in loading:
        q = equilibrate(model, mat, q, _supports() + [_end(eps)])
        f = _force(model, q)
        assert f == pytest.approx(_sigma_loading(eps), rel=1e-7), eps
    eps_max = loading[-1]
    sig_max = _sigma_loading(eps_max)
    assert sig_max < 0.9 * E * eps_max  # past yield: well below the elastic line
    # unloading by a strain decrement smaller than the elastic range: elastic, slope E (the initial stiffness)
    d = 0.5 * eps_yield
    alpha_before = mat.alpha.copy()
    q = equilibrate(model, mat, q, _supports() + [_end(eps_max - d)])
    f_un = _force(model, q)
    assert (sig_max - f_un) / d == pytest.approx(E, rel=1e-6)
    np.testing.assert_array_equal(mat.alpha, alpha_before)  # no further yield
    # release the end: the bar keeps a permanent set eps_p = eps_max - sigma_max / E
    q = equilibrate(model, mat, q, _supports())
    end = model.rest[:, 0] > L - 1e-9
    set_ = float(np.mean(q[end, 0] - model.rest[end, 0])) / L
    expected = eps_max - sig_max / E
    assert expected > 0.5 * eps_yield
    assert set_ == pytest.approx(expected, rel=1e-7)
    assert abs(_force(model, q)) < 1e-9 * sig_max


def test_elastic_below_yield_equals_base_material():
    base = material("hooke", young=E, poisson=NU, strain="linear")
    mat = PlasticMaterial(base, 3, yield_strain=0.1)
    rng = np.random.default_rng(0)
    F = np.eye(3) + 1e-3 * rng.standard_normal((3, 3, 3))
    assert mat.update(F) == 0
    for a, b in zip(mat.evaluate(F), base.evaluate(F)):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-18)


def test_return_mapping_lands_on_the_hardened_yield_surface():
    base = material("hooke", young=E, poisson=NU, strain="green")
    mat = PlasticMaterial(base, 5, yield_strain=1e-2, hardening=0.3)
    rng = np.random.default_rng(1)
    F = np.eye(3) + 0.1 * rng.standard_normal((5, 3, 3))
    assert mat.update(F) == 5
    e_el = base.strain.apply(F) - mat.plastic_strain
    # consistency: eps_eq(elastic) = eps_y + H alpha (to round-off), plastic flow is deviatoric (trace 0)
    np.testing.assert_allclose(von_mises_strain(e_el), 1e-2 + 0.3 * mat.alpha, rtol=1e-12)
    np.testing.assert_allclose(mat.plastic_strain[:, :3].sum(axis=1), 0.0, atol=1e-15)
    # samples= picks rows: evaluating a permutation gives the permuted results
    perm = rng.permutation(5)
    np.testing.assert_allclose(mat.energy(F[perm], samples=perm), mat.energy(F)[perm], rtol=1e-14)


def test_bad_input():
    base = material("hooke", young=E, poisson=NU, strain="linear")
    mat = PlasticMaterial(base, 4, yield_strain=1e-3)
    mat.evaluate(np.tile(np.eye(3), (3, 1, 1)))  # virgin: the base material, any rows
    assert mat.update(np.tile(np.diag([1.01, 1.0, 1.0]), (4, 1, 1))) == 4
    with pytest.raises(InputError, match="samples="):
        mat.evaluate(np.tile(np.eye(3), (3, 1, 1)))  # yielded: rows must match the samples
    with pytest.raises(InputError, match="tensor strain"):
        PlasticMaterial(material("neo-hookean", young=1.0, poisson=0.3), 4, yield_strain=1e-3)
    with pytest.raises(InputError, match="yield_strain"):
        PlasticMaterial(base, 4, yield_strain=0.0)


def test_load_ramp_in_one_solve_commits_each_step():
    """solve() with 4 static steps: at each record (the solver's sink runs after the step's plastic state
    is committed) the end force is the closed form at its strain, and the layer's measures are the
    committed state's (yield counts from the closed form: none before the first yield, all 32 Gauss
    points after, the stress being uniform)."""
    from voxflex.deform.layers.plasticity import PlasticModel
    from voxflex.deform.solve.options import SolverOptions
    from voxflex.deform.solve.stepping import solve

    model, mat = _bar()
    layer = PlasticModel(model)
    eps_yield = 3 * MU * EPS_Y / E
    eps_max = 3.0 * eps_yield
    seen = []

    def sink(rec):
        seen.append((rec.time, _force(model, rec.q), *layer.measure()))

    records = solve(layer, fixed=_supports() + [_end(eps_max)], options=SolverOptions(steps=4, tolerance=1e-10),
                    sink=sink)
    assert len(seen) == 5 and len(layer.history) == 2  # the rest state and 4 steps; two committed states held
    for t, force, _, _ in seen[1:]:
        assert force == pytest.approx(_sigma_loading(t * eps_max), rel=1e-7), t
    assert [c for *_, c, _ in seen] == [0, 0, 32, 32, 32]  # strains 0.75, 1.5, 2.25, 3 x the yield strain
    # uniaxial stress: the equivalent plastic strain is the axial plastic strain eps - sigma / E
    expected = eps_max - _sigma_loading(eps_max) / E
    assert seen[-1][3] == pytest.approx(expected, rel=1e-7)
    assert _force(model, records[-1].q) == pytest.approx(_sigma_loading(eps_max), rel=1e-7)


def test_layer_refuses_models_it_cannot_track():
    from voxflex.deform.layers.plasticity import PlasticModel

    base = material("hooke", young=E, poisson=NU, strain="linear")
    image = LabelImage(np.ones((4, 1, 1), dtype=np.uint8))
    with pytest.raises(InputError, match="no plastic material"):
        PlasticModel(VoxelModel.from_image(image, {1: base}))
    mat = PlasticMaterial(base, None, yield_strain=EPS_Y)
    with pytest.raises(InputError, match="volumetric"):
        PlasticModel(VoxelModel.from_image(image, {1: mat}, volumetric="reduced"))
    mat = PlasticMaterial(base, None, yield_strain=EPS_Y)
    PlasticModel(VoxelModel.from_image(image, {1: mat}))
    assert mat.n_samples == 32  # sized by the layer: 4 voxels x 8 Gauss points
    with pytest.raises(InputError, match="material of its own"):
        PlasticModel(VoxelModel.from_image(LabelImage(np.ones((2, 1, 1), dtype=np.uint8)), {1: mat}))
