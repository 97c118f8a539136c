"""``report.html``: every section present for a run, an identify and an upload, self-contained, text escaped.

The summaries in ``tests/data/html_report/`` were written by ``hilident run
configs/emulated-gantry.toml``, ``hilident identify`` on its identification
recording (with a ``[model] rigid_axis`` config and ``--validation`` its
verification recording) and ``hilident upload`` of its notch; the page is
read back with :mod:`html.parser`.
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import struct
import zlib
from dataclasses import replace
from pathlib import Path

import pytest

from hilident.cli.main import main
from hilident.html_report import REPORT_NAME, write_report, write_report_quietly
from hilident.html_report.advice import group_warnings, split_advice
from hilident.html_report.sections import SECTIONS
from support.report_page import SECTION_IDS, Page, check_report, check_self_contained

DATA = Path(__file__).resolve().parent / "data" / "html_report"
CONFIGS = Path(__file__).resolve().parents[1] / "configs"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def tiny_png(width: int = 3, height: int = 2) -> bytes:
    """A valid grey PNG made with the standard library (the report embeds bytes, it does not draw)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    rows = b"".join(b"\x00" + bytes([128] * width) for _ in range(height))
    return (
        PNG_SIGNATURE
        + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(rows))
        + chunk(b"IEND", b"")
    )


def folder_with(tmp_path: Path, name: str, summary: dict | None = None, pngs=("bode.png",)) -> Path:
    out = tmp_path / name
    out.mkdir()
    if summary is None:
        shutil.copy(DATA / f"{name}.json", out / "summary.json")
    else:
        (out / "summary.json").write_text(json.dumps(summary))
    for png in pngs:
        (out / png).write_bytes(tiny_png())
    return out


def report_of(folder: Path) -> Page:
    path = write_report(folder)
    assert path == folder / REPORT_NAME
    return Page(path.read_text(encoding="utf-8"))


@pytest.mark.parametrize("name", ["run", "identify", "upload"])
def test_every_section_is_there_for_each_command(tmp_path, name):
    page = report_of(folder_with(tmp_path, name))
    assert list(page.sections) == SECTION_IDS
    for anchor, title, _ in SECTIONS:
        assert page.headings[anchor].strip() == title
    # the contents list reaches every section
    assert [a["href"] for a in page.all("a") if a["href"].startswith("#")] == [f"#{i}" for i in SECTION_IDS]
    check_self_contained(page)
    assert page.all("title") and f"hilident {name}" in page.text


def test_run_report_has_the_headline_figures_with_units(tmp_path):
    summary = json.loads((DATA / "run.json").read_text())
    page = report_of(folder_with(tmp_path, "run", pngs=("bode.png", "friction.png")))
    head = page.sections["headline"]
    res = summary["resonances"][0]
    assert f"{res['frequency_hz']:.6g} ± {res['frequency_ci95_hz']:.2g} Hz (95 %)" in head
    assert f"damping ratio {res['damping_ratio']:.3g} ± {res['damping_ci95']:.2g}" in head
    fr = summary["friction"]["params"]
    assert f"Fc {fr['Fc']:.3g} N*m" in head and f"Fv {fr['Fv']:.3g} N*m/(m/s)" in head
    ver = summary["verification"]
    assert f"reduced by {ver['band_reduction_db']:.3g} dB" in head
    achieved = summary["upload"]["slots"][0]["achieved"]["attenuation_at_design_center_db"]
    assert f"designed 40 dB, achieved on the device {achieved:.3g} dB" in head
    # the friction section names the structure the criterion chose and every fitted parameter's standard error
    friction = page.sections["friction"]
    assert "Coulomb + viscous" in friction and "N*m/(m/s)" in friction
    assert f"{summary['friction']['stderr']['Fv']:.2g} N*m/(m/s)" in friction
    assert "found IDLE, 0 stale frame(s) discarded, latched faults: none" in page.sections["run"]
    assert "target met" in page.sections["run"]  # why the amplitude was chosen
    model = page.sections["model"]
    assert "Resonances of the measured response" in model and f"{res['half_power_bandwidth_hz']:.3g} Hz" in model
    # the notch table holds the designed and the read-back coefficients
    notches = page.sections["notches"]
    assert f"{summary['notch_filters'][0]['b'][0]:.9g}" in notches
    assert f"{summary['upload']['slots'][0]['readback_b'][0]:.9g}" in notches
    assert "Verification" in notches and "What the filter slots held before" in notches
    assert str(summary["stream"]["samples"]) in page.sections["stream"]
    # the sampling warning is grouped and its remedy is shown as what to do
    warnings = page.sections["warnings"]
    assert "Measurement and excitation (1)" in warnings and "What to do: decimate by 2" in warnings


