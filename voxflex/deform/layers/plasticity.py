"""Plasticity by a rest-strain (relative) mapping: ``e → e - e_p`` with von Mises yield on the strain.

A :class:`PlasticMaterial` wraps an elastic :class:`~voxflex.deform.materials.constitutive.Material`
whose strain is a Voigt tensor (``linear``, ``green``, the corotational
ones): the law sees the elastic strain ``e - e_p`` where ``e_p`` ``(s, 6)`` is
a plastic (rest) strain stored per quadrature sample.  Subtracting a fixed
``e_p`` is a relative mapping with identity Jacobian, so stress and tangent
are the base material's at the shifted strain (exact derivatives for a given
state).

Yield and hardening (strain space, isotropic, associative)
-----------------------------------------------------------
With ``dev`` the deviator of the elastic strain tensor (Voigt shear halved)
and ``ε_eq = sqrt(2/3) |dev(e - e_p)|`` the von Mises equivalent strain, a
sample yields when ``ε_eq > ε_y + H α`` (``ε_y`` the yield strain, H ≥ 0 the
dimensionless linear hardening modulus, α the accumulated equivalent plastic
strain).  The return mapping (radial, exact for linear hardening) moves e_p
along the trial deviator ``n``: ``Δγ = (sqrt(2/3) |dev_tr| - ε_y - H α_n) /
(sqrt(2/3) (1 + H))``, ``e_p += Δγ n``, ``α += sqrt(2/3) Δγ``.  For an
isotropic Hooke law the deviatoric stress is ``2 μ dev``, so this is the
classical von Mises model with yield stress ``σ_y = 3 μ ε_y`` and hardening
modulus ``3 μ H``; in uniaxial stress the elastic-plastic tangent is
``E·3μH / (E + 3μH)``.

The state is updated between solves, not inside Newton (a staggered scheme):
:meth:`PlasticMaterial.update` return-maps from the last committed state with
the current total strain; repeating solve + update until e_p stops changing
solves the implicit incremental problem of the load step, and
:meth:`PlasticMaterial.commit` then makes it the start of the next step.
:class:`PlasticModel` does this inside the solvers: it wraps a model whose
materials include plastic ones and implements the post-convergence hook
(:func:`voxflex.deform.models.protocol.end_step`), so :func:`~voxflex.deform.solve.stepping.solve`
re-solves every step until no plastic strain changes by more than
:data:`STATIONARY` of the yield strain, then commits it (and keeps the
committed state of every step in :attr:`PlasticModel.history`).

Sample identity
---------------
``evaluate(F, samples=ids)`` takes the sample indices of the rows of F.
Without ``samples`` it requires F to hold every sample in order (one call
over all samples of the label: the frame models with point samples always
evaluate so, a voxel model does for a label of at most
:data:`~voxflex.deform.models.voxel.constant.CHUNK_ELEMENTS` voxels, element-major, the
Gauss points of each voxel in turn); any other row count is refused once a
sample has yielded, because the plastic strains could not be matched to the
rows.  A virgin material (no plastic strain anywhere) is the base material
and takes any rows: the models query the rest tangent with one row of F = I.
:class:`PlasticModel` checks the model evaluates its plastic labels that way.

Example
-------
>>> import numpy as np
>>> from voxflex.deform.materials.constitutive import material
>>> mat = PlasticMaterial(material("hooke", young=1.0, poisson=0.0, strain="linear"), 1, yield_strain=0.01)
>>> F = np.diag([1.1, 1.0, 1.0])[None]
>>> mat.update(F)                  # the sample yields
1
>>> bool(mat.energy(F)[0] < material("hooke", young=1.0, poisson=0.0, strain="linear").energy(F)[0])
True
"""

from __future__ import annotations

from collections import deque

import numpy as np

from ...errors import InputError
from ..materials.constitutive import Material, strain_kind
from ..models.protocol import PointSamples, end_step
from .base import ModelLayer

__all__ = ["PlasticMaterial", "PlasticModel", "von_mises_strain", "STATIONARY", "ANDERSON_DEPTH"]

ANDERSON_DEPTH = 5
"""Passes of a step that :meth:`PlasticModel.end_step` combines (Anderson mixing) to speed up the
staggered iteration."""


