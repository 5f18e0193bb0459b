"""Every material's own constants can be given in a scene, and reach the material.

Table-driven through ``voxflex simulate``: a 2x1x1-voxel block is moved as a
whole by a prescribed uniform stretch (every node prescribed, so the state is
exact), and the elastic energy in the result file must equal
``V * W(F)`` of ``vf.material(model, **constants)`` to 1e-12 relative (the
energy of a uniform F integrates exactly).  A wrong constant name is a
one-line error with a did-you-mean and that model's keys.
"""

from __future__ import annotations

import numpy as np
import pytest

import voxflex as vf
from voxflex.cli import main
from voxflex.deform.materials.constitutive import MODEL_CONSTANTS

F = np.array([[1.1, 0.05, 0.0], [0.0, 0.97, 0.02], [0.01, 0.0, 1.03]])

CONSTANTS = {
    "hooke": {"mu": 300.0, "lmbda": 500.0},
    "hooke-orthotropic": {"E1": 1e3, "E2": 2e3, "E3": 1.5e3, "nu12": 0.2, "nu13": 0.25, "nu23": 0.3,
                          "G12": 400.0, "G13": 450.0, "G23": 500.0},
    "stvk": {"mu": 300.0, "lmbda": 500.0},
    "neo-hookean": {"mu": 300.0, "lmbda": 500.0},
    "stable-neo-hookean": {"mu": 300.0, "lmbda": 500.0},
    "mooney-rivlin": {"c1": 100.0, "c2": 50.0, "bulk": 900.0},
    "arruda-boyce": {"mu": 200.0, "bulk": 900.0, "lambda_m": 3.5},
    "veronda-westmann": {"c1": 100.0, "c2": 1.5, "bulk": 900.0},
    "volume-log": {"bulk": 900.0},
    "volume-quadratic": {"bulk": 900.0},
    "ogden": {"mu_p": [200.0, 1.0], "alpha_p": [2.0, -2.0], "lmbda": 400.0},
}


def test_the_table_covers_every_model():
    assert set(CONSTANTS) == set(MODEL_CONSTANTS) == set(vf.deform.MATERIALS)
    for name, consts in CONSTANTS.items():
        assert set(consts) <= set(MODEL_CONSTANTS[name])


def _toml(value):
    return "[" + ", ".join(map(repr, value)) + "]" if isinstance(value, list) else repr(value)


def _scene(model: str, constants: dict) -> str:
    rows = "\n".join(f"{k} = {_toml(v)}" for k, v in constants.items())
    T = np.hstack([F, np.zeros((3, 1))])
    transform = "[" + ", ".join("[" + ", ".join(repr(float(x)) for x in r) + "]" for r in T) + "]"
    return f"""
[object]
shape = "box"
size = [2.0, 1.0, 1.0]
voxel_size = 1.0

[nodes]
kind = "voxel"
[[material]]
model = "{model}"
{rows}

[[fixed]]
transform = {transform}
"""


@pytest.mark.parametrize("model", sorted(CONSTANTS))
def test_scene_constants_reach_the_material(model, tmp_path, capsys):
    path = tmp_path / f"{model}.toml"
    path.write_text(_scene(model, CONSTANTS[model]))
    out = tmp_path / "r.h5"
    assert main(["simulate", str(path), "-o", str(out), "--quiet"]) == 0, capsys.readouterr().err
    energy = vf.Result.load(out).energy_elastic[-1]
    mat = vf.material(model, **CONSTANTS[model])
    expected = 2.0 * float(mat.energy(F[None])[0])
    assert energy == pytest.approx(expected, rel=1e-12)


def test_a_wrong_constant_name_suggests_that_models_keys(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(_scene("arruda-boyce", {"mu": 1.0, "bulk": 2.0, "lamda_m": 3.0}))
    assert main(["simulate", str(path), "-o", str(tmp_path / "r.h5"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "unknown key 'lamda_m' in [material] (did you mean 'lambda_m'?)" in err[0]
    assert "valid keys for model 'arruda-boyce'" in err[0] and "lambda_m" in err[0]
