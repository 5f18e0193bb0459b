"""The layout of a result file: its format name, per-state datasets, static parts and totals.

One definition shared by :class:`voxflex.result.Result` (reading, saving) and
:class:`voxflex.result.ResultWriter` (streaming); no heavy imports.
"""

from __future__ import annotations

__all__ = ["SERIES", "SERIES_GROUPS", "STATIC", "TOTALS"]

_FORMAT = "voxflex-result"

TOTALS = {"steps": int, "newton_iterations": int, "step_seconds": float, "inverted_samples": int,
          "min_det_F": float, "min_det_F_step": int}
"""Keys (and types) of :attr:`Result.totals`, the ``/stats`` attributes of a result file."""

SERIES = (
    ("time", "time"),
    ("surface_positions", "surface/positions"),
    ("nodes_state", "nodes/state"),
    ("energy_elastic", "energy/elastic"),
    ("energy_kinetic", "energy/kinetic"),
    ("newton_iterations", "stats/newton_iterations"),
    ("step_seconds", "stats/step_seconds"),
    ("step", "stats/step"),
    ("inverted_samples", "stats/inverted_samples"),
    ("min_det_F", "stats/min_det_F"),
    ("reactions", "reactions/force"),
    ("contact_force", "contact/force"),
    ("cable_tension", "cable/tension"),
    ("cable_points", "cable/points"),
    ("plastic_samples", "plasticity/yielded_samples"),
    ("plastic_strain_max", "plasticity/max_strain"),
    ("node_points", "nodes/points"),
    ("fraction", "stats/fraction"),
)
"""(Result attribute, file path) of every per-state dataset (T, ...) that is not a named group."""

SERIES_GROUPS = (("probes", "probes/"), ("probe_displacement", "probe_displacements/"),
                 ("fields", "surface/fields/"), ("cell_fields", "fields/"))
"""(Result attribute, path prefix) of the per-state datasets held in named groups (one per name)."""

_INT_SERIES = frozenset({"stats/newton_iterations", "stats/inverted_samples", "stats/step",
                         "plasticity/yielded_samples"})
_CHUNK_BYTES = 1 << 20  # about 1 MiB per compressed chunk (HDF5's chunk cache holds one per dataset)
_BLOCK_BYTES = 4 << 20  # states buffered before a write

STATIC = ("version", "scene", "node_kind", "model", "surface_rest", "surface_faces", "nodes_rest", "image_labels",
          "image_spacing", "image_origin", "image_direction", "cell_location", "cable_point_cable", "problem")
"""The parts of a result that do not change over the states (written once, before any state)."""
