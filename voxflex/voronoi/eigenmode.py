"""Skinning-eigenmode frame weights: the lowest modes of the elastic energy on the voxel grid.

Benchekroun et al. (2023) take the weights of a linear-blend skinning subspace
from the lowest eigenvectors of a *scalar* "weight-space" operator made from the
elastic energy: for an affine handle ``A`` carried by a weight ``w`` the
displacement is ``w(X) A [X; 1]``, and the trace over the three displacement
components of the elasticity Hessian is a material-weighted Laplacian.  Here:

1. **Operators.**  On the nodes of the voxel corners (:class:`TrilinearGrid`, the
   voxel model's own discretisation) the scalar stiffness and mass are

       K = sum_e int grad N^T D_e grad N,     M = sum_e int rho_e N N^T

   (2x2x2 Gauss points, exact for trilinear functions), with
   ``D_jl = sum_d C_djdl`` the trace over the displacement components of the
   material's rest tangent ``C = d2W/dF2 (I)`` (an isotropic material gives
   ``(lambda + 4 mu) I``: stiff labels get flatter modes, soft ones carry the
   bending) and ``rho`` the density (``stiffness`` and ``density`` per label;
   both default to 1).
2. **The weight space S** (dimension = the number of frames n).
   *Without fixed regions* it is ``span{1, x, y, z}`` plus the lowest ``n - 4``
   modes of ``K phi = lambda M phi`` (the constant is the first mode): the
   weights reproduce linear fields exactly, so the blended affine frames
   represent every quadratic displacement (pure bending is exact, and the
   frame model's 18 gauge motions of linearly precise weights appear, see
   :func:`voxflex.deform.models.frames.modes.gauge_modes`).
   *With fixed regions* (``seed_owner``: the voxels a frame owns outright) the
   corners all of whose material voxels a frame owns are Dirichlet corners: S
   is one *lift* per such frame (``h_j = 1`` on its corners, 0 on the others',
   K-harmonic in between: the constant 1 for one region) plus the lowest
   ``n - J`` modes with zero value at every Dirichlet corner.  Every weight
   other than the region's frame vanishes there, so holding that frame holds
   the region exactly (the skinning-eigenmode paper's constrained modes);
   linear precision is given up (the region's motion is prescribed), the
   partition of unity is kept.
3. **Frames** (where the n frames sit, and which weight is whose): the given
   frames first (the ``positions`` of a scene and one per fixed region), then
   the voxel centres chosen by column-pivoted QR of the modal basis at the
   material voxel centres (Q-DEIM, Drmac & Gugercin 2016): the points where the
   modes are most distinguishable, so that interpolation at them is well
   conditioned (a greedy pivoted Gram-Schmidt whose ties -- symmetric bodies -- go to the first voxel in C
   order within a relative 1e-9, so that the same scene in other units picks the same voxels).
   A frame that owns no Dirichlet corner gets the **cardinal
   function** of S at its point (``w_i(X_k) = delta_ik`` over those frames);
   the frame of region j gets ``h_j - sum_k h_j(X_k) l_k`` (``l_k`` the
   cardinal functions of the modes).  Then ``sum_i w_i = 1`` everywhere
   (and ``sum_i w_i X_i = X`` without fixed regions) to round-off.  The weights are
   global (every frame is a parent of every point) and sign-changing; the span
   of the blended frames (``S (x) affine``) depends on the count and the fixed
   regions, not on where the free frames sit.  When the last mode asked for is one of a degenerate cluster
   (:data:`CLUSTER_TOL`; e.g. a square cross-section's two bending directions) the whole cluster is taken
   and the model has **more frames than asked** (the info's frame count says how many): a partial
   cluster would be an arbitrary, round-off-driven subspace (measured on the 32x8x8 cantilever: clusters
   end between counts 5/6, 7/8, 10/11, 12/13, 17/18, 22/23, ..., 39/40 with one clamp frame).
4. **Inside a voxel** the corner values are interpolated trilinearly, like the
   reproducing-kernel weights (C0, conforming, exact derivatives).

Cost: the stiffness assembly grows as ``parents^2`` per sample, and here every
frame is a parent: ``benchmarks/bench_weights_convergence.py --part cost``.

The modes are computed by a block LOBPCG preconditioned by smoothed-aggregation
multigrid (pyamg; a block V-cycle with Jacobi smoothing), started from the
modes of the next coarser aggregation level (recursively, down to a dense
solve): :func:`lowest_modes`.

References
----------
O. Benchekroun, J. Zhang, S. Chaudhuri, E. Grinspun, Y. Zhou, A. Jacobson,
"Fast complicated-object simulation with skinning eigenmodes", ACM TOG 42(4), 2023.
A. V. Knyazev, "Toward the optimal preconditioned eigensolver: LOBPCG", SISC 23(2), 2001.
Z. Drmac, S. Gugercin, "A new selection operator for the discrete empirical
interpolation method", SISC 38(2), 2016.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..errors import InputError
from ..image.grid import TrilinearGrid, trilinear_weights
from .corner_weights import CornerWeights

__all__ = ["EigenmodeWeights", "EigenmodeWarning", "eigenmode", "scalar_operators", "lowest_modes",
           "DENSE_MAX", "MODE_TOL", "CONDITION_MAX"]

DENSE_MAX = 1500
"""Eigenproblems up to this many unknowns are solved densely (scipy.linalg.eigh)."""

MODE_TOL = 1e-6
"""Relative residual ``|K x - lambda M x| / ((|lambda| + lambda_k / 100) |M x|)`` at which a mode is converged
(``lambda_k`` the largest wanted eigenvalue: a free body's zero mode is judged on the wanted spectrum's scale)."""

MAX_ITERATIONS = 60
"""LOBPCG iterations per level at most (a warning names the residual reached when they run out)."""

CLUSTER_TOL = 1e-6
"""Eigenvalues within this relative distance of each other are one (degenerate) cluster: a square section's
two bending directions, a symmetric body's mirror pairs.  A cut through a cluster would keep an arbitrary
(round-off driven) part of it, so the last mode's cluster is always taken whole (see :func:`eigenmode`)."""

