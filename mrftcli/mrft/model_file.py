"""A plant structure the user declares (``--model-file FILE``): a transfer function in s with named parameters.

The paper states identification for any LTI plant W(s, p) of known structure, with the known
parameters (set E) and the ranges of the unknown ones (set I). A model file states exactly that, as
TOML or JSON::

    # G(s) = K e^{-tau s} / (T s + 1)^2, tau known from a bench test
    transfer_function = "K*exp(-tau*s)/(T*s + 1)**2"

    [parameters]
    K = { range = [0.01, 100], unit = "mm / %" }
    T = { range = [0.001, 10], unit = "s" }
    tau = { value = 0.004, unit = "s" }

or with python-control's numerator and denominator coefficients in s (highest power first; each a
number or an expression of the parameters) and a delay::

    numerator = ["K"]
    denominator = ["T**2", "2*T", 1]
    delay = "tau"

A parameter with a ``value`` is known (set E); one with a ``range = [lo, hi]`` is identified within
it (set I). The text is parsed by :mod:`mrftcli.mrft.tf_parse` from Python's ``ast`` tree (only
numbers, the parameters, s, arithmetic, whole-number powers and exp(-tau*s); nothing is evaluated, see
docs/security.md); sympy, given the expression built from that tree, cancels common factors of
numerator and denominator, so the realisation (``scipy.signal.tf2ss``, the controllable canonical
form of the coprime pair) is minimal. python-control's own ``tf2ss``/``minreal`` would do
the same but its import costs about 2 s at every CLI start; sympy's ``cancel`` is the library
doing the algebra here, not hand-written code.

As in every built-in family the gain is ``K`` and the delay ``tau``: ``K`` must be a factor of the
transfer function (absent: a known gain of 1, already in the expression) and the delay must be
written ``exp(-tau*s)`` (absent: a known delay of 0). Unstable poles are allowed (a loop the relay
stabilises, e.g. a tokamak's vertical position); an improper or biproper transfer function is
refused (a relay loop needs a strictly proper plant).
"""

from __future__ import annotations

import dataclasses
import keyword
import math
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..errors import InputError
from ..validate import PARAMETER_MAGNITUDE, check_parameter_value
from ..jsonable import load_json_text, load_toml_text
from .model import Parameter, StateSpace, UnitNormalisation, json_parameter_values, model_json, model_json_parameters
from .tf_parse import MAX_ORDER, check_transfer_text, parse_transfer_function

__all__ = ["DeclaredModel", "load_model_file", "parse_model_spec", "declared_model"]

#: functions a transfer function may use besides its parameters and s
_FUNCTIONS = ("exp",)
_DEFAULT_UNITS = {"K": "output / command", "tau": "s"}
#: most parameters a model file may declare
MAX_PARAMETERS = 32
#: largest model file [bytes]
MAX_MODEL_FILE = 1 << 20


#: one monomial of an expanded polynomial: (power of s, coefficient, ((parameter index, power), ...))
_Monomial = tuple[int, float, tuple[tuple[int, int], ...]]


