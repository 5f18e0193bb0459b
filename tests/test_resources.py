"""Resources estimated before a run, and the refusal of scenes that cannot fit.

Oracles: the models that the scenes actually build (voxel and node counts,
exact for boxes), the CSR matrix a model really assembles (a lower bound of
its memory), and the suggested fixes themselves (a scene changed as the
message says must pass the same check).
"""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import paths
import pytest

import voxflex.resources as res
from voxflex.errors import InputError
from voxflex.image.label_image import LabelImage
from voxflex.scene import MaterialSpec, NodesSpec, ObjectSpec, Scene, SolverSpec

ROOT = paths.ROOT
GiB = 1 << 30


def _box(size=(4.0, 1.0, 1.0), h=0.25, model="hooke", **kw):
    kw.setdefault("nodes", NodesSpec(kind="voxel"))
    return Scene(object=ObjectSpec(shape="box", size=size, voxel_size=h),
                 materials=(MaterialSpec(model=model, young=1e4, poisson=0.3),), **kw)


def test_available_memory_reads_the_machine():
    avail = res.available_memory()
    total = None
    try:
        text = Path("/proc/meminfo").read_text()
        total = int(re.search(r"MemTotal:\s+(\d+) kB", text).group(1)) * 1024
    except (OSError, AttributeError):
        pytest.skip("no /proc/meminfo here")
    assert avail is not None and 0 < avail <= total


def test_available_memory_falls_back_gracefully(monkeypatch):
    import builtins

    real_open = builtins.open

    def no_meminfo(path, *a, **k):
        if str(path) == "/proc/meminfo":
            raise OSError("not here")
        return real_open(path, *a, **k)

    monkeypatch.setattr(builtins, "open", no_meminfo)
    avail = res.available_memory()  # sysconf or the cgroup, or None: never an exception
    assert avail is None or avail > 0
    monkeypatch.setattr(res, "available_memory", lambda: None)
    huge = _box(size=(100.0, 100.0, 100.0), h=0.001)
    assert res.check(huge).voxels == 10**15  # unknown memory: nothing is refused


def test_box_counts_are_exact_against_the_built_model():
    import voxflex as vf

    for size, h in [((4.0, 1.0, 1.0), 0.25), ((0.3, 0.03, 0.03), 0.006), ((1.0, 0.5, 0.25), 0.125)]:
        scene = _box(size, h)
        est = res.estimate(scene)
        model = vf.model(scene)
        assert est.voxels == model.n_elements
        assert est.nodes == model.n_nodes and est.dofs == 3 * model.n_nodes
        assert est.states == 2 and est.node_kind == "voxel"


@pytest.mark.parametrize("shape, size, h", [("sphere", (0.5,), 0.1), ("cylinder", (0.5, 1.0), 0.1)])
def test_curved_shapes_within_a_few_percent(shape, size, h):
    import voxflex as vf

    scene = Scene(object=ObjectSpec(shape=shape, size=size, voxel_size=h), nodes=NodesSpec(kind="voxel"),
                  materials=(MaterialSpec(model="neo-hookean", young=1e4, poisson=0.3),))
    est = res.estimate(scene)
    model = vf.model(scene)
    # the volume / h^3 count against the voxels whose centres fall inside: staircase error of a
    # coarse ball or disc (5 voxels per radius) is a few percent; 10 % bounds it, nodes likewise 15 %
    assert est.voxels == pytest.approx(model.n_elements, rel=0.10)
    assert est.nodes == pytest.approx(model.n_nodes, rel=0.15)


def test_image_and_mesh_sources():
    import voxflex as vf

    scene = Scene.from_toml(ROOT / "examples" / "object_mesh.toml")
    est = res.estimate(scene)
    model = vf.model(replace(scene, nodes=NodesSpec(kind="voxel")))
    assert est.voxels == pytest.approx(model.n_elements, rel=0.15)  # mesh volume / h^3 vs voxel centres inside
    image_scene = Scene.from_toml(ROOT / "examples" / "object_image.toml")
    image = LabelImage.load(image_scene.object.image)
    est = res.estimate(image_scene)
    assert est.voxels == int(np.count_nonzero(image.labels))  # counted, not estimated
    assert est.voxel_size == pytest.approx(float(np.max(image.spacing)))


