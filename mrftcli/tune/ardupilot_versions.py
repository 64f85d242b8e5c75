"""ArduPilot's parameter names per release, and the pre-arm rules on the parameters ``tune --export`` writes.

**Versions.** ArduPilot 4.7 renamed AC_PosControl's z cascade and moved it to SI units
(``AC_PosControl::convert_parameters``, "PARAMETER_CONVERSION - Added: Nov-2024 for 4.7"): ``PSC_POSZ_P`` ->
``PSC_D_POS_P``; ``PSC_VELZ_*`` -> ``PSC_D_VEL_*`` (values moved as they are); ``PSC_ACCZ_P``/``_I``/``_D`` ->
``PSC_D_ACC_*`` x 0.1 (``convert_old_parameters_scaled(conversion_info_01, ..., 0.1, 0)``: the throttle per
m/s^2 instead of per 1000 per cm/s^2); ``PSC_ACCZ_FF``/``_FLTE``/``_FLTT``/``_FLTD`` moved unscaled (the
conversion table; the _D_ACC_FF @Description says x 0.1, the code does not: we write 0, where both agree).
A 4.6 name loaded on 4.7 by a ground station is skipped (the vehicle has no such parameter), so the file
names its version. The design works in 4.6's units (:mod:`mrftcli.tune.ardupilot_z`); :func:`ardupilot_names`
writes a version's names and scalings, :func:`to_46_units` reads them back.

The default is the current stable release, :data:`ARDUPILOT_DEFAULT_VERSION`: 4.7 (ArduPilot's "Parameter Name
Changes" page: "These renames shipped in the 4.7.0 release"). The 4.7 rows are from AC_PosControl.cpp after the
rename; ``blitzy-public-samples/ardupilot-blitzy`` (upstream master of 2025-07-21, "4.7.0-dev") predates it and
still has 4.6's names, so its SITL takes ``--stack-version 4.6``. The roll/pitch (``ATC_``) names are written
the same for both versions (not re-read for 4.7).

**Pre-arm rules** (:func:`prearm_checks`): the vehicle refuses to arm on ``AC_PosControl::pre_arm_checks``
(``_POSZ_P``, ``_VELZ_P``, ``_ACCZ_P``, ``_ACCZ_I`` > 0; 4.7: ``_D_POS_P``, ``_D_VEL_P``, ``_D_ACC_P``,
``_D_ACC_I``) and ``AC_AttitudeControl::pre_arm_checks`` (``ANG_*_P`` > 0; with ``RAT_*_FF`` 0 the rate P and I
> 0; D >= 0), both called from ``AP_Arming_Copter::parameter_checks`` ("Bad parameter: %s"), which also
refuses ``ACRO_BAL_ROLL``/``_PITCH`` above the angle P (checked against their largest documented value, 3). Each rule is
checked on the values written, with its source line.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

__all__ = ["ARDUPILOT_VERSIONS", "ARDUPILOT_DEFAULT_VERSION", "ardupilot_names", "to_46_units", "PreArmRule",
           "PreArmResult", "prearm_checks", "check_version", "z_bounds"]

ARDUPILOT_VERSIONS = ("4.6", "4.7")
#: The current stable release (ardupilot.org "Parameter Name Changes": the renames shipped in 4.7.0).
ARDUPILOT_DEFAULT_VERSION = "4.7"

#: 4.6 name -> (4.7 name, scale: 4.7 value = scale x 4.6 value), AC_PosControl::convert_parameters.
_RENAMES_47: dict[str, tuple[str, float]] = {
    "PSC_POSZ_P": ("PSC_D_POS_P", 1.0),
    "PSC_VELZ_P": ("PSC_D_VEL_P", 1.0), "PSC_VELZ_I": ("PSC_D_VEL_I", 1.0), "PSC_VELZ_D": ("PSC_D_VEL_D", 1.0),
    "PSC_VELZ_FF": ("PSC_D_VEL_FF", 1.0), "PSC_VELZ_FLTE": ("PSC_D_VEL_FLTE", 1.0),
    "PSC_ACCZ_P": ("PSC_D_ACC_P", 0.1), "PSC_ACCZ_I": ("PSC_D_ACC_I", 0.1), "PSC_ACCZ_D": ("PSC_D_ACC_D", 0.1),
    "PSC_ACCZ_FF": ("PSC_D_ACC_FF", 1.0), "PSC_ACCZ_FLTE": ("PSC_D_ACC_FLTE", 1.0),
}

_BLITZY = "blitzy-public-samples/ardupilot-blitzy @2598e9d4 (upstream master 2025-07-21, 4.6 names)"
_PSC46 = f"libraries/AC_AttitudeControl/AC_PosControl.cpp:{{}} ({_BLITZY})"
_PSC47 = ("libraries/AC_AttitudeControl/AC_PosControl.cpp, AC_PosControl::pre_arm_checks after the 4.7 rename "
          "(upstream; '%s_D_ACC_I must be > 0')")
_ATC = f"libraries/AC_AttitudeControl/AC_AttitudeControl.cpp:{{}} ({_BLITZY})"


def check_version(version: str | None) -> str:
    """The version to write (default :data:`ARDUPILOT_DEFAULT_VERSION`), or InputError naming the choices."""
    from ..errors import InputError

    v = ARDUPILOT_DEFAULT_VERSION if version is None else version
    if v not in ARDUPILOT_VERSIONS:
        raise InputError(f"--stack-version {version}: ArduPilot versions supported are "
                         f"{', '.join(ARDUPILOT_VERSIONS)} (their parameter names differ)")
    return v


def ardupilot_names(params: Mapping[str, float], version: str) -> dict[str, float]:
    """``params`` (4.6 names and units) as ``version`` names and scales them (order kept)."""
    if version == "4.6":
        return dict(params)
    out = {}
    for n, v in params.items():
        new, scale = _RENAMES_47.get(n, (n, 1.0))
        out[new] = scale * v
    return out


def to_46_units(params: Mapping[str, float]) -> dict[str, float]:
    """A file's values (either version's names) in 4.6's names and units (the inverse of :func:`ardupilot_names`)."""
    back = {new: (old, scale) for old, (new, scale) in _RENAMES_47.items()}
    out = {}
    for n, v in params.items():
        old, scale = back.get(n, (n, 1.0))
        out[old] = v / scale
    return out


