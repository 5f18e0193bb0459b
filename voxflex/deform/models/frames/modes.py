"""Rank check of a frame model's quadrature: count the zero-energy modes of a free body.

A free body of affine frames integrated with linear isotropic elasticity at
the samples has exactly six zero-energy modes (three translations, three
infinitesimal rotations) when the samples are enough; with too few samples
the stiffness ``K = sum_s J_s^T (V_s C) J_s`` is rank-deficient and the extra
null vectors are spurious (hourglass) modes.  Each mid-point sample adds at most
6 to the rank (the symmetric strain components); an elaston with gradient
terms adds at most 24 (strain and its gradient).

>>> import numpy as np                                              # doctest: +SKIP
>>> zero_energy_modes(frames, samples)                              # doctest: +SKIP
6
"""

from __future__ import annotations

import warnings

import numpy as np

from ....errors import InputError
from ...chain.mappings import DeformationGradientWithGradientMapping
from ...chain.nodes import AffineFrames

__all__ = ["SpuriousModesWarning", "zero_energy_modes", "check_modes", "free_body_stiffness", "softest_mode",
           "SOFT_RATIO", "gauge_modes", "hidden_modes", "motion_gram", "weights_gauge_modes", "dimensionless"]

GAUGE_TOL = 1e-8
"""A gauge candidate (:meth:`AffineFrames.gauge_modes`) whose deformation gradient and motion at the
samples are below this fraction of those of a unit dilation is exact (moves nothing)."""


