"""Frame placement: farthest-point sampling and Lloyd relaxation in the geodesic metric.

Frames are placed in this order, and every frame of an earlier step stays
where it is:

1. the user's ``positions`` (kept exactly as given);
2. one frame in the material part of every ``fixed`` box that holds none yet
   (the material voxel nearest the centroid of that part), so that boundary
   conditions are represented;
3. one frame in every connected component (26-connectivity, the connectivity
   of the distances) that holds none yet: a voxel drawn with the seed;
4. farthest-point sampling up to ``count``: each new frame is the material
   voxel farthest from all frames so far (the first in C order on ties);
   adding one only re-propagates where the new frame is nearer;
5. Lloyd relaxation of the frames of steps 3-4 on continuous positions: each
   moves to the centroid of its Voronoi cell (to the cell's voxel nearest the
   centroid when the centroid lies outside the cell), until no frame changes
   voxel (the cells, hence the centroids, are then those of the last
   iteration: a fixed point) or ``iterations`` is reached; each then snaps to
   the centre of the voxel it lies in.

Placement measures distances with the 26-neighbour Dijkstra from the frames'
voxels (:func:`geodesic_distance` with ``method="dijkstra"``), not with fast
marching: it is ~4x cheaper per voxel, a cell depends only on the voxels of
the frames, and a Lloyd iteration re-marches only the cells of the frames that
changed voxel (exactly, :func:`_repropagate`).  Its bias (up to 12.8 % longer
than the straight line off the lattice directions, none along them) moves the
cell borders by a fraction of that where cells are elongated; the frames stay
evenly spread (tests), and the shape functions are computed with fast
marching.  On the SOFA frames beam (40 frames, natural neighbours, 1000
mid-point samples) the frame model's tip deflection is +0.46 % from the voxel
model's with this placement (+1.04 % with the earlier fast-marching one;
changing only which frame wins exact ties gave +0.04 %: layouts this close
differ by tenths of a percent either way).

Large images (at least ``COARSE_MIN_VOXELS`` = 200,000 material voxels) run
steps 3-5 first on the image halved along every axis (a voxel per 2x2x2 block
holding material; recursively while it is still large), map each automatic
frame to the nearest material voxel of its block, and finish with at most
``FINE_ITERATIONS`` = 3 Lloyd iterations at full resolution.  A Lloyd
iteration costs about one full Dijkstra (most cells change in the early ones),
so this replaces ~10 full-resolution marches and the farthest-point marches
(~4.5 V) by three: on a 128³ cube with 50 frames, 4.2 s of CPU instead of
12.7 s (same run), with a Lloyd energy (mean squared distance to the nearest
frame) 0.55 % higher and a covering radius 8.6 % larger (43.2 voxels against
39.8: Lloyd does not minimise it).  The
halved image is used only where it is faithful: no blocks joined without
neighbouring material voxels (a one-voxel gap or slit stays open), blocks
filled to 90 % on average (no thin plates), the same components; else the
placement is the full-resolution one.  The SOFA beam (40,000 voxels) is below
the threshold and placed as before.

Example
-------
>>> import numpy as np
>>> from voxflex.image import LabelImage
>>> img = LabelImage(np.ones((20, 4, 4), np.uint8), spacing=(0.1, 0.1, 0.1))
>>> place_frames(img, 2).shape
(2, 3)
"""

from __future__ import annotations

import numpy as np

from .._ties import TIE, first_extreme

from ..errors import InputError, check_choice
from . import _march as M
from .geodesic import _centres, _prepare, _seed_voxels, check_image, check_seed, voxel_units

__all__ = ["place_frames", "pinned_frames", "strain_density", "STRAIN_EXPONENT", "STRAIN_CLIP"]

DISTANCES = ("geodesic", "compliance")
#: images with at least this many material voxels are first placed at half resolution
COARSE_MIN_VOXELS = 200_000
#: fine Lloyd iterations after a half-resolution placement
FINE_ITERATIONS = 3


STRAIN_EXPONENT = 0.5
"""``[nodes] placement = "strain"``: frames per volume follow ``(e / e_mean)^0.5`` (e the first solve's strain
energy density): an energy-error equidistribution for quadratically complete kinematics would put
``(|grad^3 u|^2)^(3/7)``; the strain energy is a proxy of lower order, and the square root keeps the
unstrained parts (a cantilever's free end carries the motion) from being starved."""

