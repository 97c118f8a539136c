"""Driver folders of vendor families whose filter objects are documented, written as a user would write them.

Each family is a :class:`~vendor_drives.VendorDrive` whose EDS carries the
family's filter objects as its manual documents them (index, sub-indices,
names, types, ranges, defaults), written here in the project's own words, not
copied from a vendor file; the ``[filters]`` table is the one
``docs/filter_encodings.md`` gives for the family, and the folder's README
cites the public source of every vendor fact and marks every assumption. The
rest of the EDS is the standard CiA 402 drive of :mod:`vendor_drives`.

Sources (the pages cited in each README):

* Copley Controls, Parameter Dictionary p. 75-76 (plus family filter block),
  http://38.142.81.21:8001/manual/copley-controls/serial-encoder/2-user-guide-english/page-76.html
* Synapticon SOMANET, object 0x2023 "Notch filter",
  https://doc-legacy.synapticon.com/software/42/documentation_html/object_htmls/2023/index.html
* Kollmorgen AKD User Guide p. 626-627 (VL.ARZF, VL.ARPQ, VL.ARZQ, CANopen 3406h),
  https://www.easymanua.ls/kollmorgen/akd-series/manual?p=626
* Beckhoff InfoSys, AX2000 ASCII reference (BQMODE, BQFC, BQFR, BQDC, BQDR,
  CANopen 0x3662-0x3666), https://infosys.beckhoff.com/content/1033/ax2000_ascii/
* Ingenia's dictionary den-net-e_2.8.0_v3.xdf (current reference filters,
  registers 0x0580-0x058B, CANopen 0x2580-0x258B),
  https://github.com/ingeniamc/ingenialink-python/blob/master/tests/resources/den-net-e_2.8.0_v3.xdf
  (facts only: the repository's licence, CC BY-NC-ND 4.0, forbids copying it)
"""

from __future__ import annotations

from pathlib import Path

from support.vendor_drives import VendorDrive, write_vendor_drive

_BOOL, _INT8, _INT32, _UINT16, _UINT32, _UINT8, _REAL32, _OCTETS = 0x1, 0x2, 0x4, 0x6, 0x7, 0x5, 0x8, 0xA

COPLEY_PLUS_README = """# copley-plus (fixture)

A Copley Controls plus-family drive (Xenus+, AEM, ...) as the project models it
for its tests. The EDS is written by `tests/support/filter_families.py`; only
its filter objects follow Copley's documentation, the rest is a standard CiA
402 drive.

## From Copley's documentation

* The filter block: 14 words; word 1 bits 13-15 the type (3 band reject, 7
  disabled), bit 8 poles - 1, bit 4 "already designed"; words 2 and 3 the first
  and second frequency in Hz; words 5-14 `a1, a2, b0, b1, b2` as IEEE-754
  float32, upper 16 bits first; `y = b0 x + b1 x[-1] + b2 x[-2] + a1 y[-1] +
  a2 y[-2]`. Copley Parameter Dictionary p. 75-76,
  http://38.142.81.21:8001/manual/copley-controls/serial-encoder/2-user-guide-english/page-76.html
* CANopen objects 0x2106 "Velocity loop output filter coefficients", 0x2108
  "Velocity loop command filter coefficients", 0x2109 "Analog reference input
  filter": OCTET_STRING, read-write, not PDO-mappable (Copley's Accelnet EDS,
  as summarised in the project's notes on vendor filter conventions).

## Assumptions

* Vendor ID 0x000000AB and product code: not from a cited source.
* No DefaultValue for 0x2106 (the drive holds whatever it was given); 0x2108
  defaults to a disabled block.
* The velocity loop, where the output filter runs, at 3 kHz (`[board]
  loop_rate_hz`): not from a cited source; set the drive's own rate.
* Only 0x2106 is described as a slot: it filters the torque command.
"""

SYNAPTICON_README = """# synapticon-somanet (fixture)

A Synapticon SOMANET drive as the project models it for its tests. The EDS is
written by `tests/support/filter_families.py`; only its notch object follows
Synapticon's documentation.

## From Synapticon's documentation

* 0x2023 "Notch filter" on the velocity controller's output (the torque
  demand): sub 1 Enabled (BOOL), sub 2 Center frequency (UINT16, 10-2000 Hz,
  default 100), sub 3 Rejection band (UINT16, 1-4000 Hz, default 1); the filter
  `R = 1 - 3 BW`, `K = (1 - 2R cos 2 pi f + R^2) / (2 - 2 cos 2 pi f)`, f and
  BW relative to the sampling frequency.
  https://doc-legacy.synapticon.com/software/42/documentation_html/object_htmls/2023/index.html

## Assumptions

* Vendor ID 0x000022D2 and product code: not from a cited source.
* The filter's sampling frequency, 4 kHz (`[board] loop_rate_hz`): not from a
  cited source; set the drive's own rate.
* BOOLEAN for sub 1 (the page says BOOL).
"""

