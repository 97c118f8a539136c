"""summary.json's JSON Schema (shipped in the package) against real summaries of run, identify and upload."""

from __future__ import annotations

import copy

import pytest

jsonschema = pytest.importorskip("jsonschema")

from hilident.io.summary import LAYOUTS  # noqa: E402
from hilident.schemas import summary_schema  # noqa: E402
from support.exported_summaries import load, summaries  # noqa: E402


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    return {kind: load(folder) for kind, folder in summaries(tmp_path_factory.mktemp("summaries")).items()}


@pytest.fixture(scope="module")
def validator():
    schema = summary_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    return jsonschema.Draft202012Validator(schema)


def errors(validator, summary) -> list[str]:
    return [f"{'/'.join(map(str, e.absolute_path))}: {e.message[:200]}" for e in validator.iter_errors(summary)]


@pytest.mark.parametrize("kind", ["run", "identify", "upload"])
def test_real_summaries_validate_as_their_own_kind(made, validator, kind):
    summary = made[kind]
    assert errors(validator, summary) == []
    (branch,) = [
        b
        for b in validator.schema["oneOf"]
        if jsonschema.Draft202012Validator({**b, "$defs": validator.schema["$defs"]}).is_valid(summary)
    ]
    assert branch["title"] == kind
    # the run had a friction test, a grey-box model, an upload and a verification: every section was checked
    if kind == "run":
        assert summary["friction"] and summary["model"] and summary["upload"]["slots"]
        assert summary["verification"]["resonances"]


def test_every_key_of_every_layout_is_described(validator):
    props = validator.schema["properties"]
    for kind, keys in LAYOUTS.items():
        for key in keys:
            assert key in props and props[key].get("description"), (kind, key)


def described(schema: dict, where: str = "#") -> list[str]:
    """Paths of properties with no description (their own, or the definition they refer to)."""
    missing = []
    for name, prop in (schema.get("properties") or {}).items():
        if not prop.get("description"):
            missing.append(f"{where}/{name}")
        missing += described(prop, f"{where}/{name}")
        if isinstance(prop.get("items"), dict):
            missing += described(prop["items"], f"{where}/{name}[]")
    return missing


def test_every_property_has_a_description_with_its_unit(validator):
    schema = validator.schema
    assert described(schema) == []
    for name, part in schema["$defs"].items():
        assert part.get("description"), name
        assert described(part, f"$defs/{name}") == []
    notch = schema["$defs"]["notch"]["properties"]
    assert "Hz" in notch["center_hz"]["description"] and "dB" in notch["depth_db"]["description"]
    friction = schema["$defs"]["friction"]["properties"]["params"]["properties"]
    assert "N*m/(m/s)" in friction["Fv"]["description"] and "m/s" in friction["vs"]["description"]
    assert "rad/s" in schema["$defs"]["plant_model"]["properties"]["num"]["description"]


def test_wrong_types_and_missing_sections_are_caught(made, validator):
    bad = copy.deepcopy(made["run"])
    bad["resonances"][0]["frequency_hz"] = "21.8 Hz"
    assert any(e.startswith("resonances/0/frequency_hz") for e in errors(validator, bad))
    bad = copy.deepcopy(made["run"])
    bad["notch_filters"][0]["b"] = [1.0, 0.0]
    assert any(e.startswith("notch_filters/0/b") for e in errors(validator, bad))
    bad = copy.deepcopy(made["upload"])
    del bad["source"]
    assert errors(validator, bad)  # an upload names its source
    bad = copy.deepcopy(made["identify"])
    bad["upload"] = {"written": "yes", "verified_readback": False, "slots": []}
    assert any(e.startswith("upload/written") for e in errors(validator, bad))
