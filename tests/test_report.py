"""`vdb label`, `vdb metrics`, `vdb report`, `vdb labels agree` end to end on synthetic logs, and rendering."""

from __future__ import annotations

import base64
import importlib
import json
import re
import sys
from pathlib import Path

import pytest
import vladrivebench
from vladrivebench._analysis.labels import LabelStore
from vladrivebench._analysis.report import Section, cell_text, render_latex
from vladrivebench._analysis.tables import Cell, Row, Table
from vladrivebench._cli.main import main

GOLD = Path(__file__).parent / "data" / "gold_labels.jsonl"


@pytest.fixture(scope="module")
def fx():
    folder = str(Path(__file__).parent)
    if folder not in sys.path:
        sys.path.insert(0, folder)
    return importlib.import_module("analysis_episodes")


@pytest.fixture
def run_dir(tmp_path, fx):
    """Two models on a pedestrian approach plus a baseline run, as a `vdb run` output directory."""
    episodes = tmp_path / "episodes"
    for model, text in (("alpha", fx.STOP_PED), ("beta", fx.CONTRADICTION)):
        fx.write_episode(episodes / f"{model}__P.1__s0.mcap", speeds=[3.0] * 190, model=model,
                         cot=lambda s, d, v, t=text: t if d < 30 else fx.CLEAR, v_des=lambda s, d, v: v * 0.8)
    fx.write_episode(episodes / "alpha__BASE__s0.mcap", speeds=[5.0] * 30, kind=None, model="alpha",
                     scenario_id="BASE", cot=lambda s, d, v: fx.ACCEL, v_des=lambda s, d, v: v)
    return tmp_path


def vdb(fx, capsys, *args):
    with fx.registry_with_fakes():
        code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(code, err):
    assert code == 2
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("vdb: error: ") and "Traceback" not in err
    return lines[0]


# -- vdb label ----------------------------------------------------------------------------------------------
def test_label_stores_once_and_relabelling_costs_nothing(run_dir, fx, capsys):
    code, out, _ = vdb(fx, capsys, "label", str(run_dir), "--labeler", "fake", "--quiet")
    assert code == 0 and out.startswith("labelled ") and "for 410 steps (0 already stored, " in out
    first = len(LabelStore(run_dir, "fake"))
    assert first == len((run_dir / "labels" / "fake.jsonl").read_text().splitlines())
    code, out, _ = vdb(fx, capsys, "label", str(run_dir), "--labeler", "fake", "--quiet")
    assert code == 0 and out.startswith("labelled 0 new CoTs for 410 steps (410 already stored)")
    code, out, _ = vdb(fx, capsys, "label", str(run_dir), "--labeler", "fake", "--labeler-opt", "version=v2",
                       "--quiet")
    assert code == 0 and f"labelled {first} new CoTs" in out  # a new version relabels exactly what is stored


def test_label_shows_progress_with_eta_on_stderr(run_dir, fx, capsys):
    code, out, err = vdb(fx, capsys, "label", str(run_dir), "--labeler", "fake", "--chunk", "50")
    assert code == 0 and re.search(r"labelled: (\d+)/\1 CoTs, done in \d+s", err)


def test_a_killed_labelling_keeps_the_chunks_done(run_dir, fx, capsys):
    with fx.registry_with_fakes():
        code = main(["label", str(run_dir), "--labeler", "dying", "--chunk", "3", "--quiet"])
    capsys.readouterr()
    assert code == 130
    assert len(LabelStore(run_dir, "dying")) == 6
    code, out, _ = vdb(fx, capsys, "label", str(run_dir), "--labeler", "dying", "--chunk", "1000", "--quiet")
    unique = len(LabelStore(run_dir, "dying"))
    assert code == 0 and out.startswith(f"labelled {unique - 6} new CoTs")  # only what the kill left undone


@pytest.mark.parametrize(("args", "message"), [
    (["--backends", "openai:x"], "labeler 'fake' does not take option 'backends'"),
    (["--dry-run"], "labeler 'fake' has no plan()"),
    (["--labeler", "nope"], "unknown labeler 'nope'"),
    (["--labeler", "checked"], "FAKE_API_KEY is not set"),
    (["--labeler-opt", "noequals"], "expected key=value"),
    (["--out", "x.jsonl"], "--out goes with --texts"),
])
def test_label_mistakes_are_one_line_and_write_nothing(run_dir, fx, capsys, args, message):
    code, _, err = vdb(fx, capsys, "label", str(run_dir), *(["--labeler", "fake"] if "--labeler" not in args else []),
                       *args)
    assert message in one_line_error(code, err)
    assert not (run_dir / "labels").exists()