def gauge_modes(frames, values, *, tol: float = GAUGE_TOL, chunk: int = 8192) -> np.ndarray:
    """(12n, g) orthonormal basis of the affine frames' motions that move no sample and deform none.

    With weights that reproduce linear fields at every sample (reproducing kernels) ``g = 18``
    (:meth:`~voxflex.deform.chain.nodes.AffineFrames.gauge_modes`): the 12n DOFs describe the
    motion redundantly, and a free body's stiffness (and consistent mass) has 18 zero
    eigenvalues besides the 6 rigid ones that are not spurious (nothing moves).  Where linear
    precision is given up somewhere (a clamp's own voxels, natural-neighbour weights near the
    surface) fewer or none are exact.  Exactness: the singular values of the map from the
    candidates to (F, x / L) at the samples, below ``tol`` times the response to a unit dilation;
    the map is reduced by a QR over chunks of ``chunk`` samples (memory bounded for any count).
    """
    import scipy.linalg as sla

    from . import _kernels as K

    X = np.ascontiguousarray(frames, dtype=np.float64)
    n = len(X)
    nodes = AffineFrames(X)
    B = nodes.gauge_candidates()
    Z, Rz = np.linalg.qr(B)  # Z = B Rz^-1: the responses of Z are those of B times Rz^-1
    d = np.abs(np.diag(Rz))
    if not d.min(initial=1.0) > 1e-12 * d.max(initial=0.0):
        # dependent candidates (frames on a line or a plane): an orthonormal basis of their span, Z = B Tz with
        # Tz = V_r S_r^-1 (the QR's triangle is singular there)
        U, S, Vt = np.linalg.svd(B, full_matrices=False)
        r = int(np.count_nonzero(S > 1e-12 * S.max(initial=0.0)))
        if r == 0:
            return np.zeros((B.shape[0], 0))
        Z, Tz = U[:, :r], Vt[:r].T / S[:r]
    else:
        Tz = None
    phi, Cb = nodes.gauge_basis()  # dA_a of candidate k = sum_m Cb[k, m] phi_a[m]
    C2 = Cb.transpose(0, 2, 1, 3).reshape(18 * 3, 12)  # rows (k, i), columns (m, j)
    L = float(np.ptp(X, axis=0).max()) if n > 1 else 1.0
    L = L if L > 0 else 1.0
    def sums(a, b):
        # per sample, over its parents: S[m, j] = sum w phi_m r_j (the motion), T[m, j, l] = sum phi_m (w I + r (x) dw)
        S = np.empty((b - a, 4, 3))
        T = np.empty((b - a, 4, 3, 3))
        K.gauge_sums(np.ascontiguousarray(values.index[a:b], dtype=np.int64),
                     np.ascontiguousarray(values.w[a:b], dtype=np.float64),
                     np.ascontiguousarray(values.dw[a:b], dtype=np.float64),
                     np.ascontiguousarray(values.rest[a:b], dtype=np.float64), X, np.ascontiguousarray(phi), S, T)
        return S.reshape(-1, 12, 1), T.reshape(-1, 12, 3)

    ref = np.sqrt(max(values.m, 1) / n)  # |F| over the samples of the unit dilation A_a = I / sqrt(3n)
    # First the Gram matrix of the map from the basis to (F, x / L) at the samples, summed from the 12 x 12 Grams
    # of the sums (F = C2 T: the candidates' Gram is sum_i C2_i (sum T T^T) C2_i^T, i the spatial row): its
    # eigenvalues are the squared singular values to within a few eps of the largest, so where none is below
    # (tol ref)^2 + 1e-10 of the largest no exact gauge motion exists (weights that lose linear precision
    # somewhere: the bunny's 94k voxel centres skip the map's 1.1M x 18 QR, 0.3 of 0.4 s).  Otherwise the exact
    # singular values by a QR of the map over the chunks.
    MT = np.zeros((12, 12))
    MS = np.zeros((12, 12))
    for a in range(0, values.m, chunk):
        S, T = sums(a, min(values.m, a + chunk))
        Tt = T.transpose(1, 0, 2).reshape(12, -1)
        MT += Tt @ Tt.T
        MS += S[:, :, 0].T @ S[:, :, 0]
    gram = sum(C2[i::3] @ (MT + MS / L**2) @ C2[i::3].T for i in range(3))  # (18, 18) over the candidates B
    gram = Tz.T @ gram @ Tz if Tz is not None else sla.solve_triangular(
        Rz, sla.solve_triangular(Rz, gram, trans="T", check_finite=False).T, trans="T", check_finite=False)
    ev = np.linalg.eigvalsh(0.5 * (gram + gram.T))
    if not (ev.size and ev[0] <= (tol * ref) ** 2 + 1e-10 * max(ev[-1], 0.0)):
        return np.zeros((12 * n, 0))
    R = np.zeros((0, Z.shape[1]))
    for a in range(0, values.m, chunk):
        S, T = sums(a, min(values.m, a + chunk))
        F = np.matmul(C2, T)  # (c, (k, i), l): candidate k's F[i, l]
        x = np.matmul(C2, S)  # (c, (k, i), 1): candidate k's motion x_i
        F = F.reshape(-1, 18, 9).transpose(0, 2, 1).reshape(-1, 18)
        x = x.reshape(-1, 18, 3).transpose(0, 2, 1).reshape(-1, 18)
        FX = np.concatenate([F, x / L])
        rows = FX @ Tz if Tz is not None else sla.solve_triangular(Rz, FX.T, trans="T", check_finite=False).T  # @ Rz^-1
        R = sla.qr(np.concatenate([R, rows]), mode="r", check_finite=False)[0][:Z.shape[1]]
    _, sv, Vt = np.linalg.svd(R, full_matrices=False)
    return Z @ Vt[sv <= tol * ref].T


