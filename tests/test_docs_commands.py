"""Every command the README and the docs show is one hilident accepts, the command reference lists every
sub-command and option there is, and the README's worked flows run as written (on quick copies of the
configs they name, in a scratch folder)."""

from __future__ import annotations

import csv
import json
import re
import shutil
import tomllib

import pytest
import tomli_w

from hilident.cli.main import build_parser, main
from support.doc_blocks import (
    DOCUMENTS,
    ROOT,
    fenced_blocks,
    hilident_commands,
    inline_commands,
    option_strings,
    section,
    split_synopsis,
    subcommand_parsers,
)

PARSER = build_parser()
COMMANDS = subcommand_parsers(PARSER)
README = ROOT / "README.md"


def reference_synopses() -> list[str]:
    """The synopsis lines of the README's "Commands" block (continuation lines joined)."""
    (block,) = [b for b in fenced_blocks(README) if b.text.startswith("hilident init [")]
    synopses: list[str] = []
    for line in block.text.splitlines():
        if line.startswith("hilident "):
            synopses.append(line)
        elif line.strip().startswith("[") and synopses:
            synopses[-1] += " " + line.strip()
    return synopses


def named_options(synopses: list[str]) -> dict[str, set[str]]:
    named: dict[str, set[str]] = {}
    for line in synopses:
        path, options = split_synopsis(line.split()[1:], COMMANDS)
        named.setdefault(path, set()).update(options)
    return named


def test_the_command_reference_lists_every_subcommand_and_option():
    named = named_options(reference_synopses())
    assert set(named) - {""} >= {path for path, sub in COMMANDS.items() if not subcommand_parsers(sub)}, (
        "a sub-command missing from README 'Commands'"
    )
    for path, options in named.items():
        parser = COMMANDS[path] if path else PARSER
        assert options <= option_strings(parser), f"README 'Commands' names options `hilident {path}` lacks"
        if path:
            missing = [
                action.option_strings[-1]
                for action in parser._actions
                if action.option_strings and action.dest != "help" and not set(action.option_strings) & options
            ]
            assert missing == [], f"`hilident {path}` options missing from README 'Commands'"
    assert named[""] >= {"--log-level"}


def every_shown_command() -> list[tuple[str, list[str]]]:
    """(where, words) of every hilident command shown in a shell block or an inline span of any document."""
    shown = []
    for path in DOCUMENTS:
        for block in fenced_blocks(path):
            if block.lang in ("sh", "bash", "console", "") and "hilident init [" not in block.text:
                shown += [(block.where, words) for words in hilident_commands(block.text)]
        shown += [(str(path.relative_to(ROOT)), text.split()[1:]) for text in inline_commands(path)]
    return shown


def test_every_command_the_documents_show_names_real_subcommands_and_options():
    shown = every_shown_command()
    assert len(shown) > 60  # README, docs and driver READMEs: a parse that finds nothing fails here
    for where, words in shown:
        path, options = split_synopsis(words, COMMANDS)
        parser = COMMANDS.get(path, PARSER) if path else PARSER
        if words and not words[0].startswith("-"):
            assert path, f"{where}: `hilident {' '.join(words)}` is no sub-command"
        assert set(options) <= option_strings(parser) | option_strings(PARSER), (
            f"{where}: `hilident {' '.join(words)}` names an option hilident does not have"
        )


def test_every_concrete_command_of_a_shell_block_parses():
    # placeholders in capitals (CONFIG, DIR) are fine as arguments; brackets are synopses, not commands
    concrete = [
        (w, words)
        for w, words in every_shown_command()
        if w.count(":") and not any(c in " ".join(words) for c in "[]|")
    ]
    assert len(concrete) >= 10
    for where, words in concrete:
        try:
            PARSER.parse_args(words)
        except SystemExit as exc:  # argparse's way of refusing
            pytest.fail(f"{where}: `hilident {' '.join(words)}` does not parse (exit {exc.code})")


def test_ci_runs_the_readme_test_command_verbatim():
    quick_start = [b for b in fenced_blocks(README) if "pytest" in b.text and "pip install" in b.text][0]
    (test_line,) = [line for line in quick_start.text.splitlines() if "pytest" in line]
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert test_line in ci


def test_the_readme_layout_names_every_module_and_every_name_exists():
    (block,) = [b for b in fenced_blocks(README) if b.text.startswith("src/hilident/")]
    words = set(re.findall(r"\b\w+\.py\b", block.text)) | set(
        re.findall(r"(?:(?<=\s)|^)([\w/]+/)(?=\s|$)", block.text, re.M)
    )
    package = ROOT / "src" / "hilident"
    present = {
        p.name + ("/" if p.is_dir() else "")
        for p in package.iterdir()
        if (p.suffix == ".py" or (p.is_dir() and (p / "__init__.py").exists())) and p.name != "__init__.py"
    }
    assert present - words == set(), "modules of src/hilident missing from README 'Layout'"
    for word in words:
        if word.endswith(".py") or word.endswith("/"):
            candidates = [folder / word for folder in (package, ROOT, ROOT / "src", ROOT / "scripts")]
            candidates += [*package.glob(f"*/{word}"), *package.glob(f"*/*/{word}")]
            assert any(c.exists() for c in candidates), f"README 'Layout' names {word}, which does not exist"


