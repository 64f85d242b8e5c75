"""``mrft-ident predict``: the exact limit cycle of a model (eq. (2) or a process family) under a relay."""

from __future__ import annotations

import click

from .model_options import build_model, structure_options, structure_text
from .options import BETA, controller_rate_option, dump_json, json_option, tp_option


@click.command("predict")
@tp_option(required=False, help="Propulsion time constant Tp [s] (--model soiptd).")
@structure_options
@click.option("--eps", type=float, default=0.0, show_default=True,
              help="Relay hysteresis [output units] (0: MRFT; with --beta 0 a relay with hysteresis).")
@click.option("--td", "Td", type=float, default=None, help="Drag time constant Td [s] (--model soiptd).")
@click.option("--tau", type=float, default=None, help="Loop delay tau [s] (--model soiptd).")
@click.option("--k", "K", type=float, default=1.0, show_default=True, help="Gain K [output unit / s^2 per command unit, e.g. m/s^2 for altitude] (K*Td = rate gain).")
@click.option("--beta", type=BETA, required=True, help="MRFT parameter beta in (-1, 1).")
@click.option("--h", type=float, default=1.0, show_default=True, help="Relay amplitude h [command units].")
@controller_rate_option("rate_hz", detail="at which the relay decides (a sampled relay; default: continuous).")
@json_option()
def predict(Tp: float | None, model_name: str, params: tuple[str, ...], ranges: tuple[str, ...], eps: float,
            Td: float | None, tau: float | None, K: float, beta: float, h: float, rate_hz: float | None,
            json_target: str | None) -> None:
    """Predict the relay's limit cycle (frequency in Hz, amplitude) of a model: by default eq. (2),
    G(s) = K Td e^{-tau s}/(s(Tp s+1)(Td s+1)) from --tp, --td, --tau, --k; a process family from --model and --param.

    Exact (LPRS) for the continuous relay. With --controller-rate, the centre of the band of limit cycles of the
    sampled relay and every admissible sampled orbit. For eq. (2) the describing-function estimate is shown for
    comparison.
    """
    from ..mrft.describing import describing_function_limit_cycle
    from ..mrft.model import LoopModel
    from ..mrft.relays import Prediction, RelayLaw
    from ..validate import check_positive

    model = _model(Tp, model_name, params, ranges, eps, Td, tau, K)
    if eps and beta != 0:
        raise click.UsageError("--eps is the hysteresis of a relay with --beta 0; an MRFT (--beta B) has none: "
                               "leave --eps out, or give --beta 0")
    kind = "mrft" if beta != 0 else ("hysteresis" if eps else "ideal")
    h = check_positive("--h", h)
    relay = RelayLaw(kind, h, -h, beta=beta, eps=eps, source="stated")
    lc = relay.limit_cycle(model, rate_hz)
    rows = [("model", f"{model.family}: G(s) = {structure_text(model)};  "
                      + "  ".join(f"{p.name}={p.value:g} {p.unit}" for p in model.parameters.values())),
            ("relay", relay.describe()[len("relay: "):] + " [command units]"
                      + (f", rate {rate_hz:g} Hz" if rate_hz else " (continuous relay)")),
            ("frequency", f"{lc.frequency_hz:.6g} Hz  ({lc.omega:.6g} rad/s, period {lc.period:.6g} s)"),
            ("amplitude", f"{lc.amplitude:.6g} [output units]"),
            ("tau*Omega", f"{lc.delay_phase:.6g} rad")]
    if rate_hz:
        orbits = ", ".join(f"{f:.5g}" for f in lc.orbits_hz) or "none (quasi-periodic)"
        rows.append(("sampled orbits", f"{orbits} Hz"))
    df = None
    if isinstance(model, LoopModel) and not eps:  # eq. (2)'s closed-form approximation, for comparison
        df = df_f, df_a = describing_function_limit_cycle(model, beta, h)
        rows.append(("DF estimate", f"{df_f:.6g} Hz, amplitude {df_a:.6g} [output units]  (approximate, for comparison)"))
    if json_target:
        dump_json(Prediction(lc, model, relay, df).to_json(), json_target)
    if json_target == "-":
        return
    width = max(len(r[0]) for r in rows)
    for name, value in rows:
        click.echo(f"{name:<{width}}  {value}")


def _model(Tp: float | None, model_name: str, params: tuple[str, ...], ranges: tuple[str, ...], eps: float,
           Td: float | None, tau: float | None, K: float):
    """The model to predict, every parameter given: eq. (2) from --tp/--td/--tau/--k, a family from --param."""
    from ..errors import InputError
    from ..mrft.model import LoopModel

    if model_name == "soiptd":
        if Tp is None or Td is None or tau is None or params or ranges:
            raise click.UsageError("--model soiptd takes --tp, --td and --tau (--param and --range are for "
                                   "process models)")
        return LoopModel(Tp, Td, tau, K)
    given = [name for name, value in (("--tp", Tp), ("--td", Td), ("--tau", tau)) if value is not None]
    if given:
        raise click.UsageError(f"{', '.join(given)} {'is' if len(given) == 1 else 'are'} for --model soiptd; "
                               f"--model {model_name} takes its parameters as --param NAME=VALUE")
    model = build_model(model_name, params, ranges)
    missing = [p.name for p in model.parameters.values() if not p.known]
    if missing:
        raise InputError(f"predict --model {model_name} needs every parameter: add --param "
                         + " ".join(f"{n}=VALUE" for n in missing))
    return model
