"""Derivative-contract cases of the strain measures (voxflex.deform.materials.strains).

x is a batch F (n, 3, 3), y the strain vectors (n, m).  jvp / vjp / geometric
are contractions of ``jacobian`` and ``geometric``; the harness checks them
against central differences (rtol 1e-6, see tests/contract.py).

The batch: three F near identity, two large rotations combined with stretches
(well separated singular values, so principal stretches and the flipped SVD
value are differentiable), and for the SVD variant an inverted F as well.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from contract import MappingCase

from voxflex.deform.materials.strains import STRAINS


def _rotation(v):
    v = np.asarray(v, dtype=float)
    th = np.linalg.norm(v)
    k = v / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def sample_F(inverted: bool = False, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    F = [np.eye(3) + 0.1 * rng.standard_normal((3, 3)) for _ in range(3)]
    F.append(_rotation([0.4, -2.1, 1.0]) @ np.diag([1.6, 0.7, 1.2]) @ _rotation([1.3, 0.2, -0.5]))
    F.append(_rotation([-2.5, 0.3, 0.9]) @ np.diag([0.5, 2.0, 0.9]))
    if inverted:
        # singular values (1.5, 1.1, 0.6) with a reflection: det F < 0
        F.append(_rotation([0.3, 1.7, -0.2]) @ np.diag([1.5, -0.6, 1.1]) @ _rotation([0.9, -0.4, 2.0]))
    return np.stack(F)


def _case(name: str, inverted: bool = False) -> MappingCase:
    st = STRAINS[name]

    def jacobian(x):
        J = st.jacobian(x)
        n, m = J.shape[:2]
        return sp.block_diag([J[e].reshape(m, 9) for e in range(n)], format="csr")

    return MappingCase(
        name=f"strain-{name}" + ("-inverted" if inverted else ""),
        x0=sample_F(inverted),
        apply=st.apply,
        jvp=lambda x, v: np.einsum("nkij,nij->nk", st.jacobian(x), v),
        vjp=lambda x, u: np.einsum("nkij,nk->nij", st.jacobian(x), u),
        geometric=None if st.constant_jacobian else (
            lambda x, u, v: np.einsum("nijkl,nkl->nij", st.geometric(x, u), v)
        ),
        jacobian=jacobian,
        constant_jacobian=st.constant_jacobian,
    )


CASES = [_case(name) for name in STRAINS]
# inversion: the signed SVD is smooth there; the polar factor (a reflection) and
# the invariants are smooth for any non-singular F as well
CASES += [_case(name, inverted=True) for name in ("corotational-svd", "corotational", "invariant", "invariant-deviatoric")]
