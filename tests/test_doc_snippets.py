"""The code and TOML snippets of docs/ are what the code does: each runs, parses or equals its source."""

from __future__ import annotations

import tomllib

import pytest

from hilident.config.tables import parse_config
from hilident.drivers.description import load_driver
from hilident.errors import ConfigError
from support.doc_blocks import ROOT, fenced_blocks
from support.vendor_drives import RECORDERS, VendorDrive, eds_text

DOCS = ROOT / "docs"


def blocks(name: str, lang: str) -> list[str]:
    found = [b.text for b in fenced_blocks(DOCS / name) if b.lang == lang]
    assert found, f"docs/{name} has no {lang} block"
    return found


def test_the_acquisition_table_in_adapters_md_is_the_codes():
    from hilident.adapters.canopen import drive as canopen_drive

    (snippet,) = blocks("adapters.md", "python")
    namespace = dict(vars(canopen_drive))
    exec(compile(snippet, "docs/adapters.md", "exec"), namespace)
    assert namespace["ACQUISITIONS"] == canopen_drive.ACQUISITIONS


def test_the_schema_example_builds_a_table_and_refuses_a_bad_key(monkeypatch):
    import sys
    import types

    (snippet,) = blocks("schema.md", "python")
    module = types.ModuleType("schema_md")  # dataclasses look their module up in sys.modules
    monkeypatch.setitem(sys.modules, "schema_md", module)
    namespace = vars(module)
    namespace["raw_table"] = {"base": 100, "page_samples": 64}
    exec(compile(snippet, "docs/schema.md", "exec"), namespace)
    window = namespace["window"]
    assert (window.base, window.page_samples, window.capacity_samples) == (100, 64, 65536)
    namespace["raw_table"] = {"base": 100, "page_samples": 0}
    with pytest.raises(ConfigError) as info:
        exec(compile(snippet, "docs/schema.md", "exec"), namespace)
    assert info.value.key == "modbus.table.page_samples" and info.value.file == "drivers/x/driver.toml"


def test_the_schema_table_names_files_that_exist():
    text = (DOCS / "schema.md").read_text()
    table = text.split("## Where each file's tables are declared", 1)[1].split("\n\n", 2)[1]
    modules = [line.rsplit("|", 2)[1].strip(" `") for line in table.splitlines()[2:]]
    assert len(modules) >= 5
    assert [m for m in modules if not (ROOT / "src" / m).is_file()] == []


def test_the_canopen_driver_toml_loads_with_an_eds(tmp_path):
    """The driver.toml of docs/canopen_drives.md, beside an EDS of a drive it fits, is a driver hilident loads."""
    driver_toml = next(t for t in blocks("canopen_drives.md", "toml") if t.startswith("[driver]"))
    folder = tmp_path / "acme-xy100"
    folder.mkdir()
    (folder / "driver.toml").write_text(driver_toml)
    eds = tomllib.loads(driver_toml)["canopen"]["eds"]
    (folder / eds).write_bytes(eds_text(VendorDrive("acme-xy100", declare_modes=False)).encode("latin-1"))
    driver = load_driver(folder)
    assert driver.name == "acme-xy100" and driver.transport == "canopen"
    assert driver.loop_rate_hz == 4000.0 and driver.filter_slots == 0


def test_the_canopen_recorder_tables_are_the_test_drives():
    """The doc says its [canopen.recorder] and [canopen.generator] are those of the test drive acme-recorder."""
    from hilident.protocol.canopen_recorder import parse_recorder

    documented = next(t for t in blocks("canopen_drives.md", "toml") if t.startswith("[canopen.recorder]"))
    tested = RECORDERS["prbs"][1].replace("{max_samples}", "8192")
    doc, test = parse_recorder(tomllib.loads(documented)), parse_recorder(tomllib.loads(tested))
    assert doc is not None and doc.generator is not None
    assert (doc.recorder, doc.generator) == (test.recorder, test.generator)


def test_the_canopen_recorder_run_config_parses():
    snippet = next(t for t in blocks("canopen_drives.md", "toml") if t.startswith("[device]"))
    raw = tomllib.loads((ROOT / "configs" / "emulated-canopen-gantry.toml").read_text())
    for table, values in tomllib.loads(snippet).items():
        raw[table] = {**raw.get(table, {}), **values} if table == "device" else values
    import tomli_w

    cfg = parse_config(tomli_w.dumps(raw), "docs/canopen_drives.md")
    assert cfg.device.acquisition == "recorder" and cfg.excitation.kind == "prbs"
    assert cfg.excitation.register_length == 10
