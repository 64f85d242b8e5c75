"""The knobs of one analysis (:func:`mrftcli.analyze.analyze_flight`) as one frozen, checked record.

How a log is read is :class:`mrftcli.io.ReadOptions`; how its tests are screened and identified is
:class:`AnalyzeOptions` (with the relay stated, :class:`RelayOptions`, and the windows of the log to
use), for every model family. Every caller (``analyze``, ``tune``, ``batch``, ``watch``, ``diagnose``,
``plan``) builds one record instead of repeating a keyword list.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Integral

from ..errors import InputError
from ..io.logtypes import Signal
from ..mrft.cascade import InnerLoop
from ..mrft.consensus import CONSTRAINTS
from ..segment import StabilityCriterion, ValidityCriterion
from ..validate import check_positive

__all__ = ["AnalyzeOptions", "RelayOptions", "CascadeOptions", "TRY_DIAGNOSE", "TRY_DIAGNOSE_COMMAND"]

#: :attr:`AnalyzeOptions.diagnose_hint` of a command that has ``--diagnose`` (``analyze``, ``batch``) without it
TRY_DIAGNOSE = " (try --diagnose)"
#: :attr:`AnalyzeOptions.diagnose_hint` of a caller without ``--diagnose`` (``tune``, ``vehicle``, ``plan``, a library
#: caller): the default
TRY_DIAGNOSE_COMMAND = " (try mrft-ident diagnose)"

#: the relays a process-plant analysis is told about (:func:`mrftcli.segment.relay_type.infer_relay`)
RELAY_KINDS = ("mrft", "ideal", "hysteresis")


@dataclass(frozen=True)
class RelayOptions:
    """What the user states about the relay (None: inferred from the data, per test).

    Attributes
    ----------
    kind : str or None
        ``"mrft"``, ``"ideal"`` or ``"hysteresis"``.
    beta : float or None
        MRFT beta.
    eps : float or None
        Hysteresis [output units], >= 0; only with ``kind`` ``"hysteresis"`` (InputError otherwise).
    """

    kind: str | None = None
    beta: float | None = None
    eps: float | None = None

    def __post_init__(self) -> None:
        # eps is only read with a stated hysteresis relay (segment/relay_type): anywhere else it would be ignored
        if self.eps is not None and self.kind != "hysteresis":
            raise InputError(f"--eps {self.eps:g} is a hysteresis relay's: give --relay hysteresis with it, "
                             "or leave --eps out to infer the relay")
        if self.eps is not None and not (math.isfinite(self.eps) and self.eps >= 0):
            raise InputError(f"--eps must be a non-negative number [output units], got {self.eps:g}")

    @property
    def stated(self) -> bool:
        """Whether anything is stated (eq. (2) reads its relay from the log and takes none)."""
        return (self.kind, self.beta, self.eps) != (None, None, None)


@dataclass(frozen=True)
class CascadeOptions:
    """What a cascade's analysis (an outer loop through its closed inner loop) takes beside its model.

    Attributes
    ----------
    draws : tuple of InnerLoop
        Draws of the inner loop over its analysis' uncertainty
        (:func:`mrftcli.analyze.cascade.inner_draws`); empty: the inner model taken as exact.
    assumptions : tuple of str
        The caller's assumptions to state first.
    inner_source, gains_source : str
        Where the inner model and the inner gains came from, as the assumptions say it (the options of
        ``analyze``; ``vehicle`` names its own sources).
    """

    draws: tuple[InnerLoop, ...] = ()
    assumptions: tuple[str, ...] = ()
    inner_source: str = "--inner-model"
    gains_source: str = "--inner-gains"


@dataclass(frozen=True)
class AnalyzeOptions:
    """How the MRFT tests of a flight are screened and identified, checked on creation.

    Attributes
    ----------
    min_stable_cycles : int
        Fewest stable relay cycles a test needs to be used (default 3).
    criterion : StabilityCriterion, optional
        Stable-limit-cycle criterion of the segmenter; None: ``StabilityCriterion()``.
    validity : ValidityCriterion, optional
        Thresholds of the limit-cycle validity check (:func:`mrftcli.segment.check_limit_cycle`): a test
        whose output does not follow its relay as an MRFT limit cycle is rejected, and so are the tests
        whose loop-gain sign disagrees with the others' (:func:`mrftcli.analyze.screen.screen_tests`);
        None: ``ValidityCriterion()``.
    n_bootstrap : int
        Bootstrap draws for the uncertainty (default 400; fewer for logs with many tests).
    max_combinations : int
        Cap on the per-combination identifications of the paper's Table III (a seeded random subset
        above it; default 400).
    seed : int
        Seed of the bootstrap and of the combination subset: a seed gives the same figures.
    constraints : tuple of {"phase", "amplitude"}
        Weighted constraints added to the UFM slices for the point estimate and the bootstrap (beyond
        the paper, :mod:`mrftcli.mrft.consensus`); ``()`` gives the paper's method alone.
    refine_waveform : bool
        Refine the MRFT estimate by output error on the tests' windows and report it when the data
        accept it (:func:`mrftcli.mrft.refine.refine`); False: the MRFT estimate alone.
    controller_rate_hz : float, optional
        Rate [Hz] the relay decides at, overriding the flight's ``timing.controller_rate_hz`` for the
        segmenter (a log sub-sampling its controller); None: the flight's.
    relay : RelayOptions
        What is stated about the relay (a process model's; eq. (2) reads beta from the log).
    windows : tuple of (float, float)
        Parts of the log to use [s, log clock]; empty: all of it.
    baseline : (float or Signal, float) or None
        A process model's operating point ``Y0`` [output units] (or its logged signal) and its std:
        a biased relay's mean levels then measure the static gain
        (:mod:`mrftcli.analyze.static_gain`).
    cascade : CascadeOptions
        A cascade model's inner-loop draws and the wording of its sources.
    diagnose_hint : str
        How the warnings a model-mismatch diagnosis would explain end (eq. (2): the tests' constraints disagree,
        the waveform refinement not used): :data:`TRY_DIAGNOSE` for a command that offers ``--diagnose`` and was
        not given it, :data:`TRY_DIAGNOSE_COMMAND` (the default) for a caller that does not; empty when the
        diagnosis is run with it.

    The eq. (2) strategy reads every field but ``relay`` and ``baseline``; a process family's reads
    ``min_stable_cycles``, ``relay``, ``windows`` and ``baseline``; a cascade's ``min_stable_cycles`` and
    ``cascade``.

    Raises
    ------
    InputError
        ``min_stable_cycles``, ``n_bootstrap`` or ``max_combinations`` below 1, an unknown constraint,
        a non-positive controller rate.

    Examples
    --------
    >>> AnalyzeOptions(n_bootstrap=100, constraints=()).constraints
    ()
    >>> AnalyzeOptions(constraints=("phase", "gain"))
    Traceback (most recent call last):
    ...
    mrftcli.errors.InputError: unknown constraint(s) ['gain']; choose from ['phase', 'amplitude']
    """

    min_stable_cycles: int = 3
    criterion: StabilityCriterion | None = None
    validity: ValidityCriterion | None = None
    n_bootstrap: int = 400
    max_combinations: int = 400
    seed: int = 0
    constraints: tuple[str, ...] = CONSTRAINTS
    refine_waveform: bool = True
    controller_rate_hz: float | None = None
    relay: RelayOptions = RelayOptions()
    windows: tuple[tuple[float, float], ...] = ()
    baseline: tuple[float | Signal, float] | None = None
    cascade: CascadeOptions = CascadeOptions()
    diagnose_hint: str = TRY_DIAGNOSE_COMMAND

    def __post_init__(self) -> None:
        for name in ("min_stable_cycles", "n_bootstrap", "max_combinations"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, Integral) or value < 1:
                raise InputError(f"{name} must be a whole number of at least 1, got {value!r}")
        constraints = tuple(self.constraints)
        bad = [c for c in constraints if c not in CONSTRAINTS]
        if bad:
            raise InputError(f"unknown constraint(s) {bad}; choose from {list(CONSTRAINTS)}")
        object.__setattr__(self, "constraints", constraints)  # a list given: stored as the tuple
        object.__setattr__(self, "windows", tuple((float(a), float(b)) for a, b in self.windows))
        if self.relay.kind is not None and self.relay.kind not in RELAY_KINDS:
            raise InputError(f"unknown relay {self.relay.kind!r}; choose from {list(RELAY_KINDS)}")
        if self.controller_rate_hz is not None:
            object.__setattr__(self, "controller_rate_hz",
                               check_positive("controller rate [Hz]", self.controller_rate_hz))