STRAIN_CLIP = 16.0
"""``e / e_mean`` is clipped to [1/16, 16] before the exponent: frame densities within a factor 16 of each other
(spacings within 16^(1/3) = 2.5), so that a stress singularity (a clamp's edge) cannot take every frame."""


def strain_density(energy, image, *, exponent=STRAIN_EXPONENT, clip=STRAIN_CLIP):
    """Relative frame density (for :func:`place_frames`' ``density``) from a strain-energy density image.

    Parameters
    ----------
    energy : (nx, ny, nz) float, Pa, >= 0 in the material (e.g. :func:`voxflex.build.strain_indicator`)
    image : LabelImage
    exponent, clip : float, see :data:`STRAIN_EXPONENT` and :data:`STRAIN_CLIP`

    Returns
    -------
    (nx, ny, nz) float: ``clip(e / mean(e), 1 / clip, clip) ** exponent`` in the material (1 outside); all ones
    when the energy is zero everywhere (nothing to follow).
    """
    e = np.asarray(energy, dtype=np.float64)
    material = image.labels > 0
    if e.shape != image.shape or not np.all(np.isfinite(e[material])) or np.any(e[material] < 0):
        raise InputError(f"energy must be a finite, non-negative image of shape {image.shape}")
    mean = float(e[material].mean()) if material.any() else 0.0
    out = np.ones(image.shape)
    if mean > 0:
        out[material] = np.clip(e[material] / mean, 1.0 / clip, clip) ** exponent
    return out


def _compliance_for(distance, compliance):
    check_choice("distance", distance, DISTANCES)
    if distance == "compliance" and compliance is None:
        raise InputError("distance='compliance' needs compliance={label: young_modulus}")
    if distance == "geodesic" and compliance is not None:
        raise InputError("compliance is used only with distance='compliance'; pass both or neither")
    return compliance if distance == "compliance" else None


def _boxes(fixed):
    out = []
    for i, box in enumerate(fixed):
        try:
            lo, hi = (np.asarray(b, dtype=np.float64) for b in box)
        except (TypeError, ValueError):
            raise InputError(f"fixed[{i}] must be a pair (min (3,), max (3,)) of world corners") from None
        if lo.shape != (3,) or hi.shape != (3,) or np.any(np.isnan(lo)) or np.any(np.isnan(hi)):
            raise InputError(f"fixed[{i}] must be a pair (min (3,), max (3,)) of world corners (+-inf allowed, no NaN)")
        if np.any(hi < lo):
            raise InputError(f"fixed[{i}] has max < min along some axis: {lo.tolist()} .. {hi.tolist()}")
        out.append((lo, hi))
    return out


def voxels_touching_box(image, lo, hi) -> np.ndarray:
    """Boolean image: the voxels whose (closed, world-aligned bounding) box meets the box [lo, hi].

    A fixed region is often a thin box around a face of the object (``x <= 0``):
    it holds no voxel centre but touches the first layer of voxels.  Frames are
    placed in, and a fixed region holds the frames of, the voxels it touches.
    """
    ijk = np.indices(image.shape).reshape(3, -1).T
    return voxel_boxes_meet(image, ijk, lo, hi).reshape(image.shape)


def voxel_boxes_meet(image, ijk, lo, hi) -> np.ndarray:
    """(m,) bool: whether the (closed, world-aligned bounding) box of each voxel ``ijk`` (m, 3) meets the box
    [lo, hi] (:func:`voxels_touching_box` for a few voxels: a frame model's held frames)."""
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    centres = _centres(image, np.asarray(ijk).reshape(-1, 3))
    half = 0.5 * np.abs(np.asarray(image.direction, dtype=float)) @ np.asarray(image.spacing, dtype=float)
    tol = 1e-9 * float(np.max(image.spacing))
    return np.all((centres + half >= lo - tol) & (centres - half <= hi + tol), axis=1)


