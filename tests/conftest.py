"""Fixtures shared by the end-to-end tests, and the ``twin`` marker on every test that starts a twin.

A twin is an emulated device served in real time behind a real transport: a serial board on a
pseudo-terminal or a raw TCP line, a CANopen drive on a virtual bus or behind socketcand, a Modbus drive
as a TCP or RTU server. A test that starts one, or that runs a whole ``hilident run`` session (a session
always talks to a twin here), takes seconds of wall clock; every such test carries the ``twin`` marker,
so ``pytest -m "not twin"`` is the quick pure half of the suite and ``pytest -m twin`` the rest
(CONTRIBUTING.md, "Fast loop").

The marker is put where the cost comes from: a test is a twin test when it uses a fixture of
:data:`TWIN_FIXTURES`, or when its body, a fixture it uses, or a helper of the test suite they call
(followed to any depth) calls one of :func:`twin_starters` or runs the ``run`` command. A module whose
tests all run sessions says so itself with ``pytestmark = pytest.mark.twin``.
"""

from __future__ import annotations

import inspect
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from types import CodeType, FunctionType, MethodType, ModuleType

import pytest

# Two test processes share two cores: a BLAS thread pool in each (and in every host or twin process a test
# starts) only adds threads that spin while they wait, and makes the small matrix products of the twins'
# physics several times slower. Set before numpy is first imported (the test modules import it after this
# file); a value given in the environment is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

TESTS = Path(__file__).resolve().parent

#: Fixtures that start a twin (or a twin in another process) for the test that uses them.
TWIN_FIXTURES = frozenset({"standalone_emulator"})

#: The command-line command that runs a whole session against the device of its config, the one that serves the
#: twin of a config to another process, and the module that runs the command line in another process.
SESSION_COMMAND = "run"
SERVE_COMMAND = ("emulate", "--config")
CLI_MODULE = "hilident.cli"


def twin_starters() -> tuple[Callable, ...]:
    """What starts a twin when a test calls it: the emulator's servers, the commands that connect a device (a
    session, an upload) and their connection, and the twin helpers of tests/support."""
    from hilident.cli import driver_trial
    from hilident.emulator import factory
    from hilident.emulator.canopen import server as canopen_server
    from hilident.emulator.modbus import server as modbus_server
    from hilident.emulator.serial import server as serial_server
    from hilident.session.connection import connect_device
    from hilident.session.run import Session
    from hilident.session.upload import UploadCommand
    from support import fresh_recording, twins

    return (
        factory.start_emulator,
        factory.start_standalone,
        serial_server.start,
        serial_server.start_serial_board,
        modbus_server.start,
        canopen_server.start,
        canopen_server.start_socketcand,
        connect_device,
        driver_trial.try_filter_slots,
        Session,
        UploadCommand,
        twins.Twin,
        twins.host,
        fresh_recording.twin_device,
        fresh_recording.record,
    )


def command_line() -> Callable:
    """``hilident``'s command line in this process: a twin starter when its command is ``run``."""
    from hilident.cli.main import main

    return main


class TwinFinder:
    """Whether a test starts a twin: by the fixtures it uses and by what its code calls.

    The code of the test, of the fixtures it uses and of every function or class of the test suite they name is
    followed; it starts a twin when it names one of the starters (by identity, not by spelling), runs the ``run``
    command in this process or in another, or serves a config's twin in another process.
    """

    def __init__(self, starters: tuple[Callable, ...], command_line: Callable):
        self._starter_ids = {id(starter) for starter in starters}
        self._command_line = command_line
        self._seen: dict[tuple[CodeType, type | None], bool] = {}

    def starts_a_twin(self, item: pytest.Item) -> bool:
        """Whether the test ``item`` starts a twin, by a fixture or by a call."""
        if not isinstance(item, pytest.Function):
            return False
        if TWIN_FIXTURES.intersection(item.fixturenames):
            return True
        return any(self._calls_a_starter(func, item.cls) for func in _test_code(item))

    def _calls_a_starter(self, func: object, cls: type | None) -> bool:
        if isinstance(func, staticmethod | classmethod | MethodType):
            func = func.__func__
        if isinstance(func, FunctionType):
            func = inspect.unwrap(func)  # a decorated helper: its own code
        if not isinstance(func, FunctionType) or not _in_test_suite(func):
            return False
        return self._code_calls_a_starter(func.__code__, func.__globals__, cls)

    def _code_calls_a_starter(self, code: CodeType, namespace: dict, cls: type | None) -> bool:
        key = (code, cls)
        if key not in self._seen:
            self._seen[key] = False  # a helper that reaches itself again adds nothing
            nested = (const for const in code.co_consts if isinstance(const, CodeType))
            self._seen[key] = (
                _starts_a_twin_in_another_process(code)
                or any(self._starts_with(_resolve(name, namespace, cls), code, cls) for name in code.co_names)
                or any(self._code_calls_a_starter(inner, namespace, cls) for inner in nested)
            )
        return self._seen[key]

    def _starts_with(self, found: object, code: CodeType, cls: type | None) -> bool:
        """Whether ``found``, a name ``code`` uses, starts a twin (a module: one of its names ``code`` uses)."""
        if self._is_starter(found, code):
            return True
        if isinstance(found, ModuleType):
            return any(self._is_starter(vars(found).get(name), code) for name in code.co_names)
        if isinstance(found, type):
            return _in_test_suite(found) and any(self._calls_a_starter(member, None) for member in vars(found).values())
        return self._calls_a_starter(found, cls)

    def _is_starter(self, found: object, code: CodeType) -> bool:
        if found is self._command_line:
            return SESSION_COMMAND in _constants(code)
        return id(found) in self._starter_ids


