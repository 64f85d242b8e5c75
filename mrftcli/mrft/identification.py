"""The one identification record: :class:`IdentificationRecord`, what :func:`~mrftcli.mrft.identify.identify` returns.

Every strategy (eq. (2)'s unit manifolds, the families' response points, the cascade's cycles) writes one
layout (docs/records.md)::

    {"schema_version": 3, "strategy": "response-points", "family": "fopdt", "model": {...},
     "parameters": {"K": {...}, "T": {...}, "L": {...}}, ...the strategy's fit figures}

``parameters`` holds every parameter of the model, identified or given, as the one parameter record
(:class:`~mrftcli.mrft.parameter.ParameterEstimate`), in its strategy's order (eq. (2): Td, tau, K, Tp, with no K
without amplitudes; a family: its model's; the cascade: its free ones, then a given K); what only one strategy finds
(eq. (2)'s tests and Monte Carlo, the families' response points, the cascade's inner draws) follows as that
strategy's keys (:meth:`IdentificationRecord.fit_json`). :meth:`IdentificationRecord.from_json` reads any strategy by its
model's family, and, for one release, each strategy's version 1 and 2 (their own ``schema_version`` before the
merge; the parameters in their former shapes, :meth:`ParameterEstimate.from_json`).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Self

from ..errors import InputError
from ..jsonable import check_schema_version
from .model import model_from_json
from .parameter import ParameterEstimate

__all__ = ["IdentificationRecord", "IDENTIFICATION_SCHEMA_VERSION", "spelt_unit"]

#: version of :meth:`IdentificationRecord.to_json`; 3: one layout for every strategy (``strategy``, ``family``,
#: ``model``, ``parameters`` with every parameter, known ones included); versions 1 and 2 of each strategy
#: (eq. (2)'s, the families', the cascade's: each its own layout) still read
IDENTIFICATION_SCHEMA_VERSION = 3


def spelt_unit(name: str, unit: str, model: Any) -> str:
    """The unit a record writes for the estimate ``name`` whose own is ``unit``: that one, or where it is empty
    (eq. (2)'s K, kept "" in memory as identify gives it) ``model``'s parameter's (``output / (command s^2)``,
    :data:`~mrftcli.mrft.model.K_UNIT`). The one rule of every record that writes eq. (2)'s K: this one's, the
    analysis's (:mod:`mrftcli.analyze.record`) and compare's (:mod:`mrftcli.compare.inputs`)."""
    if unit:
        return unit
    p = getattr(model, "parameters", {}).get(name)
    return str(p.unit) if p is not None else ""


@dataclass(frozen=True, eq=False)
class IdentificationRecord:
    """An identified model and its parameters, whichever strategy found them.

    Attributes
    ----------
    model : PlantModel
        The point estimate (known parameters and ranges kept).
    estimates : tuple of ParameterEstimate
        Every parameter of the model (``name`` set), identified or given, in the strategy's order (module
        docstring: eq. (2)'s Td, tau, K, Tp is not :class:`~mrftcli.mrft.model.LoopModel`'s Tp, Td, tau, K).
    """

    model: Any
    estimates: tuple[ParameterEstimate, ...]

    #: the method an identified parameter records when its JSON does not say (versions before the one record)
    _method: ClassVar[str] = ""
    #: what a null interval end reads as (eq. (2)'s NaN, the fits' open +-inf)
    _open_value: ClassVar[float] = math.inf
    #: the fit cuts intervals at the model's ranges (``one_sided`` is found again from them when read)
    _sided: ClassVar[bool] = True
    #: parameters the strategy may leave out (written null by older versions): eq. (2)'s K without amplitudes
    _optional: ClassVar[frozenset[str]] = frozenset()

    def estimate(self, name: str) -> ParameterEstimate:
        """The estimate of one parameter by name (KeyError when the model has none of that name)."""
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(name)

    @property
    def parameters(self) -> dict[str, ParameterEstimate]:
        """The estimates by name, in :attr:`estimates`' order."""
        return {e.name: e for e in self.estimates}

    def to_json(self) -> dict[str, Any]:
        """The one layout: ``schema_version``, ``strategy``, ``family``, ``model``, ``parameters``, then
        :meth:`fit_json`."""
        from .identify import strategy_of  # identify imports this module

        return {"schema_version": IDENTIFICATION_SCHEMA_VERSION, "strategy": strategy_of(self.model).name,
                "family": self.model.family, "model": self.model.to_json(),
                "parameters": {e.name: e.to_json(unit=spelt_unit(e.name, e.unit, self.model)) for e in self.estimates},
                **self.fit_json()}

    def fit_json(self) -> dict[str, Any]:
        """The strategy's own figures (none here)."""
        return {}

    @classmethod
    def from_json(cls, data: Any) -> Self:
        """The record of a :meth:`to_json` object, of the strategy its model's family names.

        Raises
        ------
        InputError
            Not an object of a version this reads, no ``model`` or ``parameters`` object, a model of another
            strategy than ``cls``'s, or a bad field (one-line message).
        """
        from .identify import strategy_of  # identify imports this module

        d = check_schema_version(data, "identification JSON", range(1, IDENTIFICATION_SCHEMA_VERSION + 1))
        params = d.get("parameters")
        if not isinstance(params, Mapping) or not isinstance(d.get("model"), Mapping):
            raise InputError("identification JSON needs 'model' and 'parameters' objects")
        model = model_from_json(d["model"])
        strategy = strategy_of(model)
        sub = getattr(importlib.import_module(strategy.module), strategy.record)
        if not issubclass(sub, cls):
            raise InputError(f"identification JSON: a {model.family} model's record ({strategy.name}), "
                             f"not a {cls.__name__}")
        bounds = {n: p.bounds for n, p in model.parameters.items()} if sub._sided else {}
        estimates = tuple(ParameterEstimate.from_json(str(n), v, bounds=bounds.get(str(n)), open_value=sub._open_value,
                                                      method=sub._method)
                          for n, v in params.items() if v is not None or n not in sub._optional)
        try:
            record: Self = sub.fit_from_json(d, model, estimates)
            return record
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"identification JSON: bad or missing field ({type(err).__name__}: {err})") from err

    @classmethod
    def fit_from_json(cls, data: Mapping[str, Any], model: Any,
                      estimates: tuple[ParameterEstimate, ...]) -> Self:
        """The record from its model, estimates and the strategy's keys of ``data`` (:meth:`fit_json`)."""
        return cls(model, estimates)
