"""Result files streamed step by step: same contents, bounded memory, nothing destroyed.

Oracles: the same scene run without a result file (every state held in
memory: the file must hold exactly those numbers, bit for bit, wall times
aside); the solver run on its own (the sink must not change the states);
tracemalloc's peak over a short run (beyond the writer's 64-state buffer) and one five times longer (streaming must
not grow, holding every state must, by about the states' bytes: the positive
control that shows the measurement sees growth); the bytes of an existing
result file before and after a failed or interrupted run.

The model is one voxel (24 DOF) under gravity in implicit Euler with a fixed
face, a probe and the fields von-mises and reaction, so that every kind of
per-state dataset is written and each step is cheap (a few ms on 2 cores).
"""

from __future__ import annotations

import dataclasses
import os
import signal
import tracemalloc
from dataclasses import replace

import h5py
import numpy as np
import pytest

import voxflex as vf
import voxflex.resources as res
import voxflex.result_text
from voxflex._atomic import Interrupted
from voxflex.cli import main
from voxflex.errors import InputError
from voxflex.result import Result, ResultWriter
from voxflex.scene import Scene

SCENE = """
[object]
shape = "box"
size = [1.0, 1.0, 1.0]
voxel_size = 1.0
[nodes]
kind = "voxel"
[[material]]
model = "hooke"
young = 1e7
poisson = 0.3
density = 1000
[[fixed]]
min = [-1.0, -1.0, -1.0]
max = [0.01, 2.0, 2.0]
[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]
[solver]
kind = "implicit-euler"
steps = 10
dt = 0.001
[[probe]]
name = "tip"
point = [1.0, 0.5, 0.5]
[output]
fields = ["von-mises", "reaction"]
"""
SHORT, LONG = 80, 400
GiB = 1 << 30


def _scene(steps):
    scene = Scene.from_toml_text(SCENE)
    return replace(scene, solver=replace(scene.solver, steps=steps))


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    m = vf.model(_scene(10))
    # compile every kernel and import every module (h5py's included) outside the measurements
    vf.simulate(_scene(5), progress=False, model=m, output=tmp_path_factory.mktemp("warm") / "warm.h5")
    return m


def _run(model, steps, **kw):
    return vf.simulate(_scene(steps), progress=False, model=model, **kw)


def _peak(fn):
    """(result, peak bytes traced above the start) of fn()."""
    tracemalloc.start()
    try:
        tracemalloc.reset_peak()
        base = tracemalloc.get_traced_memory()[0]
        out = fn()
        return out, tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


@pytest.fixture(scope="module")
def runs(model, tmp_path_factory):
    folder = tmp_path_factory.mktemp("stream")
    out = {}
    for n in (SHORT, LONG):
        path = folder / f"run{n}.h5"
        out["streamed", n] = _peak(lambda: _run(model, n, output=path, keep="last")) + (path,)
        out["memory", n] = _peak(lambda: _run(model, n))
    return out


def _row_bytes(path):
    """Bytes of one state in the file (uncompressed): the per-state datasets' sizes over T."""
    sizes = []
    with h5py.File(path, "r") as f:
        T = f["time"].shape[0]
        f.visititems(lambda name, d: sizes.append(d.nbytes) if isinstance(d, h5py.Dataset)
                     and d.shape[:1] == (T,) and name != "image/labels" else None)
    return sum(sizes) / T


@pytest.mark.slow
def test_streaming_memory_does_not_grow_with_the_steps(runs):
    _, short, path = runs["streamed", SHORT]
    streamed, long_, _ = runs["streamed", LONG]
    _, held_short = runs["memory", SHORT]
    held, held_long = runs["memory", LONG]
    extra = LONG - SHORT
    # the positive control: holding every state grows by at least the states' own bytes
    grown = held_long - held_short
    assert grown >= extra * _row_bytes(path), (grown, extra * _row_bytes(path))
    # streaming: five times the steps cost less than 20 % of that growth.  Measured here: streamed peaks of
    # 265 to 345 kB at 80, 130, 200, 400 and 2000 steps, no trend (the writer buffers at most 64 states in
    # every one of them), against about 1 MB more for holding the 320 extra states
    assert long_ - short < 0.2 * grown, (short, long_, grown)
    # and what the streamed run returns is bounded: the rest state and the last one
    assert streamed.step.tolist() == [0, LONG] and held.n_states == LONG + 1


