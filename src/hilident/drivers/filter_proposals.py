"""The ``[filters]`` table ``drivers new`` proposes for a drive of a documented family, recognised from its EDS.

A family is recognised by its filter objects as its manual documents them
(index, sub-index, data type, a fragment of the object's name) and by the
vendor ID of the EDS's identity ([DeviceInfo] VendorNumber, else the default of
0x1018:1). Objects that match with the family's vendor ID make a proposal;
objects that match while the EDS gives no vendor ID, or one that is no
documented family's, make a proposal that says it was recognised from the
objects only. ``drivers new`` writes the proposal with every key marked
``PLACEHOLDER`` and the source of each value in its comment, so the user
confirms values instead of writing structure (:func:`propose_filters`).

The recognisers are data (:data:`FAMILIES`); the documentation behind each
is cited in its ``source`` (docs/filter_encodings.md has the tables too).
"""

from __future__ import annotations

from dataclasses import dataclass

from hilident.protocol import eds as E

__all__ = ["FAMILIES", "FilterFamily", "FilterProposal", "ObjectSign", "propose_filters", "vendor_id"]

_BOOLEAN, _INT8, _INT16, _INT32 = 0x1, 0x2, 0x3, 0x4
_UINT8, _UINT16, _UINT32, _REAL32, _OCTETS, _DOMAIN = 0x5, 0x6, 0x7, 0x8, 0xA, 0xF


@dataclass(frozen=True)
class ObjectSign:
    """An object a family's EDS has, as its manual documents it.

    Attributes
    ----------
    index, subindex : int
        Where it is (sub-index 0 for a plain variable).
    types : tuple of int
        The CiA 301 data types it may have.
    names : tuple of str
        Fragments of its EDS name, one of which it contains (case ignored).
    sizes : tuple of int or None
        An OCTET_STRING's default length in bytes, one of these (None in it: no default is also accepted); empty:
        not asked.
    """

    index: int
    subindex: int
    types: tuple[int, ...]
    names: tuple[str, ...]
    sizes: tuple[int | None, ...] = ()

    def matches(self, od) -> bool:
        """The EDS ``od`` has this object, of one of the types, named with one of the fragments."""
        info = E.object_info(od, self.index, self.subindex)
        if info is None or info.data_type not in self.types:
            return False
        if not any(fragment.lower() in info.name.lower() for fragment in self.names):
            return False
        if self.sizes:
            size = len(info.default) if isinstance(info.default, bytes) and info.default else None
            return size in self.sizes
        return True


@dataclass(frozen=True)
class FilterFamily:
    """A documented family of drives: how to recognise it and the ``[filters]`` table to propose.

    Attributes
    ----------
    name : str
        The family, for comments and messages.
    vendor_ids : tuple of int
        Its CiA vendor IDs.
    vendor_source : str
        Where the vendor ID was confirmed (or that it was not).
    signs : tuple of ObjectSign
        The objects the EDS must have, every one.
    filter_slots : int
        ``[board] filter_slots`` with the proposed table.
    tables : tuple of (str, tuple of (str, str, str))
        Per TOML table (``"filters"``, ``"filters.fields"``), its ``(key, TOML value, source of the value)``.
    source : str
        The documentation the objects and the table come from.
    """

    name: str
    vendor_ids: tuple[int, ...]
    vendor_source: str
    signs: tuple[ObjectSign, ...]
    filter_slots: int
    tables: tuple[tuple[str, tuple[tuple[str, str, str], ...]], ...]
    source: str


