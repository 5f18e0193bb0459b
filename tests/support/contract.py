"""The shared derivative contract every mapping and material is held to.

Each module of the deformation core contributes cases in a file
``tests/contract_<module>.py`` that defines a list ``CASES`` of
:class:`MappingCase` and/or :class:`MaterialCase`; ``tests/test_contract.py``
collects them all and runs the checks below.

All checks use central finite differences in float64 along random directions.
With step ``eps`` relative to the state's scale, the truncation error is
O(eps^2) and the round-off O(1e-16/eps); with the default ``eps = 1e-6`` both
stay below ~1e-9 relative, so the default relative tolerance ``rtol = 1e-6``
leaves three orders of margin while still catching any wrong term (a missing
or wrong term produces O(1) relative errors).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np


@dataclass
class MappingCase:
    """A differentiable map ``y = apply(x)`` between arrays of any shape.

    ``jvp(x, v)`` is J(x) v, ``vjp(x, u)`` is J(x)^T u, ``geometric(x, u, v)``
    is the geometric stiffness (d/dx [J(x)^T u]) v, ``jacobian(x)`` the
    assembled J as a dense or sparse (y.size, x.size) matrix.  Leave
    ``geometric`` as None only when J is constant (``constant_jacobian``),
    which is then checked too.
    """

    name: str
    x0: np.ndarray
    apply: Callable
    jvp: Callable
    vjp: Callable
    geometric: Callable | None = None
    jacobian: Callable | None = None
    constant_jacobian: bool = False
    rtol: float = 1e-6
    eps: float = 1e-6
    seed: int = 0


@dataclass
class MaterialCase:
    """Energy density W(F), first Piola-Kirchhoff stress P = dW/dF and tangent dP/dF."""

    name: str
    F0: np.ndarray  # (n, 3, 3)
    energy: Callable  # (n,3,3) -> (n,)
    stress: Callable  # (n,3,3) -> (n,3,3)
    tangent: Callable  # (n,3,3) -> (n,3,3,3,3)
    rtol: float = 1e-6
    eps: float = 1e-6
    seed: int = 0
    extra: dict = field(default_factory=dict)


def _relerr(a, b) -> float:
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    scale = max(np.linalg.norm(a), np.linalg.norm(b), 1e-300)
    return float(np.linalg.norm(a - b) / scale)


def check_mapping(case: MappingCase) -> None:
    rng = np.random.default_rng(case.seed)
    x = np.array(case.x0, dtype=float)
    y = np.asarray(case.apply(x))
    h = case.eps * max(1.0, float(np.max(np.abs(x))))
    for _ in range(2):
        v = rng.standard_normal(x.shape)
        u = rng.standard_normal(y.shape)
        # J v against central differences
        fd = (np.asarray(case.apply(x + h * v)) - np.asarray(case.apply(x - h * v))) / (2 * h)
        jv = np.asarray(case.jvp(x, v))
        assert jv.shape == y.shape, f"{case.name}: jvp shape {jv.shape} != {y.shape}"
        err = _relerr(jv, fd)
        assert err < case.rtol, f"{case.name}: J v differs from finite differences by {err:.2e}"
        # adjoint identity <J v, u> = <v, J^T u>
        jtu = np.asarray(case.vjp(x, u))
        assert jtu.shape == x.shape, f"{case.name}: vjp shape {jtu.shape} != {x.shape}"
        lhs, rhs = float(np.vdot(jv, u)), float(np.vdot(v, jtu))
        assert abs(lhs - rhs) <= 1e-10 * max(abs(lhs), abs(rhs), np.linalg.norm(jv) * np.linalg.norm(u)), (
            f"{case.name}: <Jv,u>={lhs!r} but <v,J^T u>={rhs!r}"
        )
        # geometric stiffness against the change of J^T u
        fd_g = (np.asarray(case.vjp(x + h * v, u)) - np.asarray(case.vjp(x - h * v, u))) / (2 * h)
        if case.geometric is None:
            assert case.constant_jacobian, f"{case.name}: no geometric stiffness given and J is not declared constant"
            scale = max(np.linalg.norm(jtu), 1e-300)
            assert np.linalg.norm(fd_g) / scale < case.rtol, f"{case.name}: J declared constant but J^T u changes"
        else:
            kg = np.asarray(case.geometric(x, u, v))
            assert kg.shape == x.shape, f"{case.name}: geometric shape {kg.shape} != {x.shape}"
            err = _relerr(kg, fd_g)
            assert err < case.rtol or np.linalg.norm(kg - fd_g) < case.rtol * np.linalg.norm(jtu), (
                f"{case.name}: geometric stiffness differs from finite differences of J^T u by {err:.2e}"
            )
        if case.jacobian is not None:
            J = case.jacobian(x)
            Jv = J @ v.ravel()
            err = _relerr(np.asarray(Jv).ravel(), jv.ravel())
            assert err < 1e-12, f"{case.name}: assembled J disagrees with jvp by {err:.2e}"


def check_material(case: MaterialCase) -> None:
    rng = np.random.default_rng(case.seed)
    F = np.array(case.F0, dtype=float)
    n = F.shape[0]
    P = np.asarray(case.stress(F))
    A = np.asarray(case.tangent(F))
    assert P.shape == (n, 3, 3) and A.shape == (n, 3, 3, 3, 3)
    h = case.eps
    for _ in range(2):
        dF = rng.standard_normal(F.shape)
        # stress against the energy gradient, per sample
        fd_w = (np.asarray(case.energy(F + h * dF)) - np.asarray(case.energy(F - h * dF))) / (2 * h)
        pw = np.einsum("nij,nij->n", P, dF)
        err = _relerr(pw, fd_w)
        assert err < case.rtol, f"{case.name}: stress differs from the energy gradient by {err:.2e}"
        # tangent against the stress gradient
        fd_p = (np.asarray(case.stress(F + h * dF)) - np.asarray(case.stress(F - h * dF))) / (2 * h)
        ap = np.einsum("nijkl,nkl->nij", A, dF)
        err = _relerr(ap, fd_p)
        assert err < case.rtol, f"{case.name}: tangent differs from the stress gradient by {err:.2e}"
    # major symmetry of the tangent (it is a Hessian)
    Am = A.reshape(n, 9, 9)
    asym = np.max(np.abs(Am - Am.transpose(0, 2, 1))) / max(np.max(np.abs(Am)), 1e-300)
    assert asym < 1e-10, f"{case.name}: tangent not symmetric ({asym:.2e})"
