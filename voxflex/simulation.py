"""Run a scene: image -> model -> boundary conditions -> solver -> :class:`Result`.

The model comes from :func:`voxflex.build.model` (the registry keyed by
``[nodes] kind``), or is given; everything here talks to it through the model
protocol (:mod:`voxflex.deform.model`).  Layers are built only when needed:
the mass matrix only for dynamics (the solver builds it), densities only for
gravity or dynamics, probe mappings only for probes, the boundary surface
once (the result file always carries it).

Example
-------
>>> import voxflex as vf
>>> result = vf.simulate("examples/cantilever.toml", progress=False)   # doctest: +SKIP
>>> result.probes["tip"][-1]                                             # doctest: +SKIP
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ._version import __version__
from .errors import ConvergenceError, InputError
from .result import Result
from .scene import Scene

__all__ = ["simulate"]


def simulate(scene, *, progress: bool = True, output=None, model=None) -> Result:
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
        The solver did not converge (the message says what was tried).
    """
    if not isinstance(scene, Scene):
        if isinstance(scene, (str, Path)):
            scene = Scene.from_toml(scene)
        else:
            raise InputError(f"simulate needs a Scene or a scene file path, got {type(scene).__name__}")
    from .build import build_image, model as build_model
    from .deform.boundary import FixedRegion, ForceRegion
    from .deform.solvers import SolverOptions, solve

    if model is None:
        image = build_image(scene)
        model = build_model(scene, image=image)
    else:
        image = model.image

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

    from ._progress import progress as _bar

    bar = _bar(total=s.steps, desc="simulate", unit="step") if progress else None

    def callback(record):
        if bar is not None:
            bar.update(1)
            bar.set_postfix(newton=record.newton_iterations, refresh=False)

    try:
        records = solve(
            model,
            fixed=fixed,
            forces=forces,
            gravity=None if gravity is None else np.array(gravity),
            densities=densities,
            options=options,
            callback=callback,
        )
    except ConvergenceError as exc:
        advice = model.advice()
        if not advice:
            raise
        raise ConvergenceError(f"{exc}; note: {advice}") from None
    finally:
        if bar is not None:
            bar.close()

    result = _make_result(scene, image, model, records, probe_map)
    target = output if output is not None else scene.output.file
    if target is not None:
        result.save(target)
    return result


def _make_result(scene, image, model, records, probe_map) -> Result:
    surf_rest, faces, surf_map = model.boundary_surface()
    states = np.stack([np.asarray(r.q, dtype=float) for r in records])  # (T, n, d)
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
    )


def _contact_forces(model, states, times, scene):
    """(T, obstacles, 3) forces of the obstacles on the body at every state, or None without contact."""
    from .deform.contact import ContactModel

    if not isinstance(model, ContactModel):
        return None
    dynamic = scene.solver.kind == "implicit-euler"
    t_end = scene.solver.steps * scene.solver.dt
    fractions = [t / t_end if dynamic else t for t in times]
    return np.stack([model.contact_forces(q, fraction=f) for q, f in zip(states, fractions)])