_COPLEY_DICT = "Copley Parameter Dictionary p. 74-76"
_COPLEY_VENDOR = "0x000000AB: Copley Controls' vendor ID in public EtherCAT master code (VENDORID_COPLEY)"
_COPLEY_OBJECT = "0x2106 Velocity loop output filter coefficients: the filter on the torque command"
_AKD_GUIDE = "AKD User Guide p. 626-627, AKD BASIC User Guide p. 451, 456"
_AKD_VENDOR = (
    "0x0000006A: Kollmorgen's vendor ID, with the AKD's product code 0x00414B44, in public EtherCAT master code"
)
_AKD_FIELDS: tuple[tuple[str, str, str], ...] = (
    ("pole_hz", '["0x3406:1", "0x3406:2"]', "VL.ARPF1, VL.ARPF2 at sub 1-4: inferred from the sub-index pattern only"),
    ("pole_q", '["0x3406:5", "0x3406:6"]', f"VL.ARPQ1, VL.ARPQ2 at sub 5-8 ({_AKD_GUIDE})"),
    ("zero_hz", '["0x3406:9", "0x3406:0xA"]', f"VL.ARZF1, VL.ARZF2 at sub 9-0xC ({_AKD_GUIDE})"),
    ("zero_q", '["0x3406:0xD", "0x3406:0xE"]', f"VL.ARZQ1, VL.ARZQ2 at sub 0xD-0x10 ({_AKD_GUIDE})"),
)
_AKD_RANGES = (
    "ranges",
    "{ pole_hz = [5, 5000], zero_hz = [5, 5000], pole_q = [0.2, 20], zero_q = [0.1, 5] }",
    f"VL.ARPF/ARZF 5-5000 Hz, VL.ARPQ 0.2-20, VL.ARZQ 0.1-5 ({_AKD_GUIDE})",
)
_AKD_ENABLE = ("enable", '"none"', "an AR filter always runs what it holds; AR1 and AR2 are in the forward path")


def _akd_signs(types: tuple[int, ...]) -> tuple[ObjectSign, ...]:
    return (
        ObjectSign(0x3406, 5, types, ("ARPQ", "pole q")),
        ObjectSign(0x3406, 9, types, ("ARZF", "zero f")),
        ObjectSign(0x3406, 0xD, types, ("ARZQ", "zero q")),
    )


_AX2000 = "https://infosys.beckhoff.com/content/1033/ax2000_ascii"
_AX2000_SOURCE = f"Beckhoff InfoSys, AX2000 ASCII reference: BQMODE, BQFC, BQFR, BQDC, BQDR ({_AX2000}/)"
_AX2000_PAGES = {
    "BQMODE": f"{_AX2000}/15075191947.html",
    "BQFC": f"{_AX2000}/15075186827.html",
    "BQFR": f"{_AX2000}/15075189387.html",
    "BQDC": f"{_AX2000}/15075183755.html",
    "BQDR": f"{_AX2000}/15075185291.html",
}
_AX2000_VENDOR = (
    "0x00000002: Beckhoff Automation's vendor ID in public EtherCAT master code (VendorIdBeckhoff, "
    "BECKHOFF_VENDOR_ID); not in the AX2000 pages cited"
)
_AX2000_INTEGERS = (_INT32, _UINT32)
#: (index, parameter, field) of the AX2000's bi-quad, CANopen objects of the ASCII reference
_AX2000_OBJECTS = (
    (0x3664, "BQFC", "center_hz"),
    (0x3665, "BQFR", "ratio"),
    (0x3662, "BQDC", "center_damping"),
    (0x3663, "BQDR", "damping_ratio"),
)
_AX2000_FIELDS: tuple[tuple[str, str, str], ...] = tuple(
    (field, f'["0x{index:04X}"]', f"{name}, CANopen 0x{index:04X} ({_AX2000_PAGES[name]})")
    for index, name, field in _AX2000_OBJECTS
)
_AX2000_KEYS: tuple[tuple[str, str, str], ...] = (
    (
        "encoding",
        '"center_ratio_damping"',
        "BQFC, BQFR, BQDC, BQDR; zeros at BQFC / sqrt(BQFR) damped BQDC / sqrt(BQDR), "
        "poles at BQFC sqrt(BQFR) damped BQDC sqrt(BQDR): an assumption, Beckhoff documents the parameters, not "
        "the transfer function",
    ),
    (
        "scales",
        "{ center_hz = 0.001, ratio = 0.001, center_damping = 0.001, damping_ratio = 0.001 }",
        f"BQFC: Integer32, weighting 1000 on the bus ({_AX2000_PAGES['BQFC']}); the same for BQFR, BQDC, BQDR is an "
        "assumption",
    ),
    (
        "ranges",
        "{ center_hz = [20, 1000], ratio = [0.1, 10], center_damping = [0.2, 1], damping_ratio = [0.25, 5] }",
        "BQFC 20-1000 Hz, BQFR 0.1-10, BQDC 0.2-1, BQDR 0.25-5 (the BQFC, BQFR, BQDC, BQDR pages); BQDR <= 5 caps a "
        "notch at 14 dB",
    ),
    ("enable", '["0x3666"]', f"BQMODE, CANopen 0x3666, Integer8 ({_AX2000_PAGES['BQMODE']})"),
    (
        "enable_values",
        "{ on = 2, off = 0 }",
        f"BQMODE 2 bi-quad, 0 none; 1 PID-T2 (the default), 3 reserved ({_AX2000_PAGES['BQMODE']})",
    ),
)