def test_dry_run_prints_the_labelers_plan(run_dir, fx, capsys):
    code, out, _ = vdb(fx, capsys, "label", str(run_dir), "--labeler", "planning", "--dry-run")
    assert code == 0 and "fake-backend: " in out and " calls, 0 cached" in out
    assert not (run_dir / "labels").exists()


def test_label_a_directory_without_logs(tmp_path, fx, capsys):
    code, _, err = vdb(fx, capsys, "label", str(tmp_path), "--labeler", "fake")
    assert "no episode logs" in one_line_error(code, err)


# -- standalone texts and agreement --------------------------------------------------------------------------------
def test_label_texts_then_agree_with_a_gold_file(tmp_path, fx, capsys):
    src = tmp_path / "cots.jsonl"
    lines = [{"id": f"c{i}", "text": t, "context": {"critical_kind": "pedestrian"}}
             for i, t in enumerate([fx.STOP_PED, fx.CLEAR, fx.PHANTOM_CAR, fx.CONTRADICTION, fx.ACCEL] * 4)]
    src.write_text("\n".join(json.dumps(line) for line in lines) + "\n")
    out = tmp_path / "labelled.jsonl"
    code, stdout, _ = vdb(fx, capsys, "label", "--texts", str(src), "--out", str(out), "--labeler", "fake", "--quiet")
    assert code == 0 and "labelled 20 CoTs" in stdout
    gold = tmp_path / "gold.jsonl"
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    rows[2]["labels"]["hallucination"] = False  # one disagreement
    gold.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    code, stdout, _ = vdb(fx, capsys, "labels", "agree", str(gold), str(out))
    assert code == 0 and "20 items compared" in stdout
    assert "stated_action: κ = 1.000" in stdout and re.search(r"hallucination: κ = 0\.\d+", stdout)
    code, stdout, _ = vdb(fx, capsys, "labels", "agree", str(gold), str(out), "--json")
    data = json.loads(stdout)
    hall = next(p for p in data["properties"] if p["property"] == "hallucination")
    assert hall["confusion"] == [[16, 1], [0, 3]] and hall["categories"] == ["no", "yes"]


def test_gold_file_agrees_with_itself(fx, capsys):
    code, out, _ = vdb(fx, capsys, "labels", "agree", str(GOLD), str(GOLD))
    assert code == 0 and out.count("κ = 1.000") == 6


@pytest.mark.parametrize(("args", "message"), [
    (["label", "--texts", "missing.jsonl", "--out", "o.jsonl"], "missing.jsonl: no such file"),
    (["label", "--texts", "in.jsonl"], "--out FILE.jsonl is required"),
    (["labels", "agree", "in.jsonl", "in.jsonl"], 'in.jsonl:1: no "labels"'),
])
def test_texts_mistakes_are_one_line(tmp_path, fx, capsys, monkeypatch, args, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "in.jsonl").write_text('{"text": "Stop."}\n')
    code, _, err = vdb(fx, capsys, *args)
    assert message in one_line_error(code, err)


# -- vdb metrics / report ------------------------------------------------------------------------------------------
def test_metrics_json_has_every_table_with_counts(run_dir, fx, capsys):
    vdb(fx, capsys, "label", str(run_dir), "--labeler", "fake", "--quiet")
    code, out, _ = vdb(fx, capsys, "metrics", str(run_dir), "--json")
    assert code == 0
    data = json.loads(out)
    ids = [r["id"] for m in data["metrics"] for r in m["results"]]
    assert ids[:2] == ["mention_rate", "mention_rate_by_distance"]
    assert {"contradiction", "alignment_distance", "alignment_command", "hallucination"} <= set(ids)
    for metric in data["metrics"]:
        for result in metric["results"]:
            if result["type"] == "table":
                assert all("count" in cell for row in result["rows"] for cell in row["cells"])
    contradiction = next(r for m in data["metrics"] for r in m["results"] if r["id"] == "contradiction")
    beta = next(row for row in contradiction["rows"] if row["labels"][0] == "beta")
    assert beta["cells"][1]["value"] > 0 and beta["cells"][1]["low"] < beta["cells"][1]["value"]


def test_metrics_text_lists_what_is_missing(run_dir, fx, capsys):
    code, out, _ = vdb(fx, capsys, "metrics", str(run_dir))
    assert code == 0 and "note: no labels" in out


