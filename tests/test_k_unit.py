"""Eq. (2)'s K, kept with an empty unit in memory as identify gives it, is spelt by one rule
(mrft.identification.spelt_unit) in every record that writes it: the identification record, the analysis JSON
(its parameters, parameters_mrft, parameters_waveform) and compare's estimates (three rules before)."""

from __future__ import annotations

import json

from mrftcli.analyze import AnalysisResult, AnalyzeOptions, analyze_path
from mrftcli.compare.inputs import estimates_from_analysis
from mrftcli.io import ReadOptions
from mrftcli.mrft.identification import spelt_unit
from mrftcli.mrft.model import K_UNIT, soiptd_model
from mrftcli.samples import sample_log


def test_one_rule_spells_eq2s_k_in_every_record():
    model = soiptd_model(0.0422)
    assert spelt_unit("K", "", model) == K_UNIT and spelt_unit("K", "m", model) == "m"
    assert spelt_unit("T", "", model) == ""  # not the model's: nothing to spell it from
    result = analyze_path(sample_log("design1_altitude.csv"), model, read=ReadOptions(loop="altitude"),
                          options=AnalyzeOptions(n_bootstrap=50))
    assert result.K.unit == ""  # in memory, as identify gives it
    data = json.loads(json.dumps(result.to_json()))
    groups = [data[k] for k in ("parameters", "parameters_mrft", "parameters_waveform") if k in data]
    assert len(groups) >= 2 and all(g["K"]["unit"] == K_UNIT and g["tau"]["unit"] == "s" for g in groups)
    assert result.identification.to_json()["parameters"]["K"]["unit"] == K_UNIT
    back = AnalysisResult.from_json(data)
    assert back.K.unit == "" and json.loads(json.dumps(back.to_json()))["parameters"]["K"]["unit"] == K_UNIT
    assert estimates_from_analysis(data, source="x").parameters["K"].unit == K_UNIT
