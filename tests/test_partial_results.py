"""Partial results: a run whose later step fails still writes the steps that converged.

Oracle: a neo-Hookean bar squeezed uniformly (sliding supports) by a mirror map
whose right face crosses the left one at load factor 0.5: with 5 steps, steps 1
and 2 (stretch 0.6 and 0.2) are admissible, step 3 (stretch -0.2) would invert
every voxel, which neo-Hooke forbids (infinite energy), so the run must stop
there with 2 converged steps written and marked incomplete.
"""

from __future__ import annotations

import numpy as np
import pytest
from results import SQUEEZE_SCENE as SCENE

import voxflex as vf
from voxflex.cli import main
from voxflex.result import Result
from voxflex.scene import Scene


def test_failure_at_step_3_of_5_writes_the_two_converged_steps(tmp_path):
    out = tmp_path / "bar.h5"
    with pytest.raises(vf.ConvergenceError, match="step 3/5") as exc:
        vf.simulate(Scene.from_toml_text(SCENE), progress=False, output=out)
    assert "2 step(s) that converged were written" in str(exc.value)
    r = Result.load(out)
    assert not r.complete and "step 3/5" in r.error
    assert r.n_steps == 2 and r.n_states == 3
    # the converged states are the uniform squeeze: end face at x = 2 (1 - 2 s), s = 0.2, 0.4 (to round-off)
    np.testing.assert_allclose(r.probes["end"][:, 0], [2.0, 1.2, 0.4], rtol=0, atol=1e-9)
    np.testing.assert_allclose(r.time, [0.0, 0.2, 0.4], rtol=0, atol=1e-15)
    assert r.inverted_samples.tolist() == [0, 0, 0] and r.min_det_F[-1] > 0


def test_cli_exits_non_zero_and_says_where_the_partial_file_is(tmp_path, capsys):
    scene = tmp_path / "bar.toml"
    scene.write_text(SCENE)
    out = tmp_path / "bar.h5"
    assert main(["simulate", str(scene), "-o", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "marked incomplete" in err and str(out) in err
    r = Result.load(out)
    assert r.n_steps == 2 and not r.complete
    assert main(["info", str(out)]) == 0
    assert "INCOMPLETE" in capsys.readouterr().out


def test_failure_at_the_first_step_writes_nothing(tmp_path):
    out = tmp_path / "bar.h5"
    text = SCENE.replace("steps = 5", "steps = 1")
    with pytest.raises(vf.ConvergenceError):
        vf.simulate(Scene.from_toml_text(text), progress=False, output=out)
    assert not out.exists()  # nothing converged: no file (an existing one would be left as it was)


def test_n_steps_counts_steps_not_states(tmp_path):
    r = vf.simulate(Scene.from_toml_text(SCENE.replace("steps = 5", "steps = 2").replace("-1.0, 0.0, 0.0, 0.0",
                                                                                          "0.9, 0.0, 0.0, 0.0")),
                    progress=False)
    assert r.n_steps == 2 and r.n_states == 3 and r.complete and r.error == ""
    assert r.step_index(-1) == 2 and r.displacement(2).shape == r.surface_rest.shape
