"""Simulation results: the in-memory :class:`Result`, its HDF5 file and ParaView series.

The HDF5 layout is docs/results.md's table, exactly (extra datasets/attrs may
be added; readers ignore what they do not know):

=========================================== ============ =======================================
path                                        shape        meaning
=========================================== ============ =======================================
attrs ``voxflex_version``, ``scene``                     version string; the scene as TOML text
``/time``                                   (T,)         time of each state (static: load factor)
``/probes/NAME``                            (T, 3)       world position of each probe
``/surface/rest``                           (V, 3)       rest positions of the surface vertices
``/surface/faces``                          (F, 3)       triangles (int64)
``/surface/positions``                      (T, V, 3)    deformed positions
``/nodes/rest``, ``/nodes/state``           (n, d),      the DOFs (d = 3 for points, 12 for affine)
                                            (T, n, d)
``/energy/elastic``, ``/energy/kinetic``    (T,)         energies (J)
``/stats/newton_iterations``,               (T,)         solver effort (step 0, the rest state, is 0)
``/stats/step_seconds``
``/image/labels`` + attrs ``spacing``,      (nx, ny, nz) the label image simulated
``origin`` (+ ``direction``, extension)
=========================================== ============ =======================================

Extensions: root attr ``node_kind`` (``"voxel"``, ``"affine"`` or ``"rigid"``), attr ``format = "voxflex-result"``;
the group ``/model`` whose attributes describe the model (``node_kind``, ``count``,
``dofs``, ``quadrature``, ``samples``, ``shape_function``, ``precompute_seconds`` ...).
With obstacles, ``/contact/force`` (T, obstacles, 3): the total force (N) each
obstacle exerts on the body at every state (absent without obstacles).
With cables, ``/cable/tension`` (T, cables): the tension (N) of each ``[[cable]]``
at every state, in the order of the scene's tables (absent without cables), and
``/cable/points`` (T, P, 3) with ``/cable/point_cable`` (P,): the world positions
of every cable's polyline (its anchor first, then its points) at every state and
the cable each point belongs to (renders draw them).
With plasticity, ``/plasticity/yielded_samples`` (T,): how many samples have
yielded so far, and ``/plasticity/max_strain`` (T,): the largest equivalent
plastic strain ``sqrt(2/3) |e_p|`` at every state.
Fields asked for by ``[output] fields``: ``/fields/NAME`` (T, C, ...) per cell
(attr ``location``: ``"voxels"`` or ``"samples"``), ``/surface/fields/NAME``
(T, F, ...) per surface triangle, ``/reactions/force`` (T, R, 3) per fixed region.
Inversion: ``/stats/inverted_samples`` (T,) and ``/stats/min_det_F`` (T,).
A run that failed after some steps is still written: root attrs ``complete``
(False) and ``error`` (the message).
Recorded steps: ``/stats/step`` (T,) the step number of each state (0 .. T-1
unless the run recorded every k-th step), and the ``/stats`` attributes
``steps``, ``newton_iterations``, ``step_seconds``, ``inverted_samples``,
``min_det_F``, ``min_det_F_step``: totals over every step of the run.
Every dataset is gzip-compressed; the per-state datasets are resizable and
chunked along the states (:class:`ResultWriter` appends them state by state
during a run); the file is written atomically.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ._atomic import atomic_path
from ._result_layout import SERIES, SERIES_GROUPS, TOTALS  # the file layout, one definition
from ._result_writer import ResultWriter
from ._version import __version__
from .errors import InputError

__all__ = ["Result", "ResultWriter", "AUTO_KEEP_BYTES", "TOTALS"]

AUTO_KEEP_BYTES = 256 << 20
"""``keep = "auto"`` with a result file holds every recorded state in memory while they need at most this
many bytes (estimated from the rest state), otherwise the rest state and the last one."""



def series_of(rows) -> dict:
    """Result keyword arguments of the per-state datasets ``rows`` (file path -> (T, ...) array)."""
    out = {}
    for attr, path in SERIES:
        if path in rows:
            out[attr] = rows[path]
    for attr, prefix in SERIES_GROUPS:
        out[attr] = {k[len(prefix):]: v for k, v in rows.items() if k.startswith(prefix)}
    return out


def _arr(name, value, ndim, last=None, dtype=float) -> np.ndarray:
    a = np.asarray(value, dtype=dtype)
    if a.ndim != ndim or (last is not None and a.shape[-1] != last):
        want = f"{ndim}-D" + (f" with last axis {last}" if last is not None else "")
        raise InputError(f"Result.{name} must be {want}, got shape {a.shape}")
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


def _field(name, value) -> np.ndarray:
    a = np.ascontiguousarray(np.asarray(value, dtype=float))
    if a.ndim < 2:
        raise InputError(f"Result.{name} must be at least 2-D (states, cells, ...), got shape {a.shape}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Result:
    """Everything a simulation produced (same content as the result file).

    Parameters
    ----------
    time : (T,) float
        Time of each recorded state in s (static runs: the load factor, 0..1).
    probes : dict name -> (T, 3) float
        World positions of the probe points, metres.
    probe_displacement : dict name -> (T, 3) float
        The probes' displacements from rest, metres, from the solver's displacement state
        (``/probe_displacements/NAME``): they keep the digits a position rounds away (a 1 m body
        moved 1e-17 m).  Empty for files that predate it and models whose points are not linear in
        their state (rigid frames); :meth:`probe_displacements` falls back on the positions.
    surface_rest : (V, 3) float; surface_faces : (F, 3) int; surface_positions : (T, V, 3) float
        The boundary surface (triangles) at rest and at every state.
    nodes_rest : (n, d) float; nodes_state : (T, n, d) float
        Degrees of freedom (d = 3 for voxel nodes).
    energy_elastic, energy_kinetic : (T,) float
        Joules.
    newton_iterations : (T,) int; step_seconds : (T,) float
        Solver effort per recorded state (the rest state: 0).
    image_labels : (nx, ny, nz) int; image_spacing, image_origin : (3,) float; image_direction : (3, 3)
        The label image simulated.
    scene : str
        The scene as TOML text.
    version : str
        The voxflex version that produced it.
    node_kind : str
        ``"voxel"`` (trilinear corner nodes), ``"affine"`` or ``"rigid"`` (reduced frame models;
        ``/nodes/state`` holds 12 numbers per affine frame, 6 per rigid frame).
    model : dict
        Scalar attributes describing the model (written as ``/model`` attributes).
    contact_force : (T, k, 3) float or None
        Total force (N) each of the k obstacles exerts on the body at every state
        (``/contact/force``); None without obstacles.
    cable_tension : (T, c) float or None
        Tension (N) of each of the c cables at every state (``/cable/tension``); None without cables.
    cable_points : (T, P, 3) float or None; cable_point_cable : (P,) int or None
        World positions (m) of the cables' polyline points at every state (``/cable/points``; per
        cable its anchor, if any, then its points) and the cable of each point (``/cable/point_cable``).
    plastic_samples : (T,) int or None; plastic_strain_max : (T,) float or None
        Samples that have yielded so far and the largest equivalent plastic strain at every state
        (``/plasticity/yielded_samples``, ``/plasticity/max_strain``); None without plasticity.
    fields : dict name -> (T, F, ...) float
        Result fields on the surface triangles (``/surface/fields/NAME``): what renders colour by
        (names of :data:`voxflex.deform.models.fields.FIELD_NAMES`).
    cell_fields : dict name -> (T, C, ...) float
        The same fields per cell (``/fields/NAME``): C voxels or C samples, see ``cell_location``.
    cell_location : str
        ``"voxels"`` (voxel nodes: each voxel averages its Gauss points, voxels in C order of the
        image) or ``"samples"`` (frames: the quadrature samples); ``""`` without cell fields.
    reactions : (T, R, 3) float or None
        Total force (N) each of the R ``[[fixed]]`` regions exerts on the body (``/reactions/force``).
    inverted_samples : (T,) int or None; min_det_F : (T,) float or None
        Number of samples with det F <= 0 and the smallest det F at every state.
    complete : bool
        False when the run failed after the recorded steps; ``error`` then holds the message.
    error : str
    step : (T,) int, optional
        The step number of each state held (``/stats/step``): 0 for the rest state, k after the
        k-th step.  Default ``0 .. T-1`` (every step recorded and held).  A run recording every
        k-th step, or a :func:`~voxflex.simulate` result that holds only the last states
        (``keep``), has gaps.
    problem : dict
        What the run solved, as renders and readers need it without the scene text (``/problem``):
        ``title``, ``solver_kind``, ``end_time`` (s; 1 for statics), ``gravity`` ((3,) m/s^2 or None),
        ``obstacles`` (list of dicts: ``kind``, its parameters, ``friction``, ``motion``) and ``fixed``
        (list of dicts: ``min``, ``max``, ``components``, ``transform``).  {} for files that predate it.
    node_points : (T, n, 3) float or None
        The point a render draws for each node (a frame's origin) at every state (``/nodes/points``);
        None for models whose nodes are not drawn (voxel corners, membrane vertices).
    fraction : (T,) float or None
        The run fraction of each state (``/stats/fraction``): the load factor, or t / t_end.
    totals : dict
        Totals over every step of the run, recorded or not (``/stats`` attributes): ``steps``,
        ``newton_iterations``, ``step_seconds``, ``inverted_samples`` (the most at one step),
        ``min_det_F`` and ``min_det_F_step``.  Missing keys are computed from the states held;
        :meth:`run_totals` gives them all.
    """

    time: np.ndarray
    probes: dict
    surface_rest: np.ndarray
    surface_faces: np.ndarray
    surface_positions: np.ndarray
    nodes_rest: np.ndarray
    nodes_state: np.ndarray
    energy_elastic: np.ndarray
    energy_kinetic: np.ndarray
    newton_iterations: np.ndarray
    step_seconds: np.ndarray
    image_labels: np.ndarray
    image_spacing: np.ndarray
    image_origin: np.ndarray
    image_direction: np.ndarray = field(default_factory=lambda: np.eye(3))
    scene: str = ""
    version: str = __version__
    node_kind: str = field(default_factory=lambda: _reference_kind())
    model: dict = field(default_factory=dict)
    contact_force: np.ndarray | None = None
    cable_tension: np.ndarray | None = None
    cable_points: np.ndarray | None = None
    cable_point_cable: np.ndarray | None = None
    plastic_samples: np.ndarray | None = None
    plastic_strain_max: np.ndarray | None = None
    fields: dict = field(default_factory=dict)
    cell_fields: dict = field(default_factory=dict)
    cell_location: str = ""
    reactions: np.ndarray | None = None
    inverted_samples: np.ndarray | None = None
    min_det_F: np.ndarray | None = None
    complete: bool = True
    error: str = ""
    step: np.ndarray | None = None
    totals: dict = field(default_factory=dict)
    problem: dict = field(default_factory=dict)
    node_points: np.ndarray | None = None
    fraction: np.ndarray | None = None
    probe_displacement: dict = field(default_factory=dict)

    def __post_init__(self):
        s = object.__setattr__
        time = _arr("time", self.time, 1)
        T = time.shape[0]
        if T == 0:
            raise InputError("Result.time is empty; a result holds at least the rest state")
        s(self, "time", time)
        probes = {}
        for name, pos in dict(self.probes).items():
            p = _arr(f"probes['{name}']", pos, 2, 3)
            if p.shape[0] != T or "/" in str(name):
                raise InputError(f"probe '{name}' must have shape ({T}, 3) and a name without '/', got {p.shape}")
            probes[str(name)] = p
        s(self, "probes", probes)
        moved = {}
        for name, d in dict(self.probe_displacement or {}).items():
            a = _arr(f"probe_displacement['{name}']", d, 2, 3)
            if a.shape[0] != T or str(name) not in probes:
                raise InputError(f"probe_displacement '{name}' must have shape ({T}, 3) and name a probe, got {a.shape}")
            moved[str(name)] = a
        s(self, "probe_displacement", moved)
        s(self, "surface_rest", _arr("surface_rest", self.surface_rest, 2, 3))
        s(self, "surface_faces", _arr("surface_faces", self.surface_faces, 2, 3, dtype=np.int64))
        V = self.surface_rest.shape[0]
        if self.surface_faces.size and (self.surface_faces.min() < 0 or self.surface_faces.max() >= V):
            raise InputError(f"Result.surface_faces index vertices outside 0..{V - 1}")
        s(self, "surface_positions", _arr("surface_positions", self.surface_positions, 3, 3))
        if self.surface_positions.shape[:2] != (T, V):
            raise InputError(f"Result.surface_positions must be ({T}, {V}, 3), got {self.surface_positions.shape}")
        s(self, "nodes_rest", _arr("nodes_rest", self.nodes_rest, 2))
        s(self, "nodes_state", _arr("nodes_state", self.nodes_state, 3))
        if self.nodes_state.shape != (T, *self.nodes_rest.shape):
            raise InputError(
                f"Result.nodes_state must be ({T}, {', '.join(map(str, self.nodes_rest.shape))}), "
                f"got {self.nodes_state.shape}"
            )
        for name, dtype in (
            ("energy_elastic", float),
            ("energy_kinetic", float),
            ("newton_iterations", np.int64),
            ("step_seconds", float),
        ):
            a = _arr(name, getattr(self, name), 1, dtype=dtype)
            if a.shape != (T,):
                raise InputError(f"Result.{name} must have shape ({T},), got {a.shape}")
            s(self, name, a)
        labels = np.asarray(self.image_labels)
        if labels.ndim != 3 or not np.issubdtype(labels.dtype, np.integer):
            raise InputError(f"Result.image_labels must be a 3-D integer array, got {labels.dtype} {labels.shape}")
        labels = np.ascontiguousarray(labels)
        labels.setflags(write=False)
        s(self, "image_labels", labels)
        s(self, "image_spacing", _arr("image_spacing", self.image_spacing, 1, 3))
        s(self, "image_origin", _arr("image_origin", self.image_origin, 1, 3))
        if not (np.all(np.isfinite(self.image_spacing)) and np.all(self.image_spacing > 0)):
            raise InputError(f"Result.image_spacing must be 3 finite lengths > 0 (m), got {self.image_spacing.tolist()}")
        if not np.all(np.isfinite(self.image_origin)):
            raise InputError(f"Result.image_origin must be 3 finite coordinates (m), got {self.image_origin.tolist()}")
        direction = np.asarray(self.image_direction, dtype=float)
        if direction.shape != (3, 3):
            raise InputError(f"Result.image_direction must be 3x3, got {direction.shape}")
        if not (np.all(np.isfinite(direction)) and np.allclose(direction.T @ direction, np.eye(3), atol=1e-6)):
            raise InputError("Result.image_direction must be orthonormal (its columns are the world directions of "
                             f"the array axes), got {direction.tolist()}")
        s(self, "image_direction", direction)
        s(self, "scene", str(self.scene))
        s(self, "version", str(self.version))
        s(self, "node_kind", str(self.node_kind))
        model = {}
        for key, value in dict(self.model).items():
            if isinstance(value, (np.generic,)):
                value = value.item()
            if not isinstance(value, (str, int, float, bool)):
                raise InputError(f"Result.model['{key}'] must be a string or a number, got {type(value).__name__}")
            model[str(key)] = value
        s(self, "model", model)
        if self.contact_force is not None:
            cf = _arr("contact_force", self.contact_force, 3, 3)
            if cf.shape[0] != T:
                raise InputError(f"Result.contact_force must be ({T}, obstacles, 3), got {cf.shape}")
            s(self, "contact_force", cf)
        if self.cable_tension is not None:
            ct = _arr("cable_tension", self.cable_tension, 2)
            if ct.shape[0] != T:
                raise InputError(f"Result.cable_tension must be ({T}, cables), got {ct.shape}")
            s(self, "cable_tension", ct)
        if (self.cable_points is None) != (self.cable_point_cable is None):
            raise InputError("Result.cable_points and cable_point_cable go together: give both or neither")
        if self.cable_points is not None:
            cp = _arr("cable_points", self.cable_points, 3, 3)
            pc = _arr("cable_point_cable", self.cable_point_cable, 1, dtype=np.int64)
            if cp.shape[0] != T or cp.shape[1] != len(pc):
                raise InputError(f"Result.cable_points must be ({T}, {len(pc)}, 3) (one row per cable_point_cable "
                                 f"entry), got {cp.shape}")
            s(self, "cable_points", cp)
            s(self, "cable_point_cable", pc)
        if self.node_points is not None:
            npts = _arr("node_points", self.node_points, 3, 3)
            if npts.shape[:2] != (T, self.nodes_rest.shape[0]):
                raise InputError(f"Result.node_points must be ({T}, {self.nodes_rest.shape[0]}, 3), got {npts.shape}")
            s(self, "node_points", npts)
        if self.fraction is not None:
            fr = _arr("fraction", self.fraction, 1)
            if len(fr) != T:
                raise InputError(f"Result.fraction must be ({T},), got {fr.shape}")
            s(self, "fraction", fr)
        s(self, "problem", dict(self.problem))
        if (self.plastic_samples is None) != (self.plastic_strain_max is None):
            raise InputError("Result.plastic_samples and plastic_strain_max go together: give both or neither")
        if self.plastic_samples is not None:
            ps = _arr("plastic_samples", self.plastic_samples, 1, dtype=np.int64)
            pm = _arr("plastic_strain_max", self.plastic_strain_max, 1)
            if len(ps) != T or len(pm) != T:
                raise InputError(f"Result.plastic_samples and plastic_strain_max must be ({T},), got "
                                 f"{ps.shape} and {pm.shape}")
            s(self, "plastic_samples", ps)
            s(self, "plastic_strain_max", pm)
        F = self.surface_faces.shape[0]
        out = {}
        for name, values in dict(self.fields).items():
            a = _field(f"fields['{name}']", values)
            if a.shape[:2] != (T, F):
                raise InputError(f"Result.fields['{name}'] must be ({T}, {F}, ...) (one value per surface triangle), "
                                 f"got {a.shape}")
            out[str(name)] = a
        s(self, "fields", out)
        out = {}
        for name, values in dict(self.cell_fields).items():
            a = _field(f"cell_fields['{name}']", values)
            if a.ndim < 2 or a.shape[0] != T:
                raise InputError(f"Result.cell_fields['{name}'] must be ({T}, cells, ...), got {a.shape}")
            out[str(name)] = a
        s(self, "cell_fields", out)
        if out and self.cell_location not in ("voxels", "samples"):
            raise InputError(f"Result.cell_location must be 'voxels' or 'samples', got {self.cell_location!r}")
        s(self, "cell_location", str(self.cell_location))
        if self.reactions is not None:
            r = _arr("reactions", self.reactions, 3, 3)
            if r.shape[0] != T:
                raise InputError(f"Result.reactions must be ({T}, regions, 3), got {r.shape}")
            s(self, "reactions", r)
        for name, dtype in (("inverted_samples", np.int64), ("min_det_F", float)):
            if getattr(self, name) is not None:
                a = _arr(name, getattr(self, name), 1, dtype=dtype)
                if a.shape != (T,):
                    raise InputError(f"Result.{name} must have shape ({T},), got {a.shape}")
                s(self, name, a)
        s(self, "complete", bool(self.complete))
        s(self, "error", str(self.error))
        step = np.arange(T, dtype=np.int64) if self.step is None else _arr("step", self.step, 1, dtype=np.int64)
        if step.shape != (T,) or step[0] < 0 or np.any(np.diff(step) <= 0):
            raise InputError(f"Result.step must be ({T},) increasing step numbers from 0, got {step.tolist()[:8]}")
        s(self, "step", step)
        totals = {}
        for key, value in dict(self.totals).items():
            if key not in TOTALS:
                raise InputError(f"Result.totals has an unknown key '{key}'; valid: {', '.join(TOTALS)}")
            totals[key] = TOTALS[key](np.asarray(value).item())
        s(self, "totals", totals)

    # -- conveniences -----------------------------------------------------
    @property
    def n_steps(self) -> int:
        """Number of steps the run made up to the last state held (T - 1 when every step is recorded and held)."""
        return int(self.step[-1])

    def run_totals(self) -> dict:
        """Totals over every step of the run: :attr:`totals`, completed from the states held.

        Returns
        -------
        dict
            ``steps`` (int), ``newton_iterations`` (int), ``step_seconds`` (float, s),
            ``inverted_samples`` (int, the most at one state, or None), ``min_det_F`` (float or
            None) and ``min_det_F_step`` (int, the step where it occurred, or None).
        """
        out = {"steps": self.n_steps, "newton_iterations": int(self.newton_iterations.sum()),
               "step_seconds": float(self.step_seconds.sum()), "inverted_samples": None, "min_det_F": None,
               "min_det_F_step": None}
        if self.inverted_samples is not None:
            out["inverted_samples"] = int(self.inverted_samples.max())
        if self.min_det_F is not None:
            worst = int(np.argmin(self.min_det_F))
            out["min_det_F"], out["min_det_F_step"] = float(self.min_det_F[worst]), int(self.step[worst])
        out.update(self.totals)
        return out

    @property
    def n_states(self) -> int:
        """Number of recorded states T (the rest state and one per step)."""
        return int(self.time.shape[0])

    @property
    def n_nodes(self) -> int:
        return int(self.nodes_rest.shape[0])

    @property
    def n_dofs(self) -> int:
        return int(self.nodes_rest.size)

    @property
    def n_voxels(self) -> int:
        return int(np.count_nonzero(self.image_labels))

    def step_index(self, step: int) -> int:
        """Normalize a step index (negative counts from the end); InputError when out of range."""
        T = self.n_states
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)):
            raise InputError(f"step must be an integer state index, got {step!r}; this result has states 0..{T - 1} "
                             "(or -1 for the last)")
        if not -T <= step < T:
            raise InputError(f"step {step!r} is out of range; this result has steps 0..{T - 1} (or -1 for the last)")
        return int(step) % T

    def displacement(self, step: int = -1) -> np.ndarray:
        """Surface vertex displacements (V, 3) at ``step``, metres."""
        return self.surface_positions[self.step_index(step)] - self.surface_rest

    def probe_displacements(self, step: int = -1) -> dict:
        """{name: (3,) displacement of each probe at ``step``} in metres."""
        i = self.step_index(step)
        out = {k: v[i] - v[0] for k, v in self.probes.items()}
        for k, d in self.probe_displacement.items():  # the solver's displacements: digits the positions lack
            out[k] = d[i] - d[0]
        return out

    # -- HDF5 -------------------------------------------------------------
    def save(self, path, *, force: bool = False) -> Path:
        """Write the result file (HDF5, the layout of docs/results.md), atomically; returns the path.

        An existing file that is not a voxflex result is refused (it would be lost) unless ``force``,
        as :func:`voxflex.simulate` refuses it (:func:`voxflex._result_target.check_result_output`).
        """
        from ._result_target import check_result_output

        path = check_result_output(_path(path, "result file"), force=force, option="path",
                                   hint="pass force=True to overwrite it")
        checked = Result(**{f.name: getattr(self, f.name) for f in fields(self)})  # its dicts may have been edited
        with atomic_path(path) as tmp:
            writer = ResultWriter(tmp, checked)
            try:
                writer.append_block(checked.rows())
                writer.close(complete=checked.complete, error=checked.error, totals=checked.run_totals())
            finally:
                writer.abort()
        return path

    def rows(self) -> dict:
        """The per-state datasets by file path: {path: (T, ...) array} (what :class:`ResultWriter` appends)."""
        out = {}
        for attr, path in SERIES:
            value = getattr(self, attr)
            if value is not None:
                out[path] = value
        for attr, prefix in SERIES_GROUPS:
            for name, value in getattr(self, attr).items():
                out[prefix + name] = value
        return out

    @classmethod
    def load(cls, path) -> Result:
        """Read a result file; InputError when the file is missing or not a voxflex result."""
        import h5py

        path = _path(path, "result file")
        if not _is_file(path):
            from .errors import missing_file

            raise missing_file(path, "result file")
        try:
            f = h5py.File(path, "r")
        except OSError as exc:
            with open(path, "rb") as fh:
                hdf5 = fh.read(8) == b"\x89HDF\r\n\x1a\n"
            if hdf5:  # an HDF5 file cut short or damaged in its superblock
                reason = " ".join(str(exc).split())[:160]
                raise InputError(f"'{path}' is a damaged HDF5 file ({reason}); write it again with "
                                 "'voxflex simulate'") from None
            raise InputError(f"'{path}' is not an HDF5 file; give a result file written by 'voxflex simulate'") from None
        with f:
            try:
                return cls._read(f, path)
            except InputError as exc:
                if str(exc).startswith(f"'{path}'"):
                    raise
                raise InputError(f"'{path}' holds an inconsistent result ({exc}); write it again with "
                                 "'voxflex simulate'") from None
            except (RuntimeError, KeyError, OSError, ValueError, TypeError, IndexError, AttributeError) as exc:
                # h5py's messages for a damaged file (a bad heap, a B-tree signature, a size past the end)
                reason = " ".join(str(exc).split())[:160] or type(exc).__name__
                raise InputError(f"'{path}' is damaged ({reason}); write it again with 'voxflex simulate'") from None

    @classmethod
    def _read(cls, f, path) -> Result:
        """The result in an open HDF5 file (h5py errors of a damaged file propagate)."""
        required = ("time", "surface/rest", "surface/faces", "surface/positions", "nodes/rest", "nodes/state")
        missing = [p for p in required if p not in f]
        if "voxflex_version" not in f.attrs or missing:
            what = f"lacks /{missing[0]}" if missing else "has no voxflex_version attribute"
            raise InputError(
                f"'{path}' is not a voxflex result file ({what}); give a file written by 'voxflex simulate'"
            )
        T = f["time"].shape[0]

        def get(name, default=None):
            return f[name][()] if name in f else default

        labels_ds = f["image/labels"] if "image/labels" in f else None
        if labels_ds is not None:
            labels = labels_ds[()]
            spacing = labels_ds.attrs.get("spacing", f["image"].attrs.get("spacing", np.ones(3)))
            origin = labels_ds.attrs.get("origin", f["image"].attrs.get("origin", np.zeros(3)))
            direction = labels_ds.attrs.get("direction", f["image"].attrs.get("direction", np.eye(3)))
        else:
            labels, spacing, origin, direction = np.zeros((1, 1, 1), np.uint8), np.ones(3), np.zeros(3), np.eye(3)
        zeros = np.zeros(T)
        return cls(
            time=f["time"][()],
            probes={k: v[()] for k, v in f["probes"].items()} if "probes" in f else {},
            probe_displacement=({k: v[()] for k, v in f["probe_displacements"].items()}
                                if "probe_displacements" in f else {}),
            surface_rest=f["surface/rest"][()],
            surface_faces=f["surface/faces"][()],
            surface_positions=f["surface/positions"][()],
            nodes_rest=f["nodes/rest"][()],
            nodes_state=f["nodes/state"][()],
            energy_elastic=get("energy/elastic", zeros),
            energy_kinetic=get("energy/kinetic", zeros),
            newton_iterations=get("stats/newton_iterations", zeros.astype(np.int64)),
            step_seconds=get("stats/step_seconds", zeros),
            image_labels=labels,
            image_spacing=spacing,
            image_origin=origin,
            image_direction=direction,
            scene=_text(f.attrs.get("scene", "")),
            version=_text(f.attrs["voxflex_version"]),
            node_kind=_text(f.attrs["node_kind"]) if "node_kind" in f.attrs else _reference_kind(),
            model={k: (_text(v) if isinstance(v, (bytes, str)) else np.asarray(v).item())
                   for k, v in (f["model"].attrs.items() if "model" in f else ())
                   if isinstance(v, (bytes, str)) or np.size(v) == 1},  # what it does not know (an array): ignored
            contact_force=get("contact/force"),
            cable_tension=get("cable/tension"),
            cable_points=get("cable/points"),
            cable_point_cable=get("cable/point_cable"),
            plastic_samples=get("plasticity/yielded_samples"),
            plastic_strain_max=get("plasticity/max_strain"),
            fields={k: v[()] for k, v in f["surface/fields"].items()} if "surface/fields" in f else {},
            cell_fields={k: v[()] for k, v in f["fields"].items()} if "fields" in f else {},
            cell_location=_text(next(iter(f["fields"].values())).attrs.get("location", ""))
            if "fields" in f and len(f["fields"]) else "",
            reactions=get("reactions/force"),
            inverted_samples=get("stats/inverted_samples"),
            min_det_F=get("stats/min_det_F"),
            complete=_flag(f.attrs.get("complete", True), "complete"),
            error=_text(f.attrs.get("error", "")),
            step=get("stats/step"),
            totals={k: v for k, v in (f["stats"].attrs.items() if "stats" in f else ()) if k in TOTALS},
            problem=_read_problem(f["problem"]) if "problem" in f else {},
            node_points=get("nodes/points"),
            fraction=get("stats/fraction"),
        )

    # -- ParaView ---------------------------------------------------------
    def export_vtk(self, target) -> Path:
        """Write a ParaView time series: one ``.vtp`` per state plus a ``.pvd`` collection.

        Parameters
        ----------
        target : path
            A ``.pvd`` file (the ``.vtp`` files go beside it, named after it) or a
            folder (created if missing; the collection is ``result.pvd`` inside).

        Returns
        -------
        Path of the ``.pvd`` file.  Each ``.vtp`` holds the deformed surface with
        point arrays ``displacement`` (V, 3) and ``displacement_magnitude`` (V,),
        and the result's surface :attr:`fields` as cell data (tensors as 9 components).
        Voxel results with :attr:`cell_fields` also get a series of hexahedral
        cells, ``NAME_cells.pvd`` with one ``.vtu`` per state, carrying them as cell data.
        """
        import pyvista as pv

        target = _path(target, "VTK export target")
        if target.exists() and not target.is_dir() and target.suffix.lower() != ".pvd":
            raise InputError(f"VTK export target '{target}' is a file; give a folder (created if missing) or a .pvd "
                             "file name")
        if target.suffix.lower() == ".pvd" and target.is_dir():
            target = target / "result.pvd"  # a folder that happens to end in .pvd
        bad = [t for t in range(self.n_states) if not np.all(np.isfinite(self.surface_positions[t]))]
        if bad:
            raise InputError(f"the result's surface at state {bad[0]} is not finite (NaN or inf): there is nothing "
                             "meaningful to export; check the run (voxflex info) and simulate it again")
        if target.suffix.lower() == ".pvd":
            folder, stem = target.parent if str(target.parent) else Path("."), target.stem
        else:
            if target.suffix and not target.is_dir():
                raise InputError(f"VTK export target '{target}' must be a folder or a .pvd file")
            folder, stem = target, "result"
            folder.mkdir(parents=True, exist_ok=True)
        if not folder.is_dir():
            raise InputError(f"output folder '{folder}' does not exist; create it or choose another path")
        faces = np.hstack([np.full((self.surface_faces.shape[0], 1), 3), self.surface_faces]).ravel()

        def surface(t):
            mesh = pv.PolyData(np.array(self.surface_positions[t]), faces=faces)
            u = self.surface_positions[t] - self.surface_rest
            mesh.point_data["displacement"] = u
            mesh.point_data["displacement_magnitude"] = np.linalg.norm(u, axis=1)
            for key, values in self.fields.items():
                mesh.cell_data[key] = _vtk_components(values[t])
            return mesh

        pvd = self._write_series(folder, stem, "vtp", surface)
        if self.cell_fields and self.cell_location == "voxels":
            self._export_hexahedra(folder, f"{stem}_cells")
        return pvd

    def _export_hexahedra(self, folder: Path, stem: str) -> Path:
        """The voxels as hexahedral cells at every state with :attr:`cell_fields` as cell data."""
        import pyvista as pv

        from .image.grid import CORNER_OFFSETS, TrilinearGrid
        from .image.label_image import LabelImage

        image = LabelImage(self.image_labels, spacing=self.image_spacing, origin=self.image_origin,
                           direction=self.image_direction)
        grid = TrilinearGrid.from_image(image, self.image_labels > 0)
        C = next(iter(self.cell_fields.values())).shape[1]
        if grid.n_elements != C or grid.n_nodes != self.n_nodes:
            raise InputError(f"the result's cell fields ({C} cells) do not match the voxels of its image "
                             f"({grid.n_elements}); export the surface series only")
        vtk_order = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]]
        corner = [int(np.flatnonzero(np.all(CORNER_OFFSETS == c, axis=1))[0]) for c in vtk_order]
        conn = grid.element_nodes[:, corner]
        cells = np.hstack([np.full((C, 1), 8), conn]).ravel()
        types = np.full(C, pv.CellType.HEXAHEDRON, dtype=np.uint8)

        def hexahedra(t):
            mesh = pv.UnstructuredGrid(cells, types, np.array(self.nodes_state[t]))
            for key, values in self.cell_fields.items():
                mesh.cell_data[key] = _vtk_components(values[t])
            return mesh

        return self._write_series(folder, stem, "vtu", hexahedra)

    def _write_series(self, folder: Path, stem: str, ext: str, mesh_of) -> Path:
        """One ``STEM_TTTT.EXT`` per state (``mesh_of(t)``) and the ``STEM.pvd`` collection, atomically."""
        entries = []
        for t in range(self.n_states):
            name = f"{stem}_{t:04d}.{ext}"
            with atomic_path(folder / name) as tmp:
                mesh_of(t).save(str(tmp), binary=True)
            entries.append((float(self.time[t]), name))
        pvd = folder / f"{stem}.pvd"
        with atomic_path(pvd) as tmp:
            tmp.write_text(_pvd_xml(entries), encoding="utf-8")
        return pvd


def _vtk_components(values) -> np.ndarray:
    """Cell values (C, ...) as VTK arrays: scalars (C,), vectors (C, 3), tensors (C, 9)."""
    values = np.asarray(values, dtype=float)
    return values.reshape(len(values), -1) if values.ndim > 2 else values


def _pvd_xml(entries) -> str:
    from xml.sax.saxutils import quoteattr

    rows = "\n".join(
        f'    <DataSet timestep="{t!r}" group="" part="0" file={quoteattr(name)}/>' for t, name in entries
    )
    return (
        '<?xml version="1.0"?>\n'
        '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
        "  <Collection>\n"
        f"{rows}\n"
        "  </Collection>\n"
        "</VTKFile>\n"
    )


def _read_problem(g) -> dict:
    """The dict :func:`_write_problem` wrote."""
    def value(v):
        if isinstance(v, (bytes, str)):
            return _text(v)
        a = np.asarray(v)
        return a.item() if a.ndim == 0 else a

    out = {k: value(v) for k, v in g.attrs.items()}
    out.setdefault("gravity", None)
    for name in ("obstacles", "fixed"):
        items = g[name] if name in g else {}
        out[name] = [{k: value(v) for k, v in items[str(i)].attrs.items()} for i in range(len(items))]
    return out


def _reference_kind() -> str:
    """The name of the reference node kind: what a result that does not say its kind was made with."""
    from .deform.models.kinds import reference_kind

    return reference_kind().name


def _path(value, what: str) -> Path:
    """``value`` as a Path; InputError for what is not a path (a number, None)."""
    import os

    if not isinstance(value, (str, os.PathLike)):
        raise InputError(f"{what} must be a path (str or Path), got {type(value).__name__}")
    return Path(value)


def _is_file(path: Path) -> bool:
    """``path.is_file()`` that says False instead of raising (a name too long, a loop of links)."""
    try:
        return path.is_file()
    except OSError:
        return False



def _flag(value, name: str) -> bool:
    """A boolean attribute of a result file (True/False, or the integers 1/0 h5py may hand back); anything else
    (``complete = "no"`` read as True) is a damaged file."""
    v = np.asarray(value)
    if v.size == 1 and (v.dtype == bool or np.issubdtype(v.dtype, np.integer)) and v.item() in (0, 1):
        return bool(v.item())
    raise InputError(f"the result's '{name}' attribute is {value!r}, not a boolean: the file is damaged; write it "
                     "again with 'voxflex simulate'")

def _text(value) -> str:
    return value.decode("utf-8") if isinstance(value, bytes) else str(value)












