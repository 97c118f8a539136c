"""Adapters resolve from the built-in backend table, entry points add third-party ones."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from hilident.adapters import backends
from hilident.adapters.backends import BACKENDS, adapter_class, known_transports
from hilident.errors import ConfigError


@pytest.fixture
def no_entry_points(monkeypatch):
    """A source tree that was never installed: the entry point group is empty."""
    monkeypatch.setattr(backends, "entry_points", lambda group: [])


@pytest.mark.parametrize("transport", sorted(BACKENDS))
def test_builtin_adapters_resolve_without_entry_points(no_entry_points, transport):
    cls = adapter_class(transport)
    module_name, _, class_name = BACKENDS[transport].partition(":")
    assert cls.__module__ == module_name and cls.__name__ == class_name


def test_third_party_adapter_resolves_by_entry_point(monkeypatch):
    class ThirdParty:
        pass

    ep = SimpleNamespace(name="ethercat", load=lambda: ThirdParty)
    monkeypatch.setattr(backends, "entry_points", lambda group: [ep] if group == backends.ENTRY_POINT_GROUP else [])
    assert adapter_class("ethercat") is ThirdParty
    assert known_transports() == ["canopen", "ethercat", "modbus", "serial"]


def test_builtin_name_wins_over_an_entry_point(monkeypatch):
    ep = SimpleNamespace(name="serial", load=lambda: object)
    monkeypatch.setattr(backends, "entry_points", lambda group: [ep])
    assert adapter_class("serial").__name__ == "SerialBoardAdapter"


def test_unknown_transport_is_a_config_error_naming_the_known_ones(no_entry_points):
    with pytest.raises(ConfigError) as info:
        adapter_class("profibus")
    assert info.value.key == "driver.transport"
    assert "'profibus'" in str(info.value) and "canopen" in str(info.value)


def test_adapter_class_is_found_in_backends_only():
    from hilident.adapters import base

    assert not hasattr(base, "adapter_class")  # no re-export: its users import it from hilident.adapters.backends
    assert adapter_class.__module__ == "hilident.adapters.backends"
