"""Materials: a strain measure composed with an energy law, over deformation gradients.

A :class:`Material` is ``W(F) = law(strain(F))``.  With the strain Jacobian
``D = de/dF`` (n, m, 3, 3), the law's stress ``s = dW/de`` (n, m) and tangent
``K`` (n, m, m), and the strain's geometric term ``G = sum_k s_k d2e_k/dF2``:

* first Piola-Kirchhoff stress ``P = D^T s`` (n, 3, 3) [Pa],
* tangent ``A[n, i, j, k, l] = dP_ij/dF_kl = D^T K D + G`` (n, 3, 3, 3, 3) [Pa].

:meth:`Material.evaluate` does it in one pass with two compiled kernels (the
law's and a general chain-rule kernel); ``backend="numpy"`` runs their numpy
twins.  :func:`material` builds any registered model by name from Young's
modulus and Poisson's ratio (or the model's own constants).

>>> import numpy as np
>>> mat = material("stvk", young=1e4, poisson=0.0)
>>> F = np.diag([1.1, 1.0, 1.0])[None]
>>> round(float(mat.stress(F)[0, 0, 0]), 6)    # E lambda (lambda^2 - 1) / 2
1155.0
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..._jit import chunk_bounds, njit, prange
from ...errors import InputError, check_choice
from . import laws as _laws
from .catalogue import _ORTHO, MODEL_CONSTANTS, POISSON_RANGE, check_constants

__all__ = ["Material", "MATERIALS", "shifted_invariants", "project_psd", "MODEL_CONSTANTS", "POISSON_RANGE",
           "material", "lame", "strain_kind", "check_constants"]

def strain_kind(strain) -> str:
    """The kind of strain vector a Strain produces (``"tensor"``, ``"invariant"``, ...).

    Raises InputError for an object that is not a registered strain and does
    not declare one of :data:`voxflex.deform.materials.laws.STRAIN_KINDS` as ``kind``.
    """
    kind = getattr(strain, "kind", None)
    if isinstance(kind, str) and kind in _laws.STRAIN_KINDS:
        return kind
    raise InputError(
        f"strain {getattr(strain, 'name', strain)!r} does not declare its kind; use a registered strain "
        f"(vf.strain names) or give it a kind among {', '.join(_laws.STRAIN_KINDS)}"
    )


def _get_strain(name):
    from . import strains

    return strains.get_strain(name)


# ----------------------------------------------------------------------------------------------
# the chain rule kernel and its numpy twin
# ----------------------------------------------------------------------------------------------
@njit
def _chain_kernel(jac, s, K, geo, P, A, with_tangent, with_geo):  # pragma: no cover - compiled
    """P = D^T s and A = D^T K D + G per sample; jac (n, m, 9), geo (n, 9, 9).

    A is computed on and above its diagonal and mirrored, so it is exactly symmetric (1000 neo-Hooke
    samples: 0.26 against 0.35 ms for all 81 entries).  Only the upper triangle of geo is read (it is
    symmetric), each entry before A[a, b] or A[b, a] is written, so ``geo`` and ``A`` may be the same
    array: :meth:`Material.evaluate` adds into the strain's geometric term in place (no second
    81-double array per sample to allocate and fill; the whole evaluate of 16384 neo-Hooke samples, five
    processes alternated with the code before, min of 80 calls each: median 9.4 against 13.7 ms).

    Serial on purpose: the pass is memory-bound (81 doubles written per sample), and on the
    2-core CI ``parallel=True`` measured no faster (0.86e6 vs 0.92e6 samples/s, m = 6) while
    compiling 2.4x longer (5.8 s vs 2.4 s).
    """
    n, m, _ = jac.shape
    kd = np.empty((m, 9))
    for q in range(n):
        for a in range(9):
            acc = 0.0
            for k in range(m):
                acc += s[q, k] * jac[q, k, a]
            P[q, a] = acc
        if with_tangent:
            for k in range(m):
                for b in range(9):
                    acc = 0.0
                    for l in range(m):
                        acc += K[q, k, l] * jac[q, l, b]
                    kd[k, b] = acc
            for a in range(9):  # A is symmetric (K and geo are second derivatives): its upper triangle, mirrored
                for b in range(a, 9):
                    acc = geo[q, a, b] if with_geo else 0.0
                    for k in range(m):
                        acc += jac[q, k, a] * kd[k, b]
                    A[q, a, b] = acc
                    A[q, b, a] = acc


def _chain_numpy(jac, s, K, geo, with_tangent):
    P = np.einsum("nk,nka->na", s, jac)
    if not with_tangent:
        return P, None
    A = np.einsum("nka,nkl,nlb->nab", jac, K, jac, optimize=True)
    if geo is not None:
        A = A + geo
    return P, A


# ----------------------------------------------------------------------------------------------
# projection of per-sample tangents to positive semi-definite, and its numpy twin
# ----------------------------------------------------------------------------------------------
PSD_CHUNK_SAMPLES = 4096
"""Samples per parallel chunk of :func:`_project_psd_kernel` at least (each sample is independent: the
same bits for any thread count).  A voxel bunny's 754k Gauss points: 0.9 s a call on one thread."""


