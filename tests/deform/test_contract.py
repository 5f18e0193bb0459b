"""Run every registered mapping and material through the derivative contract.

Cases come from ``tests/support/contract_*.py`` modules (one per library module),
each defining ``CASES``; see :mod:`contract` for the checks and tolerances.
"""

from __future__ import annotations

import importlib

import paths
import pytest
from contract import MappingCase, MaterialCase, check_mapping, check_material  # noqa: E402


def _collect():
    cases = []
    for path in sorted((paths.ROOT / "tests" / "support").glob("contract_*.py")):
        module = importlib.import_module(path.stem)
        cases.extend(module.CASES)
    return cases


_CASES = _collect()


@pytest.mark.parametrize("case", _CASES, ids=[c.name for c in _CASES])
def test_contract(case):
    if isinstance(case, MappingCase):
        check_mapping(case)
    elif isinstance(case, MaterialCase):
        check_material(case)
    else:  # pragma: no cover
        raise TypeError(type(case))
