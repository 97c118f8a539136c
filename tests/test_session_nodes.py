"""`hilident run` on a config naming several CANopen nodes (`[device.canopen] node_ids`) takes the run of several
nodes (:mod:`hilident.session.nodes_run`): what it cannot do for several nodes is refused naming the key and the
file, before any twin or bus starts."""

from __future__ import annotations

from pathlib import Path

from hilident.cli.main import main

CONFIGS = Path(__file__).resolve().parents[1] / "configs"

MECHANISM = """
[emulator.mechanism]
masses_kg = [20.0, 20.0, 10.0]
links = [[0, 2, 2.0e5, 40.0], [1, 2, 2.0e5, 40.0]]
motors = [[0, 10.0], [1, 10.0]]
sensors = [2, 2]
"""


def test_an_automatic_amplitude_on_several_nodes_is_refused_naming_the_key_and_starts_nothing(tmp_path, capsys):
    text = (
        (CONFIGS / "emulated-canopen-gantry.toml").read_text().replace("node_id = 1", "node_id = 1\nnode_ids = [1, 2]")
    )
    config = tmp_path / "two.toml"
    config.write_text(text + MECHANISM)
    out = tmp_path / "out"
    code = main(["run", str(config), "--out", str(out), "--yes"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "excitation.amplitude_nm" in err and "two.toml" in err and "several nodes" in err
    assert not list(out.glob("*.h5"))  # nothing recorded: nothing moved
