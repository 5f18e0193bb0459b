"""Build what a scene asks for: its label image, its materials and its model.

:func:`model` looks the scene's ``[nodes] kind`` up in the registry of node
kinds (:mod:`voxflex.deform.models.kinds`), lets the kind build its model and
adds the layers the scene asks for (plasticity, contact, cables); the result
is a model of the protocol in :mod:`voxflex.deform.models.protocol`, the only
thing solvers, loads, results and renders talk to.

Example
-------
>>> import voxflex as vf
>>> scene = vf.Scene.from_toml("examples/cantilever.toml")   # doctest: +SKIP
>>> m = vf.model(scene)                                      # doctest: +SKIP
>>> m.node_kind, m.rest.shape                                # doctest: +SKIP
('voxel', (..., 3))
"""

from __future__ import annotations

import numpy as np

from .deform.models.kinds import node_kind
from .errors import InputError
from .scene import Scene

__all__ = ["model", "build_image", "build_materials", "ComponentsDroppedWarning"]


class ComponentsDroppedWarning(UserWarning):
    """Material components were dropped by [object] keep / min_component_voxels."""


def build_image(scene: Scene):
    """The label image of ``scene.object`` (shape or mesh voxelized, image loaded), with the
    components that ``keep`` / ``min_component_voxels`` drop removed (with a warning); for a
    kind whose image is its own (a membrane: the voxels its mesh passes through), that image."""
    own = node_kind(scene.nodes.kind).build_image(scene)
    if own is not None:
        return own
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
    from .rasterize.voxelizer import voxelize

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
    from .deform.materials.constitutive import material

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
    from .deform.layers.plasticity import PlasticMaterial

    try:
        return PlasticMaterial(base, None, yield_strain=spec.yield_strain, hardening=spec.hardening or 0.0)
    except InputError as exc:
        raise InputError(f"[[material]] label {label}: {exc}") from None