def _project_psd_kernel(A) -> int:
    """Clamp the negative eigenvalues of each symmetric A[q] (n, 9, 9) to 0, in place; returns how many changed.

    A Cholesky attempt first (81 multiply-adds, no LAPACK call): a tangent it factors is
    positive definite and stays exactly as it is; the others get ``V max(lambda, 0) V^T``.
    Large batches run in chunks on numba's threads (:data:`PSD_CHUNK_SAMPLES`).
    """
    n = A.shape[0]
    chunks = min(64, n // PSD_CHUNK_SAMPLES)
    if chunks < 2:
        return int(_project_psd_range(A, 0, n))
    return int(_project_psd_chunks(A, chunks))


@njit(parallel=True)
def _project_psd_chunks(A, chunks):  # pragma: no cover - compiled
    counts = np.zeros(chunks, dtype=np.int64)
    for c in prange(chunks):
        s0, s1 = chunk_bounds(A.shape[0], chunks, c)
        counts[c] = _project_psd_range(A, s0, s1)
    return counts.sum()


@njit
def _project_psd_range(A, s0, s1):  # pragma: no cover - compiled
    """:func:`_project_psd_kernel` on samples s0 <= q < s1."""
    L = np.empty((9, 9))
    changed = 0
    for q in range(s0, s1):
        pd = True
        for i in range(9):
            for j in range(i + 1):
                acc = A[q, i, j]
                for k in range(j):
                    acc -= L[i, k] * L[j, k]
                if i == j:
                    if not acc > 0.0:  # NaN too: left to the eigen branch, which keeps NaN
                        pd = False
                        break
                    L[i, i] = np.sqrt(acc)
                else:
                    L[i, j] = acc / L[j, j]
            if not pd:
                break
        if pd:
            continue
        S = np.empty((9, 9))
        for i in range(9):
            for j in range(9):
                S[i, j] = 0.5 * (A[q, i, j] + A[q, j, i])
        if not np.all(np.isfinite(S)):
            continue
        lam, V = np.linalg.eigh(S)
        for i in range(9):
            for j in range(9):
                acc = 0.0
                for k in range(9):
                    if lam[k] > 0.0:
                        acc += V[i, k] * lam[k] * V[j, k]
                A[q, i, j] = acc
        changed += 1
    return changed


def _project_psd_numpy(A):
    """Numpy twin of :func:`_project_psd_kernel` (eigen-decomposition of every sample); returns (A, changed)."""
    S = 0.5 * (A + np.swapaxes(A, 1, 2))
    lam, V = np.linalg.eigh(S)
    neg = np.any(lam < 0, axis=1)
    out = A.copy()
    out[neg] = np.einsum("nik,nk,njk->nij", V[neg], np.maximum(lam[neg], 0.0), V[neg])
    return out, int(np.count_nonzero(neg))


def project_psd(A, *, backend: str = "numba"):
    """Per-sample tangents projected to positive semi-definite: negative eigenvalues set to 0.

    Parameters
    ----------
    A : array (n, 3, 3, 3, 3) or (n, 9, 9)
        Symmetric tangents dP/dF [Pa] (not modified).
    backend : {"numba", "numpy"}

    Returns
    -------
    array like A: unchanged where A is positive definite, ``V max(lambda, 0) V^T`` elsewhere.
    With a deformation gradient linear in the node state (voxels, affine frames) the
    assembled Hessian ``sum J^T A J`` is then positive semi-definite.
    """
    check_choice("backend", backend, _laws.BACKENDS)
    A = np.asarray(A, dtype=np.float64)
    shape = A.shape
    if A.ndim not in (3, 5) or A.shape[1:] not in ((9, 9), (3, 3, 3, 3)):
        raise InputError(f"tangents must have shape (n, 9, 9) or (n, 3, 3, 3, 3), got {A.shape}")
    flat = np.ascontiguousarray(A.reshape(-1, 9, 9))
    if backend == "numpy":
        return _project_psd_numpy(flat)[0].reshape(shape)
    out = flat.copy()
    _project_psd_kernel(out)
    return out.reshape(shape)


COINCIDENT_GAP = 1e-8
"""Relative gap ``(sig_p - sig_q) / sig_1`` under which two principal stretches count as equal."""


def _stretch_tangent(F, e, s, K, divided=True):
    """Tangent (n, 3, 3, 3, 3) of an isotropic law over principal stretches, from one SVD of F.

    ``A = sum_pq K_pq Phi_p (x) Phi_q + sum_{p<q} c_pq S_pq (x) S_pq + d_pq N_pq (x) N_pq`` with
    ``Phi_p = u_p v_p^T``, ``S_pq, N_pq = (u_p v_q^T +- u_q v_p^T)/sqrt 2``,
    ``d_pq = (s_p + s_q)/(sig_p + sig_q)`` and ``c_pq = (s_p - s_q)/(sig_p - sig_q)``, replaced by its
    limit ``(K_pp + K_qq)/2 - K_pq`` (the law being symmetric in the stretches) when the stretches
    coincide (or always, ``divided=False``, for the tests).  Independent of the SVD basis chosen
    inside a repeated singular value.  An independent oracle for the tests: the strain kernel gets
    the same limit from the law tangent it is given.
    """
    U, sig, Vt = np.linalg.svd(F)
    phi = np.einsum("nip,njp->npij", U, Vt.transpose(0, 2, 1))  # u_p v_p^T
    A = np.einsum("npq,npij,nqkl->nijkl", K, phi, phi)
    for p in range(3):
        for q in range(p + 1, 3):
            up, uq = U[:, :, p], U[:, :, q]
            vp, vq = Vt[:, p, :], Vt[:, q, :]
            a = np.einsum("ni,nj->nij", up, vq)
            b = np.einsum("ni,nj->nij", uq, vp)
            S = (a + b) / np.sqrt(2.0)
            N = (a - b) / np.sqrt(2.0)
            gap = e[:, p] - e[:, q]
            limit = 0.5 * (K[:, p, p] + K[:, q, q]) - K[:, p, q]
            close = np.abs(gap) <= COINCIDENT_GAP * np.abs(e[:, 0])
            if divided:
                with np.errstate(divide="ignore", invalid="ignore"):
                    c = np.where(close, limit, (s[:, p] - s[:, q]) / np.where(close, 1.0, gap))
            else:
                c = limit
            d = (s[:, p] + s[:, q]) / (e[:, p] + e[:, q])
            A += c[:, None, None, None, None] * np.einsum("nij,nkl->nijkl", S, S)
            A += d[:, None, None, None, None] * np.einsum("nij,nkl->nijkl", N, N)
    return A


def shifted_invariants(F, *, backend: str = "numba"):
    """``I1 - 3`` and ``J - 1`` (n,) of ``C = F^T F`` from ``H = F - I``, without cancellation.

    ``I1 - 3 = 2 tr H + |H|^2`` and ``J - 1 = tr H + i2(H) + det H`` with
    ``i2 = ((tr H)^2 - tr(H H)) / 2``: each is a sum of small terms, so near rest
    their error is round-off relative to the strain, not to 3 or 1.  ``backend``:
    a compiled kernel (one pass, no temporaries: 1000 samples in about 0.01 ms
    against 0.08 ms) or its numpy twin; they agree to round-off.
    """
    check_choice("backend", backend, _laws.BACKENDS)
    F = np.asarray(F, dtype=np.float64)
    if backend == "numpy":
        return _shifted_invariants_numpy(F)
    i1 = np.empty(F.shape[0])
    j = np.empty(F.shape[0])
    _shifted_invariants_kernel(np.ascontiguousarray(F), i1, j)
    return i1, j


@njit
def _shifted_invariants_kernel(F, i1, j):  # pragma: no cover - compiled
    for n in range(F.shape[0]):
        h00 = F[n, 0, 0] - 1.0
        h11 = F[n, 1, 1] - 1.0
        h22 = F[n, 2, 2] - 1.0
        h01 = F[n, 0, 1]
        h02 = F[n, 0, 2]
        h10 = F[n, 1, 0]
        h12 = F[n, 1, 2]
        h20 = F[n, 2, 0]
        h21 = F[n, 2, 1]
        tr = h00 + h11 + h22
        sq = h00 * h00 + h11 * h11 + h22 * h22 + h01 * h01 + h02 * h02 + h10 * h10 + h12 * h12 + h20 * h20 + h21 * h21
        hh = h00 * h00 + h11 * h11 + h22 * h22 + 2.0 * (h01 * h10 + h02 * h20 + h12 * h21)
        det = h00 * (h11 * h22 - h12 * h21) - h01 * (h10 * h22 - h12 * h20) + h02 * (h10 * h21 - h11 * h20)
        i1[n] = 2.0 * tr + sq
        j[n] = tr + 0.5 * (tr * tr - hh) + det


def _shifted_invariants_numpy(F):
    H = F - np.eye(3)
    tr = H[:, 0, 0] + H[:, 1, 1] + H[:, 2, 2]
    i1 = 2.0 * tr + np.einsum("nij,nij->n", H, H)
    i2 = 0.5 * (tr * tr - np.einsum("nij,nji->n", H, H))
    det = (H[:, 0, 0] * (H[:, 1, 1] * H[:, 2, 2] - H[:, 1, 2] * H[:, 2, 1])
           - H[:, 0, 1] * (H[:, 1, 0] * H[:, 2, 2] - H[:, 1, 2] * H[:, 2, 0])
           + H[:, 0, 2] * (H[:, 1, 0] * H[:, 2, 1] - H[:, 1, 1] * H[:, 2, 0]))
    return i1, tr + i2 + det


def _check_F(F) -> np.ndarray:
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 3 or F.shape[1:] != (3, 3):
        raise InputError(f"deformation gradients F must have shape (n, 3, 3), got {F.shape}")
    return F


# ----------------------------------------------------------------------------------------------
# Material
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Material:
    """An energy density over deformation gradients: ``law(strain(F))``.

    Parameters
    ----------
    strain : Strain
        A strain measure from :mod:`voxflex.deform.materials.strains` (``apply``, ``jacobian``, ``geometric``).
        Another object with those methods and a ``kind`` works too; if its ``geometric`` returns a
        new array on every call, ``fresh_geometric = True`` lets :meth:`evaluate` build the tangent
        in that array instead of a copy (voxflex's strains do).
    law : Law
        An energy law from :mod:`voxflex.deform.materials.laws` whose ``accepts`` holds the strain's kind.
    name : str
        The registry name (or a label of your choice).
    parameters : dict
        The constants it was built from (for records and summaries).
    """

    strain: object
    law: _laws.Law
    name: str = "custom"
    parameters: dict = field(default_factory=dict)

    def __post_init__(self):
        if not isinstance(self.law, _laws.Law):
            raise InputError(f"law must be a voxflex Law, got {type(self.law).__name__}")
        kind = strain_kind(self.strain)
        if kind not in self.law.accepts:
            from .strains import STRAINS

            valid = [n for n, st in STRAINS.items() if st.kind in self.law.accepts]
            raise InputError(
                f"material '{self.name}' cannot use strain '{self.strain.name}' ({kind}); valid: {', '.join(valid)}"
            )

    @property
    def constant_tangent(self) -> bool:
        """Whether dP/dF does not depend on F: a quadratic law over a strain affine in F."""
        return bool(self.law.quadratic and getattr(self.strain, "constant_jacobian", False))

    @property
    def _shifted(self) -> bool:
        """Whether W is evaluated from ``H = F - I`` without cancellation (the law's ``shifted_energy``
        over the ``invariant`` strain): the energy a line search compares stays exact to round-off
        relative to itself near rest, not to the moduli (stiffness contrast 1e6)."""
        return self.law.shifted_energy is not None and getattr(self.strain, "name", None) == "invariant"

    @property
    def linear_in_i1(self) -> bool:
        """Whether the tangent has the form of :attr:`~voxflex.deform.materials.laws.Law.linear_in_i1`:
        such a law over the ``invariant`` strain (see :meth:`evaluate_i1j`)."""
        return bool(getattr(self.law, "linear_in_i1", False)) and getattr(self.strain, "name", None) == "invariant"

    def evaluate_i1j(self, F):
        """Energy, stress and the tangent's coefficients of a :attr:`linear_in_i1` material, without the
        (n, 9, 9) tangent: ``W, P, (s1, s3, K33, J)`` with ``dP/dF = 2 s1 I + s3 d2J/dF2 + K33 dJ/dF dJ/dF``
        (each (n,); NaN where J <= 0, like the tangent).  For the voxel model's element stiffness
        (:func:`~voxflex.deform.models.voxel._kernels.element_stiffness_i1j`)."""
        if not self.linear_in_i1:
            raise InputError(f"material '{self.name}' is not of the form W = a I1 + f(J) over the invariant strain")
        F = _check_F(F)
        e = np.ascontiguousarray(self.strain.apply(F), dtype=np.float64)
        W, s, K = self.law._evaluate(e, True, "numba")
        if self._shifted:
            W = self.law.shifted_energy(*shifted_invariants(F))
        return W, self.strain.vjp(F, s), (s[:, 0].copy(), s[:, 2].copy(), K[:, 2, 2].copy(), e[:, 2].copy())

    def energy(self, F) -> np.ndarray:
        """Energy density W (n,) [Pa] of deformation gradients F (n, 3, 3)."""
        F = _check_F(F)
        if self._shifted:
            return self.law.shifted_energy(*shifted_invariants(F))
        e = np.ascontiguousarray(self.strain.apply(F), dtype=np.float64)
        return self.law._evaluate(e, False, "numba")[0]

    def stress(self, F) -> np.ndarray:
        """First Piola-Kirchhoff stress P = dW/dF (n, 3, 3) [Pa]."""
        return self.evaluate(F, tangent=False)[1]

    def tangent(self, F) -> np.ndarray:
        """Tangent A[n, i, j, k, l] = dP_ij/dF_kl (n, 3, 3, 3, 3) [Pa]."""
        return self.evaluate(F, tangent=True)[2]

    def evaluate(self, F, *, tangent: bool = True, backend: str = "numba", project: bool = False):
        """Energy, stress and tangent in one fused pass (what the solvers call).

        Parameters
        ----------
        F : array (n, 3, 3)
            Deformation gradients.
        tangent : bool
            Also compute the tangent (else the third result is None).
        backend : {"numba", "numpy"}
            Compiled kernels or their numpy twins (same results to round-off).
        project : bool
            Return the tangent projected to positive semi-definite per sample
            (:func:`project_psd`; skipped for a constant tangent, PSD already).

        Returns
        -------
        W : (n,) [Pa]; P : (n, 3, 3) [Pa]; A : (n, 3, 3, 3, 3) [Pa] or None.
        """
        F = _check_F(F)
        check_choice("backend", backend, _laws.BACKENDS)
        n = F.shape[0]
        numpy = backend == "numpy"
        if not tangent and not numpy and getattr(self.strain, "compiled_vjp", False) is True:
            # the stress alone (a line search's trials, forces): the strain, the law, then s through the
            # strain's own kernel, never forming the (n, 3, 3, 3) Jacobian (14,000 neo-Hooke samples: 1.18 -> 0.66 ms)
            e = np.ascontiguousarray(self.strain.apply(F), dtype=np.float64)
            W, s, _ = self.law._evaluate(e, False, backend)
            if self._shifted:
                W = self.law.shifted_energy(*shifted_invariants(F, backend=backend))
            return W, self.strain.vjp(F, s), None
        e, jac = self.strain.evaluate_reference(F) if numpy else self.strain.evaluate(F)
        e = np.ascontiguousarray(e, dtype=np.float64)
        m = e.shape[1]
        jac = np.ascontiguousarray(np.reshape(jac, (n, m, 9)), dtype=np.float64)
        W, s, K = self.law._evaluate(e, tangent, backend)
        geo = None
        if tangent and not getattr(self.strain, "constant_jacobian", False):
            # the law's tangent lets principal stretches take the right limit where they coincide
            if numpy:
                geo = self.strain.evaluate_reference(F, s, law_tangent=K)[2]
            else:
                geo = self.strain.geometric(F, s, law_tangent=K)
            geo = np.ascontiguousarray(np.reshape(geo, (n, 9, 9)), dtype=np.float64)
        if backend == "numpy":
            P, A = _chain_numpy(jac, s, K, geo, tangent)
        else:
            P = np.empty((n, 9))
            if geo is not None and getattr(self.strain, "fresh_geometric", False):
                A = geo  # in place: the kernel reads geo[a, b] (a <= b) before it writes A[a, b] or A[b, a]
            elif geo is not None:
                A = geo.copy()  # a strain of the user's may hand out an array it keeps
            else:
                A = np.empty((n, 9, 9) if tangent else (1, 9, 9))
            _chain_kernel(
                jac,
                s,
                K if tangent else np.zeros((1, m, m)),
                A,
                P,
                A,
                tangent,
                geo is not None,
            )
            if not tangent:
                A = None
        if project and A is not None and not self.constant_tangent:
            if numpy:
                A = _project_psd_numpy(A)[0]
            else:
                _project_psd_kernel(A)
        if self._shifted:
            W = self.law.shifted_energy(*shifted_invariants(F, backend=backend))  # the same W as :meth:`energy`
        P = P.reshape(n, 3, 3)
        A = None if A is None else A.reshape(n, 3, 3, 3, 3)
        return W, P, A


# ----------------------------------------------------------------------------------------------
# parameters
# ----------------------------------------------------------------------------------------------
def lame(young: float, poisson: float) -> tuple[float, float]:
    """Lamé constants ``(mu, lmbda)`` [Pa] from Young's modulus [Pa] and Poisson's ratio."""
    mu = young / (2.0 * (1.0 + poisson))
    lmbda = young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson))
    return mu, lmbda