def test_notes_are_shown_apart_from_the_warnings_and_ask_for_nothing(tmp_path):
    summary = json.loads((DATA / "run.json").read_text())
    summary["warnings"] = []
    delay = (
        "transfer-function fit: right-half-plane zero(s) at 260.1 Hz (a 0.612 ms delay): the phase lag of a delay "
        "(the drive's computation, transport or current loop), non-minimum phase, not anti-resonances"
    )
    summary["notes"] = [delay]
    page = report_of(folder_with(tmp_path, "run", summary))
    shown = page.sections["warnings"]
    assert "No warnings." in shown and "Notes (1)" in shown and "260.1 Hz (a 0.612 ms delay)" in shown
    assert "What to do" not in shown  # a note asks for nothing
    assert {"class": "notes"} in page.all("ul") and {"class": "warnings"} not in page.all("ul")
    assert re.search(r"warnings\s*none", page.sections["headline"])  # notes are no warnings


def test_identify_report_shows_the_grey_box_model_and_its_validation(tmp_path):
    summary = json.loads((DATA / "identify.json").read_text())
    page = report_of(folder_with(tmp_path, "identify"))
    model = page.sections["model"]
    m = summary["model"]
    assert "Grey-box model: rigid_axis" in model
    assert f"{m['params']['M']:.4g} kg" in model and f"{m['stderr']['M']:.2g} kg" in model
    assert f"{m['params']['Fv']:.4g} N*s/m" in model
    val = m["validation"]["verification.h5"]
    assert "verification.h5" in model and f"{val['fit_percent']:.3g} %" in model
    assert f"{val['relative_error']:.3g}" in model and "Ljung-Box p = 0" in model
    assert "Transfer function fitted" in model and "anti-resonance" in model
    # every model warning is in the model group, each with a remedy or the group's general advice
    groups = {g.topic: g for g in group_warnings(summary["warnings"])}
    assert len(groups["Model fit"].items) == len(summary["warnings"]) - 1
    assert f"Model fit ({len(summary['warnings']) - 1})" in page.sections["warnings"]
    assert "What to do: try the other input_hold" in page.sections["warnings"]
    # identify designs a notch but uploads none
    assert "identify uploads nothing" in page.sections["notches"]
    assert "re 1 (m/s)/(N*m)" in page.sections["headline"]


def test_upload_report_shows_the_achieved_notch_and_the_device(tmp_path):
    summary = json.loads((DATA / "upload.json").read_text())
    page = report_of(folder_with(tmp_path, "upload", pngs=()))
    assert "hilident-board 1.0" in page.sections["run"] and "4000 Hz" in page.sections["run"]
    assert "No plots of this command in this folder" in page.sections["plots"]
    slot = summary["upload"]["slots"][0]
    assert f"{slot['achieved']['realisable_db']:.3g} dB" in page.sections["notches"]
    assert "every slot read back as written" in page.sections["notches"]


def test_plots_are_embedded_as_png_data(tmp_path):
    folder = folder_with(tmp_path, "run", pngs=("bode.png", "friction.png", "compare.png"))
    (folder / "compare.png").write_bytes(tiny_png(5, 4))
    page = report_of(folder)
    images = page.all("img")
    assert [i["alt"] for i in images] == ["bode.png", "compare.png", "friction.png"]
    for img in images:
        data = base64.b64decode(img["src"].removeprefix("data:image/png;base64,"), validate=True)
        assert data.startswith(PNG_SIGNATURE)
        assert data == (folder / img["alt"]).read_bytes()


def test_plots_older_than_the_summary_are_left_out(tmp_path):
    folder = folder_with(tmp_path, "run", pngs=("bode.png", "friction.png"))
    summary_time = (folder / "summary.json").stat().st_mtime
    os.utime(folder / "friction.png", (summary_time - 3600, summary_time - 3600))  # an earlier run's plot
    page = report_of(folder)
    assert [i["alt"] for i in page.all("img")] == ["bode.png"]
    assert "older than summary.json" in page.sections["plots"] and "friction.png" in page.sections["plots"]