GUARD_MODES = 4
"""Modes computed beyond those asked for, to see whether the last one's cluster continues."""

CONDITION_MAX = 1e10
"""Largest admissible condition number of the interpolation matrix of the modes at the free frames:
above it the given frames cannot tell the modes apart (e.g. two frames at the same abscissa of a bar whose
modes vary along it only) and the weights would be (nearly) linearly dependent."""


class EigenmodeWarning(UserWarning):
    """The eigensolver stopped before its tolerance."""


# --------------------------------------------------------------------------- operators
def _gauss_tables(spacing, direction):
    """World gradients (8q, 8, 3) and values (8q, 8) of the corner functions at the 2x2x2 Gauss points."""
    g = 0.5 / np.sqrt(3.0)
    p = np.array([0.5 - g, 0.5 + g])
    local = np.array(np.meshgrid(p, p, p, indexing="ij")).reshape(3, -1).T
    N, dN, _ = trilinear_weights(local)
    G = (dN / np.asarray(spacing, dtype=float)) @ np.asarray(direction, dtype=float).T
    return N, G


def _label_table(image, values, default, name, shape):
    """Per-label table of ``values`` ({label: array of ``shape``}), ``default`` where None."""
    labels = [int(x) for x in np.unique(image.labels[image.labels > 0])]
    table = np.zeros((int(image.labels.max()) + 1,) + shape)
    for lab in labels:
        v = default if values is None else values.get(lab, values.get(str(lab)) if isinstance(values, dict) else None)
        if v is None:
            raise InputError(f"{name} has no value for label {lab}; give one per material label")
        a = np.asarray(v, dtype=float)
        if a.shape == () and shape == (3, 3):
            a = float(a) * np.eye(3)
        if a.shape != shape or not np.all(np.isfinite(a)):
            raise InputError(f"{name}[{lab}] must be a finite array of shape {shape} (or a number), got {v!r}")
        table[lab] = a
    return table