def _number(name, value, *, low=None, high=None, low_open=True, high_open=True, what="") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number{what}, got {value!r}") from None
    ok = math.isfinite(v)
    if ok and low is not None:
        ok = v > low if low_open else v >= low
    if ok and high is not None:
        ok = v < high if high_open else v <= high
    if not ok:
        lo = "" if low is None else ("(" if low_open else "[") + f"{low:g}"
        hi = "" if high is None else f"{high:g}" + (")" if high_open else "]")
        rng = f"{lo or '(-inf'}, {hi or 'inf)'}"
        raise InputError(f"{name} = {value!r} is out of range; valid: {rng}{what}")
    return v




def _young_poisson(young, poisson):
    E = _number("young", young, low=0.0, what=" Pa")
    nu = _number("poisson", poisson, low=POISSON_RANGE[0], high=POISSON_RANGE[1])
    return E, nu


def _split(model, young, poisson, constants, alternatives):
    """Resolve (young, poisson) or a model's own constants; return (E, nu, consts dict)."""
    check_constants(model, sorted(constants))
    given = [k for k in alternatives if k in constants]
    if young is not None or poisson is not None:
        if young is None or poisson is None:
            raise InputError(f"material '{model}' needs both young and poisson (or {', '.join(alternatives)})")
        if given:
            raise InputError(
                f"material '{model}': give either young/poisson or {', '.join(alternatives)}, not both ({given[0]})"
            )
        E, nu = _young_poisson(young, poisson)
        return E, nu, dict(constants)
    if not alternatives:
        raise InputError(f"material '{model}' needs young and poisson")
    return None, None, dict(constants)


