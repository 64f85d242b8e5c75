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
    note = lead_note(eq2.assign(lead=lead_rows(eq2)))  # the note reads summary_frame's column
    assert note is not None and note.startswith("1 loop(s)") and "a.ulg pitch (-3 ms)" in note
    process = eq2.assign(model=pd.Series(["fopdt", None, None, None], dtype="string"))
    assert lead_rows(process).tolist() == [False, False, False, False]
    assert lead_note(process.assign(lead=lead_rows(process))) is None
    assert lead_rows(pd.DataFrame({"path": ["x"]})).tolist() == [False]


def test_the_summary_and_the_fleet_report_carry_the_lead(tmp_path, monkeypatch) -> None:
    """summary.csv/parquet had no lead column and the fleet HTML no lead at all (only the printed row and the
    notes said it): the summary's ``lead`` column (after tau_std) and the report's row and notes now do."""
    import mrftcli.report.fleet as fleet
    from mrftcli.batch.summary import SUMMARY_COLUMNS, summary_frame

    rows = [{"path": f"/f/{name}.ulg", "loop": "pitch", "vehicle": "v", "status": "ok", "result_status": "ok",
             "tau_mean": tau, "tau_std": 5e-4, "Td_mean": 1.0, "Td_std": 0.1, "K_mean": 100.0, "K_std": 1.0,
             "n_tests": 2, "n_cycles": 20} for name, tau in (("lead", -0.0029), ("lag", 0.004))]
    df = summary_frame(rows)
    assert SUMMARY_COLUMNS.index("lead") == SUMMARY_COLUMNS.index("tau_std") + 1
    assert df["lead"].tolist() == [True, False]
    df.to_parquet(tmp_path / "s.parquet", index=False, engine="pyarrow")
    assert pd.read_parquet(tmp_path / "s.parquet")["lead"].tolist() == [True, False]
    monkeypatch.setattr(fleet, "plot_loop", lambda d, loop, path: path)  # the table, not the figure
    html = fleet.write_fleet_report(df, tmp_path / "report", notes=[str(lead_note(df))]).read_text()
    assert "<th>lead (tune designs at tau 0)</th>" in html
    lead_row = next(r for r in html.split("<tr>") if "/f/lead.ulg" in r)
    lag_row = next(r for r in html.split("<tr>") if "/f/lag.ulg" in r)
    assert "<td>tau &lt; 0</td>" in lead_row and "tau &lt; 0" not in lag_row
    assert "1 loop(s) identified with tau &lt; 0" in html and "lead.ulg pitch (-2.9 ms)" in html


def test_a_process_summarys_rows_never_lead() -> None:
    """summary_frame computes the column once, with a process row's model beside it: a process family's tau < 0
    (impossible for its families, here forced) is not eq. (2)'s lead; an eq. (2) row in the same frame still is."""
    from mrftcli.batch.summary import summary_frame

    base = {"loop": "pitch", "vehicle": "v", "status": "ok", "result_status": "ok", "tau_std": 1e-4, "n_tests": 2}
    rows = [{**base, "path": "/f/p.csv", "tau_mean": -0.002, "model": "fopdt", "parameters": "K 1"},
            {**base, "path": "/f/q.ulg", "tau_mean": -0.003}]
    df = summary_frame(rows)
    assert df["lead"].tolist() == [False, True]
    assert lead_note(df) == ("1 loop(s) identified with tau < 0 (a lead: eq. (2) admits an estimator's few ms; tune "
                             "designs them at tau = 0): q.ulg pitch (-3 ms)")
