"""The device side: an emulated twin of every device, speaking its real wire protocol.

A twin is the same physics for every transport, a *firmware* (the device's
state, objects or registers, and behaviour) and a *server* (the wire). The
layout is the same for the three transports::

    emulator/
      plant.py, sensors.py,     shared physics: plant and friction, sensors, process disturbances,
      disturbance.py, drive.py  and the drive loop (DriveLoop) every firmware wraps
      coupling.py               k and d of the cart-to-load coupling as functions of the cart position
      coupled_plant.py          one linear mechanism of several drives (CoupledModel, CoupledPlant and its ports)
      preset.py                 bench realism presets (the messy bench by default, or a clean one)
      clock.py                  the one simulated clock (SimClock: pacing without bursts, coasting)
                                and the one table player (TablePlayer) every twin runs on
      device.py                 build_drive (physics from [emulator]) and EmulatedDevice (what start returns)
      factory.py                start_emulator / start_standalone: dispatch on the driver's transport
      serial/                   the myRIO-style board on a serial line
        firmware.py             BoardFirmware: the protocol state machine (drivers/myrio-board/PROTOCOL.md)
        links.py                pseudo-terminal, raw TCP and in-memory pipe links; line damage
        server.py               BoardServer (clock thread + UART thread), start
      modbus/                   Modbus drives
        firmware.py             ModbusDriveFirmware: a map with an excitation table and a capture
        parameter_firmware.py   ParameterDriveFirmware: a real drive's parameter list (DSY-RS)
        pdu.py                  request PDUs -> firmware calls -> response PDUs (the specification)
        rtu.py                  RTU framing on pseudo-terminals (null-modem bridge, t3.5 silence)
        server.py               ModbusDriveServer (Modbus TCP / RTU, the clock thread), start
      canopen/                  CiA 402 drives on a CAN bus
        firmware.py             CanopenDriveFirmware: CiA 402 states and the SDO callbacks, around its parts
        host.py                   (FirmwareHost: what the parts ask of the firmware, a typed protocol):
        objects.py                ObjectStore (stored values, scalings), roles.py (object roles, EMCY codes),
        setpoints.py              SetPoints (modes of operation, set-points), parameters.py (limits, filters),
        pdo.py                    PdoExchange (PDO mapping, SYNC-driven runs), guarding.py (heartbeat
        playback.py               consumer, node guarding), TablePlayback (table, capture), recorder.py
                                  (a vendor drive's recorder and generator)
        sdo.py                  the SDO server with block transfers and the abort fault
        socketcand.py           a socketcand server, for a host in another process
        server.py               CanopenDriveServer (network, clock thread), start, start_socketcand; several
                                nodes on one mechanism (CanopenBusServer, MechanismGroup, LockstepDrive)

Dependencies point one way: a transport's ``server`` imports its ``firmware``
and the shared modules (``device``, ``clock``, physics); :mod:`factory` imports
the servers; nothing imports :mod:`factory` inside the package. The emulator
never imports ``hilident.adapters``: the two meet only in ``hilident.protocol`` (the
wire) and ``hilident.filters`` (the biquad the drive runs).

**A new drive of a known transport** needs no code here: a folder under
``drivers/`` (its EDS or register map) is served by that transport's firmware.

**A twin for a new transport**: add ``emulator/<transport>/`` with a
``firmware.py`` (device state and behaviour around a
:class:`~hilident.emulator.drive.DriveLoop`; for table runs, play samples with
:class:`~hilident.emulator.clock.TablePlayer` and offer ``running``,
``produced``, ``sample_rate_hz``, ``advance(n)`` and ``idle(n)``: the
:class:`~hilident.emulator.clock.PacedFirmware` protocol) and a ``server.py``
(the wire, a clock thread that calls
:meth:`~hilident.emulator.clock.SimClock.step`, ``close()`` and ``error``: the
:class:`~hilident.emulator.device.EmulatorServer` protocol, and
``start(cfg, driver, device) -> EmulatedDevice``); then add the transport to ``_STARTERS`` (and
:data:`~hilident.emulator.factory.STANDALONE_LINKS`) in :mod:`factory`.

May import ``protocol``, ``filters``, ``drivers``, ``config``, ``numbers`` and ``links``; never ``adapters``,
``session``, ``batch`` or ``cli``.
"""
