"""Result fields: stress, strain, stretches and energy density from the deformation gradients of a model.

Fields are computed from what every model offers through
:meth:`~voxflex.deform.models.protocol.Model.sample_fields`: the deformation gradients
``F`` at its quadrature samples, their volumes and labels, the *cell* each
sample belongs to (voxel model: its voxel, every voxel averaging its 2x2x2
Gauss points; frame model: the sample itself) and a layer on the boundary
surface (voxel model: the voxel behind each triangle; frame model: ``F``
evaluated through the frames' point mapping at the centre of the voxel
behind each triangle).

Per sample, with ``P = dW/dF`` the material's first Piola-Kirchhoff stress
and ``J = det F``:

==================  ==============  ======  ===================================================
name                shape per cell  units   meaning
==================  ==============  ======  ===================================================
``stress``          (3, 3)          Pa      Cauchy stress ``sigma = P F^T / J``
``von-mises``       ()              Pa      ``sqrt(3/2 s:s)``, ``s`` the deviator of ``sigma``
``strain``          (3, 3)          1       Green-Lagrange strain ``E = (F^T F - I) / 2`` (tensor, not Voigt)
``stretches``       (3,)            1       principal stretches ``sqrt(eig(F^T F))``, largest first
``energy-density``  ()              Pa      strain energy per unit rest volume ``W(F)`` (J/m^3)
``volume-ratio``    ()              1       ``J = det F`` (deformed / rest volume)
``reaction``        (regions, 3)    N       total force each ``[[fixed]]`` region exerts on the body
==================  ==============  ======  ===================================================

A cell's ``stress``, ``strain``, ``energy-density`` and ``volume-ratio`` are
the volume averages over its samples; its ``von-mises`` and ``stretches`` are
those of the averaged stress and strain (so the three always agree).  A
uniform ``F`` gives the same values in every cell to round-off.

Elastons (frame models) carry ``F`` and its gradient; the fields are taken at
the sample's point (the region's centre).

Example
-------
>>> import numpy as np
>>> from voxflex.deform.materials.constitutive import material
>>> F = np.diag([1.01, 1.0, 1.0])[None]
>>> out = point_fields(F, np.array([1]), {1: material("stvk", young=1e4, poisson=0.0)}, ("von-mises",))
>>> round(float(out["von-mises"][0]), 6)     # uniaxial: sigma_xx = E (l^2 - 1) / 2 * l^2 / l
101.505
"""

from __future__ import annotations

import numpy as np

from ...errors import InputError, check_choice

__all__ = [
    "FIELD_NAMES",
    "CELL_FIELDS",
    "SCALAR_FIELDS",
    "check_field_names",
    "cauchy_stress",
    "von_mises",
    "green_strain",
    "principal_stretches",
    "point_fields",
    "cell_average",
    "model_fields",
]

FIELD_NAMES = ("stress", "von-mises", "strain", "stretches", "energy-density", "volume-ratio", "reaction")
"""Every field ``[output] fields`` may ask for (the one vocabulary; see the module table)."""

CELL_FIELDS = FIELD_NAMES[:-1]
"""The fields with one value per cell (every name but ``reaction``, which is one force per fixed region)."""

SCALAR_FIELDS = ("von-mises", "energy-density", "volume-ratio")
"""Fields with one number per cell: what a render can colour by."""

_TRAILING = {"stress": (3, 3), "von-mises": (), "strain": (3, 3), "stretches": (3,), "energy-density": (),
             "volume-ratio": ()}


_ALWAYS = ("displacement", "displacements", "position", "positions")


def check_field_names(names, *, where: str = "fields") -> tuple[str, ...]:
    """Validate a list of field names; returns them as a tuple without repeats, in the given order.

    Raises
    ------
    InputError
        A name that is not a string or not in :data:`FIELD_NAMES` (the message lists the valid ones).
    """
    if isinstance(names, str) or not isinstance(names, (list, tuple)):
        raise InputError(f"{where} must be a list of field names such as [\"von-mises\"], got {names!r}")
    out = []
    for name in names:
        if isinstance(name, str) and name.strip().lower() in _ALWAYS:
            raise InputError(f"{where}: '{name}' is always recorded (every result stores the positions of the "
                             "nodes, surface and probes, and their displacements); remove it from the list, which "
                             f"names the extra per-sample fields: {', '.join(FIELD_NAMES)}")
        check_choice(where, name, FIELD_NAMES)
        if name not in out:
            out.append(name)
    return tuple(out)


# -- per-sample quantities ----------------------------------------------------------
def cauchy_stress(F, P) -> np.ndarray:
    """Cauchy stress ``P F^T / det F`` (n, 3, 3) [Pa] of deformation gradients F and first Piola stresses P (n, 3, 3).

    Inverted samples (det F < 0) give the formula's value; det F = 0 gives inf/NaN.
    """
    J = np.linalg.det(F)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.matmul(P, np.swapaxes(F, 1, 2)) / J[:, None, None]


def von_mises(sigma) -> np.ndarray:
    """Von Mises equivalent stress (n,) [Pa] of stresses sigma (n, 3, 3): ``sqrt(3/2 s:s)``, s the deviator."""
    sym = 0.5 * (sigma + np.swapaxes(sigma, 1, 2))
    tr = np.trace(sym, axis1=1, axis2=2)
    dev = sym - (tr / 3.0)[:, None, None] * np.eye(3)
    return np.sqrt(1.5 * np.einsum("nij,nij->n", dev, dev))


