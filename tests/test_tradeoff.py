"""voxflex.sweep and ``voxflex tradeoff``: errors against hand computations, the reference's
refinement floor, the Pareto front and the budget by brute force, outputs, bad input, Dask = serial.

The sweeps are tiny (the linear cantilever of examples/ at 8x2x2 voxels, a few frames) so that the
file runs in seconds; what is checked is the bookkeeping, not the accuracy of the reduced models.
"""

from __future__ import annotations

import csv
import dataclasses
import math

import numpy as np
import paths
import pytest
from golden import LINEAR_CANTILEVER_CONVERGED, LINEAR_CANTILEVER_TIP, RELATIVE

import voxflex as vf
from voxflex.cli import main
from voxflex.errors import InputError
from voxflex.scene import Scene
from voxflex.image.levels import merge_blocks as _merge
from voxflex.image.levels import split_voxels as _split
from voxflex.sweep import COLUMNS, METRICS, Configuration, TradeoffTable, _surface_error, tradeoff

EXAMPLES = paths.ROOT / "examples"
SPEC_COLUMNS = ("kind, count, shape_function, quadrature, samples, dofs, precompute_seconds, solve_seconds, "
                "newton_iterations, probe_error, surface_error, energy_error, pareto, reference_error").split(", ")
SWEEP = dict(frames=(5, 8), samples=(4, 40), shape_functions=("natural-neighbour",), quadratures=("midpoint", "elaston"),
             progress=False)  # the machinery, on the weights whose figures the assertions name


@pytest.fixture(scope="module")
def scene():
    return Scene.from_toml(EXAMPLES / "cantilever.toml")


@pytest.fixture(scope="module")
def table(scene):
    return tradeoff(scene, max_error=0.3, **SWEEP)


def _run(scene, config, image=None):
    """A configuration run by hand, outside the sweep machinery."""
    from threadpoolctl import threadpool_limits

    s = config.scene(scene)
    with threadpool_limits(limits=1):
        m = vf.model(s, image=image)
        return m, vf.simulate(s, model=m, progress=False)


def _rel(a, b):
    return abs(a - b) / abs(b)


def test_rows_reference_first_then_coarser_grid_then_sweep(table):
    roles = [r["role"] for r in table.rows]
    assert roles[:2] == ["reference", "refinement"]
    assert all(r == "reduced" for r in roles[2:])
    ref = table.rows[0]
    assert ref["kind"] == "voxel" and ref["voxel_size"] == 0.5 and ref["dofs"] == 3 * 9 * 3 * 3
    assert all(ref[m] == 0.0 for m in METRICS)
    assert table.rows[1]["voxel_size"] == 1.0
    reduced = {(r["count"], r["quadrature"]) for r in table.rows[2:]}
    assert reduced == {(5, "midpoint"), (8, "midpoint"), (5, "elaston"), (8, "elaston")}
    # 8 frames on 4 elaston regions (37 sub-rule points) leave a near-zero-energy mode (4,800 times softer
    # than one sample per voxel): refused before solving, listed with the reason
    assert len(table.skipped) == 1 and "8 frames" in table.skipped[0][0] and "elaston 4" in table.skipped[0][0]
    assert "near-zero-energy mode" in table.skipped[0][1]
    for r in table.rows:
        assert "surfaces differ" not in r["note"]  # same image: the same boundary vertex for vertex
        assert r["total_seconds"] == pytest.approx(r["precompute_seconds"] + r["solve_seconds"])
        assert r["dofs"] == (12 * r["count"] if r["kind"] == "affine" else r["dofs"])


