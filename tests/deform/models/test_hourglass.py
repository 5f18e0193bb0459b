"""Hourglass control of the mid-point voxel model.

Oracles: the rank of the stiffness (exactly the 6 rigid modes), Jensen's
inequality (the stabilisation is positive semi-definite) and its null space
(affine motions, finite rotations included), the algebraic identity
"mid-point + Gauss-minus-mid-point stiffness = Gauss" for linear elasticity,
central finite differences, the symmetry of the clamped cantilever and the
Gauss-Legendre solution of the same problem.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from voxflex.deform.materials.constitutive import material
from voxflex.deform.models.voxel.model import VoxelModel
from voxflex.deform.solve.boundary import FixedRegion
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage

TIP = np.array([4.0, 0.5, 0.5])
CLAMP = FixedRegion([-1.0, -1.0, -1.0], [1e-9, 2.0, 2.0])


def _zero_modes(model):
    ev = np.linalg.eigvalsh(model.hessian(model.rest).toarray())
    return int(np.sum(ev < 1e-9 * ev.max()))


@pytest.mark.parametrize("shape", [(1, 1, 1), (2, 2, 2), (3, 1, 2)])
@pytest.mark.parametrize("mat", [material("hooke", young=1e4, poisson=0.3, strain="linear"),
                                 material("neo-hookean", young=1e4, poisson=0.45)])
def test_stabilised_midpoint_has_only_the_rigid_modes(shape, mat):
    image = LabelImage(np.ones(shape), spacing=(0.2, 0.3, 0.25))
    bare = VoxelModel.from_image(image, {1: mat}, quadrature="midpoint", hourglass="none")
    stab = VoxelModel.from_image(image, {1: mat}, quadrature="midpoint", hourglass="stiffness", volumetric="auto")
    assert _zero_modes(bare) > 6
    assert _zero_modes(stab) == 6


def test_hourglass_stiffness_is_psd_and_blind_to_affine_motion():
    image = LabelImage(np.ones((1, 1, 1)), spacing=(0.2, 0.3, 0.25))
    for nu, vol in [(0.3, "full"), (0.49, "reduced")]:
        model = VoxelModel.from_image(image, {1: material("neo-hookean", young=1e4, poisson=nu)},
                                      quadrature="midpoint", hourglass="stiffness", volumetric=vol)
        K = model._hourglass_unit(1)
        ev = np.linalg.eigvalsh(K)
        assert ev.min() >= -1e-12 * ev.max()  # Jensen: sum w B^T C B >= B_c^T C B_c
        # 24 - 12 affine motions (3 x 4 coefficients) = 12 hourglass-and-more directions at most
        assert int(np.sum(ev > 1e-9 * ev.max())) <= 12
        c, s = np.cos(1.1), np.sin(1.1)
        R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
        X = model.rest
        for A in (R, np.array([[1.2, 0.3, 0.0], [-0.1, 0.9, 0.4], [0.2, 0.0, 1.1]])):
            u = (X @ A.T + [1.0, 2.0, 3.0] - X).ravel()
            assert np.abs(K @ u).max() <= 1e-12 * np.abs(K).max() * np.abs(u).max()


@pytest.mark.parametrize("nu, volumetric", [(0.3, "full"), (0.49, "reduced")])
def test_linear_midpoint_plus_hourglass_equals_gauss(nu, volumetric):
    # for linear elasticity K_mid + (K_gauss - K_mid) is K_gauss (full) and, with the deviatoric part
    # only, B-bar (isotropic: the bulk term at the centre, the deviatoric one at the Gauss points).
    # Equal to round-off (1e-12 of the largest entry)
    rng = np.random.default_rng(0)
    a = (rng.random((4, 3, 2)) < 0.8).astype(int)
    a[0, 0, 0] = 1
    image = LabelImage(a, spacing=(0.1, 0.2, 0.15))
    mat = material("hooke", young=1e4, poisson=nu, strain="linear")
    g_model = VoxelModel.from_image(image, {1: mat}, volumetric=volumetric)
    gauss = g_model.hessian(g_model.rest)
    mid = VoxelModel.from_image(image, {1: mat}, quadrature="midpoint", hourglass="stiffness", volumetric=volumetric)
    assert mid.constant_tangent
    Hm = mid.hessian(mid.rest)
    assert abs(Hm - gauss).max() <= 1e-12 * abs(gauss).max()


def test_nonlinear_stabilised_midpoint_matches_finite_differences():
    rng = np.random.default_rng(4)
    image = LabelImage(np.ones((3, 2, 2)), spacing=(0.1, 0.2, 0.15))
    model = VoxelModel.from_image(image, {1: material("neo-hookean", young=1e4, poisson=0.45)},
                                  quadrature="midpoint", hourglass="stiffness", volumetric="auto")
    q = model.rest + 0.01 * rng.standard_normal(model.rest.shape)
    E, g, H = model.energy_gradient_hessian(q)
    v = rng.standard_normal(q.shape)
    h = 1e-6  # same argument as the shared contract: FD errors ~1e-9 relative, 1e-6 catches any wrong term
    assert (model.energy(q + h * v) - model.energy(q - h * v)) / (2 * h) == pytest.approx(np.sum(g * v), rel=1e-6)
    fdg = (model.gradient(q + h * v) - model.gradient(q - h * v)) / (2 * h)
    Hv = (H @ v.ravel()).reshape(q.shape)
    assert np.linalg.norm(fdg - Hv) <= 1e-6 * np.linalg.norm(Hv)
    # a translated body gets no stabilisation energy (displacements taken relative to the voxel mean):
    # only the material's own round-off at F = I + O(eps) remains, the same as the bare rule's
    bare = VoxelModel.from_image(image, model.materials, quadrature="midpoint", hourglass="none")
    moved = model.rest + [3.0, -2.0, 1.0]
    assert abs(model.energy(moved) - bare.energy(moved)) <= 1e-20


def _tip(mat, quadrature, **kw):
    image = LabelImage(np.ones((16, 4, 4)), spacing=(0.25, 0.25, 0.25))
    model = VoxelModel.from_image(image, {1: mat}, quadrature=quadrature, **kw)
    records = solve(model, fixed=[CLAMP], gravity=[0, 0, -9.81], densities={1: 1.0},
                    options=SolverOptions(tolerance=1e-10))
    return model.point_mapping([TIP]).apply(records[-1].q)[0] - TIP


@pytest.mark.parametrize("name, kw, nu, rel", [
    # linear: the identity above, so the solutions agree to the solver's tolerance (1e-8 relative)
    ("hooke", {"strain": "linear"}, 0.3, 1e-8),
    # neo-Hooke: mid-point evaluates the nonlinear part at one point; measured 1.0e-5 (nu = 0.3) and
    # 1.2e-4 (nu = 0.4999, against F-bar Gauss) relative at a 9 % tip deflection: 1e-3 bounds both
    ("neo-hookean", {}, 0.3, 1e-3),
    ("neo-hookean", {}, 0.4999, 1e-3),
])
def test_midpoint_cantilever_is_symmetric_and_matches_gauss(name, kw, nu, rel):
    mat = material(name, young=1e4, poisson=nu, **kw)
    mid = _tip(mat, "midpoint", hourglass="stiffness", volumetric="auto")
    gauss = _tip(mat, "gauss-legendre", volumetric="auto")
    # vertical gravity on a symmetric beam: no sideways motion (today's bare rule: 0.59 m); 1e-9 m is
    # round-off of a 0.37 m deflection through a solver at 1e-10 relative tolerance
    assert abs(mid[1]) < 1e-9
    assert mid[2] == pytest.approx(gauss[2], rel=rel)
    assert mid[0] == pytest.approx(gauss[0], rel=max(rel, 1e-2), abs=1e-12)


def test_options_are_validated_and_advice_names_the_fix():
    image = LabelImage(np.ones((1, 1, 1)))
    mat = material("hooke", young=1e4, poisson=0.3, strain="linear")
    with pytest.raises(InputError, match="hourglass"):
        VoxelModel.from_image(image, {1: mat}, quadrature="midpoint", hourglass="flanagan")
    bare = VoxelModel.from_image(image, {1: mat}, quadrature="midpoint", hourglass="none")
    stab = VoxelModel.from_image(image, {1: mat}, quadrature="midpoint", hourglass="stiffness")
    assert 'hourglass = "stiffness"' in bare.advice() and stab.advice() == ""
    assert stab.describe()["hourglass"] == "stiffness" and stab.describe()["volumetric"] == "full"
    # Gauss-Legendre ignores the stabilisation (its stiffness already sees the hourglass modes)
    g1 = VoxelModel.from_image(image, {1: mat}, hourglass="stiffness").hessian(stab.rest)
    g0 = VoxelModel.from_image(image, {1: mat}, hourglass="none").hessian(stab.rest)
    assert abs(g1 - g0).max() == 0.0


def test_scene_keys_default_to_the_remedies():
    from voxflex.scene import ElasticitySpec, Scene

    spec = ElasticitySpec()
    assert (spec.volumetric, spec.hourglass) == ("auto", "stiffness")
    with pytest.raises(InputError, match=r"\[elasticity\] volumetric"):
        ElasticitySpec(volumetric="reduce")
    with pytest.raises(InputError, match=r"\[elasticity\] hourglass"):
        ElasticitySpec(hourglass=1)
    text = ('[object]\nshape = "box"\nsize = [1, 1, 1]\nvoxel_size = 0.5\n[[material]]\nyoung = 1e4\npoisson = 0.3\n'
            '[elasticity]\nquadrature = "midpoint"\nvolumetric = "reduced"\nhourglass = "none"\n')
    scene = Scene.from_toml_text(text)
    assert (scene.elasticity.volumetric, scene.elasticity.hourglass) == ("reduced", "none")
    assert Scene.from_toml_text(scene.to_toml()) == scene
    assert replace(scene.elasticity, hourglass="stiffness").hourglass == "stiffness"
