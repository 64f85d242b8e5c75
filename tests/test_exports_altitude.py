"""ArduPilot's altitude cascade (tracker issue 25): refused with the quantity the model lacks named, its
ranges vendored with their source; the CLI says it in one line."""

from __future__ import annotations

import pytest

from mrftcli.errors import InputError
from mrftcli.tune.stack_params import STACK_PARAMS, check_ranges, param
from mrftcli.tune.stacks import check_exportable


def test_refusal_names_the_missing_quantities_and_the_source():
    with pytest.raises(InputError) as err:
        check_exportable("ardupilot", "altitude", "PD")
    msg = str(err.value)
    assert "\n" not in msg and "PSC_ACCZ" in msg and "AC_PosControl.cpp" in msg
    assert "accelerometer path" in msg and "EKF velocity's lag" in msg  # what is not identified
    assert "--export px4" in msg  # what can be done instead


def test_psc_ranges_are_vendored_with_their_source():
    rows = {p.name: p for p in STACK_PARAMS if p.name.startswith("PSC_")}
    assert {"PSC_POSZ_P", "PSC_VELZ_P", "PSC_ACCZ_P", "PSC_ACCZ_I", "PSC_ACCZ_D"} <= set(rows)
    assert all("AC_PosControl.cpp" in p.source and p.stack == "ardupilot" for p in rows.values())
    assert (param("ardupilot", "PSC_ACCZ_P").minimum, param("ardupilot", "PSC_ACCZ_P").maximum) == (0.2, 1.5)
    assert [v.param.name for v in check_ranges("ardupilot", {"PSC_POSZ_P": 0.5, "PSC_VELZ_P": 5.0})] == ["PSC_POSZ_P"]


def test_cli_refuses_in_one_line(capsys):
    from mrftcli.cli.main import main

    with pytest.raises(SystemExit) as ex:
        main(["tune", "--tp", "0.0422", "--td", "3.0", "--tau", "0.05", "--k", "10", "--loop", "altitude",
              "--export", "ardupilot"])
    err = capsys.readouterr().err
    assert ex.value.code == 2 and len(err.strip().splitlines()) == 1 and "PSC_ACCZ" in err
