"""hilident: hardware-in-the-loop DAQ and drive bridge for the lab bench."""

__version__ = "0.1.0"
