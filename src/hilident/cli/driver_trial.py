"""``hilident drivers check``, second half: the folder's filter slot tried on a throw-away twin of the folder.

The trial itself (:func:`~hilident.drivers.filter_trial.trial_filter_slot`) is
in ``drivers``, which imports neither the adapters nor the emulator; a twin and
the adapter that talks to it are opened the way ``hilident run`` opens a
device on ``port = "emulator"`` (:func:`~hilident.session.connection.connect_device`),
which only the command line above the session may do. The twin answers SDOs
at once (nothing runs in real time): the trial adds about half a second.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from hilident.config.tables import parse_config
from hilident.drivers.description import DESCRIPTION_FILE, load_driver
from hilident.drivers.filter_trial import trial_filter_slot
from hilident.errors import HilidentError
from hilident.progress import Progress
from hilident.protocol.canopen_filters import parse_filter_objects
from hilident.session.connection import connect_device

__all__ = ["FilterTrial", "try_filter_slots"]

#: A configuration with nothing but the limits every config needs; the device is the twin.
_MINIMAL = "[limits]\ntorque_nm = 1.0\nvelocity_mps = 1.0\nposition_min_m = -1.0\nposition_max_m = 1.0\n"


@dataclass(frozen=True)
class FilterTrial:
    """What the trial of a folder's filter slot found.

    Attributes
    ----------
    tried : bool
        A twin was opened and slot 0 tried.
    errors : tuple of str
        Each failure, naming the ``[filters]`` key and the object.
    warnings : tuple of str
        Why the slot was not tried, when the folder has filter objects but no slot to try.
    """

    tried: bool = False
    errors: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()


def try_filter_slots(folder) -> FilterTrial:
    """Try slot 0 of a CANopen driver folder's ``[filters]`` objects on a throw-away twin of the folder.

    Nothing is tried for a folder without filter objects. Call it on a folder
    that ``check_driver_folder`` passed: a folder the driver loader refuses is
    reported as one error.

    Parameters
    ----------
    folder : str or Path
        The driver folder.

    Returns
    -------
    FilterTrial
    """
    folder = Path(folder)
    source = str(folder / DESCRIPTION_FILE)
    try:
        driver = load_driver(folder)
        table = driver.sections.get("filters")
        if driver.transport != "canopen" or not isinstance(table, dict) or parse_filter_objects(table, source) is None:
            return FilterTrial()
    except HilidentError as exc:
        return FilterTrial(errors=(str(exc),))
    if driver.filter_slots < 1:
        return FilterTrial(
            warnings=(f"{source}: [board.filter_slots] is 0: the [filters] objects are not used, nor tried",)
        )
    cfg = parse_config(_MINIMAL, "<drivers check>")
    cfg = replace(cfg, device=replace(cfg.device, port="emulator"))
    try:
        device = connect_device(cfg, driver, Progress(enabled=False))
    except HilidentError as exc:
        return FilterTrial(
            errors=(f"{source}: [filters] a twin of the folder could not be opened to try slot 0: {exc}",)
        )
    try:
        errors = trial_filter_slot(device.adapter, table, source)
    finally:
        device.close()
    return FilterTrial(tried=True, errors=tuple(errors))