def green_strain(F) -> np.ndarray:
    """Green-Lagrange strain ``(F^T F - I) / 2`` (n, 3, 3), dimensionless."""
    return 0.5 * (np.matmul(np.swapaxes(F, 1, 2), F) - np.eye(3))


def _stretches_from_green(E) -> np.ndarray:
    lam2 = 1.0 + 2.0 * np.linalg.eigvalsh(0.5 * (E + np.swapaxes(E, 1, 2)))  # ascending
    return np.sqrt(np.maximum(lam2, 0.0))[:, ::-1]


def principal_stretches(F) -> np.ndarray:
    """Principal stretches (n, 3), largest first: the square roots of the eigenvalues of ``F^T F``."""
    return _stretches_from_green(green_strain(F))


def point_fields(F, label, materials, names) -> dict:
    """Fields at individual points: {name: (n, ...)} for the cell fields in ``names``.

    Parameters
    ----------
    F : (n, 3, 3) float
        Deformation gradients.
    label : (n,) int
        Material label of each point.
    materials : mapping label -> Material
    names : sequence of str
        Names from :data:`CELL_FIELDS` (``reaction`` is ignored here).
    """
    raw = _raw(F, label, materials, names)
    return _derive(raw, names)


def _raw(F, label, materials, names):
    """The averageable quantities at the points: sigma, E, W, J (only those ``names`` need)."""
    names = set(names)
    n = len(F)
    raw = {}
    need_stress = bool(names & {"stress", "von-mises"})
    need_w = "energy-density" in names
    if need_stress or need_w:
        sigma = np.zeros((n, 3, 3)) if need_stress else None
        W = np.zeros(n) if need_w else None
        for lab in np.unique(label):
            ids = np.flatnonzero(label == lab)
            w, P, _ = materials[int(lab)].evaluate(F[ids], tangent=False)
            if need_stress:
                sigma[ids] = cauchy_stress(F[ids], P)
            if need_w:
                W[ids] = w
        if need_stress:
            raw["sigma"] = sigma
        if need_w:
            raw["W"] = W
    if names & {"strain", "stretches"}:
        raw["E"] = green_strain(F)
    if "volume-ratio" in names:
        raw["J"] = np.linalg.det(F)
    return raw


def _derive(raw, names) -> dict:
    out = {}
    for name in names:
        if name == "stress":
            out[name] = raw["sigma"]
        elif name == "von-mises":
            out[name] = von_mises(raw["sigma"])
        elif name == "strain":
            out[name] = raw["E"]
        elif name == "stretches":
            out[name] = _stretches_from_green(raw["E"])
        elif name == "energy-density":
            out[name] = raw["W"]
        elif name == "volume-ratio":
            out[name] = raw["J"]
    return out


def cell_average(values, weight, cell, n_cells: int) -> np.ndarray:
    """Weighted averages per cell: values (s, ...), weight (s,) >= 0, cell (s,) in 0..n_cells-1 -> (n_cells, ...).

    A cell whose weights sum to 0 takes the plain mean of its samples.
    """
    values = np.asarray(values, dtype=float)
    flat = values.reshape(len(values), -1)
    wsum = np.bincount(cell, weights=weight, minlength=n_cells)
    count = np.bincount(cell, minlength=n_cells).astype(float)
    plain = wsum[cell] <= 0
    w = np.where(plain, 1.0, weight)
    den = np.where(wsum > 0, wsum, np.maximum(count, 1.0))
    out = np.empty((n_cells, flat.shape[1]))
    for j in range(flat.shape[1]):
        out[:, j] = np.bincount(cell, weights=w * flat[:, j], minlength=n_cells) / den
    return out.reshape((n_cells,) + values.shape[1:])


def model_fields(model, q, names, *, sample=None):
    """Cell and surface fields of ``model`` at state ``q`` (n, d).

    Parameters
    ----------
    model : Model
        Anything offering :meth:`~voxflex.deform.models.protocol.Model.sample_fields`.
    q : (n, d) float
    names : sequence of str
        Names from :data:`FIELD_NAMES` (``reaction`` is skipped: it needs the loads).
    sample : dict, optional
        ``model.sample_fields(q)`` when the caller has it already (not recomputed).

    Returns
    -------
    cells : dict name -> (C, ...)
        One value per cell (voxel or sample).
    surface : dict name -> (F, ...)
        One value per triangle of ``model.boundary_surface()``.
    """
    names = [n for n in names if n in CELL_FIELDS]
    s = model.sample_fields(q) if sample is None else sample
    raw = _raw(s["F"], s["label"], s["materials"], names)
    avg = {k: cell_average(v, s["volume"], s["cell"], s["n_cells"]) for k, v in raw.items()}
    cells = _derive(avg, names)
    if s.get("triangle_cell") is not None:
        surface = {k: v[s["triangle_cell"]] for k, v in cells.items()}
    else:
        sF = s["surface_F"]
        at = point_fields(sF() if callable(sF) else sF, s["surface_label"], s["materials"], names)
        surface = {k: v[s["triangle_point"]] for k, v in at.items()}
    return cells, surface


def trailing_shape(name: str) -> tuple:
    """The per-cell shape of a cell field (e.g. (3, 3) for ``stress``)."""
    if name not in _TRAILING:
        raise InputError(f"'{name}' is not a cell field; valid: {', '.join(CELL_FIELDS)}")
    return _TRAILING[name]
