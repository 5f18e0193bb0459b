"""Build an affine frame model from a scene: placement, shape functions, samples, the soft-mode guard.

The precompute (frames, blended weights, samples and the regions' tables) is
stored in the on-disk cache (:mod:`voxflex.cache`).

Sample counts.  Unless a scene says ``[elasticity] samples``, the count of
regions comes from the frames: :data:`REGIONS_PER_FRAME` per frame, then
checked the way a static solve needs it -- the free body's zero-energy modes
and the softest deformation against one mid-point sample per voxel
(:mod:`voxflex.deform.models.frames.modes`) -- and doubled until both pass (at
most :data:`MAX_DOUBLINGS` times, and no more regions than voxels).  What was
chosen and why is in the model's info (``samples_chosen``, written to the
result's ``/model`` and shown by ``voxflex info``).  A count the scene gives
is kept as it is and only judged: a static scene whose samples leave a
zero-energy or near-zero-energy mode among the frames it does not hold is
refused before solving, others get a warning.
"""

from __future__ import annotations

import numpy as np

from ....errors import InputError
from ....voronoi.families import UNTRUNCATED
from ..kinds import NodeEstimate
from .kind import DEFAULT_FRAMES

class SpuriousModes(InputError):
    """The frames' samples leave (near-)zero-energy modes among the frames a scene does not hold: a static scene is
    refused with it; while :func:`build` tries a scene's default weights, any scene is (and falls back)."""


class _LostPrecision(InputError):
    """The default reproducing-kernel weights are not linearly precise at some voxel corners (frames on a line or a
    plane inside a kernel): raised only while :func:`build` tries them, which then falls back."""


REGIONS_PER_FRAME = {"midpoint": 5, "elaston": 10}
"""Mid-point / elaston regions per frame when a scene does not say ``[elasticity] samples`` (the start of
the count the builder chooses; see the module docstring).  Measured on the neo-Hooke cantilever 32x8x8
(``benchmarks/bench_frames_quadrature.py``): stabilised mid-point regions are within 0.3 % of
Gauss-Legendre from 5 per frame on; elastons need 10 per frame and :data:`VOXELS_PER_ELASTON`."""


VOXELS_PER_ELASTON = 10
"""Elaston regions are at most about this many voxels by default (count >= voxels / 10): a degree-2
sub-rule of <= 10 points stands for the Gauss points of ~10 voxels.  Measured on the cantilever: 10 per
frame on 20-voxel regions (10 frames) was 1.6 % off Gauss-Legendre, on 10-voxel regions 0.1 %."""


