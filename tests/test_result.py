"""The result file: SPEC layout after a real run, round trip, atomic writes, ParaView series."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import h5py
import numpy as np
import paths
import pytest
from golden import LINEAR_CANTILEVER_TIP, RELATIVE
from results import hand_result  # noqa: E402 - shared with test_render

import voxflex
from voxflex.errors import InputError
from voxflex.result import Result
from voxflex.result_text import describe_result

EXAMPLES = paths.ROOT / "examples"




def _equal(a: Result, b: Result) -> bool:
    arrays = [
        "time", "surface_rest", "surface_faces", "surface_positions", "nodes_rest", "nodes_state",
        "energy_elastic", "energy_kinetic", "newton_iterations", "step_seconds", "image_labels",
        "image_spacing", "image_origin", "image_direction",
    ]
    same = all(np.array_equal(getattr(a, k), getattr(b, k)) for k in arrays)
    same &= a.probes.keys() == b.probes.keys() and all(np.array_equal(a.probes[k], b.probes[k]) for k in a.probes)
    return same and (a.scene, a.version, a.node_kind) == (b.scene, b.version, b.node_kind)


@pytest.fixture(scope="module")
def cantilever(tmp_path_factory):
    path = tmp_path_factory.mktemp("result") / "cantilever.h5"
    result = voxflex.simulate(EXAMPLES / "cantilever.toml", progress=False, output=path)
    return result, path


def test_layout_matches_the_spec_after_a_real_simulation(cantilever):
    result, path = cantilever
    T, V, n = 2, result.surface_rest.shape[0], result.n_nodes  # static, 1 load step: rest + 1 state
    assert n == 9 * 3 * 3  # 8x2x2 voxels -> 9x3x3 corner nodes
    with h5py.File(path, "r") as f:
        assert f.attrs["voxflex_version"] == voxflex.__version__
        assert "[object]" in f.attrs["scene"] and 'model = "hooke"' in f.attrs["scene"]
        expected = {
            "time": (T,),
            "probes/tip": (T, 3),
            "surface/rest": (V, 3),
            "surface/faces": (result.surface_faces.shape[0], 3),
            "surface/positions": (T, V, 3),
            "nodes/rest": (n, 3),
            "nodes/state": (T, n, 3),
            "energy/elastic": (T,),
            "energy/kinetic": (T,),
            "stats/newton_iterations": (T,),
            "stats/step_seconds": (T,),
            "image/labels": (8, 2, 2),
        }
        for name, shape in expected.items():
            assert f[name].shape == shape, name
            if f[name].size > 1:
                assert f[name].compression == "gzip", name
        assert np.allclose(f["image/labels"].attrs["spacing"], [0.5, 0.5, 0.5])
        assert np.allclose(f["image/labels"].attrs["origin"], [0.0, 0.0, 0.0])
        for where in (f["image"], f["image/labels"]):  # geometry on the group and on the dataset
            assert np.allclose(where.attrs["direction"], np.eye(3))
            assert np.allclose(where.attrs["spacing"], [0.5, 0.5, 0.5])
        assert np.issubdtype(f["surface/faces"].dtype, np.integer)
        np.testing.assert_array_equal(f["time"][()], [0.0, 1.0])  # static: load factors
        # the surface is the node set seen through vertex_node: positions agree with the node states
        rest_nodes = {tuple(p): i for i, p in enumerate(f["nodes/rest"][()])}
        idx = [rest_nodes[tuple(p)] for p in f["surface/rest"][()]]
        np.testing.assert_array_equal(f["surface/positions"][()], f["nodes/state"][()][:, idx])
        # the rest state: zero energy, no displacement
        # F at rest is I up to round-off (~1e-16), so W ~ E * 1e-32 * volume: far below 1e-20 J
        assert abs(f["energy/elastic"][0]) < 1e-20
        np.testing.assert_array_equal(f["nodes/state"][0], f["nodes/rest"][()])
    # the tip probe: the 8x2x2 reference of peer libraries (see examples/cantilever.toml), 1e-5 relative
    assert result.probes["tip"][-1, 2] - 0.5 == pytest.approx(LINEAR_CANTILEVER_TIP[8], rel=RELATIVE)


def test_save_load_round_trip(cantilever, tmp_path):
    result, path = cantilever
    loaded = Result.load(path)
    assert _equal(loaded, result)
    hand = hand_result()
    hand.save(tmp_path / "hand.h5")
    assert _equal(Result.load(tmp_path / "hand.h5"), hand)


def test_atomic_write_keeps_the_existing_file(tmp_path, monkeypatch):
    target = tmp_path / "r.h5"
    hand_result(T=2).save(target)
    before = target.read_bytes()

    original = h5py.Group.create_dataset

    def failing(self, name, *args, **kwargs):
        if name == "positions":  # fail half-way through the file
            raise RuntimeError("disk full (simulated)")
        return original(self, name, *args, **kwargs)

    monkeypatch.setattr(h5py.Group, "create_dataset", failing)
    with pytest.raises(RuntimeError, match="simulated"):
        hand_result(T=5).save(target)
    monkeypatch.undo()
    assert target.read_bytes() == before  # the old file is intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.h5"]  # no partial temporary left
    with pytest.raises(RuntimeError):
        monkeypatch.setattr(h5py.Group, "create_dataset", failing)
        hand_result().save(tmp_path / "new.h5")
    assert not (tmp_path / "new.h5").exists()


def test_loading_something_else_is_a_clear_error(tmp_path):
    with pytest.raises(InputError, match="not found"):
        Result.load(tmp_path / "missing.h5")
    (tmp_path / "text.h5").write_text("hello")
    with pytest.raises(InputError, match="not an HDF5 file"):
        Result.load(tmp_path / "text.h5")
    with h5py.File(tmp_path / "other.h5", "w") as f:
        f["data"] = np.zeros(3)
    with pytest.raises(InputError, match="not a voxflex result file"):
        Result.load(tmp_path / "other.h5")


def test_inconsistent_shapes_are_rejected():
    r = hand_result()
    with pytest.raises(InputError, match="surface_positions"):
        Result(**{**_fields(r), "surface_positions": r.surface_positions[:2]})
    with pytest.raises(InputError, match="probe 'tip'"):
        Result(**{**_fields(r), "probes": {"tip": np.zeros((7, 3))}})


def _fields(r: Result) -> dict:
    from dataclasses import fields

    return {f.name: getattr(r, f.name) for f in fields(r)}


def test_describe_result(cantilever):
    text = describe_result(cantilever[1])
    assert "81 voxel nodes, 243 DOF" in text and "32 occupied" in text and "probe tip" in text


def test_export_vtk_writes_a_paraview_series(tmp_path):
    import pyvista as pv

    r = hand_result(T=3)
    pvd = r.export_vtk(tmp_path / "series")
    assert pvd == tmp_path / "series" / "result.pvd"
    entries = ET.parse(pvd).getroot().find("Collection").findall("DataSet")
    assert [float(e.get("timestep")) for e in entries] == [0.0, 0.5, 1.0]
    for t, e in enumerate(entries):
        mesh = pv.read(pvd.parent / e.get("file"))
        assert mesh.n_points == 8 and mesh.n_cells == 12
        np.testing.assert_allclose(mesh.points, r.surface_positions[t])
        np.testing.assert_allclose(mesh.point_data["displacement"], r.surface_positions[t] - r.surface_rest)
    # a .pvd target names the files after it
    pvd2 = r.export_vtk(tmp_path / "beam.pvd")
    assert pvd2.exists() and (tmp_path / "beam_0002.vtp").exists()
    # ParaView's own reader opens the collection (pyvista wraps vtkPVDReader)
    reader = pv.get_reader(str(pvd2))
    assert len(reader.time_values) == 3
