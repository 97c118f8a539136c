"""Hostile configurations: whatever a config file holds, loading it ends in a
:class:`~hilident.errors.ConfigError` naming the file and a key, or in a valid
:class:`~hilident.config.tables.Config`; never another exception, never a large
allocation. And a config that loads builds its signals without surprises.
"""

from __future__ import annotations

import dataclasses
import tracemalloc
import typing

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from hilident.config.tables import Config, excitation_samples, load_config, parse_config
from hilident.errors import ConfigError
from hilident.signals import ramp_extent, velocity_ramps
from hilident.signals._checks import MAX_SAMPLES
from support.hostile_toml import toml_string, toml_value

LIMITS = {"torque_nm": 10, "velocity_mps": 1, "position_min_m": -1, "position_max_m": 1}


def _tables(cls=Config, prefix=()):
    """(table path, {key: type hint}) for every table of the schema."""
    hints = typing.get_type_hints(cls)
    here = {}
    for f in dataclasses.fields(cls):
        if f.metadata.get("internal"):
            continue
        hint = hints[f.name]
        if isinstance(hint, typing.types.UnionType):
            hint = next(h for h in typing.get_args(hint) if h is not type(None))
        if dataclasses.is_dataclass(hint):
            yield from _tables(hint, prefix + (f.name,))
        else:
            here[f.name] = hint
    if here:
        yield prefix, here


TABLES = dict(_tables())


def toml_text(tables: dict) -> str:
    out = []
    for path, values in tables.items():
        out.append("[" + ".".join(toml_string(p) for p in path) + "]")
        out += [f"{toml_string(k)} = {toml_value(v)}" for k, v in values.items()]
    return "\n".join(out) + "\n"


scalars = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**80), max_value=2**80),
    st.sampled_from([0, 1, -1, 2, 32, 33, 2**31, 2**63 - 1, 10**30]),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e308, -1e308, 1e-300, 1e-9, 1e9, 0.5, 2.0, 20.0]),
    st.text(max_size=10),
    st.sampled_from(["emulator", "spy:///dev/null?file=/tmp/x", "multisine", "prbs", "velocity_mps", "torque"]),
)
values = st.one_of(scalars, st.lists(scalars, max_size=5), st.dictionaries(st.text(max_size=5), scalars, max_size=2))


def typed(hint):
    """Values of the type a key expects, hostile ones included (nan, inf, 1e308, 2**80, long lists)."""
    if hint is bool:
        return st.booleans()
    if hint is int:
        return st.one_of(st.integers(-5, 100), st.integers(min_value=-(2**80), max_value=2**80))
    if hint is float:
        return st.one_of(st.floats(-10, 1e4), st.floats(allow_nan=True, allow_infinity=True))
    if hint is str:
        return st.one_of(
            st.text(max_size=10),
            st.sampled_from(
                ["spy:///dev/pts/1?file=/tmp/x", "velocity_mps", "prbs", "multisine", "torque", "x" * 5000]
            ),
        )
    (item,) = typing.get_args(hint)
    return st.one_of(st.lists(typed(item), max_size=6), st.lists(typed(item), min_size=60, max_size=70))


@st.composite
def configs(draw):
    """A config of a few tables from the schema; mostly known keys with values of their type, some anything."""
    tables = {("limits",): dict(LIMITS)} if draw(st.integers(0, 3)) else {}
    for path in draw(st.lists(st.sampled_from(sorted(TABLES)), max_size=4, unique=True)):
        table = tables.setdefault(path, {})
        for _ in range(draw(st.integers(1, 4))):
            if draw(st.integers(0, 39)) == 0:
                table[draw(st.text(min_size=1, max_size=8))] = draw(values)
                continue
            key = draw(st.sampled_from(sorted(TABLES[path])))
            table[key] = draw(values if draw(st.integers(0, 4)) == 0 else typed(TABLES[path][key]))
    return tables


def _outcome(text: str):
    try:
        return parse_config(text, "hostile.toml")
    except ConfigError as exc:
        assert exc.file == "hostile.toml" and exc.key, exc
        assert "np.float64" not in str(exc) and len(str(exc)) < 1500, str(exc)
        return exc


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(configs())
def test_any_config_is_valid_or_a_config_error_and_loads_in_bounded_memory(tables):
    text = toml_text(tables)
    tracemalloc.start()
    try:
        _outcome(text)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 8 * 2**20  # nothing of the size of an experiment is allocated at load