def place_frames(image, count, *, positions=None, fixed=(), seed=0, distance="geodesic", compliance=None,
                 iterations=10, density=None):
    """Frame positions spread evenly over the material in the geodesic metric (see :func:`_place_frames`
    for the parameters).

    The placement runs on the image in voxel units (spacing divided by the smallest edge, rounded to 12
    digits; origin at 0), so that the same scene in any unit of length places the same frames: distances
    in metres round differently at each unit, and the marches' bucket queue, the Lloyd centroids' voxels and
    the ties between equidistant frames followed the rounding (a beam at 1 m and at 0.37 m or 1 mm got
    frames a voxel apart).  The automatic frames come back at the voxel centres of ``image``.
    """
    import dataclasses

    check_image(image)
    seed = check_seed(seed)
    spacing_u, h = voxel_units(image.spacing)
    origin = np.asarray(image.origin, dtype=np.float64)
    unit = dataclasses.replace(image, spacing=spacing_u, origin=np.zeros(3))

    def to_unit(x):
        return (np.asarray(x, dtype=np.float64) - origin) / h

    # checked in the scene's own unit first: the messages name what the user wrote, not voxel units
    if positions is not None and np.size(positions):
        _seed_voxels(image, positions, name="positions")
    world = _boxes(fixed)
    material = image.labels > 0
    for i, (lo, hi) in enumerate(world):
        if not voxels_touching_box(image, lo, hi)[material].any():
            raise InputError(f"fixed[{i}] box {lo.tolist()} .. {hi.tolist()} touches no material voxel (the object "
                             f"spans {_extent(image)}); move or enlarge it")
    pos_u = None if positions is None else to_unit(np.asarray(positions, dtype=np.float64).reshape(-1, 3))
    fixed_u = [(to_unit(lo), to_unit(hi)) for lo, hi in world]
    out = _place_frames(unit, count, positions=pos_u, fixed=fixed_u, seed=seed, distance=distance,
                        compliance=compliance, iterations=iterations, density=density)
    out = np.asarray(out, dtype=np.float64).reshape(-1, 3)
    k = 0 if positions is None else len(pos_u)
    res = np.empty_like(out)
    if k:
        res[:k] = np.asarray(positions, dtype=np.float64).reshape(-1, 3)  # user frames exactly as given
    ijk = np.floor(unit.world_to_index(out[k:]) + 1e-6).astype(np.int64)  # automatic frames: voxel centres
    res[k:] = image.index_to_world(ijk + 0.5)
    return res


def _extent(image) -> str:
    """The material's world bounding box, as a message shows it."""
    boxes = list(image.world_bounding_boxes().values())
    lo = np.min([b[0] for b in boxes], axis=0)
    hi = np.max([b[1] for b in boxes], axis=0)
    return f"{[float(f'{v:.6g}') for v in lo]} .. {[float(f'{v:.6g}') for v in hi]}"


