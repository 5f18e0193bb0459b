"""Build what a scene asks for: its label image, its materials and its model.

:func:`model` looks the scene's ``[nodes] kind`` up in :data:`MODEL_BUILDERS`
and returns a model of the protocol in :mod:`voxflex.deform.model`; the
solvers, loads, results and renders only ever talk to that protocol.

Example
-------
>>> import voxflex as vf
>>> scene = vf.Scene.from_toml("examples/cantilever.toml")   # doctest: +SKIP
>>> m = vf.model(scene)                                      # doctest: +SKIP
>>> m.node_kind, m.rest.shape                                # doctest: +SKIP
('voxel', (..., 3))
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .errors import InputError, check_choice
from .scene import Scene

__all__ = ["model", "build_image", "build_materials", "MODEL_BUILDERS", "ComponentsDroppedWarning"]


class ComponentsDroppedWarning(UserWarning):
    """Material components were dropped by [object] keep / min_component_voxels."""


def build_image(scene: Scene):
    """The label image of ``scene.object`` (shape or mesh voxelized, image loaded), with the
    components that ``keep`` / ``min_component_voxels`` drop removed (with a warning); for a
    membrane, the voxels its mesh passes through (:func:`~voxflex.deform.membrane_model.footprint_image`)."""
    if scene.nodes.kind == "membrane":
        from .deform.membrane_model import footprint_image

        return footprint_image(*_membrane_mesh(scene), scene.object.voxel_size)
    return _drop_components(_raw_image(scene), scene.object.keep, scene.object.min_component_voxels)


def _drop_components(image, keep: str, min_voxels: int):
    if keep == "all" and min_voxels <= 1:
        return image
    import dataclasses
    import warnings

    comps, n = image.connected_components(connectivity="face")
    if n == 0:
        return image
    sizes = np.bincount(comps.ravel(), minlength=n + 1)[1:]
    drop = sizes < min_voxels
    if keep == "largest":
        drop |= np.arange(n) != int(np.argmax(sizes))
    if not np.any(drop):
        return image
    if np.all(drop):
        raise InputError(
            f"[object] min_component_voxels = {min_voxels} drops every material component (the largest has "
            f"{int(sizes.max())} voxels); lower it"
        )
    gone = np.isin(comps, np.flatnonzero(drop) + 1)
    labels = np.where(gone, 0, image.labels).astype(image.labels.dtype)
    occupancy = None if image.occupancy is None else np.where(gone, 0.0, image.occupancy)
    warnings.warn(
        f"dropped {int(drop.sum())} of {n} material components ({int(sizes[drop].sum())} voxels) by "
        f"[object] keep = \"{keep}\", min_component_voxels = {min_voxels}",
        ComponentsDroppedWarning,
        stacklevel=3,
    )
    return dataclasses.replace(image, labels=labels, occupancy=occupancy)


def _raw_image(scene: Scene):
    obj = scene.object
    if obj.image is not None:
        from .image import LabelImage
        from .rasterize.orient import turn_up

        return turn_up(LabelImage.load(obj.image), obj.up)  # [object] up: that axis becomes +z
    from .rasterize.voxelize import voxelize

    occupancy = bool(obj.occupancy)
    if obj.mesh is not None:
        return voxelize(obj.mesh, obj.voxel_size, occupancy=occupancy, progress=False, up=obj.up)
    from .rasterize.primitives import Box, Cylinder, Sphere

    origin = obj.origin if obj.origin is not None else (0.0, 0.0, 0.0)
    if obj.shape == "box":
        prim = Box(obj.size, origin=origin)
    elif obj.shape == "cylinder":
        prim = Cylinder(obj.size[0], obj.size[1], origin=origin, axis=obj.axis or "z")
    else:
        prim = Sphere(obj.size[0], origin=origin)
    return voxelize(prim, obj.voxel_size, occupancy=occupancy, progress=False, up=obj.up)


def build_materials(scene: Scene, labels_present) -> dict:
    """{label: Material} for the labels present in the image (InputError on a label without material)."""
    from .deform.materials import material

    present = sorted(int(x) for x in labels_present)
    if not present:
        raise InputError("the image has no material (every label is 0); voxelize a non-empty object")
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
        if spec.yield_strain is not None:
            out[label] = _plastic(out[label], spec, label)
    return out


def _plastic(base, spec, label):
    """The plastic material of a ``[[material]]`` with ``yield_strain`` (sized later by its model)."""
    from .deform.plasticity import PlasticMaterial

    try:
        return PlasticMaterial(base, None, yield_strain=spec.yield_strain, hardening=spec.hardening or 0.0)
    except InputError as exc:
        raise InputError(f"[[material]] label {label}: {exc}") from None


_PLASTIC_SURFACE_FIELDS = ("stress", "von-mises", "energy-density")
"""Result fields that evaluate the materials on the frames' surface layer, which has no plastic state."""


