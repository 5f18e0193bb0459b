"""Resources a scene will need, estimated before anything is built.

:func:`estimate` reads only the scene (and the header-sized facts of its
object: the voxel count of an image, the volume and bounds of a mesh, the
size of a primitive) and returns an :class:`Estimate`: voxels, nodes, degrees
of freedom, the model's memory, the memory of every stored state, and a rough
time.  :func:`check` refuses a scene whose estimate exceeds the memory this
machine has available (``/proc/meminfo`` and the cgroup limit; when neither
can be read nothing is refused), naming what would fit: the voxel size, the
frame count or the number of steps.

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

import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = ["Estimate", "estimate", "check", "available_memory", "MEMORY_FRACTION"]

MEMORY_FRACTION = 0.8
"""Share of the available memory a run may plan to use (the rest: Python, the OS, other processes)."""

# measured by benchmarks/bench_resources.py: slope of peak RSS over DOF, 28k -> 92k DOF (Hooke), 4k -> 29k (neo-Hooke)
BYTES_PER_DOF = {"constant": 4.3e3, "nonlinear": 7.1e3, "reduced": 8.5e3}
"""Voxel model, peak bytes per DOF of a static solve: constant tangent (linear Hooke), nonlinear, nonlinear F-bar."""
CHUNK_BYTES = 2.5e8
"""Bounded per-batch work arrays of the voxel model (tangents of CHUNK_ELEMENTS voxels) once the model exceeds one batch."""
SECONDS_PER_DOF_ITERATION = {"constant": 3.1e-5, "nonlinear": 2.5e-5, "reduced": 6.6e-5}
"""Seconds per Newton iteration per DOF (voxel model, 2-core machine, sparse solve included)."""
ITERATIONS_PER_STEP = {"constant": 1, "nonlinear": 5, "reduced": 5}
"""Newton iterations a step typically takes (a constant tangent converges in one)."""
FRAME_BYTES_PER_VOXEL_PARENT = 112.0
"""Affine frames: shape-function values, gradients and Hessians (1 + 3 + 9 doubles) and an index per voxel and parent."""
FRAME_DENSE_COPIES = 3
"""Affine frames: dense (12 n)^2 matrices alive at once (Hessian, factor, work copy)."""


@dataclass(frozen=True)
class Estimate:
    """What a scene is expected to need.

    Attributes
    ----------
    node_kind : str
    voxels : int
        Occupied voxels (estimated from the volume for shapes and meshes).
    nodes : int
        Voxel-corner nodes or frames.
    dofs : int
    model_bytes : int
        Peak memory of building the model and solving one step (bytes).
    state_bytes : int
        Memory kept per stored state (node state twice, surface, probes; bytes).
    states : int
        Stored states: steps + 1 (the rest state).
    seconds : float
        Rough solve time (order of magnitude) on a 2-core machine.
    voxel_size : float or None
        The object's voxel size (m), the largest spacing of an image.
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

    @property
    def total_bytes(self) -> int:
        """Model plus every stored state (bytes)."""
        return int(self.model_bytes + self.states * self.state_bytes)

    def summary(self) -> str:
        """One line: sizes, memory and time."""
        what = {"voxel": "nodes", "membrane": "vertices"}.get(self.node_kind, "frames")
        return (f"about {self.voxels:,} voxels, {self.nodes:,} {what}, {self.dofs:,} DOF; memory ~{_human(self.total_bytes)} "
                f"(model {_human(self.model_bytes)} + {self.states:,} states x {_human(self.state_bytes)}); "
                f"time ~{_duration(self.seconds)} (rough)")


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

    image = LabelImage.load(path)
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
    from .deform.materials import material
    from .deform.voxel_model import nearly_incompressible, tangent_is_constant

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
def estimate(scene) -> Estimate:
    """Voxels, DOF, memory and a rough time of ``scene``, before building anything.

    Parameters
    ----------
    scene : Scene

    Returns
    -------
    Estimate

    Raises
    ------
    InputError
        Not a Scene, or its object cannot be read (missing image or mesh file).
    """
    from .scene import Scene

    if not isinstance(scene, Scene):
        raise InputError(f"estimate needs a Scene (vf.Scene.from_toml(path)), got {type(scene).__name__}")
    return _estimate(scene)