def _require(model, constants, names):
    missing = [k for k in names if k not in constants]
    if missing:
        raise InputError(
            f"material '{model}' needs young and poisson, or {', '.join(names)} (missing {missing[0]})"
        )


def _isotropic_lame(model, young, poisson, constants):
    E, nu, c = _split(model, young, poisson, constants, ("mu", "lmbda"))
    if E is not None:
        mu, lm = lame(E, nu)
        return mu, lm, {"young": E, "poisson": nu, "mu": mu, "lmbda": lm}
    _require(model, c, ("mu", "lmbda"))
    mu = _number("mu", c["mu"], low=0.0, what=" Pa")
    lm = _number("lmbda", c["lmbda"], low=-2.0 * mu / 3.0, what=" Pa (bulk modulus lmbda + 2 mu / 3 > 0)")
    E = mu * (3 * lm + 2 * mu) / (lm + mu)
    return mu, lm, {"young": E, "poisson": lm / (2 * (lm + mu)), "mu": mu, "lmbda": lm}


def _strain(model, strain, default):
    name = default if strain is None else strain
    if not isinstance(name, str):
        return name  # a Strain object
    return _get_strain(name)  # InputError listing the registered strains


def _hooke(young=None, poisson=None, strain=None, **constants):
    mu, lm, params = _isotropic_lame("hooke", young, poisson, constants)
    law = _laws.HookeLaw(_laws.isotropic_stiffness(mu, lm))
    return Material(_strain("hooke", strain, "corotational"), law, "hooke", params)