def test_text_from_the_summary_is_escaped(tmp_path):
    summary = json.loads((DATA / "run.json").read_text())
    summary["warnings"] = ['<script>alert("x")</script> friction: odd', "a & b <b>bold</b>"]
    summary["config"] = "<img src=x onerror=alert(1)>.toml"
    summary["failed_step"], summary["error"] = "verification", "<iframe src=http://example.com>"
    page = report_of(folder_with(tmp_path, "run", summary))
    check_self_contained(page)
    assert not page.all("b") and not page.all("iframe")
    assert '<script>alert("x")</script> friction: odd' in page.sections["warnings"]
    assert "a & b <b>bold</b>" in page.sections["warnings"]
    assert "<img src=x onerror=alert(1)>.toml" in page.sections["run"]
    assert "<iframe src=http://example.com>" in page.sections["headline"]
    assert len(page.all("img")) == 1  # only the embedded plot


def test_partial_and_odd_summaries_still_give_every_section(tmp_path):
    failed = {
        "hilident_version": "0.1.0",
        "config": "gone.toml",
        "device": {"driver": "myrio-board"},
        "friction": json.loads((DATA / "run.json").read_text())["friction"],
        "warnings": [],
        "failed_step": "identification",
        "error": "lost the line",
    }
    page = report_of(folder_with(tmp_path, "failed", failed, pngs=()))
    assert list(page.sections) == SECTION_IDS
    assert "identification" in page.sections["headline"] and "lost the line" in page.sections["headline"]
    assert "configuration text was not found" in page.sections["run"]
    # keys of unexpected types leave their figures empty instead of failing the report
    odd = {
        "resonances": "none",
        "stream": None,
        "friction": {"params": [1, 2]},
        "upload": {"slots": [1]},
        "notch_filters": [{"center_hz": "x"}],
        "model": {"params": {"M": None}},
        "warnings": "one",
    }
    page = report_of(folder_with(tmp_path, "odd", odd, pngs=()))
    assert list(page.sections) == SECTION_IDS
    page = report_of(folder_with(tmp_path, "empty", {}, pngs=()))
    assert list(page.sections) == SECTION_IDS and "No warnings." in page.sections["warnings"]


def test_recordings_are_linked_and_their_config_is_shown(tmp_path):
    from hilident.io.recording import RunWriter

    folder = folder_with(tmp_path, "run")
    attrs = {
        "experiment": "identification",
        "mode": "torque",
        "config_toml": "[run]\nseed = 7 # <ok>\n",
        "device": {"name": "board", "firmware": "fw 9.9", "port": "/dev/pts/3"},
        "versions": {"hilident": "0.1.0", "numpy": "9.8.7", "scipy": "6.5.4"},
    }
    with RunWriter(folder / "identification run.h5", ["x"], ["m"], 100.0, attrs) as rec:
        import numpy as np

        rec.append(np.zeros((250, 1)))
    (folder / "broken.h5").write_bytes(b"not hdf5")
    page = report_of(folder)
    hrefs = [a["href"] for a in page.all("a") if not a["href"].startswith("#")]
    assert hrefs == ["broken.h5", "identification%20run.h5"]
    rec_text = page.sections["recordings"]
    assert "identification" in rec_text and "250" in rec_text and "2.5 s" in rec_text
    run = page.sections["run"]
    assert "fw 9.9" in run and "numpy 9.8.7, scipy 6.5.4" in run
    pre = [d for d in page.text.split("\n") if "seed = 7 # <ok>" in d]
    assert pre, "the stored configuration is shown (escaped)"
    assert "stored in identification run.h5" in run
    assert page.all("details")


