"""Registration and option validation: one-line errors, exit status 2, no traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest
from vdb_model_scripted import plugin
from vdb_model_scripted.model import ScriptedModel
from vladrivebench import ConfigError
from vladrivebench.testing import Registry


def registry() -> Registry:
    return Registry([("scripted", plugin)], entry_points=False)


def test_the_plugin_registers_the_scripted_model():
    reg = registry()
    assert reg.names("model") == ["scripted"]
    model = reg.create("model", "scripted", {"alpha": 1, "cot_format": "qa", "miss_rate": 0.25})
    assert isinstance(model, ScriptedModel)
    assert model.options()["alpha"] == 1.0 and model.rates.miss == 0.25 and model.cot_format.is_slotted


@pytest.mark.parametrize("options, message", [
    ({"alpha": 1.5}, "option alpha must be a number in [0, 1], got 1.5"),
    ({"alpha": "high"}, "option alpha must be a number in [0, 1], got 'high'"),
    ({"miss_rate": -0.1}, "option miss_rate must be a number in [0, 1]"),
    ({"hallucination_rate": True}, "option hallucination_rate must be a number in [0, 1], got True"),
    ({"contradiction_rate": float("nan")}, "option contradiction_rate must be a number in [0, 1]"),
    ({"light_error_rate": 2}, "option light_error_rate must be a number in [0, 1], got 2"),
    ({"cot_format": "json"}, "option cot_format must be 'sentence' or 'qa', got 'json'"),
    ({"cruise_speed": 12}, "option cruise_speed must be a number in [0.5, 8.5] m/s, got 12"),
    ({"perception_range": 0}, "option perception_range must be a number in [1, 1000] m, got 0"),
    ({"noise": -1}, "option noise must be a number in [0, 2] m/s, got -1"),
    ({"alpah": 0.5}, "does not take option 'alpha'"),
])
def test_bad_options_are_one_line_config_errors(options, message):
    with pytest.raises(ConfigError) as info:
        registry().create("model", "scripted", options)
    text = str(info.value)
    assert "\n" not in text
    if "does not take" in message:
        assert "does not take option 'alpah'" in text and "alpha" in text
    else:
        assert message in text and text.startswith("model 'scripted': ")


def test_registering_imports_nothing_heavy():
    code = ("import sys; from vladrivebench._engine.registry import Registry; import vdb_model_scripted.plugin as p; "
            "Registry([('scripted', p)], entry_points=False); "
            "print(sorted(m for m in ('torch', 'transformers', 'libsumo', 'scipy', 'vdb_model_scripted.model') "
            "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_cli_reports_a_bad_option_on_one_line_with_status_2(tmp_path):
    from vladrivebench.testing import run_cli as main

    code = ("import sys; from vladrivebench.testing import run_cli as main; "
            f"sys.exit(main(['run', '--model', 'scripted', '--model-opt', 'alpha=3', '--scenarios', 'E.1', "
            f"'--seeds', '1', '--out', {str(tmp_path / 'out')!r}]))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert main is not None
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines == [lines[0]] and lines[0].startswith("vdb: error: ")
    assert "alpha must be a number in [0, 1], got 3" in lines[0]
    assert "Traceback" not in result.stderr
