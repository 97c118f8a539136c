"""The command line: parses arguments and hands each command to the session, identify, batch or the emulator.

May import every other package; nothing imports it.
"""