def test_report_command_exit_codes(tmp_path, capsys):
    folder = folder_with(tmp_path, "identify")
    assert main(["report", str(folder)]) == 0
    assert f"wrote {folder / REPORT_NAME}" in capsys.readouterr().out
    assert (folder / REPORT_NAME).read_text().startswith("<!DOCTYPE html>")
    (folder / REPORT_NAME).unlink()
    assert main(["report", str(folder / "summary.json")]) == 0 and (folder / REPORT_NAME).is_file()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["report", str(empty)]) == 2
    err = capsys.readouterr().err
    assert "no summary.json" in err and str(empty) in err and "Traceback" not in err
    assert main(["report", str(tmp_path / "missing")]) == 2
    (empty / "summary.json").write_text("[1,")
    assert main(["report", str(empty)]) == 3
    assert "summary.json" in capsys.readouterr().err
    (empty / "summary.json").write_text("[1]")
    assert main(["report", str(empty)]) == 3


def test_a_report_that_cannot_be_written_is_a_warning_line(tmp_path):
    lines: list[str] = []
    assert write_report_quietly(tmp_path / "nothing", lines.append) is None
    assert len(lines) == 1 and lines[0].startswith("warning: ") and "report.html not written" in lines[0]


def test_split_advice_keeps_the_remedy_of_a_warning():
    finding, remedy = split_advice(
        "closed-loop data without an excitation column: the estimate is biased "
        "(give [data].excitation to use the excitation as reference)"
    )
    assert finding.endswith("the estimate is biased")
    assert remedy == "give [data].excitation to use the excitation as reference"
    assert split_advice("parameter 'Fc' = 0.1 is not significant") == ("parameter 'Fc' = 0.1 is not significant", "")


def test_run_identify_and_upload_write_their_report(tmp_path, capsys):
    """A real session on the gantry twin, an identify on its recording and an upload of its notch."""
    from hilident.config.tables import load_config
    from hilident.session.run import Session

    cfg = load_config(CONFIGS / "emulated-gantry.toml")
    cfg = replace(
        cfg,
        emulator=replace(cfg.emulator, link="pipe", time_scale=8.0),
        excitation=replace(cfg.excitation, amplitude_nm=8.0),
    )
    run = tmp_path / "run"
    Session(cfg, run).run()
    page = check_report(run)
    assert sorted(i["alt"] for i in page.all("img")) == ["bode.png", "friction.png"]
    assert "identification.h5" in [a["href"] for a in page.all("a")]
    assert "stored in identification.h5" in page.sections["run"]
    assert re.search(r"peak -\d+(\.\d+)? dB re 1 \(m/s\)/\(N\*m\)", page.sections["headline"])

    ident = tmp_path / "ident"
    assert main(["identify", str(run / "identification.h5"), "--out", str(ident), "-q"]) == 0
    assert f"wrote {ident / REPORT_NAME} (open it in a browser)" in capsys.readouterr().out
    page = check_report(ident)
    # the run's friction test lies beside the recording: identify plots its fit too
    assert sorted(i["alt"] for i in page.all("img")) == ["bode.png", "friction.png"]
    assert "the data file, outside this folder" in page.sections["recordings"]

    upload = tmp_path / "upload"
    assert (
        main(
            [
                "upload",
                "--from",
                str(run),
                "--config",
                str(CONFIGS / "emulated-gantry.toml"),
                "--out",
                str(upload),
                "-q",
            ]
        )
        == 0
    )
    page = check_report(upload)
    assert "read back" in page.sections["notches"]
    assert [i["alt"] for i in page.all("img")] == ["notch.png"]  # designed vs stored, drawn by the upload


def test_identify_that_fails_at_a_step_reports_what_it_found(tmp_path, capsys):
    from test_identify_data_keys import msd_record, write_csv

    rec = msd_record(1000.0, 4000, 4)
    write_csv(tmp_path / "d.csv", {"t": rec["t"], "f": rec["f"], "x": rec["x"]})
    (tmp_path / "c.toml").write_text(
        '[data]\ntime = "t"\ntorque = "f"\noutput = "x"\n[model]\nkind = "mass_spring_damper"\n'
    )
    out = tmp_path / "out"
    assert (
        main(["identify", str(tmp_path / "d.csv"), "--config", str(tmp_path / "c.toml"), "--out", str(out), "-q"]) == 2
    )
    assert "not written" not in capsys.readouterr().err
    page = check_report(out)
    assert "The step “model” failed" in page.sections["headline"] and "data.position" in page.sections["headline"]
    assert "resonance at" in page.sections["headline"]
    assert '[model]\nkind = "mass_spring_damper"' in page.sections["run"]