def _stvk(young=None, poisson=None, strain=None, **constants):
    mu, lm, params = _isotropic_lame("stvk", young, poisson, constants)
    law = _laws.HookeLaw(_laws.isotropic_stiffness(mu, lm))
    return Material(_strain("stvk", strain, "green"), law, "stvk", params)




def _hooke_orthotropic(young=None, poisson=None, strain=None, **constants):
    model = "hooke-orthotropic"
    if young is not None or poisson is not None:
        raise InputError(f"material '{model}' takes {', '.join(_ORTHO)}, not young/poisson")
    check_constants(model, sorted(constants))
    missing = [k for k in _ORTHO if k not in constants]
    if missing:
        raise InputError(f"material '{model}' needs {', '.join(_ORTHO)} (missing {missing[0]})")
    v = {}
    for k in _ORTHO:
        if k[0] in "EG":
            v[k] = _number(k, constants[k], low=0.0, what=" Pa")
        else:
            v[k] = _number(k, constants[k])
    law = _laws.HookeLaw(_laws.orthotropic_stiffness(**v))
    return Material(_strain(model, strain, "corotational"), law, model, v)


def _neo_hookean(young=None, poisson=None, strain=None, **constants):
    mu, lm, params = _isotropic_lame("neo-hookean", young, poisson, constants)
    return Material(_strain("neo-hookean", strain, "invariant"), _laws.NeoHookeanLaw(mu, lm), "neo-hookean", params)


