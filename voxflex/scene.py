"""Scenes: what to simulate, read from TOML or built in code.

A scene mirrors the pipeline (docs/scene.md is the reference): the object (a
primitive shape, a surface mesh or a label image), one material per label, the
nodes, the elasticity integration, fixed regions, loads, the solver, probes and
the output file.  Each table is a frozen dataclass validated on construction;
:meth:`Scene.from_toml` / :meth:`Scene.from_dict` validate at the edge (unknown
tables and keys are errors with a did-you-mean and the valid names; wrong types
and ranges name the table and the key) and :meth:`Scene.to_toml` writes a file
that reads back to an equal scene.

Example
-------
>>> from voxflex.scene import Scene, ObjectSpec, MaterialSpec
>>> scene = Scene(object=ObjectSpec(shape="box", size=(4.0, 1.0, 1.0), voxel_size=0.25),
...               materials=(MaterialSpec(model="hooke", young=1e4, poisson=0.3),))
>>> Scene.from_toml_text(scene.to_toml()) == scene
True

Defaults: ``[nodes] kind = "affine"`` (frames); ``[elasticity] quadrature`` is the
node kind's own (``"midpoint"`` for frames: regions with their mean F and the
fluctuation energy, ``hourglass = "stiffness"``; ``"gauss-legendre"`` for voxels);
``[nodes] parents = 6`` (the cut to the largest weights is not conforming
and softens the model: docs/scene.md, ``parents``).  Extensions: a top-level ``title``; ``[object]
axis`` for cylinders; ``[[material]]`` model constants and a per-material
``strain``; ``[[load]] kind = "force"``; ``[solver]`` options mirroring the solver's.
"""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from ._checks import check_keys as _check_keys
from ._checks import string as _string
from ._checks import valid_keys as _valid_keys
from .deform.materials.catalogue import MATERIAL_NAMES, MODEL_CONSTANTS
from .deform.models.kinds import node_kind, node_kinds
from .deform.solve.boundary import PRESSURE_KIND
from .errors import InputError, did_you_mean
from .sampling.quadrature import REGION_RULES
from .scene_tables import (  # noqa: F401  (the tables are part of this module's interface)
    DISTANCES,
    FRICTION_MAX,
    KEEP,
    KEEP_CHOICES,
    LOAD_KINDS,
    MIN_PARENTS,
    NODE_KINDS,
    SHAPES,
    CableSpec,
    ContactSpec,
    ElasticitySpec,
    FixedSpec,
    LoadSpec,
    MaterialSpec,
    MembraneSpec,
    NodesSpec,
    ObjectSpec,
    ObstacleSpec,
    OutputSpec,
    ProbeSpec,
    SolverSpec,
    check_every,
    check_keep,
)

__all__ = [
    "Scene",
    "ObjectSpec",
    "MaterialSpec",
    "NodesSpec",
    "ElasticitySpec",
    "FixedSpec",
    "LoadSpec",
    "SolverSpec",
    "ProbeSpec",
    "OutputSpec",
    "ObstacleSpec",
    "ContactSpec",
    "CableSpec",
    "MembraneSpec",
    "describe_scene",
    "default_scene_path",
]

def _check_kind(scene) -> None:
    """What the scene's node kind does not take (one-line errors naming the fix): another kind's own
    shapes, tables and loads, dynamics for a static-only kind, quadratures it does not have, then the
    kind's own checks (:meth:`~voxflex.deform.models.kinds.NodeKind.check`)."""
    kind = node_kind(scene.nodes.kind)
    obj = scene.object
    for other in node_kinds().values():
        if other is kind:
            continue
        use = f'use [nodes] kind = "{other.name}"'
        if obj.shape in other.shapes:
            raise InputError(f'[object] shape = "{obj.shape}" is a {other.name} shape; {use}'
                             + (f" (with a [{next(iter(other.tables))}] table)" if other.tables else "")
                             + " or a solid shape (box, cylinder, sphere)")
        for table in other.tables:
            if getattr(scene, table, None) is not None:
                raise InputError(f"[{table}] applies to [nodes] kind = \"{other.name}\" only; remove it or set that kind")
        bad = [ld.kind for ld in scene.loads if ld.kind in other.load_kinds]
        if bad:
            raise InputError(f'[load] kind = "{bad[0]}" acts on {other.plural} only; {use}, or a traction load '
                             "on a solid")
    q = scene.elasticity.quadrature
    if q not in kind.quadratures:
        raise InputError(f'[elasticity] quadrature = "{q}" does not apply to [nodes] kind = "{kind.name}" '
                         f"({kind.plural}); valid for it: {', '.join(kind.quadratures)}")
    n = scene.elasticity.samples
    if n is not None and not (kind.reduced and q in REGION_RULES):
        raise InputError(
            f"[elasticity] samples = {n} counts the integration regions of frames with quadrature = "
            + " or ".join(f'"{r}"' for r in REGION_RULES) + "; "
            + (f'[nodes] kind = "{kind.name}" integrates every voxel' if not kind.reduced else
               f'"{q}" integrates every voxel with 2x2x2 points') + ", so it would be ignored; remove it"
            + ("" if not kind.reduced else ' or set quadrature = "midpoint" or "elaston"'))
    if kind.reduced and kind.shape_functions and scene.nodes.parents < MIN_PARENTS:
        p = scene.nodes.parents
        raise InputError(
            f"[nodes] parents = {p} is too few: cut to fewer than {MIN_PARENTS} frames per point the weights leave "
            "the frames far stiffer than their own uncut weights (the 16x4x4 cantilever with 20 frames sags 56 % "
            "less with 2 parents, 31 % with 3, 10 % with 4); use parents >= "
            f"{MIN_PARENTS} (default {NodesSpec.parents})")
    kind.check(scene)