STATIONARY = 1e-10
"""A step's plastic strains are settled when no component changes by more than this fraction of the
yield strain between two solves (:meth:`PlasticModel.end_step`)."""


_SQ23 = np.sqrt(2.0 / 3.0)


def _deviator(e):
    """Deviatoric strain tensor in Voigt (tensor shear, no factor 2) and its Frobenius norm."""
    d = np.asarray(e, dtype=np.float64).copy()
    d[:, 3:] *= 0.5
    d[:, :3] -= d[:, :3].mean(axis=1, keepdims=True)
    norm = np.sqrt((d[:, :3] ** 2).sum(axis=1) + 2.0 * (d[:, 3:] ** 2).sum(axis=1))
    return d, norm


def von_mises_strain(e) -> np.ndarray:
    """Equivalent strain ``sqrt(2/3) |dev(e)|`` ``(s,)`` of Voigt strains ``(s, 6)`` (engineering shear)."""
    e = np.asarray(e, dtype=np.float64)
    if e.ndim != 2 or e.shape[1] != 6:
        raise InputError(f"strains must be (s, 6) Voigt vectors, got shape {e.shape}")
    return _SQ23 * _deviator(e)[1]


class _ShiftedStrain:
    """The base strain minus a per-row offset (set before each evaluation)."""

    kind = "tensor"
    size = 6

    def __init__(self, base):
        self.base = base
        self.name = f"{base.name}-minus-plastic"
        self.constant_jacobian = bool(getattr(base, "constant_jacobian", False))
        self.fresh_geometric = bool(getattr(base, "fresh_geometric", False))  # geometric() is the base's
        self.offset = None

    def apply(self, F):
        return self.base.apply(F) - self.offset

    def evaluate(self, F, s=None, *, law_tangent=None):
        out = self.base.evaluate(F, s, law_tangent=law_tangent)
        return (out[0] - self.offset,) + tuple(out[1:])

    def evaluate_reference(self, F, s=None, *, law_tangent=None):
        out = self.base.evaluate_reference(F, s, law_tangent=law_tangent)
        return (out[0] - self.offset,) + tuple(out[1:])

    def jacobian(self, F):
        return self.base.jacobian(F)

    def geometric(self, F, s, *, law_tangent=None):
        return self.base.geometric(F, s, law_tangent=law_tangent)


