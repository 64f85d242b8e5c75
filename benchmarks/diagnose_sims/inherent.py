"""What a simulator carries on every flight that the library models (issue 39): a second reading of the scores.

RotorPy's motors are a first-order lag on the rotor speed and its thrust is ``k omega^2``; the
benchmark commands each motor ``omega_0 sqrt(u)`` (``u`` collective thrust / weight, hover 1). With
``s = omega / (omega_0 sqrt(u_0)) - 1`` that is ``s' = (sqrt(1 + w / u_0) - 1 - s) / tau_m`` and a thrust
``u_0 ((1 + s)^2 - 1)`` beyond hover: the library's ``thrust_rectification`` exactly, with ``F = u_0 = 1``
command unit (``mrftcli.diagnose.physics``). So every RotorPy flight carries it, more visibly the larger
``h`` and ``tau_m omega``; a "clean" RotorPy flight on which it is named is named right, and it is no
spurious second effect beside the effect flown.

JSBSim's F450 carries the same physics: its propellers' thrust at J = 0 is ``C_THRUST(0) rho n^2 D^4``
(``engine/DJI_9450.xml``) and its E305 motors' rotor speed follows the throttle through the rotor's
inertia (``FGBrushLessDCMotor``: a lag on n, not the same up and down); the benchmark linearises the
command through the static thrust curve measured on a stand, so the command asks for ``n ~ sqrt(u)``
and the thrust is ``n^2``: ``thrust_rectification`` with F = 1 again. Measured on the stand (the
simulator's motors, not the library's code: ``jsbsim_flight.stand_rectification``), the F whose
mean-thrust deficit under a square wave 1 +- h equals JSBSim's is 0.87-1.21 (h 0.15-0.3, 1.5-3 Hz).
(Before the stand, the thrust table was read on a climbing vehicle and the flights carried a
concave command->thrust map beside it: no effect of the library was counted then.)

The benchmark's figures against the issue's targets stay the strict ones (nothing named on a clean
flight, one effect on the others); :func:`inherent_reading` prints beside them the figures with the
simulator's own physics counted as present, and the F found against the true 1. Both simulators
also carry physics the library lacks (JSBSim's propellers damp a climb only: the thrust table starts
at J = 0; its motors spin up and down at different rates), which nothing here counts.
"""

from __future__ import annotations

__all__ = ["INHERENT", "inherent_reading"]

#: per simulator: the library's effects the simulator has on every flight, with their true value
INHERENT: dict[str, dict[str, float]] = {"rotorpy": {"thrust_rectification": 1.0},
                                         "jsbsim": {"thrust_rectification": 1.0}}


def inherent_reading(sim: str, results: list[dict]) -> None:
    """Print the clean and spurious-second figures with the simulator's own physics counted as present."""
    from bench_diagnose import _pct  # noqa: PLC0415 - the benchmark's percentage, one home (benchmarks/ on the path)

    own = INHERENT.get(sim, {})
    if not own:
        return
    clean = [r for r in results if r["effect"] is None and r.get("error") is None]
    kept = [r for r in clean if not set(r.get("found") or []) - set(own) and not r.get("unexplained")]
    named = [r for r in results if r["effect"] is not None and r["effect"] in (r.get("found") or [])]
    alone = [r for r in named if not set(r["found"]) - {r["effect"], *own}]
    values = [f"{name} {r['values'][name]:.3g}/{true:g}" for r in results for name, true in own.items()
              if name in (r.get("found") or []) and name in r.get("values", {})]
    print(f"  with {sim}'s own physics counted as present ({', '.join(f'{k} = {v:g}' for k, v in own.items())}; "
          "diagnose_sims/inherent.py):")
    print(f"    clean flights answered with nothing but it: {_pct(len(kept), len(clean))}; "
          f"named right with no other second effect: {_pct(len(alone), len(named))}")
    print(f"    its value found/true where named: {', '.join(values) or 'none'}")