KOLLMORGEN_README = """# kollmorgen-akd (fixture)

A Kollmorgen AKD drive's anti-resonance (AR) filters as the project models
them for its tests. The EDS is written by `tests/support/filter_families.py`;
only its filter record follows Kollmorgen's documentation.

## From Kollmorgen's documentation

* `AR(s) = (s^2/(2 pi F_Z)^2 + s/(Q_Z 2 pi F_Z) + 1) / (s^2/(2 pi F_P)^2 +
  s/(Q_P 2 pi F_P) + 1)`; AR1 and AR2 in the forward path; discretised at
  t = 62.5 us (16 kHz). AKD User Guide p. 626-627,
  https://www.easymanua.ls/kollmorgen/akd-series/manual?p=626
* VL.ARZF1-4: 5-5000 Hz, default 500, CANopen 3406h sub 9-0xC; VL.ARPQ1-4:
  0.2-20, default 0.5, 3406h sub 5-8 (same guide, p. 626, and the AKD BASIC
  User Guide p. 451); VL.ARZQ1-4: 0.1-5, default 0.5, 3406h sub 0xD-0x10 (AKD
  BASIC User Guide p. 456).

## Assumptions

* VL.ARPF1-4 at 3406h sub 1-4, 5-5000 Hz, default 500: inferred from the
  sub-index pattern, not documented in the cited pages.
* UNSIGNED32 at 1000:1 for every field: Kollmorgen documents this scaling for
  the AKD2G's CoE objects, not for 3406h of the AKD.
* No enable object: an AR filter always runs what it holds; hilident bypasses
  it by putting its zeros on its poles.
* Vendor ID 0x0000006A and product code: not from a cited source.
"""

BECKHOFF_README = """# beckhoff-ax2000 (fixture)

A Beckhoff AX2000 drive's bi-quad filter as the project models it for its
tests. The EDS is written by `tests/support/filter_families.py`; only its
bi-quad objects follow Beckhoff's documentation.

## From Beckhoff's documentation (InfoSys, AX2000 ASCII reference)

* BQMODE, CANopen 0x3666, Integer8: 0 none, 1 PID-T2 (default), 2 bi-quad,
  3 reserved. https://infosys.beckhoff.com/content/1033/ax2000_ascii/15075191947.html
* BQFC, the centre frequency sqrt(w_AR w_R) in Hz, 20-1000, default 200,
  CANopen 0x3664, Integer32 with weighting 1000 on the bus.
  https://infosys.beckhoff.com/content/1033/ax2000_ascii/15075186827.html
* BQFR = w_R / w_AR, 0.1-10, default 2.5, CANopen 0x3665.
  https://infosys.beckhoff.com/content/1033/ax2000_ascii/15075189387.html
* BQDC, the centre damping, 0.2-1, default 0.3, CANopen 0x3662.
  https://infosys.beckhoff.com/content/1033/ax2000_ascii/15075183755.html
* BQDR, the damping ratio, 0.25-5, default 2.0, CANopen 0x3663.
  https://infosys.beckhoff.com/content/1033/ax2000_ascii/15075185291.html

## Assumptions

* The transfer function: `H(s) = (s^2/w_AR^2 + 2 D_AR s/w_AR + 1) /
  (s^2/w_R^2 + 2 D_R s/w_R + 1)` with `w_AR = 2 pi BQFC / sqrt(BQFR)`,
  `w_R = 2 pi BQFC sqrt(BQFR)`, `D_AR = BQDC / sqrt(BQDR)`, `D_R = BQDC
  sqrt(BQDR)`, discretised by the bilinear transform pre-warped at each
  frequency. Beckhoff documents the parameters, not the filter. A notch then
  has BQFR = 1 and the depth BQDR at its centre: at most 5 (14 dB).
* Integer32 with weighting 1000 for BQFR, BQDC and BQDR too (documented for
  BQFC only); LowLimit/HighLimit are the documented ranges times 1000.
* Vendor ID 0x00000002: Beckhoff's in public EtherCAT master code, not in the
  AX2000 pages; the product code is not from a cited source.
* The bi-quad runs at 4 kHz (`[board] loop_rate_hz`), the velocity loop's rate:
  not from a cited source; set the drive's own rate.
"""

