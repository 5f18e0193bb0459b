"""Scenes: every SPEC key parses, unknown keys are caught with a did-you-mean, TOML round trip, paths."""

from __future__ import annotations

import math
import os

import pytest

from voxflex.errors import InputError
from voxflex.scene import (
    FixedSpec,
    LoadSpec,
    MaterialSpec,
    NodesSpec,
    ObjectSpec,
    ProbeSpec,
    Scene,
    SolverSpec,
    default_scene_path,
    describe_scene,
)

# The SPEC's scene table, every key (the comments of the SPEC's example turned into keys).
SPEC_SCENE = """
[object]
shape = "box"
size = [4.0, 1.0, 1.0]
voxel_size = 0.1
origin = [0.0, 0.0, 0.0]

[[material]]
label = 1
model = "neo-hookean"
young = 1.0e4
poisson = 0.3
density = 1000.0

[nodes]
kind = "affine"
count = 20
shape_function = "natural-neighbour"

[elasticity]
quadrature = "elaston"
samples = 200
strain = "corotational"

[[fixed]]
min = [-1e9, -1e9, -1e9]
max = [0.05, 1e9, 1e9]
components = "xyz"

[[fixed]]
min = [3.95, -1e9, -1e9]
max = [1e9, 1e9, 1e9]
components = "x"
transform = [[1,0,0,0.1],[0,1,0,0],[0,0,1,0]]

[[load]]
kind = "gravity"
vector = [0.0, 0.0, -9.81]

[[load]]
kind = "traction"
vector = [0.0, 0.0, -5.0]
min = [3.95, -1e9, -1e9]
max = [1e9, 1e9, 1e9]

[solver]
kind = "static"
dt = 0.01
steps = 1

[[probe]]
name = "tip"
point = [4.0, 0.5, 0.5]

[output]
file = "result.h5"
"""


def _minimal(**extra) -> dict:
    d = {"object": {"shape": "box", "size": [1.0, 1.0, 1.0], "voxel_size": 0.5}, "material": [{"young": 1e4}]}
    d.update(extra)
    return d


def test_every_spec_key_parses(tmp_path):
    scene = Scene.from_toml_text(SPEC_SCENE, base_dir=tmp_path)
    assert scene.object.shape == "box" and scene.object.size == (4.0, 1.0, 1.0)
    assert scene.object.voxel_size == 0.1 and scene.object.origin == (0.0, 0.0, 0.0)
    (m,) = scene.materials
    assert (m.label, m.model, m.young, m.poisson, m.density) == (1, "neo-hookean", 1e4, 0.3, 1000.0)
    assert (scene.nodes.kind, scene.nodes.count, scene.nodes.shape_function) == ("affine", 20, "natural-neighbour")
    e = scene.elasticity
    assert (e.quadrature, e.samples, e.strain) == ("elaston", 200, "corotational")
    assert scene.fixed[0].max == (0.05, 1e9, 1e9) and scene.fixed[0].components == "xyz"
    assert scene.fixed[1].components == "x" and scene.fixed[1].transform[0] == (1.0, 0.0, 0.0, 0.1)
    assert [ld.kind for ld in scene.loads] == ["gravity", "traction"]
    assert scene.gravity == (0.0, 0.0, -9.81)
    assert scene.loads[1].min == (3.95, -1e9, -1e9)
    assert (scene.solver.kind, scene.solver.dt, scene.solver.steps) == ("static", 0.01, 1)
    assert scene.probes[0] == ProbeSpec("tip", (4.0, 0.5, 0.5))
    # relative output path resolved against the scene's folder
    assert scene.output.file == str(tmp_path / "result.h5")