@settings(max_examples=80, deadline=None)
@given(st.binary(max_size=200), st.integers(0, 400))
def test_any_bytes_are_valid_or_a_config_error(tmp_path_factory, garbage, at):
    raw = toml_text({("limits",): LIMITS, ("excitation",): {"kind": "sine"}}).encode()
    at %= len(raw) + 1
    path = tmp_path_factory.mktemp("cfg") / "hostile.toml"
    path.write_bytes(raw[:at] + garbage + raw[at:])
    try:
        load_config(path)
    except ConfigError as exc:
        assert str(path) in str(exc) and exc.key


excitation_tables = st.fixed_dictionaries(
    {
        "kind": st.sampled_from(["sine", "square", "chirp", "noise", "prbs", "multisine", "step"]),
        "duration_s": st.one_of(st.floats(0.01, 30.0), st.sampled_from([1e9, 1e-6, 5e4])),
        "period_s": st.one_of(st.floats(0.005, 8.0), st.sampled_from([1e6, 40.0])),
        "register_length": st.integers(2, 32),
        "clock_divider": st.one_of(st.integers(1, 8), st.integers(1, 2**31 - 1)),
        "fade_s": st.floats(0.0, 20.0),
        "frequency_hz": st.floats(0.5, 700.0),
        "f_min_hz": st.floats(0.1, 5.0),
        "f_max_hz": st.floats(10.0, 200.0),
    }
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(excitation_tables, st.sampled_from([250.0, 1000.0, 4000.0]))
def test_an_excitation_that_loads_is_built_with_the_length_computed_at_load(excitation, fs):
    from hilident.session.excitation import build_excitation

    cfg = _outcome(
        toml_text(
            {
                ("limits",): LIMITS,
                ("run",): {"sample_rate_hz": fs},
                ("excitation",): excitation,
                ("friction_test",): {"enabled": False},
            }
        )
    )
    if isinstance(cfg, ConfigError):
        return
    n = excitation_samples(cfg)
    assert 1 <= n <= MAX_SAMPLES
    assume(n <= 2**17)  # build only what a test can afford
    assert build_excitation(cfg).samples.size == n


friction_tables = st.fixed_dictionaries(
    {
        "speeds_mps": st.lists(
            st.one_of(st.floats(0.001, 0.3), st.sampled_from([1e-12, 0.0, -0.1])), min_size=1, max_size=6
        ),
        "hold_s": st.one_of(st.floats(0.01, 2.0), st.sampled_from([1e9, 1e-9])),
        "settle_s": st.floats(0.0, 0.5),
        "accel_mps2": st.one_of(st.floats(0.05, 10.0), st.sampled_from([1e-9, 1e-300, 1e30])),
    }
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(friction_tables)
def test_a_friction_test_that_loads_fits_the_position_window_and_the_size_bound(friction):
    cfg = _outcome(toml_text({("limits",): LIMITS, ("friction_test",): friction}))
    if isinstance(cfg, ConfigError):
        return
    ft = cfg.friction_test
    n, travel = ramp_extent(ft.speeds_mps, ft.hold_s, ft.accel_mps2, cfg.run.sample_rate_hz, ft.settle_s)
    assert n <= MAX_SAMPLES and travel < 1.0  # half of the [-1, 1] m window
    assume(n <= 2**17)
    profile = velocity_ramps(ft.speeds_mps, ft.hold_s, ft.accel_mps2, cfg.run.sample_rate_hz, ft.settle_s)
    assert profile.setpoint_mps.size == n and profile.max_excursion_m == pytest.approx(travel, rel=1e-9, abs=1e-12)


def _error(text: str) -> ConfigError:
    err = _outcome(text)
    assert isinstance(err, ConfigError), "accepted"
    return err


@pytest.mark.parametrize(
    "extra, key, says",
    [
        ({("limits",): dict(LIMITS, torque_nm=1e308)}, "limits.torque_nm", "1e+308"),
        ({("limits",): dict(LIMITS, torque_nm=float("inf"))}, "limits.torque_nm", "finite"),
        ({("limits",): dict(LIMITS, velocity_mps=float("nan"))}, "limits.velocity_mps", "got nan"),
        ({("friction_test",): {"accel_mps2": 1e-9}}, "friction_test.accel_mps2", "samples"),
        ({("excitation",): {"duration_s": 1e9}}, "excitation.duration_s", "1e+12 samples"),
        ({("excitation",): {"kind": "prbs", "register_length": 32}}, "excitation.register_length", "samples"),
        ({("excitation",): {"kind": "prbs", "clock_divider": 2**40}}, "excitation.clock_divider", "2147483647"),
        ({("friction_test",): {"speeds_mps": [0.01] * 300_000}}, "friction_test.speeds_mps", "300000"),
        ({("excitation",): {"period_s": 30.0}}, "excitation.period_s", "longer than excitation.duration_s"),
        ({("excitation",): {"kind": "sine", "fade_s": 11.0}}, "excitation.fade_s", "fades"),
        ({("excitation",): {"kind": "sine", "frequency_hz": 600.0}}, "excitation.frequency_hz", "Nyquist"),
        ({("run",): {"seed": 2**64}}, "run.seed", "4294967295"),
        ({("device",): {"port": "spy:///dev/pts/3?file=/home/me/.bashrc"}}, "device.port", "overwrite"),
        ({("device",): {"port": "SPY://COM3?raw&file"}}, "device.port", "file="),
        ({("device",): {"port": "a\u0000b"}}, "device.port", "control characters"),
        ({("device",): {"driver": "x" * 5000}}, "device.driver", "4096"),
        ({("emulator", "faults"): {"abort_object": "zz"}}, "emulator.faults.abort_object", "object address"),
        ({("friction_test",): {"speeds_mps": [0.2], "hold_s": 5.0}}, "friction_test.speeds_mps", "position window"),
    ],
)
def test_hostile_values_name_their_key(extra, key, says):
    tables = {("limits",): LIMITS}
    tables.update(extra)
    err = _error(toml_text(tables))
    assert err.key == key and says in err.message, str(err)


def test_spy_without_a_file_is_fine():
    cfg = parse_config(toml_text({("limits",): LIMITS, ("device",): {"port": "spy:///dev/ttyUSB0?color"}}))
    assert cfg.device.port.startswith("spy://")


def test_a_non_utf8_config_names_file_and_offset(tmp_path):
    path = tmp_path / "bench.toml"
    path.write_bytes(b"[run]\nseed = 1 # \xff\n")
    with pytest.raises(ConfigError, match=r"bench.toml.*not UTF-8.*0xff at offset 17"):
        load_config(path)


def test_an_oversized_config_is_refused_before_it_is_parsed(tmp_path):
    path = tmp_path / "big.toml"
    path.write_bytes(b"# " + b"x" * (2 << 20) + b"\n")
    with pytest.raises(ConfigError, match="KiB"):
        load_config(path)


def test_deep_nesting_is_a_syntax_error():
    assert _error("a = " + "[" * 20_000 + "]" * 20_000).key == "(syntax)"


@settings(max_examples=100, deadline=None)
@given(st.floats(0.0, 0.02), st.integers(1, 60))
def test_fades_that_load_fit_the_excitation(fade_s, n):
    """The load-time check and signals.fade agree at the edge (round(fade_s * fs) samples per fade)."""
    from hilident.session.excitation import build_excitation

    cfg = _outcome(
        toml_text({("limits",): LIMITS, ("excitation",): {"kind": "step", "duration_s": n / 1000.0, "fade_s": fade_s}})
    )
    if isinstance(cfg, ConfigError):
        assert cfg.key == "excitation.fade_s" and 2 * round(fade_s * 1000.0) > n
    else:
        assert build_excitation(cfg).samples.size == n


@pytest.mark.parametrize(
    "table, values",
    [
        (("friction_test",), {"accel_mps2": 1e-9}),
        (("excitation",), {"duration_s": 1e9}),
        (("excitation",), {"kind": "prbs", "register_length": 32}),
        (("excitation",), {"kind": "prbs", "register_length": 20, "clock_divider": 2**30}),
        (("excitation",), {"kind": "multisine", "duration_s": 33554.0, "period_s": 4.0}),  # the lead-in tips it over
    ],
)
def test_oversized_experiments_are_refused_without_allocating_them(table, values):
    text = toml_text({("limits",): LIMITS, table: values})
    tracemalloc.start()
    try:
        err = _error(text)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert "(2**25)" in err.message and peak < 2 * 2**20
