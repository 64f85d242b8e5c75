"""Sentences and unit names that the terminal and the HTML report say alike (no matplotlib here, so the
CLI's text output imports it without loading a plotting library)."""

from __future__ import annotations

from ..io.logtypes import gain_unit, output_unit, sig

__all__ = ["output_unit", "gain_unit", "uncertainty_sentence", "sig"]


def uncertainty_sentence(refined: bool, mrft_interval: bool) -> str:
    """Which of the uncertainties an analysis prints a user should act on (one line).

    Parameters
    ----------
    refined : bool
        The values are the waveform refinement's (its Gauss-Newton std, over all stable cycles).
    mrft_interval : bool
        A note also quotes the MRFT estimate's interval (frequencies and amplitudes alone).
    """
    source = "the waveform refinement over all stable cycles" if refined else "the estimate from all stable cycles"
    others = "the spread over combinations (how much subsets of cycles disagree)"
    if mrft_interval:
        others += " and the MRFT interval (frequencies and amplitudes alone)"
    wider = " and are wider by design" if refined else ""
    return (f"uncertainty: use the ± std and 95 % interval above ({source}); {others} check the data"
            f"{wider}, not the uncertainty of these values")
