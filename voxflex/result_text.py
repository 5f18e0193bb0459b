"""Results in words: what ``voxflex info`` prints of a result file and ``voxflex simulate`` of a run."""

from __future__ import annotations

import numpy as np

from .result import Result

__all__ = ["describe_result", "field_lines"]


def describe_result(path) -> str:
    """A short human-readable summary of a result file (used by ``voxflex info``)."""
    with np.errstate(over="ignore", invalid="ignore"):  # a damaged file's 1e300 positions: described, not warned
        return _describe(Result.load(path), path)


def _describe(r, path) -> str:
    T = r.n_states
    totals = r.run_totals()
    labels, counts = np.unique(r.image_labels[r.image_labels > 0], return_counts=True)
    lines = [
        f"result: {path} (voxflex {r.version})",
        f"  image: {' x '.join(map(str, r.image_labels.shape))} voxels, spacing {r.image_spacing.tolist()} m, "
        f"{r.n_voxels} occupied ({', '.join(f'label {a}: {b}' for a, b in zip(labels, counts))})",
        f"  model: {_model_text(r)}; surface {r.surface_rest.shape[0]} vertices, {r.surface_faces.shape[0]} triangles",
        f"  states: {T} ({_states_text(r)}; time {r.time[0]:g} .. {r.time[-1]:g}); "
        f"Newton iterations {totals['newton_iterations']}, solve time {totals['step_seconds']:.3g} s",
        f"  energy at the end: elastic {r.energy_elastic[-1]:.6g} J, kinetic {r.energy_kinetic[-1]:.6g} J",
        f"  max surface displacement at the end: {np.linalg.norm(r.displacement(-1), axis=1).max():.6g} m",
    ]
    moved = r.probe_displacements(-1)
    for name, pos in r.probes.items():
        u = moved[name]
        lines.append(
            f"  probe {name}: rest {_fmt(pos[0])} -> final {_fmt(pos[-1])} (displacement {_fmt(u)})"
        )
    lines += [f"  {line}" for line in field_lines(r)]
    if not r.complete:
        lines.append(f"  INCOMPLETE: the run failed after step {r.n_steps}: {r.error}")
    series = [("surface positions", r.surface_positions), ("node states", r.nodes_state), ("times", r.time),
              ("elastic energies", r.energy_elastic), ("kinetic energies", r.energy_kinetic)]
    series += [(f"probe {name}'s positions", v) for name, v in r.probes.items()]
    series += [(f"probe {name}'s displacements", v) for name, v in r.probe_displacement.items()]
    for what, values in series:  # a run records finite states only: these were edited or damaged since
        bad = np.flatnonzero(~np.isfinite(values.reshape(T, -1)).all(axis=1))
        if len(bad):
            lines.append(f"  DAMAGED: the {what} of {len(bad)} state(s) are not finite (first: state {bad[0]})")
    if np.any(np.diff(r.time) < 0):
        lines.append(f"  DAMAGED: the times decrease (first after state {int(np.flatnonzero(np.diff(r.time) < 0)[0])})")
    return "\n".join(lines)


def field_lines(r) -> list:
    """Lines naming the fields, reactions and inversion statistics a result carries (info and summaries)."""
    lines = []
    if r.cell_fields:
        per = r.cell_location.rstrip("s") or "cell"
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
        totals = r.run_totals()
        lines.append(f"inversion: {totals['inverted_samples']} samples with det F <= 0 at worst; "
                     f"min det F {totals['min_det_F']:.6g} (step {totals['min_det_F_step']})")
    return lines


def _states_text(r) -> str:
    """'the rest state and N steps', or which steps the states are when some are not held."""
    if r.n_states - 1 == r.n_steps:
        return f"the rest state and {r.n_steps} steps"
    return f"the rest state and {r.n_states - 1} of {r.n_steps} steps: {_steps_list(r.step[1:])}"


def _steps_list(steps) -> str:
    steps = [int(k) for k in steps]
    if len(steps) <= 4:
        return "steps " + ", ".join(map(str, steps))
    stride = np.unique(np.diff(steps[:-1]))
    every = f"every {int(stride[0])} steps, " if len(stride) == 1 else ""
    return f"steps {steps[0]}, {steps[1]} .. {steps[-1]} ({every}{len(steps)} states)"


def _model_text(r) -> str:
    """One phrase naming the model: node count (as its kind says them), DOFs, shape functions, quadrature,
    the frame builder's sample count and why (``samples_chosen``) when known."""
    m = r.model
    text = f"{r.n_nodes} {m.get('nodes', r.node_kind + ' nodes')}, {r.n_dofs} DOF"
    extra = [f"{k.replace('_', ' ')} {m[k]}" for k in ("shape_function", "quadrature", "samples", "regions",
                                                        "hourglass", "volumetric") if k in m]
    if "precompute_seconds" in m:
        extra.append(f"precompute {float(m['precompute_seconds']):.3g} s")
    text += f" ({', '.join(extra)})" if extra else ""
    if "shape_function_chosen" in m:
        text += f"; shape function chosen: {m['shape_function_chosen']}"
    if "samples_chosen" in m:
        text += f"; samples chosen: {m['samples_chosen']}"
    return text


def _fmt(v) -> str:
    return "[" + ", ".join(f"{x:.6g}" for x in v) + "]"