def _stable_neo_hookean(young=None, poisson=None, strain=None, **constants):
    mu, lm, params = _isotropic_lame("stable-neo-hookean", young, poisson, constants)
    law = _laws.StableNeoHookeanLaw(4.0 * mu / 3.0, lm + 5.0 * mu / 6.0)
    return Material(_strain("stable-neo-hookean", strain, "invariant"), law, "stable-neo-hookean", params)


def _mooney_rivlin(young=None, poisson=None, strain=None, **constants):
    model = "mooney-rivlin"
    E, nu, c = _split(model, young, poisson, constants, ("c1", "bulk"))
    c2 = _number("c2", c.get("c2", 0.0), what=" Pa")
    if E is not None:
        mu, lm = lame(E, nu)
        c1 = 0.5 * mu - c2
        bulk = lm + 2.0 * mu / 3.0
    else:
        _require(model, c, ("c1", "bulk"))
        c1 = _number("c1", c["c1"], what=" Pa")
        bulk = _number("bulk", c["bulk"], low=0.0, what=" Pa")
        mu = 2.0 * (c1 + c2)
        if not (mu > 0):
            raise InputError(
                f"mooney-rivlin needs c1 + c2 > 0 (shear modulus 2(c1 + c2)); got c1={c1:g}, c2={c2:g}"
            )
        E, nu, lm = _moduli_summary(model, mu, bulk, "2(c1 + c2)")
    params = {"young": E, "poisson": nu, "c1": c1, "c2": c2, "bulk": bulk, "mu": mu, "lmbda": lm}
    return Material(_strain(model, strain, "invariant-deviatoric"), _laws.MooneyRivlinLaw(c1, c2, bulk), model, params)


