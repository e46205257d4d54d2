"""The validation page's pooled uncertainty coverage (issue 12 §4: across the studies)."""

import pytest

from hrvptm.collect import _coverage_overview


def _report(name: str, **variants) -> tuple:
    data = {
        "study": {"experiment": {"experiment": {"name": name}}},
        "variants": {k: {"summary": s} for k, s in variants.items()},
    }
    return (None, "", data)


def _summary(n: int, c1: float, c2: float, prefix: str = "u_") -> dict:
    out = {f"{prefix}coverage_n": n}
    for ax in "xyz":
        out[f"{prefix}coverage_1sigma_{ax}"] = c1
        out[f"{prefix}coverage_2sigma_{ax}"] = c2
    return out


def test_coverage_is_pooled_over_studies_weighted_by_their_errors():
    loaded = [
        _report("a", mismatched=_summary(100, 0.60, 0.90), matched=_summary(300, 0.70, 0.96)),
        _report("b", mismatched=_summary(600, 0.70, 0.95, prefix="")),  # positions: no "u_"
        _report("c", mismatched={"pooled_n": 5}),  # tables without σ: left out
    ]
    lines = _coverage_overview(loaded)
    rows = [ln for ln in lines if ln.startswith("| ")]
    assert rows[1:4] == [
        "| a (mismatched) | 100 | 60 / 90 | 60 / 90 | 60 / 90 |",
        "| a (matched) | 300 | 70 / 96 | 70 / 96 | 70 / 96 |",
        "| b (mismatched) | 600 | 70 / 95 | 70 / 95 | 70 / 95 |",
    ]
    # (100 × 0.60 + 900 × 0.70) / 1000 = 0.69; (90 + 288 + 570) / 1000 = 0.948
    assert rows[4] == "| **all studies** | 1000 | " + " | ".join(["**69 / 95**"] * 3) + " |"
    assert not any(ln.startswith("| c ") for ln in rows)


@pytest.mark.parametrize("summary", [{}, {"u_coverage_n": 0}])
def test_no_coverage_table_without_uncertainties(summary):
    assert _coverage_overview([_report("a", mismatched=summary)]) == []
