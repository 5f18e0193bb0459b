"""Resources a scene will need, estimated before anything is built.

:func:`estimate` reads only the scene (and the header-sized facts of its
object: the voxel count of an image, the volume and bounds of a mesh, the
size of a primitive) and returns an :class:`Estimate`: voxels, nodes, degrees
of freedom, the model's memory, the memory of every stored state, and a rough
time, and, when the run writes a result file, the file's size.  With a
result file the states stream to it step by step (:func:`voxflex.simulate`),
so memory holds only the states ``keep`` asks for, and the number of steps is
bounded by the disk, not by memory.  :func:`check` refuses a scene whose
estimate exceeds the memory this machine has available (``/proc/meminfo`` and
the cgroup limit; when neither can be read nothing is refused) or, with a
result file, the free space of its folder, naming what would fit: the voxel
size, the frame count, the number of steps, a result file, ``keep`` or
``every``.

The constants are measured by ``benchmarks/bench_resources.py`` (peak
resident memory of a static solve above the imports, per DOF, fitted over
sizes; seconds per Newton iteration per DOF); they describe this code on a
2-core machine and are an estimate, not a bound.

>>> from voxflex.scene import Scene, ObjectSpec, MaterialSpec
>>> scene = Scene(object=ObjectSpec(shape="box", size=(4.0, 1.0, 1.0), voxel_size=0.25),
...               materials=(MaterialSpec(model="hooke", young=1e4, poisson=0.3),))
>>> e = estimate(scene)
>>> e.voxels, e.dofs
(256, 1275)
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = ["Estimate", "estimate", "estimate_on_image", "check", "available_memory", "free_disk", "MEMORY_FRACTION", "STREAM_BYTES"]

MEMORY_FRACTION = 0.8
"""Share of the available memory a run may plan to use (the rest: Python, the OS, other processes)."""

STREAM_BYTES = 4 * 2**20 + 24 * 2**20
"""Streaming a result file: the writer's buffer (4 MiB) and HDF5's chunk caches (1 MiB for each of 24 datasets)."""
FIELD_COMPONENTS = {"stress": 9, "strain": 9, "stretches": 3}
"""Numbers per cell of the ``[output] fields`` that are not scalars (docs/results.md)."""


@dataclass(frozen=True)
class Estimate:
    """What a scene is expected to need.

    Attributes
    ----------
    node_kind : str
        The name of the scene's :class:`~voxflex.deform.models.kinds.NodeKind`.
    voxels : int
        Occupied voxels (estimated from the volume for shapes and meshes).
    nodes : int
        Voxel-corner nodes or frames.
    dofs : int
    model_bytes : int
        Peak memory of building the model and solving one step (bytes).
    state_bytes : int
        Memory per state held (node state twice, surface, probes, fields; bytes).
    states : int
        Recorded states: the rest state and every ``every``-th step (and the last).
    seconds : float
        Rough solve time (order of magnitude) on a 2-core machine.
    voxel_size : float or None
        The object's voxel size (m), the largest spacing of an image.
    kept_states : int or None
        States held in memory (``keep``); None means all ``states``.
    file_bytes : int
        Size of the result file, uncompressed (an upper bound: the datasets are
        gzip-compressed); 0 when no file is written.
    row_bytes : int
        Bytes of one recorded state in the file (uncompressed).
    streamed : bool
        A result file is written (states streamed to it; memory holds ``kept_states``
        and :data:`STREAM_BYTES`).
    """

    node_kind: str
    voxels: int
    nodes: int
    dofs: int
    model_bytes: int
    state_bytes: int
    states: int
    seconds: float
    voxel_size: float | None = None
    kept_states: int | None = None
    file_bytes: int = 0
    row_bytes: int = 0
    streamed: bool = False

    @property
    def held_states(self) -> int:
        """States held in memory."""
        return int(self.states if self.kept_states is None else self.kept_states)

    @property
    def total_bytes(self) -> int:
        """Memory: the model, the states held and, when streaming, the writer (bytes)."""
        return int(self.model_bytes + self.held_states * self.state_bytes + (STREAM_BYTES if self.streamed else 0))

    def summary(self) -> str:
        """One line: sizes, memory, the result file and time."""
        from .deform.models.kinds import node_kind

        kind = node_kind(self.node_kind)
        text = (f"about {self.voxels:,} voxels, {self.nodes:,} {kind.plural}, {self.dofs:,} DOF; memory ~{_human(self.total_bytes)} "
                f"(model {_human(self.model_bytes)} + {self.held_states:,} states x {_human(self.state_bytes)}")
        text += " + the file writer)" if self.streamed else ")"
        if self.streamed:
            text += f"; result file up to {_human(self.file_bytes)} ({self.states:,} states)"
        return text + f"; time ~{_duration(self.seconds)} (rough)"


def available_memory() -> int | None:
    """Bytes this process may still allocate: MemAvailable, capped by a cgroup limit; None when unknown.

    Reads ``/proc/meminfo`` (``MemAvailable``, else ``MemFree + Cached``) and the
    cgroup v2 (``memory.max - memory.current``) or v1 limit; falls back on
    ``os.sysconf`` (available physical pages), then None.
    """
    avail = None
    try:
        info = {}
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                key, _, rest = line.partition(":")
                parts = rest.split()
                if parts:
                    info[key] = int(parts[0]) * (1024 if parts[-1] == "kB" else 1)
        if "MemAvailable" in info:
            avail = info["MemAvailable"]
        elif "MemFree" in info:
            avail = info["MemFree"] + info.get("Cached", 0)
    except (OSError, ValueError):
        avail = None
    if avail is None:
        try:
            avail = int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):
            avail = None
    limit = _cgroup_room()
    if limit is not None:
        avail = limit if avail is None else min(avail, limit)
    return avail


def _cgroup_room() -> int | None:
    for maximum, current in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                             ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                              "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            text = Path(maximum).read_text().strip()
            if text == "max":
                return None
            room = int(text) - int(Path(current).read_text().strip())
            if int(text) >= 1 << 60:  # v1 "unlimited"
                return None
            return max(room, 0)
        except (OSError, ValueError):
            continue
    return None


# ----------------------------------------------------------------------------------------------
# the object's size
# ----------------------------------------------------------------------------------------------
def _mtime(path) -> float:
    try:
        return os.stat(path).st_mtime
    except OSError:
        return 0.0  # the loader raises the one-line error


@functools.lru_cache(maxsize=8)
def _image_counts(path: str, mtime: float):
    """(voxels, corner nodes, surface nodes, largest spacing) of a label image file, counted."""
    from .image import LabelImage

    return _counts(LabelImage.load(path))


def _counts(image):
    """(voxels, corner nodes, surface nodes, largest spacing) of a label image."""
    mask = np.pad(np.asarray(image.labels) > 0, 1)
    corners = np.zeros(np.array(mask.shape) - 1, dtype=bool)
    full = np.ones_like(corners)
    for i in (0, 1):
        for j in (0, 1):
            for k in (0, 1):
                shifted = mask[i:i + corners.shape[0], j:j + corners.shape[1], k:k + corners.shape[2]]
                corners |= shifted
                full &= shifted
    nodes = int(np.count_nonzero(corners))
    return int(np.count_nonzero(mask)), nodes, nodes - int(np.count_nonzero(full)), float(np.max(image.spacing))


def estimate_on_image(scene, image):
    """The :class:`~voxflex.deform.models.kinds.NodeEstimate` of the scene's model on its built ``image``
    (counted voxels and corners, not estimated from the object's volume)."""
    from .deform.models.kinds import node_kind

    return node_kind(scene.nodes.kind).estimate(scene, _counts(image), _material_class(scene))


@functools.lru_cache(maxsize=8)
def _mesh_measures(path: str, mtime: float):
    """(enclosed volume m^3, area m^2) of a surface mesh file (an open surface: its bounding box volume)."""
    from .rasterize.mesh import load_mesh

    mesh = load_mesh(path)
    v = np.asarray(mesh.vertices, dtype=float)
    tri = v[np.asarray(mesh.faces)]
    area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
    volume = abs(float(mesh.signed_volume))
    if volume <= 0:
        volume = float(np.prod(v.max(axis=0) - v.min(axis=0)))
    return volume, area


STAIRCASE = 1.5
"""Mean of |n_x| + |n_y| + |n_z| over the directions of a sphere: voxel faces exposed per unit of true surface area."""


def _object_size(obj, h=None):
    """(voxels, nodes, surface nodes, voxel size) of the scene's object at voxel size ``h`` (default its own).

    Boxes are exact; images are counted (nodes: corners of occupied voxels);
    curved shapes and meshes use their volume / h^3 and their staircase
    surface (``STAIRCASE`` x area / h^2) for the nodes beyond one per voxel.
    """
    if obj.image is not None:
        voxels, nodes, surface, native = _image_counts(str(obj.image), _mtime(obj.image))
        if h is None or h == native:
            return voxels, nodes, surface, native
        r = native / h  # a resampled image: volume terms scale as r^3, surface terms as r^2
        return max(int(voxels * r**3), 1), max(int(voxels * r**3 + (nodes - voxels) * r**2), 8), \
            max(int(surface * r**2), 8), float(h)
    h = float(obj.voxel_size if h is None else h)
    if obj.shape == "box":
        n = np.maximum(np.ceil(np.asarray(obj.size, dtype=float) / h - 1e-9), 1.0)
        nodes = int(np.prod(n + 1))
        return int(np.prod(n)), nodes, nodes - int(np.prod(np.maximum(n - 1, 0))), h
    if obj.mesh is not None:
        volume, area = _mesh_measures(str(obj.mesh), _mtime(obj.mesh))
    elif obj.shape == "cylinder":
        r, length = (float(x) for x in obj.size)
        volume, area = math.pi * r * r * length, 2 * math.pi * r * length + 2 * math.pi * r * r
    else:
        r = float(obj.size[0])
        volume, area = 4.0 / 3.0 * math.pi * r**3, 4.0 * math.pi * r * r
    voxels = max(int(math.ceil(volume / h**3)), 1)
    surface = max(int(math.ceil(STAIRCASE * area / h**2)), 8)
    return voxels, voxels + surface // 2, surface, h


def _material_class(scene) -> str:
    """"constant", "nonlinear" or "reduced": the costliest material class of the scene's labels."""
    from .deform.materials.constitutive import material
    from .deform.materials.fbar import nearly_incompressible
    from .deform.models.voxel.model import tangent_is_constant
    from .errors import InputError

    worst = "constant"
    for spec in scene.materials:
        try:
            mat = material(spec.model, **spec.material_kwargs(scene.elasticity.strain))
        except InputError:
            return "reduced"  # a bad material is reported by the model build; estimate the worst case
        if tangent_is_constant(mat):
            continue
        vol = scene.elasticity.volumetric
        reduced = (vol == "reduced" or (vol == "auto" and nearly_incompressible(mat))) and \
            scene.elasticity.quadrature == "gauss-legendre"
        worst = "reduced" if reduced else ("nonlinear" if worst == "constant" else worst)
    return worst


# ----------------------------------------------------------------------------------------------
# estimate and check
# ----------------------------------------------------------------------------------------------
def estimate(scene, *, output=None, keep="auto", every: int = 1) -> Estimate:
    """Voxels, DOF, memory, result file size and a rough time of ``scene``, before building anything.

    Parameters
    ----------
    scene : Scene
    output : path, optional
        The result file the run writes (its states are then streamed to it); None: none.
    keep : "auto", "all", "last" or int >= 1
        The states :func:`voxflex.simulate` holds in memory (see there).
    every : int >= 1
        Record every ``every``-th step.

    Returns
    -------
    Estimate

    Raises
    ------
    InputError
        Not a Scene, a bad ``keep`` or ``every``, or its object cannot be read (missing image or mesh file).
    """
    from .scene import Scene, check_every, check_keep

    if not isinstance(scene, Scene):
        raise InputError(f"estimate needs a Scene (vf.Scene.from_toml(path)), got {type(scene).__name__}")
    return _estimate(scene, output=output, keep=check_keep(keep), every=check_every(every))


def _estimate(scene, size=None, *, output=None, keep="all", every=1) -> Estimate:
    from .deform.models.kinds import node_kind

    kind = node_kind(scene.nodes.kind)
    if size is None:
        # a kind whose geometry is its own (a membrane: its mesh, flat or open) counts it in its estimator;
        # measuring that mesh as a solid refused a flat membrane as "encloses no volume"
        own = kind.image_builder is not None
        size = (1, 8, 8, float(scene.object.voxel_size or 1.0)) if own else _object_size(scene.object)
    est = kind.estimate(scene, size, _material_class(scene))
    voxels, _, surface, h = size
    voxels = voxels if est.voxels is None else est.voxels
    surface = surface if est.surface is None else est.surface
    nodes, dofs, model, seconds = est.nodes, est.dofs, est.model_bytes, est.seconds
    steps = int(scene.solver.steps)
    dynamic = scene.solver.kind != "static"
    # one recorded state in the file: node state, surface positions (V ~ surface nodes), probes, ten scalars,
    # fields per cell (C <= voxels) and per surface triangle (about 2 per surface vertex), reactions, contact, cables
    names = tuple(scene.output.fields)
    per_cell = sum(FIELD_COMPONENTS.get(n, 1) for n in names if n != "reaction")
    row = 8 * dofs + 24 * surface + 24 * len(scene.probes) + 80 + 8 * per_cell * (voxels + 2 * surface) \
        + 24 * ("reaction" in names) * len(scene.fixed) + 24 * len(scene.obstacles) \
        + 8 * len(scene.cables)
    # held in memory per state: that row, plus the solver's record of the node state (+ velocity in dynamics)
    state = row + (2 if dynamic else 1) * 8 * dofs
    every = max(int(every), 1)
    recorded = steps // every + 1 + (1 if steps % every else 0)
    streamed = output is not None
    static = 8 * dofs + 48 * surface + voxels + 4096  # rest nodes, rest surface and its faces, the label image
    file_bytes = static + recorded * row if streamed else 0
    if keep == "auto":
        keep = "all" if not streamed or recorded * row <= _auto_keep_bytes() else "last"
    kept = recorded if keep == "all" else min(recorded, 1 + (1 if keep == "last" else int(keep)))
    return Estimate(node_kind=kind.name, voxels=int(voxels), nodes=int(nodes), dofs=int(dofs), model_bytes=int(model),
                    state_bytes=int(state), states=int(recorded), seconds=float(seconds), voxel_size=h,
                    kept_states=int(kept), file_bytes=int(file_bytes), row_bytes=int(row), streamed=streamed)


def _auto_keep_bytes() -> int:
    from .result import AUTO_KEEP_BYTES

    return AUTO_KEEP_BYTES


def free_disk(path) -> int | None:
    """Bytes free in the folder that would hold ``path`` (None when it cannot be read)."""
    folder = Path(path).parent if str(Path(path).parent) else Path(".")
    try:
        return int(shutil.disk_usage(folder).free)
    except OSError:
        return None


def check(scene, *, available: int | None = None, fraction: float = MEMORY_FRACTION, output=None,
          keep="auto", every: int = 1, disk: int | None = None) -> Estimate:
    """Refuse a scene that would not fit in memory or on disk; return its :class:`Estimate` otherwise.

    Parameters
    ----------
    scene : Scene
    available : int, optional
        Bytes of memory available (default :func:`available_memory`; when that is
        unknown nothing is refused for memory).
    fraction : float in (0, 1]
        Share of ``available`` the run may plan to use.
    output : path, optional
        The result file the run writes (its states stream to it); None: none.
    keep, every
        As for :func:`voxflex.simulate`.
    disk : int, optional
        Bytes free for ``output`` (default :func:`free_disk` of its folder; when
        unknown nothing is refused for disk).

    Raises
    ------
    InputError
        One line: what the scene needs, what is available, and what would fit
        (``[object] voxel_size``, ``[nodes] count``, ``[solver] steps``, a result
        file, ``keep`` or ``every``).
    """
    if not (isinstance(fraction, (int, float)) and 0 < fraction <= 1):
        raise InputError(f"fraction must be in (0, 1], got {fraction!r}")
    est = estimate(scene, output=output, keep=keep, every=every)
    _check_count(scene, est)  # too many nodes for the object is the cause, not the memory or the disk
    if output is not None:
        if disk is None:
            disk = free_disk(output)
        if disk is not None:
            _check_disk(scene, est, output, disk, every)
    if available is None:
        available = available_memory()
    if available is None:
        return est
    if isinstance(available, bool) or not isinstance(available, (int, np.integer)) or available <= 0:
        raise InputError(f"available must be a positive number of bytes, got {available!r}")
    budget = fraction * float(available)
    if est.total_bytes <= budget:
        return est
    need = f"the scene needs about {_human(est.total_bytes)} ({est.summary().split('; memory')[0]}) but " \
           f"{_human(budget)} is available"
    fixed = est.total_bytes - est.held_states * est.state_bytes
    if fixed > budget or est.held_states <= 2:
        raise InputError(f"{need}; {_model_fix(scene, est, budget, output=output, keep=keep, every=every)}")
    fit = int((budget - fixed) // est.state_bytes) - 1
    if output is None:
        raise InputError(
            f"{need}: {est.held_states:,} stored states of {_human(est.state_bytes)} each; write a result file "
            f"(voxflex simulate -o FILE, simulate(output=...)) so that the states stream to disk, pass keep=\"last\" "
            f"(--keep last), or use [solver] steps <= {max(fit * every, 0):,}"
            + (" (or fewer, longer steps)" if scene.solver.kind != "static" else "")
        )
    raise InputError(
        f"{need}: {est.held_states:,} states held in memory of {_human(est.state_bytes)} each beside the result "
        f"file; pass keep=\"last\" (--keep last) or keep <= {max(fit - 1, 1):,}: the file has every state"
    )


COUNT_SLACK = 2.0
"""A reduced kind's ``[nodes] count`` is refused up front when above this many times the object's estimated
voxels (a frame per voxel at most; the estimate of a mesh's voxels is approximate, so the exact check is
the placement's)."""


def _check_count(scene, est: Estimate) -> None:
    """InputError for more nodes than the object has voxels (before the memory and disk checks, which
    would blame the memory or the free disk space for what the count causes)."""
    from .deform.models.kinds import node_kind

    kind = node_kind(est.node_kind)
    count = scene.nodes.count
    if kind.reduced and count is not None and count > COUNT_SLACK * max(est.voxels, 1):
        raise InputError(f"[nodes] count = {count:,} is more {kind.plural} than the object's about {est.voxels:,} "
                         f"voxels (one {kind.noun} per voxel at most); use [nodes] count <= {est.voxels:,}")


def _check_disk(scene, est: Estimate, output, free: int, every: int) -> None:
    """Refuse a result file larger (uncompressed) than the free space of its folder, naming the ``every`` that fits."""
    if est.file_bytes <= free:
        return
    static = est.file_bytes - est.states * est.row_bytes
    room = free - static - 2 * est.row_bytes  # the rest state and the last step are always recorded
    folder = Path(output).parent if str(Path(output).parent) else Path(".")
    what = (f"the result file '{output}' needs up to {_human(est.file_bytes)} ({est.states:,} states of "
            f"{_human(est.row_bytes)}, uncompressed) but {_human(free)} is free in '{folder}'")
    steps = int(scene.solver.steps)
    if room <= 0:
        raise InputError(f"{what}; free space there or choose another folder for the result file")
    k = max(every + 1, math.ceil(steps / (room // est.row_bytes)) if room >= est.row_bytes else steps)
    raise InputError(f"{what}; record fewer states (every = {k:,}: voxflex simulate --every {k}), free space, "
                     "or choose another folder")


def _model_fix(scene, est: Estimate, budget: float, **run) -> str:
    """What would fit: a coarser voxel size (shape, mesh, image) or fewer frames."""
    from .deform.models.kinds import node_kind

    obj = scene.object
    kind = node_kind(est.node_kind)
    if kind.reduced:  # fewer nodes: the largest count that fits (the estimate grows with the count)
        count = min(int(scene.nodes.count or kind.default_count), max(int(est.voxels), 1))
        while count > 1:
            count = count * 9 // 10 if count > 10 else count - 1
            small = dataclasses.replace(scene, nodes=dataclasses.replace(scene.nodes, count=count))
            if _estimate(small, **run).total_bytes <= budget:
                return f"use [nodes] count <= {count}"
    h = _object_size(obj)[3]
    fit = h
    for _ in range(400):  # coarsen until the estimate fits (memory ~ h^-3)
        fit *= 1.05
        if _estimate(scene, _object_size(obj, fit), **run).total_bytes <= budget:
            break
    if obj.image is not None:
        return f"downsample the image to a voxel size of at least {_fmt_up(fit)} m (now {h:.4g} m)"
    return f"use [object] voxel_size >= {_fmt_up(fit)} (now {h:.4g})"


def _fmt_up(x: float) -> str:
    digits = 3 - int(math.floor(math.log10(abs(x)))) - 1
    return f"{math.ceil(x * 10**digits) / 10**digits:.{max(digits, 0)}f}" if digits > 0 else f"{math.ceil(x)}"


def _human(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} B" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"  # pragma: no cover


def _duration(s: float) -> str:
    if s < 60:
        return f"{max(s, 0.01):.2g} s"
    if s < 3600:
        return f"{s / 60:.2g} min"
    if s < 86400 * 365:
        return f"{s / 3600:.3g} h"
    return f"{s / (86400 * 365):.3g} years"

