"""A real run end to end: `vdb run` (scripted model, kinematic simulator) → `vdb label` → `vdb metrics` /
`vdb report`, and the gold file through `vdb label --texts` → `vdb labels agree`."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from vdb_labeler_lexicon import plugin as lexicon_plugin
from vdb_model_scripted import plugin as scripted_plugin
from vdb_sim_kinematic import plugin as kinematic_plugin
from vladrivebench import _builtins as builtins
from vladrivebench._cli.main import main
from vladrivebench.testing import isolated_registry

GOLD = Path(__file__).parent / "data" / "gold_labels.jsonl"
PLUGINS = (("core", builtins), ("kinematic", kinematic_plugin), ("scripted", scripted_plugin),
           ("lexicon", lexicon_plugin))


def vdb(capsys, *args):
    with isolated_registry(*PLUGINS):
        code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    with isolated_registry(*PLUGINS):
        code = main(["run", "--model", "scripted", "--scenarios", "P.1", "--seeds", "1", "--out", str(out),
                     "--model-opt", "miss_rate=0.3", "--model-opt", "hallucination_rate=0.2", "--quiet"])
    assert code == 0
    return out


def test_label_metrics_report_on_a_real_run(run_dir, capsys, tmp_path):
    code, out, _ = vdb(capsys, "label", run_dir, "--quiet")
    assert code == 0 and "with lexicon" in out and (run_dir / "labels" / "lexicon.jsonl").exists()
    code, out, _ = vdb(capsys, "metrics", run_dir, "--json")
    data = json.loads(out)
    assert code == 0 and data["labels"]["missing"] == 0 and data["labels"]["labelled"] == data["labels"]["steps"]
    tables = {r["id"]: r for m in data["metrics"] for r in m["results"] if r["type"] == "table"}
    mention = tables["mention_rate"]
    assert mention["rows"][0]["labels"] == ["Pedestrian (in-lane)"]
    far = mention["rows"][0]["cells"][0]
    assert far["count"] > 20 and 0.4 < far["value"] < 0.95  # miss rate 0.3 within perception range
    assert {"hallucination", "contradiction", "alignment_distance", "alignment_runs"} <= set(tables)
    report = tmp_path / "report.html"
    code, out, _ = vdb(capsys, "report", run_dir, "--format", "html", "--out", report)
    assert code == 0 and report.read_text().count("data:image/png;base64,") >= 3


def test_a_damaged_log_is_named_in_the_metrics(run_dir, capsys, tmp_path):
    damaged = tmp_path / "damaged"
    (damaged / "episodes").mkdir(parents=True)
    for log in (run_dir / "episodes").glob("*.mcap"):
        data = log.read_bytes()
        (damaged / "episodes" / log.name).write_bytes(data[: len(data) // 2])
    code, out, _ = vdb(capsys, "metrics", damaged)
    assert code == 0 and "is truncated: its" in out and "steps are used" in out
    code, _, err = vdb(capsys, "metrics", damaged, "--strict")
    assert code == 2 and err.startswith("vdb: error: episode log") and len(err.splitlines()) == 1


def test_gold_file_through_the_cli(capsys, tmp_path):
    out = tmp_path / "lexicon.jsonl"
    code, _, _ = vdb(capsys, "label", "--texts", GOLD, "--out", out, "--quiet")
    assert code == 0
    code, text, _ = vdb(capsys, "labels", "agree", GOLD, out, "--json")
    report = json.loads(text)
    assert code == 0 and report["compared"] >= 150
    assert all(p["kappa"] >= 0.9 for p in report["properties"])
