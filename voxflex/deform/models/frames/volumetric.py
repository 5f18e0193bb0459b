"""The frames' volumetric term projected onto their weights: the remedy for volumetric locking.

A few frames bending a nearly incompressible body cannot keep every sample's
volume (they cannot give the Poisson contraction's variation across a section),
so full integration of the volumetric term locks: the linear cantilever 32x8x8 with
20 frames and Gauss points bends 45x too little at nu = 0.4999 (-0.0087 against
-0.393 m projected, -0.376 m for the voxel model with B-bar).  ``volumetric="reduced"`` projects the volume
ratio onto the span of the frames' weights: per label, the L2 projection

    Jbar(X) = sum_a w_a(X) pi_a,   M pi = b,   M_ab = sum_s v_s w_a w_b,   b_a = sum_s v_s w_a J_s

(``J_s = det F_s``; the quadrature's own samples), and each sample sees
F-bar ``F~_s = (Jbar_s / J_s)^(1/3) F_s``, or for a material with a constant
tangent B-bar, ``F~_s = F_s + (trbar_s - tr F_s) I / 3`` (the projected trace),
which keeps its energy quadratic.  The weights are a partition of unity, so an
affine motion gives ``Jbar = J`` (the patch test holds), and the projection
space grows with the frames (the consistent limit is full integration).  The
energy ``sum_s v_s W(F~_s)`` has its exact gradient and Hessian (every sample
of a label couples with the projection: rank-n products, see
:func:`projected_pass`).  ``"auto"`` projects the labels whose
effective Poisson ratio at rest is >= 0.4
(:func:`~voxflex.deform.materials.fbar.nearly_incompressible`) when the weights are
not linearly precise; linearly precise weights (reproducing kernels) keep the full
term, because there the projection is too soft and does not converge while full
integration barely locks.  Measured on the neo-Hooke cantilever 32x8x8 with elastons
against the voxel model with F-bar (-0.3854 / -0.3791 / -0.3751 / -0.3740 m at
nu = 0.3 / 0.45 / 0.49 / 0.4999): reproducing kernels, full, 20 frames -0.3862 /
-0.3711 / -0.3633 / -0.3439, 40 frames -0.3685 (0.49) / -0.3601 (0.4999);
projected -0.4106 / -0.4120 / -0.4121 / -0.4121 (20) and -0.4141 (40, both):
7-11 % too soft.  Natural neighbours, projected: -0.3839 / -0.3922 / -0.3937 /
-0.3940 (full: -0.2965 at 0.3, -0.2172 at 0.45; measured with the old cut to 6 parents, whose jumps
softened them: with the conforming cut, ``benchmarks/bench_frames_quadrature.py --locking``).  Projecting onto the weights
times (1, x - X_a) as well (4 per frame) behaves like full integration (-0.3873 at
0.3, -0.3730 at 0.45) and lost Newton convergence at 0.49.  A sample cannot
pass through zero volume (infinite energy where ``Jbar_s / J_s <= 0``).

:class:`~voxflex.deform.models.frames.model.FrameModel` calls :func:`projected_pass` for its energy,
gradient and Hessian when some label is projected (``model.volumetric[label]``), and keeps the
operators :func:`volumetric_projection` makes.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...._linalg import vdot
from ...materials.fbar import bar_scalar

__all__ = ["volumetric_projection", "projected_pass", "dof_rows"]


def volumetric_projection(model) -> list:
    """Per projected label: its samples, the weights N (sparse, samples x frames), the pseudo-inverse of
    ``M = N^T V N`` over the frames it touches, and the sparse pattern of per-sample DOF rows; once."""
    if model._proj is None:
        n = model.n_nodes
        out = []
        dofs = model._dofs()
        for label, ids in model._groups:
            if not model.volumetric[label]:
                continue
            idx = model._index[ids]
            ok = idx >= 0
            k = len(ids)
            N = sp.csr_matrix((model._w[ids][ok], (np.broadcast_to(np.arange(k)[:, None], idx.shape)[ok], idx[ok])),
                              shape=(k, n))
            N.sum_duplicates()
            active = np.flatnonzero(np.asarray(abs(N).sum(axis=0)).ravel() > 0)
            N = N[:, active].tocsr()
            v = model._volume[ids]
            M = (N.T @ sp.diags(v) @ N).toarray()
            M = 0.5 * (M + M.T)
            # rows of the per-sample DOF vectors (m, P, 3, 4) as a CSR pattern (k, 12n)
            P = idx.shape[1]
            okr = np.broadcast_to(ok[:, :, None, None], (k, P, 3, 4)).reshape(k, -1)
            d = dofs[ids].reshape(k, -1)
            counts = okr.sum(axis=1)
            indptr = np.concatenate([[0], np.cumsum(counts)])
            # M^+ = U diag(1 / lam) U^T over its range: with fewer samples than frames M is singular, and
            # the projection (onto the span of the weights at the samples) is still an orthogonal one
            lam, U = np.linalg.eigh(M)
            keep = lam > 1e-12 * max(float(lam.max(initial=0.0)), 1e-300)
            Minv = (U[:, keep] / lam[keep]) @ U[:, keep].T
            out.append({"label": label, "ids": ids, "N": N, "NT": N.T.tocsr(), "M": 0.5 * (Minv + Minv.T),
                        "okr": okr, "indices": d[okr], "indptr": indptr, "linear": bool(
                            getattr(model.materials[label], "constant_tangent", False))})
        model._proj = out
    return model._proj


def projected_pass(model, F, gradient, hessian):
    """Samples with the volumetric term of some labels projected onto the frames' weights (module
    docstring).

    Per projected label, with ``J_s`` the samples' volume ratios (or traces, B-bar),
    ``Jbar = N pi``, ``pi = M^-1 N^T V J``: the per-sample derivatives of ``W(F~(F_s, Jbar_s))``
    (:func:`~voxflex.deform.materials.fbar.bar_scalar`: gF, gJ, HFF, HFJ, HJJ) chain as
    gradient ``J^T (v gF + y c)`` with ``y = V N M^-1 N^T (v gJ)``, ``c_s = dJ_s/dF_s``, and Hessian
    ``J^T blockdiag(v HFF + y d2J) J + X Q + (X Q)^T + Q^T N^T diag(v HJJ) N Q`` with
    ``Q = M^-1 N^T V B`` (``B_s = c_s^T J_s``, the rows of dJ/dq) and
    ``X = sum_s v_s J_s^T HFJ_s N_s`` (numpy and scipy.sparse; every product is rank n).
    """
    vol = model._volume
    m, n = len(vol), model.n_nodes
    want = gradient or hessian
    energy = 0.0
    P = np.zeros((m, 3, 3)) if want else None
    A = np.zeros((m, 3, 3, 3, 3)) if hessian else None
    extra = []
    for label, ids in model._groups:
        if model.volumetric[label]:
            continue
        W, Pl, Al = model.materials[label].evaluate(F[ids], tangent=hessian)
        energy += vdot(vol[ids], W)
        if want:
            P[ids] = Pl
        if hessian:
            A[ids] = Al
    for pr in model._projection():
        ids, N, NT, cho, linear = pr["ids"], pr["N"], pr["NT"], pr["M"], pr["linear"]
        Fl = F[ids]
        v = vol[ids]
        Js = np.trace(Fl, axis1=1, axis2=2) if linear else np.linalg.det(Fl)
        Jbar = N @ (cho @ (NT @ (v * Js)))
        out = bar_scalar(model.materials[pr["label"]], Fl, Jbar, linear=linear, gradient=want, tangent=hessian)
        energy += vdot(v, out[0])
        if not np.isfinite(energy):
            return np.inf, (np.full((n, 12), np.nan) if gradient else None), \
                (np.full((12 * n, 12 * n), np.nan) if hessian else None)
        if not want:
            continue
        gF, gJ = out[1], out[2]
        y = v * (N @ (cho @ (NT @ (v * gJ))))  # dE/dJ_s through Jbar
        if linear:
            c = np.broadcast_to(np.eye(3), Fl.shape)
        else:
            c = np.linalg.det(Fl)[:, None, None] * np.linalg.inv(Fl).transpose(0, 2, 1)  # cofactor
        P[ids] = gF.reshape(-1, 3, 3) + (y / v)[:, None, None] * c
        if hessian:
            Al = out[3].reshape(-1, 3, 3, 3, 3)
            if not linear:  # y d2(det F): cof derivative, d2J/dF_ij dF_kl = J (Finv_ji Finv_lk - Finv_li Finv_jk)
                Fi = np.linalg.inv(Fl)
                Jd = np.linalg.det(Fl)
                d2 = Jd[:, None, None, None, None] * (np.einsum("sji,slk->sijkl", Fi, Fi)
                                                      - np.einsum("sli,sjk->sijkl", Fi, Fi))
                Al = Al + (y / v)[:, None, None, None, None] * d2
            A[ids] = Al
            extra.append((pr, c, out[4], out[5]))
    if not want:
        return energy, None, None
    grad = model._forces(P) if gradient else None
    H = None
    if hessian:
        H = model._stiffness(A)
        for pr, c, HFJ, HJJ in extra:
            ids, N, NT, cho = pr["ids"], pr["N"], pr["NT"], pr["M"]
            v = vol[ids]
            B = dof_rows(model, pr, ids, c.reshape(-1, 3, 3))  # dJ_s/dq (k, 12n) sparse
            Xr = dof_rows(model, pr, ids, (v[:, None] * HFJ).reshape(-1, 3, 3))  # v_s J_s^T HFJ_s
            Z = (NT @ sp.diags(v) @ B).toarray()  # (na, 12n)
            Q = cho @ Z
            X = (Xr.T @ N).toarray()  # (12n, na)
            XQ = X @ Q
            ND = (NT @ sp.diags(v * HJJ) @ N).toarray()
            H += XQ + XQ.T + Q.T @ (ND @ Q)
        H = 0.5 * (H + H.T)
    return energy, grad, H


def dof_rows(model, pr, ids, c) -> sp.csr_matrix:
    """Sparse (k, 12n) rows ``J_s^T vec(c_s)``: per sample the DOF vector of ``c_s : dF_s``
    (``sum_j c[i, j] G[p, c, j]`` at DOF (p, i, c))."""
    rows = np.einsum("sij,spcj->spic", c, model._G[ids]).reshape(len(ids), -1)
    return sp.csr_matrix((rows[pr["okr"]], pr["indices"], pr["indptr"]), shape=(len(ids), 12 * model.n_nodes))