_INGENIA_REPO = "https://github.com/ingeniamc/ingenialink-python"
#: the dictionary every Ingenia key cites (facts only: the repository's licence, CC BY-NC-ND 4.0, forbids copying)
_INGENIA_XDF = "den-net-e_2.8.0_v3.xdf"
_INGENIA_VENDOR = f"0x0000029C: the default of DRV_ID_VENDOR_ID (register 0x06E0, CANopen 0x26E0) in {_INGENIA_XDF}"
_INGENIA_SOURCE = (
    f"Ingenia's dictionary {_INGENIA_REPO}/blob/master/tests/resources/{_INGENIA_XDF} and ingenialink/constants.py "
    "(facts only, the licence forbids copying): CL_CUR_REF_FILTER1_TYPE/FREQ/Q/GAIN at registers 0x0580-0x0583, "
    "CL_CUR_REF_FILTER2_* at 0x0588-0x058B, CANopen object 0x2000 + register (CANOPEN_ADDRESS_OFFSET; the "
    "dictionary's CANopenObject entries)"
)


def _ingenia_signs() -> tuple[ObjectSign, ...]:
    signs = []
    for n, base in ((1, 0x2580), (2, 0x2588)):
        # the dictionary's label ("Current reference filter 1 type") or its id (CL_CUR_REF_FILTER1_TYPE)
        label, ident = f"current reference filter {n} ", f"cur_ref_filter{n}_"
        signs += [
            ObjectSign(base, 0, (_UINT16,), (f"{label}type", f"{ident}type")),
            ObjectSign(base + 1, 0, (_UINT32,), (f"{label}freq", f"{ident}freq")),
            ObjectSign(base + 2, 0, (_REAL32,), (f"{label}q", f"{ident}q")),
        ]
    return tuple(signs)


_INGENIA_KEYS: tuple[tuple[str, str, str], ...] = (
    (
        "encoding",
        '"notch_parameters"',
        "a biquad of TYPE 5 Notch set by FREQ (Hz) and Q; the TYPE enum is the audio EQ cookbook's set of biquads, so "
        "type 5 is assumed to be its notch: full depth, -3 dB bandwidth FREQ / Q",
    ),
    ("width_unit", '"q"', f"CL_CUR_REF_FILTER1_Q, a float Q-factor ({_INGENIA_XDF})"),
    (
        "depth_unit",
        '"full"',
        "the cookbook notch cuts fully and ignores GAIN (an assumption); GAIN 0x2583, 0x258B is not written",
    ),
    ("scales", "{ center = 1, width = 0 }", f"FREQ UNSIGNED32 in Hz, Q a float ({_INGENIA_XDF}); no range given"),
    (
        "enable",
        '["0x2580", "0x2588"]',
        f"CL_CUR_REF_FILTER1_TYPE, CL_CUR_REF_FILTER2_TYPE, UNSIGNED16 ({_INGENIA_XDF})",
    ),
    ("enable_values", "{ on = 5, off = 0 }", f"TYPE 5 Notch, 0 Disabled, the default ({_INGENIA_XDF})"),
)
_INGENIA_FIELDS: tuple[tuple[str, str, str], ...] = (
    ("center", '["0x2581", "0x2589"]', f"CL_CUR_REF_FILTER1_FREQ, CL_CUR_REF_FILTER2_FREQ ({_INGENIA_XDF})"),
    ("width", '["0x2582", "0x258A"]', f"CL_CUR_REF_FILTER1_Q, CL_CUR_REF_FILTER2_Q ({_INGENIA_XDF})"),
)