def _with_plasticity(built, scene: Scene):
    """``built`` wrapped in :class:`~voxflex.deform.plasticity.PlasticModel` when a label is plastic."""
    from .deform.plasticity import with_plasticity

    plastic = [m.label for m in scene.materials if m.yield_strain is not None]
    if not plastic:
        return built
    if scene.nodes.kind == "rigid":
        raise InputError('plasticity ([material] yield_strain) needs deformable nodes: use [nodes] kind = "affine" '
                         'or "voxel"')
    bad = [f for f in scene.output.fields if f in _PLASTIC_SURFACE_FIELDS]
    if bad and scene.nodes.kind != "voxel":
        raise InputError(f'[output] fields "{bad[0]}" with plasticity needs [nodes] kind = "voxel" (the frames\' '
                         "surface layer carries no plastic state); remove it or use voxel nodes")
    return with_plasticity(built)


def _voxel_model(scene: Scene, image, materials):
    from .deform.voxel_model import VoxelModel

    quadrature = scene.elasticity.quadrature
    if quadrature == "elaston":
        raise InputError(
            'elaston quadrature needs regions of several voxels (frame models); with [nodes] kind = "voxel" '
            'use quadrature = "gauss-legendre" or "midpoint"'
        )
    sf = scene.nodes.shape_function
    if sf not in (None, "trilinear"):
        raise InputError(
            f'[nodes] shape_function = "{sf}" applies to frames; voxel nodes are trilinear '
            '(remove the key or use "trilinear")'
        )
    el = scene.elasticity
    return VoxelModel.from_image(image, materials, quadrature=quadrature, use_occupancy=bool(scene.object.occupancy),
                                 volumetric=el.volumetric, hourglass=el.hourglass)


DEFAULT_FRAMES = 20
"""Frames placed when a scene does not say ``[nodes] count`` (fewer when the object has fewer voxels)."""

SAMPLES_PER_FRAME = 20
"""Mid-point / elaston samples per frame when a scene does not say ``[elasticity] samples``.

Too few samples per frame leave near-mechanisms that the exact rank check does
not see: the linear cantilever 32x8x8 with 50 frames sags -0.681, -0.453 and
-0.409 m with 200, 500 and 1000 samples against -0.388 m for the voxel model
(the soft side of it is spurious). At 20 per frame the error is on the stiff
side of the reference or within a few per cent (20 frames, 400 samples: -0.350 m).
"""


