"""The CANopen CiA 402 drive's twin: :mod:`.firmware` and its parts, :mod:`.sdo`, :mod:`.socketcand`, :mod:`.server`."""