def _estimate(scene, size=None) -> Estimate:
    voxels, corner_nodes, surface, h = size if size is not None else _object_size(scene.object)
    kind = scene.nodes.kind
    steps = int(scene.solver.steps)
    dynamic = scene.solver.kind != "static"
    cls = _material_class(scene)
    if kind == "voxel":
        nodes = corner_nodes
        dofs = 3 * nodes
        chunk = CHUNK_BYTES * min(1.0, voxels / 16384.0)
        model = BYTES_PER_DOF[cls] * dofs + chunk
        seconds = steps * ITERATIONS_PER_STEP[cls] * SECONDS_PER_DOF_ITERATION[cls] * dofs
    else:
        nodes = int(scene.nodes.count or 20) + len(scene.nodes.positions or ()) + len(scene.fixed)
        dofs = (12 if kind == "affine" else 6) * nodes
        model = (FRAME_BYTES_PER_VOXEL_PARENT * scene.nodes.parents + 64.0) * voxels \
            + FRAME_DENSE_COPIES * 8.0 * dofs**2
        seconds = steps * ITERATIONS_PER_STEP[cls] * (dofs**3 / 3 / 1e10 + 2e-6 * voxels)
    # kept per state: the solver's record and the result's stack of the node state (+ velocity in dynamics),
    # the surface positions, the probes
    state = (3 if dynamic else 2) * 8 * dofs + 24 * surface + 24 * len(scene.probes) + 64
    return Estimate(node_kind=kind, voxels=int(voxels), nodes=int(nodes), dofs=int(dofs), model_bytes=int(model),
                    state_bytes=int(state), states=steps + 1, seconds=float(seconds), voxel_size=h)


def check(scene, *, available: int | None = None, fraction: float = MEMORY_FRACTION) -> Estimate:
    """Refuse a scene that would not fit in memory; return its :class:`Estimate` otherwise.

    Parameters
    ----------
    scene : Scene
    available : int, optional
        Bytes available (default :func:`available_memory`; when that is
        unknown nothing is refused).
    fraction : float in (0, 1]
        Share of ``available`` the run may plan to use.

    Raises
    ------
    InputError
        One line: what the scene needs, what is available, and what would
        fit (``[object] voxel_size``, ``[nodes] count`` or ``[solver] steps``).
    """
    if not (isinstance(fraction, (int, float)) and 0 < fraction <= 1):
        raise InputError(f"fraction must be in (0, 1], got {fraction!r}")
    est = estimate(scene)
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
    if est.model_bytes > budget:
        raise InputError(f"{need}; {_model_fix(scene, est, budget)}")
    fit = int((budget - est.model_bytes) // est.state_bytes) - 1
    raise InputError(
        f"{need}: {est.states:,} stored states of {_human(est.state_bytes)} each; use [solver] steps <= {max(fit, 0):,}"
        + (" (or fewer, longer steps)" if scene.solver.kind != "static" else "")
    )


def _model_fix(scene, est: Estimate, budget: float) -> str:
    """What would fit: a coarser voxel size (shape, mesh, image) or fewer frames."""
    obj = scene.object
    if est.node_kind != "voxel":
        dense = FRAME_DENSE_COPIES * 8.0 * 144.0
        rest = est.model_bytes - dense * est.nodes**2
        if rest < budget:
            count = int(math.sqrt((budget - rest) / dense))
            return f"use [nodes] count <= {max(count - len(scene.fixed) - len(scene.nodes.positions or ()), 1)}"
    h = _object_size(obj)[3]
    fit = h
    for _ in range(400):  # coarsen until the estimate fits (memory ~ h^-3)
        fit *= 1.05
        if _estimate(scene, _object_size(obj, fit)).total_bytes <= budget:
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