def _place_frames(image, count, *, positions=None, fixed=(), seed=0, distance="geodesic", compliance=None,
                  iterations=10, density=None):
    """Frame positions spread evenly over the material in the geodesic metric.

    Parameters
    ----------
    image : voxflex.image.LabelImage
        The object (label 0 is empty).
    count : int
        Total number of frames, user and automatic ones included; 1 <= count
        <= number of material voxels.
    positions : (k, 3) float array, metres, optional
        User frames, placed first and kept exactly as given; each must lie in
        a material voxel.
    fixed : sequence of (min (3,), max (3,)) world boxes, metres
        Regions with boundary conditions: at least one frame ends up inside the
        material part of each (one is added when none is there).
    seed : int
        Seed of the draw of the first frame of a component; the result is
        deterministic for a given seed.
    distance : {"geodesic", "compliance"}
        The metric; ``"compliance"`` needs ``compliance={label: young_modulus}``.
    compliance : dict, optional
        Young's modulus per label (see :func:`geodesic_distance`).
    iterations : int
        Maximum number of Lloyd iterations (0 disables the relaxation); on
        large images those of the half-resolution placement, followed by at
        most 3 at full resolution (see the module notes).
    density : (nx, ny, nz) float array, optional
        Relative frame density wanted in each material voxel (> 0, dimensionless;
        e.g. from a first solve's strain energy: ``[nodes] placement = "strain"``).
        Distances are measured with the slowness ``density^(1/3)`` (a frame's cell
        is smaller where the density is higher: frames per volume follow the
        density) and the Lloyd centroids are weighted by the density.  The
        half-resolution shortcut of large images is not used with it.

    Returns
    -------
    (n, 3) float array, metres
        World positions, n = count: user positions, then fixed-box frames, then
        component frames, then the farthest-point ones; automatic frames sit at
        voxel centres.

    Raises
    ------
    InputError
        count < 1 or above the number of material voxels, a user position
        outside the material, a fixed box without material, more frames
        required (positions, boxes, components) than ``count``.

    References
    ----------
    Y. Eldar et al., "The farthest point strategy for progressive image
    sampling", IEEE TIP 6(9), 1997.  S. Lloyd, "Least squares quantization in
    PCM", IEEE TIT 28(2), 1982.
    """
    from scipy import ndimage

    comp = _compliance_for(distance, compliance)
    material = image.labels > 0
    nmat = int(material.sum())
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)):
        raise InputError(f"count must be an integer number of frames, got {count!r}")
    count = int(count)
    if count < 1:
        raise InputError(f"count must be >= 1 (number of frames), got {count}")
    if count > nmat:
        raise InputError(f"count = {count} exceeds the {nmat} material voxels; ask for at most {nmat} frames")
    iterations = int(iterations)
    if iterations < 0:
        raise InputError(f"iterations must be >= 0, got {iterations}")
    boxes = _boxes(fixed)

    mask, cost, pshape, spacing = _prepare(image, comp)
    weight = None
    if density is not None:
        density = np.asarray(density, dtype=np.float64)
        if density.shape != image.shape:
            raise InputError(f"density must be an image of shape {image.shape}, got {density.shape}")
        if not np.all(np.isfinite(density[material])) or np.any(density[material] <= 0):
            raise InputError("density must be finite and positive in every material voxel")
        d = np.where(material, density, 1.0) / float(np.mean(density[material]))
        # rounded to TIE: a density from a solve carries its round-off (1e-13), which decided the ties of the
        # marches (voxels equidistant from two frames) differently at each unit of the same scene
        d = np.maximum(np.round(d / TIE) * TIE, TIE)
        cost = cost * M.pad_grid(material, np.cbrt(d))[1]
        weight = d[material]
    ijk = np.argwhere(material)
    centres = _centres(image, ijk)
    mflat = M.inner_to_flat(ijk, pshape)
    vox_id = -np.ones(image.shape, dtype=np.int64)
    vox_id[material] = np.arange(nmat)

    frames, frame_vox, n_user = _pinned(image, positions, boxes, material, vox_id, centres)
    n_pinned = len(frames)

    comp_lab, ncomp = ndimage.label(material, structure=np.ones((3, 3, 3), bool))
    comp_of = comp_lab[material]  # per material voxel, 1..ncomp
    has = np.zeros(ncomp + 1, bool)
    has[comp_of[np.asarray(frame_vox, dtype=np.int64)]] = True
    rng = np.random.default_rng(seed)
    missing = [c for c in range(1, ncomp + 1) if not has[c]]
    if len(frames) + len(missing) > count:
        raise InputError(
            f"count = {count} is too small: {n_user} user frame(s), {n_pinned - n_user} for fixed boxes and "
            f"{len(missing)} for components without a frame need {len(frames) + len(missing)}; raise count"
        )
    for c in missing:
        members = np.flatnonzero(comp_of == c)
        v = int(members[rng.integers(len(members))])
        frames.append(centres[v])
        frame_vox.append(v)

    def seeds_of(pos):
        return image.world_to_index(np.asarray(pos).reshape(-1, 3)) + M.PAD

    coarse = None
    if iterations > 0 and comp is None and density is None and nmat >= COARSE_MIN_VOXELS:
        coarse = _coarse_layout(image, material, ncomp, count, frames[:n_pinned], seed, iterations)
    if coarse is not None:  # automatic frames from the half-resolution placement, then a few fine Lloyd steps
        del frames[n_pinned:], frame_vox[n_pinned:]
        taken = set(frame_vox)
        for c in coarse:
            v = _fine_voxel_of(image, material, vox_id, c, taken)
            taken.add(v)
            frames.append(centres[v])
            frame_vox.append(v)
        iterations = min(iterations, FINE_ITERATIONS)

    # farthest-point sampling in the Dijkstra metric, re-propagating only where a new frame is nearer
    dist, owner = M.march(mask, cost, pshape, spacing, seeds_of(frames), np.arange(len(frames)), fmm=0)
    while len(frames) < count:
        dm = dist[mflat]
        dm = np.where(np.isfinite(dm), dm, -1.0)
        v = int(first_extreme(dm, "max"))
        frames.append(centres[v])
        frame_vox.append(v)
        M.march(mask, cost, pshape, spacing, seeds_of(centres[v]), [len(frames) - 1], fmm=0, dist=dist, owner=owner)

    # Lloyd relaxation of the automatic frames (user and fixed-box frames stay), on continuous
    # positions: a frame moves to its cell's centroid (or, when the centroid is not in a voxel
    # of the cell, to the cell's voxel centre nearest it, lowest index on ties) and snaps to the
    # centre of its voxel at the end.  Moving voxel by voxel instead stalls wherever the
    # centroid is within half a voxel of the frame, or exactly half-way between two centres.
    # The cells are those of the frames' voxel centres, so only the frames whose voxel changed
    # are re-propagated (:func:`_repropagate`), and an iteration where none changed is a fixed point.
    frame_vox = np.asarray(frame_vox, dtype=np.int64)
    movable = np.flatnonzero(np.arange(len(frames)) >= n_pinned)
    pos = np.array(frames, dtype=np.float64).reshape(-1, 3)
    n = len(pos)
    cur_vox = frame_vox.copy()
    for it in range(iterations if len(movable) else 0):
        own = owner[mflat]
        cnt = np.bincount(own, minlength=n).astype(np.float64)
        wsum = cnt if weight is None else np.bincount(own, weights=weight, minlength=n)
        wc = centres if weight is None else centres * weight[:, None]
        cen = np.stack([np.bincount(own, weights=wc[:, a], minlength=n) for a in range(3)], axis=1)
        cen /= np.where(wsum > 0, wsum, 1.0)[:, None]
        # a symmetric cell's centroid lies on a voxel face, where the density's round-off (1e-13) decided the
        # voxel (1 m and 1 um beams put a frame on mirror voxels): within TIE of a face it counts as on it
        cijk = np.floor(image.world_to_index(cen) + TIE).astype(np.int64)
        inside = np.all((cijk >= 0) & (cijk < np.array(image.shape)), axis=1)
        cvox = np.full(n, -1, dtype=np.int64)
        cvox[inside] = vox_id[tuple(cijk[inside].T)]
        ok = (cvox >= 0) & (cnt > 0)
        ok[ok] = own[cvox[ok]] == np.flatnonzero(ok)
        best = np.full(n, -1, dtype=np.int64)
        lost = movable[~ok[movable] & (cnt[movable] > 0)]
        if len(lost):  # the cell's voxel nearest its centroid (lowest index on ties)
            sel = np.flatnonzero(np.isin(own, lost))
            d2 = ((centres[sel] - cen[own[sel]]) ** 2).sum(1)
            order = np.lexsort((sel, d2, own[sel]))
            first = np.r_[0, np.flatnonzero(np.diff(own[sel][order])) + 1]
            best[own[sel][order[first]]] = sel[order[first]]
        new_vox = cur_vox.copy()
        for i in movable:
            if ok[i]:
                pos[i] = cen[i]
                new_vox[i] = cvox[i]
            elif best[i] >= 0:
                pos[i] = centres[best[i]]
                new_vox[i] = best[i]
        changed = np.flatnonzero(new_vox != cur_vox)
        cur_vox = new_vox
        if len(changed) == 0 or it == iterations - 1:
            break  # same voxels, same cells: the positions are the fixed point
        if cnt[changed].sum() > 0.5 * nmat:  # most cells change: a fresh march is cheaper than clearing them
            seeds = seeds_of(pos)
            seeds[movable] = M.PAD + np.floor(seeds[movable] - M.PAD) + 0.5  # the voxel centres
            dist, owner = M.march(mask, cost, pshape, spacing, seeds, np.arange(n), fmm=0)
        else:
            _repropagate(mask, cost, pshape, spacing, dist, owner, changed, mflat[cur_vox[changed]])
    for i in movable:
        ijk = np.floor(image.world_to_index(pos[i][None])[0] + TIE).astype(np.int64)
        frames[i] = image.index_to_world((ijk + 0.5)[None])[0]
    return np.array(frames, dtype=np.float64).reshape(-1, 3)


