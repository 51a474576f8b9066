"""The README generator: the answers it writes and the block it replaces."""

from __future__ import annotations

import pytest
from vdb_paradigm_salience.results import GRID, SECTION, answers, command, fill, pooled
from vdb_paradigm_salience.stats import logistic_threshold


def cell(kind, offset, pixels, overrides, trials):
    return {"kind": kind, "offset": offset, "key": f"{kind}_o{offset:g}_{pixels}", "salience": {"pixels": pixels},
            "counts": {"overrides": overrides, "trials": trials}}


def results(cells):
    fits = {kind: logistic_threshold([(c["salience"]["pixels"], c["counts"]["overrides"], c["counts"]["trials"])
                                      for c in cells if c["kind"] == kind]) for kind in ("pedestrian", "car")}
    return {"salience": {"cells": cells, "fits": fits}}


def test_the_answers_follow_the_counts():
    cells = [cell("pedestrian", -1.0, 5, 18, 20), cell("pedestrian", -1.0, 12, 15, 20),
             cell("pedestrian", 0.0, 6, 4, 20), cell("pedestrian", 0.0, 14, 2, 20),
             cell("car", -1.0, 6, 0, 20), cell("car", 0.0, 40, 0, 20)]
    text = "\n".join(answers(results(cells)))
    assert "kerbside pedestrian (offset -1 m) 33/40 = 82 %" in text and "centred 6/40 = 15 %" in text
    assert "overridden more often; the intervals separate" in text
    assert "car: no salience threshold — not identifiable (no trial was overridden" in text
    assert "the car is overridden least; the intervals separate" in text
    assert "pedestrian: the override rate falls as salience rises" in text


def test_overlapping_or_empty_cells_are_said_so():
    cells = [cell("pedestrian", -1.0, 5, 1, 4), cell("pedestrian", 0.0, 6, 1, 4), cell("car", 0.0, 40, 0, 0)]
    text = "\n".join(answers(results(cells)))
    assert "the kerbside one is overridden not more often; the intervals overlap" in text
    assert "cannot be compared (no trials)" in text and "cells without trials" in text
    assert pooled(cells, "car") == {"overrides": 0, "trials": 0, "rate": None, "low": None, "high": None, "cells": 1}


def test_the_block_is_replaced_between_its_markers_only():
    readme = f"before\n<!-- results:{SECTION} -->\nold\n<!-- /results:{SECTION} -->\nafter\n"
    assert fill(readme, "new\n") == f"before\n<!-- results:{SECTION} -->\nnew\n<!-- /results:{SECTION} -->\nafter\n"
    with pytest.raises(SystemExit, match="has no"):
        fill("no markers", "new\n")


def test_the_command_is_the_documented_sweep(tmp_path):
    args = command(tmp_path, 10, "kv", "mpc")
    assert args[:8] == ["intervene", "--model", "kv", "--controller", "mpc", "--mode", "salience", "--route"]
    assert [args[i + 1] for i, a in enumerate(args) if a == "--paradigm-opt"] == list(GRID)
    assert args[-2:] == ["--out", str(tmp_path / SECTION)] and "10" in args
