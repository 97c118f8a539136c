"""The following error monitor of the emulated CANopen drive in a position mode (CiA 402 0x6065, 0x6066).

The drive compares, every loop tick, its position demand with its position
actual value. When the difference stays above the following error window
(0x6065, position increments; 0xFFFFFFFF switches the monitor off) for longer
than the following error time out (0x6066, ms), the drive faults with EMCY
0x8611 (following error). Pure: per-tick errors in, the verdict out.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FOLLOWING_ERROR_OFF", "FollowingErrorMonitor"]

#: 0x6065 value that switches the following error monitor off (CiA 402).
FOLLOWING_ERROR_OFF = 0xFFFFFFFF


class FollowingErrorMonitor:
    """How long the following error has stayed above the window, across the cycles of one run.

    Attributes
    ----------
    over_ticks : int
        Loop ticks the error has been above the window, up to the last tick checked.
    """

    def __init__(self):
        self.restart()

    def restart(self) -> None:
        self.over_ticks = 0

    def exceeded(self, error_m: np.ndarray, window_m: float, timeout_s: float, tick_s: float) -> bool:
        """Whether the following error outlasted the time out within these ticks.

        Parameters
        ----------
        error_m : ndarray
            Position demand minus position actual at each tick, m (or rad).
        window_m : float
            The following error window, m (or rad).
        timeout_s : float
            The following error time out, s.
        tick_s : float
            One loop tick, s.
        """
        for over in (np.abs(error_m) > window_m).tolist():
            self.over_ticks = self.over_ticks + 1 if over else 0
            if self.over_ticks * tick_s > timeout_s:
                return True
        return False
