"""Model-mismatch diagnosis: where the identified model and the recording disagree, and which physics explains it."""

from .physics import CANDIDATES, EFFECTS, LIBRARY, Effect
from .selection import BIC_THRESHOLD, DiagnosisResult, EffectFinding, diagnose

__all__ = ["diagnose", "DiagnosisResult", "EffectFinding", "BIC_THRESHOLD", "LIBRARY", "CANDIDATES", "EFFECTS", "Effect"]
