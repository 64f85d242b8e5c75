"""One g in the package: standard gravity 9.80665 m/s^2 (CGPM 1901; PX4's CONSTANTS_ONE_G), where the cascade
model, the simulator and its HEAR writer used 9.81 and tune's stack parameters 9.80665."""

from __future__ import annotations

import pytest

#: the CGPM's standard gravity (3rd CGPM, 1901), exact by definition [m/s^2]
G_N = 9.80665


def test_one_g_for_the_cascade_the_simulator_and_the_stacks() -> None:
    from mrftcli.analyze.cascade import OUTER_COMMANDS
    from mrftcli.mrft import cascade
    from mrftcli.mrft.cascade import STANDARD_GRAVITY
    from mrftcli.sim import cascade_spec
    from mrftcli.tune import stack_params, stacks

    assert STANDARD_GRAVITY == G_N
    # one public name: the modules that use g import it, none re-exports it (it had five names)
    assert not hasattr(cascade, "G")
    assert all("STANDARD_GRAVITY" not in m.__all__ for m in (cascade_spec, stack_params, stacks))
    assert OUTER_COMMANDS["attitude"] == G_N  # analyze's K of a commanded attitude
    fields = {f.name: f for f in cascade_spec.CascadeSpec.__dataclass_fields__.values()}
    assert fields["g"].default == G_N  # simulate --cascade's y'' = g phi


def test_the_hear_writer_logs_the_hover_thrust_as_g(tmp_path) -> None:
    """The HEAR bag's /fh_des z (the hover thrust in m/s^2) is g, read back by the reader (was 9.81)."""
    from mrftcli.io import open_log
    from mrftcli.mrft.model import LoopModel
    from mrftcli.sim.cascade import simulate_cascade
    from mrftcli.sim.cascade_spec import CascadeSpec, InnerGains
    from mrftcli.sim.cascade_write import write_cascade
    from mrftcli.sim.spec import TestSpec

    spec = CascadeSpec(inner=LoopModel(0.04, 1.3, 0.03, 30.0), gains=InnerGains(0.4, 0.0, 0.06, 0.006, 100.0),
                       Td=0.8, tau=0.03, outer_tests=(TestSpec(-0.3, 1.0, 2.0),), hover_s=0.5, hold_s=0.5, seed=1)
    log = tmp_path / "flight.bag"
    write_cascade(simulate_cascade(spec), log, layout="hear-ros")
    with open_log(log, echo_warnings=False) as src:
        _, leaves, values = src.values(src.resolve_topic("/fh_des"), "z")
    assert values[leaves[0]] == pytest.approx(G_N, abs=0)
