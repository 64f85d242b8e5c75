"""``mrft-ident predict``: the exact MRFT limit cycle of a model of eq. (2)."""

from __future__ import annotations

import click

from .model_options import build_model, structure_options
from .options import BETA, controller_rate_option, dump_json, json_option, tp_option


@click.command("predict")
@tp_option(required=False, help="Propulsion time constant Tp [s] (--model soiptd).")
@structure_options
@click.option("--eps", type=float, default=0.0, show_default=True,
              help="Relay hysteresis [output units] (0: MRFT; with --beta 0 a relay with hysteresis).")
@click.option("--td", "Td", type=float, default=None, help="Drag time constant Td [s] (--model soiptd).")
@click.option("--tau", type=float, default=None, help="Loop delay tau [s] (--model soiptd).")
@click.option("--k", "K", type=float, default=1.0, show_default=True, help="Gain K (K*Td = rate gain).")
@click.option("--beta", type=BETA, required=True, help="MRFT parameter beta in (-1, 1).")
@click.option("--h", type=float, default=1.0, show_default=True, help="Relay amplitude h [command units].")
@controller_rate_option("rate_hz", detail="at which the relay decides (a sampled relay; default: continuous).")
@json_option()
def predict(Tp: float | None, model_name: str, params: tuple[str, ...], ranges: tuple[str, ...], eps: float,
            Td: float | None, tau: float | None, K: float, beta: float, h: float, rate_hz: float | None,
            json_target: str | None) -> None:
    """Predict the MRFT limit cycle (frequency in Hz, amplitude) of G(s) = K Td e^{-tau s}/(s(Tp s+1)(Td s+1)).

    Exact (LPRS) for the continuous relay. With --controller-rate, the centre of the band of limit cycles of the
    sampled relay and every admissible sampled orbit. The describing-function estimate is shown for
    comparison.
    """
    from ..mrft.describing import describing_function_limit_cycle
    from ..mrft.lprs import mrft_limit_cycle
    from ..mrft.model import LoopModel

    if model_name != "soiptd":
        _predict_process(model_name, params, ranges, eps, beta, h, rate_hz, json_target)
        return
    if Tp is None or Td is None or tau is None or params or ranges or eps:
        raise click.UsageError("--model soiptd takes --tp, --td and --tau (--param, --range and --eps are for "
                               "process models)")

    model = LoopModel(Tp, Td, tau, K)
    lc = mrft_limit_cycle(model, beta, h, rate_hz)
    df_f, df_a = describing_function_limit_cycle(model, beta, h)
    out = lc.to_dict()
    out.update({"model": {"Tp": Tp, "Td": Td, "tau": tau, "K": K},
                "describing_function": {"frequency_hz": df_f, "amplitude": df_a}})
    if json_target:
        dump_json(out, json_target)
    if json_target == "-":
        return
    rows = [
        ("model", f"Tp={Tp:g} s  Td={Td:g} s  tau={tau:g} s  K={K:g} [output units/s² per command unit]"),
        ("MRFT", f"beta={beta:g}  h={h:g} [command units]" + (f"  rate={rate_hz:g} Hz" if rate_hz else "  (continuous relay)")),
        ("frequency", f"{lc.frequency_hz:.6g} Hz  ({lc.omega:.6g} rad/s, period {lc.period:.6g} s)"),
        ("amplitude", f"{lc.amplitude:.6g} [output units]"),
        ("tau*Omega", f"{lc.delay_phase:.6g} rad"),
    ]
    if rate_hz:
        orbits = ", ".join(f"{f:.5g}" for f in lc.orbits_hz) or "none (quasi-periodic)"
        rows.append(("sampled orbits", f"{orbits} Hz"))
    rows.append(("DF estimate", f"{df_f:.6g} Hz, amplitude {df_a:.6g} [output units]  (approximate, for comparison)"))
    width = max(len(r[0]) for r in rows)
    for name, value in rows:
        click.echo(f"{name:<{width}}  {value}")


def _predict_process(model_name: str, params: tuple[str, ...], ranges: tuple[str, ...], eps: float, beta: float,
                     h: float, rate_hz: float | None, json_target: str | None) -> None:
    """``predict --model NAME --param K=.. --param tau=.. ...``: the exact cycle under an MRFT or a hysteresis relay."""
    from ..errors import InputError
    from ..mrft.relays import RelayLaw

    model = build_model(model_name, params, ranges)
    missing = [p.name for p in model.parameters.values() if not p.known]
    if missing:
        raise InputError(f"predict --model {model_name} needs every parameter: add --param "
                         + " ".join(f"{n}=VALUE" for n in missing))
    kind = "mrft" if beta != 0 else ("hysteresis" if eps else "ideal")
    relay = RelayLaw(kind, h, -h, beta=beta, eps=eps, source="stated")
    lc = relay.limit_cycle(model, rate_hz)
    out = {**lc.to_dict(), "model": model.to_json(), "relay": relay.to_json()}
    if json_target:
        dump_json(out, json_target)
    if json_target == "-":
        return
    values = "  ".join(f"{p.name}={p.value:g} {p.unit}" for p in model.parameters.values())
    click.echo(f"model      {model.family}: G(s) = {model.structure};  {values}")
    click.echo(f"{relay.describe()}" + (f", rate {rate_hz:g} Hz" if rate_hz else " (continuous relay)"))
    click.echo(f"frequency  {lc.frequency_hz:.6g} Hz  ({lc.omega:.6g} rad/s, period {lc.period:.6g} s)")
    click.echo(f"amplitude  {lc.amplitude:.6g} [output units]")