def _frame_model(scene: Scene, image, materials, *, cache: bool = True):
    """Affine frames: placement, shape functions and samples from the image, then the frame model.

    The precompute (frames, blended weights, samples) is loaded from the on-disk
    cache (:mod:`voxflex.cache`) when a run with the same image and settings made
    it before; ``precompute_seconds`` in the result's ``/model`` is what this run
    spent (``precompute_cached`` says whether it was loaded).
    """
    import time

    from . import cache as disk
    from .deform.frame_model import FrameModel

    t0 = time.perf_counter()
    nodes = scene.nodes
    compliance = None
    if nodes.distance == "compliance":
        compliance = {label: float(m.parameters.get("young", np.nan)) for label, m in materials.items()}
        bad = [label for label, E in compliance.items() if not np.isfinite(E) or E <= 0]
        if bad:
            raise InputError(f'[nodes] distance = "compliance" needs a Young\'s modulus for label(s) {bad}; '
                             'give young (or use distance = "geodesic")')
    kind = nodes.shape_function or "natural-neighbour"
    fixed = [(np.asarray(f.min, dtype=float), np.asarray(f.max, dtype=float)) for f in scene.fixed]
    count = nodes.count if nodes.count is not None else min(DEFAULT_FRAMES, int((image.labels > 0).sum()))
    quadrature = scene.elasticity.quadrature
    n_samples = scene.elasticity.samples if scene.elasticity.samples is not None else SAMPLES_PER_FRAME * count
    occupancy = bool(scene.object.occupancy)
    settings = {"count": count, "positions": nodes.positions, "kind": kind, "parents": nodes.parents,
                "distance": nodes.distance, "seed": nodes.seed, "compliance": compliance,
                "fixed": [(lo.tolist(), hi.tolist(), f.components) for (lo, hi), f in zip(fixed, scene.fixed)],
                "quadrature": quadrature, "samples": n_samples, "occupancy": occupancy}
    use_cache = cache and disk.enabled()
    key = None
    if use_cache:
        occ = np.zeros(0) if image.occupancy is None else np.asarray(image.occupancy)
        key = disk.key_of(disk.code_fingerprint(), image.labels, np.asarray(image.spacing),
                          np.asarray(image.origin), np.asarray(image.direction), occ, settings)
    stored = disk.load("frames", key) if use_cache else None
    softest = None
    if stored is not None:
        frames, sf, samples = _from_store(image, stored, kind, nodes.parents)
        softest = float(stored["softest"]) if "softest" in stored else None
    else:
        frames, sf, samples = _precompute(image, count, kind, fixed, nodes, compliance, quadrature,
                                          n_samples, occupancy)
    info = {"shape_function": kind, "parents": int(nodes.parents), "distance": nodes.distance,
            "precompute_cached": stored is not None}
    # [elasticity] volumetric: "reduced" asks for F-bar / B-bar over each frame's cell; "auto" stays "full"
    # for frames: measured (benchmarks/bench_locking.py) the reduced term removes the locking but makes
    # the cantilever 12-74 % softer than the beam trend, and at nu = 0.45 (the default scene) it is no closer
    volumetric = scene.elasticity.volumetric
    model = FrameModel.from_image(image, frames, sf, materials, samples=samples, use_occupancy=occupancy, info=info,
                                  volumetric="full" if volumetric == "auto" else volumetric)
    if quadrature != "gauss-legendre":
        import warnings

        from .deform.modes import SpuriousModesWarning, check_modes, free_body_stiffness

        K = free_body_stiffness(frames, samples)  # once: the rank check, the refusal and the softest mode
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", SpuriousModesWarning)
            zero = check_modes(frames, samples, stiffness=K)  # warns, naming how many samples to add
        if zero > 6:
            _refuse_static_mechanism(scene, model, K, samples, zero - 6)
        elif stored is None:
            softest = _softest_mode(scene, image, model, frames, sf, samples, occupancy, K)
        for w in caught:
            warnings.warn(w.message, w.category, stacklevel=2)
        if zero <= 6 and softest is not None:
            model.info["softest_mode"] = softest
            _judge_soft_modes(scene, samples, softest)
    if use_cache and stored is None:
        extra = {} if softest is None else {"softest": np.float64(softest)}
        disk.save("frames", key, {**_to_store(frames, sf, samples), **extra})
    model.info["precompute_seconds"] = time.perf_counter() - t0
    return model