def scalar_operators(image, grid=None, *, stiffness=None, density=None):
    """The scalar weight-space stiffness K and mass M on the voxel corners (see the module docstring).

    Parameters
    ----------
    image : LabelImage
    grid : TrilinearGrid, optional (built from ``image``)
    stiffness : dict {label: (3, 3) array or number}, optional
        ``D`` per label [Pa] (default the identity: a unit Laplacian).
    density : dict {label: number}, optional
        Density per label [kg/m^3] (default 1).

    Returns
    -------
    K, M : (N, N) scipy.sparse.csr_matrix, symmetric positive semi-definite / definite
        (N = ``grid.n_nodes``).
    """
    grid = TrilinearGrid.from_image(image) if grid is None else grid
    Dt = _label_table(image, stiffness, np.eye(3), "stiffness", (3, 3))
    if np.any(np.linalg.eigvalsh(0.5 * (Dt + Dt.transpose(0, 2, 1)))[[int(x) for x in np.unique(image.labels[image.labels > 0])]] <= 0):
        raise InputError("stiffness must be positive definite for every material label")
    rt = _label_table(image, density, 1.0, "density", ())
    if np.any(rt[np.unique(image.labels[image.labels > 0])] <= 0):
        raise InputError("density must be positive for every material label")
    N, G = _gauss_tables(grid.spacing, grid.direction)
    vol = float(np.prod(grid.spacing)) / len(N)
    base = np.einsum("qaj,qbl->jlab", G, G) * vol  # (3, 3, 8, 8)
    mass = np.einsum("qa,qb->ab", N, N) * vol
    labs = image.labels[tuple(grid.element_ijk.T)].astype(np.int64)
    present = np.unique(labs)
    Ke = np.zeros((len(Dt), 64))
    Me = np.zeros((len(Dt), 64))
    for lab in present:
        Ke[lab] = np.einsum("jl,jlab->ab", Dt[lab], base).ravel()
        Me[lab] = (rt[lab] * mass).ravel()
    en = grid.element_nodes
    rows = np.repeat(en, 8, axis=1).ravel()
    cols = np.tile(en, (1, 8)).ravel()
    nn = grid.n_nodes
    K = sp.csr_matrix((Ke[labs].ravel(), (rows, cols)), shape=(nn, nn))
    M = sp.csr_matrix((Me[labs].ravel(), (rows, cols)), shape=(nn, nn))
    return K, M


# --------------------------------------------------------------------------- eigensolver
def _sym(a):
    return 0.5 * (a + a.T)


def _m_orthonormal(V, BV):
    """Columns of V made orthonormal in the M inner product (BV = M V); dependent directions dropped."""
    G = _sym(V.T @ BV)
    e, U = np.linalg.eigh(G)
    top = float(e.max(initial=0.0))
    keep = e > 1e-12 * top if top > 0 else np.zeros(len(e), bool)
    T = U[:, keep] / np.sqrt(e[keep])
    return V @ T, BV @ T, T


class _BlockVCycle:
    """A V-cycle of a pyamg smoothed-aggregation hierarchy applied to blocks of vectors at once:
    damped Jacobi (weight 4 / (3 rho(D^-1 A))), one pre- and two post-smoothing steps, a dense
    pseudo-inverse at the coarsest level."""

    def __init__(self, levels, start=0):
        from pyamg.util.linalg import approximate_spectral_radius

        self.levels = levels[start:]
        self.dinv = []
        for lev in self.levels[:-1]:
            d = lev.A.diagonal()
            Dinv = sp.diags(1.0 / d) @ lev.A
            rho = float(approximate_spectral_radius(Dinv.tocsr()))
            self.dinv.append(((4.0 / 3.0) / rho / d)[:, None])
        self.coarse = np.linalg.pinv(self.levels[-1].A.toarray())

    def __call__(self, b):
        return self._cycle(np.asarray(b, dtype=float), 0)

    def _cycle(self, b, i):
        if i == len(self.levels) - 1:
            return self.coarse @ b
        lev = self.levels[i]
        A, dinv = lev.A, self.dinv[i]
        x = dinv * b
        r = b - A @ x
        x += lev.P @ self._cycle(lev.R @ r, i + 1)
        for _ in range(2):
            x += dinv * (b - A @ x)
        return x


