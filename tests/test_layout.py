"""The package's layout holds: imports go one way, nothing branches on a node kind's name, light modules stay light.

The stages, lowest first: infrastructure (errors, _checks, _jit, _lazy, _linalg ...), image, rasterize,
voronoi, sampling, then deform as the chain (materials < chain < models ~ layers < solve), then the top
(scene, build, simulation, result, rendering, tradeoff, resources, cli).  A module may import from its own
stage and the ones below it, never from a later one (also not inside a function).
"""

from __future__ import annotations

import ast
import io
import subprocess
import sys
import tokenize
from pathlib import Path

import paths
import pytest

ROOT = paths.ROOT
PACKAGE = ROOT / "voxflex"

# rank of each stage; modules at the same rank may import each other (models ~ layers)
INFRASTRUCTURE = ("errors", "_atomic", "_blas", "_checks", "_jit", "_lazy", "_linalg", "_linalg_kernels", "_progress", "_ties",
                  "_version", "cache")
STAGES = [
    *((f"voxflex.{m}", 0) for m in INFRASTRUCTURE),
    ("voxflex.image", 1), ("voxflex.rasterize", 2), ("voxflex.voronoi", 3), ("voxflex.sampling", 4),
    ("voxflex.deform.materials", 5), ("voxflex.deform.chain", 6),
    ("voxflex.deform.models", 7), ("voxflex.deform.layers", 7), ("voxflex.deform.solve", 8),
    ("voxflex.deform", 8),
    ("voxflex", 9),
]