ARRUDA_BOYCE_LAMBDA_M = 2.8
"""Default locking stretch of ``arruda-boyce`` built from young/poisson."""
VERONDA_WESTMANN_C2 = 1.0
"""Default exponent c2 of ``veronda-westmann`` built from young/poisson."""


def _moduli_summary(model, mu, bulk, shear):
    """(young, poisson, lmbda) of the small-strain shear modulus mu and bulk modulus (> 0).

    Any positive bulk modulus gives a Poisson's ratio in (-1, 0.5); ``shear``
    names how the model's constants make mu (kept for the callers' messages).
    """
    lm = bulk - 2.0 * mu / 3.0
    return mu * (3 * lm + 2 * mu) / (lm + mu), lm / (2 * (lm + mu)), lm


def _arruda_boyce(young=None, poisson=None, strain=None, **constants):
    """Arruda-Boyce: ``mu`` is the series coefficient, the small-strain shear modulus is ``mu * factor``.

    From young/poisson (and ``lambda_m``, default 2.8) ``mu = mu_0 / factor(lambda_m)`` with
    ``mu_0`` the Lamé shear modulus and ``bulk = lmbda + 2 mu_0 / 3``, so the material linearizes
    exactly to Hooke with that E and nu (``factor`` is the law's ``shear_modulus / mu``).
    """
    model = "arruda-boyce"
    E, nu, c = _split(model, young, poisson, constants, ("mu", "bulk"))
    lam_m = _number("lambda_m", c.get("lambda_m", ARRUDA_BOYCE_LAMBDA_M), low=1.0, what=" (locking stretch)")
    factor = _laws.ArrudaBoyceLaw(1.0, lam_m, 1.0).shear_modulus
    if E is not None:
        mu0, lm = lame(E, nu)
        mu = mu0 / factor
        bulk = lm + 2.0 * mu0 / 3.0
    else:
        _require(model, c, ("mu", "bulk"))
        mu = _number("mu", c["mu"], low=0.0, what=" Pa")
        bulk = _number("bulk", c["bulk"], low=0.0, what=" Pa")
        mu0 = mu * factor
        E, nu, lm = _moduli_summary(model, mu0, bulk, "mu*factor")
    law = _laws.ArrudaBoyceLaw(mu, lam_m, bulk)
    params = {"young": E, "poisson": nu, "mu": mu, "lambda_m": lam_m, "bulk": bulk,
              "shear_modulus": mu0, "lmbda": lm}
    return Material(_strain(model, strain, "invariant-deviatoric"), law, model, params)



def _veronda_westmann(young=None, poisson=None, strain=None, **constants):
    """Veronda-Westmann: from young/poisson (and ``c2``, default 1) ``c1 = mu / c2``, ``bulk = lmbda + 2 mu / 3``."""
    model = "veronda-westmann"
    E, nu, c = _split(model, young, poisson, constants, ("c1", "bulk"))
    c2 = _number("c2", c.get("c2", VERONDA_WESTMANN_C2), low=0.0, what=" (dimensionless)")
    if E is not None:
        mu, lm = lame(E, nu)
        c1 = mu / c2
        bulk = lm + 2.0 * mu / 3.0
    else:
        _require(model, c, ("c1", "bulk"))
        c1 = _number("c1", c["c1"], low=0.0, what=" Pa")
        bulk = _number("bulk", c["bulk"], low=0.0, what=" Pa")
        mu = c1 * c2
        E, nu, lm = _moduli_summary(model, mu, bulk, "c1*c2")
    params = {"young": E, "poisson": nu, "c1": c1, "c2": c2, "bulk": bulk, "mu": mu, "lmbda": lm}
    law = _laws.VerondaWestmannLaw(c1, c2, bulk)
    return Material(_strain(model, strain, "invariant-deviatoric"), law, model, params)


def _volume(model, law_type):
    def factory(young=None, poisson=None, strain=None, **constants):
        E, nu, c = _split(model, young, poisson, constants, ("bulk",))
        if E is not None:
            bulk = E / (3.0 * (1.0 - 2.0 * nu))
            params = {"young": E, "poisson": nu, "bulk": bulk}
        else:
            _require(model, c, ("bulk",))
            bulk = _number("bulk", c["bulk"], low=0.0, what=" Pa")
            params = {"bulk": bulk}
        return Material(_strain(model, strain, "invariant"), law_type(bulk), model, params)

    factory.__name__ = "_" + model.replace("-", "_")
    return factory