def weights_gauge_modes(sf, frames, values) -> np.ndarray:
    """:func:`gauge_modes` of the weights ``sf`` at the points of ``values``, kept in the shape function's own
    cache (the weight families are frozen dataclasses with a ``_cache`` dict) for the points of
    ``sf.voxel_values()``: the precompute's checks and the mass matrix ask for the same ones (1.2-2.3 s on the
    bunny); without a cache, or at other points, computed."""
    store = getattr(sf, "_cache", None)
    vv = sf.voxel_values() if hasattr(sf, "voxel_values") and isinstance(store, dict) else None
    same = vv is not None and (values is vv or (vv.rest.shape == values.rest.shape
                                                and np.array_equal(vv.rest, values.rest)))
    if same:
        cached = store.get("gauge_modes")
        if cached is not None and cached.shape[0] == 12 * len(frames):
            return cached
    modes = hidden_modes(frames, values, gauge_modes(frames, values))
    if same:
        store["gauge_modes"] = modes
    return modes


def _row_responses(frames, values, y, L):
    """Motion / L and F at every point of ``values`` (rows: the points' motions, then their F rows; columns: the
    vectors) of the per-component motions ``y`` (3n, k): frame a's row ``y[3a:3a+3]`` of A moves a spatial
    component by ``y[3a:3a+3] . r`` (r = X - X_a), t unmoved."""
    idx = values.index
    ok = idx >= 0
    ii = np.where(ok, idx, 0)
    w = np.where(ok, values.w, 0.0)
    dw = np.where(ok[..., None], values.dw, 0.0)
    r = values.rest[:, None, :] - np.asarray(frames)[ii]  # (m, P, 3)
    Y = y.reshape(-1, 3, y.shape[1])[ii]  # (m, P, 3, k)
    lin = np.einsum("mpj,mpjk->mpk", r, Y)  # (m, P, k): the frame's value at the point
    motion = np.einsum("mp,mpk->mk", w, lin) / L
    F = np.einsum("mp,mpjk->mjk", w, Y) + np.einsum("mpk,mpl->mlk", lin, dw)  # (m, 3, k)
    return motion, F.reshape(-1, y.shape[1])


def motion_gram(frames, values, *, masses=None, length: float = 1.0, translation: bool = True,
                chunk: int = 4096) -> np.ndarray:
    """``sum_p m_p b_p b_p^T`` over the points of ``values``: ``b_p`` holds, in each parent frame's slots,
    ``w [r / length; 1]`` (``translation``; (4n, 4n)) or ``w r / length`` ((3n, 3n)), r = X_p - X_a -- how one
    spatial component of the point moves with the frame's row of A (and its t).  The point mass of
    :func:`~voxflex.deform.models.frames.mass.point_mass` and the motionless rows of :func:`hidden_modes`.
    Dense by chunks of points (the sparse J of the bunny's 94k voxel centres with 35 parents would hold
    10 million entries); ``masses`` default 1."""
    X = np.asarray(frames, dtype=np.float64)
    n = len(X)
    k = 4 if translation else 3
    out = np.zeros((k * n, k * n))
    for a in range(0, values.m, chunk):
        b = min(values.m, a + chunk)
        idx = values.index[a:b]
        ok = idx >= 0
        ii = np.where(ok, idx, 0)
        r = (values.rest[a:b, None, :] - X[ii]) / length
        B = (np.concatenate([r, np.ones(ii.shape + (1,))], axis=2) if translation else r) * values.w[a:b, :, None]
        S = np.zeros((b - a, k * n))
        rows = np.broadcast_to(np.arange(b - a)[:, None, None], B.shape)
        cols = k * ii[..., None] + np.arange(k)
        sel = np.broadcast_to(ok[..., None], B.shape)  # a point's parents are distinct frames: plain stores
        S[rows[sel], cols[sel]] = B[sel]
        out += S.T @ (S if masses is None else S * np.asarray(masses)[a:b, None])
    return out