def _stage(module: str) -> int:
    for prefix, rank in STAGES:
        if module == prefix or module.startswith(prefix + "."):
            return rank
    return 9


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path):
    """(line, imported module) of every import in the file, relative ones resolved."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.startswith("voxflex"):
                for alias in node.names:  # `from . import x` may import a submodule
                    sub = f"{mod}.{alias.name}"
                    yield node.lineno, sub if (PACKAGE.parent / (sub.replace(".", "/") + ".py")).exists() or \
                        (PACKAGE.parent / sub.replace(".", "/")).is_dir() else mod
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("voxflex"):
                    yield node.lineno, alias.name


def _sources():
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def test_imports_only_go_down_the_pipeline():
    upward = []
    for path in _sources():
        me = _module_name(path)
        if me in ("voxflex", "voxflex.deform") or path.name == "__init__.py":
            continue  # the lazy public names of a package point at its own stages
        for line, mod in _imports(path):
            if _stage(mod) > _stage(me):
                upward.append(f"{path.relative_to(ROOT)}:{line} imports {mod}")
    assert not upward, "imports that go up the pipeline:\n" + "\n".join(upward)


def test_no_code_outside_the_models_branches_on_a_node_kind_name():
    """A node kind's name (as a string literal) appears only in the models and the kind registry; everything
    else asks the kind object (voxflex.deform.models.kinds)."""
    from voxflex.deform.models.kinds import node_kinds

    names = {repr(n) for n in node_kinds()} | {f'"{n}"' for n in node_kinds()}
    found = []
    models = PACKAGE / "deform" / "models"
    for path in _sources():
        if models in path.parents:
            continue
        tokens = tokenize.generate_tokens(io.StringIO(path.read_text(encoding="utf-8")).readline)
        for tok in tokens:
            if tok.type == tokenize.STRING and tok.string in names:
                found.append(f"{path.relative_to(ROOT)}:{tok.start[0]}: {tok.string}")
    assert not found, "node kind names outside the models:\n" + "\n".join(found)


def test_reading_a_scene_loads_neither_numba_nor_scipy():
    code = ("import sys, voxflex.scene as s; s.Scene.from_toml(s.default_scene_path()); "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'scipy')); print(bad)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_the_kind_registry_and_the_vocabularies_are_light():
    code = ("import sys; from voxflex.deform.models.kinds import node_kinds; node_kinds(); "
            "import voxflex.voronoi.families, voxflex.deform.materials.catalogue, voxflex.sampling.quadrature; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'scipy')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_catalogues_name_what_the_registries_hold():
    from voxflex.deform.materials.catalogue import MATERIAL_NAMES, STRAIN_NAMES
    from voxflex.deform.materials.constitutive import MATERIALS
    from voxflex.deform.materials.strains import STRAINS

    assert tuple(MATERIALS) == MATERIAL_NAMES and tuple(STRAINS) == STRAIN_NAMES


LAZY_PACKAGES = ("voxflex", "voxflex.deform", "voxflex.deform.materials", "voxflex.deform.chain",
                 "voxflex.deform.models", "voxflex.deform.layers", "voxflex.deform.solve", "voxflex.voronoi",
                 "voxflex.rasterize", "voxflex.sampling")


@pytest.mark.parametrize("package", LAZY_PACKAGES)
def test_lazy_names_are_never_shadowed_by_submodules(package):
    """Every public name of a lazy package resolves to the object, not to a submodule of the same name, even
    after every submodule was imported (importing ``pkg.x`` sets the attribute ``x`` of ``pkg``)."""
    import importlib
    import pkgutil
    import types

    pkg = importlib.import_module(package)
    for info in pkgutil.walk_packages(pkg.__path__, package + "."):
        importlib.import_module(info.name)
    for name in pkg.__all__:
        assert not isinstance(getattr(pkg, name), types.ModuleType), f"{package}.{name} is a module"


def test_every_package_is_installed():
    """pyproject.toml lists its packages one by one: a new folder must be added there."""
    import tomllib

    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {_module_name(p.parent) for p in PACKAGE.rglob("__init__.py") if "__pycache__" not in p.parts}
    assert found - listed == set(), f"packages missing from pyproject.toml: {sorted(found - listed)}"


def test_no_import_cycles():
    """Modules import each other without cycles (also through imports inside functions): e.g. image.io no
    longer imports image.label_image, nor the multigrid the linear solvers."""
    graph = {}
    for path in _sources():
        if path.name == "__init__.py":
            continue
        me = _module_name(path)
        graph[me] = {m for _, m in _imports(path) if m != me and not m.endswith(".__init__")}
    modules = set(graph)
    graph = {m: {d for d in deps if d in modules} for m, deps in graph.items()}
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph[m]):
            if state.get(d) == 1:
                cycles.append(stack[stack.index(d):] + [d])
            elif d not in state:
                visit(d)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_benchmarks_and_examples_import_what_exists():
    """Every ``from voxflex... import name`` in benchmarks/ and examples/ names a module and a name that exist
    (they are not run by the suite; a moved module must not break them silently)."""
    import importlib

    bad = []
    for path in sorted([*(ROOT / "benchmarks").glob("*.py"), *(ROOT / "examples").glob("*.py")]):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("voxflex"):
                mod = importlib.import_module(node.module)
                for alias in node.names:
                    if not hasattr(mod, alias.name):
                        try:
                            importlib.import_module(f"{node.module}.{alias.name}")
                        except ImportError:
                            bad.append(f"{path.name}: {node.module}.{alias.name}")
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    if alias.name.startswith("voxflex"):
                        importlib.import_module(alias.name)
    assert not bad, "missing: " + ", ".join(bad)


def test_solvers_read_the_voxel_grid_only_through_the_capability():
    """``dof_grid`` belongs to :class:`OnVoxelGrid` models: the solvers read it through ``newton._grid_of``
    (an isinstance check), never off any model (a frame model's shifted Newton step raised AttributeError)."""
    found = []
    for path in sorted((PACKAGE / "deform" / "solve").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        allowed = {id(n) for fn in ast.walk(tree) if isinstance(fn, ast.FunctionDef) and fn.name == "_grid_of"
                   for n in ast.walk(fn)}
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr == "dof_grid" and id(node) not in allowed \
                    and not (isinstance(node.value, ast.Name) and node.value.id == "self"):
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not found, "dof_grid read off a model outside newton._grid_of: " + ", ".join(found)


def test_every_registered_kind_builds_a_model_of_the_whole_protocol():
    """vf.simulate checks a model with isinstance(model, Model); the rigid frames lacked the protocol's
    ``materials`` (found when that check replaced a probe of four attributes).  Each registered kind's model of a
    small scene has every member of the protocol."""
    import typing
    import warnings

    import voxflex as vf
    from voxflex.deform.models.kinds import node_kinds
    from voxflex.deform.models.protocol import Model
    from voxflex.scene import Scene

    members = sorted(typing._get_protocol_attrs(Model))
    base = """
[object]
shape = "box"
size = [0.04, 0.01, 0.01]
voxel_size = 0.002
[[material]]
model = "neo-hookean"
young = 1e5
poisson = 0.3
density = 1000
[nodes]
kind = "{kind}"
{extra}
[[fixed]]
min = [-1, -1, -1]
max = [0.0001, 1, 1]
"""
    checked = 0
    for name in node_kinds():
        if name == "membrane":
            continue  # a membrane is built from a mesh of its own (its tests cover it)
        extra = "count = 6" if name in ("affine", "rigid") else ""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = vf.model(Scene.from_toml_text(base.format(kind=name, extra=extra)), cache=False)
        assert isinstance(model, Model), (name, [m for m in members if not hasattr(model, m)])
        checked += 1
    assert checked >= 3