# Treloar-rubber-like default shape of the Ogden terms (Ogden 1972): relative mu_p and alpha_p
_OGDEN_ALPHA = (1.3, 5.0, -2.0)
_OGDEN_WEIGHT = (0.63, 0.0012, -0.01)


def _ogden(young=None, poisson=None, strain=None, **constants):
    model = "ogden"
    E, nu, c = _split(model, young, poisson, constants, ("mu_p", "lmbda"))
    if E is not None:
        mu, lm = lame(E, nu)
        if "alpha_p" in c:
            al = np.atleast_1d(np.asarray(c["alpha_p"], dtype=float))
            if al.ndim != 1 or al.size == 0 or not np.all(np.isfinite(al)) or np.any(al == 0):
                raise InputError("ogden alpha_p must be a non-empty sequence of finite non-zero numbers")
            mus = 2.0 * mu / (al * al.size)  # equal share of the shear modulus per term
        else:
            al = np.asarray(_OGDEN_ALPHA)
            w = np.asarray(_OGDEN_WEIGHT)
            mus = w * mu / np.sum(0.5 * w * al)
    else:
        _require(model, c, ("mu_p", "alpha_p", "lmbda"))
        mus = np.atleast_1d(np.asarray(c["mu_p"], dtype=float))
        al = np.atleast_1d(np.asarray(c["alpha_p"], dtype=float))
        lm = _number("lmbda", c["lmbda"], what=" Pa")
        if mus.shape != al.shape or mus.ndim != 1:
            raise InputError("ogden mu_p and alpha_p must have the same length")
        mu = float(np.sum(0.5 * mus * al))
        if not mu > 0:
            raise InputError(f"ogden needs sum(mu_p * alpha_p) / 2 > 0 (the shear modulus); got {mu:g}")
        E = mu * (3 * lm + 2 * mu) / (lm + mu)
        nu = lm / (2 * (lm + mu))
    law = _laws.OgdenLaw(tuple(mus), tuple(al), lm)
    params = {"young": E, "poisson": nu, "mu": mu, "lmbda": lm, "mu_p": law.mu_p, "alpha_p": law.alpha_p}
    return Material(_strain(model, strain, "principal-stretch"), law, model, params)



MATERIALS: dict[str, Callable[..., Material]] = {
    "hooke": _hooke,
    "hooke-orthotropic": _hooke_orthotropic,
    "stvk": _stvk,
    "neo-hookean": _neo_hookean,
    "stable-neo-hookean": _stable_neo_hookean,
    "mooney-rivlin": _mooney_rivlin,
    "arruda-boyce": _arruda_boyce,
    "veronda-westmann": _veronda_westmann,
    "volume-log": _volume("volume-log", _laws.VolumeLogLaw),
    "volume-quadratic": _volume("volume-quadratic", _laws.VolumeQuadraticLaw),
    "ogden": _ogden,
}
"""Registry: model name -> factory ``(young=None, poisson=None, strain=None, **constants) -> Material``."""


def material(name: str, *, young=None, poisson=None, strain=None, **constants) -> Material:
    """Build a registered material model by name.

    Parameters
    ----------
    name : str
        One of :data:`MATERIALS`: ``hooke`` (default strain ``corotational``;
        ``strain="linear"`` is small-strain elasticity, ``"green"`` is StVK),
        ``hooke-orthotropic`` (``E1, E2, E3, nu12, nu13, nu23, G12, G23, G13``),
        ``stvk``, ``neo-hookean``, ``stable-neo-hookean``, ``mooney-rivlin``
        (``c1, c2, bulk``), ``arruda-boyce`` (``mu, lambda_m, bulk``; young/poisson
        with an optional ``lambda_m``, default 2.8), ``veronda-westmann`` (``c1, c2, bulk``;
        young/poisson with an optional ``c2``, default 1), ``volume-log``,
        ``volume-quadratic`` (``bulk``), ``ogden`` (``mu_p, alpha_p, lmbda``).
    young : float, optional
        Young's modulus [Pa], > 0.
    poisson : float, optional
        Poisson's ratio in (-1, 0.5) (negative for auxetic materials).
    strain : str or Strain, optional
        The strain measure; default: the one the model needs.
    **constants
        Model constants instead of young/poisson: ``mu``, ``lmbda`` [Pa] for the
        isotropic models; see above for the others.

    Raises
    ------
    InputError
        Unknown model, unknown or missing parameter, value out of range, or a
        strain the law cannot read.

    Examples
    --------
    >>> mat = material("neo-hookean", young=1e4, poisson=0.3)
    >>> mat.parameters["mu"]   # doctest: +ELLIPSIS
    3846.15...
    """
    check_choice("material", name, MATERIALS)
    return MATERIALS[name](young=young, poisson=poisson, strain=strain, **constants)