def _static_frames(scene: Scene) -> bool:
    """A static affine scene without obstacles or cables: the scenes judged before solving by the
    frame quadrature's modes (those layers may hold the modes; dynamics has mass)."""
    return (scene.nodes.kind == "affine" and scene.solver.kind == "static" and not scene.obstacles
            and not getattr(scene, "cables", ()))


def _held(scene: Scene, model) -> np.ndarray:
    held = set()
    for f in scene.fixed:
        held.update(int(d) for d in model.held_dofs(f.min, f.max, f.components))
    return np.fromiter(sorted(held), dtype=np.int64, count=len(held))


def _softest_mode(scene: Scene, image, model, frames, sf, samples, occupancy, K) -> float | None:
    """The samples' softest deformation against one mid-point sample per voxel
    (:func:`voxflex.deform.modes.softest_mode`) over the DOFs the scene does not hold (a free
    body: all, rigid modes deflated).  About 0.1 s for the default scene; stored in the cache entry."""
    import dataclasses

    from .deform.frame_model import voxel_samples
    from .deform.modes import softest_mode
    from .voronoi.shape_functions import keep_largest

    reference = voxel_samples(image, sf, rule="midpoint", use_occupancy=occupancy)
    reference = dataclasses.replace(reference, values=keep_largest(reference.values, scene.nodes.parents))
    held = _held(scene, model)
    free = np.setdiff1d(np.arange(12 * len(frames)), held) if len(held) else None
    return softest_mode(frames, samples, reference, free, stiffness=K)


def _judge_soft_modes(scene: Scene, samples, softest: float) -> None:
    """Refuse a static affine scene whose samples leave a near-zero-energy mode; warn for the others."""
    import warnings

    from .deform.modes import SOFT_RATIO, SpuriousModesWarning

    if softest >= SOFT_RATIO:
        return
    what = (f"the {len(samples.volume)} {samples.kind} samples leave a deformation mode {1 / max(softest, 1e-300):.0f} "
            f"times softer than one sample per voxel would (limit {1 / SOFT_RATIO:.0f}): a spurious near-zero-energy "
            "mode")
    fix = 'raise [elasticity] samples, use fewer frames, or quadrature = "gauss-legendre"'
    if _static_frames(scene):
        raise InputError(f"{what}, so the static answer would be far too soft; {fix}")
    warnings.warn(f"{what}; results may be far too soft; {fix}", SpuriousModesWarning, stacklevel=3)


def _refuse_static_mechanism(scene: Scene, model, K, samples, spurious: int) -> None:
    """InputError when the samples leave zero-energy modes among the frames a static scene does not hold.

    The free body's spurious modes (:func:`voxflex.deform.modes.check_modes`) are harmless where they
    only move held frames; with any left among the free ones, static equilibrium is not unique and
    Newton cannot converge (it did not, after minutes of cut load steps).  Only static affine scenes
    without obstacles or cables are judged here (those layers may hold such modes; dynamics has mass).
    ``K``: the free body's stiffness (:func:`voxflex.deform.modes.free_body_stiffness`).
    """
    if not _static_frames(scene):
        return
    from ._blas import one_thread

    free = np.setdiff1d(np.arange(K.shape[0]), _held(scene, model))
    with one_thread():
        ev = np.linalg.eigvalsh(K[np.ix_(free, free)])
    zero = int(np.count_nonzero(ev <= 1e-8 * max(float(ev.max(initial=0.0)), 1e-300)))
    if zero:
        raise InputError(
            f"the {len(samples.volume)} {samples.kind} samples leave {zero} zero-energy mode(s) among the frames "
            f"the scene does not hold ({spurious} in the free body), so static equilibrium is not unique; raise "
            '[elasticity] samples, use fewer frames, or quadrature = "gauss-legendre"')


