"""One CLI grammar (issue 25): the options several commands share mean, read and print the same everywhere.

Walks every command of :data:`mrftcli.cli.main.COMMANDS` and checks each shared option's type,
metavar or choices and help wording against one table; then runs the grammar's promises (bare
``--json`` is stdout, ``--rate`` a deprecated alias of ``--controller-rate``, help names files that
exist) on the cheap commands.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from mrftcli.cli.main import COMMANDS, cli
from mrftcli.cli.options import SHARED_HELP
from mrftcli.io import READ_FORMATS
from mrftcli.io.logtypes import LOOPS

ROOT = Path(__file__).resolve().parents[1]

#: Commands without --json, and why.
NO_JSON = {
    "watch": "it streams: one JSON object per update with --jsonl",
    "build-ufm": "it writes manifold files; there is no result to print",
}
#: Commands whose --format is not the log format read, and why.
FORMAT_EXCEPTIONS = {
    "simulate": "it writes a log: the formats it can write",
    "topics": "free text, so that the reader names an unknown format itself (the help lists every format)",
}
#: What --out names per command (docs/usage.md, "One grammar").
OUT_KIND = {"batch": "folder", "build-ufm": "folder", "simulate": "file", "tune": "file", "vehicle": "file"}
#: Commands that draw a progress bar, so take -q/--quiet.
PROGRESS = {"analyze", "diagnose", "batch", "plan", "tune", "simulate", "build-ufm", "vehicle", "topics"}


def _commands() -> dict[str, click.Command]:
    ctx = click.Context(cli)
    out = {}
    for name in COMMANDS:
        command = cli.get_command(ctx, name)
        assert command is not None, name
        out[name] = command
    return out


COMMAND_OBJECTS = _commands()


def _options(command: click.Command) -> dict[str, click.Option]:
    """Visible options by their long name (hidden aliases are checked separately)."""
    out = {}
    for param in command.params:
        if isinstance(param, click.Option) and not param.hidden:
            for opt in param.opts:
                if opt.startswith("--"):
                    out[opt] = param
    return out


def _type_key(param: click.Option) -> tuple:
    """A comparable description of an option's type: its class, choices and range."""
    t = param.type
    choices = tuple(t.choices) if isinstance(t, click.Choice) else None
    bounds = (t.min, t.max, t.min_open, t.max_open) if isinstance(t, click.types._NumberRangeBase) else None
    return type(t).__name__, choices, bounds, param.multiple


def _where(option: str) -> dict[str, click.Option]:
    return {name: opts[option] for name, cmd in COMMAND_OBJECTS.items()
            if option in (opts := _options(cmd))}


@pytest.mark.parametrize("option", sorted(SHARED_HELP))
def test_shared_option_help_has_one_wording(option):
    where = _where(option)
    if option == "--format":
        where = {k: v for k, v in where.items() if k not in FORMAT_EXCEPTIONS or k == "topics"}
    assert where, f"{option} is used by no command"
    for name, param in where.items():
        assert SHARED_HELP[option].lower() in (param.help or "").lower(), (name, option, param.help)


def test_every_command_has_json_file_or_stdout():
    for name, command in COMMAND_OBJECTS.items():
        opts = _options(command)
        if name in NO_JSON:
            assert "--json" not in opts, f"{name} has --json: drop it from NO_JSON"
            continue
        param = opts.get("--json")
        assert param is not None, f"{name} has no --json"
        assert not param.is_flag and param.flag_value == "-", name  # a bare --json is stdout
        assert param.metavar == "FILE|-" and param.default is None, name


def test_controller_rate_is_one_option_with_a_hidden_rate_alias():
    where = _where("--controller-rate")
    assert {"analyze", "diagnose", "plan", "tune", "watch", "batch", "identify", "predict",
            "simulate"} <= set(where)
    assert len({_type_key(p) for p in where.values()}) == 1
    assert {p.metavar for p in where.values()} == {"HZ"}
    for name, command in COMMAND_OBJECTS.items():
        assert "--rate" not in _options(command), f"{name} shows --rate: it is --controller-rate"
        hidden = [p for p in command.params if isinstance(p, click.Option) and "--rate" in p.opts]
        assert bool(hidden) == (name in where), name
        assert all(p.hidden for p in hidden), name


