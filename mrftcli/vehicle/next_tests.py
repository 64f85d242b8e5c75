"""What to fly next for a loop the flight gives no model for (:class:`~mrftcli.vehicle.record.MissingLoop`).

A loop flown at a single beta has a test to plan from: :func:`mrftcli.plan.plan_tests` designs the
next test within the limits that test flew at (its amplitude, its relay height), and the plan's
assumptions say what else it took. A loop without a usable test gets the ``mrft-ident plan`` command
that designs its first tests, with the limits left for the user to give (they are the vehicle's, not
the log's).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from ..errors import InputError, InsufficientDataError, MrftError, SegmentationError, TpRejectedError
from ..mrft.model import soiptd_model
from ..plan import PlanLimits, PlanOptions, PlanResult, Prior, flown_from_result, plan_tests
from ..sim import default_noise_std
from .loops import INNER_OF
from .record import MissingLoop

__all__ = ["PLAN_TIME_S", "NOT_FOLLOWING", "missing_from_error", "missing_topics"]

#: How a rejected test's reason starts when the loop's output does not follow the relay at all.
NOT_FOLLOWING = "the output does not follow this relay"
#: Relay time [s] a planned next test is given (stated in the plan's assumptions).
PLAN_TIME_S = 20.0
#: The plan command's prior ranges when nothing is known yet (``mrft-ident plan``'s defaults).
_PRIOR = Prior(Td=(0.2, 3.0), tau=(0.01, 0.1), K=(0.5, 20.0))


def _plan_command(loop: str, Tp: float, log: str | None = None) -> str:
    source = f" --from {log}" if log else ""
    return f"mrft-ident plan --tp {Tp:g} --loop {loop}{source} --max-amplitude A --max-h H --time S"


def _after_inner(loop: str) -> str:
    inner = INNER_OF.get(loop)
    return f" once the {inner} loop's new gains are loaded" if inner else ""


def missing_topics(loop: str, absent: tuple[str, ...], Tp: float) -> MissingLoop:
    """A loop whose command or output topic the log does not hold."""
    return MissingLoop(loop, "no-topics", f"the log does not record the {loop} loop ({', '.join(absent)})",
                       f"record the {loop} loop's command and output and fly MRFT tests on it at two betas"
                       f"{_after_inner(loop)} ({_plan_command(loop, Tp)} designs them)")


def _single_beta_plan(loop: str, Tp: float, partial: dict[str, Any], rate_hz: float | None) -> PlanResult | None:
    """The next test after a single-beta flight, planned within the limits that test flew at."""
    try:
        flown, _ = flown_from_result({"partial": partial})
        rate = rate_hz or max((float(t.get("rate_hz") or 0.0) for t in partial.get("tests", ())), default=0.0)
        if not flown or not rate:
            return None
        noise = default_noise_std(loop)
        limits = PlanLimits(max_amplitude=max(f.amplitude for f in flown), max_h=max(f.h for f in flown),
                              time_s=PLAN_TIME_S, rate_hz=rate, noise_std=noise)
        plan = plan_tests(soiptd_model(Tp), limits, prior=_PRIOR, flown=flown, options=PlanOptions(n_tests=1))
    except MrftError:
        return None  # the hint below names the plan command instead
    assumed = (f"the flown test's amplitude {limits.max_amplitude:.3g} and relay height {limits.max_h:.3g} as "
               "the limits (give mrft-ident plan --max-amplitude/--max-h for others)",
               f"{PLAN_TIME_S:g} s of relay time (--time)",
               f"sensor noise std {noise:.3g} (the {loop} loop's default; --noise)",
               f"prior Td {_PRIOR.Td[0]:g}-{_PRIOR.Td[1]:g} s, tau {_PRIOR.tau[0]:g}-{_PRIOR.tau[1]:g} s, "
               f"K {_PRIOR.K[0]:g}-{_PRIOR.K[1]:g} (plan's defaults; --td-range/--tau-range/--k-range)")
    return dataclasses.replace(plan, assumptions=(*plan.assumptions, *assumed))


def missing_from_error(loop: str, err: MrftError, Tp: float, log: str, rate_hz: float | None = None,
                       plan: bool = True) -> MissingLoop:
    """The missing loop an analysis error leaves, with what to fly next.

    Parameters
    ----------
    loop : str
    err : MrftError
        What the loop's analysis raised.
    Tp : float
        Known propulsion time constant [s] (of the plan).
    log : str
        The log (named in the plan command).
    rate_hz : float, optional
        Controller rate [Hz] of the plan; None: the flown test's.
    plan : bool
        Plan the next test of a single-beta loop (:func:`mrftcli.plan.plan_tests`, about a second).
    """
    message = " ".join(str(err).split())
    if isinstance(err, InsufficientDataError):
        planned = _single_beta_plan(loop, Tp, err.partial, rate_hz) if plan else None
        if planned is not None and planned.tests:
            t = planned.tests[0]
            hint = (f"fly one more test on the {loop} loop at beta {t.beta:+.2f}, h {t.h:.3g}, for {t.duration_s:.0f} s "
                    f"(planned from the flown test; the plan's assumptions are in the JSON)")
        else:
            hint = f"fly a second test on the {loop} loop at another beta ({_plan_command(loop, Tp, log)} designs it)"
        return MissingLoop(loop, "single-beta", message, hint, planned)
    if isinstance(err, SegmentationError):
        reasons = [str(t.get("reason", "")) for t in err.rejected_tests or ()]
        if reasons and all(r.startswith(NOT_FOLLOWING) for r in reasons):
            # a command topic several loops share (the reference layout's /mrft/command): the relay
            # moved, this loop's output did not follow it, so the tests were another loop's
            message = (f"no MRFT test of the {loop} loop: the {len(reasons)} relay test(s) on its command topic "
                       f"do not move its output (another loop's tests)")
            err = SegmentationError(message)
        if err.rejected_tests:
            return MissingLoop(loop, "unusable-tests", message,
                               f"fly the {loop} loop's tests again, longer and within the limits the message "
                               f"names{_after_inner(loop)} ({_plan_command(loop, Tp, log)} designs them)")
        return MissingLoop(loop, "no-tests", message,
                           f"fly MRFT tests on the {loop} loop at two betas{_after_inner(loop)} "
                           f"({_plan_command(loop, Tp)} designs them)")
    if isinstance(err, TpRejectedError):
        return MissingLoop(loop, "wrong-tp", message,
                           f"no new test needed: rerun with --tp {err.best:.4g} (the Tp this flight fits), or "
                           f"--accept-tp to keep {Tp:g} s")
    if isinstance(err, InputError) and "topic" in message:
        return MissingLoop(loop, "no-topics", message,
                           f"record the {loop} loop's command and output and fly MRFT tests on it at two betas")
    return MissingLoop(loop, "failed", message,
                       f"see the message; mrft-ident analyze {log} --loop {loop} --tp {Tp:g} shows the details")
