"""No public function takes a long keyword list (issue 21): settings that travel together are one options record.

Walks every module of the package, takes the names in its ``__all__`` that the package defines, and
counts the parameters of each public function, of each public method of a public class and of a
hand-written ``__init__`` (a dataclass's generated ``__init__`` is its record's fields, not a keyword
list). ``self``/``cls`` and ``*args``/``**kwargs`` are not counted.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
from collections.abc import Callable, Iterator

import pytest

import mrftcli
from mrftcli.analyze import AnalyzeOptions
from mrftcli.batch import BatchOptions
from mrftcli.errors import InputError
from mrftcli.io import ReadOptions
from mrftcli.watch import WatchOptions

#: the most parameters a public function may take; a longer list becomes an options record
#: (``ReadOptions``, ``AnalyzeOptions``, ``WatchOptions``, ``BatchOptions``, ``PlanOptions``, ``SegmentOptions``,
#: ``DesignOptions``, ...)
MAX_PARAMETERS = 10

#: qualified name -> why it is allowed more for now. Each entry must still be over the limit (a stale
#: exception fails the test, so the list shrinks as they are fixed). Empty since issue 21's last four
#: (``SegmentOptions``, ``RotorCoefficients``, ``StackLogSpec``, ``DesignOptions``).
EXCEPTIONS: dict[str, str] = {}


def public_modules() -> list[str]:
    """Every module of the package (the private generated manifolds and ``__main__`` aside)."""
    return ["mrftcli"] + sorted(
        m.name for m in pkgutil.walk_packages(mrftcli.__path__, prefix="mrftcli.")
        if not m.name.endswith("__main__") and not m.name.startswith("mrftcli._manifolds"))


def n_parameters(func: Callable[..., object]) -> int:
    """Named parameters of ``func`` (no ``self``/``cls``, no ``*args``/``**kwargs``)."""
    params = inspect.signature(func).parameters.values()
    return sum(1 for p in params
               if p.name not in ("self", "cls") and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))


def _class_callables(cls: type) -> Iterator[tuple[str, Callable[..., object]]]:
    for name, member in vars(cls).items():
        if isinstance(member, (staticmethod, classmethod)):
            member = member.__func__
        if inspect.isfunction(member) and (not name.startswith("_") or
                                           (name == "__init__" and not dataclasses.is_dataclass(cls))):
            yield f"{cls.__module__}.{cls.__qualname__}.{name}", member


def public_callables() -> dict[str, Callable[..., object]]:
    """Qualified name -> function, for every public function and method of the package's ``__all__``s."""
    found: dict[str, Callable[..., object]] = {}
    for module_name in public_modules():
        module = importlib.import_module(module_name)
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name, None)
            if not str(getattr(obj, "__module__", "")).startswith("mrftcli"):
                continue  # a re-exported third-party or builtin name
            if inspect.isclass(obj):
                found.update(_class_callables(obj))
            elif inspect.isfunction(obj):
                found[f"{obj.__module__}.{obj.__qualname__}"] = obj
    return found


def test_the_counter_sees_a_long_keyword_list():
    """The check itself: a function of 11 named parameters is over the limit; self and **kwargs do not count."""

    def long(a, b, c, d, e, f, g, h, i, j, k):  # noqa: ARG001 - only its signature matters
        pass

    class Record:
        def method(self, a, *args, b=1, **kwargs):  # noqa: ARG002
            pass

    assert n_parameters(long) == 11 > MAX_PARAMETERS
    assert dict(_class_callables(Record)) and n_parameters(Record.method) == 2


def test_the_walk_reaches_the_options_records_callers():
    """The functions issue 21 regrouped are in the walk (the test would pass vacuously otherwise)."""
    found = public_callables()
    for name in ("mrftcli.io.read_flight", "mrftcli.analyze.driver.analyze_flight", "mrftcli.analyze.driver.analyze_path",
                 "mrftcli.watch.watch", "mrftcli.batch.run.run_batch", "mrftcli.segment.segmenter.segment_arrays",
                 "mrftcli.mrft.propagate.rk4_rotor", "mrftcli.io.stacks.write_stack_log", "mrftcli.tune.design.tune"):
        assert name in found, name
    assert len(found) > 300


def test_no_public_function_takes_more_than_ten_parameters():
    found = public_callables()
    counts = {name: n_parameters(func) for name, func in found.items()}
    over = sorted(f"{name} ({n})" for name, n in counts.items() if n > MAX_PARAMETERS and name not in EXCEPTIONS)
    assert not over, ("public functions over the limit; group their settings into a frozen options record "
                      f"(docs/architecture.md, Options records): {over}")
    stale = sorted(name for name in EXCEPTIONS if counts.get(name, 0) <= MAX_PARAMETERS)
    assert not stale, f"no longer over the limit (or gone): remove from EXCEPTIONS: {stale}"


def test_the_four_regrouped_functions_are_short():
    """read_flight, analyze_flight/analyze_path, watch and run_batch take their settings as records."""
    from mrftcli.analyze import analyze_flight, analyze_path
    from mrftcli.batch import run_batch
    from mrftcli.io import read_flight
    from mrftcli.watch import watch

    counts = {f.__name__: n_parameters(f) for f in (read_flight, analyze_flight, analyze_path, watch, run_batch)}
    assert max(counts.values()) <= 8, counts  # were 14, 11, 21, 16 and 14


@pytest.mark.parametrize(("make", "needle"), [
    (lambda: AnalyzeOptions(min_stable_cycles=0), "min_stable_cycles must be a whole number of at least 1, got 0"),
    (lambda: AnalyzeOptions(n_bootstrap=2.5), "n_bootstrap must be a whole number"),
    (lambda: AnalyzeOptions(constraints=["phase", "gain"]), r"unknown constraint\(s\) \['gain'\]"),
    (lambda: AnalyzeOptions(controller_rate_hz=-50.0), "controller rate"),
    (lambda: ReadOptions(time_unit="h"), "unknown time unit 'h'"),
    (lambda: ReadOptions(loop="yaw"), "unknown loop 'yaw'"),
    (lambda: WatchOptions(idle=0.0), "idle"),
    (lambda: WatchOptions(min_cycles=0), "min_cycles must be a whole number of at least 1"),
    (lambda: BatchOptions(jobs=0), "--jobs must be at least 1, got 0"),
    (lambda: BatchOptions(scheduler_timeout_s=float("nan")), "scheduler timeout"),
])
def test_an_options_record_refuses_a_bad_value_on_creation_in_one_line(make, needle):
    with pytest.raises(InputError, match=needle) as exc:
        make()
    assert "\n" not in str(exc.value)


def test_options_records_are_frozen_and_normalised():
    opts = AnalyzeOptions(constraints=["phase"])
    assert opts.constraints == ("phase",)  # a list given is stored as the tuple (hashable, immutable)
    for record in (opts, ReadOptions(), WatchOptions(), BatchOptions()):
        assert dataclasses.is_dataclass(record)
        with pytest.raises(dataclasses.FrozenInstanceError):
            record.seed = 1  # type: ignore[misc]  # the point: assignment is refused


def test_the_cli_log_options_are_read_options_fields():
    """Every command passes its shared log options on as ``ReadOptions(**read_options)``."""
    from mrftcli.cli.options import READ_OPTIONS

    assert set(READ_OPTIONS) <= {f.name for f in dataclasses.fields(ReadOptions)}