def test_model_memory_is_at_least_the_assembled_stiffness():
    import voxflex as vf

    for model_name in ("hooke", "neo-hookean"):
        scene = _box((2.0, 0.5, 0.5), 0.1, model=model_name)
        est = res.estimate(scene)
        H = vf.model(scene).hessian(vf.model(scene).rest)
        csr = H.data.nbytes + H.indices.nbytes + H.indptr.nbytes
        assert est.model_bytes >= 2 * csr  # the stiffness and its free-DOF copy at least
        assert est.model_bytes <= 40 * csr  # and not absurdly more (measured 6-15x with solver work)


def test_a_billion_steps_are_refused_with_the_steps_that_fit():
    scene = _box(solver=SolverSpec(steps=1_000_000_000))
    with pytest.raises(InputError, match=r"\[solver\] steps <=") as exc:
        res.check(scene, available=8 * GiB)
    message = str(exc.value)
    assert "\n" not in message and "stored states" in message
    fit = int(re.search(r"steps <= ([\d,]+)", message).group(1).replace(",", ""))
    assert 1000 < fit < 1_000_000_000
    # the suggestion itself passes, one more state beyond the budget does not fit by much
    ok = res.check(replace(scene, solver=SolverSpec(steps=fit)), available=8 * GiB)
    assert ok.total_bytes <= res.MEMORY_FRACTION * 8 * GiB
    assert res.estimate(replace(scene, solver=SolverSpec(steps=fit + 2))).total_bytes > res.MEMORY_FRACTION * 8 * GiB


def test_a_model_too_large_names_a_voxel_size_that_fits():
    scene = _box(size=(4.0, 1.0, 1.0), h=0.002, model="neo-hookean")  # 5e8 voxels
    with pytest.raises(InputError, match=r"\[object\] voxel_size >=") as exc:
        res.check(scene, available=2 * GiB)
    h = float(re.search(r"voxel_size >= ([\d.]+)", str(exc.value)).group(1))
    assert h > 0.002
    coarser = replace(scene, object=replace(scene.object, voxel_size=h))
    assert res.check(coarser, available=2 * GiB).voxels < 5e8


def test_frames_too_many_names_a_count_that_fits():
    scene = _box(h=0.05, nodes=NodesSpec(kind="affine", count=40_000))
    with pytest.raises(InputError, match=r"\[nodes\] count <=") as exc:
        res.check(scene, available=4 * GiB)
    count = int(re.search(r"count <= (\d+)", str(exc.value)).group(1))
    assert 1 <= count < 40_000
    fitted = replace(scene, nodes=NodesSpec(kind="affine", count=count))
    assert res.check(fitted, available=4 * GiB).nodes <= count + 1


def test_estimate_scales_and_summarises():
    one = res.estimate(_box(solver=SolverSpec(steps=1)))
    ten = res.estimate(_box(solver=SolverSpec(steps=10)))
    assert ten.seconds == pytest.approx(10 * one.seconds) and ten.states == 11
    assert ten.total_bytes - one.total_bytes == 9 * one.state_bytes
    text = ten.summary()
    assert "DOF" in text and "memory" in text and "time" in text and "\n" not in text
    # a near-incompressible neo-Hooke (F-bar by "auto") costs more than a linear one of the same size
    lin = res.estimate(_box(model="hooke"))
    red = res.estimate(replace(_box(model="neo-hookean"),
                               materials=(MaterialSpec(model="neo-hookean", young=1e4, poisson=0.45),)))
    assert red.model_bytes > lin.model_bytes and red.seconds > lin.seconds


def test_bad_arguments():
    with pytest.raises(InputError, match="needs a Scene"):
        res.estimate("scene.toml")
    with pytest.raises(InputError, match="fraction"):
        res.check(_box(), fraction=2.0)
    with pytest.raises(InputError, match="available"):
        res.check(_box(), available=-5)
    assert math.isfinite(res.check(_box(), available=8 * GiB).seconds)


def test_a_membrane_is_estimated_from_its_mesh():
    """The estimate asks the scene's node kind: a membrane's DOFs are its free vertices (3 each), not 20 frames
    of a sphere as before the node kinds had estimators (120 DOF estimated for a 507-DOF model)."""

    import voxflex as vf
    from voxflex.resources import estimate
    from voxflex.scene import Scene

    scene = Scene.from_toml(paths.ROOT / "examples" / "membrane_pressure.toml")
    est = estimate(scene)
    model = vf.model(scene)
    assert est.node_kind == "membrane" and est.dofs == model.rest.size == 3 * model.n_nodes
    assert est.nodes == model.n_nodes and "membrane vertices" in est.summary()