#: The documented families, the first that matches wins (Copley's first generation before its plus family: the
#: block's default size tells them apart).
FAMILIES: tuple[FilterFamily, ...] = (
    FilterFamily(
        "Copley Controls, first generation (9-word filter block)",
        (0x000000AB,),
        _COPLEY_VENDOR,
        (ObjectSign(0x2106, 0, (_OCTETS, _DOMAIN), ("filter",), sizes=(18,)),),
        1,
        (
            (
                "filters",
                (
                    ("encoding", '"word_block"', f"one octet string of 16-bit words per filter ({_COPLEY_DICT})"),
                    (
                        "preset",
                        '"copley"',
                        f"9 INT16 words with the scaler K, 18 bytes as the EDS default ({_COPLEY_DICT})",
                    ),
                    ("objects", '["0x2106"]', _COPLEY_OBJECT),
                ),
            ),
        ),
        _COPLEY_DICT,
    ),
    FilterFamily(
        "Copley Controls, plus family (14-word filter block)",
        (0x000000AB,),
        _COPLEY_VENDOR,
        (ObjectSign(0x2106, 0, (_OCTETS, _DOMAIN), ("filter",), sizes=(28, None)),),
        1,
        (
            (
                "filters",
                (
                    ("encoding", '"word_block"', f"one octet string of 16-bit words per filter ({_COPLEY_DICT})"),
                    (
                        "preset",
                        '"copley_plus"',
                        f"14 words, float32 coefficients (Xenus+, AEM, ...; {_COPLEY_DICT}); a first-generation drive "
                        'holds 9 words: preset = "copley"',
                    ),
                    ("objects", '["0x2106"]', _COPLEY_OBJECT),
                ),
            ),
        ),
        _COPLEY_DICT,
    ),
    FilterFamily(
        "Synapticon SOMANET (notch record 0x2023)",
        (0x000022D2,),
        "0x000022D2: Synapticon's vendor ID in public EtherCAT master code (SOMANET drives)",
        (
            ObjectSign(0x2023, 1, (_BOOLEAN, _UINT8), ("enable",)),
            ObjectSign(0x2023, 2, (_UINT16, _UINT32), ("center", "centre")),
            ObjectSign(0x2023, 3, (_UINT16, _UINT32), ("band",)),
        ),
        1,
        (
            (
                "filters",
                (
                    ("encoding", '"center_band"', "centre and rejection band in Hz, full depth (Synapticon, 0x2023)"),
                    ("ranges", "{ center = [10, 2000], band = [1, 4000] }", "UINT16 10-2000 Hz and 1-4000 Hz"),
                    ("objects", '["0x2023"]', "0x2023 Notch filter on the velocity controller's output"),
                    ("fields", "{ center = 2, band = 3 }", "sub 2 Center frequency, sub 3 Rejection band"),
                    ("enable_subindex", "1", "sub 1 Enabled"),
                ),
            ),
        ),
        "Synapticon SOMANET object 0x2023 Notch filter (doc-legacy.synapticon.com, software 4.2)",
    ),
    FilterFamily(
        "Kollmorgen AKD (AR filters in 0x3406, UNSIGNED32)",
        (0x0000006A,),
        _AKD_VENDOR,
        _akd_signs((_UINT32, _INT32)),
        2,
        (
            (
                "filters",
                (
                    ("encoding", '"pole_zero_q"', f"VL.ARPF/ARPQ/ARZF/ARZQ ({_AKD_GUIDE})"),
                    (
                        "scales",
                        "{ pole_hz = 0.001, pole_q = 0.001, zero_hz = 0.001, zero_q = 0.001 }",
                        "1000:1 is the AKD2G's documented CoE scaling, an assumption for the AKD's 0x3406",
                    ),
                    _AKD_RANGES,
                    _AKD_ENABLE,
                ),
            ),
            ("filters.fields", _AKD_FIELDS),
        ),
        _AKD_GUIDE,
    ),
    FilterFamily(
        "Kollmorgen AKD (AR filters in 0x3406, REAL32)",
        (0x0000006A,),
        _AKD_VENDOR,
        _akd_signs((_REAL32,)),
        2,
        (
            (
                "filters",
                (
                    ("encoding", '"pole_zero_q"', f"VL.ARPF/ARPQ/ARZF/ARZQ, float ({_AKD_GUIDE})"),
                    _AKD_RANGES,
                    _AKD_ENABLE,
                ),
            ),
            ("filters.fields", _AKD_FIELDS),
        ),
        _AKD_GUIDE,
    ),
    FilterFamily(
        "Beckhoff AX2000 (bi-quad BQFC, BQFR, BQDC, BQDR, BQMODE at 0x3662-0x3666)",
        (0x00000002,),
        _AX2000_VENDOR,
        (
            *(
                ObjectSign(index, 0, _AX2000_INTEGERS, (name, "bi-quad", "biquad"))
                for index, name, _ in _AX2000_OBJECTS
            ),
            ObjectSign(0x3666, 0, (_INT8, _UINT8, _INT16, _UINT16), ("BQMODE", "bi-quad", "biquad")),
        ),
        1,
        (("filters", _AX2000_KEYS), ("filters.fields", _AX2000_FIELDS)),
        _AX2000_SOURCE,
    ),
    FilterFamily(
        "Ingenia/Novanta Denali, Everest, Summit (current reference filters 1 and 2, 0x2580-0x258B)",
        (0x0000029C,),
        _INGENIA_VENDOR,
        _ingenia_signs(),
        2,
        (("filters", _INGENIA_KEYS), ("filters.fields", _INGENIA_FIELDS)),
        _INGENIA_SOURCE,
    ),
)