INGENIA_README = """# ingenia-denali (fixture)

An Ingenia/Novanta drive (Denali, Everest, Summit) as the project models it
for its tests. The EDS is written by `tests/support/filter_families.py`; only
its current reference filter objects follow Ingenia's dictionary.

## From Ingenia's dictionary

Source: https://github.com/ingeniamc/ingenialink-python/blob/master/tests/resources/den-net-e_2.8.0_v3.xdf
and `ingenialink/constants.py` of the same repository (CC BY-NC-ND 4.0:
facts only, nothing is copied).

* Current reference filter 1: TYPE register 0x0580 (UNSIGNED16, rw, enum 0
  Disabled, 1 Low pass, 2 High pass, 3 Band pass, 4 Peak, 5 Notch, 6 Low shelf,
  7 High shelf, default 0), FREQ 0x0581 (UNSIGNED32, Hz, default 100), Q 0x0582
  (float, default 0.7071), GAIN 0x0583 (float, dB, default 0); filter 2 at
  0x0588-0x058B. "Indicates the type of filter applied for all current
  set-points".
* A register A of axis 1 is the CANopen object 0x2000 + A, sub-index 0
  (CANOPEN_ADDRESS_OFFSET = 0x2000; the dictionary's CANopenObject entries give
  0x2580 for CL_CUR_REF_FILTER1_TYPE and 0x2588 for CL_CUR_REF_FILTER2_TYPE).
* Vendor ID 0x0000029C: the default of DRV_ID_VENDOR_ID (register 0x06E0).
* The current loop at 20 kHz: the default of CL_CUR_FREQ (register 0x0458).

## Assumptions

* TYPE 5 "Notch" is the audio EQ cookbook's notch (the enum is the cookbook's
  set of biquads): full depth, -3 dB bandwidth FREQ / Q, GAIN ignored; the host
  writes TYPE, FREQ and Q, never GAIN.
* The current reference filters run at the current loop's rate, 20 kHz
  (`[board] loop_rate_hz`).
* The product code is not from a cited source.
"""


def _record(index: int, members: list[tuple]) -> list[tuple]:
    """EDS entries of a record: sub 0, then ``(sub, name, type, default, low, high)`` members."""
    out: list[tuple] = [(index, 0, "Highest sub-index supported", _UINT8, "ro", False, max(m[0] for m in members))]
    for sub, member, dtype, default, *limits in members:
        out.append((index, sub, member, dtype, "rw", False, default, *limits))
    return out


COPLEY_FIRST_README = """# copley-first (fixture)

A first-generation Copley Controls drive (Accelnet, Xenus) as the project
models it for its tests. The EDS is written by
`tests/support/filter_families.py`; only its filter objects follow Copley's
documentation, the rest is a standard CiA 402 drive.

## From Copley's documentation

* The filter block: 9 words `[info, info, info, b2, b1, b0, a2, a1, K]`,
  16-bit coefficients with the unsigned scaler K, `y = K (b0 x + b1 x[-1] +
  b2 x[-2] + a1 y[-1] + a2 y[-2]) / 32768 / 4096`; 0xFFFF in word 1 disables
  the filter. Copley Parameter Dictionary p. 74,
  http://38.142.81.21:8001/manual/copley-controls/serial-encoder/2-user-guide-english/page-74.html
* CANopen objects 0x2106, 0x2108, 0x2109 (velocity loop output, velocity loop
  command, analog reference input filter): OCTET_STRING, read-write, not
  PDO-mappable (Copley's Accelnet EDS).

## Assumptions

* Vendor ID 0x000000AB and product code: not from a cited source.
* Every filter object defaults to a disabled 18-byte block (word 1 0xFFFF).
* The velocity loop, where the output filter runs, at 3 kHz.
"""