def _precompute(image, count, kind, fixed, nodes, compliance, quadrature, n_samples, occupancy):
    """Frames, blended shape functions and samples (pruned to ``parents``) of an image."""
    import dataclasses

    from .deform.frame_model import voxel_samples
    from .voronoi import place_frames, shape_function
    from .voronoi.shape_functions import keep_largest

    positions = None if nodes.positions is None else np.asarray(nodes.positions, dtype=float)
    frames = place_frames(image, count, positions=positions, fixed=fixed, seed=nodes.seed,
                          distance=nodes.distance, compliance=compliance)
    sf = shape_function(image, frames, kind=kind, parents=nodes.parents, distance=nodes.distance,
                        compliance=compliance, seed_owner=_clamp_owners(image, frames, fixed))
    if quadrature == "gauss-legendre":
        samples = voxel_samples(image, sf, rule="gauss-legendre", use_occupancy=occupancy)
    else:
        from .sampling import sample

        samples = sample(image, sf, kind=quadrature, count=n_samples, seed=nodes.seed)
    # at most `parents` frames per sample: the blended weights of a sample (and the union over a
    # region) have more, and the stiffness costs ~432 P^2 flops per sample
    samples = dataclasses.replace(samples, values=keep_largest(samples.values, nodes.parents))
    return frames, sf, samples


def _to_store(frames, sf, samples) -> dict:
    W = sf._smoothed()._W
    v = samples.values
    out = {"frames": frames, "W_indptr": W.indptr, "W_indices": W.indices, "W_data": W.data,
           "kind": np.array(samples.kind), "points": samples.points, "volume": samples.volume,
           "label": samples.label, "index": v.index, "w": v.w, "dw": v.dw,
           "ddw": v.ddw if v.ddw is not None else np.zeros((0,))}
    if hasattr(samples, "moments"):
        out["moments"] = samples.moments
        out["region"] = samples.region
    return out


def _from_store(image, d, kind, parents):
    """Rebuild (frames, shape function, samples) from a cache entry."""
    import scipy.sparse as sp

    from .deform.frame_model import VoxelSamples
    from .voronoi.shape_function import ShapeFunction
    from .voronoi.shape_functions import ShapeValues
    from .voronoi.smoothing import SmoothWeights

    frames = d["frames"]
    n = len(frames)
    W = sp.csr_matrix((d["W_data"], d["W_indices"], d["W_indptr"]), shape=(int((image.labels > 0).sum()), n))
    smooth = SmoothWeights.from_csr(image, W)
    sf = ShapeFunction(frames=frames, kind="sibson" if kind == "natural-neighbour" else kind, parents=parents,
                       image=image, smooth=True, _cache={"smooth": smooth})
    ddw = d["ddw"] if d["ddw"].size else None
    values = ShapeValues(index=d["index"], w=d["w"], dw=d["dw"], ddw=ddw, rest=d["points"], n_nodes=n)
    skind = str(d["kind"])
    if "moments" in d:
        from .sampling.samples import Samples

        samples = Samples(kind=skind, points=d["points"], volume=d["volume"], moments=d["moments"],
                          label=d["label"], region=d["region"], values=values)
    else:
        samples = VoxelSamples(skind, d["points"], d["volume"], d["label"], values)
    return frames, sf, samples


