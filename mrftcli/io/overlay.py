"""The results MCAP: an analysis written back on the log's own clock, to view beside the log.

``mrft-ident analyze LOG --mcap-out FIT.mcap`` writes this file (what to write comes from
:func:`mrftcli.analyze.analysis_overlay`; this module only writes it); a user opens LOG and FIT.mcap together
in Foxglove Studio or PlotJuggler (docs/usage.md) and sees the model's prediction on the recording.
Messages are JSON (``jsonschema`` schemas, the MCAP encoding both tools read without ROS type
definitions); every ``log_time`` is the original log's time [ns], so both files share one time axis.

Topics
------
``/mrft_ident/fit``
    One message per output sample inside a test: ``output`` (the output as analysed: after a quaternion
    conversion and ``--output-scale``), ``predicted`` (the identified model driven by the recorded
    relay command, :func:`mrftcli.mrft.waveform.predict_output`), ``residual`` (output - predicted),
    ``test`` (test number, 1-based).
``/mrft_ident/tests``
    Four messages per test, two at its start (``active`` 0 then 1) and two at its end (1 then 0): test
    number, beta (effective, used), nominal beta, relay h and bias, frequency [Hz], amplitude (output
    units), stable cycles, start and end times [s] and the RMS residual of the fit. Plotted (PlotJuggler,
    Foxglove's Plot panel), ``active`` is a square pulse over each test: a line between one test's end
    and the next one's start stays at 0 instead of drawing a diagonal across the test.
``/mrft_ident/events``
    One ``foxglove.Event`` per test in the current Foxglove schema, taken from the maintained package
    (``foxglove-sdk``'s ``foxglove.messages.Event``: its protobuf schema and its encoder; ``start_time``,
    ``end_time``, ``metadata`` [KeyValuePair{key, value}]): the test's start and end with its number,
    beta, h, frequency, amplitude and fit residual as strings, so Foxglove marks the tests on its
    timeline. This channel is protobuf; the others JSON.
``/mrft_ident/parameters``
    The identified parameters (eq. (2): Tp, Td, tau [s] and K; any other family's by name) with
    standard deviations and 95 % intervals, at the first and the last output sample (so a plot draws
    them as lines across the log).

Metadata records (``mrft_ident``, ``mrft_ident.test.N``) repeat the parameters and the tests as
strings for tools that list metadata (``mcap info``, Foxglove's metadata panel). The analysis itself
(``analyze --json``'s object) rides along as the attachment ``analysis.json`` (``application/json``)
when the caller passes it.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..errors import InputError
from ..jsonable import finite_or_none
from .atomic import atomic_path, check_output_path

__all__ = ["OverlayTest", "OverlayFit", "check_overlay_path", "write_overlay", "OVERLAY_TOPICS", "ANALYSIS_ATTACHMENT"]

#: the topics :func:`write_overlay` writes
OVERLAY_TOPICS = ("/mrft_ident/fit", "/mrft_ident/tests", "/mrft_ident/parameters", "/mrft_ident/events")

#: the name of the analysis JSON attached to the results MCAP
ANALYSIS_ATTACHMENT = "analysis.json"



def foxglove_event_schema() -> tuple[str, str, bytes]:
    """(name, encoding, data) of ``foxglove.Event`` as foxglove-sdk ships it (never hand-written)."""
    from foxglove.messages import Event

    schema = Event.get_schema()
    return schema.name, schema.encoding, bytes(schema.data)


@dataclass(frozen=True)
class OverlayTest:
    """One segmented test as annotated in the results MCAP (times in the log's time base [s])."""

    number: int
    t_start: float
    t_end: float
    beta: float
    beta_nominal: float | None
    h: float
    bias: float
    frequency_hz: float
    amplitude: float
    cycles: int
    rms_residual: float


@dataclass(frozen=True)
class OverlayFit:
    """The model's prediction over one test, sample by sample at the output times [s]."""

    number: int
    t: np.ndarray
    output: np.ndarray
    predicted: np.ndarray


def check_overlay_path(path: str | Path) -> Path:
    """The output path if it replaces nothing but an MCAP file (:func:`mrftcli.io.atomic.check_output_path`),
    else a one-line InputError; its folder and whether it can be written are the CLI's one output check
    (:func:`mrftcli.cli.options.check_output_file`, before this). ``-`` is refused: an MCAP is binary, not for stdout."""
    if str(path) == "-":
        raise InputError("--mcap-out writes a binary MCAP file: give a file name (e.g. --mcap-out results.mcap), "
                         "not '-' (stdout takes the text outputs: --json -)")
    return check_output_path(path, "--mcap-out", ours=_is_overlay, what="a results MCAP")


def _is_overlay(path: Path) -> bool:
    """A results MCAP this module wrote (its ``mrft_ident`` metadata record): what ``--mcap-out`` replaces.

    The magic bytes alone would take a recorded flight (the command's own LOG among them) for one.
    """
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        if fh.read(5) != b"\x89MCAP":
            return False
        fh.seek(0)
        try:
            summary = make_reader(fh).get_summary()
        except (McapError, ValueError, OSError, struct.error):  # a cut file: not one to replace
            return False
    return summary is not None and any(m.name == "mrft_ident" for m in summary.metadata_indexes)


def _schema(properties: dict[str, str]) -> bytes:
    types = {"number": {"type": "number"}, "integer": {"type": "integer"},
             "number|null": {"type": ["number", "null"]}}
    return json.dumps({"type": "object", "properties": {k: types[v] for k, v in properties.items()}}).encode()


def _json_bytes(data: Mapping[str, object]) -> bytes:
    """Strict JSON (NaN and infinities as null, which every JSON reader accepts)."""
    from ..jsonable import to_jsonable

    return json.dumps(to_jsonable(data), allow_nan=False).encode()


def _ns(t: float) -> int:
    return max(int(round(float(t) * 1e9)), 0)


#: the JSON fields of the Test and Fit messages and their types (the Parameters' follow the parameters)
_TEST_PROPS = {"test": "integer", "active": "integer", "beta": "number|null", "beta_nominal": "number|null",
               "h": "number", "bias": "number", "frequency_hz": "number|null", "amplitude": "number|null",
               "cycles": "integer", "t_start": "number", "t_end": "number", "rms_residual": "number|null"}
_FIT_PROPS = {"output": "number|null", "predicted": "number|null", "residual": "number|null", "test": "integer"}


def _fit_rows(fits: Sequence[OverlayFit]) -> list[tuple[int, int, bytes]]:
    """One Fit message (channel 0) per sample of each test's prediction."""
    rows: list[tuple[int, int, bytes]] = []
    for fit in fits:
        t = np.asarray(fit.t, float)
        out = np.asarray(fit.output, float)
        pred = np.asarray(fit.predicted, float)
        for ti, yo, yp in zip(t.tolist(), out.tolist(), pred.tolist()):
            msg = {"output": finite_or_none(yo), "predicted": finite_or_none(yp),
                   "residual": finite_or_none(yo - yp), "test": int(fit.number)}
            rows.append((_ns(ti), 0, json.dumps(msg, separators=(",", ":")).encode()))
    return rows


def _test_rows(tests: Sequence[OverlayTest]) -> list[tuple[int, int, bytes]]:
    """Four Test messages (channel 1) per test: a square pulse, 0 then 1 at its start, 1 then 0 at its end."""
    rows: list[tuple[int, int, bytes]] = []
    for test in tests:
        base = {"test": test.number, "beta": finite_or_none(test.beta), "beta_nominal": finite_or_none(test.beta_nominal),
                "h": float(test.h), "bias": float(test.bias), "frequency_hz": finite_or_none(test.frequency_hz),
                "amplitude": finite_or_none(test.amplitude), "cycles": int(test.cycles), "t_start": float(test.t_start),
                "t_end": float(test.t_end), "rms_residual": finite_or_none(test.rms_residual)}
        for when, active in ((test.t_start, 0), (test.t_start, 1), (test.t_end, 1), (test.t_end, 0)):
            rows.append((_ns(when), 1, json.dumps({**base, "active": active}).encode()))
    return rows


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _event_rows(tests: Sequence[OverlayTest]) -> list[tuple[int, int, bytes]]:
    """One ``foxglove.Event`` (channel 3) per test, from its start to its end, encoded by foxglove-sdk."""
    from foxglove.messages import Event, KeyValuePair, Timestamp

    rows: list[tuple[int, int, bytes]] = []
    for test in tests:
        start, end = _ns(test.t_start), max(_ns(test.t_end), _ns(test.t_start))
        fields = {"test": test.number, "beta": test.beta, "h": test.h, "frequency_hz": test.frequency_hz,
                  "amplitude": test.amplitude, "cycles": test.cycles, "rms_residual": test.rms_residual}
        meta = [KeyValuePair(key="name", value=f"MRFT test {test.number}")]
        meta += [KeyValuePair(key=k, value=f"{v:.6g}" if isinstance(v, float) else str(v)) for k, v in fields.items()]
        msg = Event(start_time=Timestamp(**_stamp(start)), end_time=Timestamp(**_stamp(end)), metadata=meta)
        rows.append((start, 3, bytes(msg.encode())))
    return rows


def _parameter_values(parameters: Mapping[str, Mapping[str, float | None]],
                      names: list[str]) -> dict[str, float | None]:
    """The Parameters message: ``Td``, ``Td_std``, ``Td_ci95_low``, ... (None where not finite)."""
    params: dict[str, float | None] = {}
    for n in names:
        p = parameters[n]
        params[n] = finite_or_none(p.get("value"))
        for k in ("std", "ci95_low", "ci95_high"):
            params[f"{n}_{k}"] = finite_or_none(p.get(k))
    return params


def write_overlay(path: str | Path, *, tests: Sequence[OverlayTest], fits: Sequence[OverlayFit],
                  parameters: Mapping[str, Mapping[str, float | None]], metadata: Mapping[str, str] | None = None,
                  analysis_json: Mapping[str, object] | None = None) -> Path:
    """Write the results MCAP (see the module docstring for its topics).

    Parameters
    ----------
    path : str or Path
        Target file (replaced if it exists).
    tests : sequence of OverlayTest
        The tests used for identification.
    fits : sequence of OverlayFit
        The prediction over each test.
    parameters : mapping
        ``name -> {"value", "std", "ci95_low", "ci95_high", ...}`` (the one parameter record's JSON) of each
        of the model's parameters, in their units (eq. (2): Tp, Td, tau [s], K in output units / (command
        unit s^2)).
    metadata : mapping, optional
        Extra strings for the ``mrft_ident`` metadata record (log path, loop, version).
    analysis_json : mapping, optional
        The analysis as JSON values (``AnalysisResult.to_json()`` made JSON-able), attached as
        ``analysis.json`` (``application/json``); NaN is written as null.

    Returns
    -------
    Path
    """
    from mcap.writer import CompressionType, Writer

    path = Path(path)
    names = list(parameters)  # every family's parameters by name (eq. (2): Tp, Td, tau, K)
    param_props = {}
    for n in names:
        for k in ("value", "std", "ci95_low", "ci95_high"):
            param_props[f"{n}_{k}" if k != "value" else n] = "number|null"
    # (log_time, channel, payload), merged in time order
    rows = _fit_rows(fits) + _test_rows(tests)
    events = _event_rows(tests)
    params = _parameter_values(parameters, names)
    times = [r[0] for r in rows]
    if times:
        for when in sorted({min(times), max(times)}):
            rows.append((when, 2, json.dumps(params).encode()))
    # a stable sort: a test's two edge messages at one time keep their order (0 then 1, 1 then 0)
    rows = sorted(rows + events, key=lambda r: (r[0], r[1]))

    with atomic_path(path) as tmp, open(tmp, "wb") as stream:  # a viewer never opens half a file
        writer = Writer(stream, compression=CompressionType.ZSTD, chunk_size=1 << 20)
        writer.start(profile="", library="mrft-ident")
        channels = []
        event_name, event_encoding, event_schema = foxglove_event_schema()
        schemas = ((_schema(_FIT_PROPS), "jsonschema", "json"), (_schema(_TEST_PROPS), "jsonschema", "json"),
                   (_schema(param_props), "jsonschema", "json"), (event_schema, event_encoding, event_encoding))
        for topic, schema_name, (schema, encoding, message_encoding) in zip(
                OVERLAY_TOPICS, ("mrft_ident/Fit", "mrft_ident/Test", "mrft_ident/Parameters", event_name), schemas):
            sid = writer.register_schema(schema_name, encoding, schema)
            channels.append(writer.register_channel(topic, message_encoding, sid))
        seq = [0, 0, 0, 0]
        for log_time, ch, data in rows:
            writer.add_message(channel_id=channels[ch], log_time=log_time, publish_time=log_time, data=data,
                               sequence=seq[ch])
            seq[ch] += 1
        meta = {k: json.dumps(v) if not isinstance(v, str) else v for k, v in params.items()}
        meta.update({str(k): str(v) for k, v in (metadata or {}).items()})
        writer.add_metadata("mrft_ident", meta)
        for test in tests:
            writer.add_metadata(f"mrft_ident.test.{test.number}",
                                {k: str(v) for k, v in test.__dict__.items()})
        if analysis_json is not None:
            first = times[0] if times else 0
            writer.add_attachment(create_time=first, log_time=first, name=ANALYSIS_ATTACHMENT,
                                  media_type="application/json", data=_json_bytes(analysis_json))
        writer.finish()  # type: ignore[no-untyped-call]  # mcap's Writer.finish has no annotations
    return path
