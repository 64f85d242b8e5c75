"""``mrft-ident predict``: the exact MRFT limit cycle of a model of eq. (2)."""

from __future__ import annotations

import click

from .options import BETA, dump_json, tp_option


@click.command("predict")
@tp_option(help="Propulsion time constant Tp [s].")
@click.option("--td", "Td", type=float, required=True, help="Drag time constant Td [s].")
@click.option("--tau", type=float, required=True, help="Loop delay tau [s].")
@click.option("--k", "K", type=float, default=1.0, show_default=True, help="Gain K (K*Td = rate gain).")
@click.option("--beta", type=BETA, required=True, help="MRFT parameter beta in (-1, 1).")
@click.option("--h", type=float, default=1.0, show_default=True, help="Relay amplitude h [command units].")
@click.option("--rate", "rate_hz", type=float, default=None, help="Relay rate [Hz] (sampled relay); default continuous.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of a table.")
def predict(Tp: float, Td: float, tau: float, K: float, beta: float, h: float, rate_hz: float | None,
            as_json: bool) -> None:
    """Predict the MRFT limit cycle (frequency in Hz, amplitude) of G(s) = K Td e^{-tau s}/(s(Tp s+1)(Td s+1)).

    Exact (LPRS) for the continuous relay. With --rate, the centre of the band of limit cycles of the
    sampled relay and every admissible sampled orbit. The describing-function estimate is shown for
    comparison.
    """
    from ..mrft.describing import describing_function_limit_cycle
    from ..mrft.lprs import mrft_limit_cycle
    from ..mrft.model import LoopModel

    model = LoopModel(Tp, Td, tau, K)
    lc = mrft_limit_cycle(model, beta, h, rate_hz)
    df_f, df_a = describing_function_limit_cycle(model, beta, h)
    out = lc.to_dict()
    out.update({"model": {"Tp": Tp, "Td": Td, "tau": tau, "K": K},
                "describing_function": {"frequency_hz": df_f, "amplitude": df_a}})
    if as_json:
        dump_json(out, None)
        return
    rows = [
        ("model", f"Tp={Tp:g} s  Td={Td:g} s  tau={tau:g} s  K={K:g}"),
        ("MRFT", f"beta={beta:g}  h={h:g}" + (f"  rate={rate_hz:g} Hz" if rate_hz else "  (continuous relay)")),
        ("frequency", f"{lc.frequency_hz:.6g} Hz  ({lc.omega:.6g} rad/s, period {lc.period:.6g} s)"),
        ("amplitude", f"{lc.amplitude:.6g}"),
        ("tau*Omega", f"{lc.delay_phase:.6g} rad"),
    ]
    if rate_hz:
        orbits = ", ".join(f"{f:.5g}" for f in lc.orbits_hz) or "none (quasi-periodic)"
        rows.append(("sampled orbits", f"{orbits} Hz"))
    rows.append(("DF estimate", f"{df_f:.6g} Hz, amplitude {df_a:.6g}  (approximate, for comparison)"))
    width = max(len(r[0]) for r in rows)
    for name, value in rows:
        click.echo(f"{name:<{width}}  {value}")
