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
(:func:`~voxflex.deform.materials.fbar.nearly_incompressible`).

The capped remainder (``"auto"`` with linearly precise weights on point samples: Gauss-Legendre, elastons,
bare mid-point samples).  The projection onto a few frames' weights takes away the stiffness of every part of
the volume change the weights cannot resolve, which with reproducing kernels made the frames 5-11 % too soft
at 20-40 frames (numbers below); the full term keeps it at the material's bulk modulus, which locks.  Under
"auto" such labels keep the projection and give the remainder the bulk modulus of the same shear modulus at
nu = 0.4 (:func:`~voxflex.deform.materials.fbar.capped_bulk`, ``kc``):

    E = sum_s v_s W(F~_s) + kc / 2 sum_s v_s (J_s - Jbar_s)^2

with its exact gradient and Hessian (``kc (J - Jbar) c`` per sample; ``-kc (db/dq)^T M^+ (db/dq)`` through
``b``).  Since the projection is V-orthogonal, ``|J|^2 = |Jbar|^2 + |J - Jbar|^2``: for a linear material
at nu = 0.4 the capped model is the full one, so "auto" does not jump where it switches on, and the
remainder vanishes for an affine motion (the patch test) and as frames are added (the weights' span grows).
Above 0.4 the part the weights resolve keeps the material's incompressibility, the rest is held like a
nu = 0.4 material: no locking, no softening.  Linear cantilever 32x8x8, reproducing kernels, against the voxel
model with B-bar (``python benchmarks/bench_frames_quadrature.py --locking`` measures neo-Hooke):
elastons at 20 / 40 / 80 frames within +0.9 / -1.0 / -0.6 % at every nu of 0.3, 0.45, 0.49, 0.499, 0.4999,
Gauss-Legendre within +1.2 / -0.7 / +0.3 %; the full term +8.3 / +3.7 / +6.2 % stiff at 0.4999 (Gauss-Legendre),
the bare projection 9.5 / 10.0 / 1.9 % soft.  Stabilised mid-point regions with linearly precise weights keep
the full term under "auto" (their fluctuation has no remainder term yet).

Earlier measurements (before the capped remainder): on the neo-Hooke cantilever 32x8x8 with elastons
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

Stabilised mid-point regions (one sample per region with its Gauss points' mean F and fluctuation
energy, :mod:`~voxflex.deform.models.frames.stabilise`) integrate the projection as their Gauss points
would: with one weight per region (its mean) ``M`` and ``b`` were those of a discrete projection over the
region centroids, too close to the samples' own ratios, and the library's default frames on the bundled
scene (clamped at x <= 1.5 mm then) came out 5 % stiffer than the same frames with Gauss-Legendre points (11.98 against 12.61 mm).  Now
``M`` gains the weights' fluctuation moments ``Omega = sum_r sum_q v_q dw_q dw_q^T``, ``b`` the covariance of
the weights and the volume ratio inside each region (``cof(F_r) : sum_q v_q dw_q dF_q``: exact for a
trace, first order for det), and the energy the projected ratio's fluctuation inside the regions,
``kappa pi^T Omega pi / 2``: a linear material then gives the Gauss points' energy, gradient and Hessian
to round-off, and neo-Hooke on the bundled scene 12.630 against 12.611 mm (0.15 %).

:class:`~voxflex.deform.models.frames.model.FrameModel` calls :func:`projected_pass` for its energy,
gradient and Hessian when some label is projected (``model.volumetric[label]``), and keeps the
operators :func:`volumetric_projection` makes.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ...._blas import one_thread
from ...._linalg import vdot
from ...materials.fbar import _det3, _inv3, bar_scalar
from ._projection_kernels import weighted_rows
from .stabilise import _dofs, _rows

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
            extra = _region_moments(model, ids, active) if model.tables is not None else None
            if extra is not None:  # the weights' fluctuation inside the regions: M as their Gauss points give it
                M = M + extra["Omega"]
            lam, U = np.linalg.eigh(M)
            keep = lam > 1e-12 * max(float(lam.max(initial=0.0)), 1e-300)
            Minv = (U[:, keep] / lam[keep]) @ U[:, keep].T
            cap = float(model.volumetric_cap.get(label, 0.0))
            if cap and extra is not None:
                raise ValueError("the capped remainder is for point samples (stabilised regions keep the full term)")
            col = np.full(n, -1, dtype=np.int64)
            col[active] = np.arange(len(active))
            out.append({"label": label, "ids": ids, "N": N, "NT": N.T.tocsr(), "M": 0.5 * (Minv + Minv.T), "cap": cap,
                        "col": col, "dofs4": dofs[ids].reshape(k, P, 3, 4),
                        "okr": okr, "indices": d[okr], "indptr": indptr, "linear": bool(
                            getattr(model.materials[label], "constant_tangent", False)), "regions": extra})
            if extra is not None:
                extra["kappa"] = _rest_bulk(model.materials[label], out[-1]["linear"])
        model._proj = out
    return model._proj


def _region_moments(model, ids, active) -> dict | None:
    """The weights' moments over the stabilised mid-point regions ``ids`` of one label (sample i = region i):
    ``Omega`` (na, na) over the active frames, and per group of regions the cross moments ``C`` with their
    positions in ``ids``, parents and active columns (:class:`~.stabilise.RegionTables`)."""
    tables = model.tables
    if not tables.weight_moments:
        return None
    na = len(active)
    col = np.full(model.n_nodes, -1, dtype=np.int64)
    col[active] = np.arange(na)
    pos = np.full(tables.n_regions, -1, dtype=np.int64)
    pos[ids] = np.arange(len(ids))
    Omega = np.zeros((na, na))
    groups = []
    for regs, Pb, Om, Cr in tables.weight_moments:
        sel = pos[regs] >= 0
        if not sel.any():
            continue
        r = regs[sel]
        idx = tables.index[r, :Pb]
        frames = np.where(idx >= 0, idx, 0)
        a = col[frames]
        ok = (idx >= 0) & (a >= 0)  # a parent the label's weights never reach has no moments (zero rows)
        cols = np.where(ok, a, 0)
        np.add.at(Omega, (cols[:, :, None], cols[:, None, :]), np.where(ok[:, :, None] & ok[:, None, :], Om[sel], 0.0))
        groups.append({"pos": pos[r], "frames": frames, "cols": cols, "dofs": _dofs(idx),
                       "C": np.where(ok[:, :, None, None, None], Cr[sel], 0.0), "G": tables.G[r, :Pb]})
    return {"Omega": 0.5 * (Omega + Omega.T), "groups": groups}


def _rest_bulk(material, linear) -> float:
    """``d2 W~ / d Jbar2`` at rest (F = I, Jbar = 1 or the trace 3): the label's bulk modulus, the stiffness
    of the projected volume ratio's fluctuation inside a region."""
    F = np.eye(3)[None]
    out = bar_scalar(material, F, np.array([3.0 if linear else 1.0]), linear=linear, gradient=True, tangent=True)
    return float(out[5][0])


_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0


def _cofactor_terms(F, linear):
    """Per region: cof(F) (k, 3, 3) and F^-1 (None for the trace of B-bar: cof = I, no curvature)."""
    if linear:
        return np.broadcast_to(np.eye(3), F.shape), None
    Fi = np.linalg.inv(F)
    return np.linalg.det(F)[:, None, None] * Fi.transpose(0, 2, 1), Fi


_EPS2 = np.einsum("ikm,jln->mnijkl", _EPS, _EPS).reshape(9, 81)
"""The third derivative of det as a (9, 81) map: ``d3 det [Y]_(ij)(kl) = sum_mn eps_ikm eps_jln Y_mn``."""


def _region_D(du, C):
    """``D[r, a] = sum_p d_p C[r, a, p]`` (Rb, Pb, 3, 3) from the parents' DOF rows du (Rb, Pb, 3, 4) and the
    cross moments C (Rb, Pb, Pb, 4, 3), as one batched product."""
    R, Pb = C.shape[:2]
    rows = du.transpose(0, 2, 1, 3).reshape(R, 1, 3, 4 * Pb)  # (r, i, (p, c))
    return np.matmul(rows, C.reshape(R, Pb, 4 * Pb, 3))


def _cof_rows(cof, C):
    """``out[..., p, i, c] = sum_j cof[r, i, j] C[..., p, c, j]`` for C (Rb, ..., 4, 3): the DOF rows of
    ``cof : sum_p d_p C_p`` (shaped like C with the last two axes (3, 4))."""
    R = C.shape[0]
    out = np.matmul(C.reshape(R, -1, 3), cof.transpose(0, 2, 1)).reshape(C.shape[:-1] + (3,))  # (..., c, i)
    return np.swapaxes(out, -1, -2)


def _d2det(F, Fi, Y):
    """``d2 det(F) [Y]`` (k, 3, 3): the derivative of ``cof(F) : Y`` in F for fixed Y,
    ``J (tr(F^-1 Y) F^-T - (F^-1 Y F^-1)^T)``."""
    J = np.linalg.det(F)
    FY = np.einsum("kij,kjl->kil", Fi, Y)
    return J[:, None, None] * (np.trace(FY, axis1=1, axis2=2)[:, None, None] * Fi.transpose(0, 2, 1)
                               - np.einsum("kij,kjl->kil", FY, Fi).transpose(0, 2, 1))


def projected_pass(model, F, gradient, hessian, d=None):
    """Samples with the volumetric term of some labels projected onto the frames' weights (module
    docstring).

    Per projected label, with ``J_s`` the samples' volume ratios (or traces, B-bar),
    ``Jbar = N pi``, ``pi = M^-1 b``, ``b = N^T V J``: the per-sample derivatives of ``W(F~(F_s, Jbar_s))``
    (:func:`~voxflex.deform.materials.fbar.bar_scalar`: gF, gJ, HFF, HFJ, HJJ) chain as
    gradient ``J^T (v gF + y c)`` with ``y = V N M^-1 N^T (v gJ)``, ``c_s = dJ_s/dF_s``, and Hessian
    ``J^T blockdiag(v HFF + y d2J) J + X Q + (X Q)^T + Q^T N^T diag(v HJJ) N Q`` with
    ``Q = M^-1 N^T V B`` (``B_s = c_s^T J_s``, the rows of dJ/dq) and
    ``X = sum_s v_s J_s^T HFJ_s N_s`` (numpy and scipy.sparse; every product is rank n).

    Stabilised mid-point regions integrate the projection as their Gauss points do (``d``: the DOFs
    minus rest, for the cross moments): ``M`` gains the weights' fluctuation ``Omega``, ``b`` the
    covariance of the weights and the volume ratio inside each region, ``c_a = sum_r cof(F_r) : D_ra``
    with ``D_ra = sum_q v_q dw_qa dF_q`` (linear in the DOFs through the cross moments; first order in
    the fluctuation, exact for B-bar's trace), and the energy the fluctuation of ``Jbar`` inside the
    regions, ``kappa pi^T Omega pi / 2`` (``kappa`` the rest bulk modulus; exact for a linear material):
    for a linear material the regions then give the Gauss points' energy to round-off.  The gradient
    and Hessian of these terms are exact (``dc/dq``, ``Q = M^-1 db/dq``, and ``y^T d2c`` through the
    derivatives of the determinant).
    """
    vol = model._volume
    m, n = len(vol), model.n_nodes
    want = gradient or hessian
    energy = 0.0
    P = np.zeros((m, 3, 3)) if want else None
    A = np.zeros((m, 3, 3, 3, 3)) if hessian else None
    extra = []
    gextra = np.zeros(12 * n) if want else None
    for label, ids in model._groups:
        if model.volumetric[label]:
            continue
        W, Pl, Al = model.materials[label].evaluate(F[ids], tangent=hessian)
        energy += vdot(vol[ids], W)
        if want:
            P[ids] = Pl
        if hessian:
            A[ids] = Al
    rows = None
    for pr in model._projection():
        ids, N, NT, cho, linear = pr["ids"], pr["N"], pr["NT"], pr["M"], pr["linear"]
        R = pr.get("regions")
        Fl = F[ids]
        v = vol[ids]
        # det and inverse once per pass, by cofactors (_det3 / _inv3: 5x LAPACK's batched calls on 3x3s)
        Jd = None if linear else _det3(Fl)
        Js = np.trace(Fl, axis1=1, axis2=2) if linear else Jd
        b = NT @ (v * Js)
        local = []  # per group of regions: (group, D, cof, F^-1, F)
        if R is not None:
            if rows is None:
                if d is None:
                    raise ValueError("projected_pass over stabilised regions needs d, the DOFs minus rest")
                rows = _rows(np.asarray(d, dtype=float).reshape(n, 12))  # (n, 3, 4)
            for g in R["groups"]:
                D = _region_D(rows[g["frames"]], g["C"])  # (Rb, Pb, 3, 3)
                Fr = Fl[g["pos"]]
                cof, Fi = _cofactor_terms(Fr, linear)
                np.add.at(b, g["cols"], np.einsum("rij,raij->ra", cof, D))
                local.append((g, D, cof, Fi, Fr))
        pi = cho @ b
        Jbar = N @ pi
        out = bar_scalar(model.materials[pr["label"]], Fl, Jbar, linear=linear, gradient=want, tangent=hessian)
        energy += vdot(v, out[0])
        kc = pr["cap"]
        if kc:  # the remainder: kc / 2 sum_s v_s (J_s - Jbar_s)^2
            energy += 0.5 * kc * vdot(v, (Js - Jbar) ** 2)
        if R is not None:
            Op = R["Omega"] @ pi
            energy += 0.5 * R["kappa"] * vdot(pi, Op)
        if not np.isfinite(energy):
            return np.inf, (np.full((n, 12), np.nan) if gradient else None), \
                (np.full((12 * n, 12 * n), np.nan) if hessian else None)
        if not want:
            continue
        gF, gJ = out[1], out[2]
        gpi = NT @ (v * gJ)
        if R is not None:
            gpi = gpi + R["kappa"] * Op
        yv = cho @ gpi  # dE/db
        if kc:  # the remainder's kc / 2 (sum_s v_s J_s^2 - b^T M^+ b): dE/db = -kc pi (its direct part below)
            yv = yv - kc * pi
        y = v * (N @ yv)  # dE/dJ_s through Jbar
        Fi_s = None if linear else _inv3(Fl)  # every J_s / Jbar_s > 0 here (the energy is finite)
        if linear:
            c = np.broadcast_to(np.eye(3), Fl.shape)
        else:
            c = Jd[:, None, None] * Fi_s.transpose(0, 2, 1)  # cofactor
        Pl = gF.reshape(-1, 3, 3) + (y / v)[:, None, None] * c
        if kc:  # the remainder's direct dE/dJ_s = kc v_s J_s
            Pl = Pl + (kc * Js)[:, None, None] * c
        Yl = []  # per group: y . D (Rb, 3, 3) and y . C (Rb, Pb, 4, 3)
        for g, D, cof, Fi, Fr in local:
            ya = yv[g["cols"]]
            Y = np.einsum("ra,raij->rij", ya, D)
            Cg = g["C"]
            T = np.matmul(ya[:, None, :], Cg.reshape(len(ya), Cg.shape[1], -1)).reshape(Cg.shape[0], *Cg.shape[2:])
            if Fi is not None:  # y . dc through cof(F_r): d2 det [Y] on the region's F
                Pl[g["pos"]] += _d2det(Fr, Fi, Y) / v[g["pos"], None, None]
            # y . dc through D: d (cof : sum_p d_p C_p) / d d_p[i, c] = sum_j cof_ij T_p[c, j]
            gextra += np.bincount(g["dofs"].ravel(), weights=_cof_rows(cof, T).ravel(), minlength=12 * n)
            Yl.append((Y, T))
        P[ids] = Pl
        if hessian:
            Al = out[3].reshape(-1, 3, 3, 3, 3)
            if kc:  # the remainder's direct second derivative: kc (c (x) c + J_s d2J_s), its d2J with y's below
                Al = Al + kc * np.einsum("sij,skl->sijkl", c, c)
            if not linear:  # y d2(det F): cof derivative, d2J/dF_ij dF_kl = J (Finv_ji Finv_lk - Finv_li Finv_jk)
                d2 = Jd[:, None, None, None, None] * (np.einsum("sji,slk->sijkl", Fi_s, Fi_s)
                                                      - np.einsum("sli,sjk->sijkl", Fi_s, Fi_s))
                Al = Al + ((y / v) + kc * Js)[:, None, None, None, None] * d2
                for (g, D, cof, Fi, Fr), (Y, T) in zip(local, Yl):  # y . d2c: the third derivative of det [Y]
                    Al[g["pos"]] += (Y.reshape(-1, 9) @ _EPS2).reshape(-1, 3, 3, 3, 3) / v[g["pos"], None, None, None,
                                                                                              None]
                d2l = [d2[g["pos"]] for g, *_ in local]  # the regions' d2 det, for the cross term below
            A[ids] = Al
            extra.append((pr, c, out[4], out[5], local, Yl, None if linear else d2l))
    if not want:
        return energy, None, None
    grad = (model._forces(P) + gextra.reshape(n, 12)) if gradient else None
    H = None
    if hessian:
        H = model._stiffness(A)
        # the rank-n products below are small dense ones (active frames x DOFs): on one BLAS thread, as the
        # solvers' dense kernels are (voxflex._blas: threaded OpenBLAS left spinning threads that stalled the
        # next Cholesky, 1.4 ms, for up to 108 ms on the bundled scene)
        with one_thread():
            for pr, c, HFJ, HJJ, local, Yl, d2l in extra:
                ids, N, NT, cho = pr["ids"], pr["N"], pr["NT"], pr["M"]
                R = pr.get("regions")
                v = vol[ids]
                # Z = N^T V (dJ/dq) (na, 12n) and X = sum_s v_s J_s^T HFJ_s N_s (12n, na): one compiled pass each
                na = N.shape[1]
                args = (model._index[ids], pr["col"], model._w[ids], v, model._G[ids])
                Z = weighted_rows(*args, np.broadcast_to(c, (len(ids), 3, 3)), pr["dofs4"], na, 12 * n)
                for g, D, cof, Fi, Fr in local:  # dc/dq
                    rows_c = _cof_rows(cof, g["C"])
                    if Fi is not None:
                        S = _d2det(np.repeat(Fr, D.shape[1], axis=0), np.repeat(Fi, D.shape[1], axis=0),
                                   D.reshape(-1, 3, 3)).reshape(D.shape)
                        rows_c = rows_c + np.einsum("raij,rpcj->rapic", S, g["G"], optimize=True)  # G: dF_r / d d_p
                    flat = np.broadcast_to(g["cols"][:, :, None, None, None], rows_c.shape) * Z.shape[1] + \
                        np.broadcast_to(g["dofs"][:, None], rows_c.shape)
                    Z += np.bincount(flat.ravel(), weights=rows_c.ravel(), minlength=Z.size).reshape(Z.shape)
                Q = cho @ Z
                X = weighted_rows(*args, np.asarray(HFJ).reshape(-1, 3, 3), pr["dofs4"], na, 12 * n).T
                XQ = X @ Q
                ND = (NT @ sp.diags(v * HJJ) @ N).toarray()
                if R is not None:
                    ND = ND + R["kappa"] * R["Omega"]
                H += XQ + XQ.T + Q.T @ (ND @ Q)
                if pr["cap"]:  # the remainder through b: -kc (db/dq)^T M^+ (db/dq)
                    H -= pr["cap"] * (Z.T @ Q)
                for k, (g, D, cof, Fi, Fr) in enumerate(local if d2l is not None else ()):  # y . d2c: d2 det [dF, dY]
                    T = Yl[k][1]
                    M1 = np.einsum("rpcj,rijkl,rqdl->rpicqkd", g["G"], d2l[k], T, optimize=True)
                    Pb = T.shape[1]
                    M1 = M1.reshape(len(Fr), 12 * Pb, 12 * Pb)
                    M1 = M1 + M1.transpose(0, 2, 1)
                    dd = g["dofs"].reshape(len(Fr), 12 * Pb)
                    H += np.bincount((dd[:, :, None] * H.shape[1] + dd[:, None, :]).ravel(), weights=M1.ravel(),
                                     minlength=H.size).reshape(H.shape)
        H = 0.5 * (H + H.T)
    return energy, grad, H


def dof_rows(model, pr, ids, c) -> sp.csr_matrix:
    """Sparse (k, 12n) rows ``J_s^T vec(c_s)``: per sample the DOF vector of ``c_s : dF_s``
    (``sum_j c[i, j] G[p, c, j]`` at DOF (p, i, c)): the plain twin of
    :func:`~._projection_kernels.weighted_rows` (``N^T V`` times these rows), which the tests compare."""
    rows = np.einsum("sij,spcj->spic", c, model._G[ids]).reshape(len(ids), -1)
    return sp.csr_matrix((rows[pr["okr"]], pr["indices"], pr["indptr"]), shape=(len(ids), 12 * model.n_nodes))
