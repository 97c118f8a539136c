"""Driver descriptions: found from a checkout or an installed wheel, and from user folders."""

from __future__ import annotations

import shutil

import pytest

from hilident.drivers import available_drivers, find_driver, search_path
from hilident.errors import ConfigError


def test_builtin_board_is_found_wherever_hilident_is_installed():
    d = find_driver("myrio-board")
    assert d.transport == "serial" and d.filter_slots >= 1
    assert (d.folder / "PROTOCOL.md").is_file() or (d.folder / "driver.toml").is_file()
    assert "velocity_mps" in [c.name for c in d.channels]
    assert d.text.startswith("#")  # the file verbatim, for the recordings


def _user_copy(tmp_path, name="my-board", edit=None):
    folder = tmp_path / "mydrivers" / name
    shutil.copytree(find_driver("myrio-board").folder, folder)
    text = (folder / "driver.toml").read_text().replace('name = "myrio-board"', f'name = "{name}"')
    if edit:
        text = edit(text)
    (folder / "driver.toml").write_text(text)
    return folder


def test_user_folders_by_path_by_search_path_and_by_environment(tmp_path, monkeypatch):
    folder = _user_copy(tmp_path, edit=lambda t: t.replace("filter_slots = 4", "filter_slots = 2"))
    assert find_driver(str(folder)).filter_slots == 2
    assert find_driver("my-board", [folder.parent]).filter_slots == 2
    with pytest.raises(ConfigError, match="my-board"):
        find_driver("my-board")
    monkeypatch.setenv("HILIDENT_DRIVER_PATH", str(folder.parent))
    assert find_driver("my-board").name == "my-board"
    assert "my-board" in available_drivers() and folder.parent in search_path()


def test_unknown_driver_lists_what_exists():
    with pytest.raises(ConfigError) as err:
        find_driver("no-such-board")
    assert "device.driver" in str(err.value) and "myrio-board" in str(err.value)


def test_invalid_description_names_key_and_file(tmp_path):
    folder = _user_copy(tmp_path, edit=lambda t: t.replace('format = "i32"', 'format = "i24"'))
    with pytest.raises(ConfigError) as err:
        find_driver(str(folder))
    assert "format" in str(err.value) and "driver.toml" in str(err.value)