def _resolve(name: str, namespace: dict, cls: type | None) -> object:
    """What ``name`` in a test's code stands for: an attribute of its test class, a global of its module, or a
    module it imports inside a function (a dotted name)."""
    found = getattr(cls, name, None) if cls is not None else None
    if found is None:
        found = namespace.get(name)
    return sys.modules.get(name) if found is None else found


def _starts_a_twin_in_another_process(code: CodeType) -> bool:
    """``python -m hilident.cli run ...`` or ``python -m hilident.cli emulate ... --config ...`` in a subprocess."""
    constants = _constants(code)
    return CLI_MODULE in constants and (SESSION_COMMAND in constants or constants.issuperset(SERVE_COMMAND))


def _constants(code: CodeType) -> set:
    """The constants of ``code``, those of a literal list or tuple of constants each on its own."""
    found: set = set()
    pending = list(code.co_consts)
    while pending:
        const = pending.pop()
        if isinstance(const, tuple | frozenset):
            pending.extend(const)
        elif not isinstance(const, CodeType):
            found.add(const)
    return found


def _test_code(item: pytest.Function) -> Iterator[Callable]:
    """The test function and the functions of every fixture it uses."""
    yield item.function
    for defs in item._fixtureinfo.name2fixturedefs.values():  # where pytest keeps an item's fixture definitions
        yield from (fixture_def.func for fixture_def in defs)


def _in_test_suite(obj: object) -> bool:
    """Whether ``obj``, a function or a class, is defined in a file under tests/."""
    if isinstance(obj, FunctionType):
        filename = obj.__code__.co_filename
    else:
        filename = getattr(sys.modules.get(getattr(obj, "__module__", "")), "__file__", None) or ""
    return Path(filename).is_relative_to(TESTS)


@pytest.fixture(autouse=True)
def _signal_dispositions():
    """Each test leaves the worker's signal handlers as it found them: ``hilident`` run in-process and ended by
    a signal ignores further ones on its way out (``endings.ignore_further_signals``, right for a process about
    to exit), and a later test in the same worker, or a process it starts (which inherits what is ignored),
    would not see its signals."""
    import threading

    from hilident.endings import ENDING_SIGNALS

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    found = {s: signal.getsignal(s) for s in ENDING_SIGNALS}
    yield
    for s, handler in found.items():
        if handler is not None and signal.getsignal(s) is not handler:
            signal.signal(s, handler)


@pytest.fixture(autouse=True)
def _configured_friction_legs(request, monkeypatch):
    """Sessions in this process play the friction test's configured legs only, unless the test is marked
    ``friction_rounds``: its added rounds (``[friction_test] target_ci_percent``) take tens of seconds of twin
    time per session, and only the tests of the friction test itself (tests/test_friction_extension.py) need
    them. The first round is fitted and reported as usual; the extension says its target was met."""
    if request.node.get_closest_marker("friction_rounds") is None:
        from hilident.session import friction_test

        monkeypatch.setattr(friction_test, "_met", lambda result, target_percent: True)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark every test that starts a twin ``twin``."""
    finder = TwinFinder(twin_starters(), command_line())
    for item in items:
        if finder.starts_a_twin(item):
            item.add_marker(pytest.mark.twin)


@pytest.fixture
def standalone_emulator():
    """Start ``hilident emulate TRANSPORT --config CONFIG ...`` in another process.

    Yields ``start(transport, config, *extra) -> port``, the line the emulator
    printed. Every emulator started is stopped with SIGTERM at teardown and
    must exit cleanly (code 0).
    """
    procs: list[subprocess.Popen] = []

    def start(transport: str, config, *extra: str) -> str:
        proc = subprocess.Popen(
            [sys.executable, "-m", "hilident.cli", "emulate", transport, "--config", str(config), *extra],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        procs.append(proc)
        port = proc.stdout.readline().strip()
        assert port, proc.stderr.read()
        return port

    yield start
    for proc in procs:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0, proc.stderr.read()
