"""Simulation results: the in-memory :class:`Result`, its HDF5 file and ParaView series.

The HDF5 layout is the SPEC's result table, exactly (extra datasets/attrs may
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
Every dataset is gzip-compressed; the file is written atomically.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._atomic import atomic_path
from ._version import __version__
from .errors import InputError

__all__ = ["Result", "describe_result"]

_FORMAT = "voxflex-result"


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
        (names of :data:`voxflex.deform.fields.FIELD_NAMES`).
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
    node_kind: str = "voxel"
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
        direction = np.asarray(self.image_direction, dtype=float)
        if direction.shape != (3, 3):
            raise InputError(f"Result.image_direction must be 3x3, got {direction.shape}")
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

    # -- conveniences -----------------------------------------------------
    @property
    def n_steps(self) -> int:
        """Number of steps recorded: T - 1 (the rest state is state 0, not a step)."""
        return int(self.time.shape[0]) - 1

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
        if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or not -T <= step < T:
            raise InputError(f"step {step!r} is out of range; this result has steps 0..{T - 1} (or -1 for the last)")
        return int(step) % T

    def displacement(self, step: int = -1) -> np.ndarray:
        """Surface vertex displacements (V, 3) at ``step``, metres."""
        return self.surface_positions[self.step_index(step)] - self.surface_rest

    def probe_displacements(self, step: int = -1) -> dict:
        """{name: (3,) displacement of each probe at ``step``} in metres."""
        i = self.step_index(step)
        return {k: v[i] - v[0] for k, v in self.probes.items()}

    # -- HDF5 -------------------------------------------------------------
    def save(self, path) -> Path:
        """Write the result file (HDF5, the SPEC layout), atomically; returns the path."""
        import h5py

        path = Path(path)
        comp = dict(compression="gzip", compression_opts=4, shuffle=True)

        def put(group, name, data):
            data = np.asarray(data)
            if data.size == 0:
                return group.create_dataset(name, data=data)
            return group.create_dataset(name, data=data, chunks=True, **comp)

        with atomic_path(path) as tmp:
            with h5py.File(tmp, "w") as f:
                f.attrs["voxflex_version"] = self.version
                f.attrs["scene"] = self.scene
                f.attrs["format"] = _FORMAT
                f.attrs["node_kind"] = self.node_kind
                f.attrs["complete"] = self.complete
                if self.error:
                    f.attrs["error"] = self.error
                put(f, "time", self.time)
                g = f.create_group("model")
                for key, value in self.model.items():
                    g.attrs[key] = value
                g = f.create_group("probes")
                for name, pos in self.probes.items():
                    put(g, name, pos)
                g = f.create_group("surface")
                put(g, "rest", self.surface_rest)
                put(g, "faces", self.surface_faces)
                put(g, "positions", self.surface_positions)
                g = f.create_group("nodes")
                put(g, "rest", self.nodes_rest)
                put(g, "state", self.nodes_state)
                g = f.create_group("energy")
                put(g, "elastic", self.energy_elastic)
                put(g, "kinetic", self.energy_kinetic)
                g = f.create_group("stats")
                put(g, "newton_iterations", self.newton_iterations)
                put(g, "step_seconds", self.step_seconds)
                if self.inverted_samples is not None:
                    put(g, "inverted_samples", self.inverted_samples)
                if self.min_det_F is not None:
                    put(g, "min_det_F", self.min_det_F)
                if self.cell_fields:
                    g = f.create_group("fields")
                    for name, values in self.cell_fields.items():
                        put(g, name, values).attrs["location"] = self.cell_location
                if self.fields:
                    g = f["surface"].create_group("fields")
                    for name, values in self.fields.items():
                        put(g, name, values)
                if self.reactions is not None:
                    put(f.create_group("reactions"), "force", self.reactions)
                g = f.create_group("image")
                d = put(g, "labels", self.image_labels)
                d.attrs["spacing"] = self.image_spacing
                d.attrs["origin"] = self.image_origin
                d.attrs["direction"] = self.image_direction
                g.attrs["spacing"] = self.image_spacing
                g.attrs["origin"] = self.image_origin
                g.attrs["direction"] = self.image_direction
                if self.contact_force is not None:
                    put(f.create_group("contact"), "force", self.contact_force)
                if self.cable_tension is not None:
                    g = f.create_group("cable")
                    put(g, "tension", self.cable_tension)
                    if self.cable_points is not None:
                        put(g, "points", self.cable_points)
                        put(g, "point_cable", self.cable_point_cable)
                if self.plastic_samples is not None:
                    g = f.create_group("plasticity")
                    put(g, "yielded_samples", self.plastic_samples)
                    put(g, "max_strain", self.plastic_strain_max)
        return path

    @classmethod
    def load(cls, path) -> Result:
        """Read a result file; InputError when the file is missing or not a voxflex result."""
        import h5py

        path = Path(path)
        if not path.is_file():
            raise InputError(f"result file '{path}' not found; check the path")
        try:
            f = h5py.File(path, "r")
        except OSError:
            raise InputError(f"'{path}' is not an HDF5 file; give a result file written by 'voxflex simulate'") from None
        with f:
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
                node_kind=_text(f.attrs.get("node_kind", "voxel")),
                model={k: (_text(v) if isinstance(v, (bytes, str)) else np.asarray(v).item())
                       for k, v in (f["model"].attrs.items() if "model" in f else ())},
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
                complete=bool(f.attrs.get("complete", True)),
                error=_text(f.attrs.get("error", "")),
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

        target = Path(target)
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

        from .image.label_image import LabelImage
        from .voronoi.trilinear import CORNER_OFFSETS, TrilinearGrid

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


def _text(value) -> str:
    return value.decode("utf-8") if isinstance(value, bytes) else str(value)


def describe_result(path) -> str:
    """A short human-readable summary of a result file (used by ``voxflex info``)."""
    r = Result.load(path)
    T = r.n_states
    labels, counts = np.unique(r.image_labels[r.image_labels > 0], return_counts=True)
    lines = [
        f"result: {path} (voxflex {r.version})",
        f"  image: {' x '.join(map(str, r.image_labels.shape))} voxels, spacing {r.image_spacing.tolist()} m, "
        f"{r.n_voxels} occupied ({', '.join(f'label {a}: {b}' for a, b in zip(labels, counts))})",
        f"  model: {_model_text(r)}; surface {r.surface_rest.shape[0]} vertices, {r.surface_faces.shape[0]} triangles",
        f"  states: {T} (the rest state and {r.n_steps} steps; time {r.time[0]:g} .. {r.time[-1]:g}); "
        f"Newton iterations {int(r.newton_iterations.sum())}, solve time {r.step_seconds.sum():.3g} s",
        f"  energy at the end: elastic {r.energy_elastic[-1]:.6g} J, kinetic {r.energy_kinetic[-1]:.6g} J",
        f"  max surface displacement at the end: {np.linalg.norm(r.displacement(-1), axis=1).max():.6g} m",
    ]
    for name, pos in r.probes.items():
        u = pos[-1] - pos[0]
        lines.append(
            f"  probe {name}: rest {_fmt(pos[0])} -> final {_fmt(pos[-1])} (displacement {_fmt(u)})"
        )
    lines += [f"  {line}" for line in field_lines(r)]
    if not r.complete:
        lines.append(f"  INCOMPLETE: the run failed after step {r.n_steps}: {r.error}")
    return "\n".join(lines)


def field_lines(r) -> list:
    """Lines naming the fields, reactions and inversion statistics a result carries (info and summaries)."""
    lines = []
    if r.cell_fields:
        per = "voxel" if r.cell_location == "voxels" else "sample"
        parts = []
        for name, v in r.cell_fields.items():
            shape = "x".join(map(str, v.shape[2:])) or "scalar"
            extra = f", max at the end {np.nanmax(v[-1]):.6g}" if v.ndim == 2 else ""
            parts.append(f"{name} ({shape}{extra})")
        lines.append(f"fields per {per} ({next(iter(r.cell_fields.values())).shape[1]} {per}s) and on the "
                     f"surface: {'; '.join(parts)}")
    if r.reactions is not None:
        for i, force in enumerate(r.reactions[-1]):
            lines.append(f"reaction of fixed region #{i} at the end: {_fmt(force)} N")
    if getattr(r, "contact_force", None) is not None:
        for i, force in enumerate(r.contact_force[-1]):
            lines.append(f"contact force of obstacle #{i} at the end: {_fmt(force)} N")
    if getattr(r, "cable_tension", None) is not None:
        lines.append(f"cable tensions at the end: {_fmt(r.cable_tension[-1])} N")
    if getattr(r, "plastic_samples", None) is not None:
        lines.append(f"plasticity: {int(r.plastic_samples[-1])} samples have yielded at the end; largest "
                     f"equivalent plastic strain {float(r.plastic_strain_max.max()):.6g} "
                     f"(at the end {float(r.plastic_strain_max[-1]):.6g})")
    if r.min_det_F is not None and r.inverted_samples is not None:
        worst = int(np.argmin(r.min_det_F))
        lines.append(f"inversion: {int(r.inverted_samples.max())} samples with det F <= 0 at worst; "
                     f"min det F {float(r.min_det_F.min()):.6g} (state {worst})")
    return lines


def _model_text(r) -> str:
    """One phrase naming the model: node kind and count, DOFs, shape functions and quadrature when known."""
    m = r.model
    if r.node_kind == "voxel":
        text = f"voxel nodes, {r.n_nodes} nodes, {r.n_dofs} DOF"
    elif r.node_kind == "membrane":
        text = f"membrane, {r.n_nodes} vertices, {r.n_dofs} DOF"
    else:
        text = f"{r.n_nodes} {r.node_kind} frames, {r.n_dofs} DOF"
    extra = [f"{k.replace('_', ' ')} {m[k]}" for k in ("shape_function", "quadrature", "samples") if k in m]
    if "precompute_seconds" in m:
        extra.append(f"precompute {float(m['precompute_seconds']):.3g} s")
    return text + (f" ({', '.join(extra)})" if extra else "")


def _fmt(v) -> str:
    return "[" + ", ".join(f"{x:.6g}" for x in v) + "]"