def hidden_modes(frames, values, gauge, *, tol: float = GAUGE_TOL, chunk: int = 4096) -> np.ndarray:
    """The gauge motions ``gauge`` (12n, g) completed with every other change of the frames' A (t fixed, as the
    candidates of :func:`gauge_modes`) that moves no point of ``values`` and deforms none: an orthonormal
    (12n, g') basis, g' >= g.

    The 18 candidates of :func:`gauge_modes` are what linear precision alone leaves; frames crowded on a small
    body leave more (22 eigenmode frames on a 32-voxel ball: 3 more, so the implicit-Euler tangent was singular
    along motions nobody sees, Newton's iterate drifted 86 km along them and the energy lost its digits).
    Cheap where there are none: a spatial component's motion is linear in each frame's row of A (3n unknowns),
    so the (3n, 3n) Gram matrix of the points' motions shows whether more than ``g / 3`` rows per component move
    no point; only then are their deformation gradients formed and the F-free ones kept.  Motions over the
    frames' extent L and F are both dimensionless: the verdict does not depend on the unit."""
    X = np.asarray(frames, dtype=np.float64)
    n = len(X)
    if gauge.shape[1] == 0 or values.m == 0:
        return gauge  # weights that are not linearly precise: nothing moves nothing
    L = float(np.ptp(X, axis=0).max()) if n > 1 else 1.0
    L = L if L > 0 else 1.0
    G3 = motion_gram(X, values, length=L, translation=False, chunk=chunk)
    ev, V = np.linalg.eigh(G3)
    top = float(ev.max())
    if not top > 0:
        return gauge
    still = V[:, ev <= 1e-12 * top]  # moving the points by 1e-6 of the most visible row, or less: candidates
    if 3 * still.shape[1] <= gauge.shape[1]:
        return gauge  # no more motionless directions than the gauge motions themselves
    motion, F = _row_responses(X, values, still, L)
    _, sv, Vt = np.linalg.svd(np.concatenate([motion, F]), full_matrices=False)
    # exact: their motion and F below tol of the most visible row's motion (both dimensionless)
    rows = still @ Vt[sv <= tol * np.sqrt(top)].T  # (3n, h): rows of A that move nothing and deform nothing
    if rows.shape[1] == 0:
        return gauge
    h = rows.shape[1]
    cand = np.zeros((n, 12, 3 * h))  # the same rows in each of A's three rows (the spatial components)
    for i in range(3):
        cand[:, 3 * i:3 * i + 3, i * h:(i + 1) * h] = rows.reshape(n, 3, h)
    cand = cand.reshape(12 * n, 3 * h)
    cand -= gauge @ (gauge.T @ cand)  # less what the gauge motions already span
    U, sv2, _ = np.linalg.svd(cand, full_matrices=False)
    extra = U[:, sv2 > 1e-6]
    if extra.shape[1] == 0:
        return gauge
    extra -= gauge @ (gauge.T @ extra)
    extra, _ = np.linalg.qr(extra)
    return np.concatenate([gauge, extra], axis=1)


class SpuriousModesWarning(UserWarning):
    """The samples leave zero-energy modes beyond the six rigid ones."""


def _unit_hooke_F() -> np.ndarray:
    """(9, 9) tangent d2W/dF2 of ``W = mu |sym(F)|^2 + lambda/2 tr(F)^2`` with mu = lambda = 1."""
    I = np.eye(3)
    C = np.einsum("ij,kl->ijkl", I, I) + np.einsum("ik,jl->ijkl", I, I) + np.einsum("il,jk->ijkl", I, I)
    return C.reshape(9, 9)