@pytest.mark.parametrize("option", ["--loop", "--min-cycles", "--time-unit", "--report", "--model", "--tp"])
def test_shared_option_has_one_type(option):
    where = _where(option)
    assert where
    if option == "--loop":
        # batch alone also takes auto (the loops the log records); x and y everywhere
        assert tuple(where.pop("batch").type.choices) == (*LOOPS, "auto")
    keys = {_type_key(p)[:3] for p in where.values()}  # --loop is repeatable in batch and compare
    assert len(keys) == 1, {name: _type_key(p) for name, p in where.items()}
    assert len({p.metavar for p in where.values()}) == 1, option
    if option == "--loop":
        assert keys == {("Choice", LOOPS, None)}


def test_format_is_the_log_format():
    for name, param in _where("--format").items():
        if name in FORMAT_EXCEPTIONS:
            continue
        assert isinstance(param.type, click.Choice) and tuple(param.type.choices) == READ_FORMATS, name
    assert "mat" in (_where("--format")["topics"].help or "")


def test_tunes_log_format_is_format_with_its_old_names_hidden(tmp_path):
    """tune read the log format with --log-format (its --format was the deprecated --export): --format is now the
    log format as in every command; --log-format is a hidden alias (a note), both names at once refused."""
    from cli_helpers import run_main

    tune = COMMAND_OBJECTS["tune"]
    assert "--log-format" not in _options(tune)
    assert [p.hidden for p in tune.params if isinstance(p, click.Option) and "--log-format" in p.opts] == [True]
    log = tmp_path / "flight.log"
    log.write_bytes(b"\x00\x01 not a log")
    base = ("tune", str(log), "--tp", "0.04", "--loop", "altitude")
    new, old = run_main(*base, "--format", "csv"), run_main(*base, "--log-format", "csv")
    assert new.returncode == old.returncode == 3 and "not a CSV" in new.stderr
    assert "--log-format is deprecated; use --format FMT" in old.stderr and "deprecated" not in new.stderr
    both = run_main(*base, "--log-format", "csv", "--format", "csv")
    assert both.returncode == 2 and "give --format only" in both.stderr


@pytest.mark.parametrize(("value", "fix"), [("px4", "--export px4"), ("hear", "--export hear"),
                                            ("json", "--export generic"), ("table", "default output")])
def test_tunes_old_export_values_of_format_are_refused_with_the_fix(value, fix):
    """--format px4 on a .ulg reads as the log's format to a user, but was tune's deprecated export: refused (a
    usage error, one line) naming the log formats and the option the value is now, before any work."""
    from cli_helpers import run_main

    from mrftcli.io import READ_FORMATS

    proc = run_main("tune", "--tp", "0.04", "--td", "0.01", "--tau", "0.2", "--k", "30", "--loop", "roll",
                    "--controller-rate", "200", "--format", value)
    assert proc.returncode == 2 and proc.stdout == "" and len(proc.stderr.splitlines()) == 1, proc.stderr
    assert f"--format {value} is not a log format" in proc.stderr and fix in proc.stderr
    assert ", ".join(READ_FORMATS) in proc.stderr


def test_quiet_on_every_command_with_a_progress_bar():
    for name in PROGRESS:
        param = _options(COMMAND_OBJECTS[name]).get("--quiet")
        assert param is not None and param.is_flag and "-q" in param.opts, name


def test_min_cycles_wherever_tests_are_segmented():
    assert {"analyze", "diagnose", "plan", "tune", "watch", "batch"} <= set(_where("--min-cycles"))


def test_out_means_one_kind_of_thing_per_command():
    where = _where("--out")
    assert set(where) == set(OUT_KIND)
    for name, param in where.items():
        assert "-o" in param.opts, name


