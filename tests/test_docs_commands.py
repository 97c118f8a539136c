"""Every command the README and the docs show is one hilident accepts, the generated command reference lists
every sub-command and option there is, the development page's layout names every package, and the worked flows
of the README and the docs run as written (on quick copies of the configs they name, in a scratch folder)."""

from __future__ import annotations

import csv
import html
import json
import re
import shutil
import tomllib

import pytest
import tomli_w

from hilident.cli.main import build_parser, main
from support.doc_blocks import (
    DOCS,
    DOCUMENTS,
    ROOT,
    block_after,
    fenced_blocks,
    hilident_commands,
    hook_module,
    inline_commands,
    option_strings,
    section,
    split_synopsis,
    subcommand_parsers,
)

PARSER = build_parser()
COMMANDS = subcommand_parsers(PARSER)
README = ROOT / "README.md"


# --- the generated command reference --------------------------------------------------------------------------


def reference_sections() -> dict[str, str]:
    """The generated command-line reference page, by command path (``""`` for ``hilident`` itself)."""
    page = hook_module("cli_page").cli_reference(build_parser())
    parts = re.split(r"^## `hilident ?(.*?)`\n", page, flags=re.M)
    return dict(zip(parts[1::2], parts[2::2], strict=True))


def documented_options(text: str) -> dict[str, str]:
    """Option string -> help of every row of a command's argument table (``-q, --quiet`` gives both)."""
    rows = re.findall(r"^\| (`.+?`) \| (.*) \|$", text, re.M)
    options = {}
    for names, help_text in rows:
        for name in re.findall(r"`(-[^` ]+)", names):
            options[name] = help_text
    return options


def synopsis(text: str) -> str:
    """The synopsis line of a command's section."""
    return text.split("```text\n", 1)[1].split("\n", 1)[0]


def test_the_generated_command_reference_lists_every_subcommand_and_option():
    sections = reference_sections()
    assert set(sections) == {""} | set(COMMANDS), "a sub-command missing from the generated reference"
    for path, text in sections.items():
        parser = COMMANDS[path] if path else PARSER
        listed, (named_path, named) = documented_options(text), split_synopsis(synopsis(text).split()[1:], COMMANDS)
        assert set(listed) <= option_strings(parser), f"the reference names options `hilident {path}` lacks"
        for action in parser._actions:
            if action.option_strings and action.dest != "help":
                assert set(action.option_strings) <= set(listed), f"`hilident {path}` {action.option_strings}"
                assert all(listed[o] for o in action.option_strings), f"`hilident {path}` {action.option_strings}"
        if path:
            assert named_path == path and set(named) <= option_strings(parser), synopsis(text)
            assert {a.option_strings[-1] for a in parser._actions if a.option_strings and a.dest != "help"} <= set(
                named
            ), f"`hilident {path}`: its synopsis misses an option"
    assert "--log-level" in documented_options(sections[""])


def test_the_generated_command_reference_shows_each_positional_with_its_help():
    sections = reference_sections()
    for path, sub in COMMANDS.items():
        shown = html.unescape(re.sub(r"\\(.)", r"\1", sections[path]))  # as the page reads, markup escapes undone
        for action in sub._actions:
            if not action.option_strings and action.help:
                assert " ".join(action.help.split()) in shown, f"`hilident {path}`: {action.dest}"


# --- the commands the documents show -------------------------------------------------------------------------


def every_shown_command() -> list[tuple[str, list[str]]]:
    """(where, words) of every hilident command shown in a shell block or an inline span of any document."""
    shown = []
    for path in DOCUMENTS:
        for block in fenced_blocks(path):
            if block.lang in ("sh", "bash", "console", ""):
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


def test_every_page_of_docs_is_read_by_these_tests():
    assert {p for p in DOCS.rglob("*.md")} <= set(DOCUMENTS)
    assert {"index.md", "getting-started.md", "development.md"} <= {p.name for p in DOCUMENTS}


def test_the_getting_started_page_shows_the_readme_quick_start():
    def quick_start(path):
        return section(path, "Quick start" if path == README else "Install and run a first session")

    def commands(path):
        return [b.text for b in fenced_blocks(path) if b.lang == "sh" and b.text in quick_start(path)]

    assert commands(DOCS / "getting-started.md") == commands(README) != []


def test_the_development_layout_names_every_package_and_every_name_exists():
    (block,) = [b for b in fenced_blocks(DOCS / "development.md") if b.text.startswith("src/hilident/")]
    words = set(re.findall(r"\b\w+\.py\b", block.text)) | set(
        re.findall(r"(?:(?<=\s)|^)([\w/]+/)(?=\s|$)", block.text, re.M)
    )
    package = ROOT / "src" / "hilident"
    present = {
        p.name + ("/" if p.is_dir() else "")
        for p in package.iterdir()
        if (p.suffix == ".py" or (p.is_dir() and (p / "__init__.py").exists())) and p.name != "__init__.py"
    }
    assert present - words == set(), "modules or packages of src/hilident missing from docs/development.md 'Layout'"
    for word in words:
        if word.endswith(".py") or word.endswith("/"):
            candidates = [folder / word for folder in (package, ROOT, ROOT / "src", ROOT / "scripts")]
            candidates += [*package.glob(f"*/{word}"), *package.glob(f"*/*/{word}")]
            assert any(c.exists() for c in candidates), f"docs/development.md 'Layout' names {word}: no such file"


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


def commands_after(path, text_before: str) -> list[list[str]]:
    """The hilident commands of the first shell block after ``text_before`` in the document ``path``."""
    return hilident_commands(block_after(path, text_before).text)


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


def test_the_flow_for_a_parameter_drive_runs_as_written(scratch, capsys):
    commands = commands_after(DOCS / "drivers.md", "The\nflow for such a drive, on the twins:")
    assert [c[0] for c in commands] == ["run", "identify", "upload"]
    for words in commands:
        assert main(words) == 0, words
    upload_out = commands[2][commands[2].index("--from") + 1] + "-upload"
    summary = json.loads((scratch / upload_out / "summary.json").read_text())
    assert summary["upload"]["verified_readback"] and summary["upload"]["saved"]


def test_the_flow_for_a_scope_export_runs_as_written(scratch, capsys):
    """``identify scope_export.csv --config axis.toml``, then ``upload --dry-run`` and ``upload --yes --save``
    into ``drive.toml``: the export is a recording of the gantry twin written as a scope would (time, torque,
    velocity columns), ``axis.toml`` maps it, ``drive.toml`` is the DSY-RS twin."""
    from hilident.io.recording import read_run

    commands = commands_after(DOCS / "upload.md", "Modbus drive with a parameter map only) is:")
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