def _lobpcg(K, M, X, precond, nwant, tol, maxiter):
    """Block LOBPCG for the lowest ``nwant`` pairs of ``K x = lambda M x`` from the block X (N, b >= nwant).
    Returns (lambda (b,), X (N, b) M-orthonormal, iterations, largest relative residual of the wanted)."""
    X, BX, _ = _m_orthonormal(X, M @ X)
    AX = K @ X
    lam, C = np.linalg.eigh(_sym(X.T @ AX))
    X, AX, BX = X @ C, AX @ C, BX @ C
    P = AP = BP = None
    res = np.inf
    it = 0
    for it in range(1, maxiter + 1):
        R = AX - BX * lam
        # relative to the wanted spectrum's scale: a zero mode (a free body's constant) has K x = 0
        scale = np.abs(lam) + 1e-2 * abs(float(lam[nwant - 1]))
        rel = np.linalg.norm(R, axis=0) / np.maximum(scale * np.linalg.norm(BX, axis=0), 1e-300)
        res = float(rel[:nwant].max())
        if res < tol:
            it -= 1
            break
        W = precond(R)
        W -= X @ (BX.T @ W)
        W, BW, _ = _m_orthonormal(W, M @ W)
        if W.shape[1] == 0:
            break
        AW = K @ W
        S, AS, BS = [X, W], [AX, AW], [BX, BW]
        if P is not None:
            S.append(P)
            AS.append(AP)
            BS.append(BP)
        S, AS, BS = np.hstack(S), np.hstack(AS), np.hstack(BS)
        GA, GB = _sym(S.T @ AS), _sym(S.T @ BS)
        e, U = np.linalg.eigh(GB)
        keep = e > 1e-12 * e.max()
        T = U[:, keep] / np.sqrt(e[keep])
        mu, Y = np.linalg.eigh(_sym(T.T @ GA @ T))
        b = X.shape[1]
        Cf = T @ Y[:, :b]
        lam = mu[:b]
        Cp = Cf.copy()
        Cp[:b] = 0.0  # the new search direction: the W and P parts of the update
        P, AP, BP = S @ Cp, AS @ Cp, BS @ Cp
        X, AX, BX = S @ Cf, AS @ Cf, BS @ Cf
    return lam, X, it, res