def test_errors_match_a_hand_computation(scene, table):
    # The sweep's runs and the hand runs are the same deterministic computation on one thread:
    # 1e-9 relative leaves room only for summation order, nothing else.
    cfg = Configuration("affine", count=8, shape_function="natural-neighbour", quadrature="midpoint", samples=40)
    _, ref = _run(scene, Configuration("voxel"))
    m, res = _run(scene, cfg)
    u_ref = ref.probes["tip"] - ref.probes["tip"][0]
    u = res.probes["tip"] - res.probes["tip"][0]
    probe = np.max(np.linalg.norm(u - u_ref, axis=1)) / np.max(np.linalg.norm(u_ref, axis=1))
    # same voxelized boundary, vertex for vertex
    np.testing.assert_array_equal(res.surface_rest, ref.surface_rest)
    d_ref = ref.surface_positions - ref.surface_rest
    d = res.surface_positions - res.surface_rest
    rms = [math.sqrt(sum(float(np.sum((d[t, v] - d_ref[t, v]) ** 2)) for v in range(len(d_ref[t]))) / len(d_ref[t]))
           for t in range(len(d))]
    surface = max(rms) / np.max(np.linalg.norm(d_ref, axis=2))
    e_ref = ref.energy_elastic + ref.energy_kinetic
    energy = np.max(np.abs(res.energy_elastic + res.energy_kinetic - e_ref)) / np.max(np.abs(e_ref))
    row = next(r for r in table.rows if r["count"] == 8 and r["quadrature"] == "midpoint" and r["samples"] > 4)
    assert row["dofs"] == 96 and row["samples"] == m.n_samples
    assert _rel(row["probe_error"], probe) < 1e-9
    assert _rel(row["surface_error"], surface) < 1e-9
    assert _rel(row["energy_error"], energy) < 1e-9
    assert row["probe_uz"] == pytest.approx(u[-1, 2], rel=1e-9)


def test_reference_error_is_the_coarser_grid_against_the_reference(scene, table):
    coarse_scene = dataclasses.replace(scene, object=dataclasses.replace(scene.object, voxel_size=1.0))
    from voxflex.build import build_image

    coarse_image = build_image(coarse_scene)
    # merging 2x2x2 blocks of the 8x2x2 box gives the box voxelized at 1.0
    np.testing.assert_array_equal(_merge(build_image(scene)).labels, coarse_image.labels)
    _, ref = _run(scene, Configuration("voxel"))
    _, coarse = _run(coarse_scene, Configuration("voxel"))
    u_ref = ref.probes["tip"][-1] - ref.probes["tip"][0]
    u = coarse.probes["tip"][-1] - coarse.probes["tip"][0]
    expected = np.linalg.norm(u - u_ref) / np.linalg.norm(u_ref)  # one load step: the final state decides
    assert _rel(table.reference_error["probe_error"], expected) < 1e-9
    assert table.rows[0]["reference_error"] == table.reference_error["probe_error"]
    assert table.rows[1]["probe_error"] == table.reference_error["probe_error"]


def test_errors_below_the_reference_floor_are_flagged_and_ranked_at_the_floor(table):
    floor = table.reference_error
    for r in table.rows[2:]:
        flags = set(filter(None, r["below_reference"].split(";")))
        assert flags == {m.split("_")[0] for m in METRICS if r[m] < floor[m]}
        assert table.ranked_error(r) == max(r["probe_error"], floor["probe_error"])
    assert table.ranked_error(table.rows[0]) == floor["probe_error"]


def test_pareto_front_and_budget_by_brute_force(table):
    rows = table.rows
    for r in rows:
        dominated = any(o is not r and o["total_seconds"] <= r["total_seconds"]
                        and table.ranked_error(o) < table.ranked_error(r)
                        or o is not r and o["total_seconds"] < r["total_seconds"]
                        and table.ranked_error(o) <= table.ranked_error(r) for o in rows)
        assert r["pareto"] == (not dominated), r
    fits = [r for r in rows if table.ranked_error(r) <= 0.3]
    expected = min(fits, key=lambda r: r["total_seconds"]) if fits else None
    assert table.choice is expected


def test_surfaces_of_voxel_and_frame_models_coincide_vertex_for_vertex(scene):
    v = vf.model(Configuration("voxel").scene(scene)).boundary_surface()
    f = vf.model(Configuration("affine", count=5, shape_function="natural-neighbour", quadrature="midpoint",
                               samples=40).scene(scene)).boundary_surface()
    np.testing.assert_array_equal(v[0], f[0])
    np.testing.assert_array_equal(v[1], f[1])


def test_surface_error_on_a_synthetic_field():
    # rest vertices on a unit square grid; reference moves every vertex by (0, 0, -1), the model by
    # (0, 0, -1) + (0.1 on half of them): RMS = sqrt(0.5 * 0.01), max reference displacement 1.
    V = np.array([[i, j, 0.0] for i in range(4) for j in range(4)])
    X_ref = (V + [0.0, 0.0, -1.0])[None]
    extra = np.zeros_like(V)
    extra[::2, 0] = 0.1
    run = {"surface_rest": V[::-1].copy(), "surface_positions": (X_ref[0] + extra)[None, ::-1], "voxel_size": 1.0}
    ref = {"surface_rest": V, "surface_positions": X_ref, "voxel_size": 1.0}
    err, of_ref, of_model = _surface_error(run, ref)
    assert of_ref == of_model == 1.0
    assert err == pytest.approx(math.sqrt(0.5 * 0.01), rel=1e-14)  # round-off only
    half = {"surface_rest": V[:8], "surface_positions": X_ref[:, :8], "voxel_size": 1.0}
    assert _surface_error(half, ref) == (0.0, 0.5, 1.0)