def z_bounds(version: str) -> dict[str, tuple[float, float]]:
    """The z cascade's documented ranges in 4.6's names and units, for ``version`` (what the design must keep)."""
    from .stack_params import param

    out = {}
    for old in ("PSC_POSZ_P", "PSC_VELZ_P", "PSC_VELZ_I", "PSC_ACCZ_P", "PSC_ACCZ_I"):
        new, scale = _RENAMES_47[old] if version == "4.7" else (old, 1.0)
        row = param("ardupilot", new)
        out[old] = (row.minimum / scale, row.maximum / scale)
    return out


@dataclass(frozen=True)
class PreArmRule:
    """One pre-arm rule on one parameter: ``value > bound`` (``strict``) or ``>= bound``, and where the stack
    says so; ``bound_name`` names a vehicle parameter the bound stands for (at its largest documented value)."""

    param: str
    strict: bool
    source: str
    bound: float = 0.0
    bound_name: str = ""

    @property
    def rule(self) -> str:
        against = f"{self.bound_name} (<= {self.bound:g})" if self.bound_name else f"{self.bound:g}"
        return f"{self.param} {'>' if self.strict else '>='} {against}"

    def passes(self, value: float) -> bool:
        if self.strict:
            return value > self.bound
        return value >= self.bound - 1e-9 * max(1.0, abs(self.bound))  # a value written at the bound


@dataclass(frozen=True)
class PreArmResult:
    """A rule checked on the value written."""

    rule: PreArmRule
    value: float
    passed: bool

    def to_json(self) -> dict[str, object]:
        return {"rule": self.rule.rule, "value": self.value, "passed": self.passed, "source": self.rule.source}


def _rules(version: str) -> tuple[PreArmRule, ...]:
    if version == "4.7":
        psc = [PreArmRule(n, True, _PSC47) for n in ("PSC_D_POS_P", "PSC_D_VEL_P", "PSC_D_ACC_P", "PSC_D_ACC_I")]
    else:
        psc = [PreArmRule(n, True, _PSC46.format(line)) for n, line in
               (("PSC_POSZ_P", 1848), ("PSC_VELZ_P", 1852), ("PSC_ACCZ_P", 1856), ("PSC_ACCZ_I", 1860))]
    atc = []
    for ax, acro in (("RLL", "ACRO_BAL_ROLL"), ("PIT", "ACRO_BAL_PITCH")):
        atc += [PreArmRule(f"ATC_ANG_{ax}_P", True, _ATC.format(1418)),
                # AP_Arming_Copter::parameter_checks "Check ACRO_BAL_ROLL/PITCH"; ACRO_BAL_* @Range 0 3
                PreArmRule(f"ATC_ANG_{ax}_P", False, f"ArduCopter/AP_Arming_Copter.cpp:229 ({_BLITZY})", 3.0, acro),
                PreArmRule(f"ATC_RAT_{ax}_P", True, _ATC.format(1450)),  # with FF 0 (line 1438: else branch)
                PreArmRule(f"ATC_RAT_{ax}_I", True, _ATC.format(1454)),
                PreArmRule(f"ATC_RAT_{ax}_D", False, _ATC.format(1460))]
    return (*psc, *atc)


def prearm_checks(params: Mapping[str, float], version: str) -> list[PreArmResult]:
    """Every pre-arm rule of ``version`` on a parameter in ``params`` (the names as written), checked.

    Examples
    --------
    >>> [(r.rule.rule, r.passed) for r in prearm_checks({"PSC_ACCZ_I": 0.0}, "4.6")]
    [('PSC_ACCZ_I > 0', False)]
    """
    return [PreArmResult(r, float(params[r.param]), r.passes(float(params[r.param])))
            for r in _rules(version) if r.param in params]