def _clamp_owners(image, frames, boxes):
    """Voxels each fixed region touches, owned outright by the nearest frame it holds (-1 elsewhere).

    A fixed region holds the frames in the voxels it touches; making those
    frames own every voxel the region touches means every material point the
    region touches moves with held frames only, so a clamp holds the whole
    face instead of a frame's neighbourhood (on a cantilever the loose clamp
    made the frame model 30-100 % too soft).
    """
    from .voronoi.placement import voxels_touching_box

    owner = -np.ones(image.shape, dtype=np.int64)
    if not boxes:
        return None
    material = image.labels > 0
    fi = np.clip(np.floor(image.world_to_index(frames) + 1e-9).astype(np.int64), 0, np.asarray(image.shape) - 1)
    for lo, hi in boxes:
        touch = voxels_touching_box(image, lo, hi) & material
        held = np.flatnonzero(touch[fi[:, 0], fi[:, 1], fi[:, 2]] | np.all((frames >= lo) & (frames <= hi), axis=1))
        if len(held) == 0 or not np.any(touch):
            continue
        c = image.index_to_world(np.argwhere(touch) + 0.5)
        near = held[np.argmin(((c[:, None, :] - frames[held][None, :, :]) ** 2).sum(-1), axis=1)]
        owner[touch] = near
    return owner


def _rigid_model(scene: Scene, image, materials, *, cache: bool = True):
    """Rigid frames: the affine frame model of the scene (same placement, weights, samples and
    cache) restricted to rotations (:class:`~voxflex.deform.rigid_frame_model.RigidFrameModel`).

    Refused (InputError, naming the fix): dynamics (the mass in rotation coordinates depends on
    the state), obstacles, force and traction loads (their moments turn with the frames, the
    solvers hold generalised forces constant), and a moved sliding support of one component whose
    rotation is not about that axis (the frame keeps row c of R only by turning about axis c).
    """
    from .deform.rigid_frame_model import RigidFrameModel

    fix = 'use [nodes] kind = "affine"'
    if scene.solver.kind != "static":
        raise InputError(f'rigid frames run static scenes only (their mass matrix depends on the rotation); {fix} '
                         'for dynamics')
    if scene.obstacles:
        raise InputError(f"rigid frames do not take [[obstacle]] contact yet; {fix}")
    pushed = [ld.kind for ld in scene.loads if ld.kind != "gravity"]
    if pushed:
        raise InputError(f'rigid frames take gravity loads only ([[load]] kind = "{pushed[0]}": its moment turns '
                         f"with the frames and the solver holds forces constant); {fix}")
    for i, f in enumerate(scene.fixed):
        if f.transform is None or len(f.components) != 1:
            continue
        c = "xyz".index(f.components)
        R = np.asarray(f.transform, dtype=float)[:, :3]
        if np.abs(R[c] - np.eye(3)[c]).max() > 1e-9:
            raise InputError(f'[[fixed]] #{i + 1} moves a sliding support (components = "{f.components}") by a '
                             f"rotation that is not about the {f.components} axis, which rigid frames cannot "
                             f'follow; hold more components, or {fix}')
    inner = _frame_model(scene, image, materials, cache=cache)
    densities = {int(label): float(scene.material_for(int(label)).density) for label in materials}
    return RigidFrameModel(inner, densities=densities)


def _membrane_mesh(scene: Scene):
    """(points (n, 3), triangles (m, 3)) of a membrane scene: a disk or rectangle made at
    ``voxel_size`` (the target edge length), or the mesh file as it is."""
    from .deform.membrane_model import disk_mesh, load_membrane_mesh, rectangle_mesh

    obj = scene.object
    if obj.mesh is not None:
        return load_membrane_mesh(obj.mesh, up=obj.up)
    if obj.up != "z":
        raise InputError('[object] up applies to a membrane mesh file; a disk or rectangle lies in z = origin_z '
                         "(remove up)")
    origin = np.asarray(obj.origin if obj.origin is not None else (0.0, 0.0, 0.0), dtype=float)
    if obj.shape == "disk":
        r = obj.size[0]
        return disk_mesh(r, obj.voxel_size, center=origin + np.array([r, r, 0.0]))
    return rectangle_mesh(obj.size, obj.voxel_size, origin=origin)