class PlasticMaterial:
    """An elastic material with a per-sample plastic rest strain (see the module docstring).

    Parameters
    ----------
    base : Material
        The elastic material; its strain must be a Voigt tensor strain.
    n_samples : int or None
        Number of quadrature samples s whose state is stored; None: sized by
        :class:`PlasticModel` from the model the material is used in.
    yield_strain : float
        ε_y > 0, the von Mises equivalent strain at first yield (dimensionless).
    hardening : float
        H >= 0, the increase of the yield strain per unit equivalent plastic strain.

    Attributes
    ----------
    plastic_strain : (s, 6) float
        Current e_p (Voigt, engineering shear).
    alpha : (s,) float
        Current accumulated equivalent plastic strain.
    """

    constant_tangent = False  # the shift changes between steps: never cache the stiffness

    def __init__(self, base: Material, n_samples: int, *, yield_strain: float, hardening: float = 0.0):
        if not isinstance(base, Material):
            raise InputError(f"base must be a voxflex Material (vf.material(...)), got {type(base).__name__}")
        if strain_kind(base.strain) != "tensor":
            raise InputError(f"plasticity needs a tensor strain (linear, green, corotational...), not '{base.strain.name}'")
        if n_samples is not None and (int(n_samples) != n_samples or n_samples < 1):
            raise InputError(f"n_samples must be a positive integer or None, got {n_samples!r}")
        if not (np.isfinite(yield_strain) and yield_strain > 0):
            raise InputError(f"yield_strain must be > 0 (equivalent strain), got {yield_strain!r}")
        if not (np.isfinite(hardening) and hardening >= 0):
            raise InputError(f"hardening must be >= 0 (dimensionless), got {hardening!r}")
        self.base = base
        self.yield_strain = float(yield_strain)
        self.hardening = float(hardening)
        self.name = f"plastic-{base.name}"
        self.parameters = dict(base.parameters, yield_strain=self.yield_strain, hardening=self.hardening)
        self._strain = _ShiftedStrain(base.strain)
        self._inner = Material(strain=self._strain, law=base.law, name=self.name, parameters=self.parameters)
        self.n_samples = None
        if n_samples is not None:
            self.size(int(n_samples))

    def size(self, n_samples: int) -> None:
        """Allocate the (virgin) state of ``n_samples`` samples; a sized material keeps its size."""
        if self.n_samples is not None:
            if n_samples != self.n_samples:
                raise InputError(f"this plastic material holds the state of {self.n_samples} samples; a model "
                                 f"with {n_samples} samples of it needs a material of its own")
            return
        self.n_samples = int(n_samples)
        self.plastic_strain = np.zeros((self.n_samples, 6))
        self.alpha = np.zeros(self.n_samples)
        self._committed = (self.plastic_strain.copy(), self.alpha.copy())

    @property
    def virgin(self) -> bool:
        """True while no sample has a plastic strain (the material is then its base material)."""
        return self.n_samples is None or not np.any(self.plastic_strain)

    # -- rows <-> samples ----------------------------------------------------
    def _rows(self, F, samples, *, state=False):
        F = np.asarray(F, dtype=np.float64)
        if F.ndim != 3 or F.shape[1:] != (3, 3):
            raise InputError(f"deformation gradients F must have shape (n, 3, 3), got {F.shape}")
        if self.n_samples is None:
            if state or samples is not None:
                raise InputError("this plastic material has no state yet: give n_samples, or use it in a model "
                                 "wrapped by PlasticModel (which sizes it)")
            return F, None
        if samples is None:
            if len(F) != self.n_samples and not state and self.virgin:
                return F, None  # no plastic strain anywhere: the base material, whatever the rows
            if len(F) != self.n_samples:
                raise InputError(
                    f"F has {len(F)} rows but the plastic state has {self.n_samples} samples; pass samples= "
                    "(the sample index of each row) or evaluate every sample in one call"
                )
            return F, slice(None)
        ids = np.asarray(samples, dtype=np.int64).reshape(-1)
        if len(ids) != len(F) or (ids.size and (ids.min() < 0 or ids.max() >= self.n_samples)):
            raise InputError(f"samples must give one index in [0, {self.n_samples}) per row of F")
        return F, ids

    # -- material interface ----------------------------------------------------
    def evaluate(self, F, *, tangent: bool = True, backend: str = "numba", samples=None):
        """W (n,) Pa, P (n, 3, 3) Pa, A (n, 3, 3, 3, 3) Pa or None, at the current plastic state."""
        F, ids = self._rows(F, samples)
        self._strain.offset = np.zeros((len(F), 6)) if ids is None else self.plastic_strain[ids]
        try:
            return self._inner.evaluate(F, tangent=tangent, backend=backend)
        finally:
            self._strain.offset = None

    def energy(self, F, *, samples=None) -> np.ndarray:
        """Energy density W (n,) [Pa]."""
        return self.evaluate(F, tangent=False, samples=samples)[0]

    def stress(self, F, *, samples=None) -> np.ndarray:
        """First Piola-Kirchhoff stress (n, 3, 3) [Pa]."""
        return self.evaluate(F, tangent=False, samples=samples)[1]

    def tangent(self, F, *, samples=None) -> np.ndarray:
        """Tangent dP/dF (n, 3, 3, 3, 3) [Pa] at a fixed plastic state."""
        return self.evaluate(F, tangent=True, samples=samples)[2]

    # -- state -------------------------------------------------------------------
    def update(self, F, *, samples=None) -> int:
        """Return-map the samples from the committed state with total strain ``strain(F)``.

        Sets :attr:`plastic_strain` and :attr:`alpha` of those samples; returns
        the number of samples that yield.
        """
        F, ids = self._rows(F, samples, state=True)
        ep0, a0 = self._committed[0][ids], self._committed[1][ids]
        e = self.base.strain.apply(F)
        dev, r = _deviator(e - ep0)
        f = _SQ23 * r - (self.yield_strain + self.hardening * a0)
        yielding = f > 0
        dgamma = np.where(yielding, f, 0.0) / (_SQ23 * (1.0 + self.hardening))
        n = dev / np.where(r > 0, r, 1.0)[:, None]
        n[:, 3:] *= 2.0  # back to engineering shear
        self.plastic_strain[ids] = ep0 + dgamma[:, None] * n
        self.alpha[ids] = a0 + _SQ23 * dgamma
        return int(np.count_nonzero(yielding))

    def commit(self) -> None:
        """Make the current state the start of the next load step."""
        if self.n_samples is not None:
            self._committed = (self.plastic_strain.copy(), self.alpha.copy())

    def reset(self) -> None:
        """Back to the virgin state (no plastic strain)."""
        if self.n_samples is None:
            return
        self.plastic_strain[:] = 0.0
        self.alpha[:] = 0.0
        self.commit()


