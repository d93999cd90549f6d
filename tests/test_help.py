"""The command line explains itself: every command and argument has help, with units and examples,
in words a user who never read the papers can follow."""

import argparse
import subprocess
import sys

import pytest

from nlpcal.cli import build_parser, main


def _commands(parser, path=()):
    """(path, parser) for every command and subcommand."""
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*path, name))


COMMANDS = list(_commands(build_parser()))


@pytest.mark.parametrize(
    "path, parser", COMMANDS, ids=[" ".join(p) or "nlpcal" for p, _ in COMMANDS]
)
def test_every_argument_has_help(path, parser):
    for action in parser._actions:
        if isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            continue
        if action.help == argparse.SUPPRESS:  # hidden aliases of old names
            continue
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                assert choice.help, f"{' '.join(path)} {choice.dest} has no help"
            continue
        assert action.help, f"{' '.join(path)}: {action.option_strings or action.dest} has no help"


@pytest.mark.parametrize(
    "path, parser", COMMANDS, ids=[" ".join(p) or "nlpcal" for p, _ in COMMANDS]
)
def test_help_reads_as_plain_text(path, parser):
    text = parser.format_help()
    assert "`" not in text  # no Markdown
    assert "seed 00" not in text  # no internal paper labels
    assert "-v, --verbose" in text and "-q, --quiet" in text
    leaf = not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)
    if path and leaf:
        assert "examples:" in text and "nlpcal " in text.split("examples:")[1]


def test_top_level_help_says_what_nlpcal_is_and_where_to_start(capsys):
    assert main(["--help"]) == 0
    text = capsys.readouterr().out
    assert "calibrates three-axis magnetometers" in text
    start = text.split("start here:")[1]
    for command in ("nlpcal calibrate", "nlpcal apply", "nlpcal stats"):
        assert command in start


def test_one_name_for_the_field_magnitude():
    # --reference-field everywhere a field magnitude is given; the old names stay hidden.
    for path, parser in COMMANDS:
        options = {s for a in parser._actions for s in a.option_strings}
        visible = {
            s for a in parser._actions if a.help != argparse.SUPPRESS for s in a.option_strings
        }
        assert not ({"--field", "--field-nt"} & visible), path
        if {"--field", "--field-nt"} & options:
            assert "--reference-field" in visible, path


@pytest.mark.parametrize("argv", [["--version"], ["--help"], ["calibrate", "--help"]])
def test_version_and_help_import_no_numerical_library(argv):
    """The command line answers --version and --help without importing numpy, pandas or
    CasADi, which take most of a second to import."""
    heavy = ("numpy", "pandas", "casadi", "numba")
    code = (
        "import sys\n"
        "from nlpcal.cli import main\n"
        "try:\n"
        f"    main({argv!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print('imported:', *(m for m in {heavy!r} if m in sys.modules))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    assert done.stdout.splitlines()[-1] == "imported:"
