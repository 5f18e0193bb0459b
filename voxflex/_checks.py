"""Validators of scene tables and options: every message names the table and the key, and says what is valid.

Used by the scene's tables and by the runtime options that are scene tables
themselves (:class:`voxflex.deform.solve.options.SolverOptions`), so each key
is checked in one place with one message.  Light: no numpy.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import fields

from .errors import InputError, did_you_mean

__all__ = ["number", "vector", "string", "boolean", "check_keys", "valid_keys", "where"]


# ---------------------------------------------------------------------------
def where(table: str, key: str) -> str:
    return f"[{table}] {key}"


def number(table, key, value, *, positive=False, nonnegative=False, integer=False, minimum=None):
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        kind = "an integer" if integer else "a number"
        raise InputError(f"{where(table, key)} must be {kind}, got {value!r}")
    if integer:
        if not isinstance(value, numbers.Integral):
            if not float(value).is_integer():
                raise InputError(f"{where(table, key)} must be an integer, got {value!r}")
        value = int(value)
    else:
        value = float(value)
        if math.isnan(value):
            raise InputError(f"{where(table, key)} must be a number, got nan")
    if positive and not value > 0:
        raise InputError(f"{where(table, key)} must be > 0, got {value!r}")
    if nonnegative and not value >= 0:
        raise InputError(f"{where(table, key)} must be >= 0, got {value!r}")
    if minimum is not None and value < minimum:
        raise InputError(f"{where(table, key)} must be >= {minimum}, got {value!r}")
    if not integer and not positive and not nonnegative:
        return value
    if not integer and math.isinf(value):
        raise InputError(f"{where(table, key)} must be finite, got {value!r}")
    return value


def vector(table, key, value, length=3, *, finite=True, positive=False) -> tuple[float, ...]:
    if isinstance(value, (str, bytes)) or not hasattr(value, "__len__") or len(value) != length:
        raise InputError(f"{where(table, key)} must be a list of {length} numbers, got {value!r}")
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, numbers.Real) or math.isnan(v):
            raise InputError(f"{where(table, key)} must be a list of {length} numbers, got {value!r}")
        if finite and math.isinf(v):
            raise InputError(f"{where(table, key)} must be finite, got {value!r}")
        if positive and not v > 0:
            raise InputError(f"{where(table, key)} must be > 0 everywhere, got {value!r}")
        out.append(float(v))
    return tuple(out)


def string(table, key, value, choices=None) -> str:
    if not isinstance(value, str):
        raise InputError(f"{where(table, key)} must be a string, got {value!r}")
    if "\x00" in value:  # no file name or HDF5 string holds one
        raise InputError(f"{where(table, key)} holds a NUL character (\\u0000), got {value!r}; remove it")
    try:
        value.encode("utf-8")
    except UnicodeEncodeError:  # a lone surrogate (from a Python str; TOML cannot spell one)
        raise InputError(f"{where(table, key)} is not valid Unicode text (a lone surrogate), got {value!r}; "
                         "remove the character") from None
    if choices is not None and value not in choices:
        raise InputError(
            f"{where(table, key)}: unknown value '{value}'{did_you_mean(value, choices)}; "
            f"valid: {', '.join(choices)}"
        )
    return value


def boolean(table, key, value) -> bool:
    if not isinstance(value, bool):
        raise InputError(f"{where(table, key)} must be true or false, got {value!r}")
    return value


def check_keys(table: str, data: dict, valid) -> None:
    for key in data:
        if key not in valid:
            raise InputError(
                f"unknown key '{key}' in [{table}]{did_you_mean(key, valid)}; valid keys: {', '.join(valid)}"
            )


def valid_keys(cls) -> tuple[str, ...]:
    return tuple(f.name for f in fields(cls) if not f.name.startswith("_"))