@dataclass(frozen=True)
class FilterProposal:
    """A family recognised in an EDS, and how.

    Attributes
    ----------
    family : FilterFamily
    vendor_id : int or None
        The EDS's vendor ID (None: it gives none).
    by_vendor : bool
        The vendor ID is the family's; False: recognised from the objects only.
    """

    family: FilterFamily
    vendor_id: int | None
    by_vendor: bool

    @property
    def how(self) -> str:
        """How the family was recognised, for comments and messages."""
        objects = ", ".join(f"0x{s.index:04X}:{s.subindex}" for s in self.family.signs)
        if self.by_vendor:
            return f"vendor ID 0x{self.vendor_id:08X} and objects {objects}"
        given = "gives no vendor ID" if self.vendor_id is None else f"gives vendor ID 0x{self.vendor_id:08X}"
        return f"objects {objects} only (the EDS {given}, not the family's): confirm the drive is one"


def vendor_id(od, summary: E.EdsSummary) -> int | None:
    """The EDS's vendor ID: [DeviceInfo] VendorNumber, else the default of 0x1018:1 (None: neither, or 0)."""
    if summary.vendor_number:
        return summary.vendor_number
    info = E.object_info(od, 0x1018, 1)
    return info.default if info is not None and isinstance(info.default, int) and info.default else None


def propose_filters(od, summary: E.EdsSummary) -> FilterProposal | None:
    """The ``[filters]`` proposal for the drive an EDS describes, or None when it is of no documented family.

    Parameters
    ----------
    od : canopen.ObjectDictionary
        The EDS.
    summary : EdsSummary
        Its summary (:func:`~hilident.protocol.eds.inspect_eds`).

    Returns
    -------
    FilterProposal or None
        The first family of :data:`FAMILIES` whose objects the EDS has, unless the EDS's vendor ID is another
        documented family's.
    """
    vendor = vendor_id(od, summary)
    known = {v for family in FAMILIES for v in family.vendor_ids}
    for family in FAMILIES:
        if not all(sign.matches(od) for sign in family.signs):
            continue
        if vendor in family.vendor_ids:
            return FilterProposal(family, vendor, by_vendor=True)
        if vendor not in known:
            return FilterProposal(family, vendor, by_vendor=False)
    return None