def _pinned(image, positions, boxes, material, vox_id, centres):
    """Steps 1-2 of :func:`place_frames`: the user's positions, then one frame in every fixed box holding
    none.  Returns (world positions (list), material voxel ids (list), number of user frames)."""
    frames: list[np.ndarray] = []  # world positions
    frame_vox: list[int] = []      # material voxel id of each frame
    if positions is not None and np.size(positions):
        P, _, pijk = _seed_voxels(image, positions, name="positions")
        frames.extend(P)
        frame_vox.extend(vox_id[tuple(pijk.T)].tolist())
    n_user = len(frames)
    for i, (lo, hi) in enumerate(boxes):
        inside = voxels_touching_box(image, lo, hi)[material]
        if not inside.any():
            raise InputError(f"fixed[{i}] box {lo.tolist()} .. {hi.tolist()} touches no material voxel; "
                             "move or enlarge it")
        if frame_vox and np.any(inside[np.asarray(frame_vox, dtype=np.int64)]):
            continue
        sel = np.flatnonzero(inside)
        c = centres[sel].mean(axis=0)
        v = int(sel[first_extreme(((centres[sel] - c) ** 2).sum(1), "min")])
        frames.append(centres[v])
        frame_vox.append(v)
    return frames, frame_vox, n_user


