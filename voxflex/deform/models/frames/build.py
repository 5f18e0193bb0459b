"""Build an affine frame model from a scene: placement, shape functions, samples, the soft-mode guard.

The precompute (frames, blended weights, samples) is stored in the on-disk
cache (:mod:`voxflex.cache`).  Before a static solve the samples are checked
for zero-energy and near-zero-energy modes and the scene refused with the fix.
"""

from __future__ import annotations

import numpy as np

from ....errors import InputError
from ..kinds import NodeEstimate
from .kind import DEFAULT_FRAMES

SAMPLES_PER_FRAME = 20
"""Mid-point / elaston samples per frame when a scene does not say ``[elasticity] samples``.

Too few samples per frame leave near-mechanisms that the exact rank check does
not see: the linear cantilever 32x8x8 with 50 frames sags -0.681, -0.453 and
-0.409 m with 200, 500 and 1000 samples against -0.388 m for the voxel model
(the soft side of it is spurious). At 20 per frame the error is on the stiff
side of the reference or within a few per cent (20 frames, 400 samples: -0.350 m).
"""


UNTRUNCATED = ("reproducing-kernel", "eigenmode")
"""Weight families never truncated to ``parents`` (conforming; linearly precise or global)."""


def build(scene, image, materials, *, cache: bool = True, placement_energy=None):
    """Affine frames: placement, shape functions and samples from the image, then the frame model.

    ``placement_energy``: the strain-energy density image of a first solve (``[nodes] placement =
    "strain"``, :func:`voxflex.build.strain_indicator`) whose metric places the frames.

    The precompute (frames, blended weights, samples) is loaded from the on-disk
    cache (:mod:`voxflex.cache`) when a run with the same image and settings made
    it before; ``precompute_seconds`` in the result's ``/model`` is what this run
    spent (``precompute_cached`` says whether it was loaded).
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
    kind = nodes.shape_function or "natural-neighbour"
    fixed = [(np.asarray(f.min, dtype=float), np.asarray(f.max, dtype=float)) for f in scene.fixed]
    count = nodes.count if nodes.count is not None else min(DEFAULT_FRAMES, int((image.labels > 0).sum()))
    quadrature = scene.elasticity.quadrature
    n_samples = scene.elasticity.samples if scene.elasticity.samples is not None else SAMPLES_PER_FRAME * count
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
                                          n_samples, occupancy, weight_space=weight_space, density=density)
    info = {"shape_function": kind, "parents": int(sf.parents if untruncated else nodes.parents),
            "distance": nodes.distance, "precompute_cached": stored is not None,
            "placement": nodes.placement or "volume"}
    if rk:
        info.update(support=float(sf.support), kernel_grown_frames=int(sf.grown_frames),
                    kernel_fallback_corners=int(sf.fallback_corners))
    if kind == "eigenmode":
        info.update(eigenmode_linear=bool(sf.linear), eigenmode_lifted=int(len(sf.lifted)),
                    eigenmode_condition=float(sf.condition), eigenmode_lebesgue=float(sf.max_lebesgue))
    # [elasticity] volumetric: "reduced" asks for F-bar / B-bar over each frame's cell; "auto" stays "full"
    # for frames: measured (benchmarks/bench_locking.py) the reduced term removes the locking but makes
    # the cantilever 12-74 % softer than the beam trend, and at nu = 0.45 (the default scene) it is no closer
    volumetric = scene.elasticity.volumetric
    model = FrameModel.from_image(image, frames, sf, materials, samples=samples, use_occupancy=occupancy, info=info,
                                  volumetric="full" if volumetric == "auto" else volumetric)
    if quadrature != "gauss-legendre":
        import warnings

        from .modes import SpuriousModesWarning, check_modes, free_body_stiffness

        if rk:
            warnings.warn(f'reproducing-kernel weights with {quadrature} samples: their kinematics no longer stiffen '
                          'the model, so the reduced quadrature\'s softness shows (the neo-Hooke cantilever with 20 '
                          'frames and mid-point samples came out 49 % too soft, 0.8 % with Gauss points); use '
                          '[elasticity] quadrature = "gauss-legendre" with them for now', UserWarning, stacklevel=2)

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


def _softest_mode(scene, image, model, frames, sf, samples, occupancy, K) -> float | None:
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
    free = np.setdiff1d(np.arange(12 * len(frames)), held) if len(held) else None
    return softest_mode(frames, samples, reference, free, stiffness=K)


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


def _judge_soft_modes(scene, samples, softest: float) -> None:
    """Refuse a static affine scene whose samples leave a near-zero-energy mode; warn for the others."""
    import warnings

    from .modes import SOFT_RATIO, SpuriousModesWarning

    if softest >= SOFT_RATIO:
        return
    what = (f"the {len(samples.volume)} {samples.kind} samples leave a deformation mode {1 / max(softest, 1e-300):.0f} "
            f"times softer than one sample per voxel would (limit {1 / SOFT_RATIO:.0f}): a spurious near-zero-energy "
            "mode")
    fix = 'raise [elasticity] samples, use fewer frames, or quadrature = "gauss-legendre"'
    if _static_frames(scene):
        raise InputError(f"{what}, so the static answer would be far too soft; {fix}")
    warnings.warn(f"{what}; results may be far too soft; {fix}", SpuriousModesWarning, stacklevel=3)


def _refuse_static_mechanism(scene, model, K, samples, spurious: int) -> None:
    """InputError when the samples leave zero-energy modes among the frames a static scene does not hold.

    The free body's spurious modes (:func:`voxflex.deform.models.frames.modes.check_modes`) are harmless where they
    only move held frames; with any left among the free ones, static equilibrium is not unique and
    Newton cannot converge (it did not, after minutes of cut load steps).  Only static affine scenes
    without obstacles or cables are judged here (those layers may hold such modes; dynamics has mass).
    ``K``: the free body's stiffness (:func:`voxflex.deform.models.frames.modes.free_body_stiffness`).
    """
    if not _static_frames(scene):
        return
    from ...._blas import one_thread

    free = np.setdiff1d(np.arange(K.shape[0]), _held(scene, model))
    with one_thread():
        ev = np.linalg.eigvalsh(K[np.ix_(free, free)])
    zero = int(np.count_nonzero(ev <= 1e-8 * max(float(ev.max(initial=0.0)), 1e-300)))
    if zero:
        raise InputError(
            f"the {len(samples.volume)} {samples.kind} samples leave {zero} zero-energy mode(s) among the frames "
            f"the scene does not hold ({spurious} in the free body), so static equilibrium is not unique; raise "
            '[elasticity] samples, use fewer frames, or quadrature = "gauss-legendre"')


def _precompute(image, count, kind, fixed, nodes, compliance, quadrature, n_samples, occupancy, *,
                weight_space=None, density=None):
    """Frames, blended shape functions and samples (pruned to ``parents``) of an image.  ``weight_space``:
    the eigenmode weights' per-label stiffness and density (:func:`_weight_space`); ``density``: the relative
    frame density of ``[nodes] placement = "strain"``."""
    import dataclasses

    from ....sampling.voxel import voxel_samples
    from ....voronoi import place_frames, shape_function
    from ....voronoi.shape_functions import keep_largest

    positions = None if nodes.positions is None else np.asarray(nodes.positions, dtype=float)
    rk = kind == "reproducing-kernel"
    if kind == "eigenmode":  # the scene's positions and one frame per fixed region; the rest from the modes
        from ....voronoi.placement import pinned_frames

        given = pinned_frames(image, positions=positions, fixed=fixed)
        sf = shape_function(image, given, kind=kind, count=count, seed_owner=_clamp_owners(image, given, fixed),
                            **(weight_space or {}))
        frames = sf.frames
    else:
        frames = place_frames(image, count, positions=positions, fixed=fixed, seed=nodes.seed,
                              distance=nodes.distance, compliance=compliance, density=density)
        sf = shape_function(image, frames, kind=kind, parents=None if rk else nodes.parents, distance=nodes.distance,
                            compliance=compliance, seed_owner=_clamp_owners(image, frames, fixed),
                            **({"support": nodes.support} if rk else {}))
    untruncated = kind in UNTRUNCATED
    if quadrature == "gauss-legendre":
        # values and gradients only (F needs no Hessian): global eigenmode weights on the bunny's 750k Gauss
        # points would hold 2 GB of Hessians at 40 frames
        samples = voxel_samples(image, (lambda p: sf(p, hessians=False)) if untruncated else sf,
                                rule="gauss-legendre", use_occupancy=occupancy)
    else:
        from ....sampling import sample

        samples = sample(image, sf, kind=quadrature, count=n_samples, seed=nodes.seed)
    # at most `parents` frames per sample: the blended weights of a sample (and the union over a
    # region) have more, and the stiffness costs ~432 P^2 flops per sample; reproducing-kernel
    # weights keep every parent (truncating them breaks linear precision and conformity)
    if not untruncated:
        samples = dataclasses.replace(samples, values=keep_largest(samples.values, nodes.parents))
    return frames, sf, samples


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


def _to_store(frames, sf, samples) -> dict:
    v = samples.values
    if getattr(sf, "kind", None) in UNTRUNCATED:
        out = sf.to_store()
    else:
        W = sf._smoothed()._W
        out = {"W_indptr": W.indptr, "W_indices": W.indices, "W_data": W.data}
    out.update({"frames": frames,
           "kind": np.array(samples.kind), "points": samples.points, "volume": samples.volume,
           "label": samples.label, "index": v.index, "w": v.w, "dw": v.dw,
           "ddw": v.ddw if v.ddw is not None else np.zeros((0,))})
    if hasattr(samples, "moments"):
        out["moments"] = samples.moments
        out["region"] = samples.region
    return out


def _from_store(image, d, kind, parents):
    """Rebuild (frames, shape function, samples) from a cache entry."""
    import scipy.sparse as sp

    from ....sampling.voxel import VoxelSamples
    from ....voronoi.shape_functions import ShapeValues
    from ....voronoi.smoothing import SmoothWeights
    from ....voronoi.weights import ShapeFunction

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
    ddw = d["ddw"] if d["ddw"].size else None
    values = ShapeValues(index=d["index"], w=d["w"], dw=d["dw"], ddw=ddw, rest=d["points"], n_nodes=n)
    skind = str(d["kind"])
    if "moments" in d:
        from ....sampling.samples import Samples

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
    from ....voronoi.placement import voxels_touching_box

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
    if scene.nodes.shape_function == "reproducing-kernel":  # never truncated: every kernel reaching a point;
        # measured 29 / 50 parents with 40 / 80 frames at support 2.5 on the cantilever, 35 on the bunny
        support = scene.nodes.support or 2.5
        parents = min(nodes, int(np.ceil(2.5 * support ** 3)))
    elif scene.nodes.shape_function == "eigenmode":  # global: every frame is a parent of every point
        parents = nodes
    model = (FRAME_BYTES_PER_VOXEL_PARENT * parents + 64.0) * voxels + FRAME_DENSE_COPIES * 8.0 * dofs**2
    iterations = 1 if material_class == "constant" else 5
    seconds = int(scene.solver.steps) * iterations * (dofs**3 / 3 / 1e10 + 2e-6 * voxels)
    return NodeEstimate(nodes, dofs, model, seconds)