def copley_first() -> VendorDrive:
    """Copley first generation: the velocity loop output filter, one 9-word octet string of INT16 coefficients."""
    disabled = bytes.fromhex("FFFF") + bytes(16)  # word 1 0xFFFF: disabled
    return VendorDrive(
        "copley-first",
        vendor="Copley Controls",
        vendor_number=0x000000AB,
        product_number=0x00000100,
        loop_rate_hz=3000.0,
        max_sample_rate_hz=1000.0,
        vendor_objects=[
            (0x2106, None, "Velocity loop output filter coefficients", _OCTETS, "rw", False, disabled),
            (0x2108, None, "Velocity loop command filter coefficients", _OCTETS, "rw", False, disabled),
            (0x2109, None, "Analog reference input filter", _OCTETS, "rw", False, disabled),
        ],
        filter_table=('[filters]\nencoding = "word_block"\npreset = "copley"\nobjects = ["0x2106"]\n'),
        filter_slots=1,
        readme=COPLEY_FIRST_README,
    )


def copley_plus() -> VendorDrive:
    """Copley plus family: the velocity loop output filter, one 14-word octet string (0x2106)."""
    disabled = bytes.fromhex("00E0") + bytes(26)  # word 1 type 7: disabled
    return VendorDrive(
        "copley-plus",
        vendor="Copley Controls",
        vendor_number=0x000000AB,
        product_number=0x00000110,
        loop_rate_hz=3000.0,
        max_sample_rate_hz=1000.0,
        vendor_objects=[
            (0x2106, None, "Velocity loop output filter coefficients", _OCTETS, "rw", False, None),
            (0x2108, None, "Velocity loop command filter coefficients", _OCTETS, "rw", False, disabled),
            (0x2109, None, "Analog reference input filter", _OCTETS, "rw", False, disabled),
        ],
        filter_table=('[filters]\nencoding = "word_block"\npreset = "copley_plus"\nobjects = ["0x2106"]\n'),
        filter_slots=1,
        readme=COPLEY_PLUS_README,
    )


def synapticon() -> VendorDrive:
    """Synapticon SOMANET: one notch record 0x2023 (enabled, centre, rejection band)."""
    return VendorDrive(
        "synapticon-somanet",
        vendor="Synapticon",
        vendor_number=0x000022D2,
        product_number=0x00000201,
        loop_rate_hz=4000.0,
        max_sample_rate_hz=1000.0,
        vendor_objects=_record(
            0x2023,
            [
                (1, "Enabled", _BOOL, 0),
                (2, "Center frequency", _UINT16, 100, 10, 2000),
                (3, "Rejection band", _UINT16, 1, 1, 4000),
            ],
        ),
        filter_table=(
            '[filters]\nencoding = "center_band"\nranges = { center = [10, 2000], band = [1, 4000] }\n'
            'objects = ["0x2023"]\nfields = { center = 2, band = 3 }\nenable_subindex = 1\n'
        ),
        filter_slots=1,
        readme=SYNAPTICON_README,
    )


def kollmorgen_akd() -> VendorDrive:
    """Kollmorgen AKD: the AR filters' fields in one record 0x3406, a sub-index per field and filter number."""
    groups = [("ARPF", 1, 500_000, 5_000, 5_000_000), ("ARPQ", 5, 500, 200, 20_000)]
    groups += [("ARZF", 9, 500_000, 5_000, 5_000_000), ("ARZQ", 0xD, 500, 100, 5_000)]
    members = [
        (first + n, f"VL.{name}{n + 1}", _UINT32, default, lo, hi)
        for name, first, default, lo, hi in groups
        for n in range(4)
    ]
    return VendorDrive(
        "kollmorgen-akd",
        vendor="Kollmorgen",
        vendor_number=0x0000006A,
        product_number=0x00414B44,
        loop_rate_hz=16000.0,
        max_sample_rate_hz=1000.0,
        vendor_objects=_record(0x3406, members),
        filter_table=(
            '[filters]\nencoding = "pole_zero_q"  # VL.ARPF/ARPQ/ARZF/ARZQ, 1000:1\n'
            "scales = { pole_hz = 0.001, pole_q = 0.001, zero_hz = 0.001, zero_q = 0.001 }\n"
            "ranges = { pole_hz = [5, 5000], zero_hz = [5, 5000], pole_q = [0.2, 20], zero_q = [0.1, 5] }\n"
            'enable = "none"                # an AR filter runs what it holds\n'
            "[filters.fields]                # AR1, AR2: the forward path\n"
            'pole_hz = ["0x3406:1", "0x3406:2"]\n'
            'pole_q = ["0x3406:5", "0x3406:6"]\n'
            'zero_hz = ["0x3406:9", "0x3406:0xA"]\n'
            'zero_q = ["0x3406:0xD", "0x3406:0xE"]\n'
        ),
        filter_slots=2,
        readme=KOLLMORGEN_README,
    )