_SINGLE = {
    "object": ObjectSpec,
    "nodes": NodesSpec,
    "elasticity": ElasticitySpec,
    "solver": SolverSpec,
    "output": OutputSpec,
    "contact": ContactSpec,
    **{name: spec for kind in node_kinds().values() for name, spec in kind.tables.items()},
}
_ARRAYS = {"material": MaterialSpec, "fixed": FixedSpec, "load": LoadSpec, "probe": ProbeSpec,
           "obstacle": ObstacleSpec, "cable": CableSpec}
_TOP_KEYS = ("title", "object", "material", "nodes", "elasticity", "fixed", "load", "solver", "probe", "output",
             "obstacle", "contact", "cable", *(name for kind in node_kinds().values() for name in kind.tables))
_FIELD = {"material": "materials", "fixed": "fixed", "load": "loads", "probe": "probes", "obstacle": "obstacles",
          "cable": "cables"}


@dataclass(frozen=True)
class Scene:
    """A complete simulation set-up (see the module docstring and docs/scene.md).

    Only ``object`` and at least one material are required.  ``base_dir`` is
    the folder relative paths were resolved against and ``path`` the file the
    scene was read from (informational: not compared, not written; a run
    refuses to write its result over ``path``).
    """

    object: ObjectSpec
    materials: tuple[MaterialSpec, ...]
    nodes: NodesSpec = field(default_factory=NodesSpec)
    elasticity: ElasticitySpec = field(default_factory=ElasticitySpec)
    fixed: tuple[FixedSpec, ...] = ()
    loads: tuple[LoadSpec, ...] = ()
    solver: SolverSpec = field(default_factory=SolverSpec)
    probes: tuple[ProbeSpec, ...] = ()
    output: OutputSpec = field(default_factory=OutputSpec)
    obstacles: tuple[ObstacleSpec, ...] = ()
    contact: ContactSpec = field(default_factory=ContactSpec)
    cables: tuple[CableSpec, ...] = ()
    membrane: MembraneSpec | None = None
    title: str | None = None
    base_dir: str | None = field(default=None, compare=False)
    path: str | None = field(default=None, compare=False)

    def __post_init__(self):
        if not isinstance(self.object, ObjectSpec):
            raise InputError("Scene.object must be an ObjectSpec (the [object] table)")
        for name, cls in (("materials", MaterialSpec), ("fixed", FixedSpec), ("loads", LoadSpec), ("probes", ProbeSpec),
                          ("obstacles", ObstacleSpec), ("cables", CableSpec)):
            items = getattr(self, name)
            if items is None or isinstance(items, (str, bytes, dict)):
                raise InputError(f"Scene.{name} must be a sequence of {cls.__name__} (() for none), "
                                 f"got {type(items).__name__}")
            if isinstance(items, cls):
                items = (items,)
            items = tuple(items)
            if not all(isinstance(i, cls) for i in items):
                raise InputError(f"Scene.{name} must be a sequence of {cls.__name__}")
            object.__setattr__(self, name, items)
        if not self.materials:
            raise InputError("a scene needs at least one [[material]] table, e.g. model = \"neo-hookean\"")
        labels = [m.label for m in self.materials]
        dup = sorted({x for x in labels if labels.count(x) > 1})
        if dup:
            raise InputError(f"[[material]] label {dup[0]} is given more than once; give each label one material")
        names = [p.name for p in self.probes]
        dup = sorted({x for x in names if names.count(x) > 1})
        if dup:
            raise InputError(f"[[probe]] name '{dup[0]}' is used more than once; give each probe its own name")
        if self.title is not None:
            _string("scene", "title", self.title)
        if self.elasticity.quadrature is None:  # the node kind's own quadrature (or its weight family's)
            own = node_kind(self.nodes.kind).quadrature_for(self.nodes.weights)
            object.__setattr__(self, "elasticity", replace(self.elasticity, quadrature=own))
        if not isinstance(self.contact, ContactSpec):
            raise InputError("Scene.contact must be a ContactSpec (the [contact] table)")
        _check_kind(self)

    # -- reading ----------------------------------------------------------
    @classmethod
    def from_toml(cls, path) -> Scene:
        """Read a scene file; relative paths in it are resolved against its folder."""
        if isinstance(path, str) and "\n" in path:
            raise InputError("Scene.from_toml takes a path, and this looks like scene TOML text; read text with "
                             "vf.Scene.from_toml_text(text)")
        if not isinstance(path, (str, os.PathLike)):
            raise InputError(f"a scene file path must be a string or a Path, got {type(path).__name__}")
        path = Path(path)
        if not _is_file(path):
            from .errors import missing_file

            raise missing_file(path, "scene file")
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(f"cannot read scene file '{path}': {exc}") from None
        scene = cls.from_toml_text(text, base_dir=path.resolve().parent, source=str(path))
        object.__setattr__(scene, "path", str(path.resolve()))  # the file a run must not overwrite
        return scene

    @classmethod
    def from_toml_text(cls, text: str, *, base_dir=None, source: str = "scene") -> Scene:
        """Parse scene TOML text (``base_dir``: folder for relative paths, default the current one)."""
        if isinstance(text, (bytes, bytearray)):
            raise InputError("Scene.from_toml_text takes text (str), got bytes; decode them with .decode('utf-8')")
        if not isinstance(text, str):
            raise InputError(f"Scene.from_toml_text takes the TOML text as a str, got {type(text).__name__}; "
                             "for a file use vf.Scene.from_toml(path)")
        if base_dir is not None and not isinstance(base_dir, (str, os.PathLike)):
            raise InputError(f"base_dir must be a folder path, got {type(base_dir).__name__}")
        try:
            data = tomllib.loads(text.removeprefix("\ufeff"))  # a byte-order mark (Windows editors) is no TOML
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"{source} is not valid TOML: {exc}") from None
        return cls.from_dict(data, base_dir=base_dir)

    @classmethod
    def from_dict(cls, d: dict, *, base_dir=None) -> Scene:
        """Build a scene from parsed TOML (nested dicts/lists), validating every key."""
        if not isinstance(d, dict):
            raise InputError(f"a scene must be a table of tables, got {type(d).__name__}")
        base = Path(base_dir) if base_dir is not None else Path.cwd()
        _check_keys_top(d)
        if "object" not in d:
            raise InputError("the scene has no [object] table; add one, e.g. [object] shape = \"box\" ...")
        if "material" not in d:
            raise InputError("the scene has no [[material]] table; add one, e.g. [[material]] model = \"neo-hookean\"")
        kwargs = {}
        for name, spec in _SINGLE.items():
            if name in d:
                table = d[name]
                if not isinstance(table, dict):
                    raise InputError(f"[{name}] must be a table, got {type(table).__name__}")
                kwargs[name] = _build(name, spec, table)
        for name, spec in _ARRAYS.items():
            if name in d:
                tables = d[name]
                if isinstance(tables, dict):  # [material] written as a single table
                    tables = [tables]
                if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
                    raise InputError(f"[[{name}]] must be one or more tables, e.g. [[{name}]] ...")
                kwargs[_FIELD[name]] = tuple(_build(name, spec, t) for t in tables)
        if "title" in d:
            kwargs["title"] = _string("scene", "title", d["title"])
        obj = kwargs["object"]
        if obj.mesh is not None or obj.image is not None:
            key = "mesh" if obj.mesh is not None else "image"
            resolved = _resolve(base, getattr(obj, key))
            if not Path(resolved).exists():
                raise InputError(f"[object] {key} file '{getattr(obj, key)}' not found (looked for {resolved})")
            kwargs["object"] = replace(obj, **{key: resolved})
        if "output" in kwargs and kwargs["output"].file is not None:
            kwargs["output"] = replace(kwargs["output"], file=_resolve(base, kwargs["output"].file))
        if "obstacles" in kwargs:
            kwargs["obstacles"] = tuple(replace(o, file=_resolve(base, o.file)) if o.file is not None else o
                                        for o in kwargs["obstacles"])
        return cls(**kwargs, base_dir=str(base))

    # -- writing ----------------------------------------------------------
    def to_toml(self) -> str:
        """The scene as TOML text; :meth:`from_toml_text` reads it back to an equal scene."""
        lines: list[str] = []
        if self.title is not None:
            lines += [f"title = {_toml_value(self.title)}", ""]
        lines += _table("object", self.object)
        for m in self.materials:
            lines += _table("material", m, array=True)
        lines += _table("nodes", self.nodes)
        lines += _table("elasticity", self.elasticity)
        for f in self.fixed:
            lines += _table("fixed", f, array=True)
        for ld in self.loads:
            lines += _table("load", ld, array=True)
        lines += _table("solver", self.solver)
        for p in self.probes:
            lines += _table("probe", p, array=True)
        if self.output != OutputSpec():
            lines += _table("output", self.output)
        for o in self.obstacles:
            lines += _table("obstacle", o, array=True)
        if self.contact != ContactSpec():
            lines += _table("contact", self.contact)
        for c in self.cables:
            lines += _table("cable", c, array=True)
        for kind in node_kinds().values():  # the tables a node kind adds ([membrane])
            for name in kind.tables:
                if getattr(self, name) is not None:
                    lines += _table(name, getattr(self, name))
        return "\n".join(lines).rstrip("\n") + "\n"

    # -- conveniences -----------------------------------------------------
    def material_for(self, label: int) -> MaterialSpec:
        for m in self.materials:
            if m.label == label:
                return m
        raise InputError(
            f"label {label} has no [[material]]; add one with label = {label} "
            f"(materials given for labels {', '.join(str(m.label) for m in self.materials)})"
        )

    @property
    def gravity(self) -> tuple[float, float, float] | None:
        """Sum of the gravity loads (m/s^2), or None without gravity."""
        g = [ld.vector for ld in self.loads if ld.kind == "gravity"]
        if not g:
            return None
        return tuple(float(sum(v[i] for v in g)) for i in range(3))


