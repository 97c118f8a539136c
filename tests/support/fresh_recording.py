"""Short real recordings: the session's recorder streaming into a shipped config's embedded twin."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hilident.config.tables import Config, load_config
from hilident.drivers.description import find_driver
from hilident.progress import Progress
from hilident.session.connection import ConnectedDevice, connect_device
from hilident.session.experiment import ExperimentRecorder

CONFIGS = Path(__file__).resolve().parents[2] / "configs"

#: The shipped config of each transport's embedded twin.
TRANSPORT_CONFIGS = {
    "serial": "emulated-gantry.toml",
    "modbus": "emulated-modbus-gantry.toml",
    "canopen": "emulated-canopen-gantry.toml",
}


@contextmanager
def twin_device(config: str) -> Iterator[tuple[Config, ConnectedDevice]]:
    """The shipped ``config`` and its embedded twin, connected and with the config's limits loaded."""
    cfg = load_config(CONFIGS / config)
    driver = find_driver(cfg.device.driver, cfg.device.driver_paths)
    device = connect_device(cfg, driver, Progress(enabled=False))
    try:
        lim = cfg.limits
        assert lim is not None
        device.adapter.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
        yield cfg, device
    finally:
        device.close()


def record(out: Path, config: str, modes: Sequence[str], seconds: float = 0.3) -> dict[str, Path]:
    """One recording per mode of ``seconds`` of zero excitation on the twin of ``config``; mode -> its file."""
    paths = {}
    with twin_device(config) as (cfg, device):
        recorder = ExperimentRecorder(device, out, Progress(enabled=False), [])
        for mode in modes:
            samples = np.zeros(int(round(seconds * cfg.run.sample_rate_hz)))
            paths[mode] = recorder.record(cfg, f"{mode}_run", mode, samples).path
    return paths