def test_the_streamed_file_equals_the_in_memory_run(runs):
    streamed, _, path = runs["streamed", LONG]
    held, _ = runs["memory", LONG]
    rows = held.rows()
    assert {"probes/tip", "fields/von-mises", "surface/fields/von-mises", "reactions/force",
            "stats/min_det_F"} <= set(rows)
    with h5py.File(path, "r") as f:
        assert f.attrs["complete"] and f.attrs["format"] == "voxflex-result"
        for p, values in rows.items():
            if p == "stats/step_seconds":  # wall times differ run to run
                assert f[p].shape == values.shape
                continue
            assert f[p].dtype == values.dtype and np.array_equal(f[p][()], values), p
        for p, values in (("surface/rest", held.surface_rest), ("surface/faces", held.surface_faces),
                          ("nodes/rest", held.nodes_rest), ("image/labels", held.image_labels)):
            assert np.array_equal(f[p][()], values), p
        assert f["fields/von-mises"].attrs["location"] == "voxels"
    loaded = Result.load(path)
    assert loaded.n_states == LONG + 1 and loaded.n_steps == LONG
    for key in ("nodes_state", "surface_positions", "time", "energy_kinetic", "newton_iterations"):
        assert np.array_equal(getattr(loaded, key), getattr(held, key)), key
    # the bounded result returned by the streamed run: its two states and the run's totals
    for key in ("nodes_state", "surface_positions", "reactions", "energy_elastic"):
        assert np.array_equal(getattr(streamed, key), getattr(held, key)[[0, -1]]), key
    a, b = streamed.run_totals(), held.run_totals()
    a.pop("step_seconds"), b.pop("step_seconds")
    assert a == b and a["newton_iterations"] == int(held.newton_iterations.sum())
    assert loaded.run_totals()["newton_iterations"] == a["newton_iterations"]


def test_the_sink_leaves_the_solver_states_unchanged(model):
    from voxflex.deform.solve.boundary import FixedRegion
    from voxflex.deform.solve.options import SolverOptions
    from voxflex.deform.solve.stepping import solve

    scene = _scene(40)
    held = _run(model, 40)
    seen = []
    records = solve(model, fixed=[FixedRegion(np.array(f.min), np.array(f.max)) for f in scene.fixed],
                    gravity=np.array(scene.gravity), densities={m.label: m.density for m in scene.materials},
                    options=SolverOptions(**dataclasses.asdict(scene.solver)), sink=seen.append)
    assert len(records) == 2 and len(seen) == 41  # the sink saw every record, the list kept two
    assert np.array_equal(np.stack([r.q for r in seen]), held.nodes_state)
    assert records[-1] is seen[-1] and records[0] is seen[0]


def test_every_and_keep(model, tmp_path):
    steps, every = 23, 5
    held = _run(model, steps)
    path = tmp_path / "every.h5"
    kept = _run(model, steps, output=path, every=every, keep=3)
    chosen = [0, 5, 10, 15, 20, 23]  # the rest state, every 5th step and the last
    r = Result.load(path)
    assert r.step.tolist() == chosen and r.n_steps == steps and r.n_states == len(chosen)
    assert np.array_equal(r.nodes_state, held.nodes_state[chosen])
    assert np.array_equal(r.reactions, held.reactions[chosen])  # inertia from the previous step, recorded or not
    # effort of a recorded state: the steps since the previous recorded one
    its = np.add.reduceat(held.newton_iterations, [0, 1, 6, 11, 16, 21])
    assert r.newton_iterations.tolist() == its.tolist()
    assert r.run_totals()["newton_iterations"] == int(held.newton_iterations.sum())
    assert r.run_totals()["min_det_F"] == float(held.min_det_F.min())
    assert kept.step.tolist() == [0, 15, 20, 23]
    assert np.array_equal(kept.nodes_state, held.nodes_state[[0, 15, 20, 23]])
    last = _run(model, steps, keep=2)  # without a file: the rest state and the last 2
    assert last.step.tolist() == [0, 22, 23] and np.array_equal(last.probes["tip"], held.probes["tip"][[0, 22, 23]])
    text = vf.result_text.describe_result(path)
    assert "the rest state and 5 of 23 steps" in text
    for bad in (0, -1, "some", 1.5, True):
        with pytest.raises(InputError, match="keep must be|unknown keep"):
            _run(model, 3, keep=bad)
    with pytest.raises(InputError, match="every must be"):
        _run(model, 3, every=0)