def _with_plasticity(built, scene: Scene):
    """``built`` wrapped in :class:`~voxflex.deform.layers.plasticity.PlasticModel` when a label is plastic
    (the scene's node kind has said it takes plasticity when the scene was made)."""
    from .deform.layers.plasticity import with_plasticity

    if not any(m.yield_strain is not None for m in scene.materials):
        return built
    return with_plasticity(built)


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
        The kind's model (:class:`~voxflex.deform.models.voxel.model.VoxelModel`, a frame model ...)
        with the layers the scene asks for.

    Raises
    ------
    InputError
        A label without material, a setting the node kind does not take.
    """
    from .image import LabelImage
    from .scene import as_scene

    scene = as_scene(scene, "vf.model")
    kind = node_kind(scene.nodes.kind)
    if image is None:
        image = build_image(scene)
    elif not isinstance(image, LabelImage):
        raise InputError(f"image must be the scene's LabelImage (voxflex.build.build_image(scene)), got "
                         f"{type(image).__name__}")
    labels_present = np.unique(image.labels[image.labels > 0])
    materials = build_materials(scene, labels_present)
    from .guards import check_thin_body, check_unreached_components

    # before the kind's build (a frame precompute): what no model can hold, what no sample can see
    check_unreached_components(scene, image)
    check_thin_body(scene, image)
    from .deform.layers.cables import with_cables
    from .deform.layers.contact import with_contact

    # [nodes] placement = "strain": the frames follow a first cheap solve's strain energy
    extra = {}
    if getattr(scene.nodes, "placement", "volume") == "strain":
        extra["placement_energy"] = strain_indicator(scene, image, materials)
    # the collision layer is built only when the scene has obstacles, the cable layer when it has cables
    built = kind.build(scene, image, materials, cache=cache, **extra)
    out = with_cables(with_contact(_with_plasticity(built, scene), scene), scene)
    out.__dict__["scene_tables"] = scene_tables(scene)  # what simulate checks a model against (check_built_for)
    return out


RUN_TABLES = ("loads", "solver", "probes", "output", "title", "base_dir", "path")
"""The scene's fields a run reads and its model does not; every other table (the geometry, the materials, the
nodes and their placement, which follows the fixed boxes, the integration, the layers, a kind's own table) is one
a built model depends on."""


def scene_tables(scene) -> dict:
    """{table: its repr} of every model table of ``scene`` (its fields but :data:`RUN_TABLES`; the loads too when
    the frames follow a first solve's strain energy, ``[nodes] placement = "strain"``)."""
    from dataclasses import fields

    out = {f.name: repr(getattr(scene, f.name)) for f in fields(scene) if f.name not in RUN_TABLES}
    if getattr(scene.nodes, "placement", "volume") == "strain":
        out["loads"] = repr(scene.loads)
    return out


def check_built_for(model, scene) -> None:
    """InputError when ``model`` was built by :func:`model` for a scene whose model tables differ from ``scene``'s
    (a model of one Young's modulus run under another scene's title returned the first scene's answer); models
    built otherwise (a kind's own constructors) are taken as they are."""
    built = getattr(model, "__dict__", {}).get("scene_tables")
    if built is None:
        return
    now = scene_tables(scene)
    differ = [name for name in now if built.get(name) != now[name]]
    if differ:
        names = ", ".join(f"[{n}]" for n in differ)
        raise InputError(f"the model was built for another scene: its {names} differ from this scene's; build it "
                         "with vf.model(scene) for this scene, or pass the scene it was built for")


STRAIN_SOLVE_VOXELS = 4000
"""``[nodes] placement = "strain"``: the first solve runs on the scene's image merged 2x2x2 while it has more
material voxels than this (a linear voxel model of at most ~15k DOF: a few seconds)."""

ROUNDOFF_STRAIN = 1e-12
"""``[nodes] placement = "strain"``: a first solve whose largest strain-energy density is below that of this
strain (``0.5 (lambda + 2 mu) eps^2`` of the stiffest material) has nothing to follow (a scene without loads
solves to round-off: measured 3e-26 Pa, a strain of 2e-15, on the clamped cantilever at E = 1e4 Pa): the
indicator is zero and the placement that of ``placement = "volume"``.  Dimensionless, so the same scene in
other length units gets the same verdict (gravity at 1 um still strains the cantilever by ~1e-7)."""


def _linearised(material):
    """Linear isotropic elasticity (strain "linear") with the rest tangent's Lame constants of ``material``
    (``lambda = C_xxyy``, ``mu = C_xyxy``): what a first, cheap solve needs of it."""
    from .deform.materials.constitutive import material as make

    base = getattr(material, "base", material)
    C = np.asarray(base.tangent(np.eye(3)[None]))[0]
    lam, mu = float(C[0, 0, 1, 1]), float(C[0, 1, 0, 1])
    if not (mu > 0 and lam + 2 * mu / 3 > 0):
        raise InputError(f"material {base.name!r} has no positive rest stiffness (lambda = {lam:.3g}, mu = "
                         f"{mu:.3g}); placement = \"strain\" cannot solve with it")
    return make("hooke", young=mu * (3 * lam + 2 * mu) / (lam + mu), poisson=lam / (2 * (lam + mu)), strain="linear")


def _energy_density(model, record) -> np.ndarray:
    """Per cell, the linearised materials' strain-energy density of a first solve's answer: ``H : C0 : H / 2``
    from the displacement's gradient itself when the model gives it (a 1 um body's strains are 1e-7 of a
    1 m body's under the same gravity, and ``F = I + H`` keeps 2e-9 of them: the density differed by 7e-9
    between mirror voxels, above the placement's tie tolerance, so the two scales placed frames
    differently), else the result field ``energy-density``."""
    from .deform.models.fields import cell_average, model_fields
    from .deform.models.protocol import DisplacementGradients

    if not isinstance(model, DisplacementGradients) or record.displacement is None:
        return model_fields(model, record.q, ["energy-density"])[0]["energy-density"]
    s = model.sample_fields(record.q)
    H = model.displacement_gradients(record.displacement)
    W = np.zeros(len(H))
    for label, mat in s["materials"].items():
        at = np.flatnonzero(s["label"] == label)
        C = np.asarray(mat.tangent(np.eye(3)[None]))[0]
        W[at] = 0.5 * np.einsum("sij,ijkl,skl->s", H[at], C, H[at], optimize=True)
    return cell_average(W, s["volume"], s["cell"], s["n_cells"])


def strain_indicator(scene: Scene, image, materials) -> np.ndarray:
    """Strain-energy density (Pa, an image like ``image.labels``, 0 outside) of a first, cheap solve of ``scene``.

    ``[nodes] placement = "strain"``.  The scene's reference kind (the voxel model) on the image merged
    2x2x2 (:func:`voxflex.image.levels.merge_blocks`) while it holds more than :data:`STRAIN_SOLVE_VOXELS`
    material voxels and the merge cuts no part off (a thin neck emptied by it leaves an island that a static
    solve refuses as a hinge: the bunny's 8 mm merge of its 2 mm image), each material linearised at rest (:func:`_linearised`), one static step of the scene's
    fixed regions and loads; every voxel of ``image`` takes the energy density of the coarse voxel it lies in
    (of the nearest coarse material voxel where the merge left none).  A voxel model, not a few frames, so
    that the indicator depends on no placement (no frames to place first) and resolves stress
    concentrations to its own voxel size.

    Zero everywhere when the solve's energy is round-off (:data:`ROUNDOFF_STRAIN`: a scene without loads).

    Raises
    ------
    InputError
        A scene without ``[[fixed]]`` region (a free body has no static equilibrium to follow).
    """
    import dataclasses

    from scipy import ndimage

    from .deform.models.kinds import reference_kind
    from .image.levels import merge_blocks
    from .problems import problem_of

    if not scene.fixed:
        raise InputError('[nodes] placement = "strain" follows the strain energy of a first static solve under the '
                         "scene's loads and supports, and this scene has no [[fixed]] region (a free body has no "
                         'static equilibrium); add one or use placement = "volume"')
    coarse, levels = image, 0
    parts = ndimage.label(image.labels > 0)[1]
    while int((coarse.labels > 0).sum()) > STRAIN_SOLVE_VOXELS:
        nxt = merge_blocks(coarse)
        if int((nxt.labels > 0).sum()) < 64 or ndimage.label(nxt.labels > 0)[1] > parts:
            break  # too coarse, or the merge cut a part off (held by an edge: no static solve on that image)
        coarse, levels = nxt, levels + 1
    ref = reference_kind()
    lin = {lab: _linearised(m) for lab, m in materials.items()}
    modulus = max(float(np.asarray(m.tangent(np.eye(3)[None]))[0][0, 0, 0, 0]) for m in lin.values())
    present = {int(x) for x in np.unique(coarse.labels[coarse.labels > 0])}
    lin = {lab: m for lab, m in lin.items() if lab in present}
    s = dataclasses.replace(
        scene, nodes=dataclasses.replace(scene.nodes, kind=ref.name, count=None, positions=None, shape_function=None,
                                         support=None, placement="volume"),
        elasticity=dataclasses.replace(scene.elasticity, quadrature=None, samples=None, strain=None),
        solver=dataclasses.replace(scene.solver, kind="static", steps=1), obstacles=(), probes=())
    m = ref.build(s, coarse, lin, cache=False)
    rec = problem_of(s, m).solve()[-1]
    e = np.zeros(coarse.shape)
    cm = coarse.labels > 0
    e[cm] = np.maximum(_energy_density(m, rec), 0.0)
    if not cm.all():  # every coarse voxel the merge emptied takes the nearest material voxel's value
        idx = ndimage.distance_transform_edt(~cm, return_distances=False, return_indices=True)
        e = e[tuple(idx)]
    ijk = np.argwhere(image.labels > 0)
    out = np.zeros(image.shape)
    if float(e.max(initial=0.0)) <= 0.5 * modulus * ROUNDOFF_STRAIN ** 2:
        return out  # round-off of a load-free solve: nothing to follow
    out[tuple(ijk.T)] = e[tuple((ijk >> levels).T)]
    return out