def test_split_keeps_the_geometry_and_merge_undoes_it():
    labels = np.zeros((3, 2, 2), dtype=np.uint8)
    labels[0], labels[1, 0] = 1, 2
    image = vf.LabelImage(labels, spacing=np.array([0.5, 0.5, 0.5]), origin=np.array([1.0, 2.0, 3.0]))
    fine = _split(image)
    assert fine.labels.shape == (6, 4, 4) and np.allclose(fine.spacing, 0.25)
    assert fine.label_volumes() == pytest.approx(image.label_volumes(), rel=1e-15)  # exact in binary
    np.testing.assert_array_equal(_merge(fine).labels, image.labels)
    np.testing.assert_array_equal(_merge(fine).origin, image.origin)


def test_elastons_integrate_an_invariant_strain(scene):
    """Neo-Hooke (an invariant strain) with elastons: the configuration runs (the Taylor elastons skipped
    it); on 32 one-voxel regions the sub-rules keep every Gauss point, so the answer is Gauss-Legendre's
    to the solver's tolerance."""
    neo = dataclasses.replace(scene, materials=(dataclasses.replace(scene.materials[0], model="neo-hookean",
                                                                    strain=None),),
                              elasticity=dataclasses.replace(scene.elasticity, strain=None))
    t = tradeoff(neo, frames=(5,), samples=(40,), quadratures=("elaston", "gauss-legendre"), progress=False)
    assert [r["kind"] for r in t.rows] == ["voxel", "voxel", "affine", "affine"] and not t.skipped
    el, gl = t.rows[2], t.rows[3]
    assert el["quadrature"] == "elaston" and gl["quadrature"] == "gauss-legendre"
    assert el["probe_uz"] == pytest.approx(gl["probe_uz"], rel=1e-6)


def test_finer_reference_makes_the_scene_grid_the_first_coarser_row(scene):
    t = tradeoff(scene, frames=(5,), samples=(40,), quadratures=("midpoint",), reference="finer",
                 voxel_levels=2, progress=False)
    assert [r["voxel_size"] for r in t.rows[:3]] == [0.25, 0.5, 1.0]
    # the finer grid's tip is closer to the converged 3-D value (-0.39278) than the scene's (-0.339310)
    assert abs(t.rows[0]["probe_uz"] - LINEAR_CANTILEVER_CONVERGED) < abs(t.rows[1]["probe_uz"] - LINEAR_CANTILEVER_CONVERGED)
    assert t.rows[1]["probe_uz"] == pytest.approx(LINEAR_CANTILEVER_TIP[8], rel=RELATIVE)  # the example's asserted value


def test_outputs(table, tmp_path):
    csv_path, png_path = table.save(tmp_path / "out")
    with open(csv_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert set(SPEC_COLUMNS) <= set(rows[0]) and list(rows[0]) == list(COLUMNS)
    assert len(rows) == len(table.rows)
    for got, want in zip(rows, table.rows):
        assert float(got["probe_error"]) == want["probe_error"]
        assert got["pareto"] == ("true" if want["pareto"] else "false")
    back = TradeoffTable.read_csv(csv_path)  # the CSV carries the table (repr of floats: exact)
    assert back.reference_error == table.reference_error and back.metric == table.metric
    for got, want in zip(back.rows, table.rows):
        assert all(got[k] == want[k] or (isinstance(want[k], float) and math.isnan(want[k]) and math.isnan(got[k]))
                   for k in COLUMNS), want
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="not a tradeoff.csv"):
        TradeoffTable.read_csv(other)
    assert png_path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image

    with Image.open(png_path) as im:
        assert im.size[0] > 400 and im.size[1] > 300