def _membrane_model(scene: Scene, image, materials):
    """The membrane of the scene (:class:`~voxflex.deform.membrane_model.MembraneModel`).

    The [[material]] (stvk: young, poisson, density) and ``[membrane] thickness``
    make the plane-stress StVK membrane; ``[[load]] kind = "pressure"`` loads
    add up to its pressure (ramped with the load factor in static runs, full in
    dynamics).  Refused: a pressure on a membrane whose open rim is not held in all
    three components (by ``rim = "clamped"`` or ``[[fixed]]`` regions), since
    the follower pressure is conservative only then.
    """
    from .deform.membrane import StVKMembrane
    from .deform.membrane_model import MembraneModel, open_rim

    spec = scene.materials[0]
    law = StVKMembrane(young=spec.young, poisson=spec.poisson, thickness=scene.membrane.thickness)
    points, triangles = _membrane_mesh(scene)
    pressure = float(sum(ld.pressure for ld in scene.loads if ld.kind == "pressure"))
    rim = open_rim(triangles)
    clamped = rim if scene.membrane.rim == "clamped" else None
    model = MembraneModel(points, triangles, law, density=spec.density, pressure=pressure,
                          pressure_ramp=scene.solver.kind == "static", clamped=clamped,
                          voxel_size=scene.object.voxel_size)
    model._image = image
    if pressure != 0.0 and clamped is None and len(rim):
        held = set()
        for f in scene.fixed:
            held.update(int(d) for d in model.held_dofs(f.min, f.max, f.components))
        loose = [int(v) for v in rim if not all(3 * int(model._index_of[v]) + k in held for k in range(3))]
        if loose:
            raise InputError(f"a pressure is conservative only on a clamped or closed membrane, and {len(loose)} of "
                             f"the {len(rim)} rim vertices are not held (e.g. {points[loose[0]].tolist()}); set "
                             '[membrane] rim = "clamped" or cover the rim with [[fixed]] regions')
    return model


def _not_implemented(kind: str):
    def builder(scene, image, materials):
        built = [k for k, b in MODEL_BUILDERS.items() if not getattr(b, "not_implemented", False)]
        raise NotImplementedError(
            f'[nodes] kind = "{kind}" is not implemented yet; use {" or ".join(repr(k) for k in built)}'
        )

    builder.not_implemented = True

    return builder


MODEL_BUILDERS: dict[str, Callable] = {
    "voxel": _voxel_model,
    "affine": _frame_model,
    "rigid": _rigid_model,
    "membrane": _membrane_model,
}
"""Registry: ``[nodes] kind`` -> builder ``(scene, image, materials) -> Model``."""


def model(scene, *, image=None, cache: bool = True):
    """The model ``scene`` asks for (``[nodes] kind``), built on its image.

    Parameters
    ----------
    scene : Scene or path to a scene file
    image : LabelImage, optional
        The scene's image when already built (default: :func:`build_image`).
    cache : bool
        Frame models: load / store their precompute in the on-disk cache
        (:mod:`voxflex.cache`; ``False`` recomputes).

    Returns
    -------
    Model
        A :class:`~voxflex.deform.voxel_model.VoxelModel` or a frame model.

    Raises
    ------
    InputError
        A label without material, a setting the node kind does not take.
    NotImplementedError
        A node kind that is registered but not built yet (named in the message).
    """
    if not isinstance(scene, Scene):
        scene = Scene.from_toml(scene)
    check_choice("node kind", scene.nodes.kind, MODEL_BUILDERS)
    if image is None:
        image = build_image(scene)
    labels_present = np.unique(image.labels[image.labels > 0])
    materials = build_materials(scene, labels_present)
    from .deform.cables import with_cables
    from .deform.contact import with_contact

    # the collision layer is built only when the scene has obstacles, the cable layer when it has cables
    builder = MODEL_BUILDERS[scene.nodes.kind]
    built = builder(scene, image, materials, cache=cache) if builder in (_frame_model, _rigid_model) else builder(scene, image, materials)
    return with_cables(with_contact(_with_plasticity(built, scene), scene), scene)