def pinned_frames(image, *, positions=None, fixed=()):
    """The frames :func:`place_frames` places first: the user's ``positions`` (kept as given), then one frame
    in the material part of every ``fixed`` box that holds none yet (the material voxel nearest the centroid
    of that part).  Returns (k, 3) world positions (k = 0 without either).  Eigenmode weights choose the
    other frames from their modes (:mod:`voxflex.voronoi.eigenmode`)."""
    material = image.labels > 0
    ijk = np.argwhere(material)
    vox_id = -np.ones(image.shape, dtype=np.int64)
    vox_id[material] = np.arange(len(ijk))
    frames, _, _ = _pinned(image, positions, _boxes(fixed), material, vox_id, _centres(image, ijk))
    return np.array(frames, dtype=np.float64).reshape(-1, 3)


def _repropagate(mask, cost, pshape, spacing, dist, owner, changed, seed_flat):
    """Move the frames ``changed`` to the voxels ``seed_flat`` (flat padded) in a Dijkstra field.

    Their cells are cleared and re-marched from the new voxels and from the material voxels
    bordering the cleared region (with their current distances): the result equals a fresh
    Dijkstra from every frame (up to which frame wins an exact tie), at the cost of the cleared
    cells and of what the moved frames take from their neighbours.
    """
    reset = np.flatnonzero(np.isin(owner, changed))
    dist[reset] = np.inf
    owner[reset] = -1
    off = (np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij")).reshape(3, -1).T
           @ np.array([pshape[1] * pshape[2], pshape[2], 1])).astype(np.int64)
    near = np.zeros(mask.shape[0], dtype=bool)
    for o in off:
        near[reset + o] = True
    ring = np.flatnonzero(near & (mask != 0) & np.isfinite(dist))
    si = np.concatenate([seed_flat, ring]).astype(np.int64)
    sd = np.concatenate([np.zeros(len(seed_flat)), dist[ring]])
    so = np.concatenate([np.asarray(changed, dtype=np.int64), owner[ring]])
    dist[ring] = np.inf  # re-entered as seeds with the same values
    state = M.state_of(mask)
    N = mask.shape[0]
    touched = np.empty(N, dtype=np.int32)
    nxt = np.empty(N, dtype=np.int32)
    prv = np.empty(N, dtype=np.int32)
    M._march(cost, pshape, spacing, dist, owner, state, nxt, prv, dist, False, si, sd, so, 0, touched, 0,
             float(cost.min()), float(cost.max()))


