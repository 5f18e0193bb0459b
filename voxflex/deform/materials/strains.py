"""Strain measures: the mapping from deformation gradients F to strain vectors.

The simulator chains ``nodes --J--> F --J--> strain --> energy``.  Every measure
here is a :class:`Strain` with ``apply`` (E), ``jacobian`` (dE/dF) and
``geometric`` (the second-derivative term ``sum_k s_k d2E_k/dF dF`` of the
stiffness), all batched over n samples and computed by compiled kernels
(:mod:`voxflex.deform.materials._strain_kernels`, each with a numpy twin in
:mod:`voxflex.deform.materials._strain_twins`).

Conventions
-----------
* Tensor strains are Voigt vectors ``[xx, yy, zz, xy, yz, xz]`` with
  engineering shear (``e_xy = 2 E_xy``); the conjugate stress vector ``s`` has
  no factor 2, so the energy increment is ``s . de``.
* ``jacobian(F)[n, k, i, j] = dE_k / dF_ij``;
  ``geometric(F, s)[n, i, j, k, l] = sum_c s_c d2E_c / dF_ij dF_kl``.

Measures (registry names)
-------------------------
``linear``                 sym(F) - I (small strain).
``green``                  (F^T F - I) / 2.
``corotational``           sym(R^T F) - I, R from the polar decomposition
                           F = R U (U = sqrt(F^T F)); R is the orthogonal polar
                           factor, a reflection when det F < 0 (then E = U - I
                           does not see the inversion: use ``corotational-svd``).
``corotational-svd``       R = U_F V^T from the SVD with the reflection moved into
                           the smallest singular value (det R = +1; Irving et
                           al. 2004): E = V diag(sig) V^T - I with sig_3 < 0 for
                           inverted F, smooth through flat F (sig_3 = 0).
                           Equal to ``corotational`` when det F > 0.
``corotational-qr``        R from Gram-Schmidt on F's columns (F = R T, T upper
                           triangular with positive diagonal): E = sym(T) - I.
``corotational-small``     R = I + W with W = skew(F) = (F - F^T)/2, the
                           linearized rotation (not orthonormalized):
                           E = sym((I - W) F) - I, quadratic in F; exact to
                           second order in the rotation angle only, so NOT
                           invariant under finite rotations.
``invariant``              (I1, I2, J) of C = F^T F.
``invariant-deviatoric``   (J^-2/3 I1, J^-4/3 I2, J), with the real cube root
                           (finite for J < 0, infinite at J = 0).
``principal-stretch``      the singular values of F, sorted descending.

Degenerate cases
----------------
* polar / SVD: the derivatives divide by ``sig_p + sig_q`` for p != q only, so
  repeated singular values and one zero singular value are fine; two zero
  singular values (or, for the signed SVD, a flipped value equal to minus
  another one) make them infinite.  The SVD branch switches the flipped value
  when the two smallest |sig| cross: E is continuous there but not smooth.
* QR: infinite when F's columns are linearly dependent.
* principal-stretch: the sorted singular values are not differentiable where
  two coincide.  The Jacobian is then one valid subgradient; in the geometric
  term the divided difference ``(s_p - s_q)/(sig_p - sig_q)`` uses
  ``max(sig_p - sig_q, STRETCH_GAP * sig_1)`` (STRETCH_GAP = 1e-8) as
  denominator, so it is exact for gaps above that floor and equals 0 when
  ``s_p = s_q`` exactly; for a smooth isotropic energy the true limit is
  ``psi_pp - psi_pq`` which this split cannot recover from s alone: pass the
  law's tangent ``law_tangent = ds/dsig`` to :meth:`Strain.geometric` /
  :meth:`Strain.evaluate` and pairs within the floor use
  ``(K_pp + K_qq)/2 - (K_pq + K_qp)/2`` instead (exact for laws symmetric in
  the stretches, e.g. at F = I).

References
----------
Irving, Teran, Fedkiw, "Invertible finite elements for robust simulation of
large deformation", SCA 2004.

Examples
--------
>>> import numpy as np
>>> from voxflex.deform.materials.strains import strain
>>> strain("green", np.diag([1.1, 1.0, 1.0])).round(3)
array([0.105, 0.   , 0.   , 0.   , 0.   , 0.   ])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from voxflex.errors import InputError, check_choice

from . import _strain_kernels as _k
from . import _strain_twins as _t

__all__ = [
    "Strain",
    "STRAINS",
    "get_strain",
    "strain",
    "apply_with_gradient",
    "jacobian_with_gradient",
    "geometric_with_gradient",
    "STRETCH_GAP",
]

STRETCH_GAP = 1e-8
"""Relative floor of |sig_p - sig_q| in the principal-stretch geometric term."""

_FAMILY = {"tensor": _k.TENSOR, "corot": _k.COROT, "invariant": _k.INVARIANT, "stretch": _k.STRETCH}

CHUNK_SAMPLES = 1 << 15
"""Samples per chunk at least when a strain kernel runs on numba's threads (:func:`_strain_kernels.chunked_strain`;
smaller batches run in one serial pass: waking the threads costs more).  A voxel bunny's 754k Gauss points,
invariants with their Jacobian: 40 ms on one thread, 25 ms on two; with the geometric term 203 / 83 ms."""

CHUNKS = 16
"""Chunks of a large batch at most."""

_KERNELS = {
    "tensor": (_k._tensor_kernel, _t.np_tensor),
    "corot": (_k._corot_kernel, _t.np_corot),
    "invariant": (_k._invariant_kernel, _t.np_invariant),
    "stretch": (_k._stretch_kernel, _t.np_stretch),
}


def _as_batch(F, name="F"):
    """(n,3,3) or (3,3) -> (contiguous float64 (n,3,3), was_single)."""
    F = np.asarray(F, dtype=np.float64)
    single = F.shape == (3, 3)
    if single:
        F = F[None]
    if F.ndim != 3 or F.shape[1:] != (3, 3):
        raise InputError(f"{name} must have shape (n, 3, 3) or (3, 3), got {F.shape}; pass one 3x3 matrix per sample")
    return np.ascontiguousarray(F), single


@dataclass(frozen=True)
class Strain:
    """One strain measure E(F), batched over samples.

    Attributes
    ----------
    name : str
        Registry name, e.g. ``"green"``.
    size : int
        m, the length of the strain vector (6 for Voigt tensors, 3 otherwise).
    description : str
        One line: the formula.
    constant_jacobian : bool
        dE/dF does not depend on F (``linear``).
    constant_hessian : bool
        d2E/dF2 does not depend on F (``linear``, ``green``, ``corotational-small``).
    """

    name: str
    size: int
    description: str
    family: str
    switch: float
    constant_jacobian: bool = False
    constant_hessian: bool = False
    fresh_geometric = True  # geometric() returns a new array: Material.evaluate may write into it

    @property
    def kind(self) -> str:
        """What the vector holds: ``"tensor"`` (Voigt strain), ``"invariant"``,
        ``"invariant-deviatoric"`` or ``"principal-stretch"`` (the names of
        :data:`voxflex.deform.materials.laws.STRAIN_KINDS`)."""
        return self.name if self.size == 3 else "tensor"

    # -- compiled path ---------------------------------------------------------------
    def _check_law_tangent(self, K, n, single):
        """law_tangent -> contiguous (n, m, m) for principal-stretch, an empty (0, m, m) when unused."""
        m = self.size
        if K is None or self.family != "stretch":
            return np.empty((0, m, m))
        K = np.asarray(K, dtype=np.float64)
        if single and K.shape == (m, m):
            K = K[None]
        if K.shape != (n, m, m):
            raise InputError(f"law_tangent must have shape ({n}, {m}, {m}) for strain '{self.name}', got {K.shape}; "
                             "pass ds_k/de_l of the law, one (m, m) matrix per sample")
        return np.ascontiguousarray(K)

    def _run(self, F, s, want_j, want_g, law_tangent=None):
        F, single = _as_batch(F)
        n, m = F.shape[0], self.size
        E = np.empty((n, m))
        J = np.empty((n, m, 3, 3)) if want_j else np.empty((0, m, 3, 3))
        if want_g:
            s = np.ascontiguousarray(np.asarray(s, dtype=np.float64).reshape(F.shape[0], m) if single
                                     else np.asarray(s, dtype=np.float64))
            if s.shape != (n, m):
                raise InputError(f"s must have shape ({n}, {m}) for strain '{self.name}', got {s.shape}")
            G = np.empty((n, 3, 3, 3, 3))
        else:
            s = np.empty((0, m))
            G = np.empty((0, 3, 3, 3, 3))
        kernel = _KERNELS[self.family][0]
        stretch = self.family == "stretch"
        K = self._check_law_tangent(law_tangent if want_g else None, n, single) if stretch else None
        chunks = min(CHUNKS, n // CHUNK_SAMPLES)
        if chunks >= 2:
            _k.chunked_strain(_FAMILY[self.family], F, s, 0 if stretch else int(self.switch),
                              float(self.switch) if stretch else 0.0, want_j, want_g, E, J, G,
                              K if stretch else np.empty((0, m, m)), chunks)
        elif stretch:
            kernel(F, s, self.switch, want_j, want_g, E, J, G, K)
        else:
            kernel(F, s, int(self.switch), want_j, want_g, E, J, G)
        if single:
            return E[0], (J[0] if want_j else None), (G[0] if want_g else None)
        return E, (J if want_j else None), (G if want_g else None)

    def apply(self, F) -> np.ndarray:
        """Strain vectors: F (n, 3, 3) -> E (n, m) (a (3, 3) F gives (m,))."""
        return self._run(F, None, False, False)[0]

    def jacobian(self, F) -> np.ndarray:
        """dE_k/dF_ij: (n, 3, 3) -> (n, m, 3, 3)."""
        return self._run(F, None, True, False)[1]

    def geometric(self, F, s, *, law_tangent=None) -> np.ndarray:
        """sum_k s_k d2E_k/dF_ij dF_kl: F (n, 3, 3), s (n, m) -> (n, 3, 3, 3, 3), symmetric in (ij), (kl).

        ``law_tangent`` (n, m, m), optional: the law's ``ds_k/de_l``.  Used only by
        ``principal-stretch``, where it gives the exact limit at coincident
        stretches (see the module docstring); ignored by the other measures,
        whose geometric term is exact without it.
        """
        return self._run(F, s, False, True, law_tangent)[2]

    def evaluate(self, F, s=None, *, law_tangent=None):
        """Fused E, dE/dF and, when ``s`` is given, the geometric term.

        Returns ``(E, J)`` or ``(E, J, G)`` with the shapes of :meth:`apply`,
        :meth:`jacobian` and :meth:`geometric` (``law_tangent`` as in :meth:`geometric`).
        """
        E, J, G = self._run(F, s, True, s is not None, law_tangent)
        return (E, J) if s is None else (E, J, G)

    @property
    def compiled_vjp(self) -> bool:
        """Whether :meth:`vjp` runs a kernel of its own (the invariant strains) rather than contracting
        :meth:`jacobian`: a material's pass without the tangent then never forms the Jacobian."""
        return self.family == "invariant"

    def vjp(self, F, s) -> np.ndarray:
        """``sum_k s_k dE_k/dF``: F (n, 3, 3), s (n, m) -> (n, 3, 3), the stress of a law's ``s = dW/dE``
        (the same as contracting :meth:`jacobian` with s, to round-off)."""
        F, single = _as_batch(F)
        n, m = F.shape[0], self.size
        s = np.ascontiguousarray(np.asarray(s, dtype=np.float64).reshape(n, m) if single
                                 else np.asarray(s, dtype=np.float64))
        if s.shape != (n, m):
            raise InputError(f"s must have shape ({n}, {m}) for strain '{self.name}', got {s.shape}")
        if self.compiled_vjp:
            P = np.empty((n, 3, 3))
            chunks = min(CHUNKS, n // CHUNK_SAMPLES)
            if chunks >= 2:
                _k.chunked_invariant_vjp(F, s, int(self.switch), P, chunks)
            else:
                _k._invariant_vjp_kernel(F, s, int(self.switch), P)
        else:
            P = np.einsum("nk,nkij->nij", s, self.jacobian(F))
        return P[0] if single else P

    # -- numpy twin (reference for the tests) ----------------------------------------------
    def evaluate_reference(self, F, s=None, *, law_tangent=None):
        """Same as :meth:`evaluate`, computed by the plain numpy twin (slow, for tests)."""
        F, single = _as_batch(F)
        s2 = None if s is None else np.asarray(s, dtype=np.float64).reshape(F.shape[0], self.size)
        if self.family == "stretch":
            K = self._check_law_tangent(law_tangent if s is not None else None, F.shape[0], single)
            E, J, G = _t.np_stretch(F, s2, self.switch, K if K.shape[0] else None)
        else:
            E, J, G = _KERNELS[self.family][1](F, s2, int(self.switch))
        if single:
            E, J, G = E[0], J[0], (None if G is None else G[0])
        return (E, J) if s is None else (E, J, G)


def _make(name, size, description, family, switch, **kw):
    return Strain(name=name, size=size, description=description, family=family, switch=switch, **kw)


STRAINS: dict[str, Strain] = {
    s.name: s
    for s in [
        _make("linear", 6, "sym(F) - I", "tensor", _k.LINEAR, constant_jacobian=True, constant_hessian=True),
        _make("green", 6, "(F^T F - I) / 2", "tensor", _k.GREEN, constant_hessian=True),
        _make("corotational", 6, "sym(R^T F) - I, R polar factor of F", "corot", _k.POLAR),
        _make("corotational-svd", 6, "sym(R^T F) - I, R = U V^T from the rotation-signed SVD", "corot", _k.SVD),
        _make("corotational-qr", 6, "sym(R^T F) - I, R from Gram-Schmidt on F's columns", "corot", _k.QR),
        _make("corotational-small", 6, "sym((I - W) F) - I, W = skew(F)", "tensor", _k.SMALL, constant_hessian=True),
        _make("invariant", 3, "(I1, I2, J) of C = F^T F", "invariant", 0),
        _make("invariant-deviatoric", 3, "(J^-2/3 I1, J^-4/3 I2, J)", "invariant", 1),
        _make("principal-stretch", 3, "singular values of F, descending", "stretch", STRETCH_GAP),
    ]
}
"""Every strain measure, by registry name."""


def get_strain(name: str) -> Strain:
    """The :class:`Strain` registered as ``name``; unknown names raise InputError listing the valid ones."""
    check_choice("strain", name, STRAINS)
    return STRAINS[name]


def strain(name: str, F) -> np.ndarray:
    """Strain vectors of deformation gradients.

    Parameters
    ----------
    name : str
        A registry name (see :data:`STRAINS`), e.g. ``"green"``.
    F : array_like, shape (n, 3, 3) or (3, 3)
        Deformation gradients (dimensionless), finite.

    Returns
    -------
    ndarray, shape (n, m) or (m,)
        Voigt strain ``[xx, yy, zz, xy, yz, xz]`` with engineering shear (m = 6)
        or the 3 invariants / principal stretches.

    Examples
    --------
    >>> import numpy as np
    >>> float(strain("linear", np.eye(3) + 0.01 * np.ones((3, 3)))[3])
    0.02
    """
    s = get_strain(name)
    F, single = _as_batch(F)
    if not np.all(np.isfinite(F)):
        raise InputError("F contains NaN or infinite entries; pass finite deformation gradients")
    E = s.apply(F)
    return E[0] if single else E


# ----------------------------------------------------------------------------- F with gradient (elastons)
def _check_grad(strain, F, dF):
    s = get_strain(strain) if isinstance(strain, str) else strain
    F, single = _as_batch(F)
    dF = np.asarray(dF, dtype=np.float64)
    if single:
        dF = dF[None]
    if dF.shape != F.shape + (3,):
        raise InputError(f"dF must have shape (n, 3, 3, 3) matching F {F.shape}, got {dF.shape}")
    return s, F, dF


def apply_with_gradient(strain, F, dF):
    """Strain and its spatial gradient for a linearly varying F.

    Parameters
    ----------
    strain : str or Strain
    F : (n, 3, 3)
        Deformation gradient at the sample point.
    dF : (n, 3, 3, 3)
        Its spatial gradient, ``dF[n, i, j, a] = dF_ij / dx_a`` (1/m).

    Returns
    -------
    E : (n, m)
    dE : (n, m, 3)
        ``dE[n, k, a] = sum_ij dE_k/dF_ij dF_ij/dx_a``.
    """
    s, F, dF = _check_grad(strain, F, dF)
    E, J = s.evaluate(F)
    return E, np.einsum("nkij,nija->nka", J, dF)


def jacobian_with_gradient(strain, F, dF):
    """Jacobian of ``(E, dE)`` of :func:`apply_with_gradient` w.r.t. ``(F, dF)``.

    The full Jacobian has four blocks: ``dE/dF = J``, ``dE/d(dF) = 0``,
    ``d(dE_ka)/d(dF_ijb) = delta_ab J_kij`` and ``d(dE_ka)/dF_pq = K[n, k, a, p, q]``.

    Returns
    -------
    J : (n, m, 3, 3)
        dE_k/dF_ij.
    K : (n, m, 3, 3, 3)
        ``K[n, k, a, p, q] = sum_ij d2E_k/dF_ij dF_pq dF_ija``.
    """
    s, F, dF = _check_grad(strain, F, dF)
    n, m = F.shape[0], s.size
    E, J = s.evaluate(F)
    K = np.empty((n, m, 3, 3, 3))
    for k in range(m):
        unit = np.zeros((n, m))
        unit[:, k] = 1.0
        H = s.geometric(F, unit)  # d2E_k / dF_ij dF_pq
        K[:, k] = np.einsum("nijpq,nija->napq", H, dF)
    return J, K


def geometric_with_gradient(strain, F, dF, s, ds):
    """Geometric stiffness of ``phi = s . E + sum_a ds[:, :, a] . dE[:, :, a]``.

    Parameters
    ----------
    s : (n, m)
        Stress conjugate to E.
    ds : (n, m, 3)
        Stress conjugate to the strain gradient dE.

    Returns
    -------
    G_FF : (n, 3, 3, 3, 3)
        d2 phi / dF_ij dF_kl.
    G_FdF : (n, 3, 3, 3, 3, 3)
        ``G_FdF[n, i, j, k, l, b] = d2 phi / dF_ij d(dF_klb)``; the (dF, dF) block is zero.

    Raises
    ------
    NotImplementedError
        For measures whose second derivative depends on F (the (F, F) block
        then needs third derivatives of E, not implemented): every measure
        except ``linear``, ``green`` and ``corotational-small``.
    """
    st, F, dF = _check_grad(strain, F, dF)
    if not st.constant_hessian:
        raise NotImplementedError(
            f"geometric_with_gradient needs third derivatives of strain '{st.name}', not implemented; "
            "available for linear, green and corotational-small"
        )
    n, m = F.shape[0], st.size
    s = np.asarray(s, dtype=np.float64).reshape(n, m)
    ds = np.asarray(ds, dtype=np.float64).reshape(n, m, 3)
    G_FF = st.geometric(F, s)
    G_FdF = np.empty((n, 3, 3, 3, 3, 3))
    for b in range(3):
        G_FdF[..., b] = st.geometric(F, np.ascontiguousarray(ds[:, :, b]))
    return G_FF, G_FdF
