"""The MRFT maths: the model object, the exact limit cycle (LPRS), the describing function, the
UFM/UGM, identification and the consensus of a log's tests.

Modules: :mod:`~mrftcli.mrft.model` (the model object; eq. (2)), :mod:`~mrftcli.mrft.families`
(the process families), :mod:`~mrftcli.mrft.lprs` (exact limit cycles),
:mod:`~mrftcli.mrft.describing` (harmonic balance, eqs. (4)-(7)), :mod:`~mrftcli.mrft.ufm`
(manifolds), :mod:`~mrftcli.mrft.identify` (the one entry point ``identify(data, model)``; each
family names its strategy: eq. (2)'s unit manifolds there, with :mod:`~mrftcli.mrft.slices` (the
tests' UFM slices and where they meet) and :mod:`~mrftcli.mrft.consensus` (weighted constraints and
bootstrap over a log's cycles); the families' response-point fit
:mod:`~mrftcli.mrft.identify_lti`; the cascade's :mod:`~mrftcli.mrft.cascade_identify`).
"""

from .describing import describing_function_limit_cycle
from .identification import IdentificationRecord
from .identify import IdentificationResult, ParameterEstimate, TestMeasurement, identify
from .lprs import LimitCycle, mrft_limit_cycle, sampled_limit_cycle
from .model import MODEL_FAMILIES, LoopModel, Parameter, PlantModel
from .ufm import ManifoldSet, load_manifolds

__all__ = ["LoopModel", "PlantModel", "Parameter", "MODEL_FAMILIES", "LimitCycle", "mrft_limit_cycle",
           "sampled_limit_cycle", "describing_function_limit_cycle", "ManifoldSet", "load_manifolds", "TestMeasurement", "ParameterEstimate", "IdentificationRecord", "IdentificationResult",
           "identify"]
