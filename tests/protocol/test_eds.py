"""The tolerant EDS/DCF loader and the drive summary, on fixture files modelled on real vendor files' traits."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hilident.errors import ConfigError
from hilident.protocol.eds import inspect_eds, load_eds, load_eds_bytes, load_eds_text, object_info

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "eds"


def load(name, node_id=None):
    od, warnings = load_eds(FIXTURES / name, node_id)
    return od, warnings, inspect_eds(od)


def one(warnings, *words):
    """The single warning holding every word (fails when none or several do)."""
    hits = [w for w in warnings if all(x in w for x in words)]
    assert len(hits) == 1, (words, warnings)
    return hits[0]


# --- quirks repaired and reported -----------------------------------------------------------------------------------


def test_duplicate_keys_lower_case_crlf_and_latin1_are_read_and_each_reported_once():
    od, warnings, s = load("quirks_dup_lower_crlf.eds")
    name = str(FIXTURES / "quirks_dup_lower_crlf.eds")
    assert all(w.startswith(name + ": ") for w in warnings)
    one(warnings, "line 1104 [6041]", "duplicate key 'ObjectType'", "first (line 1103) is kept")
    one(warnings, "[ManufacturerObjects]", "duplicate key '1'")
    one(warnings, "CRLF", "1291 in all")
    one(warnings, "latin-1")
    one(warnings, "[deviceinfo]", "case-insensitively")
    assert len(warnings) == 5
    # what the quirks hid is read: lower-case [deviceinfo], a lower-case key, an upper-case SUB section
    assert s.vendor_name == "Antriebe Müller GmbH" and s.product_number == 0x1234
    assert od[0x6040].name == "Controlword"
    assert 1 in od[0x1A00].subindices
    assert s.vendor_filters == ((0x2300, "Notch filter 1"),)


def test_mode_object_types_deviating_from_cia402_are_kept_as_declared_and_reported():
    od, warnings, s = load("mode_u8_wo.eds")
    one(warnings, "0x6060", "UNSIGNED8", "INTEGER8", "kept as declared")
    one(warnings, "0x6060", "write-only", "0x6061")
    one(warnings, "0x6073", "UNSIGNED32", "UNSIGNED16")
    mode = s.roles["modes_of_operation"]
    assert (mode.data_type, mode.access) == (0x05, "wo")
    assert object_info(od, 0x6073).data_type == 0x07


def test_dcf_parameter_values_override_defaults_and_its_node_id_resolves_nodeid():
    od, warnings, s = load("configured.dcf")
    one(warnings, "ParameterValue", "4 in all")
    assert s.period.seconds == pytest.approx(0.002) and s.period.value == 2  # ParameterValue 2, DefaultValue 1
    assert object_info(od, 0x1600, 1).default == 0x60400010
    assert object_info(od, 0x1800, 1).default == 0x185  # [DeviceComissioning] NodeID=5
    od3, _ = load_eds(FIXTURES / "configured.dcf", node_id=3)
    assert object_info(od3, 0x1800, 1).default == 0x183


def test_odd_nodeid_expressions_are_rewritten_and_compact_arrays_expanded():
    od, warnings, s = load("period_1006_only.eds", node_id=7)
    one(warnings, "$NODEID expression", "2 in all")
    assert object_info(od, 0x1800, 1).default == 0x180 + 7  # "0x180 + $NodeId"
    assert object_info(od, 0x1400, 1).default == 0x200 + 7  # "$nodeid+0x100+0x100"
    assert s.heartbeat_consumers == 3  # CompactSubObj=3
    assert [object_info(od, 0x1016, i).name for i in (1, 2, 3)] == ["Consumer 1", "Consumer 2", "Consumer 3"]


def test_a_consumer_heartbeat_limit_without_room_for_the_node_id_is_read_as_the_time_limit():
    # as some vendor files give it: the heartbeat time's range as the whole entry's (no producer could be watched)
    text = (FIXTURES / "pdo4_rpdo2.eds").read_text(encoding="utf-8")
    entry = "[1016sub1]\nParameterName=Consumer heartbeat time 1\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\n"
    assert entry in text
    od, warnings = load_eds_text(text.replace(entry, entry + "LowLimit=0\nHighLimit=65535\n"), "hb.eds")
    assert (od[0x1016][1].min, od[0x1016][1].max) == (0, 0x007FFFFF)
    assert "node id" in one(warnings, "0x1016", "HighLimit", "[1016sub1]")
    od, warnings = load_eds_text(text.replace(entry, entry + "LowLimit=0\nHighLimit=0x007FFFFF\n"), "ok.eds")
    assert od[0x1016][1].max == 0x007FFFFF and not [w for w in warnings if "0x1016" in w]  # room: kept, no warning


def test_missing_sync_object_is_reported():
    _, warnings, _ = load("current_only.eds")
    one(warnings, "no 0x1005")
    _, warnings, _ = load("pdo4_rpdo2.eds")
    assert not warnings


HEAD = "[DeviceInfo]\nVendorName=X\nVendorNumber=1\n[1000]\nParameterName=Device type\nDataType=0x0007\nAccessType=ro\n"


@pytest.mark.parametrize(
    "text, words",
    [
        ("[2000]\nParameterName=No type\nAccessType=rw\n", ("[2000]", "DataType", "skipped")),
        ("[2000]\nDataType=0x0006\nAccessType=rw\n", ("[2000]", "no ParameterName")),
        ("[2000]\nParameterName=A\nDataType=0x0006\nAccessType=read\n", ("[2000]", "AccessType='read'", "'ro'")),
        ("[2000]\nParameterName=A\nDataType=0x0006\nAccessType=rw\nPDOMapping=yes\n", ("PDOMapping='yes'",)),
        ("[2000]\nParameterName=A\nDataType=0x0006\nAccessType=rw\nDefaultValue=007\n", ("leading zeros",)),
        ("[2000]\nParameterName=A\nDataType=0x0006\nAccessType=rw\nDefaultValue=abc\n", ("not a value", "'abc'")),
        ("[2000]\nParameterName=A\nDataType=0x0006\nAccessType=rw\nDefaultValue=$NODEID*2\n", ("$NODEID*2", "dropped")),
        ("[3000sub1]\nParameterName=Orphan\nDataType=0x0006\nAccessType=rw\n", ("[3000sub1]", "does not declare")),
        ("[Comments]\nLines=3\nLine1=only one\n", ("Lines=3", "read 1")),
        ("[2000]\nParameterName=A\nno equals sign here\nDataType=0x0006\nAccessType=rw\n", ("not a key=value line",)),
        ("[1000]\nParameterName=Again\n", ("[1000] appears again",)),
    ],
)
def test_each_repair_is_one_warning_naming_what_was_done(text, words):
    od, warnings = load_eds_text(HEAD + text, "t.eds")
    one(warnings, "t.eds", *words)
    assert 0x1000 in od


def test_leading_zero_default_is_read_as_decimal():
    od, _ = load_eds_text(HEAD + "[2000]\nParameterName=A\nDataType=0x0006\nAccessType=rw\nDefaultValue=010\n", "t.eds")
    assert object_info(od, 0x2000).default == 10


@pytest.mark.parametrize("data", [b"", b"\x00\x01\x02", b"[DeviceInfo]\nVendorName=X\n", b"just text\n"])
def test_what_is_not_an_eds_is_a_config_error_naming_the_file(data):
    with pytest.raises(ConfigError, match="bad.eds"):
        load_eds_bytes(data, "bad.eds")


def test_a_missing_file_or_a_folder_is_a_config_error_naming_it(tmp_path):
    with pytest.raises(ConfigError, match="nothere.eds"):
        load_eds(tmp_path / "nothere.eds")
    with pytest.raises(ConfigError, match=str(tmp_path)):
        load_eds(tmp_path)


def test_a_node_id_outside_1_to_127_names_its_place_in_the_run_config():
    with pytest.raises(ConfigError) as info:
        load_eds(FIXTURES / "configured.dcf", node_id=128)
    assert info.value.key == "device.canopen.node_id" and "1..127" in info.value.message


def test_a_path_the_system_refuses_is_a_config_error_saying_why(tmp_path):
    # the OS refuses a NUL byte with a ValueError, which has no strerror
    with pytest.raises(ConfigError, match="cannot read the EDS: embedded null byte"):
        load_eds(tmp_path / "bad\x00name.eds")


# --- the summary ------------------------------------------------------------------------------------------------------


def test_four_entry_pdos_and_two_rpdos():
    _, _, s = load("pdo4_rpdo2.eds")
    assert s.rpdo_entries == (4, 4) and s.tpdo_entries == (4, 4, 4, 4)
    assert s.pdo_mapping_writable
    assert s.supported_modes == ("pp", "pv", "hm", "csp", "csv", "cst")
    assert s.cyclic_modes == ("cst", "csv", "csp")


def test_pdo_limit_is_the_declared_entries_and_sub0_highlimit_only_when_none_is_declared():
    # one entry declared, sub-index 0 accepting 64: the undeclared entries cannot be written by name
    text = (
        HEAD + "[1400]\nParameterName=R\nObjectType=0x9\n[1400sub0]\nParameterName=n\nDataType=0x0005\n"
        "AccessType=ro\n[1600]\nParameterName=M\nObjectType=0x9\n[1600sub0]\nParameterName=n\nDataType=0x0005\n"
        "AccessType=rw\nHighLimit=64\n[1600sub1]\nParameterName=e\nDataType=0x0007\nAccessType=rw\n"
    )
    s = inspect_eds(load_eds_text(text, "t.eds")[0])
    assert s.rpdo_entries == (1,) and s.tpdo_entries == ()
    bare = text.replace("[1600sub1]\nParameterName=e\nDataType=0x0007\nAccessType=rw\n", "").replace("=64", "=6")
    assert inspect_eds(load_eds_text(bare, "t.eds")[0]).rpdo_entries == (6,)


def test_interpolation_period_of_8_ms_and_ip_only_with_vendor_recorder_and_generator():
    _, _, s = load("period_60c2_8ms.eds")
    assert (s.period.object, s.period.value, s.period.exponent) == ("0x60C2", 8, -3)
    assert s.period.seconds == pytest.approx(0.008)
    assert s.supported_modes == ("pp", "hm", "ip") and s.cyclic_modes == ("ip",)
    assert [i for i, _ in s.vendor_recorders] == [0x2010, 0x2011]
    assert s.vendor_generators == ((0x2050, "PRBS excitation amplitude"),)
    assert s.vendor_filters == ()


def test_cycle_period_0x1006_only():
    _, _, s = load("period_1006_only.eds")
    assert (s.period.object, s.period.value) == ("0x1006", 1000)
    assert s.period.seconds == pytest.approx(1e-3)
    assert "interpolation_data" not in s.roles and "ip" not in s.cyclic_modes


def test_current_only_drive_and_its_factor_group():
    _, _, s = load("current_only.eds")
    assert s.torque_objects == () and s.current_objects == ("0x6075", "0x6078")
    assert s.torque_reference == "current"
    assert s.roles["rated_current"].default == 5000
    assert s.factor_group == {
        "encoder_increments": 4096,
        "motor_revolutions": 1,
        "gear_motor_revs": 1,
        "gear_shaft_revs": 1,
        "feed": 10000,
        "feed_shaft_revs": 1,
    }
    assert s.cyclic_modes == ("csv", "csp")  # 0x6502 lists CSP and CSV, no CST


def test_without_a_6502_default_modes_are_unknown_and_cyclic_modes_follow_the_objects():
    _, _, s = load("no_6502_default.eds")
    assert s.supported_modes is None
    assert s.cyclic_modes == ("cst", "csv", "csp", "ip")
    assert s.roles["rated_torque"].default == 0 and s.torque_reference == "rated_torque"


def test_roles_carry_type_access_mapping_and_default():
    _, _, s = load("pdo4_rpdo2.eds")
    tq = s.roles["target_torque"]
    assert (tq.index, tq.subindex, tq.data_type, tq.access, tq.pdo_mappable) == (0x6071, 0, 0x03, "rww", True)
    assert s.roles["position_limit_max"].default == 2147483647
    assert (s.vendor_number, s.product_name, s.revision_number) == (0xABCD, "Four-entry servo", 0x10000)
    assert s.store_parameters and not s.abort_connection


def test_vendor_objects_are_found_by_whole_words_of_their_names():
    names = {
        0x2010: "Internal DataRecorder Control",
        0x2011: "Acceptance Filter 00",
        0x2012: "Velocity Unfiltered",
        0x2013: "CurrFilt",
        0x2014: "Sine sweep generator",
        0x2015: "Anti-resonance zero Q",
        0x6010: "Notch filter (not a vendor index)",
        0x2016: "Upload Recording Data",
    }
    text = HEAD + "".join(f"[{i:04X}]\nParameterName={n}\nDataType=0x0007\nAccessType=rw\n" for i, n in names.items())
    s = inspect_eds(load_eds_text(text, "t.eds")[0])
    assert [i for i, _ in s.vendor_filters] == [0x2013, 0x2015]
    assert [i for i, _ in s.vendor_recorders] == [0x2010, 0x2016]
    assert s.vendor_generators == ((0x2014, "Sine sweep generator"),)


# --- never another exception --------------------------------------------------------------------------------------

SMALL = (
    HEAD + "[DummyUsage]\nDummy0002=1\n[Comments]\nLines=1\nLine1=x\n"
    "[1018]\nParameterName=Identity\nObjectType=0x9\nSubNumber=2\n"
    "[1018sub0]\nParameterName=n\nDataType=0x0005\nAccessType=ro\nDefaultValue=1\n"
    "[1018sub1]\nParameterName=Vendor\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x12\n"
    "[1016]\nParameterName=HB\nObjectType=0x8\nDataType=0x0007\nAccessType=rw\nCompactSubObj=2\n"
    "[1016Name]\nNrOfEntries=2\n1=a\n2=b\n"
    "[1800sub1]\nParameterName=COB\nDataType=0x0007\nAccessType=rw\nDefaultValue=$NODEID+0x180\n"
    "[6060]\nParameterName=Mode\nDataType=0x0002\nAccessType=rw\nLowLimit=-3\nHighLimit=10\nPDOMapping=1\n"
    "[6502]\nParameterName=Modes\nDataType=0x0007\nAccessType=ro\nDefaultValue=0x380\n"
    "[2000]\nParameterName=Notch filter\nDataType=0x0008\nAccessType=rw\nDefaultValue=1.5\n"
    "[DeviceComissioning]\nNodeID=3\n"
)
TOKENS = [
    "[",
    "]",
    "=",
    "\n",
    "\r\n",
    ";",
    "$NODEID",
    "sub",
    "0x",
    "-",
    "+",
    "Name",
    "DataType",
    "ObjectType=0x8",
    "CompactSubObj",
    "DEFAULT",
    "\x00",
    "é",
    "\ufeff",
    " ",
    "[1018sub",
    "Lines=",
    "NrOfEntries=9",
    "DataType=-4\n",
    "ObjectType=0x5\n",
    "07",
    "DataType=0x0040\n",
    "[0040sub1]\n",
    "Name]\n",
]


@st.composite
def mutated(draw):
    text = SMALL
    for _ in range(draw(st.integers(1, 4))):
        pos = draw(st.integers(0, len(text)))
        action = draw(st.sampled_from(("insert", "delete", "swapcase", "duplicate")))
        if action == "insert":
            text = text[:pos] + draw(st.sampled_from(TOKENS) | st.text(max_size=4)) + text[pos:]
        elif action == "delete":
            text = text[:pos] + text[pos + draw(st.integers(1, 40)) :]
        elif action == "swapcase":
            text = text[:pos] + text[pos : pos + 30].swapcase() + text[pos + 30 :]
        else:
            line_end = text.find("\n", pos) + 1 or len(text)
            line_start = text.rfind("\n", 0, pos) + 1
            text = text[:line_end] + text[line_start:line_end] + text[line_end:]
    return text


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=mutated(), node_id=st.none() | st.integers(1, 127))
def test_mutated_eds_text_gives_an_object_dictionary_or_a_config_error(text, node_id):
    try:
        od, warnings = load_eds_bytes(text.encode("utf-8", "surrogatepass"), "m.eds", node_id)
    except ConfigError as exc:
        assert "m.eds" in str(exc)
        return
    inspect_eds(od)  # the summary of whatever was read never raises either
    assert all(isinstance(w, str) and w.startswith("m.eds") for w in warnings)
