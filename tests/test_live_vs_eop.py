"""benchmarks/live_vs_eop.py's summary: the LTP / protocol ratio is taken over the rows both
protocols have (QA pass 16b: with some runs missing, means over different rows were divided:
68.7x printed where the one common row gave 25.4 / 0.2)."""

from __future__ import annotations

import pytest

from conftest import benchmark


@pytest.fixture(scope="module")
def live_vs_eop():
    return benchmark("live_vs_eop")


def test_the_ratio_is_over_the_rows_both_protocols_have(live_vs_eop):
    timing = {"age": 1.0, "ego_ms": 2.0}
    row = lambda sr: (sr, sr, 10.0, timing)   # noqa: E731  (SR = NT2F, for short)
    table = {("kcf", "baseline"): {"live": [row(0.50)], "ltp": [row(0.52)]},                  # |dSR| 2 at LTP only
             ("nanotrack", "mata"): {"live": [row(0.50)], "ltp": [row(0.754)], "eopself": [row(0.502)]}}
    text = live_vs_eop.render(table)
    assert "- mean |dSR| ltp: 13.7, mean |dNT2F|: 13.7 points over 2 row(s)" in text
    # LTP / eopself over nanotrack alone: 25.4 / 0.2 = 127x (the means of different rows gave 13.7 / 0.2)
    assert ("- mean |dSR| eopself: 0.2, mean |dNT2F|: 0.2 points over 1 row(s) (LTP / eopself over the 1 row(s) "
            "both have: SR 127.0x, NT2F 127.0x)") in text
