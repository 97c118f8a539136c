"""Notches into a device's filter slots: the upload step of ``hilident run`` and the ``hilident upload`` command.

Both go through the same two steps:

* :func:`upload_design` writes one notch into its slot disabled, reads it
  back, compares it with what the device should hold after its own rounding
  (``adapter.stored_form``) and enables it only when the two are equal
  (:meth:`~hilident.adapters.base.AdapterBase.upload_filter`); what the
  stored coefficients really do (attenuation at the designed centre, where
  the minimum lies) is computed from them (:func:`hilident.pipeline.verification.achieved_notch`);
* :func:`store_parameters` has the device store its parameters in
  non-volatile memory, where the transport has such a command.

``hilident upload --from RUN_DIR|summary.json --config CONFIG`` (:func:`upload_from`)
takes the notches of an earlier ``run`` or ``identify`` and uploads them to
the device of ``CONFIG``. Unlike a run, which keeps a verified slot when
another one fails, the command is all or nothing: on any failure (a read-back
that differs, a lost line, a signal) every slot it touched is put back as it
was, and the error ends the command with a partial ``summary.json``.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hilident import endings, html_report
from hilident.errors import (
    ArmingRefused,
    ConfigError,
    DataError,
    DeviceError,
    HilidentError,
    UsageError,
)
from hilident.io.serialise import write_json
from hilident.io.summary import DevicePart, Summary, UploadOutcome
from hilident.progress import Progress
from hilident.session.connection import DeviceConnection

#: Attenuation lost to the device's rounding (design minus achieved at the centre) above which the run warns, dB.
ROUNDING_WARNING_DB = 3.0


# --- the shared step ------------------------------------------------------------------------------


def upload_design(adapter, design, warnings: list[str]) -> dict:
    """Write ``design`` (a :class:`~hilident.pipeline.notches.NotchDesign`) into its slot, read back, enable on a match.

    A slot whose read-back differs from the device's expected stored form is
    put back as it was (by ``adapter.upload_filter``) and a warning says so.

    Parameters
    ----------
    adapter : AdapterBase
        An open device.
    design : NotchDesign
        The notch, its slot and the filter rate it was designed at (the device's loop rate), Hz.
    warnings : list of str
        Appended to: a mismatch, what the drive's encoding could not meet, a notch moved by rounding.

    Returns
    -------
    dict
        ``slot``, ``readback_b``, ``readback_a``, ``matches`` and ``achieved``
        (:func:`hilident.pipeline.verification.achieved_notch` of the stored section against the planned one:
        the attenuation at the designed centre, what the device's quantisation allows, the difference),
        plus ``expected_b``/``expected_a`` in the private key ``_expected``.
    """
    from hilident.pipeline.verification import achieved_notch

    d = design
    up = adapter.upload_filter(d.slot, d.biquad, d.spec)
    stored, expected, same = up.stored, up.expected, up.matches
    if not same:
        warnings.append(
            f"filter slot {d.slot}: read-back {stored} differs from written {expected}; "
            "the slot's previous contents were restored"
        )
    notes = getattr(adapter, "filter_notes", None)  # drives whose encoding fits the notch to what it can store
    notes = list(notes(d.spec)) if notes is not None else []
    warnings += [f"filter slot {d.slot}: {note}" for note in notes]
    achieved = achieved_notch(d, stored, planned=expected)
    if achieved["quantisation_loss_db"] > ROUNDING_WARNING_DB and not notes:  # notes already say why
        warnings.append(
            f"filter slot {d.slot}: the device's coefficient rounding moves the {d.spec.center_hz:.4g} Hz notch "
            f"to {achieved['center_hz']:.4g} Hz; it attenuates only "
            f"{achieved['realisable_db']:.1f} dB at the resonance "
            f"(designed {d.spec.depth_db:g} dB; notches far below the {d.sample_rate_hz:g} Hz filter rate suffer)"
        )
    return {
        "slot": d.slot,
        "readback_b": list(stored.b),
        "readback_a": list(stored.a),
        "matches": same,
        "achieved": achieved,
        "_expected": expected,
    }


def upload_designs(adapter, designs: list, warnings: list[str], upload: UploadOutcome) -> UploadOutcome:
    """The upload step of a run: every design through :func:`upload_design`; fills and returns ``upload``.

    ``upload.slots`` gets one record per design; ``written`` becomes True
    and ``verified_readback`` says whether every slot read back as written.
    A slot that did not is back as it was; the others keep their new notch.
    """
    matches = []
    for d in designs:
        record = upload_design(adapter, d, warnings)
        record.pop("_expected")
        matches.append(record["matches"])
        upload.slots.append(record)
    upload.written = True
    upload.verified_readback = all(matches)
    return upload


def store_parameters(adapter, transport: str, progress=None) -> tuple[str | None, str | None]:
    """Have the device store its parameters in non-volatile memory (``progress.step`` says so first).

    Returns
    -------
    (saved_with, reason) : (str or None, str or None)
        What was written to store them (``adapter.save_parameters()``), or
        None and why not (the transport has no such command in hilident).
    """
    store = getattr(adapter, "save_parameters", None)  # transports whose devices can store parameters
    if store is None:
        return None, f"a {transport} device has no store-parameters command in hilident"
    if progress is not None:
        progress.step("saving the device's parameters to non-volatile memory")
    return store(), None


# --- hilident upload: the notches of an earlier run or identify ------------------------------------

#: Keys every record of ``notch_filters`` must hold to be uploaded.
_NOTCH_KEYS = ("center_hz", "width_hz", "depth_db", "sample_rate_hz", "b", "a")
#: Relative difference of two filter rates that counts as the same rate.
_RATE_TOLERANCE = 1e-6


@dataclass
class Source:
    """The ``summary.json`` notches come from.

    Attributes
    ----------
    path : Path
        The ``summary.json`` file.
    folder : Path
        The run (or identify) folder it lies in.
    summary : dict
        Its contents.
    kind : str
        ``"identify"`` (it has a ``data`` key) or ``"run"``.
    """

    path: Path
    folder: Path
    summary: dict
    kind: str


def read_source(source: str | Path) -> Source:
    """The summary of a run or identify folder, or a ``summary.json`` given directly.

    Raises
    ------
    DataError
        No such file or folder, no ``summary.json`` in the folder, not JSON,
        or not a summary (naming the file).
    """
    path = Path(source).absolute()
    if path.is_dir():
        path = path / "summary.json"
        if not path.is_file():
            raise DataError(f"--from {source}: the folder holds no summary.json (give a run or identify folder)")
    elif not path.is_file():
        raise DataError(f"--from {source}: no such file or folder")
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise DataError(f"{path}: cannot be read as a summary.json: {exc}") from None
    if not isinstance(summary, dict) or "notch_filters" not in summary:
        raise DataError(f"{path}: not the summary.json of a hilident run or identify (no key notch_filters)")
    return Source(path, path.parent, summary, "identify" if "data" in summary else "run")


def one_node(src: Source, cfg) -> Source:
    """The source as one drive's: a run of several nodes (notches carrying their ``node``) gives the notches of
    ``[device.canopen] node_id``, the drive the upload writes.

    Raises
    ------
    ConfigError
        The config names several nodes (``device.canopen.node_ids``): an upload writes one drive.
    DataError
        The source's notches are of other nodes only.
    """
    from hilident.config.tables import node_ids

    if len(node_ids(cfg.device)) > 1:
        raise ConfigError(
            "device.canopen.node_ids",
            "hilident upload writes the notches of one drive: leave node_ids out and set node_id to the drive to "
            "write (a run of several nodes uploads every drive's own notches itself)",
            cfg.source,
        )
    records = src.summary.get("notch_filters")
    if not isinstance(records, list) or not any(isinstance(r, dict) and "node" in r for r in records):
        return src
    node = cfg.device.canopen.node_id
    mine = [r for r in records if isinstance(r, dict) and r.get("node") == node]
    if not mine:
        nodes = sorted({r.get("node") for r in records if isinstance(r, dict)}, key=str)
        raise DataError(
            f"{src.path}: notch_filters holds the notches of node(s) {', '.join(map(str, nodes))} (a run of several "
            f"nodes), none of node {node} (device.canopen.node_id in {cfg.source})"
        )
    return Source(src.path, src.folder, {**src.summary, "notch_filters": mine}, src.kind)


def _no_notch_reason(summary: dict) -> str:
    """Why the source designed no notch, as it says itself."""
    reason = summary.get("notch_skipped_reason") or (summary.get("upload") or {}).get("skipped_reason")
    return f": {reason}" if reason else ""


def notch_records(src: Source) -> list[dict]:
    """The source's ``notch_filters``, each checked; DataError naming the file and the key otherwise."""
    records = src.summary.get("notch_filters")
    if not isinstance(records, list):
        raise DataError(f"{src.path}: notch_filters must be a list")
    if not records:
        raise DataError(
            f"{src.path}: notch_filters is empty, the {src.kind} designed no notch to upload"
            + _no_notch_reason(src.summary)
        )
    for i, rec in enumerate(records):
        if not isinstance(rec, dict):
            raise DataError(f"{src.path}: notch_filters[{i}] is not a record")
        for key in _NOTCH_KEYS:
            value = rec.get(key)
            values = value if key in ("b", "a") else [value]
            ok = (
                isinstance(values, list)
                and len(values) == (3 if key in ("b", "a") else 1)
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)
            )
            if key == "depth_db" and isinstance(value, (int, float)) and value == math.inf:
                ok = True
            if not ok:
                raise DataError(
                    f"{src.path}: notch_filters[{i}].{key} is missing or not "
                    + ("three finite numbers" if key in ("b", "a") else "a finite number")
                    + f" (got {value!r})"
                )
    return records


def _resonance_for(src: Source, rec: dict, index: int):
    """The resonance of ``summary["resonances"]`` a notch was designed for (its centre is the resonance's frequency)."""
    from hilident.ident.resonance import Resonance

    found = [
        r
        for r in src.summary.get("resonances") or []
        if isinstance(r, dict)
        and isinstance(r.get("frequency_hz"), (int, float))
        and isinstance(r.get("damping_ratio"), (int, float))
    ]
    if not found:
        raise DataError(
            f"{src.path}: notch_filters[{index}] must be redesigned for the device's filter rate, but "
            "resonances holds no frequency_hz and damping_ratio to design it from"
        )
    r = min(found, key=lambda r: abs(r["frequency_hz"] - rec["center_hz"]))
    if abs(r["frequency_hz"] - rec["center_hz"]) > 1e-6 * rec["center_hz"]:
        raise DataError(
            f"{src.path}: notch_filters[{index}] ({rec['center_hz']:.6g} Hz) matches no entry of "
            "resonances, so it cannot be redesigned for the device's filter rate"
        )

    def number(key: str) -> float:
        return float(r[key]) if isinstance(r.get(key), (int, float)) else float("nan")

    return Resonance(
        float(r["frequency_hz"]),
        float(r["damping_ratio"]),
        number("peak_magnitude_db"),
        number("coherence"),
        frequency_ci95_hz=number("frequency_ci95_hz"),
        damping_ci95=number("damping_ci95"),
    )


def designs_for_device(src: Source, cfg, loop_rate_hz: float, slots: list[int], warnings: list[str]) -> list:
    """The source's notches as :class:`~hilident.pipeline.notches.NotchDesign` for slots ``slots`` at the device's rate.

    A notch designed at the device's filter rate is taken as designed (its
    coefficients); one designed for another rate is designed again from its
    resonance (centre, damping, ``cfg.notch``'s width rule and depth) at
    ``loop_rate_hz``, and a warning says so.
    """
    from hilident.filters.biquad import Biquad
    from hilident.filters.notch import NotchSpec
    from hilident.pipeline.notches import NotchDesign, design_notches

    designs = []
    for i, (rec, slot) in enumerate(zip(notch_records(src), slots, strict=False)):
        rate = float(rec["sample_rate_hz"])
        if abs(rate - loop_rate_hz) <= _RATE_TOLERANCE * loop_rate_hz:
            spec = NotchSpec(float(rec["center_hz"]), float(rec["width_hz"]), float(rec["depth_db"]))
            try:
                biquad = Biquad.from_sequences(rec["b"], rec["a"])
            except ValueError as exc:
                raise DataError(f"{src.path}: notch_filters[{i}].a: {exc}") from None
            try:
                res = _resonance_for(src, rec, i)
            except DataError:
                res = None  # not needed: the coefficients are taken as designed
            designs.append(
                NotchDesign(
                    spec, biquad, slot, loop_rate_hz, res, float(rec.get("predicted_band_reduction_db", float("nan")))
                )
            )
            continue
        res = _resonance_for(src, rec, i)
        (d,) = design_notches([res], cfg.notch, loop_rate_hz, [slot])
        warnings.append(
            f"notch at {rec['center_hz']:.4g} Hz: designed for a {rate:g} Hz filter rate in {src.path}, "
            f"the device filters at {loop_rate_hz:g} Hz: designed again from its resonance "
            f"({res.frequency_hz:.4g} Hz, zeta {res.damping_ratio:.3g}) with [notch] of the configuration: "
            f"{d.spec.width_hz:.3g} Hz wide, {d.spec.depth_db:g} dB deep"
        )
        if d.warning:
            warnings.append(d.warning)
        designs.append(d)
    return designs


def default_out(src: Source) -> Path:
    """A new folder beside the source run: ``<run>-upload``, then ``<run>-upload-2``, ... (never the source)."""
    base = src.folder.resolve()
    for n in range(1, 10_000):
        out = base.with_name(f"{base.name}-upload" + (f"-{n}" if n > 1 else ""))
        if not out.exists():
            return out
    raise UsageError(f"--out: give an output folder ({base.name}-upload-* are all taken)")


def slots_for(count: int, first: int | None, designed: list[object], filter_slots: int, driver_name: str) -> list[int]:
    """The slots the ``count`` notches go to: ``--slot N`` and the ones after it, else the slots they were designed for.

    Raises
    ------
    UsageError
        Naming ``--slot`` (or the source's slots) and how many slots the device has.
    """
    if first is not None:
        if first < 0 or first + count > filter_slots:
            raise UsageError(
                f"--slot {first}: {count} notch(es) from slot {first} do not fit the "
                f"{filter_slots} filter slot(s) of {driver_name} (slots 0 to {filter_slots - 1})"
            )
        return list(range(first, first + count))
    whole = [s for s in designed if isinstance(s, int) and not isinstance(s, bool)]
    if len(whole) == len(designed) and len(set(whole)) == count and all(0 <= s < filter_slots for s in whole):
        return whole
    if count > filter_slots:
        raise UsageError(
            f"the source has {count} notches but {driver_name} has {filter_slots} filter slot(s): "
            "upload them one by one with --slot"
        )
    return list(range(count))


@dataclass
class UploadPlan:
    """What ``hilident upload`` will write: shown before the go-ahead on a real port, and by ``--dry-run``."""

    driver: str
    port: str
    source: Path
    rows: list[dict] = field(default_factory=list)
    save: bool = False

    def describe(self) -> str:
        lines = [f"upload plan for {self.driver} on {self.port} (notches of {self.source}); nothing moves:"]
        for r in self.rows:
            now = "enabled" if r["before"]["enabled"] else "disabled"
            lines.append(
                f"  slot {r['slot']} (now {now}): notch {r['center_hz']:.5g} Hz, {r['width_hz']:.4g} Hz wide, "
                f"{r['depth_db']:.4g} dB deep"
            )
            if r.get("parameters"):
                lines.append(
                    "    the drive's parameters will be "
                    + ", ".join(f"{p['parameter'] or p['register']} = {p['value']}" for p in r["parameters"].values())
                )
            lines.append(
                f"    the device will hold b = {_coeffs(r['expected_b'])}, a = {_coeffs(r['expected_a'])}: "
                f"{r['achieved']['attenuation_at_design_center_db']:.1f} dB at {r['center_hz']:.5g} Hz "
                f"({r['achieved']['depth_error_db']:+.2f} dB from the design: its quantisation), deepest at "
                f"{r['achieved']['center_hz']:.5g} Hz"
            )
        lines.append(
            "  each slot written disabled, read back, enabled only when equal; any failure puts every slot "
            "back as it was" + ("; then the parameters are stored in non-volatile memory (--save)" if self.save else "")
        )
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {
            "driver": self.driver,
            "port": self.port,
            "source": str(self.source),
            "slots": self.rows,
            "save": self.save,
        }


def _coeffs(values) -> str:
    return "[" + ", ".join(f"{float(v):.9g}" for v in values) + "]"


def _parameters_of(adapter, slot: int) -> dict:
    """``{"parameters": ...}`` of a drive whose slots are its notch parameters (each field's parameter code,
    address and stored integer), else nothing."""
    if getattr(adapter, "parameter_slots", False):
        return {"parameters": adapter.filter_parameters(slot)["fields"]}
    return {}


def _planned_parameters_of(adapter, slot: int, spec) -> dict:
    """``{"parameters": ...}`` a parameter drive's ``slot`` will hold for ``spec``, else nothing."""
    if getattr(adapter, "parameter_slots", False):
        return {"parameters": adapter.planned_parameters(slot, spec)}
    return {}


class UploadCommand:
    """``hilident upload``: the notches of an earlier run or identify, into the device of a configuration.

    Parameters
    ----------
    cfg : Config
        The device (``[device]``, ``[emulator]`` for the twin) and ``[notch]`` (for a redesign).
    source : path
        A run or identify folder, or its ``summary.json``.
    out_dir : path or None
        Where ``summary.json`` goes (default :func:`default_out`); never the source's folder.
    progress : Progress, optional
    confirm : callable, optional
        ``confirm(plan) -> bool``: the go-ahead on a real port (as ``hilident run`` asks for it).
    slot : int, optional
        First slot (``--slot``); default the slots the notches were designed for.
    save : bool
        Store the parameters in non-volatile memory once every slot read back as written.
    dry_run : bool
        Connect, read the slots, show the plan; write nothing to the device or the disk.
    """

    def __init__(
        self,
        cfg,
        source: str | Path,
        out_dir: str | Path | None = None,
        progress=None,
        confirm: Callable | None = None,
        slot: int | None = None,
        save: bool = False,
        dry_run: bool = False,
    ):
        self.cfg = cfg
        self.source = one_node(read_source(source), cfg)
        notch_records(self.source)  # no notch: refused before anything is opened
        self.out = Path(out_dir) if out_dir else default_out(self.source)
        if self.out.resolve() == self.source.folder.resolve():
            raise UsageError(f"--out {out_dir}: that is the source's folder; its summary.json is never overwritten")
        self.progress = progress or Progress(enabled=False)
        self.confirm = confirm
        self.first_slot = slot
        self.save = save
        self.dry_run = dry_run
        self.warnings: list[str] = []
        self.device = _Device(cfg, self.progress, self.warnings)
        self.plan: UploadPlan | None = None
        self.summary: dict = {}
        self._created_out = False  # the command made --out (removed again when it ends before writing anything)

    def run(self) -> dict:
        """Connect, plan, ask, upload with rollback, store; returns the summary (also in ``<out>/summary.json``).

        With ``dry_run`` returns ``{"dry_run": True, "plan": ...}`` and writes nothing.

        Raises
        ------
        DeviceError
            A slot did not read back as written, or the device failed: every
            slot touched is back as it was, and ``summary.json`` says so
            (``failed_step``, ``error``).
        """
        started = time.monotonic()
        if not self.dry_run:
            self._prepare_out()
        dev = self.device
        state: dict[str, Any] = {
            "before": [],
            "designs": [],
            "slots": [],
            "rolled_back": [],
            "saved": False,
            "step": "connect",
            "touched": [],
        }
        failed = False
        try:
            dev.find_driver()
            dev.open_device()
            state["step"] = "plan"
            designs = self._designs()
            state["designs"] = designs
            state["before"] = self._read_slots()
            plan = self.plan = self._plan(designs, state["before"])
            if self.dry_run:
                return {"dry_run": True, "plan": plan.to_dict(), "warnings": self.warnings}
            self._arm(plan)
            state["step"] = "upload"
            self._upload(designs, state)
            if self.save:
                state["step"] = "save"
                saved_with, _ = store_parameters(dev.adapter, dev.found_driver.transport, self.progress)
                state.update(saved=True, saved_with=saved_with)
        except BaseException as exc:
            failed = True
            with endings.shielded():
                dev.safe_stop()
                if state["touched"] and not state["rolled_back"]:
                    self._roll_back(state)
                if state["step"] in ("upload", "save") and isinstance(exc, (HilidentError, KeyboardInterrupt)):
                    # what was on the device, what was written and what was put back: the partial summary
                    self._write(state, started, failed_step=state["step"], error=str(exc) or type(exc).__name__)
            raise
        finally:
            with endings.shielded():
                dev.close()
                if failed and self._created_out and not self.summary and not any(self.out.iterdir()):
                    self.out.rmdir()  # refused before anything was written: no empty folder left behind
        endings.raise_pending()
        return self._write(state, started)

    # --- steps ------------------------------------------------------------------------------------

    def _prepare_out(self) -> None:
        """The output folder takes files, or a one-line error before the device is opened."""
        self._created_out = not self.out.exists()
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            probe = self.out / ".hilident-write-test"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise UsageError(f"--out {self.out}: cannot write there: {exc.strerror or exc}") from None

    def _designs(self) -> list:
        dev = self.device
        ident, driver = dev.adapter.identity, dev.found_driver
        driver_toml = driver.folder / "driver.toml"
        if ident.filter_slots < 1:
            raise ConfigError(
                "filters",
                f"driver {driver.name!r} describes no filter capability (no [filters] "
                "table): there is no slot to upload a notch to",
                str(driver_toml),
            )
        if self.save and getattr(dev.adapter, "save_parameters", None) is None:
            raise UsageError(
                f"--save: a {driver.transport} device has no store-parameters command in hilident "
                "(upload without --save)"
            )
        records = notch_records(self.source)
        slots = slots_for(
            len(records), self.first_slot, [r.get("slot") for r in records], ident.filter_slots, dev.found_driver.name
        )
        return designs_for_device(self.source, self.cfg, float(ident.loop_rate_hz), slots, self.warnings)

    def _read_slots(self) -> list[dict]:
        """What every slot holds now (enabled, the biquad it applies), and its raw contents for a rollback."""
        ad = self.device.adapter
        out = []
        for slot in range(ad.identity.filter_slots):
            biquad, enabled = ad.read_filter(slot)
            out.append(
                {
                    "slot": slot,
                    "enabled": bool(enabled),
                    "b": [float(x) for x in biquad.b],
                    "a": [float(x) for x in biquad.a],
                    "_saved": ad.save_filter(slot),
                    **_parameters_of(ad, slot),
                }
            )
        return out

    def _plan(self, designs: list, before: list[dict]) -> UploadPlan:
        from hilident.pipeline.verification import achieved_notch

        ad = self.device.adapter
        plan = UploadPlan(self.device.found_driver.name, ad.port, self.source.path, save=self.save)
        for d in designs:
            expected = ad.stored_form(d.biquad, d.spec)
            was = before[d.slot]
            plan.rows.append(
                {
                    "slot": d.slot,
                    "center_hz": d.spec.center_hz,
                    "width_hz": d.spec.width_hz,
                    "depth_db": d.spec.depth_db,
                    "expected_b": list(expected.b),
                    "expected_a": list(expected.a),
                    "achieved": achieved_notch(d, expected, planned=expected),
                    "before": {"enabled": was["enabled"], "b": was["b"], "a": was["a"]},
                    **_planned_parameters_of(ad, d.slot, d.spec),
                }
            )
        return plan

    def _arm(self, plan: UploadPlan) -> None:
        """On a real port, write only with the go-ahead ``hilident run`` asks for (``--yes`` or the terminal)."""
        if self.cfg.uses_emulator:
            return
        if self.confirm is None or not self.confirm(plan):
            raise ArmingRefused("the upload was not confirmed; nothing was written")

    def _upload(self, designs: list, state: dict) -> None:
        """Every notch through :func:`upload_design`; the first mismatch ends it (the caller rolls back)."""
        self.progress.step(f"notch: uploading {len(designs)} filter(s)")
        for d in designs:
            state["touched"].append(d.slot)  # from here a failure puts this slot back too
            record = upload_design(self.device.adapter, d, self.warnings)
            expected = record.pop("_expected")
            record.update(
                expected_b=list(expected.b), expected_a=list(expected.a), **_parameters_of(self.device.adapter, d.slot)
            )
            state["slots"].append(record)
            if not record["matches"]:
                raise DeviceError(
                    f"{self.device.adapter.port}: filter slot {d.slot} read back "
                    f"b = {_coeffs(record['readback_b'])}, a = {_coeffs(record['readback_a'])}, not "
                    f"the b = {_coeffs(record['expected_b'])}, a = {_coeffs(record['expected_a'])} "
                    "written: every slot was put back as it was"
                )
            self.progress.step(f"  slot {d.slot}: read back as written, enabled")

    def _roll_back(self, state: dict) -> None:
        """Put every slot the upload touched back as it was (never raises; what fails becomes a warning)."""
        ad = self.device.adapter
        for slot in state["touched"]:
            try:
                ad.restore_filter(slot, state["before"][slot]["_saved"])
                biquad, enabled = ad.read_filter(slot)
                was = state["before"][slot]
                back = bool(enabled) == was["enabled"] and list(biquad.b) == was["b"] and list(biquad.a) == was["a"]
                state["rolled_back"].append({"slot": slot, "restored": bool(back)})
                if not back:
                    self.warnings.append(f"filter slot {slot}: put back, but it reads back otherwise than before")
            except Exception as exc:  # the line may be gone: say so, keep going with the others
                state["rolled_back"].append({"slot": slot, "restored": False, "error": str(exc)})
                self.warnings.append(f"filter slot {slot}: could not put back its previous contents: {exc}")

    def _write(self, state: dict, started: float, **failure) -> dict:

        dev = self.device
        ad = dev.adapter
        slots = state["slots"]
        written = bool(slots)
        verified = written and all(s["matches"] for s in slots) and len(slots) == len(state["designs"])
        upload = UploadOutcome(
            written and not state["rolled_back"],
            verified,
            slots,
            rolled_back=state["rolled_back"],
            saved=state["saved"],
            saved_with=state.get("saved_with"),
        )
        result = Summary.of_upload(
            config=self.cfg.source,
            source={
                "summary": str(self.source.path),
                "kind": self.source.kind,
                "notch_filters": self.source.summary.get("notch_filters"),
            },
            device=DevicePart.reported(
                dev.found_driver.name if dev.driver else None,
                ad.port if ad else None,
                self.cfg.uses_emulator,
                ad.identity if ad is not None else None,
            ),
            filters_before=[{k: v for k, v in b.items() if k != "_saved"} for b in state["before"]],
            designs=state["designs"],
            upload=upload,
            elapsed_s=time.monotonic() - started,
            warnings=self.warnings,
        )
        if failure:
            result.failed(failure["failed_step"], failure["error"])
        summary = result.to_dict()
        self._plot_notches(summary)
        write_json(self.out / "summary.json", summary)
        self.summary = summary
        html_report.write_report_quietly(self.out)
        return summary

    def _plot_notches(self, summary: dict) -> None:
        """``notch.png``: the chain as designed and as read back; a plot that fails is a warning of the summary,
        never a failed upload (the device holds what the summary says either way)."""
        if not summary.get("notch_filters"):
            return
        from hilident.plots.notches import plot_notches

        try:
            plot_notches(self.out / "notch.png", summary)
        except Exception as exc:  # the summary is written whatever the plot does
            summary["warnings"] = [*summary.get("warnings", []), f"plots: {self.out / 'notch.png'} not written: {exc}"]


class _Device(DeviceConnection):
    """The device of the configuration, opened as ``hilident run`` opens it (no limits loaded: nothing moves)."""

    def __init__(self, cfg, progress, warnings: list[str]):
        self.cfg, self.progress, self.warnings = cfg, progress, warnings

    def find_driver(self) -> None:
        """The driver, refused on a real port while it holds guessed values (as for ``hilident run``)."""
        from hilident.drivers.description import DESCRIPTION_FILE, find_driver

        d = find_driver(self.cfg.device.driver, self.cfg.device.driver_paths)
        if d.placeholders and not self.cfg.uses_emulator:
            raise ConfigError(
                "driver.placeholders",
                f"driver {d.name!r} still has guessed values for "
                f"{', '.join(d.placeholders)}: set them to the drive's real values (and remove "
                "them from the list) before a real port",
                str(d.folder / DESCRIPTION_FILE),
            )
        self.driver = d
