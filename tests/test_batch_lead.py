"""batch's lead (eq. (2) identified with tau < 0): one test (``summary.lead_rows``) for the printed table's flag,
the summary's notes and its column; synthetic frames, no analysis (cheap)."""

from __future__ import annotations

import math

import pandas as pd

from mrftcli.batch.summary import lead_note, lead_rows


def test_one_lead_test_serves_the_table_and_the_notes() -> None:
    """tau_mean < 0 on an eq. (2) row is a lead; 0, a positive tau, NaN (a failed row), a process row (its
    families take tau >= 0: not eq. (2)'s lead) and a frame without tau_mean are not."""
    eq2 = pd.DataFrame({"path": ["a.ulg", "b.ulg", "c.ulg", "d.ulg"], "loop": ["pitch"] * 4,
                        "tau_mean": [-0.003, 0.0, 0.002, math.nan]})
    assert lead_rows(eq2).tolist() == [True, False, False, False]
    note = lead_note(eq2)
    assert note is not None and note.startswith("1 loop(s)") and "a.ulg pitch (-3 ms)" in note
    process = eq2.assign(model=pd.Series(["fopdt", None, None, None], dtype="string"))
    assert lead_rows(process).tolist() == [False, False, False, False] and lead_note(process) is None
    assert lead_rows(pd.DataFrame({"path": ["x"]})).tolist() == [False]
