"""Issue 40 item 7, from the CLI: bare ``mrft-ident`` prints its help (not inside an error); Ctrl-C is
worded alike in every command; a file that is no log given to ``watch`` is called so."""

from __future__ import annotations

from pathlib import Path

from cli_helpers import run_cli

REPO = Path(__file__).resolve().parents[1]


def test_bare_command_prints_its_help(capsys):
    code, out, err = run_cli(capsys)
    assert code == 0 and out.startswith("Usage: mrft-ident") and "Commands:" in out
    assert "error" not in err.lower()


def test_ctrl_c_is_worded_as_in_watch(capsys, monkeypatch):
    import mrftcli.plan

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(mrftcli.plan, "plan_tests", interrupted)
    code, _, err = run_cli(capsys, "plan", "--tp", "0.0422", "--max-amplitude", "0.05", "--max-h", "0.2", "--time",
                           "30", "--controller-rate", "200", "--noise", "0.0002", "-q")
    assert code == 130 and err.strip() == "interrupted: stopped mrft-ident plan (Ctrl-C)"


def test_watch_says_a_png_is_not_a_log(tmp_path, capsys):
    png = tmp_path / "plot.png"
    png.write_bytes((REPO / "docs" / "img" / "diagnose_dead_zone.png").read_bytes())
    code, _, err = run_cli(capsys, "watch", str(png), "--tp", "0.0422", "--idle", "0.5")
    assert code == 3 and "not a log" in err and "no data in the log" not in err