def _check_keys_top(d: dict) -> None:
    for key in d:
        if key not in _TOP_KEYS:
            raise InputError(
                f"unknown table '[{key}]' in the scene{did_you_mean(key, _TOP_KEYS)}; "
                f"valid: {', '.join(_TOP_KEYS)}"
            )


def _build(name: str, spec, table: dict):
    valid = _valid_keys(spec)
    if spec is MaterialSpec:
        # keys that are not MaterialSpec fields are the model's own constants (MODEL_CONSTANTS)
        fixed = tuple(k for k in valid if k != "constants")
        table = dict(table)
        model = table.get("model", MaterialSpec.model)
        if not isinstance(model, str) or model not in MATERIAL_NAMES:
            _string(name, "model", model, MATERIAL_NAMES)
        constants = tuple((k, table.pop(k)) for k in list(table) if k not in fixed)
        for key, _ in constants:
            if key not in MODEL_CONSTANTS[model]:
                allowed = fixed + MODEL_CONSTANTS[model]
                raise InputError(
                    f"unknown key '{key}' in [material]{did_you_mean(key, allowed)}; "
                    f"valid keys for model '{model}': {', '.join(allowed)}"
                )
        return spec(**table, constants=constants)
    _check_keys(name, table, valid)
    if spec is ProbeSpec:
        for key in ("name", "point"):
            if key not in table:
                raise InputError(f"[probe] needs {key}, e.g. name = \"tip\", point = [4.0, 0.5, 0.5]")
    return spec(**table)