def lowest_modes(K, M, count, *, tol=MODE_TOL, maxiter=MAX_ITERATIONS, seed=0, dense_max=DENSE_MAX):
    """The ``count`` lowest eigenpairs of ``K x = lambda M x`` (K symmetric positive semi-definite, M
    symmetric positive definite, sparse).

    Up to ``dense_max`` unknowns: scipy's dense ``eigh``.  Above: a smoothed-aggregation hierarchy of
    ``K + sigma M`` (pyamg; ``sigma = 1e-6 mean(diag K) / mean(diag M)``, only so that the hierarchy of a
    free body is regular), the modes of the Galerkin pair ``(P^T K P, P^T M P)`` on its first coarse
    level (recursively) interpolated as the starting block, then block LOBPCG preconditioned by the
    hierarchy's V-cycle (:class:`_BlockVCycle`) with ``max(4, count // 5)`` guard vectors.

    Returns
    -------
    lam : (count,) float, ascending
    X : (n, count) float, M-orthonormal
    info : dict with ``iterations`` (per level, finest first) and ``residual`` (largest relative residual
        of the wanted pairs on the finest level)
    """
    n = K.shape[0]
    count = int(count)
    if not 1 <= count <= n:
        raise InputError(f"count must be between 1 and the number of unknowns ({n}), got {count}")
    if n <= dense_max:
        lam, X = sla.eigh(K.toarray(), M.toarray(), subset_by_index=[0, count - 1])
        return lam, X, {"iterations": [], "residual": 0.0}
    import pyamg

    sigma = 1e-6 * float(K.diagonal().mean()) / float(M.diagonal().mean())
    ml = pyamg.smoothed_aggregation_solver((K + sigma * M).tocsr(), symmetry="symmetric",
                                           max_coarse=max(300, 2 * count))
    levels = ml.levels
    b = min(n, count + max(4, count // 5))
    Ks, Ms = [K.tocsr()], [M.tocsr()]
    for lev in levels[:-1]:
        Ks.append((lev.R @ Ks[-1] @ lev.P).tocsr())
        Ms.append((lev.R @ Ms[-1] @ lev.P).tocsr())
    # the coarsest level with a dense solve, then up: interpolate, iterate
    start = len(levels) - 1
    while start > 0 and (Ks[start].shape[0] < 2 * b or Ks[start].shape[0] <= dense_max) and \
            Ks[start - 1].shape[0] <= dense_max:
        start -= 1
    k0 = min(b, Ks[start].shape[0])
    if Ks[start].shape[0] <= dense_max:
        lam, X = sla.eigh(Ks[start].toarray(), Ms[start].toarray(), subset_by_index=[0, k0 - 1])
    else:  # the hierarchy coarsened too little: a random start on that level
        X = np.random.default_rng(seed).standard_normal((Ks[start].shape[0], k0))
        lam = None
    if X.shape[1] < b:
        X = np.hstack([X, np.random.default_rng(seed).standard_normal((X.shape[0], b - X.shape[1]))])
    iterations = []
    res = 0.0
    for lv in range(start, -1, -1):
        if lv < start or lam is None:
            lam, X, its, res = _lobpcg(Ks[lv], Ms[lv], X, _BlockVCycle(levels, lv), count, tol, maxiter)
            iterations.insert(0, its)
        if lv > 0:
            X = levels[lv - 1].P @ X
    if res >= tol:
        warnings.warn(f"eigenmode weights: LOBPCG stopped after {maxiter} iterations at a relative residual of "
                      f"{res:.1e} (tolerance {tol:.0e}); the weights are smooth but not exact modes",
                      EigenmodeWarning, stacklevel=3)
    return lam[:count], X[:, :count], {"iterations": iterations, "residual": res}


# --------------------------------------------------------------------------- the shape function
@dataclass(frozen=True, eq=False)
class EigenmodeWeights(CornerWeights):
    """Skinning-eigenmode weights of frames over the material of an image (see the module docstring).

    Attributes
    ----------
    frames : (n, 3) float, metres: the given frames first, then the interpolation points
    kind : str, ``"eigenmode"``
    image : LabelImage
    grid : TrilinearGrid
    weights : (corners, n) csr_matrix, the weights at the voxel corners
    eigenvalues : (k,) float [1/m^2 for unit stiffness and density], the modes of S
    lifted : (J,) int, the frames that carry a fixed region (a lift), the others are cardinal
    linear : bool, whether S holds the linear functions (no fixed region: linearly precise)
    max_lebesgue : float, the largest ``sum_i |w_i|`` at a corner (1 for non-negative weights)
    condition : float, condition number of the interpolation matrix at the cardinal frames
    seconds : dict, the time of each stage (operators, modes, frames, weights)
    solver : dict, the eigensolver's LOBPCG ``iterations`` per level (finest first) and final ``residual``
    """

    frames: np.ndarray
    image: object
    grid: TrilinearGrid = field(repr=False)
    weights: sp.csr_matrix = field(repr=False)
    eigenvalues: np.ndarray = field(repr=False, default=None)
    lifted: np.ndarray = field(repr=False, default=None)
    linear: bool = False
    max_lebesgue: float = float("nan")
    condition: float = float("nan")
    seconds: dict = field(repr=False, default_factory=dict)
    solver: dict = field(repr=False, default_factory=dict)
    kind: str = "eigenmode"

    @property
    def linearly_precise(self) -> bool:
        """Whether the weights reproduce 1 and x (no fixed region: :attr:`linear`); frames' volumetric
        "auto" and gauge handling read it."""
        return bool(self.linear)
    _cache: dict = field(repr=False, default_factory=dict)

    # -- storage (the precompute cache) ----------------------------------------
    def to_store(self) -> dict:
        W = self.weights
        return {"em_indptr": W.indptr, "em_indices": W.indices, "em_data": W.data,
                "em_eigenvalues": np.asarray(self.eigenvalues, dtype=float),
                "em_lifted": np.asarray(self.lifted, dtype=np.int64),
                "em_stats": np.array([float(self.linear), self.max_lebesgue, self.condition])}

    @classmethod
    def from_store(cls, image, frames, d) -> "EigenmodeWeights":
        grid = TrilinearGrid.from_image(image)
        W = sp.csr_matrix((d["em_data"], d["em_indices"], d["em_indptr"]), shape=(grid.n_nodes, len(frames)))
        st = np.asarray(d["em_stats"], dtype=float)
        return cls(frames=np.asarray(frames, dtype=float), image=image, grid=grid, weights=W,
                   eigenvalues=np.asarray(d["em_eigenvalues"]), lifted=np.asarray(d["em_lifted"]),
                   linear=bool(st[0]), max_lebesgue=float(st[1]), condition=float(st[2]))


# --------------------------------------------------------------------------- construction
def _dirichlet_corners(grid, seed_owner):
    """Per corner: the frame owning every adjacent material voxel outright (-1 elsewhere)."""
    nn = grid.n_nodes
    out = np.full(nn, -1, dtype=np.int64)
    if seed_owner is None:
        return out
    en = grid.element_nodes
    own = np.asarray(seed_owner)[tuple(grid.element_ijk.T)].astype(np.int64)
    ea = own >= 0
    if not ea.any():
        return out
    adj = np.bincount(en.ravel(), minlength=nn)
    adj_a = np.bincount(en[ea].ravel(), minlength=nn)
    lo = np.full(nn, np.iinfo(np.int64).max, dtype=np.int64)
    hi = np.full(nn, -1, dtype=np.int64)
    np.minimum.at(lo, en[ea].ravel(), np.repeat(own[ea], 8))
    np.maximum.at(hi, en[ea].ravel(), np.repeat(own[ea], 8))
    full = (adj_a == adj) & (adj > 0) & (lo == hi)  # a corner between two regions stays free
    out[full] = lo[full]
    return out


def _solve_spd(A, B):
    """A^-1 B for a sparse symmetric positive (semi-)definite A: a direct solve (small A) or conjugate gradients
    preconditioned by smoothed aggregation, one column at a time (the lifts: a few columns)."""
    if A.shape[0] <= 20000:
        import scipy.sparse.linalg as spl

        return np.atleast_2d(spl.spsolve(A.tocsc(), B).T).T.reshape(B.shape)
    import pyamg

    ml = pyamg.smoothed_aggregation_solver(A.tocsr(), symmetry="symmetric")
    return np.column_stack([ml.solve(B[:, j], tol=1e-12, accel="cg") for j in range(B.shape[1])])


def eigenmode(image, frames, count, *, seed_owner=None, stiffness=None, density=None, tol=MODE_TOL):
    """Build :class:`EigenmodeWeights` (called by :func:`voxflex.voronoi.shape_function`).

    Parameters
    ----------
    image : LabelImage
    frames : (k, 3) float, validated world positions (one per material voxel): frames kept where they are
        (a scene's positions and fixed-region frames); may be empty
    count : int >= k, the number of frames (and the dimension of the weight space)
    seed_owner : (nx, ny, nz) int, optional: the frame owning each voxel outright (-1 elsewhere)
    stiffness, density : dict per label, optional (:func:`scalar_operators`)
    tol : float, the eigensolver's relative residual

    Returns
    -------
    EigenmodeWeights
    """
    import time

    t0 = time.perf_counter()
    F0 = np.asarray(frames, dtype=float).reshape(-1, 3)
    k0 = len(F0)
    count = int(count)
    material = image.labels > 0
    nmat = int(material.sum())
    if count < max(k0, 1):
        raise InputError(f"count = {count} eigenmode frames is fewer than the {k0} frames given; raise count")
    if count > nmat:
        raise InputError(f"count = {count} exceeds the {nmat} material voxels; ask for at most {nmat} frames")
    grid = TrilinearGrid.from_image(image)
    nn = grid.n_nodes
    K, M = scalar_operators(image, grid, stiffness=stiffness, density=density)
    seconds = {"operators": time.perf_counter() - t0}

    anchor = _dirichlet_corners(grid, seed_owner)
    lifted = np.unique(anchor[anchor >= 0])
    J = len(lifted)
    free = np.flatnonzero(anchor < 0)
    X = grid.node_positions
    L = float(np.ptp(X, axis=0).max()) or 1.0

    # the weight space: lifts, then (linear functions and) modes
    t = time.perf_counter()
    info = {"iterations": [], "residual": 0.0}
    if J:
        Kf = K[free][:, free].tocsr()
        Mf = M[free][:, free].tocsr()
        nm = count - J
        H = np.zeros((nn, J))
        for j, f in enumerate(lifted):
            H[anchor == f, j] = 1.0
        if J > 1:
            fixed = np.flatnonzero(anchor >= 0)
            H[free, :-1] = _solve_spd(Kf, -(K[free][:, fixed] @ H[fixed, :-1]))
            H[free, -1] = 1.0 - H[free, :-1].sum(1)
        else:
            H[free, 0] = 1.0
        lam = np.zeros(0)
        V = np.zeros((nn, 0))
        if nm > 0:
            if nm > len(free):
                raise InputError(f"count = {count} exceeds the {len(free) + J} weight-space dimensions of the "
                                 "image's free corners; ask for fewer frames")
            lam, Vf, info = lowest_modes(Kf, Mf, min(len(free), nm + GUARD_MODES), tol=tol)
            nm = _whole_clusters(lam, nm)
            lam, Vf = lam[:nm], Vf[:, :nm]
            count = J + nm
            V = np.zeros((nn, nm))
            V[free] = Vf
    else:
        m = np.asarray(M.sum(1)).ravel()
        c = (m @ X) / m.sum()
        lin = np.column_stack([np.ones(nn), (X - c) / L])
        lam, Vm, info = lowest_modes(K, M, min(nn, count + GUARD_MODES), tol=tol)
        # M-orthonormal basis: the linear functions (Gram-Schmidt in order: 1, x, y, z), then the modes in
        # order while independent
        G = _sym(lin.T @ (M @ lin))
        B = sla.solve_triangular(np.linalg.cholesky(G), lin.T, lower=True).T
        keep, last = [], None
        for j in range(Vm.shape[1]):
            if B.shape[1] + len(keep) >= count and (last is None or _whole_clusters(lam[[last, j]], 1) == 1):
                break  # enough, and mode j starts a new cluster
            v = Vm[:, j] - B @ (B.T @ (M @ Vm[:, j]))
            if len(keep):
                Q = np.column_stack(keep)
                v = v - Q @ (Q.T @ (M @ v))
            nv = float(np.sqrt(v @ (M @ v)))
            if nv > 1e-6:
                keep.append(v / nv)
                last = j
        V = np.column_stack([B] + keep) if keep else B
        if V.shape[1] < count:
            raise InputError(f"count = {count} eigenmode frames exceed the modes found ({V.shape[1]}); "
                             "ask for fewer frames")
        count = V.shape[1] if count >= 4 else count
        V = V[:, :count]
    seconds["modes"] = time.perf_counter() - t

    # frames: the given ones, then Q-DEIM points of the cardinal part at the voxel centres
    t = time.perf_counter()
    en = grid.element_nodes
    Vc = V[en].mean(axis=1)  # (voxels, nm) values at the voxel centres
    vox_ijk = grid.element_ijk
    centres = grid.index_to_world(vox_ijk + 0.5)
    given_vox = np.zeros(0, dtype=np.int64)
    if k0:
        eg, lg = grid.locate(F0, tolerance=1e-6)
        given_vox = eg
    lifted_set = set(int(i) for i in lifted)
    card_given = np.array([i for i in range(k0) if i not in lifted_set], dtype=np.int64)
    if np.any(lifted >= k0):
        raise InputError("seed_owner refers to a frame that is not among the given frames")
    ncard = count - J
    if len(card_given) > ncard:
        raise InputError(f"{len(card_given)} given frames own no fixed region but only {ncard} cardinal weights "
                         "exist; raise count")
    rows = np.zeros((0, V.shape[1]))
    if len(card_given):
        Eg, Lg = grid.locate(F0[card_given], tolerance=1e-6)
        Ng, _, _ = trilinear_weights(Lg)
        rows = np.einsum("mc,mck->mk", Ng, V[en[Eg]])
    chosen = []
    need = ncard - len(card_given)
    if need > 0:
        cand = np.ones(len(vox_ijk), dtype=bool)
        cand[given_vox] = False
        if seed_owner is not None:
            cand &= np.asarray(seed_owner)[tuple(vox_ijk.T)] < 0
        ci = np.flatnonzero(cand)
        A = Vc[ci]
        if len(rows):
            Q, _ = np.linalg.qr(rows.T)
            A = A - (A @ Q) @ Q.T
        chosen = ci[_pivots(A, need)]
    Fc = centres[chosen] if len(chosen) else np.zeros((0, 3))
    frames_all = np.concatenate([F0, Fc])
    card = np.concatenate([card_given, k0 + np.arange(len(chosen))]).astype(np.int64)
    Prow = np.concatenate([rows, Vc[chosen]]) if len(chosen) else rows
    seconds["frames"] = time.perf_counter() - t

    # weights: cardinal functions of the modal part at the cardinal frames, the lifts for the region frames
    t = time.perf_counter()
    if ncard:
        sv = np.linalg.svd(Prow, compute_uv=False)
        cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else np.inf
        if not cond < CONDITION_MAX:
            raise InputError(f"the eigenmode weights cannot be interpolated at the given frames (condition number "
                             f"{cond:.1e}): they do not tell the {ncard} modes apart; give fewer frames, other "
                             "positions, or raise count so that the remaining frames are chosen from the modes")
        Lc = np.linalg.solve(Prow.T, V.T).T  # (nn, ncard): cardinal functions l_k
    else:
        cond = 1.0
        Lc = np.zeros((nn, 0))
    W = np.zeros((nn, count))
    W[:, card] = Lc
    if J:
        if ncard:
            hk = np.einsum("mc,mcj->mj", *_centre_or_point(grid, frames_all[card], H))  # h_j at the cardinal frames
        else:
            hk = np.zeros((0, J))
        for j, f in enumerate(lifted):
            W[:, f] = H[:, j] - Lc @ hk[:, j]
    W[np.abs(W) < 1e-14 * np.abs(W).max()] = 0.0
    Wc = sp.csr_matrix(W)
    Wc.eliminate_zeros()
    lebesgue = float(np.abs(W).sum(1).max())
    seconds["weights"] = time.perf_counter() - t
    return EigenmodeWeights(frames=frames_all, image=image, grid=grid, weights=Wc, eigenvalues=np.asarray(lam),
                            lifted=lifted, linear=J == 0 and count >= 4, max_lebesgue=lebesgue, condition=cond, seconds=seconds, solver=info)


def _whole_clusters(lam, n):
    """The number of leading eigenvalues to keep, at least ``n``, so that no cluster (:data:`CLUSTER_TOL`
    relative to the larger magnitude, dimensionless) is cut; ``lam`` ascending (the guard modes after n)."""
    lam = np.asarray(lam, dtype=float)
    while 0 < n < len(lam) and abs(lam[n] - lam[n - 1]) <= CLUSTER_TOL * max(abs(lam[n]), abs(lam[n - 1])):
        n += 1
    return n


def _pivots(A, k):
    """The first ``k`` pivots of column-pivoted QR of ``A.T`` (the rows of A (m, r) of largest remaining norm,
    one after the other, each projected out of the rest): Q-DEIM's points.  Greedy Gram-Schmidt with scale-free
    ties (:func:`voxflex._ties.first_extreme`: within a relative 1e-9 the first row wins), where LAPACK's
    pivoting would pick among rows of equal norm by round-off (a symmetric bar at 1 m and 1 um got frames
    three voxels apart).  O(k m r) flops."""
    from .._ties import first_extreme

    R = np.array(A, dtype=float, copy=True)
    norms = np.einsum("ij,ij->i", R, R)
    out = []
    for _ in range(int(k)):
        p = first_extreme(np.where(np.isin(np.arange(len(R)), out), -1.0, norms), "max", floor=0.0)  # -1: taken
        out.append(p)
        v = R[p].copy()
        nv = float(np.sqrt(v @ v))
        if nv == 0.0:
            continue
        v /= nv
        R -= np.outer(R @ v, v)
        norms = np.einsum("ij,ij->i", R, R)
    return np.asarray(out, dtype=np.int64)


def _centre_or_point(grid, points, values):
    """(trilinear weights (m, 8), corner values (m, 8, k)) of corner fields ``values`` (nn, k) at points."""
    E, Lo = grid.locate(points, tolerance=1e-6)
    N, _, _ = trilinear_weights(Lo)
    return N, values[grid.element_nodes[E]]
