"""The MRFT maths: the paper's model, the exact limit cycle (LPRS), the UFM/UGM and identification."""

from .identify import IdentificationResult, ParameterEstimate, TestMeasurement, identify
from .lprs import LimitCycle, describing_function_limit_cycle, mrft_limit_cycle, sampled_limit_cycle
from .model import LoopModel
from .ufm import ManifoldSet, load_manifolds

__all__ = ["LoopModel", "LimitCycle", "mrft_limit_cycle", "sampled_limit_cycle", "describing_function_limit_cycle",
           "ManifoldSet", "load_manifolds", "TestMeasurement", "ParameterEstimate", "IdentificationResult",
           "identify"]
