"""Progress inside steps: Newton callbacks, --verbose lines, size estimates.

Oracles: the per-iterate callback sees iteration numbers 0..k for each step,
with k the step's recorded Newton iterations, and a last residual at or below
the tolerance; the --verbose log has exactly one line per iterate.
"""

from __future__ import annotations

import re

import numpy as np

import voxflex as vf
from voxflex import _progress
from voxflex.cli import main
from voxflex.deform.solve.options import SolverOptions
from voxflex.deform.solve.stepping import solve
from voxflex.scene import Scene

SCENE = """
[object]
shape = "box"
size = [2.0, 0.5, 0.5]
voxel_size = 0.25
origin = [0.0, 0.0, 0.0]
[nodes]
kind = "voxel"
[[material]]
model = "neo-hookean"
young = 1e4
poisson = 0.3
density = 100.0
[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [0.01, 1.0, 1.0]
[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]
[solver]
steps = 2
"""


def test_newton_callback_sees_every_iterate():
    from voxflex.build import model as build_model
    from voxflex.deform.solve.boundary import FixedRegion

    scene = Scene.from_toml_text(SCENE)
    model = build_model(scene)
    seen = []
    records = solve(model, fixed=[FixedRegion([-1, -1, -1], [0.01, 1, 1])], gravity=np.array([0, 0, -9.81]),
                    densities={1: 100.0}, options=SolverOptions(steps=2), newton_callback=seen.append)
    for k, rec in enumerate(records[1:], start=1):
        mine = [s for s in seen if s["label"].startswith(f"static step {k}/2")]
        assert [s["iteration"] for s in mine] == list(range(rec.newton_iterations + 1))
        assert mine[-1]["residual"] <= 1e-8 and mine[0]["step_length"] == 0.0
        assert all(s["seconds"] >= 0 and s["linear_solver"] for s in mine[1:])


def test_verbose_logs_one_line_per_newton_iteration(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE)
    assert main(["simulate", str(scene), "-o", str(tmp_path / "r.h5"), "--verbose"]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ": Newton " in ln]
    r = vf.Result.load(tmp_path / "r.h5")
    assert len(lines) == int(r.newton_iterations.sum()) + r.n_steps  # iterates 0..k of every step
    pattern = re.compile(r"static step \d/2 \(load factor [\d.]+\): Newton \d+: residual [\d.e+-]+, step length [\d.e+-]+, "
                         r"linear solver .+, [\d.]+ s")
    assert all(pattern.fullmatch(ln) for ln in lines), lines
    assert "building 81 voxel nodes over 32 voxels: about 243 DOF" in err and re.search(r"model: \d+ voxel nodes", err)


def test_quiet_runs_log_nothing(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE)
    assert main(["simulate", str(scene), "-o", str(tmp_path / "r.h5"), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == ""


def test_size_estimates():
    """The line announced before building is the node kind's own estimate, the one the resource check uses:
    3 DOF per corner node of the voxels, and the memory per DOF of a nonlinear (neo-Hooke) voxel solve."""
    from voxflex.deform.models.voxel.build import BYTES_PER_DOF, CHUNK_BYTES
    from voxflex.image.label_image import LabelImage
    from voxflex.scene import MaterialSpec, NodesSpec, ObjectSpec, Scene

    scene = Scene(object=ObjectSpec(shape="box", size=(1.0, 1.0, 0.3), voxel_size=0.01),
                  materials=(MaterialSpec(model="neo-hookean", young=1e4, poisson=0.3),), nodes=NodesSpec(kind="voxel"))
    image = LabelImage(np.ones((100, 100, 30), dtype=np.uint8))
    from voxflex.simulation import image_estimate

    dofs, text = image_estimate(image, scene)
    assert dofs == 3 * 101 * 101 * 31
    assert f"{(BYTES_PER_DOF['nonlinear'] * dofs + CHUNK_BYTES) / 2**30:.3g} GB" in text and "voxel nodes" in text
    assert _progress.newton_line({"label": "static step 1/1", "iteration": 2, "residual": 1e-3,
                                  "step_length": 0.5, "linear_solver": "cg", "linear_iterations": 40,
                                  "seconds": 0.25}) == (
        "static step 1/1: Newton 2: residual 1.000e-03, step length 0.5, linear solver cg, 40 iterations, 0.250 s")


def test_bar_shows_newton_iteration_and_residual(monkeypatch):
    bars = []

    class Bar:
        def __init__(self, **kw):
            self.postfix = []
            bars.append(self)

        def update(self, n):
            pass

        def set_postfix(self, refresh=True, **kw):
            self.postfix.append(kw)

        def close(self):
            pass

    monkeypatch.setattr(_progress, "progress", lambda **kw: Bar(**kw))
    vf.simulate(Scene.from_toml_text(SCENE), progress=True)
    inner = [p for p in bars[0].postfix if "residual" in p]
    assert inner and inner[0]["newton"] == 0 and float(inner[-1]["residual"]) <= 1e-8
