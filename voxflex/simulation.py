"""Run a scene: image -> model -> boundary conditions -> solver -> :class:`Result`.

The model comes from :func:`voxflex.build.model` (the registry keyed by
``[nodes] kind``), or is given; everything here talks to it through the model
protocol (:mod:`voxflex.deform.model`).  Layers are built only when needed:
the mass matrix only for dynamics (the solver builds it), densities only for
gravity or dynamics, probe mappings only for probes, the boundary surface
once (the result file always carries it).

Beyond positions the result carries, per state, the inversion statistics
(samples with det F <= 0 and the smallest det F) and the fields ``[output]
fields`` asks for (:mod:`voxflex.deform.fields`; reactions of the fixed
regions).  A run whose later step fails still returns its converged steps:
the result file is written marked incomplete and the error is raised after.

Example
-------
>>> import voxflex as vf
>>> result = vf.simulate("examples/cantilever.toml", progress=False)   # doctest: +SKIP
>>> result.probes["tip"][-1]                                             # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from pathlib import Path

import numpy as np

from ._version import __version__
from .errors import ConvergenceError, InputError
from .result import Result
from .scene import Scene

__all__ = ["simulate", "InversionWarning", "CANNOT_RECOVER"]


class InversionWarning(UserWarning):
    """Samples of a material that cannot recover from inversion (StVK, polar corotational Hooke) inverted."""


CANNOT_RECOVER = "stvk, and hooke (or hooke-orthotropic) with the polar corotational strain"
"""The materials :class:`InversionWarning` is about (their energy stays finite, and may even fall, when inverted)."""


def _cannot_recover(material) -> bool:
    """StVK (any strain) and Hooke laws over the polar corotational strain: an inverted sample
    has a finite, even decreasing, energy and is not pushed back."""
    name = getattr(material, "name", "")
    strain = getattr(getattr(material, "strain", None), "name", "")
    return name == "stvk" or (name in ("hooke", "hooke-orthotropic") and strain == "corotational")


def simulate(scene, *, progress: bool = True, output=None, model=None, verbose: bool = False,
             cache: bool = True) -> Result:
    """Run a scene and return its :class:`~voxflex.result.Result`.

    Parameters
    ----------
    scene : Scene or path to a scene TOML file
    progress : bool
        Show a progress bar on stderr for the solver steps (see ``voxflex._progress``).
    output : path, optional
        Where to write the result file (atomically); defaults to the scene's
        ``[output] file`` when it has one, otherwise nothing is written.
    model : Model, optional
        A model built beforehand (any implementation of the model protocol);
        default: ``voxflex.build.model(scene)``, the model the scene asks for.
    cache : bool
        Frame models load / store their precompute in the on-disk cache
        (:mod:`voxflex.cache`); ``False`` recomputes it.
    verbose : bool
        Log the model's size and memory estimate and one line per Newton iteration
        (residual, step length, linear solver and its iterations, seconds) on stderr.

    Returns
    -------
    Result
        Times, probe positions, surface and node states, energies and solver
        statistics for the rest state and every step.

    Raises
    ------
    InputError
        Bad scene (a label without material, a probe outside the material...).
    ConvergenceError
        The solver did not converge (the message says what was tried).  The steps
        that converged before are written to ``output`` all the same, the file
        marked incomplete (``Result.complete`` False, the message in ``error``).

    Warns
    -----
    InversionWarning
        When samples of a material that cannot recover from inversion (StVK, Hooke
        with the polar corotational strain) end a step with det F <= 0.
    """
    if not isinstance(scene, Scene):
        if isinstance(scene, (str, Path)):
            scene = Scene.from_toml(scene)
        else:
            raise InputError(f"simulate needs a Scene or a scene file path, got {type(scene).__name__}")
    from . import _progress
    from .build import build_image, model as build_model
    from .deform.boundary import FixedRegion, ForceRegion
    from .deform.solvers import SolverOptions, solve

    if model is None:
        from .resources import check as check_resources

        check_resources(scene)  # refuse a scene that cannot fit in memory before building anything
        image = build_image(scene)
        _progress.announce(_progress.image_estimate(image, scene.nodes.kind), force=verbose, quiet=not progress)
        t0 = time.perf_counter()
        model = build_model(scene, image=image, cache=cache)
        if verbose:
            _progress.log(f"model built in {time.perf_counter() - t0:.2f} s")
    else:
        image = model.image
    _progress.announce(_progress.model_estimate(model, scene.solver.steps), force=verbose, quiet=not progress)

    fixed = [
        FixedRegion(
            np.array(f.min),
            np.array(f.max),
            components=f.components,
            transform=None if f.transform is None else np.array(f.transform),
        )
        for f in scene.fixed
    ]
    forces = [
        ForceRegion(np.array(ld.min), np.array(ld.max), np.array(ld.vector), kind=ld.kind)
        for ld in scene.loads
        if ld.kind != "gravity"
    ]
    gravity = scene.gravity
    dynamic = scene.solver.kind == "implicit-euler"
    densities = {m.label: m.density for m in scene.materials} if (gravity is not None or dynamic) else None
    s = scene.solver
    # [solver] mirrors SolverOptions key for key (the scene is its file form)
    options = SolverOptions(**dataclasses.asdict(s))
    probe_map = None
    if scene.probes:
        points = np.array([p.point for p in scene.probes], dtype=float)
        probe_map = model.point_mapping(points)

    bar = _progress.progress(total=s.steps, desc="simulate", unit="step") if progress else None

    def callback(record):
        if bar is not None:
            bar.update(1)
            bar.set_postfix(newton=record.newton_iterations, refresh=False)

    def newton_callback(info):
        if bar is not None:
            bar.set_postfix(newton=info["iteration"], residual=f"{info['residual']:.1e}")
        if verbose:
            _progress.log(_progress.newton_line(info))

    target = output if output is not None else scene.output.file
    failure = None
    try:
        records = solve(
            model,
            fixed=fixed,
            forces=forces,
            gravity=None if gravity is None else np.array(gravity),
            densities=densities,
            options=options,
            callback=callback,
            newton_callback=newton_callback if (bar is not None or verbose) else None,
        )
    except ConvergenceError as exc:
        advice = model.advice()
        failure = ConvergenceError(f"{exc}; note: {advice}" if advice else str(exc))
        records = getattr(exc, "records", None)
        if not records or len(records) < 2 or target is None:
            raise failure from None
    finally:
        if bar is not None:
            bar.close()

    result = _make_result(scene, image, model, records, probe_map, fixed=fixed, forces=forces,
                          densities=densities, options=options,
                          error=None if failure is None else str(failure))
    if target is not None:
        result.save(target)
    if failure is not None:
        raise ConvergenceError(f"{failure}; the {result.n_steps} step(s) that converged were written to "
                               f"'{target}', marked incomplete") from None
    _warn_inversion(model, result)
    return result


def _warn_inversion(model, result) -> None:
    """InversionWarning when a material that cannot recover has inverted samples at some state."""
    if result.inverted_samples is None or not np.any(result.inverted_samples > 0):
        return
    bad = sorted({m.name for m in model.materials.values() if _cannot_recover(m)})
    if not bad:
        return
    state = int(np.flatnonzero(result.inverted_samples > 0)[0])
    warnings.warn(
        f"{int(result.inverted_samples[state])} samples inverted (det F <= 0; min det F "
        f"{float(result.min_det_F.min()):.3g}) from step {state} on, with {', '.join(bad)}, a material that "
        "cannot recover from inversion; use model = \"stable-neo-hookean\" or strain = \"corotational-svd\"",
        InversionWarning,
        stacklevel=3,
    )


def _make_result(scene, image, model, records, probe_map, *, fixed=(), forces=(), densities=None, options=None,
                 error=None) -> Result:
    from .deform.fields import model_fields

    surf_rest, faces, surf_map = model.boundary_surface()
    states = np.stack([np.asarray(r.q, dtype=float) for r in records])  # (T, n, d)
    names = scene.output.fields
    inverted, min_det, cells, surface, location = [], [], [], [], ""
    at_state, plastic = _plastic_states(model, len(records))
    for t, q in enumerate(states):
        at_state(t)  # plasticity: the stresses of each state with its own plastic state
        layer = model.sample_fields(q)
        det = np.linalg.det(layer["F"])
        inverted.append(int(np.count_nonzero(~(det > 0))))
        min_det.append(float(np.min(det)) if len(det) else 1.0)
        if any(n != "reaction" for n in names):
            c, f = model_fields(model, q, names)
            cells.append(c)
            surface.append(f)
            location = layer["cell_kind"]
    reactions = None
    if "reaction" in names and fixed:
        reactions = _reactions(model, records, scene, fixed, forces, densities, options, at_state)
    at_state(len(records) - 1)
    probes = {}
    if probe_map is not None:
        positions = np.stack([probe_map.apply(q) for q in states])  # (T, m, 3)
        probes = {p.name: positions[:, i, :] for i, p in enumerate(scene.probes)}
    return Result(
        time=np.array([r.time for r in records], dtype=float),
        probes=probes,
        surface_rest=surf_rest,
        surface_faces=faces,
        surface_positions=np.stack([surf_map.apply(q) for q in states]),
        nodes_rest=np.asarray(model.rest, dtype=float),
        nodes_state=states,
        energy_elastic=np.array([r.elastic_energy for r in records], dtype=float),
        energy_kinetic=np.array([r.kinetic_energy for r in records], dtype=float),
        newton_iterations=np.array([r.newton_iterations for r in records], dtype=np.int64),
        step_seconds=np.array([r.seconds for r in records], dtype=float),
        image_labels=image.labels,
        image_spacing=image.spacing,
        image_origin=image.origin,
        image_direction=image.direction,
        scene=scene.to_toml(),
        version=__version__,
        node_kind=model.node_kind,
        model=model.describe(),
        contact_force=_contact_forces(model, states, [r.time for r in records], scene),
        cable_tension=_cable_tensions(model, states, [r.time for r in records], scene),
        **_cable_polylines(model, states),
        plastic_samples=None if plastic is None else plastic[0],
        plastic_strain_max=None if plastic is None else plastic[1],
        fields={k: np.stack([f[k] for f in surface]) for k in (surface[0] if surface else {})},
        cell_fields={k: np.stack([c[k] for c in cells]) for k in (cells[0] if cells else {})},
        cell_location=location,
        reactions=reactions,
        inverted_samples=np.array(inverted, dtype=np.int64),
        min_det_F=np.array(min_det),
        complete=error is None,
        error=error or "",
    )


def _reactions(model, records, scene, fixed, forces, densities, options, at_state=lambda t: None):
    """(T, R, 3): total force each fixed region exerts on the body at every state.

    At the held DOFs the support's force on the body balances the rest:
    ``R = dE/dq - f`` (statics, ``f`` at the state's load factor) plus the
    inertia ``M (v_k - v_{k-1}) / h`` and damping ``D v_k`` terms of implicit Euler
    (D with the stiffness at the step's start, as the solver has it).  Each region's total is the
    virtual work of R on its DOFs under a unit translation of the body, so
    affine frames count their translation DOFs.
    """
    from .deform.boundary import fixed_dofs, region_forces

    dofs, owner = fixed_dofs(model, fixed)
    rest = np.asarray(model.rest, dtype=float)
    N = rest.size
    f = region_forces(model, forces).ravel() if forces else np.zeros(N)
    if scene.gravity is not None:
        f = f + model.gravity_force(densities, np.array(scene.gravity)).ravel()
    modes = []
    for k in range(3):
        T = np.hstack([np.eye(3), np.eye(3)[:, [k]]])
        modes.append((model.moved_state(T) - rest).ravel()[dofs])
    modes = np.stack(modes, axis=1)  # (k, 3)
    dynamic = scene.solver.kind == "implicit-euler"
    M = model.mass_matrix(densities, lumped=options.mass == "lumped") if dynamic else None
    out = np.zeros((len(records), len(fixed), 3))
    for t, rec in enumerate(records):
        q = np.asarray(rec.q, dtype=float)
        at_state(t)
        g = model.gradient(q).ravel()
        if dynamic:
            g = g - f
            if t > 0:
                v1, v0 = np.ravel(rec.v), np.ravel(records[t - 1].v)
                g = g + M @ ((v1 - v0) / options.dt)
                if options.rayleigh_mass or options.rayleigh_stiffness:
                    g = g + options.rayleigh_mass * (M @ v1)
                    if options.rayleigh_stiffness:
                        K0 = model.hessian(np.asarray(records[t - 1].q, dtype=float))
                        g = g + options.rayleigh_stiffness * (K0 @ v1)
        else:
            g = g - rec.time * f
        work = g[dofs, None] * modes
        for r in range(len(fixed)):
            out[t, r] = work[owner == r].sum(axis=0)
    return out


def _layer(model, cls):
    """The layer of type ``cls`` in a stack of wrapped models (``.inner`` after ``.inner``), or None."""
    while model is not None:
        if isinstance(model, cls):
            return model
        model = model.__dict__.get("inner")
    return None


def _plastic_states(model, n_states):
    """(at_state(t), measures) for the run's n states: ``at_state`` sets the plastic state of state t
    (a no-op without plasticity); measures are (yielded samples (T,), largest equivalent plastic strain
    (T,)) or None.  The run's states are the last n entries of the layer's history (the rest state is
    the state committed before the run)."""
    from .deform.plasticity import PlasticModel

    layer = _layer(model, PlasticModel)
    if layer is None:
        return (lambda t: None), None
    first = len(layer.history) - n_states
    count, peak = layer.measures()
    return (lambda t: layer.use_state(first + t)), (count[first:], peak[first:])


def _fractions(times, scene):
    """Run fraction of each recorded state: the load factor (statics) or t / t_end (implicit Euler)."""
    dynamic = scene.solver.kind == "implicit-euler"
    t_end = scene.solver.steps * scene.solver.dt
    return [t / t_end if dynamic else t for t in times]


def _contact_forces(model, states, times, scene):
    """(T, obstacles, 3) forces of the obstacles on the body at every state, or None without contact."""
    from .deform.contact import ContactModel

    layer = _layer(model, ContactModel)
    if layer is None:
        return None
    return np.stack([layer.contact_forces(q, fraction=f) for q, f in zip(states, _fractions(times, scene))])


def _cable_tensions(model, states, times, scene):
    """(T, cables) tension (N) of every cable at every state, or None without cables."""
    from .deform.cables import CableModel

    layer = _layer(model, CableModel)
    if layer is None:
        return None
    return np.stack([layer.tensions(q, fraction=f) for q, f in zip(states, _fractions(times, scene))])


def _cable_polylines(model, states) -> dict:
    """``cable_points`` (T, P, 3): every cable's anchor (if any) then its points, mapped at every state, and
    ``cable_point_cable`` (P,): the cable of each; {} without cables."""
    from .deform.cables import CableModel

    layer = _layer(model, CableModel)
    if layer is None:
        return {}
    owner = np.repeat(np.arange(len(layer.cables)), [len(c.points) for c in layer.cables])
    per_state, point_cable = [], []
    for i, c in enumerate(layer.cables):
        point_cable += [i] * (len(c.points) + (c.anchor is not None))
    for q in states:
        x = layer.mapping.apply(q)
        rows = []
        for i, c in enumerate(layer.cables):
            if c.anchor is not None:
                rows.append(np.asarray(c.anchor, dtype=float)[None])
            rows.append(x[owner == i])
        per_state.append(np.vstack(rows))
    return {"cable_points": np.stack(per_state), "cable_point_cable": np.array(point_cable, dtype=np.int64)}