def default_regions(quadrature: str, frames: int, voxels: int) -> int:
    """The default number of mid-point or elaston regions (before the soft-mode check may double it)."""
    n = REGIONS_PER_FRAME[quadrature] * frames
    if quadrature == "elaston":
        n = max(n, -(-voxels // VOXELS_PER_ELASTON))
    return int(min(n, voxels))


SAMPLES_PER_FRAME = REGIONS_PER_FRAME["midpoint"]
"""Mid-point regions per frame by default (kept for callers of the former name)."""


MAX_DOUBLINGS = 3
"""Times the builder doubles a default region count whose samples leave a (near-)zero-energy mode."""


def build(scene, image, materials, *, cache: bool = True, placement_energy=None):
    """Affine frames: placement, shape functions and samples from the image, then the frame model.

    A scene that names no ``[nodes] shape_function`` gets the kind's default weights (reproducing kernels:
    linearly precise, the accurate choice) unless their samples would leave a spurious (near-)zero-energy mode
    on this body -- small or thin bodies, frames nearly as dense as the voxels, frames on a line inside a
    kernel -- where it gets :data:`~voxflex.voronoi.families.FALLBACK` (natural neighbours, cut to
    ``parents``: robust there) instead, with the same quadrature; ``shape_function_chosen`` in the model's info
    (the result's ``/model``, ``voxflex info``) says which and why.  A scene that names its weights gets them,
    judged as they are.
    """
    from dataclasses import replace

    from ....voronoi.families import FALLBACK

    # a scene that sets the kernels' support asks for them: judged as they are
    named = scene.nodes.shape_function is not None or scene.nodes.support is not None
    fallback = None if named else FALLBACK.get(scene.nodes.weights)
    if fallback is None:
        return _build(scene, image, materials, cache=cache, placement_energy=placement_energy)
    if scene.elasticity.quadrature == "midpoint" and scene.elasticity.hourglass == "stiffness":
        # stabilised mid-point regions named with the default weights: a region's fluctuation term carries the
        # union of its points' parents, every parent for untruncated weights (the bundled phantom's 12 frames:
        # 15.5 s of checks per run against 1-2 s), so the weights cut to parents are the default there
        note = (f"the weights for stabilised mid-point regions (the default {scene.nodes.weights} weights reach "
                "every parent in each region's fluctuation term: use quadrature = \"elaston\" with them)")
    else:
        import warnings

        from ....voronoi.reproducing_kernel import ReproducingKernelWarning

        try:
            with warnings.catch_warnings():
                # the trial's own verdicts: lost precision is judged below, and "support below every kernel's
                # floor" speaks of a setting this scene did not make
                warnings.simplefilter("ignore", ReproducingKernelWarning)
                return _build(scene, image, materials, cache=cache, placement_energy=placement_energy, strict=True)
        except (SpuriousModes, _LostPrecision) as exc:
            why = str(exc).split(", so ")[0].split("; ")[0]
        note = f"the default {scene.nodes.weights} weights refused on this body: {why}"
    other = replace(scene, nodes=replace(scene.nodes, shape_function=fallback))
    model = _build(other, image, materials, cache=cache, placement_energy=placement_energy)
    model.info["shape_function_chosen"] = f"{fallback}, {note}"
    return model


def _build(scene, image, materials, *, cache: bool = True, placement_energy=None, strict: bool = False):
    """:func:`build` with the scene's weights as they are; ``strict``: judge every scene's samples as a static
    one's (refuse with :class:`SpuriousModes` instead of warning) -- the default weights' trial.

    ``placement_energy``: the strain-energy density image of a first solve (``[nodes] placement =
    "strain"``, :func:`voxflex.build.strain_indicator`) whose metric places the frames.

    The precompute (frames, blended weights, samples, the regions' tables and the sample count chosen)
    is loaded from the on-disk cache (:mod:`voxflex.cache`) when a run with the same image and settings
    made it before; ``precompute_seconds`` in the result's ``/model`` is what this run spent
    (``precompute_cached`` says whether it was loaded).
    """
    import time

    from .... import cache as disk
    from .model import FrameModel

    t0 = time.perf_counter()
    nodes = scene.nodes
    compliance = None
    if nodes.distance == "compliance":
        compliance = {label: float(m.parameters.get("young", np.nan)) for label, m in materials.items()}
        bad = [label for label, E in compliance.items() if not np.isfinite(E) or E <= 0]
        if bad:
            raise InputError(f'[nodes] distance = "compliance" needs a Young\'s modulus for label(s) {bad}; '
                             'give young (or use distance = "geodesic")')
    kind = nodes.weights  # the scene's family or the node kind's default
    fixed = [(np.asarray(f.min, dtype=float), np.asarray(f.max, dtype=float)) for f in scene.fixed]
    limit = None  # (the most frames, the voxel corners): _frame_limit, once per build where it is needed
    if nodes.count is not None:
        count = nodes.count
    else:  # the default, on a body too small for it: as many as stay below the voxel model's DOFs (_check_density)
        limit = _frame_limit(image)
        count = min(DEFAULT_FRAMES, int((image.labels > 0).sum()), limit[0])
    quadrature = scene.elasticity.quadrature
    hourglass = scene.elasticity.hourglass if quadrature == "midpoint" else "none"
    occupancy = bool(scene.object.occupancy)
    rk = kind == "reproducing-kernel"
    untruncated = kind in UNTRUNCATED  # never truncated to parents (conforming; linearly precise or global)
    weight_space = _weight_space(scene, materials) if kind == "eigenmode" else None
    density = None
    if placement_energy is not None:
        from ....voronoi.placement import strain_density

        density = strain_density(placement_energy, image)
    settings = {"count": count, "positions": nodes.positions, "kind": kind, "parents": nodes.parents,
                "support": nodes.support, "weight_space": weight_space,
                "placement": None if density is None else disk.key_of(density),
                "distance": nodes.distance, "seed": nodes.seed, "compliance": compliance,
                "fixed": [(lo.tolist(), hi.tolist(), f.components) for (lo, hi), f in zip(fixed, scene.fixed)],
                "quadrature": quadrature, "samples": scene.elasticity.samples, "occupancy": occupancy,
                "hourglass": hourglass}
    use_cache = cache and disk.enabled()
    key = None
    if use_cache:
        occ = np.zeros(0) if image.occupancy is None else np.asarray(image.occupancy)
        key = disk.key_of(disk.code_fingerprint(), image.labels, np.asarray(image.spacing),
                          np.asarray(image.origin), np.asarray(image.direction), occ, settings)
    refused = use_cache and strict  # the default weights' trial: a refusal on this image is remembered
    if refused:
        known = disk.load("frames-refused", key)
        if known is not None and "why" in known:
            raise SpuriousModes(bytes(np.asarray(known["why"], dtype=np.uint8)).decode("utf-8", "replace"))
    try:
        stored = disk.load("frames", key) if use_cache else None
        if stored is not None:
            try:
                pre = _from_store(image, stored, kind, nodes.parents, occupancy)
            except disk.CacheMismatch as exc:  # never trusted, never blamed on the scene: recomputed
                disk.discard("frames", key, f"does not fit this image ({exc})")
                stored = None
        def make_model(pre):
            return FrameModel(image, pre["frames"], pre["sf"], pre["samples"], materials, use_occupancy=occupancy,
                              volumetric=scene.elasticity.volumetric, hourglass=hourglass, region_tables=pre.get("tables"))

        if stored is None:
            pre = _precompute(scene, image, count, kind, fixed, nodes, compliance, quadrature, occupancy, hourglass,
                              weight_space=weight_space, density=density, make_model=make_model, limit=limit)
        sf = pre["sf"]
        if strict and rk and sf.fallback_corners:  # not linearly precise where frames lie on a line or a plane
            raise _LostPrecision(f"{sf.fallback_corners} of {sf.weights.shape[0]} voxel corners have frames on a line or a "
                                "plane within their kernels (not linearly precise there)")
        info = {"shape_function": kind, "parents": int(sf.parents if untruncated else nodes.parents),
                "distance": nodes.distance, "precompute_cached": stored is not None,
                "placement": nodes.placement or "volume"}
        if rk:
            info.update(support=float(sf.support), kernel_grown_frames=int(sf.grown_frames),
                        kernel_fallback_corners=int(sf.fallback_corners))
        if kind == "eigenmode":
            info.update(eigenmode_linear=bool(sf.linear), eigenmode_lifted=int(len(sf.lifted)),
                        eigenmode_condition=float(sf.condition), eigenmode_lebesgue=float(sf.max_lebesgue))
        if pre.get("chosen"):
            info["samples_chosen"] = pre["chosen"]
        model = pre.pop("model", None)  # the one the sample-count check judged, when the precompute made one
        if model is None:
            model = make_model(pre)
        model.info.update(info)
        if pre["regions"] is not None and model.regions is None:
            model.regions = pre["regions"]
        if quadrature == "gauss-legendre":
            pre["gauss_zero"] = _check_gauss_modes(scene, model, pre.get("gauss_zero"), strict=strict)
        else:
            import warnings

            from .modes import SpuriousModesWarning, check_modes

            K = pre.get("K")
            if K is None:
                K = _unit_stiffness(model)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", SpuriousModesWarning)
                zero = check_modes(pre["frames"], model.samples, stiffness=K, gauge=model.gauge_modes())  # warns, naming how many
            if zero > 6:
                _refuse_static_mechanism(scene, model, K, model.samples, zero - 6, strict=strict)
            softest = pre.get("softest")
            if zero <= 6 and softest is None and not pre.get("judged"):
                softest = _softest(scene, image, model, pre["sf"], occupancy, K)
            for w in caught:
                warnings.warn(w.message, w.category, stacklevel=2)
            if zero <= 6 and softest is not None:
                model.info["softest_mode"] = softest
                _judge_soft_modes(scene, model.samples, softest, strict=strict)
            pre["softest"] = softest
        if use_cache and stored is None:
            disk.save("frames", key, _to_store(pre))
        model.info["precompute_seconds"] = time.perf_counter() - t0
        return model
    except (SpuriousModes, _LostPrecision) as exc:
        if refused:  # the next run of this scene goes straight to the fallback (its own entry: "frames")
            disk.save("frames-refused", key, {"why": np.frombuffer(str(exc).encode("utf-8"), dtype=np.uint8)})
        raise


def _unit_stiffness(model) -> np.ndarray:
    """The free body's stiffness at rest with unit linear isotropic elasticity (mu = lambda = 1) at every
    sample, fluctuation included (what the soft-mode checks read)."""
    from ...materials.constitutive import material

    unit = material("hooke", strain="linear", mu=1.0, lmbda=1.0)
    return model.rest_stiffness({lab: unit for lab in model.materials})


def _ratio(softest: float) -> str:
    """How many times softer a mode is, as a message says it ("4833", "1e+100": never 300 digits)."""
    r = 1.0 / max(float(softest), 1e-300)
    return f"{r:.0f}" if r < 1e7 else f"{r:.3g}"


def _static_frames(scene) -> bool:
    """A static affine scene without obstacles or cables: the scenes judged before solving by the
    frame quadrature's modes (those layers may hold the modes; dynamics has mass)."""
    return (scene.nodes.kind == "affine" and scene.solver.kind == "static" and not scene.obstacles
            and not getattr(scene, "cables", ()))


def _held(scene, model) -> np.ndarray:
    held = set()
    for f in scene.fixed:
        held.update(int(d) for d in model.held_dofs(f.min, f.max, f.components))
    return np.fromiter(sorted(held), dtype=np.int64, count=len(held))


def _softest(scene, image, model, sf, occupancy, K) -> float | None:
    """The samples' softest deformation against one mid-point sample per voxel
    (:func:`voxflex.deform.models.frames.modes.softest_mode`) over the DOFs the scene does not hold (a free
    body: all, rigid modes deflated).  About 0.1 s for the default scene; stored in the cache entry."""
    import dataclasses

    from ....sampling.voxel import voxel_samples
    from ....voronoi.shape_functions import keep_largest
    from .modes import softest_mode

    reference = voxel_samples(image, _centre_values_of(sf), rule="midpoint", use_occupancy=occupancy)
    if getattr(sf, "kind", None) not in UNTRUNCATED:
        reference = dataclasses.replace(reference, values=keep_largest(reference.values, scene.nodes.parents))
    held = _held(scene, model)
    free = np.setdiff1d(np.arange(12 * model.n_nodes), held) if len(held) else None
    return softest_mode(model.frames, model.samples, reference, free, stiffness=K)


def _centre_values_of(sf):
    """``sf`` for :func:`voxel_samples` at the voxel centres, answering from ``sf.voxel_values()`` (already
    computed for the samples: the same points in the same order) instead of evaluating them again
    (2.2-2.6 s of the bunny's 40-frame precompute at 2 mm, 94k voxels)."""
    def centres(points):
        vv = sf.voxel_values() if hasattr(sf, "voxel_values") else None
        if vv is not None and vv.rest.shape == np.shape(points) and np.array_equal(vv.rest, points):
            return vv
        return sf(points)

    return centres


def _judge_soft_modes(scene, samples, softest: float, *, strict: bool = False) -> None:
    """Refuse a static affine scene (any scene with ``strict``) whose samples leave a near-zero-energy mode; warn
    for the others."""
    import warnings

    from .modes import SOFT_RATIO, SpuriousModesWarning

    if softest >= SOFT_RATIO:
        return
    what = (f"the {len(samples.volume)} {samples.kind} samples leave a deformation mode {_ratio(softest)} "
            f"times softer than one sample per voxel would (limit {1 / SOFT_RATIO:.0f}): a spurious near-zero-energy "
            "mode")
    fix = 'raise [elasticity] samples, use fewer frames, or quadrature = "gauss-legendre"'
    if strict or _static_frames(scene):
        raise SpuriousModes(f"{what}, so the static answer would be far too soft; {fix}")
    warnings.warn(f"{what}; results may be far too soft; {fix}", SpuriousModesWarning, stacklevel=3)


def _refuse_static_mechanism(scene, model, K, samples, spurious: int, *, strict: bool = False) -> None:
    """InputError when the samples leave zero-energy modes among the frames a static scene does not hold.

    The free body's spurious modes (:func:`voxflex.deform.models.frames.modes.check_modes`) are harmless where they
    only move held frames; with any left among the free ones, static equilibrium is not unique and
    Newton cannot converge (it did not, after minutes of cut load steps).  Only static affine scenes
    without obstacles or cables are judged here (those layers may hold such modes; dynamics has mass).
    ``K``: the free body's stiffness (:func:`_unit_stiffness`).  ``strict``: judge any scene so.
    """
    if not (strict or _static_frames(scene)):
        return
    zero = _free_zero_modes(scene, model, K)
    if zero:
        raise SpuriousModes(
            f"the {len(samples.volume)} {samples.kind} samples leave {zero} zero-energy mode(s) among the frames "
            f"the scene does not hold ({spurious} in the free body), so static equilibrium is not unique; raise "
            '[elasticity] samples, use fewer frames, or quadrature = "gauss-legendre"')


def _check_gauss_modes(scene, model, known=None, *, strict: bool = False) -> int:
    """Refuse (static affine scenes) or warn about zero-energy modes that 2x2x2 Gauss points leave; returns the
    free body's zero-energy count (kept in the cache entry: ``known``, six or fewer, is not judged again).

    Gauss points are exact for the voxel model's trilinear fields, not for affine frames: a frame moves a voxel by
    its weight times an affine field, a quadratic or higher field per voxel that 2x2x2 points under-integrate
    (as they do a 20-node hexahedron), so frames nearly as dense as the voxels can have deformations of zero
    energy at every point (6 eigenmode frames on an 8x2x2 bar: 9 of them, each moving the material).  The
    unit stiffness at the Gauss points is the model's own here; the gauge motions of linearly precise weights
    (which move nothing) are not counted."""
    import warnings

    from .modes import SpuriousModesWarning, zero_energy_modes

    if known is not None and known <= 6:
        return int(known)  # the bunny's 754k Gauss points: 3.7-4.7 s of a 14 s precompute
    K = _unit_stiffness(model)
    zero = zero_energy_modes(model.frames, model.samples, stiffness=K, gauge=model.gauge_modes())
    if zero <= 6:
        return int(zero)
    what = (f"2x2x2 Gauss points per voxel leave {zero - 6} zero-energy mode(s) of the {model.n_nodes} frames "
            f"(frames nearly as dense as the voxels move a voxel by a field the points under-integrate)")
    fix = "use fewer frames ([nodes] count) or a finer image"
    if (strict or _static_frames(scene)) and _free_zero_modes(scene, model, K):
        raise SpuriousModes(f"{what}, so static equilibrium is not unique; {fix}")
    warnings.warn(f"{what}; results may move along them; {fix}", SpuriousModesWarning, stacklevel=3)
    return int(zero)


def _free_zero_modes(scene, model, K) -> int:
    """Zero eigenvalues of the stiffness over the DOFs ``scene`` does not hold (translations scaled by the
    samples' spread, so the verdict does not depend on the unit: :func:`~voxflex.deform.models.frames.modes.
    dimensionless`), the gauge motions of linearly precise weights that the held DOFs leave free not counted:
    they move nothing (:func:`~voxflex.deform.models.frames.modes.gauge_modes`; a clamp holding one or two
    frames leaves up to 9 of the 18), so they are no mechanism."""
    import scipy.linalg as sla

    from ...._blas import one_thread
    from .modes import dimensionless

    held = _held(scene, model)
    free = np.setdiff1d(np.arange(K.shape[0]), held)
    Ks = dimensionless(K, model.samples)[np.ix_(free, free)]
    G = model.gauge_modes()  # (12n, g); no translation: the scaling leaves it alone
    if G.shape[1]:
        N = sla.null_space(G[held]) if len(held) else np.eye(G.shape[1])
        Gf = (G @ N)[free]
        if Gf.shape[1]:
            Ks = Ks + (np.trace(Ks) / len(Ks)) * (Gf @ Gf.T)
    with one_thread():
        ev = np.linalg.eigvalsh(Ks)
    return int(np.count_nonzero(ev <= 1e-8 * max(float(ev.max(initial=0.0)), 1e-300)))


def _precompute(scene, image, count, kind, fixed, nodes, compliance, quadrature, occupancy, hourglass, *,
                make_model, weight_space=None, density=None, limit=None):
    """Frames, blended shape functions and samples (pruned to ``parents``) of an image, with the sample
    count chosen (module docstring).  Returns a dict: frames, sf, samples (what the model integrates),
    regions (the sampler's, or None), tables and gauss (stabilised mid-point regions), chosen (str),
    K and softest (the checks of the chosen samples) and model (the frame model the check judged, made by
    ``make_model(pre)``: the caller's materials, so that it is built once).  ``weight_space``: the eigenmode weights' per-label
    stiffness and density (:func:`_weight_space`); ``density``: the relative frame density of
    ``[nodes] placement = "strain"``; ``limit``: :func:`_frame_limit` of the image when the caller has it."""
    from ....voronoi import place_frames, shape_function

    positions = None if nodes.positions is None else np.asarray(nodes.positions, dtype=float)
    rk = kind == "reproducing-kernel"
    if kind == "eigenmode":  # the scene's positions and one frame per fixed region; the rest from the modes
        from ....voronoi.placement import pinned_frames

        given = pinned_frames(image, positions=positions, fixed=fixed)
        _check_density(image, count + len(given), limit)
        sf = shape_function(image, given, kind=kind, count=count, seed_owner=_clamp_owners(image, given, fixed),
                            **(weight_space or {}))
        frames = sf.frames
    else:
        frames = place_frames(image, count, positions=positions, fixed=fixed, seed=nodes.seed,
                              distance=nodes.distance, compliance=compliance, density=density)
        _check_density(image, len(frames), limit)
        sf = shape_function(image, frames, kind=kind, parents=None if rk else nodes.parents, distance=nodes.distance,
                            compliance=compliance, seed_owner=_clamp_owners(image, frames, fixed),
                            **({"support": nodes.support} if rk else {}))
    if quadrature == "gauss-legendre":
        return {"frames": frames, "sf": sf, **_samples(image, sf, frames, nodes, quadrature, 0, occupancy, hourglass)}
    voxels = int((image.labels > 0).sum())
    requested = scene.elasticity.samples
    n = requested if requested is not None else default_regions(quadrature, len(frames), voxels)
    log = []
    for attempt in range(MAX_DOUBLINGS + 1):
        pre = {"frames": frames, "sf": sf, **_samples(image, sf, frames, nodes, quadrature, n, occupancy, hourglass)}
        if requested is not None:
            return pre  # the scene's count: judged by the caller, not changed
        verdict, K, softest, model = _check(scene, image, pre, occupancy, make_model)
        pre.update(K=K, softest=softest, judged=True, model=model)
        regions = len(pre["regions"].volume)
        log.append(f"{regions} regions: {verdict}")
        if verdict == "sound" or n >= voxels or attempt == MAX_DOUBLINGS:
            per = REGIONS_PER_FRAME[quadrature]
            why = f"{per} per frame" + (f", at least one per {VOXELS_PER_ELASTON} voxels" if quadrature == "elaston"
                                        else "") + ", at most one per voxel"
            if len(log) > 1:
                why += "; doubled while the samples left a soft mode"
            pre["chosen"] = f"{regions} {quadrature} regions ({why}): " + "; ".join(log)
            return pre
        n = min(2 * n, voxels)
    raise AssertionError("unreachable")  # pragma: no cover


def _samples(image, sf, frames, nodes, quadrature, n, occupancy, hourglass) -> dict:
    """The samples of one count: {samples, regions, tables, gauss}.  Reproducing-kernel and eigenmode weights
    keep every parent (truncating them breaks linear precision and conformity)."""
    import dataclasses

    from ....sampling import sample
    from ....sampling.voxel import voxel_samples
    from ....voronoi.shape_functions import keep_largest
    from .quadrature import elaston_samples, midpoint_tables, point_values

    untruncated = getattr(sf, "kind", None) in UNTRUNCATED
    parents = None if untruncated else nodes.parents
    prune = (lambda v: v) if parents is None else (lambda v: keep_largest(v, parents))
    if quadrature == "gauss-legendre":
        # values and gradients only (F needs no Hessian): global eigenmode weights on the bunny's 750k Gauss
        # points would hold 2 GB of Hessians at 40 frames
        s = voxel_samples(image, lambda p: point_values(sf, p, None), rule="gauss-legendre", use_occupancy=occupancy)
        # at most `parents` frames per sample (the stiffness costs ~432 P^2 flops per sample)
        s = dataclasses.replace(s, values=prune(s.values))
        return {"samples": s, "regions": None, "tables": None, "gauss": None}
    # elastons and mid-point regions share the mid-point sampler's compact regions (farthest point + Lloyd);
    # the union of a region's voxels' parents is pruned to `parents` at its centre
    # elastons read only the partition (their sub-rules evaluate the weights at their own points), and stabilised
    # regions their Gauss points' tables: the regions' weights are fitted only for bare mid-point regions, else
    # evaluated at the region points (the fit took 0.8-1.2 s of the bunny's natural-neighbour precompute)
    fit = quadrature == "midpoint" and hourglass != "stiffness"
    regions = sample(image, sf, kind="midpoint", count=int(n), seed=nodes.seed, fit=fit)
    regions = dataclasses.replace(regions, values=prune(regions.values))
    if quadrature == "elaston":
        pts = elaston_samples(image, sf, regions, parents=parents, use_occupancy=occupancy)
        return {"samples": pts, "regions": regions, "tables": None, "gauss": None}
    if hourglass == "stiffness":
        tables, gauss = midpoint_tables(image, sf, regions, frames, parents=parents, use_occupancy=occupancy)
        return {"samples": regions, "regions": regions, "tables": tables, "gauss": gauss}
    return {"samples": regions, "regions": regions, "tables": None, "gauss": None}


def _check(scene, image, pre, occupancy, make_model):
    """('sound' or why not, unit stiffness K, softest ratio, the model judged) of a precompute's samples for
    ``scene``.  The model is ``make_model(pre)`` (the scene's materials: the build keeps it); K is its unit
    stiffness (:func:`_unit_stiffness`)."""
    from .modes import SOFT_RATIO, zero_energy_modes

    model = make_model(pre)
    K = _unit_stiffness(model)
    zero = zero_energy_modes(pre["frames"], model.samples, stiffness=K, gauge=model.gauge_modes())
    if zero > 6:  # judged on the free body whatever the solver (the cache entry serves every solver kind)
        return f"{zero - 6} zero-energy mode(s) in the free body", K, None, model
    softest = _softest(scene, image, model, pre["sf"], occupancy, K)
    if softest is not None and softest < SOFT_RATIO:
        return f"a mode {_ratio(softest)} times softer than one sample per voxel", K, softest, model
    return "sound", K, softest, model


def _weight_space(scene, materials) -> dict:
    """The eigenmode weights' operators per label: ``stiffness`` D = the trace over the displacement components
    of the material's rest tangent (``D_jl = sum_d C_djdl``; ``(lambda + 4 mu) I`` for isotropic materials) and
    ``density`` (the scene's, when every label has a positive one; else uniform)."""
    stiff = {}
    for label, m in materials.items():
        base = getattr(m, "base", m)
        C = np.asarray(base.tangent(np.eye(3)[None]))[0]
        stiff[int(label)] = np.einsum("djdl->jl", C).round(12).tolist()
    dens = {}
    for label in materials:
        d = scene.material_for(int(label)).density
        dens[int(label)] = None if d is None else float(d)
    ok = all(v is not None and v > 0 for v in dens.values())
    return {"stiffness": stiff, "density": dens if ok else None}


def _to_store(pre) -> dict:
    sf = pre["sf"]
    if getattr(sf, "kind", None) in UNTRUNCATED:
        out = {"frames": pre["frames"], **sf.to_store()}
    else:
        W = sf._smoothed()._W
        out = {"frames": pre["frames"], "W_indptr": W.indptr, "W_indices": W.indices, "W_data": W.data}
    for name in ("samples", "regions"):
        s = pre[name]
        if s is None:
            continue
        v = s.values
        out.update({f"{name}_kind": np.array(s.kind), f"{name}_points": s.points, f"{name}_volume": s.volume,
                    f"{name}_label": s.label, f"{name}_index": v.index, f"{name}_w": v.w, f"{name}_dw": v.dw,
                    f"{name}_ddw": v.ddw if v.ddw is not None else np.zeros((0,))})
        if getattr(s, "moments", None) is not None:
            out[f"{name}_moments"] = s.moments
        if getattr(s, "region", None) is not None:
            out[f"{name}_region"] = s.region
    if pre.get("gauss") is not None:
        gv = pre["gauss"][0]
        out.update({"gauss_index": gv.index, "gauss_w": gv.w, "gauss_dw": gv.dw})
    if pre.get("chosen"):
        out["chosen"] = np.array(pre["chosen"])
    if pre.get("softest") is not None:
        out["softest"] = np.float64(pre["softest"])
    if pre.get("judged"):
        out["judged"] = np.array(True)
    if pre.get("gauss_zero") is not None:
        out["gauss_zero"] = np.int64(pre["gauss_zero"])
    return out


def _from_store(image, d, kind, parents, occupancy) -> dict:
    """Rebuild the precompute (frames, shape function, samples, regions, tables) from a cache entry;
    :class:`voxflex.cache.CacheMismatch` when the entry does not fit ``image`` (missing arrays, shapes,
    non-finite values, labels, indices)."""
    from .... import cache as disk

    try:
        _check_store(image, d)
        return _rebuild(image, d, kind, parents, occupancy)
    except disk.CacheMismatch:
        raise
    except (InputError, ValueError, KeyError, IndexError, TypeError) as exc:
        raise disk.CacheMismatch(" ".join(str(exc).split())[:200] or type(exc).__name__) from None


def _check_store(image, d) -> None:
    """What a cache entry must satisfy to describe a precompute of ``image`` (CacheMismatch otherwise)."""
    from .... import cache as disk

    if "frames" not in d or "samples_kind" not in d or not ("rk_indptr" in d or "em_indptr" in d or "W_indptr" in d):
        raise disk.CacheMismatch("it lacks the frames, the weights or the samples")
    frames = np.asarray(d["frames"])
    n = len(frames)
    if not (frames.ndim == 2 and frames.shape[1:] == (3,) and n > 0):
        raise disk.CacheMismatch("its frames do not fit")
    voxels = int((image.labels > 0).sum())
    if "W_indptr" in d and np.asarray(d["W_indptr"]).shape != (voxels + 1,):
        raise disk.CacheMismatch("its weights of the voxels do not fit")
    present = np.unique(image.labels[image.labels > 0])
    for name in ("samples", "regions"):
        if f"{name}_kind" not in d:
            continue
        points, index = np.asarray(d[f"{name}_points"]), np.asarray(d[f"{name}_index"])
        m = len(points)
        checks = [
            (points.ndim == 2 and points.shape[1:] == (3,) and m > 0, "sample points"),
            (np.asarray(d[f"{name}_volume"]).shape == (m,) and np.all(np.asarray(d[f"{name}_volume"]) > 0),
             "sample volumes"),
            (np.asarray(d[f"{name}_label"]).shape == (m,) and np.all(np.isin(d[f"{name}_label"], present)),
             "sample labels"),
            (index.ndim == 2 and len(index) == m and np.all((index >= -1) & (index < n)), "parent indices"),
        ]
        for ok, what in checks:
            if not ok:
                raise disk.CacheMismatch(f"its {what} do not fit")
    for key, value in d.items():
        a = np.asarray(value)
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise disk.CacheMismatch(f"its {key} are not finite")


def _rebuild(image, d, kind, parents, occupancy) -> dict:
    """The precompute of a checked cache entry (:func:`_check_store`)."""
    import scipy.sparse as sp

    from ....sampling.samples import Samples
    from ....sampling.subrule import gauss_points
    from ....sampling.voxel import VoxelSamples
    from ....voronoi.weights import ShapeFunction
    from ....voronoi.shape_functions import ShapeValues
    from ....voronoi.smoothing import SmoothWeights
    from .quadrature import midpoint_tables

    frames = d["frames"]
    n = len(frames)
    if "rk_indptr" in d:
        from ....voronoi.reproducing_kernel import ReproducingKernel

        sf = ReproducingKernel.from_store(image, frames, d)
    elif "em_indptr" in d:
        from ....voronoi.eigenmode import EigenmodeWeights

        sf = EigenmodeWeights.from_store(image, frames, d)
    else:
        W = sp.csr_matrix((d["W_data"], d["W_indices"], d["W_indptr"]), shape=(int((image.labels > 0).sum()), n))
        smooth = SmoothWeights.from_csr(image, W)
        sf = ShapeFunction(frames=frames, kind="sibson" if kind == "natural-neighbour" else kind, parents=parents,
                           image=image, smooth=True, _cache={"smooth": smooth})
    out = {"frames": frames, "sf": sf, "regions": None, "tables": None, "gauss": None}
    for name in ("samples", "regions"):
        if f"{name}_kind" not in d:
            continue
        ddw = d[f"{name}_ddw"] if d[f"{name}_ddw"].size else None
        values = ShapeValues(index=d[f"{name}_index"], w=d[f"{name}_w"], dw=d[f"{name}_dw"], ddw=ddw,
                             rest=d[f"{name}_points"], n_nodes=n)
        skind = str(d[f"{name}_kind"])
        if f"{name}_moments" in d:
            s = Samples(kind=skind, points=d[f"{name}_points"], volume=d[f"{name}_volume"],
                        moments=d[f"{name}_moments"], label=d[f"{name}_label"], region=d[f"{name}_region"],
                        values=values)
        else:
            s = VoxelSamples(skind, d[f"{name}_points"], d[f"{name}_volume"], d[f"{name}_label"], values,
                             region=d.get(f"{name}_region"))
        out[name] = s
    if "gauss_index" in d:
        points = gauss_points(image, use_occupancy=occupancy)[0]
        gv = ShapeValues(index=d["gauss_index"], w=d["gauss_w"], dw=d["gauss_dw"], ddw=None, rest=points, n_nodes=n)
        out["tables"], out["gauss"] = midpoint_tables(image, sf, out["regions"], frames, use_occupancy=occupancy,
                                                      values=gv)
    if "chosen" in d:
        out["chosen"] = str(d["chosen"])
    if "softest" in d:
        out["softest"] = float(d["softest"])
    out["judged"] = "judged" in d
    if "gauss_zero" in d:
        out["gauss_zero"] = int(d["gauss_zero"])
    return out


def _frame_limit(image) -> tuple[int, int]:
    """(the most affine frames, 12 DOF each, below the DOFs of the image's voxel model, the number of voxel
    corners): the voxel model has 3 DOF per corner.  The limit of :func:`_check_density`."""
    from ....image.grid import TrilinearGrid

    corners = TrilinearGrid.from_image(image).n_nodes
    return max(1, (3 * corners - 1) // 12), corners


def _check_density(image, n: int, limit=None) -> None:
    """InputError when n affine frames (12 DOF each) would carry as many DOFs as the voxel model of the image (3
    per voxel corner): frames that dense are finer than the voxels their weights are computed on.  Measured on
    the 16x4x4 cantilever (256 voxels, 425 corners, converged tip -0.39 m): 96 natural-neighbour frames -0.317 m,
    128 frames -0.515 m, 256 frames -0.802 m, no warning; on a 4x4x4 cube 48 frames were 19 % softer than the
    converged answer; reproducing kernels were refused for zero-energy modes from 128 frames on the beam.
    ``limit``: :func:`_frame_limit` of the image when the caller has it."""
    top, corners = _frame_limit(image) if limit is None else limit
    if n > top:
        raise InputError(
            f"{n} affine frames (12 DOF each, {12 * n:,}) would carry as many DOFs as the voxel model of this image "
            f"({int((image.labels > 0).sum()):,} voxels, {3 * corners:,} DOF): frames that dense are finer than the "
            f"voxels their weights are computed on, and their answers are not to be trusted; use at most {top} frames "
            '([nodes] count), or [nodes] kind = "voxel"')


def _clamp_owners(image, frames, boxes):
    """Voxels each fixed region touches, owned outright by the nearest frame it holds (-1 elsewhere).

    A fixed region holds the frames in the voxels it touches; making those
    frames own every voxel the region touches means every material point the
    region touches moves with held frames only, so a clamp holds the whole
    face instead of a frame's neighbourhood (on a cantilever the loose clamp
    made the frame model 30-100 % too soft).
    """
    from ....voronoi.geodesic import voxel_coordinates, voxel_units
    from ....voronoi.placement import voxels_touching_box

    owner = -np.ones(image.shape, dtype=np.int64)
    if not boxes:
        return None
    material = image.labels > 0
    fc = voxel_coordinates(image, frames)
    fi = np.clip(np.floor(fc + 1e-9).astype(np.int64), 0, np.asarray(image.shape) - 1)
    # distances in voxel units from exact coordinates: a voxel as far from two held frames goes to the first in
    # every unit of the scene (in metres the round-off chose: the stretched cube's corner moved sideways 1.8 mm
    # instead of 2.3 mm when the scene was written at 0.37 of its size)
    spacing_u, _ = voxel_units(image.spacing)
    for lo, hi in boxes:
        touch = voxels_touching_box(image, lo, hi) & material
        held = np.flatnonzero(touch[fi[:, 0], fi[:, 1], fi[:, 2]] | np.all((frames >= lo) & (frames <= hi), axis=1))
        if len(held) == 0 or not np.any(touch):
            continue
        c = np.argwhere(touch) + 0.5
        near = held[np.argmin((((c[:, None, :] - fc[held][None, :, :]) * spacing_u) ** 2).sum(-1), axis=1)]
        owner[touch] = near
    return owner


FRAME_BYTES_PER_VOXEL_PARENT = 112.0
"""Shape-function values, gradients and Hessians (1 + 3 + 9 doubles) and an index per voxel and parent."""
FRAME_DENSE_COPIES = 3
"""Dense (d n)^2 matrices alive at once (Hessian, factor, work copy)."""


def estimate(scene, size, material_class: str):
    """:class:`~voxflex.deform.models.kinds.NodeEstimate``` of affine (or rigid) frames: the placed frames (count, given
    positions, one more per fixed region), the weights of every voxel and the dense stiffness."""
    from ..kinds import node_kind

    kind = node_kind(scene.nodes.kind)
    voxels = size[0]
    nodes = int(scene.nodes.count or kind.default_count) + len(scene.nodes.positions or ()) + len(scene.fixed)
    dofs = kind.dofs_per_node * nodes
    parents = scene.nodes.parents
    if scene.nodes.weights == "reproducing-kernel":  # never truncated: every kernel reaching a point;
        # measured 29 / 50 parents with 40 / 80 frames at support 2.5 on the cantilever, 35 on the bunny
        support = scene.nodes.support or 2.5
        parents = min(nodes, int(np.ceil(2.5 * support ** 3)))
    elif scene.nodes.weights == "eigenmode":  # global: every frame is a parent of every point
        parents = nodes
    model = (FRAME_BYTES_PER_VOXEL_PARENT * parents + 64.0) * voxels + FRAME_DENSE_COPIES * 8.0 * dofs**2
    iterations = 1 if material_class == "constant" else 5
    seconds = int(scene.solver.steps) * iterations * (dofs**3 / 3 / 1e10 + 2e-6 * voxels)
    return NodeEstimate(nodes, dofs, model, seconds)