# --- the worked flows ------------------------------------------------------------------------------------


def quick_gantry(raw: dict) -> dict:
    """The shipped gantry, quick: a short friction test, two 2 s periods (the amplitude still chosen by trials),
    a verification run, fast simulated time, the clean twin."""
    raw = json.loads(json.dumps(raw))
    raw["friction_test"].update(speeds_mps=[0.01, 0.05, 0.2], hold_s=0.5, settle_s=0.3)
    raw["excitation"].update(period_s=2.0, duration_s=4.0)
    raw["emulator"].update(time_scale=8.0, preset="clean")
    return raw


@pytest.fixture
def scratch(tmp_path):
    """A scratch folder holding quick copies of the shipped configs, as the working directory of a flow."""
    folder = tmp_path
    (folder / "configs").mkdir()
    for config in (ROOT / "configs").glob("*.toml"):
        shutil.copy(config, folder / "configs" / config.name)
    gantry = folder / "configs" / "emulated-gantry.toml"
    gantry.write_text(tomli_w.dumps(quick_gantry(tomllib.loads(gantry.read_text()))))
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        patch.setenv("HILIDENT_LOCK_DIR", str(folder / "locks"))
        yield folder


def block_after(text_before: str) -> list[list[str]]:
    """The hilident commands of the first shell block after ``text_before`` in the README."""
    readme = README.read_text()
    offset = readme.index(text_before)
    line = readme[:offset].count("\n") + 1
    block = next(b for b in fenced_blocks(README) if b.line > line)
    return hilident_commands(block.text)


def test_the_quick_start_runs_and_prints_what_the_readme_shows(scratch, capsys):
    (words,) = hilident_commands(section(README, "Quick start").split("```sh", 1)[1].split("```", 1)[0])
    assert words[:2] == ["run", "configs/emulated-gantry.toml"]
    assert main(words) == 0
    printed = "".join(capsys.readouterr())  # results on stdout, the progress (auto amplitude) on stderr
    out = scratch / words[words.index("--out") + 1]
    shown = section(README, "What a run prints and writes").split("```", 2)[1]
    for line in shown.strip().splitlines():
        label = line.split(":", 1)[0]
        assert re.search(rf"^{re.escape(label)}:", printed, re.M), f"the README shows a '{label}:' line; not printed"
    listed = re.findall(r"`([\w.]+\.(?:html|json|h5))`", section(README, "Quick start"))
    assert len(listed) >= 5
    for name in listed:
        assert (out / name).is_file(), f"README Quick start lists {name}; the run did not write it"


def test_the_readme_flow_for_a_parameter_drive_runs_as_written(scratch, capsys):
    commands = block_after("The\nflow for such a drive, on the twins:")
    assert [c[0] for c in commands] == ["run", "identify", "upload"]
    for words in commands:
        assert main(words) == 0, words
    upload_out = commands[2][commands[2].index("--from") + 1] + "-upload"
    summary = json.loads((scratch / upload_out / "summary.json").read_text())
    assert summary["upload"]["verified_readback"] and summary["upload"]["saved"]


def test_the_readme_flow_for_a_scope_export_runs_as_written(scratch, capsys):
    """``identify scope_export.csv --config axis.toml``, then ``upload --dry-run`` and ``upload --yes --save``
    into ``drive.toml``: the export is a recording of the gantry twin written as a scope would (time, torque,
    velocity columns), ``axis.toml`` maps it, ``drive.toml`` is the DSY-RS twin."""
    from hilident.io.recording import read_run

    commands = block_after("Modbus drive with a parameter map only) is:")
    assert [c[0] for c in commands] == ["identify", "upload", "upload"]
    assert main(["run", "configs/emulated-gantry.toml", "--out", "runs/scope"]) == 0
    run = read_run(scratch / "runs" / "scope" / "identification.h5")
    with open(scratch / "scope_export.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["t", "tq", "vel"])
        writer.writerows(zip(run.time_s, run.channel("torque_nm"), run.channel("velocity_mps"), strict=True))
    axis = {
        "data": {"time": "t", "torque": "tq", "velocity": "vel", "period_s": 2.0},
        "identification": {"output": "velocity", "coherence_threshold": 0.8, "max_resonances": 1},
        "model": {"filter_rate_hz": 8000.0},
    }
    (scratch / "axis.toml").write_text(tomli_w.dumps(axis))
    shutil.copy(scratch / "configs" / "emulated-dsy-rs.toml", scratch / "drive.toml")
    for words in commands:
        assert main(words) == 0, words
        if "--dry-run" in words:
            plan = "".join(capsys.readouterr())
            assert "the drive's parameters will be P08.02 = 22, P08.03 = " in plan, plan
    summary = json.loads((scratch / "runs" / "axis-upload" / "summary.json").read_text())
    assert summary["upload"]["verified_readback"] and summary["upload"]["saved"]
    (slot,) = summary["upload"]["slots"]
    assert slot["parameters"]["center"]["value"] == 22  # the gantry's 21.79 Hz at the drive's 1 Hz step