@dataclass(frozen=True)
class _Compiled:
    """The parsed structure: names in order, and the coefficients of the delay-free, K-free part R(s).

    G(s) = K R(s) e^{-tau s}. R's numerator and denominator are expanded polynomials in s and the
    parameters, stored as their monomials, so a coefficient array in s (highest power first) is a sum
    of products of the parameter values: no expression is evaluated.
    """

    text: str
    names: tuple[str, ...]
    numerator: tuple[_Monomial, ...]
    denominator: tuple[_Monomial, ...]
    order: int

    def coefficients(self, values: Sequence[float]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Numerator and denominator coefficients in s (highest power first) at the parameter ``values``."""
        return _polynomial(self.numerator, values), _polynomial(self.denominator, values)


def _polynomial(monomials: tuple[_Monomial, ...], values: Sequence[float]) -> NDArray[np.float64]:
    # a plain loop: a few dozen monomials, called at every frequency response (numpy's overhead dominates)
    degree = max((k for k, _, _ in monomials), default=0)
    out = [0.0] * (degree + 1)
    for k, c, factors in monomials:
        for j, e in factors:
            c *= values[j] ** e
        out[degree - k] += c
    return np.array(out, dtype=float)


def _monomials(poly: Any) -> tuple[_Monomial, ...]:
    return tuple((int(m[0]), float(c), tuple((j, int(e)) for j, e in enumerate(m[1:]) if e))
                 for m, c in poly.terms())


def _check_text(text: Any, what: str) -> str:
    return check_transfer_text(text, f"model file: {what}")


@lru_cache(maxsize=64)
def _compile(text: str, names: tuple[str, ...]) -> _Compiled:
    """Parse ``text`` (a transfer function in s of ``names``) from its syntax tree; cached per structure."""
    # sympy ships no type information (no py.typed): its objects are Any here
    import sympy  # type: ignore[import-untyped]

    expr = parse_transfer_function(text, names, "model file: transfer_function")
    s = sympy.Symbol("s")
    symbols = {n: sympy.Symbol(n, real=True) for n in names}
    unused = sorted(n for n in names if symbols[n] not in expr.free_symbols)
    if unused:
        raise InputError(f"model file: parameter(s) {', '.join(unused)} do not appear in {text!r}")
    tau, K = symbols.get("tau"), symbols.get("K")
    rational = _without_delay(expr, s, tau, text)
    if K is not None:
        rational = sympy.cancel(rational / K)
        if K in rational.free_symbols:
            raise InputError(f"model file: K must be a factor of the transfer function (the gain), in {text!r}")
    num, den = sympy.fraction(sympy.cancel(sympy.together(rational)))
    shape = [symbols[n] for n in names]
    try:
        pn, pd = sympy.Poly(num, s, *shape), sympy.Poly(den, s, *shape)
    except sympy.PolynomialError:
        raise InputError(f"model file: {text!r} is not a rational function of s (times exp(-tau*s))") from None
    if not (pn.domain.is_Numerical and pd.domain.is_Numerical):
        raise InputError(f"model file: {text!r} is not a rational function of s (times exp(-tau*s))")
    num_order, den_order = pn.degree(s), pd.degree(s)
    if den_order < 1 or num_order >= den_order:
        raise InputError(f"model file: {text!r} is not strictly proper (numerator degree {num_order}, "
                         f"denominator {den_order}): a relay loop needs more poles than zeros")
    return _Compiled(text, names, _monomials(pn), _monomials(pd), int(den_order))


def _without_delay(expr: Any, s: Any, tau: Any, text: str) -> Any:
    """``expr`` with its delay factor exp(-tau*s) removed (checked to be exactly that)."""
    import sympy

    exps = list(expr.atoms(sympy.exp))
    if not exps:
        return expr
    if tau is None or len(exps) != 1 or sympy.cancel(exps[0].args[0] + tau * s) != 0:
        raise InputError(f"model file: write the delay as one factor exp(-tau*s) with a parameter tau, in {text!r}")
    rational = expr.subs(exps[0], 1)
    # a factor of the product as written (cheap); else the algebra says whether it factors out
    factors = sympy.Mul.make_args(expr)
    if exps[0] in factors and not any(f.has(sympy.exp) for f in factors if f != exps[0]):
        return rational
    if sympy.simplify(expr - rational * exps[0]) != 0:
        raise InputError(f"model file: exp(-tau*s) must be a factor of the transfer function, in {text!r}")
    return rational


@dataclass(frozen=True)
class DeclaredModel:
    """A :class:`~mrftcli.mrft.model.PlantModel` of a declared transfer function G(s) = K R(s, p) e^{-tau s}.

    Attributes
    ----------
    transfer_function : str
        The expression in s (sympy syntax, ``**`` for powers).
    values : tuple of (str, float)
        Every parameter's value, in the declared order (unknown ones: a start inside their range).
    units : tuple of (str, str)
        Every parameter's unit.
    known : frozenset of str
        The set E.
    ranges : tuple of (str, float, float)
        The set I: each unknown parameter's range.

    Examples
    --------
    >>> m = declared_model("K*exp(-tau*s)/(T*s + 1)", {"K": 2.0, "T": 0.5, "tau": 0.1})
    >>> round(abs(complex(m.frequency_response(2.0))), 4), m.realisation().order
    (1.4142, 1)
    """

    family: ClassVar[str] = "declared"
    structure: ClassVar[str] = "declared in a model file"
    #: its strategy in :func:`mrftcli.mrft.identify.identify`: a direct fit to response points
    identification: ClassVar[str] = "response-points"
    #: identify_lti searches the unknown shape parameters over their ranges (set I), not a time grid
    grid_from_ranges: ClassVar[bool] = True

    transfer_function: str
    values: tuple[tuple[str, float], ...]
    units: tuple[tuple[str, str], ...] = ()
    known: frozenset[str] = field(default=frozenset(), compare=False)
    ranges: tuple[tuple[str, float, float], ...] = field(default=(), compare=False)

    def __post_init__(self) -> None:
        names = tuple(n for n, _ in self.values)
        if len(names) > MAX_PARAMETERS:
            raise InputError(f"model file: {len(names)} parameters, more than the {MAX_PARAMETERS} a model may have")
        for name, value in self.values:
            _check_name(name)
            if not (math.isfinite(value) and abs(value) <= PARAMETER_MAGNITUDE[1]):
                raise InputError(f"model file: parameter {name} must be finite and at most "
                                 f"{PARAMETER_MAGNITUDE[1]:g} in size, got {value!r}")
        values = dict(self.values)
        if values.get("K", 1.0) == 0:
            raise InputError("model file: K must be non-zero")
        if values.get("tau", 0.0) < 0:
            raise InputError(f"model file: tau must be a non-negative delay [s], got {values['tau']!r}")
        _check_text(self.transfer_function, "transfer_function")
        _ = self._compiled  # parsed (and refused) on creation: every reader of a model goes through here

    @property
    def _compiled(self) -> _Compiled:
        names = tuple(n for n, _ in self.values)
        shape = tuple(n for n in names if n not in ("K", "tau"))
        # the text is checked inside the cached parse: this runs at every frequency response
        return _compile(self.transfer_function, shape + tuple(n for n in ("K", "tau") if n in names))

    def _coefficients(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        c = self._compiled
        values = dict(self.values)
        return c.coefficients([values[n] for n in c.names])

    @property
    def parameters(self) -> dict[str, Parameter]:
        """The parameters in the declared order (K and tau included, implicit ones known)."""
        units, ranges = dict(self.units), {n: (lo, hi) for n, lo, hi in self.ranges}
        out = {n: Parameter(n, units.get(n, _DEFAULT_UNITS.get(n, "")), v, n in self.known or n not in ranges,
                            ranges.get(n, (-math.inf, math.inf) if n != "tau" else (0.0, math.inf)))
               for n, v in self.values}
        out.setdefault("K", Parameter("K", "output / command", 1.0, True, (-math.inf, math.inf), "implicit gain"))
        out.setdefault("tau", Parameter("tau", "s", 0.0, True, (0.0, math.inf), "implicit delay"))
        return out

    @property
    def delay(self) -> float:
        """The transport delay tau [s] (0 when the transfer function has none)."""
        return float(dict(self.values).get("tau", 0.0))

    def frequency_response(self, omega: ArrayLike) -> NDArray[np.complex128]:
        """G(j omega) including the delay; ``omega`` in rad/s."""
        s = 1j * np.asarray(omega, dtype=float)
        num, den = self._coefficients()
        gain = float(dict(self.values).get("K", 1.0))
        response: NDArray[np.complex128] = gain * np.polyval(num, s) / np.polyval(den, s) * np.exp(-self.delay * s)
        return response

    def realisation(self) -> StateSpace:
        """A minimal realisation of K R(s) (``scipy.signal.tf2ss`` of the coprime pair sympy left)."""
        from scipy import signal

        num, den = self._coefficients()
        A, B, C, D = signal.tf2ss(num * float(dict(self.values).get("K", 1.0)), den)
        return StateSpace(np.asarray(A, float), np.asarray(B, float).ravel(), np.asarray(C, float).ravel(),
                          float(np.asarray(D).ravel()[0]) if np.size(D) else 0.0)

    def unit_normalisation(self, omega: float) -> UnitNormalisation | None:
        """None: a declared structure has no unit manifolds (it is identified by the direct solve)."""
        return None

    def with_parameters(self, **values: float) -> DeclaredModel:
        """A copy with some parameters replaced; ``tau`` may be set on a model without a declared delay
        only to 0 (the LPRS adds half a sample of delay to a sampled loop: then it is declared here)."""
        current = dict(self.values)
        bad = set(values) - set(current) - {"K", "tau"}
        if bad:
            raise InputError(f"unknown parameter(s) {sorted(bad)} of the declared model; it has {list(current)}")
        merged = {**current, **{k: float(v) for k, v in values.items()}}
        if "tau" in values and "tau" not in current:
            # an added delay: the structure becomes R(s) e^{-tau s}
            return dataclasses.replace(self, transfer_function=f"({self.transfer_function})*exp(-tau*s)",
                                       values=tuple(merged.items()), known=self.known | {"tau"})
        if "K" in values and "K" not in current:
            return dataclasses.replace(self, transfer_function=f"K*({self.transfer_function})",
                                       values=tuple(merged.items()), known=self.known | {"K"})
        return dataclasses.replace(self, values=tuple((n, merged[n]) for n in current))

    def to_json(self) -> dict[str, Any]:
        """``model_json`` of the parameters plus the ``transfer_function`` text."""
        declared = [p for n, p in self.parameters.items() if n in dict(self.values)]
        return {**model_json(self.family, declared), "transfer_function": self.transfer_function}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> DeclaredModel:
        """The model of a :meth:`to_json` dict; :class:`~mrftcli.errors.InputError` on bad input."""
        params = model_json_parameters(data, cls.family)
        text = data.get("transfer_function")
        if not isinstance(text, str):
            raise InputError("declared model JSON needs its 'transfer_function' text")
        spec = {n: (str(p.get("unit", "")) if isinstance(p, Mapping) else "", "", (-math.inf, math.inf))
                for n, p in params.items()}
        values, known, ranges = json_parameter_values(params, spec)
        units = tuple((n, spec[n][0]) for n in values)
        return cls(text, tuple(values.items()), units, known | (frozenset(values) - {r[0] for r in ranges}), ranges)


def declared_model(transfer_function: str, known: Mapping[str, float] | None = None,
                   ranges: Mapping[str, tuple[float, float]] | None = None,
                   units: Mapping[str, str] | None = None) -> DeclaredModel:
    """A declared model: the known parameters at their values (set E), the others in their ranges (set I).

    An unknown parameter starts at the geometric (or arithmetic) middle of its range.

    Raises
    ------
    InputError
        A parameter both known and ranged, or neither; a bad range; a bad transfer function.
    """
    known, ranges = dict(known or {}), dict(ranges or {})
    both = sorted(set(known) & set(ranges))
    if both:
        raise InputError(f"model file: parameter(s) {', '.join(both)} given both a value and a range; "
                         "a value makes it known, a range identifies it")
    values: dict[str, float] = {}
    for name, (lo, hi) in ranges.items():
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise InputError(f"model file: range of {name} must be finite with low < high, got [{lo}, {hi}]")
        check_parameter_value(f"model file: range of {name}", lo)
        check_parameter_value(f"model file: range of {name}", hi)
        values[name] = math.sqrt(lo * hi) if lo > 0 else (-math.sqrt(lo * hi) if hi < 0 else 0.5 * (lo + hi))
    for name, value in known.items():
        check_parameter_value(f"model file: parameter {name}", value)
    values.update({n: float(v) for n, v in known.items()})
    names = _declared_names(transfer_function, values)
    return DeclaredModel(transfer_function, tuple((n, values[n]) for n in names),
                         tuple((n, (units or {}).get(n, _DEFAULT_UNITS.get(n, ""))) for n in names),
                         frozenset(known), tuple((n, float(lo), float(hi)) for n, (lo, hi) in ranges.items()))


def _declared_names(text: str, values: Mapping[str, float]) -> list[str]:
    """The parameter names in a stable order: K first, the shape parameters as given, tau last."""
    text = _check_text(text, "transfer_function")
    if len(values) > MAX_PARAMETERS:
        raise InputError(f"model file: {len(values)} parameters, more than the {MAX_PARAMETERS} a model may have")
    for name in values:
        _check_name(name)
    return sorted(values, key=lambda n: (n != "K", n == "tau"))


def _check_name(name: str) -> None:
    if (not isinstance(name, str) or not name.isidentifier() or keyword.iskeyword(name) or len(name) > 64
            or name in ("s",) + _FUNCTIONS):
        raise InputError(f"model file: {str(name)[:64]!r} cannot name a parameter (a name of letters, digits and _, "
                         "not a Python keyword; s and exp are reserved)")


def _spec_text(spec: Mapping[str, Any]) -> str:
    """The transfer function of a parsed file: ``transfer_function``, or numerator/denominator/delay."""
    if "transfer_function" in spec:
        return _check_text(spec["transfer_function"], "transfer_function")
    if "numerator" not in spec or "denominator" not in spec:
        raise InputError("model file: give transfer_function = \"...\", or numerator = [...] and denominator = [...] "
                         "(coefficients in s, highest power first)")

    def poly(key: str) -> str:
        coeffs = spec[key]
        if not isinstance(coeffs, list) or not coeffs:
            raise InputError(f"model file: {key} must be a list of coefficients (numbers or expressions)")
        if len(coeffs) > MAX_ORDER + 1:
            raise InputError(f"model file: {key} has {len(coeffs)} coefficients, a polynomial of order "
                             f"{len(coeffs) - 1}, above the model order limit of {MAX_ORDER}")
        for i, c in enumerate(coeffs):
            if isinstance(c, bool) or not isinstance(c, (str, int, float)):
                raise InputError(f"model file: {key}[{i}] must be a number or an expression in the parameters")
        terms = [f"({_check_text(str(c), f'{key}[{i}]')})*s**{len(coeffs) - 1 - i}" for i, c in enumerate(coeffs)]
        return " + ".join(terms)

    text = f"({poly('numerator')})/({poly('denominator')})"
    delay = spec.get("delay")
    if delay is not None:
        if str(delay).strip() != "tau":
            raise InputError("model file: delay must be the parameter tau (declare tau's value or range)")
        text += "*exp(-tau*s)"
    return text


def parse_model_spec(spec: Mapping[str, Any]) -> DeclaredModel:
    """A :class:`DeclaredModel` from a model file's parsed content (module docstring).

    Raises
    ------
    InputError
        Missing or malformed fields (one line naming the field and the fix).
    """
    if not isinstance(spec, Mapping):
        raise InputError("model file: expected a table/object at the top level")
    text = _spec_text(spec)
    params = spec.get("parameters")
    if not isinstance(params, Mapping) or not params:
        raise InputError("model file: needs a [parameters] table: NAME = { value = V } (known) or "
                         "{ range = [LO, HI] } (to identify)")
    known: dict[str, float] = {}
    ranges: dict[str, tuple[float, float]] = {}
    units: dict[str, str] = {}
    for name, p in params.items():
        entry = p if isinstance(p, Mapping) else {"value": p}
        try:
            if "value" in entry and "range" not in entry:
                known[name] = float(entry["value"])
            elif "range" in entry and "value" not in entry:
                lo, hi = entry["range"]
                ranges[name] = (float(lo), float(hi))
            else:
                raise ValueError("neither or both")
        except (TypeError, ValueError):
            raise InputError(f"model file: parameter {name}: give value = V (known) or range = [LO, HI] "
                             "(to identify), not both") from None
        if "unit" in entry:
            units[name] = str(entry["unit"])
    return declared_model(text, known, ranges, units)


def load_model_file(path: str | Path) -> DeclaredModel:
    """Read a model file (``.toml`` or ``.json``) into a :class:`DeclaredModel`.

    Raises
    ------
    InputError
        Unreadable file, bad TOML/JSON, or a bad declaration (one line).
    """
    p = Path(path)
    try:
        size = p.stat().st_size
        if size > MAX_MODEL_FILE:
            raise InputError(f"--model-file {path}: {size} bytes, more than the {MAX_MODEL_FILE} a model file "
                             "may have (a transfer function and its parameters)")
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(f"--model-file {path}: cannot read it ({getattr(err, 'strerror', None) or err})") from None
    what = f"--model-file {path}"
    spec = load_json_text(text, what) if p.suffix.lower() == ".json" else load_toml_text(text, what)
    try:
        return parse_model_spec(spec)
    except InputError as err:
        raise InputError(f"--model-file {path}: {str(err).removeprefix('model file: ')}") from None
