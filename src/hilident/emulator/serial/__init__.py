"""The serial board's twin: :mod:`.firmware` (protocol state machine), :mod:`.links` (the line), :mod:`.server`."""
