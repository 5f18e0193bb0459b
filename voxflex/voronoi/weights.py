"""Shape functions of frames on a label image: natural neighbours, distance ratio, Shepard.

How values are computed
-----------------------
1. The geodesic Voronoi partition of the frames (second-order fast marching,
   :func:`geodesic_distance`).
2. Weights at **nodes**: the frames themselves (where the weights are exactly
   δ) and a regular lattice of material voxels whose spacing follows the
   frame density, ``s = max(1, round((V / n)^(1/3) / resolution))`` voxels
   (V the number of material voxels, n of frames; ``resolution`` nodes per
   cell width, default 3), plus extra nodes wherever a thin part lies farther
   than ``1.5 s`` voxels from every node.  Natural-neighbour weights come from
   the bounded propagation of :mod:`voxflex.voronoi.natural_neighbour` (work
   per node ~ one cell, so the total is ~ ``resolution³ V`` stolen voxels,
   independent of n: 27 V on a 128³ cube with 50 frames, 1381 nodes).  Where
   a node sees its whole stolen set in a straight line (convex parts) the set
   is found by a span fill with no priority queue: 0.8 s for those 1381 nodes
   on 2 threads (the bounded fast marching it replaces took 1.3 µs per stolen
   voxel, ~70 s of CPU); elsewhere a bounded line-of-sight march.  With
   ``resolution=2`` (3.4x fewer nodes) the SOFA frames beam's tip deflection
   moved from +0.04 % to -13 % of the voxel model's, so 3 stays;
   the same propagation gives the distance-ratio weights (``1 / h_i`` over the
   frames i whose cells the node would steal from, ``h_i`` its distance to
   frame i through their shared border).  Shepard weights read one full
   propagation per frame at the nodes (cost ~ n V).
3. Each node owns the material voxels nearest to it (a Voronoi partition of
   the nodes, through material only) and carries, for each frame seen by it
   or its neighbouring nodes, a quadratic polynomial that interpolates the
   node's own value and fits those of its neighbours by least squares (a tiny
   ridge on the non-constant terms keeps degenerate, e.g. flat, neighbourhoods
   solvable).  Every frame's fit uses the same design matrix, so the fitted
   weights sum to one and their gradients and Hessians to zero exactly (the
   fit of the constant 1 is 1); a point's values are those of the polynomial
   of its voxel's node: w, ∇w and ∇²w are exact derivatives of one smooth
   function inside a node's region (they jump slightly between regions).
4. At a point, weights <= 1e-12 are dropped, the ``parents`` largest are kept and
   renormalised with consistent derivatives.

Choosing ``parents``
--------------------
A point in 3-D has typically 4-8 natural neighbours among evenly placed
frames (Voronoi cells have ~14 faces, but far faces get tiny weights).  4
(the default, the minimum for linear completeness in 3-D) keeps the
assembly cheapest (cost ~ parents²) and drops weights of a few percent
near cell corners; 6-8 keeps the weights closer to the exact natural-neighbour
coordinates.  The pruned weight mass of the unsmoothed evaluation is reported by
:meth:`ShapeFunction.pruned_mass`.  (The frame model cuts its samples' blended weights itself, conformingly:
:func:`~voxflex.voronoi.shape_functions.keep_largest`.)

Example
-------
>>> import numpy as np
>>> from voxflex.image import LabelImage
>>> img = LabelImage(np.ones((20, 4, 4), np.uint8), spacing=(0.1, 0.1, 0.1))
>>> sf = shape_function(img, [[0.05, 0.2, 0.2], [1.95, 0.2, 0.2]], kind="sibson", parents=2)
>>> sv = sf(np.array([[1.0, 0.2, 0.2]]))
>>> bool(abs(sv.w.sum() - 1) < 1e-12)
True
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._jit import njit
from ..errors import InputError, check_choice
from . import _march as M
from ._sight import frame_distances
from .families import FRAME_SHAPE_FUNCTIONS
from .geodesic import _centres, _prepare, _seed_voxels, check_image, voxel_coordinates, voxel_units
from .natural_neighbour import keep_largest_insert, natural_weights, normalise_first
from .placement import _compliance_for
from ._node_fits import _adjacency, _basis, _fit_nodes, fit_nodes  # noqa: F401 - importable here as before
from .shape_functions import ShapeValues, world_points

__all__ = ["ShapeFunction", "shape_function"]

KINDS = FRAME_SHAPE_FUNCTIONS
#: fitted weights up to this are dropped as zero: the compiled and numpy evaluations of the same
#: polynomial differ by round-off (~1e-16), which must not decide whether a frame is a parent
_TINY = 1e-12


@dataclass(frozen=True, eq=False)
class ShapeFunction:
    """Shape functions of frames over the material of an image (see :func:`shape_function`).

    Attributes
    ----------
    frames : (n, 3) float array, metres
    kind : str
    parents : int
    image : voxflex.image.LabelImage

    Calling it with points (m, 3) (world, metres) returns
    :class:`~voxflex.voronoi.shape_functions.ShapeValues` with at most
    ``parents`` parents per point, Hessians included.
    """

    linearly_precise = False
    """Natural-neighbour, distance-ratio and Shepard weights reproduce constants only (not x near the surface)."""

    frames: np.ndarray
    kind: str
    parents: int
    image: object
    _node_pos: np.ndarray = field(repr=False, default=None)    # (Q, 3) world
    _node_of_voxel: np.ndarray = field(repr=False, default=None)  # (nx, ny, nz) int64, -1 outside
    _node_frames: np.ndarray = field(repr=False, default=None)  # (Q, K) int64, -1 padded
    _node_coef: np.ndarray = field(repr=False, default=None)    # (Q, K, 10): value then 9 monomial coefficients
    _scale: float = field(repr=False, default=1.0)
    _anchor: np.ndarray = field(repr=False, default=None)  # (nx, ny, nz) frame owning the voxel outright, -1 else
    smooth: bool = True
    _cache: dict = field(repr=False, default_factory=dict)

    @property
    def n_nodes(self) -> int:
        return len(self.frames)

    def _units(self):
        """(spacing in voxel units, the smallest voxel edge in metres, the fits' length scale in voxel units: the
        one :func:`shape_function` fitted with)."""
        if "units" not in self._cache:
            spacing_u, unit = voxel_units(self.image.spacing)
            self._cache["units"] = spacing_u, unit, _fit_scale(self._scale, unit)
        return self._cache["units"]

    def _unit_positions(self, points) -> np.ndarray:
        """World points (m, 3) in voxel units about the image's origin: the weights are evaluated there, so
        that two equal values (frames tied at the parents' cut) compare the same way in every unit of the
        scene (in metres their round-off decided which frame was kept: a cube's top moved 0.18 % at 1 mm)."""
        return _unit_frame(self.image, points, self._units()[0])

    def _voxels_of(self, points):
        """Material voxel (m, 3) used for each point; InputError naming the first point too far outside."""
        img = self.image
        c = voxel_coordinates(img, points)  # a point on a voxel face picks the same voxel in every unit
        ijk = np.floor(c).astype(np.int64)
        shape = np.array(img.shape)
        inside = np.all((ijk >= 0) & (ijk < shape), axis=1)
        ok = inside.copy()
        ok[inside] = img.labels[tuple(ijk[inside].T)] > 0
        bad = np.flatnonzero(~ok)
        if len(bad):  # points just outside (surface vertices at voxel corners): nearest material neighbour voxel
            half = 0.5 * float(np.max(img.spacing)) * (1 + 1e-9)
            offs = np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij")).reshape(3, -1).T
            cand = ijk[bad][:, None, :] + offs[None]  # (b, 27, 3)
            valid = np.all((cand >= 0) & (cand < shape), axis=2)
            cc = np.clip(cand, 0, shape - 1)
            valid &= img.labels[cc[..., 0], cc[..., 1], cc[..., 2]] > 0
            cb = c[bad][:, None, :]
            gap = np.maximum(np.maximum(cand - cb, cb - (cand + 1)), 0.0) * np.asarray(img.spacing)
            dd = np.where(valid, np.linalg.norm(gap, axis=2), np.inf)
            j = np.argmin(dd, axis=1)  # the first of equal gaps in offset order
            far = dd[np.arange(len(bad)), j] > half
            if np.any(far):
                b = int(bad[np.flatnonzero(far)[0]])
                raise InputError(
                    f"point {b} at {np.asarray(points[b]).tolist()} lies outside the material "
                    "(more than half a voxel from it); evaluate shape functions inside the object"
                )
            ijk[bad] = cand[np.arange(len(bad)), j]
        return ijk

    def __call__(self, points, *, hessians: bool = True) -> ShapeValues:
        """Values, gradients and (unless ``hessians=False``: ``ddw`` None) Hessians at world points (m, 3) inside
        the material."""
        X = world_points(points)
        ijk = self._voxels_of(X)
        if self.smooth:
            return self._smoothed()(X, hessians=hessians)
        sv = self._evaluate(X, self._node_of_voxel[tuple(ijk.T)])
        return sv if hessians else sv.without_hessians()

    def centre_values(self) -> ShapeValues:
        """The weights computed at every material voxel centre (before blending), pruned to
        ``parents``; voxels a frame owns outright (``seed_owner``) carry that frame alone."""
        if "centres" not in self._cache:
            mask = self.image.labels > 0
            X = self.image.voxel_centers(mask)
            sv = self._evaluate(X, self._node_of_voxel[mask])
            if self._anchor is not None and np.any(self._anchor[mask] >= 0):
                own = self._anchor[mask]
                a = own >= 0
                index, w = sv.index.copy(), sv.w.copy()
                dw, ddw = sv.dw.copy(), sv.ddw.copy()
                index[a] = -1
                w[a] = 0.0
                dw[a] = 0.0
                ddw[a] = 0.0
                index[a, 0] = own[a]
                w[a, 0] = 1.0
                sv = ShapeValues(index=index, w=w, dw=dw, ddw=ddw, rest=X, n_nodes=len(self.frames))
            self._cache["centres"] = sv
        return self._cache["centres"]

    def _centre_weights(self):
        """Frame indices and weights (V, parents) at the material voxel centres, as in
        :meth:`centre_values` but without gradients and Hessians (the smoothing reads w only:
        at 128³ the Hessians alone would take V x parents x 9 doubles, 600 MB).  Compiled
        (:func:`_centre_kernel`, voxel by voxel, reading each voxel's node's
        coefficients in place); its numpy twin is :func:`_weights_impl` (tested equal)."""
        mask = self.image.labels > 0
        ijk = np.argwhere(mask)
        # voxel centres in the nodes' frame (index coords: world = origin + (c * spacing) @ direction.T)
        # in voxel units (see _unit_positions): the same weights and the same kept parents in every unit
        spacing_u, _, h_u = self._units()
        cn = voxel_coordinates(self.image, self._node_pos)
        index, w = _centre_kernel(ijk, self._node_of_voxel[mask], cn, spacing_u,
                                  np.asarray(self.image.direction, dtype=np.float64), self._node_frames,
                                  self._node_coef, h_u, int(self.parents))
        if self._anchor is not None:
            own = self._anchor[mask]
            a = own >= 0
            index[a] = -1
            w[a] = 0.0
            index[a, 0] = own[a]
            w[a, 0] = 1.0
        return index, w

    def _smoothed(self):
        if "smooth" not in self._cache:
            from .smoothing import SmoothWeights

            if "centres" in self._cache:
                c = self._cache["centres"]
                index, w = c.index, c.w
            else:
                index, w = self._centre_weights()
            self._cache["smooth"] = SmoothWeights(self.image, index, w, len(self.frames))
        return self._cache["smooth"]

    def voxel_values(self) -> ShapeValues:
        """Values at every material voxel centre, in ``np.flatnonzero(image.labels > 0)`` order (cached)."""
        if "voxels" not in self._cache:
            if self.smooth:
                mask = self.image.labels > 0
                self._cache["voxels"] = self._smoothed()(self.image.voxel_centers(mask))
            else:
                self._cache["voxels"] = self.centre_values()
        return self._cache["voxels"]

    def pruned_mass(self) -> float:
        """Largest weight dropped by the pruning to ``parents`` in the unsmoothed evaluation (before renormalising).

        0 when the weights are smoothed (``smooth=True``, what the frame builder uses): the blended values are
        not cut here, and the frame model's own cut to its parents (conforming, see
        :func:`~voxflex.voronoi.shape_functions.keep_largest`) happens when its samples are built."""
        self.voxel_values()
        return float(self._cache.get("pruned", 0.0))

    def _evaluate(self, X, nodes, chunk=65536):
        m = len(X)
        P = self.parents
        index = np.full((m, P), -1, dtype=np.int64)
        w = np.zeros((m, P))
        dw = np.zeros((m, P, 3))
        ddw = np.zeros((m, P, 3, 3))
        pruned = 0.0
        _, unit, h_u = self._units()
        if "unit_nodes" not in self._cache:
            self._cache["unit_nodes"] = self._unit_positions(self._node_pos)
        npos = self._cache["unit_nodes"]
        for a in range(0, m, chunk):
            b = min(m, a + chunk)
            r = _evaluate_impl(self._unit_positions(X[a:b]), npos[nodes[a:b]], self._node_frames[nodes[a:b]],
                               self._node_coef[nodes[a:b]], h_u, P)
            index[a:b], w[a:b], pr = r[0], r[1], r[4]
            dw[a:b] = r[2] / unit  # per voxel unit -> per metre
            ddw[a:b] = r[3] / (unit * unit)
            pruned = max(pruned, pr)
        self._cache["pruned"] = max(self._cache.get("pruned", 0.0), pruned)
        return ShapeValues(index=index, w=w, dw=dw, ddw=ddw, rest=X, n_nodes=len(self.frames))


def _unit_frame(image, points, spacing_u) -> np.ndarray:
    """World points (m, 3) in voxel units about the image's origin (coordinates without the unit's round-off,
    :func:`~voxflex.voronoi.geodesic.voxel_coordinates`): where the natural-neighbour fits are made and evaluated."""
    return (voxel_coordinates(image, points) * spacing_u) @ np.asarray(image.direction, dtype=np.float64).T


def _fit_scale(h, unit) -> float:
    """The fits' length scale ``h`` (metres) in voxel units, rounded to 12 digits (the same bits at any unit)."""
    return float(np.round(h / unit, 12))


@njit
def _centre_kernel(ijk, nodes, cnode, spacing, direction, nfr, ncoef, h, P):
    """Compiled :func:`_weights_impl` at the material voxel centres ``ijk + 0.5`` (m, 3), each with the
    polynomials of its node (``nodes`` (m,), node positions ``cnode`` in index coords): values,
    w <= 0 dropped, the P largest kept (the first column on ties) and renormalised."""
    m = ijk.shape[0]
    K = nfr.shape[1]
    index = np.full((m, P), -1, dtype=np.int64)
    out = np.zeros((m, P))
    for r in range(m):
        q = nodes[r]
        e0 = (ijk[r, 0] + 0.5 - cnode[q, 0]) * spacing[0]
        e1 = (ijk[r, 1] + 0.5 - cnode[q, 1]) * spacing[1]
        e2 = (ijk[r, 2] + 0.5 - cnode[q, 2]) * spacing[2]
        x = (direction[0, 0] * e0 + direction[0, 1] * e1 + direction[0, 2] * e2) / h
        y = (direction[1, 0] * e0 + direction[1, 1] * e1 + direction[1, 2] * e2) / h
        z = (direction[2, 0] * e0 + direction[2, 1] * e1 + direction[2, 2] * e2) / h
        phi = (x, y, z, x * x, x * y, x * z, y * y, y * z, z * z)
        n = 0
        for k in range(K):
            f = nfr[q, k]
            if f < 0:
                continue
            c = ncoef[q, k]
            v = c[0] + c[1] * phi[0] + c[2] * phi[1] + c[3] * phi[2] + c[4] * phi[3] + c[5] * phi[4] \
                + c[6] * phi[5] + c[7] * phi[6] + c[8] * phi[7] + c[9] * phi[8]
            if v > _TINY:
                n = keep_largest_insert(out[r], index[r], n, P, v, f)
        normalise_first(out[r], n)
    return index, out


def _weights_impl(X, npos, nfr, ncoef, h, P):
    """Values only: the polynomial values at points, w <= 0 dropped, the P largest kept and renormalised.

    Per point (npos (m, 3), nfr (m, K), ncoef (m, K, 10)) or, for points of one node, the node's
    own (npos (3,), nfr (K,), ncoef (K, 10)).
    """
    x = (X - npos) / h
    phi, _, _ = _basis(x)
    if ncoef.ndim == 2:
        w = ncoef[:, 0] + phi @ ncoef[:, 1:].T
        nfr = np.broadcast_to(nfr, w.shape)
    else:
        w = ncoef[..., 0] + np.einsum("mkb,mb->mk", ncoef[..., 1:], phi)
    valid = (nfr >= 0) & (w > _TINY)
    ws = np.where(valid, w, -np.inf)
    rows = np.arange(len(X))[:, None]
    order = np.argsort(-ws, axis=1, kind="stable")[:, :P]  # the first column on ties, as the kernel
    keep = valid[rows, order]
    index = np.full((len(X), P), -1, dtype=np.int64)
    out = np.zeros((len(X), P))
    k = order.shape[1]
    index[:, :k] = np.where(keep, nfr[rows, order], -1)
    wk = np.where(keep, w[rows, order], 0.0)
    out[:, :k] = wk / wk.sum(1)[:, None]
    return index, out


def _evaluate_impl(X, npos, nfr, ncoef, h, P):
    """Polynomial values at points, drop w <= 0, keep the P largest, renormalise (consistent derivatives)."""
    x = (X - npos) / h
    phi, dphi, H = _basis(x)
    w = ncoef[..., 0] + np.einsum("mkb,mb->mk", ncoef[..., 1:], phi)
    dw = np.einsum("mkb,mbi->mki", ncoef[..., 1:], dphi) / h
    ddw = np.einsum("mkb,bij->mkij", ncoef[..., 1:], H) / (h * h)
    valid = (nfr >= 0) & (w > _TINY)
    ws = np.where(valid, w, -np.inf)
    order = np.argsort(-ws, axis=1, kind="stable")[:, :P]
    rows = np.arange(len(X))[:, None]
    keep = valid[rows, order]
    fi = np.where(keep, nfr[rows, order], -1)
    wk = np.where(keep, w[rows, order], 0.0)
    dk = np.where(keep[..., None], dw[rows, order], 0.0)
    hk = np.where(keep[..., None, None], ddw[rows, order], 0.0)
    total = np.where(valid, w, 0.0).sum(1)
    S = wk.sum(1)
    pruned = float(np.max(total - S)) if len(X) else 0.0
    dS = dk.sum(1)
    hS = hk.sum(1)
    wn = wk / S[:, None]
    dn = (dk - wn[..., None] * dS[:, None, :]) / S[:, None, None]
    hn = (hk - dn[..., :, None] * dS[:, None, None, :] - dS[:, None, :, None] * dn[..., None, :]
          - wn[..., None, None] * hS[:, None]) / S[:, None, None, None]
    hn = 0.5 * (hn + hn.transpose(0, 1, 3, 2))
    pad = ~keep
    dn[pad] = 0.0
    hn[pad] = 0.0
    k = fi.shape[1]
    if k < P:  # fewer candidate frames than parents: pad the slots
        m = len(X)
        fi = np.concatenate([fi, np.full((m, P - k), -1, dtype=np.int64)], axis=1)
        wn = np.concatenate([wn, np.zeros((m, P - k))], axis=1)
        dn = np.concatenate([dn, np.zeros((m, P - k, 3))], axis=1)
        hn = np.concatenate([hn, np.zeros((m, P - k, 3, 3))], axis=1)
    return fi, wn, dn, hn, pruned


def shape_function(image, frames, *, kind="natural-neighbour", parents=None, distance="geodesic", compliance=None,
                   resolution=3.0, seed_owner=None, smooth=True, support=None, count=None, stiffness=None,
                   density=None):
    """Shape functions of ``frames`` over the material of ``image``.

    Parameters
    ----------
    image : voxflex.image.LabelImage
    frames : (n, 3) float array, metres
        Frame positions, each in a material voxel, at most one per voxel, at
        least one in every connected component of the material.
    kind : {"natural-neighbour", "sibson", "laplace", "distance-ratio", "shepard", "reproducing-kernel", "eigenmode"}
        ``"natural-neighbour"`` is Sibson's coordinates.  ``"distance-ratio"``:
        ``w_i ~ 1 / h_i`` over the point's natural neighbours i (the frames
        whose cells it would steal from), ``h_i`` its geodesic distance to frame
        i measured through the boundary it shares with i's cell: 1 at the frame,
        0 at the neighbouring frames, 1/2 on a border between two cells where
        no third cell is a natural neighbour, exactly ``1 - d/L`` along a bar.
        ``"shepard"``: ``w_i ~ d_i^-2`` over all frames (geodesic ``d_i``; one
        full propagation per frame, so the cost grows as n times the image),
        for comparison: no linear precision, global support.
        ``"reproducing-kernel"``: geodesic Wendland kernels of radius ``support``
        local frame spacings, corrected at the voxel corners to reproduce linear
        fields exactly and interpolated trilinearly in between
        (:mod:`voxflex.voronoi.reproducing_kernel`; returns a
        :class:`~voxflex.voronoi.reproducing_kernel.ReproducingKernel`).
        ``"eigenmode"``: skinning eigenmodes, global weights from the lowest modes
        of the scalar elastic energy on the voxel grid
        (:mod:`voxflex.voronoi.eigenmode`; returns an
        :class:`~voxflex.voronoi.eigenmode.EigenmodeWeights` whose ``frames`` are
        the given ``frames`` followed by the points chosen from the modes, up to
        ``count``).
    parents : int, optional
        At most this many frames per point (>= 1; default 4); see the module
        notes.  Reproducing-kernel weights are never truncated (that would break
        the partition of unity, linear precision and conformity): every frame
        whose kernel reaches a point is a parent, and a ``parents`` below that
        number is raised with a warning.
    distance : {"geodesic", "compliance"}
    compliance : dict {label: young_modulus}, with ``distance="compliance"``.
    resolution : float
        Weight nodes per Voronoi-cell width (> 0); cost grows as its cube.
    seed_owner : (nx, ny, nz) int array, optional
        Voxels that belong to a frame outright (its index; -1 elsewhere): they
        seed the distances together with the frame, so the frame's cell
        contains them and every material point there moves with that frame
        alone (weight 1).  The frame model uses it for fixed regions, so that
        a clamp holds all the material it touches, not only the frame's voxel.
    smooth : bool
        Blend the voxel-centre weights with the quadratic B-spline over the
        material (:mod:`voxflex.voronoi.smoothing`; default): continuous values
        and gradients everywhere, which quadrature and Newton need (the
        voxel-by-voxel values jump between the weight nodes' regions and where
        the pruned parent set changes, and jumps act as cracks that samples do
        not see: on a cantilever they made the frame model 30-100 % too soft).
        The blend keeps the partition of unity and non-negativity, keeps
        ``parents`` at the voxel centres but may give a point more parents (the
        union over its 27 neighbouring voxels), and smooths the value 1 at a
        frame (unless the frame owns a seed region).  ``False``: the
        voxel-by-voxel values, pruned to ``parents``.  Not used by
        ``"reproducing-kernel"`` (continuous by construction).
    support : float, optional
        ``"reproducing-kernel"`` only: the kernel radius in local frame spacings
        (default :data:`~voxflex.voronoi.reproducing_kernel.DEFAULT_SUPPORT`).
    count : int, optional
        ``"eigenmode"`` only: the number of frames (default ``len(frames)``); the
        frames beyond the given ones are chosen from the modes.  ``frames`` may then
        be empty.
    stiffness, density : dict {label: ...}, optional
        ``"eigenmode"`` only: the trace ``D`` (3x3, Pa) of each label's rest tangent
        and its density (kg/m^3) (:func:`~voxflex.voronoi.eigenmode.scalar_operators`;
        default 1: the modes of the plain Laplacian).

    Returns
    -------
    ShapeFunction or ReproducingKernel

    References
    ----------
    R. Sibson, "A vector identity for the Dirichlet tessellation", Math. Proc.
    Camb. Phil. Soc. 87, 1980.  N. Sukumar et al., "Natural neighbour Galerkin
    methods", IJNME 50, 2001 (Laplace).  B. Gilles et al., "Frame-based
    elastic models", ACM TOG 30(2), 2011.
    """
    check_image(image)
    check_choice("kind", kind, KINDS)
    comp = _compliance_for(distance, compliance)
    rk = kind == "reproducing-kernel"
    if kind != "eigenmode" and (count is not None or stiffness is not None or density is not None):
        raise InputError(f'count, stiffness and density apply to kind = "eigenmode" only, not "{kind}"')
    if kind == "eigenmode":
        return _eigenmode(image, frames, parents, support, seed_owner, count, stiffness, density)
    if parents is None:
        parents = None if rk else 4
    elif isinstance(parents, bool) or not isinstance(parents, (int, np.integer)) or int(parents) < 1:
        raise InputError(f"parents must be an integer >= 1, got {parents!r}")
    else:
        parents = int(parents)
    if support is not None and not rk:
        raise InputError(f'support applies to kind = "reproducing-kernel" only, not "{kind}"')
    resolution = float(resolution)
    if not resolution > 0:
        raise InputError(f"resolution must be > 0, got {resolution}")
    F, fc, fijk = _seed_voxels(image, frames, name="frames")
    n = len(F)
    material = image.labels > 0
    vox_id = -np.ones(image.shape, dtype=np.int64)
    nmat = int(material.sum())
    vox_id[material] = np.arange(nmat)
    fv = vox_id[tuple(fijk.T)]
    if len(np.unique(fv)) != n:
        dup = np.flatnonzero(np.bincount(fv) > 1)[0]
        raise InputError(f"two frames share material voxel {np.argwhere(material)[dup].tolist()}; keep one per voxel")
    mask, cost, pshape, spacing_m = _prepare(image, comp)
    # the marches and the natural neighbours' stealing run in voxel units (their ties then break the same
    # way in every unit of the scene); distances come back in metres only where they leave (the kernels')
    spacing, unit = voxel_units(spacing_m)
    seed_pts, seed_own = fc + M.PAD, np.arange(n)
    anchored = np.zeros(image.shape, dtype=bool)
    if seed_owner is not None:
        seed_owner = np.asarray(seed_owner)
        if seed_owner.shape != image.shape or not np.issubdtype(seed_owner.dtype, np.integer):
            raise InputError(f"seed_owner must be an integer image of shape {image.shape}, -1 where unused")
        anchored = (seed_owner >= 0) & material
        if np.any(seed_owner[anchored] >= n):
            raise InputError(f"seed_owner refers to frame {int(seed_owner.max())} but there are {n} frames")
        aijk = np.argwhere(anchored)
        seed_pts = np.concatenate([seed_pts, aijk + 0.5 + M.PAD])
        seed_own = np.concatenate([seed_own, seed_owner[anchored].astype(np.int64)])
    d, own = frame_distances(mask, cost, pshape, spacing, seed_pts, seed_own)
    ijk = np.argwhere(material)
    mflat = M.inner_to_flat(ijk, pshape)
    if np.any(own[mflat] < 0):
        raise InputError("a connected component of the material has no frame; place one in every component "
                         "(place_frames does)")
    if rk:
        import warnings

        from .reproducing_kernel import DEFAULT_SUPPORT, reproducing_kernel

        sf = reproducing_kernel(image, F, d * unit, own, mask, cost, pshape,
                                support=DEFAULT_SUPPORT if support is None else support,
                                anchored=anchored if np.any(anchored) else None, seed_owner=seed_owner)
        if parents is not None and parents < sf.parents:
            warnings.warn(f"reproducing-kernel weights have up to {sf.parents} parents per point (every frame whose "
                          f"kernel reaches it); parents = {parents} would truncate them (breaking the partition of "
                          f"unity, linear precision and conformity), so all are kept", UserWarning, stacklevel=2)
        return sf

    # nodes: frames, then the lattice (without the frame voxels)
    s = max(1, int(round((nmat / n) ** (1.0 / 3.0) / resolution)))
    on = np.all(ijk % s == s // 2, axis=1)
    on[fv] = False
    lat = np.flatnonzero(on)
    centres = _centres(image, ijk)
    node_vox = np.concatenate([fv, lat])
    node_pos = np.concatenate([F, centres[lat]])
    # node regions (Dijkstra, through material), adding nodes in parts far from all
    nd, nown = M.march(mask, cost, pshape, spacing, voxel_coordinates(image, node_pos) + M.PAD,
                       np.arange(len(node_pos)), fmm=0)
    far = 1.5 * s * float(np.max(spacing)) * float(cost.max())
    extra = []
    while True:
        dm = nd[mflat]
        v = int(np.argmax(dm))
        if dm[v] <= far:
            break
        extra.append(v)
        M.march(mask, cost, pshape, spacing, voxel_coordinates(image, centres[v][None]) + M.PAD,
                [len(node_pos) + len(extra) - 1], fmm=0, dist=nd, owner=nown)
    if extra:
        node_vox = np.concatenate([node_vox, extra])
        node_pos = np.concatenate([node_pos, centres[extra]])
    Q = len(node_pos)

    # weights at the nodes
    kmax = 32
    nf = np.full((Q, kmax), -1, dtype=np.int64)
    nw = np.zeros((Q, kmax))
    nf[:n, 0] = np.arange(n)
    nw[:n, 0] = 1.0
    pts = voxel_coordinates(image, node_pos[n:]) + M.PAD
    if kind == "shepard":
        nf[n:], nw[n:] = _shepard_nodes(mask, cost, pshape, spacing, fc + M.PAD, pts, kmax)
    else:
        mode = {"natural-neighbour": 0, "sibson": 0, "laplace": 1, "distance-ratio": 2}[kind]
        nf[n:], nw[n:], _ = natural_weights(mask, cost, pshape, spacing, d, own, pts, n, laplace=mode, kmax=kmax)
    if np.any(anchored):
        # nodes in a frame's own seed region belong to it alone (a point there steals nothing)
        nijk = np.floor(voxel_coordinates(image, node_pos[n:])).astype(np.int64)
        inside = anchored[tuple(nijk.T)]
        nf[n:][inside] = -1
        nw[n:][inside] = 0.0
        rows = n + np.flatnonzero(inside)
        nf[rows, 0] = seed_owner[tuple(nijk[inside].T)]
        nw[rows, 0] = 1.0

    # node adjacency (26-neighbour voxel pairs in different node regions)
    no = M.unpad(nown, pshape)
    pairs = []
    nx, ny, nz = image.shape
    for o in [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (1, -1, 0), (1, 0, 1), (1, 0, -1), (0, 1, 1), (0, 1, -1),
              (1, 1, 1), (1, 1, -1), (1, -1, 1), (1, -1, -1)]:
        sa = tuple(slice(max(0, -c), n_ - max(0, c)) for c, n_ in zip(o, (nx, ny, nz)))
        sb = tuple(slice(max(0, c), n_ - max(0, -c)) for c, n_ in zip(o, (nx, ny, nz)))
        a, b = no[sa], no[sb]
        sel = (a >= 0) & (b >= 0) & (a != b)
        if sel.any():
            pairs.append(np.unique(np.minimum(a[sel], b[sel]) * Q + np.maximum(a[sel], b[sel])))
    pairs = np.unique(np.concatenate(pairs)) if pairs else np.zeros(0, np.int64)
    pa, pb = pairs // Q, pairs % Q

    # per-node quadratic fits (compiled; the numpy twin is _fit_nodes)
    # the fits in voxel units too: their normal equations are singular along the monomials a flat layer of
    # nodes cannot see, and the ridge turns the round-off of positions in metres into coefficients ~1e-8 apart
    # between units, enough to swap two parents at the pruning (a cube's top moved 0.18 % at 1 mm)
    h = s * float(np.max(spacing_m))
    node_frames, node_coef = fit_nodes(_unit_frame(image, node_pos, spacing), nf, nw, pa, pb, _fit_scale(h, unit), n)
    node_of_voxel = -np.ones(image.shape, dtype=np.int64)
    node_of_voxel[material] = nown[mflat]
    return ShapeFunction(frames=F, kind="sibson" if kind == "natural-neighbour" else kind, parents=parents,
                         image=image, _node_pos=node_pos, _node_of_voxel=node_of_voxel,
                         _node_frames=node_frames, _node_coef=node_coef, _scale=h,
                         _anchor=np.where(anchored, seed_owner, -1) if np.any(anchored) else None, smooth=bool(smooth))


def _eigenmode(image, frames, parents, support, seed_owner, count, stiffness, density):
    """Validated inputs of :func:`voxflex.voronoi.eigenmode.eigenmode`."""
    import warnings

    from .eigenmode import eigenmode

    if support is not None:
        raise InputError('support applies to kind = "reproducing-kernel" only, not "eigenmode"')
    F = np.asarray(frames, dtype=np.float64) if frames is not None else np.zeros((0, 3))
    if F.size:
        F, _, fijk = _seed_voxels(image, F, name="frames")
        key = np.ravel_multi_index(tuple(fijk.T), image.shape)
        if len(np.unique(key)) != len(key):
            raise InputError("two frames share a material voxel; keep one per voxel")
    else:
        F = np.zeros((0, 3))
    if count is None:
        count = len(F)
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or int(count) < 1:
        raise InputError(f"count must be an integer >= 1 (the number of eigenmode frames), got {count!r}")
    if seed_owner is not None:
        seed_owner = np.asarray(seed_owner)
        if seed_owner.shape != image.shape or not np.issubdtype(seed_owner.dtype, np.integer):
            raise InputError(f"seed_owner must be an integer image of shape {image.shape}, -1 where unused")
        if np.any(seed_owner >= len(F)):
            raise InputError(f"seed_owner refers to frame {int(seed_owner.max())} but {len(F)} frames are given")
    sf = eigenmode(image, F, int(count), seed_owner=seed_owner, stiffness=stiffness, density=density)
    if parents is not None and parents < sf.parents:
        warnings.warn(f"eigenmode weights are global: up to {sf.parents} parents per point; parents = {parents} "
                      "would truncate them (breaking the partition of unity and conformity), so all are kept",
                      UserWarning, stacklevel=3)
    return sf


def _shepard_nodes(mask, cost, pshape, spacing, frame_pts, pts, kmax, power=2.0):
    """Shepard weights ``d_i^-power / sum_j d_j^-power`` (geodesic d) at node points (q, 3), padded
    index coords, by one full propagation per frame (cost n x the image): the kmax largest, normalised."""
    n, q = len(frame_pts), len(pts)
    ijk = np.floor(pts).astype(np.int64)
    flat = (ijk[:, 0] * pshape[1] + ijk[:, 1]) * pshape[2] + ijk[:, 2]
    g = np.zeros((q, n))
    for i in range(n):
        di, _ = M.march(mask, cost, pshape, spacing, frame_pts[i][None], [i], fmm=2)
        dq = di[flat]
        g[:, i] = np.where(np.isfinite(dq), np.maximum(dq, 1e-300) ** -power, 0.0)
    k = min(kmax, n)
    order = np.argsort(-g, axis=1, kind="stable")[:, :k]
    gk = np.take_along_axis(g, order, axis=1)
    nf = np.full((q, kmax), -1, dtype=np.int64)
    nw = np.zeros((q, kmax))
    nf[:, :k] = np.where(gk > 0, order, -1)
    nw[:, :k] = gk / gk.sum(1)[:, None]
    return nf, nw