def test_help_names_docs_that_exist():
    runner = CliRunner()
    for name in COMMANDS:
        text = runner.invoke(cli, [name, "--help"]).stdout
        for doc in re.findall(r"docs/[\w./-]+\.md", text.replace("\n", " ")):
            assert (ROOT / doc).is_file(), f"{name} --help names {doc}"


PREDICT = ["predict", "--tp", "0.1", "--td", "0.7042", "--tau", "0.06", "--beta", "-0.4"]


def test_bare_json_is_stdout_and_file_is_written(tmp_path):
    runner = CliRunner()
    bare = runner.invoke(cli, [*PREDICT, "--json"])
    assert bare.exit_code == 0, bare.output
    data = json.loads(bare.stdout)
    dash = runner.invoke(cli, [*PREDICT, "--json", "-"])
    assert json.loads(dash.stdout) == data
    target = tmp_path / "p.json"
    to_file = runner.invoke(cli, [*PREDICT, "--json", str(target)])
    assert to_file.exit_code == 0 and json.loads(target.read_text()) == data
    assert "frequency" in to_file.stdout  # the table as well: only '-' replaces it


def test_rate_is_a_deprecated_alias():
    runner = CliRunner()
    new = runner.invoke(cli, [*PREDICT, "--controller-rate", "200", "--json", "-"])
    old = runner.invoke(cli, [*PREDICT, "--rate", "200", "--json", "-"])
    assert new.exit_code == old.exit_code == 0
    assert json.loads(old.stdout) == json.loads(new.stdout)
    # the sampled relay's figures differ from the continuous one's: the alias's value is used
    assert json.loads(old.stdout) != json.loads(runner.invoke(cli, [*PREDICT, "--json", "-"]).stdout)
    assert old.stderr.strip() == "note: --rate is deprecated; use --controller-rate HZ (same meaning)"
    assert new.stderr == ""
    both = runner.invoke(cli, [*PREDICT, "--rate", "100", "--controller-rate", "200"])
    assert both.exit_code == 2


def test_predict_refuses_options_its_model_or_relay_does_not_take():
    """--eps on an MRFT and eq. (2)'s --tp/--td/--tau beside a family's --param: one line naming the option,
    exit 2 (they were read as a hysteresis relay's advice to use a --relay option predict has not, and ignored)."""
    runner = CliRunner()
    eps = runner.invoke(cli, [*PREDICT, "--eps", "0.1"])
    assert eps.exit_code == 2 and "--eps" in eps.stderr and "--relay" not in eps.stderr
    family = ["predict", "--model", "fopdt", "--param", "K=1", "--param", "T=1", "--param", "tau=0.1", "--beta", "-0.3"]
    assert runner.invoke(cli, family).exit_code == 0
    mixed = runner.invoke(cli, [*family, "--tau", "0.2"])
    assert mixed.exit_code == 2 and "--tau is for --model soiptd" in mixed.stderr
    height = runner.invoke(cli, [*PREDICT, "--h", "-1"])  # an InputError: main() prints its one line, exit 2
    assert height.exit_code != 0 and "--h must be a positive number" in str(height.exception)
    assert "Traceback" not in eps.stderr + mixed.stderr


def test_identify_with_one_beta_exits_6():
    from mrftcli.cli.main import main

    with pytest.raises(SystemExit) as exc:
        main(["identify", "--tp", "0.1", "--test", "-0.4:0.7"])
    assert exc.value.code == 6


def test_shell_completion_completes_commands_and_choices():
    """click's completion (docs/usage.md): the lazy group lists its commands, --loop its choices."""
    runner = CliRunner()

    def complete(words: str, cword: int) -> list[str]:
        env = {"_MRFT_IDENT_COMPLETE": "bash_complete", "COMP_WORDS": words, "COMP_CWORD": str(cword)}
        return runner.invoke(cli, [], prog_name="mrft-ident", env=env).stdout.split()

    assert "plain,analyze" in complete("mrft-ident ana", 1)
    assert [w.split(",")[1] for w in complete("mrft-ident analyze --loop ", 3)] == list(LOOPS)
    assert "plain,--controller-rate" in complete("mrft-ident predict --contr", 2)
