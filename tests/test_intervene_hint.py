"""The command `vdb intervene` prints for the plots works exactly as printed."""

from __future__ import annotations

import re
import shlex

import intervention_fakes as fakes
from vladrivebench._cli import main as cli
from vladrivebench._engine import registry as plugins


def test_the_printed_report_hint_runs(capsys, tmp_path):
    previous = plugins.set_registry(fakes.fake_registry())
    try:
        out = tmp_path / "run dir"
        code = cli.main(["intervene", "--model", "keyword", "--sim", "line", "--controller", "speed", "--quiet",
                         "--route", "E.1", "--seeds", "2", "--out", str(out), "--conditions", "accel"])
        printed = capsys.readouterr().out
        assert code == 0
        hint = re.search(r"`vdb (report [^`]+)`", printed).group(1)
        assert cli.main(shlex.split(hint)) == 0, capsys.readouterr().err
        assert (out / "report.html").exists()
    finally:
        plugins.set_registry(previous)
