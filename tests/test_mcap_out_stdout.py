"""analyze --mcap-out - wrote the binary overlay to a FILE named '-' in the working folder and printed 'mcap: -' (E8's
user check; every other output takes '-' as stdout): refused in one line before the work, nothing written."""

from __future__ import annotations

import pytest

from mrftcli.errors import InputError
from mrftcli.io.overlay import check_overlay_path


def test_mcap_out_dash_is_refused_before_the_work(tmp_path, monkeypatch, capsys):
    import mrftcli.analyze
    from mrftcli.cli.main import main
    from mrftcli.samples import sample_log

    with pytest.raises(InputError, match="binary MCAP file"):
        check_overlay_path("-")

    def no_work(*args, **kwargs):
        raise AssertionError("analyze identified the log before checking --mcap-out")

    monkeypatch.setattr(mrftcli.analyze, "analyze_flight", no_work)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as code:
        main(["analyze", str(sample_log("design1_altitude.csv")), "--tp", "0.0422", "--json", "-", "--mcap-out", "-",
              "-q"])
    out, err = capsys.readouterr()
    assert code.value.code == 2 and err.count("\n") == 1 and "--mcap-out" in err and out == ""
    assert not (tmp_path / "-").exists()


def test_mcap_out_help_says_it_is_a_file_not_stdout(capsys):
    # every other output takes '-' as stdout; --help said nothing of --mcap-out's refusal of it (review R3 #8)
    from mrftcli.cli.main import main

    with pytest.raises(SystemExit):
        main(["analyze", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "(a binary file; not '-')" in help_text