class PlasticModel(ModelLayer):
    """A model whose plastic materials are updated by the solvers' post-convergence hook.

    Wraps any model of the protocol (:mod:`voxflex.deform.models.protocol`) that holds
    :class:`PlasticMaterial` instances in its ``materials``; sizes each to the
    samples of its label and forwards everything else.  After each converged
    step the solver calls :meth:`end_step`: it return-maps the plastic strains
    from the committed state at the new state and asks for the step to be
    solved again until they stop changing, then commits them.

    Parameters
    ----------
    inner : Model
        A voxel model or an affine-frame model, built with the plastic materials (labels
        without one stay elastic).  Frame quadratures of point samples: Gauss-Legendre, elastons
        (their sub-rules' points) and bare mid-point regions; stabilised mid-point regions are
        refused (their fluctuation term, :mod:`voxflex.deform.models.frames.stabilise`, is elastic).
    stationary : float
        Settling threshold, a fraction of each material's yield strain (default :data:`STATIONARY`).

    Attributes
    ----------
    plastic : dict label -> (PlasticMaterial, (s_l,) int)
        Each plastic label's material and the indices of its samples among the model's samples.
    history : deque of dict label -> (plastic strain (s_l, 6), alpha (s_l,))
        The last two committed states (at creation, then after every settled step): bounded, so a
        run of any length holds two copies of the plastic state.  Results record each step's
        measures as the step ends (:meth:`measure`).

    Raises
    ------
    InputError
        No plastic material; rigid frames, stabilised mid-point regions or a reduced volumetric term (F-bar) on a plastic
        label; a voxel label too large to be evaluated in one call (see the module docstring).
    """

    layer = "plasticity"
    layer_advice = ("plastic strains are return-mapped between solves of a step; if a step does not settle, "
                    "use more, smaller steps")

    def __init__(self, inner, *, stationary: float = STATIONARY):
        self.inner = inner
        if not (np.isfinite(stationary) and stationary > 0):
            raise InputError(f"stationary must be > 0 (a fraction of the yield strain), got {stationary!r}")
        self.stationary = float(stationary)
        plastic = {int(lab): m for lab, m in inner.materials.items() if isinstance(m, PlasticMaterial)}
        if not plastic:
            raise InputError("the model has no plastic material; build it with PlasticMaterial(...) for a label")
        if not isinstance(inner, PointSamples):
            raise InputError(f"plasticity needs a model integrated at point samples, which {inner.kind.plural} "
                             "are not; use voxel nodes or affine frames")
        reason = inner.point_sample_refusal(sorted(plastic))
        if reason:
            raise InputError(reason)
        labels = np.asarray(inner.sample_fields(inner.rest)["label"])
        self.plastic = {}
        for lab, mat in plastic.items():
            ids = np.flatnonzero(labels == lab)
            mat.size(len(ids))
            self.plastic[lab] = (mat, ids)
        self.history = deque([self._snapshot()], maxlen=2)
        self._pairs = []  # Anderson's passes of the current step (set here: the layer forwards unknown
        # attributes to the model, and the frame model has a `_pairs` table of its own)

    def _snapshot(self) -> dict:
        return {lab: (m.plastic_strain.copy(), m.alpha.copy()) for lab, (m, _) in self.plastic.items()}

    def describe(self) -> dict:
        out = dict(self.inner.describe())
        out["plastic_labels"] = " ".join(map(str, sorted(self.plastic)))  # a result attribute: one string
        return out

    def end_step(self, q) -> bool:
        """Return-map every plastic sample at the converged state q (n, d) from the committed state.

        True (solve the step again) while a plastic strain moved by more than
        ``stationary`` times its yield strain (or the wrapped model's hook asks
        for it); otherwise commits the state, appends it to :attr:`history` and returns False.
        """
        changed = end_step(self.inner, q)
        F = self.inner.deformation_gradients(q)
        x = self._vector()  # the plastic strains the step was solved with
        for mat, ids in self.plastic.values():
            mat.update(F[ids])
        g = self._vector()  # their return map at the solution
        scale = np.concatenate([np.full(m.n_samples * 6, m.yield_strain) for m, _ in self.plastic.values()])
        if np.max(np.abs(g - x) / scale, initial=0.0) > self.stationary:
            self._set(self._accelerate(x, g))
            return True
        self._pairs = []
        if changed:
            return True
        for mat, _ in self.plastic.values():
            mat.commit()
        self.history.append(self._snapshot())
        return False

    def _vector(self) -> np.ndarray:
        return np.concatenate([m.plastic_strain.ravel() for m, _ in self.plastic.values()])

    def _set(self, x) -> None:
        start = 0
        for mat, _ in self.plastic.values():
            n = mat.plastic_strain.size
            mat.plastic_strain[:] = x[start:start + n].reshape(-1, 6)
            start += n

    def _accelerate(self, x, g) -> np.ndarray:
        """The next plastic strains of the fixed-point iteration ``x -> g(x)`` (solve, then return-map),
        by Anderson mixing of the last :data:`ANDERSON_DEPTH` passes of the step.

        Plain iteration (``g`` itself) converges linearly, slowly where the plastic zone is large
        (measured on examples/plastic_bar.toml at 1 cm voxels: the change shrinks by 0.76 to 0.92 per
        pass and the last step had not settled after 100 passes; with mixing the 4 steps took 103
        passes in all); Anderson's least-squares combination of the last residuals
        ``f = g - x`` takes ``sum_j c_j g_j`` with ``sum_j c_j = 1`` minimising ``|sum_j c_j f_j|``.
        Only the iterates change: a step settles where the return map reproduces its input, so
        the committed state is an exact return map of the converged solution either way.
        """
        pairs = self._pairs
        pairs.append((x, g))
        self._pairs = pairs = pairs[-(ANDERSON_DEPTH + 1):]
        if len(pairs) < 2:
            return g
        f = [gj - xj for xj, gj in pairs]
        dF = np.stack([f[j + 1] - f[j] for j in range(len(f) - 1)], axis=1)
        dG = np.stack([pairs[j + 1][1] - pairs[j][1] for j in range(len(f) - 1)], axis=1)
        gamma = np.linalg.lstsq(dF, f[-1], rcond=1e-12)[0]
        return g - dG @ gamma

    def begin_run(self) -> None:
        """A run starts: every plastic sample back to its virgin state (a model reused for a second run started
        from the first run's last plastic strains: examples/plastic_bar.toml's intermediate states 5.9e-5 m
        apart between two runs of one model)."""
        super().begin_run()
        for mat, _ in self.plastic.values():
            mat.reset()
        self._pairs = []
        self.history = deque([self._snapshot()], maxlen=2)

    def measure(self) -> tuple[int, float]:
        """The committed state's number of yielded samples (alpha > 0) and largest equivalent plastic
        strain ``sqrt(2/3) |e_p|`` (dimensionless)."""
        state = self.history[-1]
        count = sum(int(np.count_nonzero(a > 0)) for _, a in state.values())
        peak = max(float(np.max(von_mises_strain(ep), initial=0.0)) for ep, _ in state.values())
        return count, peak


def with_plasticity(model):
    """``model`` wrapped in :class:`PlasticModel` when it has a plastic material, else ``model`` itself."""
    materials = model.materials
    if any(isinstance(m, PlasticMaterial) for m in materials.values()):
        return PlasticModel(model)
    return model