class _Boom(RuntimeError):
    pass


def _fail_at(monkeypatch, call, action):
    """Make the result writer's ``call``-th append run ``action`` (after the states before it were taken)."""
    original = ResultWriter.append
    count = [0]

    def append(self, row):
        count[0] += 1
        if count[0] == call:
            action()
        return original(self, row)

    monkeypatch.setattr(ResultWriter, "append", append)
    return count


def _old_result(model, path):
    _run(model, 3, output=path)
    return path.read_bytes()


def test_a_failure_mid_run_keeps_the_old_result_and_no_temporary(model, tmp_path, monkeypatch):
    path = tmp_path / "beam.h5"
    before = _old_result(model, path)

    def boom():
        raise _Boom("disk gone")

    _fail_at(monkeypatch, 100, boom)  # after a written block of 64 states
    with pytest.raises(_Boom):
        _run(model, 200, output=path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["beam.h5"]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_run_stops_it_within_a_step(model, tmp_path, monkeypatch, signum):
    path = tmp_path / "beam.h5"
    before = _old_result(model, path)
    # the handlers the run found (SIG_IGN for SIGINT when pytest runs as a background job, else Python's own)
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    count = _fail_at(monkeypatch, 100, lambda: os.kill(os.getpid(), signum))
    with pytest.raises(Interrupted) as exc:
        _run(model, 200, output=path)
    assert exc.value.signum == signum
    assert count[0] == 100  # stopped after the step it arrived in, not at the end of the run
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["beam.h5"]
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers  # handlers restored


def test_cli_exits_130_on_sigterm_mid_run(tmp_path, monkeypatch, capsys):
    scene = tmp_path / "beam.toml"
    scene.write_text(SCENE.replace("steps = 10", "steps = 200"))
    out = tmp_path / "beam.h5"
    assert main(["simulate", str(scene), "-o", str(out), "--quiet", "--every", "7"]) == 0
    before = out.read_bytes()
    r = Result.load(out)
    assert r.step.tolist() == [*range(0, 200, 7), 200]
    _fail_at(monkeypatch, 80, lambda: os.kill(os.getpid(), signal.SIGTERM))
    capsys.readouterr()
    assert main(["simulate", str(scene), "-o", str(out), "--quiet"]) == 130
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["beam.h5", "beam.toml"]


def test_resources_bound_streamed_runs_by_the_disk_not_the_steps(runs, tmp_path, monkeypatch):
    scene = _scene(1_000_000_000)
    target = tmp_path / "long.h5"
    # no file: every state held, refused for memory, naming the result file and the steps that fit
    with pytest.raises(InputError, match=r"result file .*steps <=") as exc:
        res.check(scene, available=8 * GiB)
    assert "\n" not in str(exc.value)
    # a result file: memory holds two states whatever the steps; only the disk bounds the run
    est = res.check(scene, available=8 * GiB, output=target, disk=10**18)
    assert est.held_states == 2 and est.total_bytes < 0.1 * GiB and est.states == 1_000_000_001
    with pytest.raises(InputError, match=r"every = ([\d,]+)") as exc:
        res.check(scene, available=8 * GiB, output=target, disk=GiB)
    k = int(exc.value.args[0].split("every = ")[1].split(":")[0].replace(",", ""))
    thinned = res.check(scene, available=8 * GiB, output=target, disk=GiB, every=k)
    assert thinned.file_bytes <= GiB
    assert res.estimate(scene, output=target, every=max(k // 2, 1)).file_bytes > GiB
    # the row estimate is an upper bound of what the file really holds per state, and not far above
    _, _, path = runs["streamed", LONG]
    actual = _row_bytes(path)
    assert actual <= est.row_bytes <= 2 * actual, (actual, est.row_bytes)
    # simulate runs the check with its output before building anything
    monkeypatch.setattr(res, "free_disk", lambda path: 10**6)
    with pytest.raises(InputError, match="--every"):
        vf.simulate(scene, progress=False, output=target)
    assert not target.exists()


def test_a_failed_run_records_its_last_converged_step_whatever_every(tmp_path):
    from results import (
        SQUEEZE_SCENE as SQUEEZE,  # converges at steps 1 and 2 of 5, fails at step 3
    )

    out = tmp_path / "bar.h5"
    with pytest.raises(vf.ConvergenceError, match="step 3/5"):
        vf.simulate(Scene.from_toml_text(SQUEEZE), progress=False, output=out, every=3)
    r = Result.load(out)
    # every 3rd step would record none of the two converged steps: the last converged one is kept
    assert not r.complete and r.step.tolist() == [0, 2] and r.n_steps == 2
    np.testing.assert_allclose(r.probes["end"][:, 0], [2.0, 0.4], rtol=0, atol=1e-9)  # uniform squeeze, s = 0.4
    assert r.run_totals()["steps"] == 2


def test_output_every_and_keep_are_scene_keys_the_call_overrides(tmp_path):
    """[output] every / keep in a scene: validated with one-line errors, written back by to_toml, used by
    simulate() unless its keep= / every= say otherwise."""
    from dataclasses import replace

    import voxflex as vf
    from voxflex.errors import InputError
    from voxflex.scene import OutputSpec, Scene, default_scene_path

    for bad, match in (({"every": 0}, "every"), ({"every": 1.5}, "every"), ({"keep": "some"}, "keep"),
                       ({"keep": 0}, "keep"), ({"keep": True}, "keep")):
        with pytest.raises(InputError, match=match):
            OutputSpec(**bad)
    scene = Scene.from_toml(default_scene_path())
    # 6 natural-neighbour frames (6 reproducing kernels on the 2 mm capsule lie on a line: a warning)
    scene = replace(scene, object=replace(scene.object, voxel_size=0.002),
                    nodes=replace(scene.nodes, count=6, shape_function="natural-neighbour"),
                    elasticity=replace(scene.elasticity, samples=120), solver=replace(scene.solver, steps=4),
                    output=OutputSpec(every=2, keep="last"))
    back = Scene.from_toml_text(scene.to_toml())
    assert (back.output.every, back.output.keep) == (2, "last")
    r = vf.simulate(scene, progress=False)
    assert list(r.step) == [0, 4]  # every 2 records 0, 2, 4; keep "last" holds the rest state and the last
    r = vf.simulate(scene, progress=False, keep="all")
    assert list(r.step) == [0, 2, 4]
    r = vf.simulate(scene, progress=False, keep="all", every=1)
    assert list(r.step) == [0, 1, 2, 3, 4]


def test_each_recorded_state_evaluates_the_sample_fields_once(tmp_path):
    # the inversion check and the output fields of a state share one model.sample_fields(q): with
    # fields asked, a run of T steps recorded every 2 evaluates them once per step (T + 1 states with the
    # rest state), not twice for the recorded ones; the fields equal those computed afresh
    from voxflex.deform.models.fields import model_fields

    m = vf.model(_scene(6))
    calls = []
    real = m.sample_fields

    def counted(q):
        calls.append(1)
        return real(q)

    m.sample_fields = counted
    result = vf.simulate(_scene(6), progress=False, model=m, every=2)
    assert len(calls) == 7
    m.sample_fields = real
    cells, _ = model_fields(m, result.nodes_state[-1], ["von-mises"])
    assert np.allclose(result.fields["von-mises"][-1], cells["von-mises"], rtol=1e-12, atol=0.0)
