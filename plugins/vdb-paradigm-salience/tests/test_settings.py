"""The salience grid is recorded whole in run.json, defaults included: a directory made under one default is
not resumed after the default changed (one line, exit 2, nothing touched); an unchanged rerun still resumes."""

from __future__ import annotations

import json

import pytest
from vdb_paradigm_salience.paradigm import Salience
from vladrivebench.intervention import EffectiveOptions
from vladrivebench.testing import run_cli

pytest.importorskip("vdb_model_scripted", reason="the scripted model plugin is not installed")
pytest.importorskip("vdb_sim_kinematic", reason="the kinematic simulator plugin is not installed")

# one cell, injected from the start; max_time is left at the paradigm's default
RUN = ["intervene", "--model", "scripted", "--route", "SAFE.centre-ped", "--mode", "salience", "--seeds", "1",
       "--quiet", "--paradigm-opt", "kinds=pedestrian", "--paradigm-opt", "offsets=0", "--paradigm-opt",
       "distances=70", "--paradigm-opt", "sizes=1"]


def snapshot(out):
    return {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def test_the_effective_grid_is_the_parsed_options_with_the_defaults():
    paradigm = Salience(kinds="car", sizes="1.3,0.7")
    assert isinstance(paradigm, EffectiveOptions)
    assert paradigm.effective_options() == {"kinds": ["car"], "offsets": [-1.0, 0.0], "distances": [25.0, 50.0],
                                            "sizes": [0.7, 1.3], "max_time": 30.0}


def test_a_changed_default_is_refused_on_resume_and_an_unchanged_rerun_resumes(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    assert run_cli([*RUN, "--out", str(out)]) == 0
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["config"]["paradigm_settings"]["max_time"] == 30.0
    assert "max_time" not in manifest["config"]["paradigm_options"]
    before = snapshot(out)
    capsys.readouterr()

    defaults = dict(zip(("kinds", "offsets", "distances", "sizes", "max_time"), Salience.__init__.__defaults__,
                        strict=True))
    monkeypatch.setattr(Salience.__init__, "__defaults__", tuple({**defaults, "max_time": 20.0}.values()))
    assert run_cli([*RUN, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("vdb: error: "), err
    assert "paradigm 'salience'" in err[0] and "max_time: 20.0 now, 30.0 before" in err[0], err[0]
    assert "a default of the paradigm changed" in err[0], err[0]
    assert snapshot(out) == before

    monkeypatch.undo()
    assert run_cli([*RUN, "--out", str(out)]) == 0
    assert snapshot(out) == before  # every episode was already there: nothing rerun, the same results
