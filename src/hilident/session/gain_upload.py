"""``hilident upload --gains``: the gains an earlier run proposed (or given ones) into the drive of a configuration.

The source run left the plant its loop sees (``loop_plant.npz``,
:func:`hilident.pipeline.loop_plant.save_seen_plant`) and the proposal
(``summary.json["loop"]["tuning"]``). The command:

1. reads the drive's present gains and the filters its slots apply;
2. takes the proposal made with notches when the slots hold enabled filters,
   else the one without, each gain replaced by one given (``--gain NAME=VALUE``);
3. refuses, before anything is written, gains that would not keep the loops
   stable on the plant and its variants on the way from the present gains
   (:func:`hilident.pipeline.gain_check.check_gains`), naming the margins they
   would leave;
4. shows the plan (``--dry-run`` stops there), asks for the go-ahead on a real
   port, writes, reads back, and puts the old gains back on any mismatch,
   failure or signal; ``--save`` stores the parameters once they read back.

Nothing moves: the closed loop is proven by the next ``hilident run``
(``[tuning] upload`` proves its own gains with a closed-loop run).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hilident import endings
from hilident.control import Cascade
from hilident.control.tuning import Targets
from hilident.errors import ArmingRefused, ConfigError, DataError, DeviceError, HilidentError, UsageError
from hilident.filters.biquad import Biquad
from hilident.io.serialise import write_json
from hilident.pipeline.gain_check import check_gains
from hilident.pipeline.loop_plant import PLANT_FILE, load_seen_plant
from hilident.progress import Progress
from hilident.protocol.loop_parameters import TUNABLE
from hilident.session.gain_step import describe_gains, put_back_gains, read_gains
from hilident.session.upload import _Device, default_out, read_source

__all__ = ["GainUploadCommand", "parse_gain_overrides"]

#: Relative difference of two loop rates that counts as the same rate.
_RATE_TOLERANCE = 1e-6


def parse_gain_overrides(items: list[str] | None) -> dict[str, float]:
    """``["kv_nm_per_mps=150", ...]`` as ``{name: value}``; UsageError naming ``--gain`` otherwise."""
    out: dict[str, float] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or name not in TUNABLE:
            raise UsageError(f"--gain {item}: give NAME=VALUE with NAME one of {list(TUNABLE)}")
        try:
            out[name] = float(value)
        except ValueError:
            raise UsageError(f"--gain {item}: {value!r} is not a number") from None
        if math.isnan(out[name]) or out[name] < 0:
            raise UsageError(f"--gain {item}: must be a number >= 0 (inf allowed for ti_s and velocity_filter_hz)")
    return out


class GainUploadCommand:
    """``hilident upload --gains``.

    Parameters
    ----------
    cfg : Config
        The device (``[device]``, ``[emulator]`` for the twin).
    source : path
        A run folder (or its ``summary.json``) whose loop step wrote ``loop_plant.npz``.
    out_dir : path or None
        Where ``summary.json`` goes (default a new folder beside the source).
    progress : Progress, optional
    confirm : callable, optional
        ``confirm(plan) -> bool``: the go-ahead on a real port.
    gains : dict, optional
        Gains that replace the proposal's (SI units, names of :data:`TUNABLE`).
    save : bool
        Store the parameters in non-volatile memory once the gains read back as written.
    dry_run : bool
        Connect, read, check and show the plan; write nothing.
    """

    def __init__(
        self,
        cfg,
        source: str | Path,
        out_dir: str | Path | None = None,
        progress=None,
        confirm: Callable | None = None,
        gains: dict[str, float] | None = None,
        save: bool = False,
        dry_run: bool = False,
    ):
        self.cfg = cfg
        self.source = read_source(source)
        self.seen = load_seen_plant(self.source.folder / PLANT_FILE)
        self.out = Path(out_dir) if out_dir else default_out(self.source)
        if self.out.resolve() == self.source.folder.resolve():
            raise UsageError(f"--out {out_dir}: that is the source's folder; its summary.json is never overwritten")
        self.progress = progress or Progress(enabled=False)
        self.confirm, self.given, self.save, self.dry_run = confirm, dict(gains or {}), save, dry_run
        self.warnings: list[str] = []
        self.device = _Device(cfg, self.progress, self.warnings)
        self.plan: dict | None = None
        self.summary: dict = {}

    def run(self) -> dict:
        """Connect, check, plan, ask, write with rollback, store; returns the summary.

        Raises
        ------
        UsageError
            The gains would not keep the loops stable (nothing written), or none are proposed or given.
        DeviceError
            A gain did not read back as written, or the drive failed: the old gains are back.
        """
        started = time.monotonic()
        dev = self.device
        state: dict[str, Any] = {"step": "connect", "before": None, "written": False}
        try:
            dev.find_driver()
            dev.open_device()
            state["step"] = "plan"
            self.plan = plan = self._plan()
            state["before"] = plan["before"]
            if self.dry_run:
                return {"dry_run": True, "plan": plan, "warnings": self.warnings}
            if not self.cfg.uses_emulator and (self.confirm is None or not self.confirm(self.describe())):
                raise ArmingRefused("the gain upload was not confirmed; nothing was written")
            self.out.mkdir(parents=True, exist_ok=True)
            state["step"] = "upload"
            self._write(plan, state)
            if self.save:
                state["step"] = "save"
                from hilident.session.upload import store_parameters

                state["saved_with"], _ = store_parameters(dev.adapter, dev.found_driver.transport, self.progress)
        except BaseException as exc:
            with endings.shielded():
                dev.safe_stop()
                if state["written"] and not state.get("restored_checked"):
                    self._put_back(state)
                if state["step"] in ("upload", "save") and isinstance(exc, (HilidentError, KeyboardInterrupt)):
                    self._summary(state, started, failed_step=state["step"], error=str(exc) or type(exc).__name__)
            raise
        finally:
            with endings.shielded():
                dev.close()
        endings.raise_pending()
        return self._summary(state, started)

    # --- steps ------------------------------------------------------------------------------------

    def _proposal(self, notched: bool) -> tuple[str, dict]:
        loop = self.source.summary.get("loop") or {}
        tuning = loop.get("tuning") or {}
        which = "with_notch" if notched else "without_notch"
        proposed = tuning.get(which) or {}
        feedforward = (tuning.get("feedforward") or {}).get("terms") or {} if proposed else {}
        gains = {**(proposed.get("gains") or {}), **feedforward, **self.given}
        if not gains:
            raise UsageError(
                f"{self.source.path}: loop.tuning.{which} proposes no gains and none were given (--gain NAME=VALUE)"
            )
        return which if proposed else "given", gains

    def _targets(self) -> Targets | None:
        t = ((self.source.summary.get("loop") or {}).get("tuning") or {}).get("targets")
        return Targets(**t) if isinstance(t, dict) else None

    def _plan(self) -> dict:
        ad = self.device.adapter
        present_values = ad.read_loop()
        if present_values is None:
            raise ConfigError(
                "loop",
                f"driver {self.device.found_driver.name!r} describes no loop ([loop]): no gains to write",
                str(self.device.found_driver.folder / "driver.toml"),
            )
        rate = float(ad.identity.loop_rate_hz)
        if abs(rate - self.seen.loop_rate_hz) > _RATE_TOLERANCE * rate:
            raise DataError(
                f"{self.source.folder / PLANT_FILE}: the plant was seen at a {self.seen.loop_rate_hz:g} Hz loop, "
                f"the drive of {self.cfg.source} runs at {rate:g} Hz"
            )
        filters = self._enabled_filters()
        which, asked = self._proposal(bool(filters))
        expected = ad.stored_loop(asked)
        present = Cascade.from_parameters(present_values, rate, filters)
        check = check_gains(present.with_gains(**expected), self.seen, self._targets(), present)
        if not check.stable:
            raise UsageError(
                f"refused before upload: the gains {describe_gains(expected)} would leave {check.describe()}; "
                "nothing written"
            )
        if check.meets_targets is False:
            self.warnings.append(f"the gains miss the source's targets: {check.describe()}")
        return {
            "driver": self.device.found_driver.name,
            "port": ad.port,
            "source": str(self.source.path),
            "proposal": which,
            "filters_enabled": len(filters),
            "before": {k: present_values[k] for k in asked},
            "asked": asked,
            "expected": expected,
            "check": check.to_dict(),
            "save": self.save,
        }

    def _enabled_filters(self) -> tuple[Biquad, ...]:
        ad = self.device.adapter
        out = []
        for slot in range(ad.identity.filter_slots):
            biquad, enabled = ad.read_filter(slot)
            if enabled:
                out.append(biquad)
        return tuple(out)

    def describe(self) -> str:
        """The plan as the go-ahead and ``--dry-run`` show it."""
        p = self.plan or {}
        w = (p.get("check") or {}).get("worst") or {}
        return "\n".join(
            [
                f"gain upload plan for {p.get('driver')} on {p.get('port')} "
                f"({p.get('proposal')} of {p.get('source')}); nothing moves:",
                f"  now        {describe_gains(p.get('before') or {})}",
                f"  will hold  {describe_gains(p.get('expected') or {})}",
                f"  smallest margins on the plant and its variants: the {w.get('loop')} loop, gain margin "
                f"{_number(w.get('gain_margin_db'))} dB, phase margin {_number(w.get('phase_margin_deg'))} deg, "
                f"Ms {_number(w.get('sensitivity_peak'))}",
                "  written, read back, the old gains put back on any mismatch or failure"
                + ("; then the parameters are stored (--save)" if p.get("save") else ""),
            ]
        )

    def _write(self, plan: dict, state: dict) -> None:
        ad = self.device.adapter
        self.progress.step(f"loop: writing gains {describe_gains(plan['expected'])}")
        state["written"] = True
        ad.write_loop(plan["asked"])
        back = read_gains(ad, plan["asked"])
        state["readback"] = back
        if back != plan["expected"]:
            raise DeviceError(
                f"{ad.port}: the gains read back {describe_gains(back)}, not the "
                f"{describe_gains(plan['expected'])} written; the old gains were put back"
            )

    def _put_back(self, state: dict) -> None:
        """The gains the drive held, written back (never raises; what fails becomes a warning)."""
        state["restored_checked"] = True
        state["restored"] = put_back_gains(self.device.adapter, state["before"], self.warnings)

    def _summary(self, state: dict, started: float, **failure) -> dict:
        plan = self.plan or {}
        kept = state["written"] and "restored" not in state
        summary = {
            "command": "upload",
            "config": self.cfg.source,
            "source": {"summary": str(self.source.path), "plant": str(self.source.folder / PLANT_FILE)},
            "gains": {
                **{k: plan.get(k) for k in ("proposal", "before", "asked", "expected", "check")},
                "readback": state.get("readback"),
                "written": state["written"],
                "kept": kept,
                "restored": state.get("restored"),
                "saved": "saved_with" in state,
                "saved_with": state.get("saved_with"),
            },
            "elapsed_s": time.monotonic() - started,
            "warnings": list(self.warnings),
        }
        if failure:
            summary.update(failed_step=failure["failed_step"], error=failure["error"])
        self.out.mkdir(parents=True, exist_ok=True)
        write_json(self.out / "summary.json", summary)
        self.summary = summary
        return summary


def _number(x) -> str:
    return "-" if x is None else f"{x:.3g}"