def as_scene(scene, who: str) -> Scene:
    """``scene`` itself, or the scene read from a path; InputError for anything else (``who``: the caller)."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, (str, os.PathLike)):
        return Scene.from_toml(scene)
    raise InputError(f"{who} needs a Scene or a scene file path, got {type(scene).__name__}; read one with "
                     "vf.Scene.from_toml(path)")


def _is_file(path: Path) -> bool:
    """``path.is_file()`` that says False instead of raising (a name too long, a loop of links)."""
    try:
        return path.is_file()
    except OSError:
        return False


def _resolve(base: Path, path: str) -> str:
    p = Path(path).expanduser()
    return str(p if p.is_absolute() else (base / p).resolve())


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)  # shortest repr: reads back bit-exact
    if isinstance(value, str):
        escaped = (
            value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n").replace("\t", "\\t").replace("\r", "\\r")
        )
        # TOML's basic strings hold no other control character: \u escapes read back to the same text
        escaped = "".join(f"\\u{ord(c):04x}" if ord(c) < 0x20 or ord(c) == 0x7F else c for c in escaped)
        return f'"{escaped}"'
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def _table(name: str, spec, *, array: bool = False) -> list[str]:
    lines = [f"[[{name}]]" if array else f"[{name}]"]
    for f in fields(spec):
        value = getattr(spec, f.name)
        if value is None:
            continue
        if f.name == "constants":
            lines += [f"{k} = {_toml_value(v)}" for k, v in value]
            continue
        lines.append(f"{f.name} = {_toml_value(value)}")
    lines.append("")
    return lines


# ---------------------------------------------------------------------------
def default_scene_path() -> Path:
    """The bundled default scene (``voxflex.data/default.toml``)."""
    from importlib.resources import files

    return Path(str(files("voxflex.data") / "default.toml"))


def _nodes_text(scene) -> str:
    """" (20 frames, natural-neighbour)" for a reduced kind, "" otherwise; weights the scene does not name are
    said to be the default, with the fallback the builder may take (the model's ``shape_function_chosen``)."""
    from .voronoi.families import FALLBACK

    kind = node_kind(scene.nodes.kind)
    if not kind.reduced:
        return ""
    count = kind.count(scene.nodes.count or kind.default_count)
    weights = scene.nodes.weights
    fallback = FALLBACK.get(weights)
    if scene.nodes.shape_function is None and scene.nodes.support is None and fallback:
        weights += f" by default; {fallback} on a body where they would leave spurious modes, or for stabilised regions"
    return f" ({count}, {weights})"


def describe_scene(path) -> str:
    """A short human-readable summary of a scene file (used by ``voxflex info``)."""
    scene = Scene.from_toml(path)
    o = scene.object
    lines = [f"scene: {path}"]
    if scene.title:
        lines.append(f"  title: {scene.title}")
    if o.shape:
        where = f" at origin {list(o.origin)}" if o.origin else ""
        extra = f", axis {o.axis}" if o.axis else ""
        lines.append(f"  object: {o.shape} size {list(o.size)}{extra}{where}, voxel size {o.voxel_size:g} m")
    elif o.mesh:
        lines.append(f"  object: mesh {o.mesh}, voxel size {o.voxel_size:g} m")
    else:
        lines.append(f"  object: image {o.image}")
    for m in scene.materials:
        params = [f"{k}={v:g}" for k, v in (("E", m.young), ("nu", m.poisson)) if v is not None]
        params += [f"{k}={v}" for k, v in m.constants]
        strain = m.strain or scene.elasticity.strain
        lines.append(
            f"  material label {m.label}: {m.model} {' '.join(params)} density {m.density:g} kg/m^3"
            + (f", strain {strain}" if strain else "")
        )
    lines.append(
        f"  nodes: {scene.nodes.kind}"
        + _nodes_text(scene)
        + f"; quadrature {scene.elasticity.quadrature}"
    )
    for f in scene.fixed:
        how = "moved by a transform" if f.transform is not None else f"held ({f.components})"
        lines.append(f"  fixed: box {list(f.min)} .. {list(f.max)} {how}")
    if scene.membrane is not None:
        lines.append(f"  membrane: thickness {scene.membrane.thickness:g} m, rim {scene.membrane.rim}")
    for ld in scene.loads:
        if ld.kind == PRESSURE_KIND:
            lines.append(f"  load: pressure {ld.pressure:g} Pa on the whole membrane")
            continue
        region = "" if ld.kind == "gravity" else f" on box {list(ld.min)} .. {list(ld.max)}"
        lines.append(f"  load: {ld.kind} {list(ld.vector)}{region}")
    s = scene.solver
    timing = f"{s.steps} time steps of {s.dt:g} s" if s.kind == "implicit-euler" else f"{s.steps} load steps"
    lines.append(f"  solver: {s.kind}, {timing}, tolerance {s.tolerance:g}")
    for p in scene.probes:
        lines.append(f"  probe {p.name}: {list(p.point)}")
    for c in scene.cables:
        how = f"pull {c.pull:g} N" if c.pull is not None else f"stiffness {c.stiffness:g} N/m, shorten {c.shorten:g} m"
        start = f" from anchor {list(c.anchor)}" if c.anchor is not None else ""
        lines.append(f"  cable: {len(c.points)} points{start}, {how}")
    if scene.output.file:
        lines.append(f"  output: {scene.output.file}")
    return "\n".join(lines)
