"""The schema's ``float | Table`` fields: a key that takes a number or an inline table."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from hilident.config.schema import build_table, spec
from hilident.errors import ConfigError


@dataclass(frozen=True)
class Curve:
    poly: list[float] = spec([])


seen: list = []


def _refuse_long(value, key, source):
    seen.append(value)
    if isinstance(value, Curve) and len(value.poly) > 2:
        raise ConfigError(key, "at most two coefficients", source)


@dataclass(frozen=True)
class Axis:
    k: float | Curve = spec(1.0, gt=0, check=_refuse_long)


def build(table):
    return build_table(Axis, table, "axis.", "axis.toml")


def test_a_number_or_a_table_is_read_and_the_check_sees_either():
    seen.clear()
    assert build({}).k == 1.0 and seen == []
    assert build({"k": 3}).k == 3.0 and isinstance(build({"k": 3}).k, float)
    assert build({"k": {"poly": [1, 2]}}).k == Curve(poly=[1.0, 2.0])
    assert seen[-1] == Curve(poly=[1.0, 2.0]) and 3.0 in seen


@pytest.mark.parametrize(
    "value, key, says",
    [
        (-1.0, "axis.k", "must be > 0"),  # the field's bounds apply to the number
        ("3", "axis.k", "must be a number or a table"),
        (True, "axis.k", "must be a number or a table"),
        ([1.0], "axis.k", "must be a number or a table"),
        (float("inf"), "axis.k", "finite"),
        ({"poly": [1.0, 2.0, 3.0]}, "axis.k", "at most two coefficients"),  # the check refuses the table
        ({"poly": ["x"]}, "axis.k.poly[0]", "must be float"),
        ({"slope": 1.0}, "axis.k.slope", "unknown key"),
    ],
)
def test_bad_values_name_the_key_and_the_file(value, key, says):
    with pytest.raises(ConfigError) as err:
        build({"k": value})
    assert err.value.key == key and err.value.file == "axis.toml" and says in err.value.message, str(err.value)