def test_defaults_and_programmatic_construction():
    scene = Scene(ObjectSpec(shape="sphere", size=(0.5,), voxel_size=0.1), (MaterialSpec(),))
    # defaults: affine frames with the node kind's own weights (reproducing kernels for frames; the builder
    # falls back to natural neighbours on a body where they leave spurious modes) and their quadrature
    # (elastons for reproducing kernels, Gauss-Legendre for voxel nodes), 6 parents (for weights cut to
    # parents), the frame count chosen at build time
    assert scene.nodes.kind == "affine" and scene.elasticity.quadrature == "elaston"
    assert scene.nodes.weights == "reproducing-kernel"
    assert scene.nodes.parents == 6 and scene.nodes.count is None
    voxel = Scene(ObjectSpec(shape="sphere", size=(0.5,), voxel_size=0.1), (MaterialSpec(),), nodes=NodesSpec(kind="voxel"))
    assert voxel.elasticity.quadrature == "gauss-legendre"
    assert scene.solver == SolverSpec() and scene.solver.kind == "static" and scene.solver.steps == 1
    assert scene.materials[0].model == "neo-hookean" and scene.materials[0].label == 1
    assert scene.fixed == () and scene.loads == () and scene.probes == () and scene.gravity is None
    assert FixedSpec().min == (-math.inf,) * 3  # an unbounded box by default
    assert Scene.from_dict(_minimal()).materials[0].young == 1e4


@pytest.mark.parametrize(
    "data, expected",
    [
        (_minimal(solver={"stpes": 3}), "unknown key 'stpes' in [solver] (did you mean 'steps'?)"),
        (_minimal(materials=[{}]), "unknown table '[materials]' in the scene (did you mean 'material'?)"),
        (
            {"object": {"shape": "box", "size": [1, 1, 1], "voxel_sise": 0.5}, "material": [{}]},
            "did you mean 'voxel_size'?",
        ),
        (_minimal(material=[{"yung": 1e4}]), "unknown key 'yung' in [material] (did you mean 'young'?)"),
        (_minimal(probe=[{"name": "a", "pont": [0, 0, 0]}]), "did you mean 'point'?"),
    ],
)
def test_unknown_keys_and_tables_suggest_the_right_name(data, expected):
    with pytest.raises(InputError) as exc:
        Scene.from_dict(data)
    message = str(exc.value)
    assert expected in message
    assert "valid" in message and "\n" not in message  # lists the valid names, one line


@pytest.mark.parametrize(
    "data, expected",
    [
        (_minimal(solver={"steps": "3"}), "[solver] steps must be an integer"),
        (_minimal(solver={"steps": 0}), "[solver] steps must be >= 1"),
        (_minimal(solver={"kind": "explicit"}), "[solver] kind: unknown value 'explicit'"),
        (_minimal(material=[{"poisson": 0.5}]), "[material] poisson must be in (-1, 0.5)"),
            (_minimal(material=[{"poisson": -1.0}]), "[material] poisson must be in (-1, 0.5)"),
        (_minimal(material=[{"young": -1.0}]), "[material] young must be > 0"),
        (_minimal(material=[{"model": "neo-hooke"}]), "did you mean 'neo-hookean'?"),
        (_minimal(fixed=[{"min": [0, 0]}]), "[fixed] min must be a list of 3 numbers"),
        (_minimal(fixed=[{"components": "xw"}]), "[fixed] components must be a non-empty subset"),
        (_minimal(fixed=[{"transform": [[1, 0, 0]]}]), "[fixed] transform must be a 3x4 matrix"),
        (_minimal(load=[{"kind": "traction", "vector": [1, 0, 0]}]), "needs a region"),
        (_minimal(material=[{}, {}]), "label 1 is given more than once"),
        ({"object": {"shape": "box", "size": [1, 1], "voxel_size": 1.0}, "material": [{}]}, "[lx, ly, lz]"),
        ({"object": {"shape": "box", "size": [1, 1, 1]}, "material": [{}]}, "needs voxel_size"),
        ({"object": {"shape": "box", "mesh": "a.stl", "voxel_size": 1.0}, "material": [{}]}, "exactly one of"),
        ({"material": [{}]}, "no [object] table"),
        ({"object": {"shape": "sphere", "size": [1], "voxel_size": 0.5}}, "no [[material]] table"),
    ],
)
def test_wrong_types_and_ranges_name_the_table_and_key(data, expected):
    with pytest.raises(InputError) as exc:
        Scene.from_dict(data)
    assert expected in str(exc.value)
    assert "\n" not in str(exc.value)