def test_html_report_embeds_png_plots_and_models_side_by_side(run_dir, fx, capsys):
    vdb(fx, capsys, "label", str(run_dir), "--labeler", "fake", "--quiet")
    target = run_dir / "report.html"
    code, out, _ = vdb(fx, capsys, "report", str(run_dir), "--format", "html", "--out", str(target))
    assert code == 0 and "plots" in out
    page = target.read_text()
    images = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", page)
    assert len(images) >= 3 and all(base64.b64decode(i).startswith(b"\x89PNG") for i in images)
    assert "colspan='3'>alpha</th>" in page and "colspan='3'>beta</th>" in page
    assert "<span class='n'>" in page  # counts beside values


@pytest.mark.parametrize("fmt", ["md", "latex"])
def test_md_and_latex_reports_write_their_plots_beside_them(run_dir, fx, capsys, fmt):
    vdb(fx, capsys, "label", str(run_dir), "--labeler", "fake", "--quiet")
    target = run_dir / f"report.{fmt}"
    code, _, _ = vdb(fx, capsys, "report", str(run_dir), "--format", fmt, "--out", str(target))
    assert code == 0
    text = target.read_text()
    plots = sorted((run_dir / "report_plots").glob("*.png"))
    assert plots and all(p.name in text for p in plots)
    if fmt == "latex":
        assert "\\toprule" in text and "\\multicolumn{3}{c}{alpha}" in text and "\\cmidrule(lr){2-4}" in text
    else:
        assert "| Scenario | alpha far |" in text


def test_report_into_a_missing_folder_is_one_line(run_dir, fx, capsys):
    code, _, err = vdb(fx, capsys, "report", str(run_dir), "--format", "md", "--out", str(run_dir / "no" / "r.md"))
    assert "does not exist" in one_line_error(code, err)


class _Broken:
    name = "broken"

    def compute(self, dataset):
        raise RuntimeError("boom")


@vladrivebench.hookimpl
def register_metrics(register):
    register("broken", _Broken, description="a metric that raises")


def test_a_failing_third_party_metric_becomes_a_note_or_fails_with_strict(run_dir, fx, capsys):
    this = sys.modules[__name__]
    from vladrivebench import _builtins as builtins
    from vladrivebench.testing import isolated_registry

    with isolated_registry(("core", builtins), ("fakes", fx), ("broken", this)):
        code = main(["metrics", str(run_dir)])
        out, _ = capsys.readouterr()
        assert code == 0 and "metric 'broken' (plugin broken, (local)) failed: RuntimeError: boom" in out
        code = main(["metrics", str(run_dir), "--strict"])
        _, err = capsys.readouterr()
    assert "RuntimeError: boom" in one_line_error(code, err)


# -- rendering details ----------------------------------------------------------------------------------------------
def test_cells_show_their_counts_and_dashes():
    assert cell_text(Cell.rate(3, 4)) == "75.0 (4)"
    assert cell_text(Cell.rate(1, 1)) == "— (1)"
    assert cell_text(Cell("12", 12, 12.0)) == "12"


def test_latex_escapes_and_dashes():
    table = Table("t_x", "Rate (%) & more", ("Scenario",), ("far", "med"),
                  (Row(("Pedestrian_(x)",), (Cell.rate(1, 1), Cell.rate(1, 2))),), groups=(("m#1", 2),))
    text = render_latex(_dataset(), [Section("m", "", [table])], {})
    assert "Rate (\\%) \\& more" in text and "Pedestrian\\_(x)" in text and "m\\#1" in text
    assert "---\\,{\\tiny(1)}" in text and "50.0\\,{\\tiny(2)}" in text


def _dataset():
    from vladrivebench._analysis.tables import AnalysisDataset

    return AnalysisDataset(directory=Path("d"), episodes=[])


def test_two_labelers_of_one_run_are_compared_through_their_stores(run_dir, fx, capsys):
    vdb(fx, capsys, "label", str(run_dir), "--labeler", "fake", "--quiet")
    vdb(fx, capsys, "label", str(run_dir), "--labeler", "planning", "--quiet")
    code, out, _ = vdb(fx, capsys, "labels", "agree", str(run_dir / "labels" / "fake.jsonl"),
                       str(run_dir / "labels" / "planning.jsonl"))
    stored = len(LabelStore(run_dir, "fake"))
    assert code == 0 and out.startswith(f"{stored} items compared") and "stated_action: κ = 1.000" in out
