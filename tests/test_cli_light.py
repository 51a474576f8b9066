"""`vdb --help` and `vdb list-plugins` load every installed plugin yet import nothing heavy."""

from __future__ import annotations

import subprocess
import sys

import pytest

HEAVY = ("torch", "transformers", "libsumo", "ray", "numpy", "scipy", "statsmodels", "matplotlib", "mcap")

PROBE = """
import sys
from vladrivebench._cli.main import main
code = main({args!r})
heavy = sorted(m for m in {heavy!r} if m in sys.modules)
print("HEAVY=" + ",".join(heavy), file=sys.stderr)
sys.exit(code)
"""


@pytest.mark.parametrize("args", [["--help"], ["list-plugins"], ["list-plugins", "--json"]])
def test_command_imports_no_heavy_module(args):
    result = subprocess.run([sys.executable, "-c", PROBE.format(args=args, heavy=HEAVY)],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "HEAVY=\n" in result.stderr or result.stderr.rstrip().endswith("HEAVY="), result.stderr


def test_bad_command_is_one_line_exit_2():
    result = subprocess.run([sys.executable, "-m", "vladrivebench._cli.main", "no-such-command"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().count("\n") == 0 and "No such command" in result.stderr


def test_intervene_default_seeds_is_the_protocols():
    from vladrivebench._cli.intervene import COMMANDS
    from vladrivebench._intervention.runs import DEFAULT_SEEDS

    (intervene,) = [c for c in COMMANDS if c.name == "intervene"]
    (seeds,) = [p for p in intervene.params if p.name == "seeds"]
    assert seeds.default == DEFAULT_SEEDS


def test_a_command_exit_code_reaches_the_shell():
    import click
    from vladrivebench._cli import main as cli

    @click.command("exit-seven")
    @click.pass_context
    def exit_seven(ctx):
        ctx.exit(7)

    cli.cli.add_command(exit_seven)
    try:
        assert cli.main(["exit-seven"]) == 7
    finally:
        cli.cli.commands.pop("exit-seven")
