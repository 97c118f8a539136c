"""Fixed synthetic inputs and a flattener shared by the pinned-result tests.

The outputs of the identification and data-file functions on these inputs
were recorded once, before those functions were split into smaller ones,
and are compared to 1e-12 relative: a restructuring must not change a
parameter or a choice.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np


def flatten(value, prefix: str = "") -> dict:
    """``{path: scalar}`` of every number, string, bool and None inside `value`.

    Complex numbers are split into ``.re`` and ``.im``; arrays, lists and
    tuples are indexed, dataclasses and dicts keyed by field name.
    """
    out: dict = {}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            out.update(flatten(getattr(value, f.name), f"{prefix}.{f.name}"))
    elif isinstance(value, dict):
        for key in value:
            out.update(flatten(value[key], f"{prefix}.{key}"))
    elif isinstance(value, np.ndarray) or isinstance(value, (list, tuple)):
        items = value.tolist() if isinstance(value, np.ndarray) else value
        out[f"{prefix}.len"] = len(items)
        for i, item in enumerate(items):
            out.update(flatten(item, f"{prefix}[{i}]"))
    elif isinstance(value, (complex, np.complexfloating)):
        out[f"{prefix}.re"] = float(value.real)
        out[f"{prefix}.im"] = float(value.imag)
    elif isinstance(value, (bool, np.bool_)):
        out[prefix] = bool(value)
    elif isinstance(value, (int, np.integer)):
        out[prefix] = int(value)
    elif isinstance(value, (float, np.floating)):
        out[prefix] = float(value)
    elif value is None or isinstance(value, str):
        out[prefix] = value
    else:
        raise TypeError(f"{prefix}: cannot flatten {type(value).__name__}")
    return out


def assert_same(actual: dict, expected: dict, rtol: float = 1e-12) -> None:
    """Every key present in both, strings and flags equal, numbers within `rtol` (NaN equal to NaN)."""
    assert sorted(actual) == sorted(expected)
    wrong = []
    for key, want in expected.items():
        got = actual[key]
        if isinstance(want, float) and isinstance(got, (int, float)) and not isinstance(got, bool):
            if math.isnan(want):
                ok = math.isnan(got)
            elif math.isinf(want):
                ok = got == want
            else:
                ok = abs(got - want) <= rtol * abs(want)
        else:
            ok = type(got) is type(want) and got == want
        if not ok:
            wrong.append(f"{key}: {got!r} != {want!r}")
    assert not wrong, "\n".join(wrong[:20])


def load_expected(path: Path) -> dict:
    return json.loads(path.read_text())


def store_expected(path: Path, cases: dict) -> None:
    path.write_text(json.dumps(cases, indent=0, sort_keys=True) + "\n")
