"""One error family for the whole tool.

Every error a user can cause by what they pass in (a bad option, a broken log, a log without a relay
test) derives from :class:`MrftError`. The CLI turns these into a one-line message and the exit code
carried by the class, so scripts can tell the failure kinds apart:

====  ==========================  ==========================================================
code  class                       meaning
====  ==========================  ==========================================================
2     InputError                  an option or argument is out of range or malformed
3     LogReadError                the log cannot be read (format, truncation, missing topic)
4     SegmentationError           no usable MRFT limit cycle in the log
5     IdentificationError         the measured figures admit no model (or no unique one)
5     TpRejectedError             the recording rejects the given Tp and fits another one
6     InsufficientDataError       some tests found, but not enough to identify everything
7     DiagnoseError               the diagnosis could not be carried out
8     batch.BatchFailedError      some logs of a batch failed (the others were analysed)
9     compare.LoopChangedError    compare: some loop changed beyond tolerance
10    compare.ResultMissingError  compare: a result is missing or unusable (nothing changed)
====  ==========================  ==========================================================
"""

from __future__ import annotations

__all__ = [
    "MrftError",
    "InputError",
    "LogReadError",
    "OtherLoopError",
    "SegmentationError",
    "IdentificationError",
    "TpRejectedError",
    "InsufficientDataError",
    "DiagnoseError",
]


class MrftError(Exception):
    """Base class of every error mrft-ident reports to the user.

    ``warnings`` holds what the tool had warned of before the error (a reader's assumed controller rate, the
    tests left out), for the CLI to show above the one-line error; empty unless the raiser sets it.
    """

    exit_code: int = 1
    warnings: tuple[str, ...] = ()


class InputError(MrftError, ValueError):
    """An argument is malformed or out of its valid range (e.g. beta outside (-1, 1))."""

    exit_code = 2


class LogReadError(MrftError):
    """A flight log cannot be read: unknown format, corrupt or truncated file, missing topic/field."""

    exit_code = 3


class SegmentationError(MrftError):
    """No usable MRFT limit cycle was found in the recording.

    ``rejected_tests`` lists the tests that were found but left out, each a dict with its ``reason``
    (``analyze --json`` writes them); None when no test was found at all.
    """

    exit_code = 4
    rejected_tests: list[dict] | None = None


class OtherLoopError(SegmentationError):
    """The log says its MRFT tests excite another loop than ``--loop`` (ArduPilot's ``MRFB:Ax``, PX4's
    ``MRFT_<AXIS>_ENABLE``): the asked loop has no tests (exit 4, as a log without a usable test on it; the
    message names the loop to give). For batch and vehicle, which try every loop, that loop has no tests."""


class IdentificationError(MrftError, ValueError):
    """The measured limit cycles admit no model in the manifold range, or the problem is ill-posed."""

    exit_code = 5


class TpRejectedError(IdentificationError):
    """The recording rejects the given Tp and fits another one (``best`` [s]); ``result`` is the analysis
    at the given Tp (its ``tp_check`` says so), for a JSON that says which."""

    def __init__(self, message: str, best: float, result: object = None) -> None:
        super().__init__(message)
        self.best = best
        self.result = result


class InsufficientDataError(MrftError):
    """Tests were found but they do not determine all parameters (e.g. a single beta).

    ``partial`` carries whatever can honestly be said (a JSON-serialisable dict), for example tau
    over an assumed Td range.
    """

    exit_code = 6

    def __init__(self, message: str, partial: dict | None = None) -> None:
        super().__init__(message)
        self.partial = partial or {}

    def to_json(self) -> dict:
        """The object ``--json`` holds for this refusal (``analyze``, ``diagnose``; ``plan --from`` reads it):
        ``{"error", "exit_code", "partial"}``."""
        return {"error": str(self), "exit_code": self.exit_code, "partial": self.partial}


class DiagnoseError(MrftError):
    """The model-mismatch diagnosis could not be carried out."""

    exit_code = 7