def free_body_stiffness(frames, samples, *, gradient: bool | None = None) -> np.ndarray:
    """Dense stiffness (12n, 12n) of affine frames at rest with unit linear isotropic elasticity at the samples.

    Parameters
    ----------
    frames : (n, 3) float
        Rest positions of the frames [m].
    samples : Samples
        Integration samples (their ``values`` are the shape functions on these frames).
    gradient : bool, optional
        Include the strain-gradient terms of elastons (``∇F`` with the moments
        M1, M2: the Taylor elastons of :mod:`voxflex.deform.materials.elaston`); default: for
        region samples of kind ``"elaston"`` with Hessians.  The frame model integrates elastons
        by sub-rules of point samples: its own rest stiffness is
        :meth:`~voxflex.deform.models.frames.model.FrameModel.rest_stiffness`, which the builder's
        checks read (with the mid-point regions' fluctuation term).

    Returns
    -------
    (12n, 12n) float, symmetric positive semi-definite [Pa m^3].
    """
    X = np.asarray(frames, dtype=np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise InputError(f"frames must be an (n, 3) array, got shape {X.shape}")
    for attr in ("values", "volume"):
        if not hasattr(samples, attr):
            raise InputError(f"samples must be a voxflex Samples (missing '{attr}'); build them with vf.sample")
    values = samples.values
    if gradient is None:
        gradient = getattr(samples, "kind", None) == "elaston" and values.ddw is not None and hasattr(samples, "M1")
    if gradient and not (hasattr(samples, "M1") and hasattr(samples, "M2")):
        raise InputError("gradient terms need the samples' moments M1 and M2 (elastons from vf.sample)")
    C = _unit_hooke_F()
    V = np.asarray(samples.volume, dtype=np.float64)
    m = len(V)
    if not gradient:
        return _point_stiffness(X, values, V, C)
    nodes = AffineFrames(X)
    mapping = DeformationGradientWithGradientMapping(nodes, values)
    M1, M2 = np.asarray(samples.M1), np.asarray(samples.M2)
    # E = 1/2 int C[dF(x)]^2, dF(x) = F + ∇F (x - p): blocks over (F 9 | ∇F 27 = (ij)*3 + a)
    H = np.zeros((m, 36, 36))
    H[:, :9, :9] = V[:, None, None] * C
    FdF = np.einsum("pq,sb->spqb", C, M1).reshape(m, 9, 27)
    H[:, :9, 9:] = FdF
    H[:, 9:, :9] = FdF.transpose(0, 2, 1)
    H[:, 9:, 9:] = np.einsum("pq,sab->spaqb", C, M2).reshape(m, 27, 27)
    J = mapping.jacobian(nodes.rest)
    import scipy.sparse as sp

    Hb = sp.block_diag(list(H), format="csr") if m else sp.csr_matrix((0, 0))
    assert Hb.shape[0] == J.shape[0] == m * 36
    K = (J.T @ Hb @ J).toarray()
    return 0.5 * (K + K.T)


def zero_energy_modes(frames, samples, *, tol: float = 1e-8, gradient: bool | None = None, stiffness=None,
                      gauge=None) -> int:
    """Number of zero eigenvalues of the free-body stiffness (six for a sound quadrature), the exact
    gauge modes of linearly precise weights (:func:`gauge_modes`, which move nothing) not counted.

    Parameters
    ----------
    frames : (n, 3) float
        Rest positions of the frames [m].
    samples : Samples
    tol : float, keyword-only
        An eigenvalue counts as zero below ``tol * max eigenvalue``.
    gradient : bool, optional
        See :func:`free_body_stiffness`.
    stiffness : (12n, 12n) float, optional
        ``free_body_stiffness(frames, samples, gradient=gradient)`` when the caller has it.
    gauge : (12n, g) float, optional
        The gauge motions (default: :func:`gauge_modes` at the samples; a model's builder passes those at
        every voxel centre, which see what a stabilised region's Gauss points see).

    Returns
    -------
    int
    """
    tol = float(tol)
    if not 0 < tol < 1:
        raise InputError(f"tol must be in (0, 1), got {tol}")
    K = free_body_stiffness(frames, samples, gradient=gradient) if stiffness is None else stiffness
    from ...._blas import one_thread

    Ks = dimensionless(K, samples)
    G = gauge_modes(frames, samples.values) if gauge is None else gauge  # no translation: scaling leaves it
    if G.shape[1]:  # motions that move nothing are not zero-energy deformations: deflate them
        Ks = Ks + (np.trace(Ks) / len(Ks)) * (G @ G.T)
    with one_thread():  # threaded BLAS stalls on small dense work here
        ev = np.linalg.eigvalsh(Ks)
    top = float(ev.max()) if ev.size else 0.0
    if top <= 0:
        return int(ev.size)
    return int((ev < tol * top).sum())


def dimensionless(K, samples) -> np.ndarray:
    """``S K S`` with the translation DOFs scaled by the samples' spread L (S = 1 on the matrix entries,
    L on the translations): the eigenvalues of K mix the units of its blocks (Pa m^3 for the matrix
    entries, Pa m for the translations), so a relative threshold on them would judge the same scene
    differently at 1 um and 1 km; those of ``S K S`` scale uniformly with the scene.

    L is the root-mean-square distance of the samples from their volume-weighted centroid [m].
    """
    pts = np.asarray(samples.points, dtype=np.float64)
    vol = np.asarray(samples.volume, dtype=np.float64)
    c = (vol @ pts) / vol.sum()
    L = float(np.sqrt((vol @ ((pts - c) ** 2).sum(axis=1)) / vol.sum()))
    if not L > 0:  # one sample: any length of the body will do
        L = float(np.cbrt(vol.sum()))
    s = np.ones(K.shape[0])
    s.reshape(-1, 12)[:, 9:] = L
    return K * s[:, None] * s[None, :]


def _point_stiffness(frames, values, volume, C) -> np.ndarray:
    """``sum_s V_s J_s^T C J_s`` (12n, 12n) of point samples by the frame model's compiled pair-block
    kernel (equal to the sparse product ``J^T blockdiag(V C) J`` to round-off, 5x faster at 800 samples), or by
    dense products where most frames are parents of every sample (:func:`~._kernels.isotropic_worth_dense`)."""
    from . import _kernels as K

    n = len(frames)
    moduli = K.isotropic_moduli(C.reshape(3, 3, 3, 3))
    if moduli is not None and K.isotropic_worth_dense(values.index, n):
        return K.isotropic_stiffness_dense(values.index, n, volume, *moduli,
                                           points=(values.w, values.dw, values.rest, frames))
    index, order = K.sorted_parents(values)
    points = K.point_arrays(values, frames, order)  # each sample's tables made on the fly, no (m, P, 4, 3) array
    A = np.ascontiguousarray(np.broadcast_to(C.reshape(3, 3, 3, 3), (len(volume), 3, 3, 3, 3)))
    return K.frame_stiffness_dense(index, None, A, n, volume, (index, None) + K.pair_list(index, n), points)


SOFT_RATIO = 0.02
"""A deformation mode whose energy at the samples is below this fraction of its energy with one
mid-point sample in every voxel is a spurious near-zero-energy mode (:func:`softest_mode`).

Measured on the documented sweeps (``docs/tradeoff.md``; smallest ratio over the free DOFs): the
configurations with tip errors of 97 % (cantilever 32x8x8, 40 frames, 100 samples), 283 % (capsule,
40 frames, 100 samples) and 225 Newton iterations (cantilever 16x4x4, 40 frames, 200 samples) have
0.0035, 0.0064 and 0.0009.  The 40 mid-point and elaston configurations the sweeps keep measure
0.039 - 1 (the default scene: 0.30).  The ratio does not catch every poor model: 40 frames on 100
elastons of the capsule measure 0.056 and are 57 % off."""


def softest_mode(frames, samples, reference, free=None, *, stiffness=None) -> float | None:
    """How much softer the samples make the softest deformation than a finer quadrature does.

    The smallest ``lambda`` of ``K_s v = lambda K_ref v`` over the DOFs ``free``, with the two
    stiffnesses of unit linear isotropic elasticity at the samples and at the reference samples
    (one mid-point sample per voxel: :func:`voxflex.sampling.voxel.voxel_samples`).  Spurious
    (hourglass) modes that under-integration leaves nearly free have ``lambda`` near 0; a sound
    quadrature 0.1 - 1.  Without ``free`` the six rigid modes, zero in both, are deflated (given
    unit ratio), and so are the gauge modes (:func:`gauge_modes`) when both have them.  None when the reference itself leaves a zero-energy mode among those DOFs.

    Parameters
    ----------
    frames : (n, 3) float
    samples, reference : Samples
        Their values on these frames.
    free : (F,) int, optional
        The DOFs the scene does not hold (default all: a free body).
    stiffness : (12n, 12n) float, optional
        ``free_body_stiffness(frames, samples)`` when the caller has it.

    Returns
    -------
    float or None
    """
    import scipy.linalg as sla

    from ...._blas import one_thread

    Ks = free_body_stiffness(frames, samples) if stiffness is None else stiffness
    Kr = free_body_stiffness(frames, reference)
    if free is None:
        R = _rigid_modes(np.asarray(frames, dtype=np.float64))
        G = gauge_modes(frames, reference.values)
        if G.shape[1] and gauge_modes(frames, samples.values).shape[1] == G.shape[1]:
            R = np.concatenate([R, G], axis=1)  # both move nothing along them: deflated like the rigid modes
        scale = np.trace(Kr) / len(Kr)
        Ks = Ks + scale * (R @ R.T)
        Kr = Kr + scale * (R @ R.T)
    else:
        free = np.asarray(free, dtype=np.int64)
        Ks, Kr = Ks[np.ix_(free, free)], Kr[np.ix_(free, free)]
    if Ks.size == 0:
        return None
    with one_thread():
        # the reference singular there (to round-off, Jacobi-scaled): no verdict.  Left to eigh, a reference
        # singular only to round-off could pass its factorisation and give garbage (-58 for the phantom's
        # clamped reproducing kernels, whose 3 motionless motions all move the held frame)
        d = np.diagonal(Kr)
        if not np.all(d > 0):
            return None
        s = 1.0 / np.sqrt(d)
        ev = np.linalg.eigvalsh(s[:, None] * Kr * s[None, :])
        if not ev[0] > 1e-12 * ev[-1]:
            return None
        try:
            lam = sla.eigh(Ks, Kr, eigvals_only=True, subset_by_index=[0, 0], check_finite=False)
        except np.linalg.LinAlgError:  # the reference is singular there
            return None
    return float(lam[0])


def _rigid_modes(frames) -> np.ndarray:
    """(12n, 6) orthonormal basis of the affine frames' rigid motions (:meth:`AffineFrames.rigid_modes`)."""
    Q, _ = np.linalg.qr(AffineFrames(frames).rigid_modes())
    return Q


def check_modes(frames, samples, *, tol: float = 1e-8, gradient: bool | None = None, stiffness=None,
                gauge=None) -> int:
    """Count zero-energy modes and warn (:class:`SpuriousModesWarning`) when there are more than six.

    The warning names how many samples to add at least (each mid-point sample
    removes at most 6 modes, an elaston with gradient terms at most 24).
    ``stiffness``: the free-body stiffness when the caller has it, ``gauge`` the gauge motions (see
    :func:`zero_energy_modes`).

    Returns
    -------
    int : the number of zero-energy modes.
    """
    if gradient is None:
        gradient = getattr(samples, "kind", None) == "elaston" and samples.values.ddw is not None \
            and hasattr(samples, "M1")
    zero = zero_energy_modes(frames, samples, tol=tol, gradient=gradient, stiffness=stiffness, gauge=gauge)
    if zero > 6:
        per = 24 if gradient else 6
        add = -(-(zero - 6) // per)
        warnings.warn(
            f"the quadrature leaves {zero - 6} spurious zero-energy modes ({zero} zero eigenvalues, a free body has 6); "
            f"add at least {add} samples (each adds at most {per} independent strain components)",
            SpuriousModesWarning,
            stacklevel=2,
        )
    return zero
