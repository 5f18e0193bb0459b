"""Run a scene: image -> model -> boundary conditions -> solver -> :class:`Result`.

Layers are built only when needed: the mass matrix only for dynamics (the
solver builds it), densities only for gravity or dynamics, the boundary
surface once (the result file always carries it).

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

__all__ = ["simulate", "build_image", "build_materials"]

_AFFINE_MESSAGE = 'reduced affine-frame models are not implemented yet; use [nodes] kind = "voxel"'


def build_image(scene: Scene):
    """The label image of ``scene.object`` (shape or mesh voxelized, image loaded)."""
    obj = scene.object
    if obj.image is not None:
        from .image import LabelImage

        return LabelImage.load(obj.image)
    from .rasterize.voxelize import voxelize

    occupancy = bool(obj.occupancy)
    if obj.mesh is not None:
        return voxelize(obj.mesh, obj.voxel_size, occupancy=occupancy, progress=False)
    from .rasterize.primitives import Box, Cylinder, Sphere

    origin = obj.origin if obj.origin is not None else (0.0, 0.0, 0.0)
    if obj.shape == "box":
        prim = Box(obj.size, origin=origin)
    elif obj.shape == "cylinder":
        prim = Cylinder(obj.size[0], obj.size[1], origin=origin, axis=obj.axis or "z")
    else:
        prim = Sphere(obj.size[0], origin=origin)
    return voxelize(prim, obj.voxel_size, occupancy=occupancy, progress=False)


def build_materials(scene: Scene, labels_present) -> dict:
    """{label: Material} for the labels present in the image (InputError on a label without material)."""
    from .deform.materials import material

    present = sorted(int(x) for x in labels_present)
    given = {m.label for m in scene.materials}
    unused = sorted(given - set(present))
    if unused:
        raise InputError(
            f"[[material]] label {unused[0]} does not occur in the image (labels present: "
            f"{', '.join(map(str, present))}); fix the label or remove that material"
        )
    out = {}
    for label in present:
        spec = scene.material_for(label)
        out[label] = material(spec.model, **spec.material_kwargs(scene.elasticity.strain))
    return out


def _check_supported(scene: Scene) -> None:
    if scene.nodes.kind == "affine":
        raise NotImplementedError(_AFFINE_MESSAGE)
    if scene.elasticity.quadrature == "elaston":
        raise NotImplementedError(
            'elaston quadrature belongs to the reduced affine-frame models (not implemented yet); '
            'with [nodes] kind = "voxel" use quadrature = "gauss-legendre" or "midpoint"'
        )
    if scene.nodes.shape_function not in (None, "barycentric", "trilinear"):
        raise InputError(
            f'[nodes] shape_function = "{scene.nodes.shape_function}" applies to affine frames; '
            'voxel nodes are trilinear (remove the key or use "trilinear")'
        )


def simulate(scene, *, progress: bool = True, output=None) -> Result:
    """Run a scene and return its :class:`~voxflex.result.Result`.

    Parameters
    ----------
    scene : Scene or path to a scene TOML file
    progress : bool
        Show a progress bar on stderr for the solver steps (see ``voxflex._progress``).
    output : path, optional
        Where to write the result file (atomically); defaults to the scene's
        ``[output] file`` when it has one, otherwise nothing is written.

    Returns
    -------
    Result
        Times, probe positions, surface and node states, energies and solver
        statistics for the rest state and every step.

    Notes
    -----
    Only ``[nodes] kind = "voxel"`` (trilinear nodes at the voxel corners, the
    full-resolution reference) is implemented, and it is the default here —
    the SPEC's default ``"affine"`` (reduced frames) raises
    ``NotImplementedError``, as does ``quadrature = "elaston"``.

    Raises
    ------
    InputError
        Bad scene (a label without material, a probe outside the material...).
    ConvergenceError
        The solver did not converge (the message says what was tried).
    NotImplementedError
        Affine-frame nodes or elaston quadrature.
    """
    if not isinstance(scene, Scene):
        if isinstance(scene, (str, Path)):
            scene = Scene.from_toml(scene)
        else:
            raise InputError(f"simulate needs a Scene or a scene file path, got {type(scene).__name__}")
    _check_supported(scene)

    from .deform.boundary import FixedRegion, ForceRegion
    from .deform.solvers import SolverOptions, solve
    from .deform.voxel_model import VoxelModel

    image = build_image(scene)
    labels_present = np.unique(image.labels[image.labels > 0])
    materials = build_materials(scene, labels_present)
    model = VoxelModel.from_image(
        image, materials, quadrature=scene.elasticity.quadrature, use_occupancy=bool(scene.object.occupancy)
    )

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
        ForceRegion(np.array(ld.min), np.array(ld.max), np.array(ld.vector), kind="total" if ld.kind == "force" else "traction")
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
        if scene.elasticity.quadrature != "midpoint":
            raise
        # one sample per voxel leaves hourglass (zero-energy) modes: the likely cause
        raise ConvergenceError(
            f"{exc}; note: mid-point quadrature leaves hourglass (zero-energy) modes in trilinear voxels, "
            'use [elasticity] quadrature = "gauss-legendre"'
        ) from None
    finally:
        if bar is not None:
            bar.close()

    result = _make_result(scene, image, model, records, probe_map)
    target = output if output is not None else scene.output.file
    if target is not None:
        result.save(target)
    return result


def _make_result(scene, image, model, records, probe_map) -> Result:
    surf_rest, faces, vertex_node = model.boundary_surface()
    states = np.stack([np.asarray(r.q, dtype=float) for r in records])  # (T, n, 3)
    probes = {}
    if probe_map is not None:
        positions = np.stack([probe_map.apply(q) for q in states])  # (T, m, 3)
        probes = {p.name: positions[:, i, :] for i, p in enumerate(scene.probes)}
    return Result(
        time=np.array([r.time for r in records], dtype=float),
        probes=probes,
        surface_rest=surf_rest,
        surface_faces=faces,
        surface_positions=states[:, vertex_node, :],
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
        node_kind="voxel",
    )