def beckhoff_ax2000() -> VendorDrive:
    """Beckhoff AX2000: one bi-quad, an Integer32 object per parameter (weighting 1000) and BQMODE as its enable."""
    parameters = [
        (0x3662, "BQDC bi-quad centre damping", 300, 200, 1000),
        (0x3663, "BQDR bi-quad damping ratio", 2000, 250, 5000),
        (0x3664, "BQFC bi-quad centre frequency", 200_000, 20_000, 1_000_000),
        (0x3665, "BQFR bi-quad frequency ratio", 2500, 100, 10_000),
    ]
    objects = [(index, None, name, _INT32, "rw", False, default, lo, hi) for index, name, default, lo, hi in parameters]
    objects.append((0x3666, None, "BQMODE bi-quad mode", _INT8, "rw", False, 1, 0, 3))
    return VendorDrive(
        "beckhoff-ax2000",
        vendor="Beckhoff Automation",
        vendor_number=0x00000002,
        product_number=0x000007D0,
        loop_rate_hz=4000.0,
        max_sample_rate_hz=1000.0,
        vendor_objects=objects,
        filter_table=(
            '[filters]\nencoding = "center_ratio_damping"  # BQFC, BQFR, BQDC, BQDR\n'
            "scales = { center_hz = 0.001, ratio = 0.001, center_damping = 0.001, damping_ratio = 0.001 }\n"
            "ranges = { center_hz = [20, 1000], ratio = [0.1, 10], center_damping = [0.2, 1], "
            "damping_ratio = [0.25, 5] }\n"
            'enable = ["0x3666"]                  # BQMODE\n'
            "enable_values = { on = 2, off = 0 }  # 2 bi-quad, 0 none\n"
            "[filters.fields]\n"
            'center_hz = ["0x3664"]\n'
            'ratio = ["0x3665"]\n'
            'center_damping = ["0x3662"]\n'
            'damping_ratio = ["0x3663"]\n'
        ),
        filter_slots=1,
        readme=BECKHOFF_README,
    )


def ingenia_denali() -> VendorDrive:
    """Ingenia/Novanta: the current reference filters 1 and 2, a plain object per register (TYPE, FREQ, Q, GAIN)."""
    objects = []
    for n, base in ((1, 0x2580), (2, 0x2588)):
        objects += [
            (base, None, f"Current reference filter {n} type", _UINT16, "rw", False, 0),
            (base + 1, None, f"Current reference filter {n} frequency", _UINT32, "rw", False, 100),
            (base + 2, None, f"Current reference filter {n} Q-factor", _REAL32, "rw", False, 0.7071),
            (base + 3, None, f"Current reference filter {n} gain", _REAL32, "rw", False, 0.0),
        ]
    return VendorDrive(
        "ingenia-denali",
        vendor="Novanta (Ingenia)",
        vendor_number=0x0000029C,
        product_number=0x00000100,
        loop_rate_hz=20000.0,
        max_sample_rate_hz=1000.0,
        vendor_objects=objects,
        filter_table=(
            '[filters]\nencoding = "notch_parameters"  # TYPE 5 Notch: FREQ and Q\n'
            'width_unit = "q"\n'
            'depth_unit = "full"                 # a full cut; GAIN is not written\n'
            "scales = { center = 1, width = 0 }  # FREQ UNSIGNED32 Hz, Q REAL32\n"
            'enable = ["0x2580", "0x2588"]       # TYPE\n'
            "enable_values = { on = 5, off = 0 }  # 5 Notch, 0 Disabled\n"
            "[filters.fields]                     # current reference filters 1 and 2\n"
            'center = ["0x2581", "0x2589"]\n'
            'width = ["0x2582", "0x258A"]\n'
        ),
        filter_slots=2,
        readme=INGENIA_README,
    )


#: The documented families, by the name of their driver folder.
FAMILIES = {
    d.name: d
    for d in (copley_first(), copley_plus(), synapticon(), kollmorgen_akd(), beckhoff_ax2000(), ingenia_denali())
}


def family_folder(tmp_path: Path, drive: VendorDrive, old: str = "", new: str = "") -> Path:
    """``drive``'s folder written under ``tmp_path``, with the first ``old`` of its driver.toml made ``new``."""
    folder = write_vendor_drive(tmp_path, drive)
    if old:
        path = folder / "driver.toml"
        text = path.read_text()
        assert old in text, old
        path.write_text(text.replace(old, new, 1))
    return folder