@pytest.mark.parametrize("kwargs, words", [
    ({"frames": (0,)}, "frames"),
    ({"frames": ()}, "frames"),
    ({"samples": (2.5,)}, "samples"),
    ({"quadratures": ("gauss",)}, "quadrature"),
    ({"shape_functions": ("voronoi",)}, "shape function"),
    ({"reference": "coarser"}, "reference"),
    ({"voxel_levels": 0}, "voxel_levels"),
    ({"max_error": -1.0}, "max_error"),
    ({"workers": 2, "scheduler": "tcp://x:1"}, "not both"),
    ({"workers": 0}, "workers"),
])
def test_bad_options(scene, kwargs, words):
    with pytest.raises(InputError, match=words):
        tradeoff(scene, progress=False, **kwargs)


def test_cli(tmp_path, capsys):
    scene_path = str(EXAMPLES / "cantilever.toml")
    out = tmp_path / "sweep"
    args = ["tradeoff", scene_path, "-o", str(out), "--frames", "5", "--samples", "40", "--quadratures", "midpoint"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "reference voxel h=0.5" in printed and "machine:" in printed
    assert (out / "tradeoff.csv").is_file() and (out / "tradeoff.png").is_file()
    # a budget nothing can meet (below the reference's own refinement error): exit 1, outputs still written
    assert main(args + ["--max-error", "1e-9", "--quiet"]) == 1
    # bad input: one line on stderr, exit 2
    for bad in (["--frames", "five"], ["--quadratures", "gaus"]):
        assert main(["tradeoff", scene_path, "-o", str(out), *bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("voxflex tradeoff: error:")
    # an existing file that is not this command's output is not replaced
    other = tmp_path / "other"
    other.mkdir()
    (other / "tradeoff.csv").write_text("precious\n")
    assert main(["tradeoff", scene_path, "-o", str(other)]) == 2
    assert "--force" in capsys.readouterr().err
    assert (other / "tradeoff.csv").read_text() == "precious\n"


@pytest.mark.slow
def test_dask_sweep_equals_the_serial_one(scene, table):
    """With Dask workers the table equals the serial one, also when Dask's default dashboard port 8787 is
    taken (another cluster, a notebook): the local cluster's dashboard takes a free port, no warning."""
    import socket

    pytest.importorskip("dask.distributed")
    with socket.socket() as taken:
        try:
            taken.bind(("127.0.0.1", 8787))
            taken.listen()
        except OSError:
            pass  # already taken by something else: the same situation
        distributed = tradeoff(scene, max_error=0.3, workers=2, **SWEEP)
    assert len(distributed.rows) == len(table.rows)
    times = {"precompute_seconds", "solve_seconds", "total_seconds", "pareto"}  # pareto depends on times
    for a, b in zip(distributed.rows, table.rows):
        for key in COLUMNS:
            if key not in times:
                assert a[key] == b[key] or (isinstance(a[key], float) and math.isnan(a[key]) and math.isnan(b[key])), key
    assert distributed.reference_error == table.reference_error
    assert distributed.skipped == table.skipped


def test_missing_dask_is_a_one_line_error_naming_the_extra(scene, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # import of it raises ImportError
    with pytest.raises(InputError, match=r'pip install "voxflex\[dask\]"'):
        tradeoff(scene, workers=2, **SWEEP)


def test_requests_the_sampler_caps_to_the_same_model_are_shown_once(scene):
    # 8x2x2 = 32 voxels: mid-point requests of 40 and 100 samples both give one sample per voxel
    t = tradeoff(scene, frames=(5,), samples=(40, 100), quadratures=("midpoint",), progress=False)
    reduced = [r for r in t.rows if r["role"] == "reduced"]
    assert len(reduced) == 1 and reduced[0]["samples"] == 32
    assert len(t.skipped) == 1 and "100 samples" in t.skipped[0][0] and "as for 40 requested" in t.skipped[0][1]


def test_precompute_times_never_come_from_the_disk_cache(scene, monkeypatch, tmp_path):
    # a sweep repeats short runs and may follow an earlier sweep: each build must do the precompute,
    # not load it (a load took 5 ms where the precompute took 0.3 s, and the median of 3 hid it)
    from voxflex import cache as disk

    monkeypatch.setenv("VOXFLEX_CACHE_DIR", str(tmp_path))
    vf.model(Configuration(role="reduced", kind="affine", count=5, shape_function="natural-neighbour",
                           quadrature="midpoint", samples=40).scene(scene))  # an entry a sweep could hit
    loads = []
    real = disk.load
    monkeypatch.setattr(disk, "load", lambda *a, **k: loads.append(a) or real(*a, **k))
    tradeoff(scene, frames=(5,), samples=(40,), quadratures=("midpoint",), progress=False)
    assert loads == []