def _coarse_layout(image, material, ncomp, count, pinned, seed, iterations):
    """Automatic frames (world, (count - len(pinned), 3)) placed on the image halved along every axis.

    The half-resolution image holds a voxel wherever its 2x2x2 block holds material.  It is
    used only when it represents the object faithfully: no two neighbouring blocks are joined
    unless some material voxels of theirs are neighbours (so a one-voxel gap or slit does not
    close, and parts are not joined: :func:`_blocks_join_faithfully`), at least 90 % of the
    blocks' volume filled (no thin plates the blocks would thicken), the same number of
    connected components, and enough voxels for ``count`` frames; else None (the caller places
    at full resolution).
    """
    from scipy import ndimage

    from ..image import LabelImage

    pad = [(0, s % 2) for s in material.shape]
    m = np.pad(material, pad)
    nx, ny, nz = (s // 2 for s in m.shape)
    blocks = m.reshape(nx, 2, ny, 2, nz, 2).sum(axis=(1, 3, 5))
    coarse = blocks > 0
    ncoarse = int(coarse.sum())
    if ncoarse < count or material.sum() < 0.9 * 8 * ncoarse or not _blocks_join_faithfully(m):
        return None
    if ndimage.label(coarse, structure=np.ones((3, 3, 3), bool))[1] != ncomp:
        return None
    img = LabelImage(coarse.astype(np.uint8), spacing=2.0 * np.asarray(image.spacing, dtype=np.float64),
                     origin=image.origin, direction=image.direction)
    pos = place_frames(img, count, positions=np.asarray(pinned).reshape(-1, 3) if len(pinned) else None,
                       seed=seed, iterations=iterations)
    return pos[len(pinned):]


def _fine_voxel_of(image, material, vox_id, position, taken):
    """The material voxel (id) of the 2x2x2 block under a half-resolution frame nearest to it (C order
    on ties), skipping voxels that already hold a frame."""
    c = image.world_to_index(np.asarray(position)[None])[0]
    base = 2 * np.floor(c / 2.0).astype(np.int64)
    best, bd = -1, np.inf
    for o in np.ndindex(2, 2, 2):
        ijk = base + o
        if np.any(ijk >= material.shape) or not material[tuple(ijk)]:
            continue
        v = int(vox_id[tuple(ijk)])
        d = float(np.sum((ijk + 0.5 - c) ** 2))
        if v not in taken and d < bd:
            best, bd = v, d
    if best < 0:  # every material voxel of the block holds a frame: the nearest free one in the image
        free = np.flatnonzero(~np.isin(np.arange(int(material.sum())), list(taken)))
        cen = np.argwhere(material)[free] + 0.5
        best = int(free[np.argmin(((cen - c) ** 2).sum(1))])
    return best


def _blocks_join_faithfully(m):
    """True when every two 26-neighbouring 2x2x2 blocks of the (even-shaped) boolean image ``m``
    that both hold material hold a pair of 26-neighbouring material voxels, one in each.

    Voxel ``2B + p`` (block B, parity p in {0, 1}^3) and its neighbour ``2B + p + e`` lie in
    block ``B + o`` with ``o = floor((p + e) / 2)`` per axis: o = -1 needs (p, e) = (0, -1),
    o = +1 needs (1, +1), o = 0 allows (0, 0), (0, 1), (1, -1), (1, 0).
    """
    from itertools import product

    nx, ny, nz = (s // 2 for s in m.shape)
    P = m.reshape(nx, 2, ny, 2, nz, 2).transpose(1, 3, 5, 0, 2, 4)  # P[p0, p1, p2] is (nx, ny, nz)
    Pp = np.pad(P, ((0, 0),) * 3 + ((1, 1),) * 3)
    coarse = P.any(axis=(0, 1, 2))
    cp = np.pad(coarse, 1)

    def shifted(a, o):
        return a[..., 1 + o[0]:1 + o[0] + nx, 1 + o[1]:1 + o[1] + ny, 1 + o[2]:1 + o[2] + nz]

    options = {-1: [(0, -1)], 1: [(1, 1)], 0: [(0, 0), (0, 1), (1, -1), (1, 0)]}
    forward = [o for o in product((-1, 0, 1), repeat=3) if o > (0, 0, 0)]
    for o in forward:
        need = coarse & shifted(cp, o)
        if not need.any():
            continue
        conn = np.zeros_like(coarse)
        for combo in product(*(options[c] for c in o)):
            p = tuple(pe[0] for pe in combo)
            q = tuple(pe[0] + pe[1] - 2 * c for pe, c in zip(combo, o))
            conn |= P[p] & shifted(Pp[q], o)
        if np.any(need & ~conn):
            return False
    return True