def test_invalid_toml_is_one_line_input_error(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("[object\nshape = 'box'\n")
    with pytest.raises(InputError, match="not valid TOML"):
        Scene.from_toml(path)
    with pytest.raises(InputError, match="not found"):
        Scene.from_toml(tmp_path / "missing.toml")


def test_to_toml_round_trips(tmp_path):
    scene = Scene.from_toml_text(SPEC_SCENE, base_dir=tmp_path)
    scene = Scene(
        object=scene.object,
        materials=scene.materials
        + (MaterialSpec(label=2, model="mooney-rivlin", strain="invariant-deviatoric", constants=(("c1", 1e3), ("bulk", 1e5))),),
        nodes=scene.nodes,
        elasticity=scene.elasticity,
        fixed=scene.fixed + (FixedSpec(max=(0.1, math.inf, math.inf), components="yz"),),
        loads=scene.loads + (LoadSpec(kind="force", vector=(1.0, 2.0, 3.0), max=(0.5, 0.5, 0.5)),),
        solver=SolverSpec(kind="implicit-euler", dt=1 / 3, steps=7, line_search=False, rayleigh_mass=0.1),
        probes=scene.probes + (ProbeSpec('odd "name"', (0.1, 0.2, 1e-17)),),
        output=scene.output,
        title='a "quoted" title\twith a tab',
    )
    text = scene.to_toml()
    again = Scene.from_toml_text(text, base_dir=tmp_path)
    assert again == scene  # floats written with repr read back bit-exact
    assert again.to_toml() == text
    # and through a file
    path = tmp_path / "scene.toml"
    path.write_text(text)
    assert Scene.from_toml(path) == scene


def test_relative_paths_resolve_against_the_scene_folder(tmp_path, monkeypatch):
    folder = tmp_path / "scenes"
    (folder / "parts").mkdir(parents=True)
    (folder / "parts" / "bar.stl").write_text("solid x\nendsolid x\n")
    (folder / "scene.toml").write_text(
        '[object]\nmesh = "parts/bar.stl"\nvoxel_size = 0.1\n[[material]]\n[output]\nfile = "out/r.h5"\n'
    )
    monkeypatch.chdir(tmp_path)  # a different working folder
    scene = Scene.from_toml("scenes/scene.toml")
    assert scene.object.mesh == str((folder / "parts" / "bar.stl").resolve())
    assert scene.output.file == str((folder / "out" / "r.h5").resolve())
    assert os.path.isabs(scene.object.mesh)
    (folder / "bad.toml").write_text('[object]\nimage = "nope.nii.gz"\n[[material]]\n')
    with pytest.raises(InputError, match="image file 'nope.nii.gz' not found"):
        Scene.from_toml(folder / "bad.toml")


def test_single_table_material_is_accepted():
    d = _minimal()
    d["material"] = {"young": 2e4}  # [material] instead of [[material]]
    assert Scene.from_dict(d).materials[0].young == 2e4


def test_describe_scene_and_the_bundled_default():
    path = default_scene_path()
    assert path.is_file()
    scene = Scene.from_toml(path)
    assert scene.nodes.kind == "affine" and scene.probes and scene.gravity is not None
    text = describe_scene(path)
    assert "object: mesh" in text and "material label 1: neo-hookean" in text and "probe tip" in text


def test_describe_scene_names_the_default_weights_and_their_fallback(tmp_path):
    """A frame scene that names no weights is described with the default and the fallback the builder may take;
    named weights (the bundled scene's) are described as they are."""
    path = tmp_path / "s.toml"
    path.write_text('[object]\nshape = "box"\nsize = [4.0, 1.0, 1.0]\nvoxel_size = 0.5\n[[material]]\nyoung = 1e3\n'
                    '[nodes]\ncount = 8\n')
    text = describe_scene(path)
    assert "(8 frames, reproducing-kernel by default; natural-neighbour on a body where" in text
    assert "(40 frames, reproducing-kernel)" in describe_scene(default_scene_path())
