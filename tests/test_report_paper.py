"""The paper's Table III beside a run's table (clradcom.radar.report.paper_table_iii):
shown for the paper's street seen from radar A, and only where the cars stand as the
paper set them."""

import pytest

from clradcom.radar.report import paper_table_iii, truth_table_lines
from clradcom.scene.street import R_SET, TABLE_III, V_SET


def street_truth(shift_b=0.0):
    """The targets radar A sees on the paper's street, as detection_truth gives them."""
    return [{"name": f"car{k}", "range_centre_m": R_SET[k] + (shift_b if k == "B" else 0.0),
             "v_rel_m_s": 0.0, "v_rel_along_m_s": abs(V_SET["A"] - V_SET[k])}
            for k in ("B", "C", "D")]


def test_table_iii_set_values_are_the_streets():
    for k, row in TABLE_III.items():
        assert row["range_set_m"] == R_SET[k]
        assert row["v_rel_set_mps"] == pytest.approx(abs(V_SET["A"] - V_SET[k]))


def test_paper_rows_only_for_the_papers_cars_as_set():
    assert [r["range_sim_m"] for r in paper_table_iii("A", street_truth())] == [
        16.1, 25.2, 34.4]
    # car B moved 1 m: the paper's numbers no longer describe it
    moved = paper_table_iii("A", street_truth(shift_b=1.0))
    assert moved[0] is None and moved[1] is not None
    assert paper_table_iii("D", street_truth()) == [None, None, None]
    other = [{"name": "plate", "range_centre_m": 16.4, "v_rel_m_s": 26.2,
              "v_rel_along_m_s": 26.2}]
    assert paper_table_iii("A", other) == [None]


def test_table_lines_carry_the_paper_columns_only_where_they_apply():
    truth = street_truth()
    rows = [("", "", "", "", "16.31", "25.90")] * 3
    lines = truth_table_lines("A", truth, rows)
    assert "Table III" in lines[0]
    assert lines[2].split() == ["carB", "16.40", "0.00", "16.31", "25.90", "|", "16.40",
                                "26.20", "16.10", "25.70"]
    plain = truth_table_lines("D", truth, rows)
    assert not any("|" in line for line in plain)
    assert plain[1].split() == ["carB", "16.40", "0.00", "16.31", "25.90"]
