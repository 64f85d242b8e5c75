"""The waveform refinement's plant past a week of Td (issue 39, found on a JSBSim benchmark flight).

The output-error cost is flat in ln Td where the windows do not show the damping, so a line search
may try Td beyond a week; eq. (2)'s model refuses such a time as a unit mistake (a one-line
"give it in seconds"), and that refusal used to end the whole analysis. The plant is built at the
week instead (the cost stays flat past it), so the refinement ends and is judged by its own rules.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from mrftcli.errors import InputError
from mrftcli.mrft.model import LoopModel
from mrftcli.mrft.refine import loop_model_plant
from mrftcli.validate import MAX_TIME_S


def test_a_line_search_past_a_week_of_td_gets_the_week_not_a_unit_error():
    with pytest.raises(InputError, match="longer than a week"):
        LoopModel(0.05, 2.0 * MAX_TIME_S, 0.03, 2.0)  # what the fit's plant called before
    plant = loop_model_plant(0.05)
    far = plant(np.array([math.log(2.0 * MAX_TIME_S), 0.03, 2.0]))
    week = plant(np.array([math.log(MAX_TIME_S * (1 - 1e-9)), 0.03, 2.0]))
    for a, b in zip(far, week):
        np.testing.assert_allclose(a, b, rtol=1e-12)
    near = plant(np.array([math.log(3.0), 0.03, 2.0]))  # inside the range: the plant of Td itself
    ref = LoopModel(0.05, 3.0, 0.03, 2.0).realisation()
    np.testing.assert_allclose(near[0], ref.A, rtol=1e-12)
