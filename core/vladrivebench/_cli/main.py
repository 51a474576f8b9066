"""The ``vdb`` command-line tool.

User errors print one line ``vdb: error: …`` on stderr and exit with status 2, never a traceback.
Results go to stdout, progress to stderr. Commands live in small modules (``cmd_*.py``) that import
their heavier dependencies inside the command functions, so ``vdb --help`` stays light.
"""

from __future__ import annotations

import importlib
import json
import sys
import warnings

import click

from vladrivebench import __version__
from vladrivebench._engine.registry import get_registry
from vladrivebench.errors import VdbError

# Modules whose module-level ``COMMANDS`` list is added to the group, in this order.
COMMAND_MODULES = [
    "vladrivebench._cli.analysis",
    "vladrivebench._cli.intervene",
    "vladrivebench._cli.run",
    "vladrivebench._cli.scenarios",
]


class VdbGroup(click.Group):
    """Loads plugin-contributed commands the first time the command list is needed."""

    _plugins_added = False

    def _add_plugin_commands(self, ctx: click.Context) -> None:
        if not self._plugins_added:
            self._plugins_added = True
            get_registry(strict=_strict(ctx)).call_hook("register_commands", cli=self)

    def list_commands(self, ctx: click.Context) -> list[str]:
        self._add_plugin_commands(ctx)
        return super().list_commands(ctx)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        command = super().get_command(ctx, cmd_name)
        if command is None:
            self._add_plugin_commands(ctx)
            command = super().get_command(ctx, cmd_name)
        return command


def _strict(ctx: click.Context | None) -> bool | None:
    root = ctx.find_root() if ctx else None
    return bool(root.params.get("strict_plugins")) or None if root else None


@click.group(cls=VdbGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="vdb")
@click.option("--strict-plugins", is_flag=True, help="Fail if any plugin fails to load (default: report and go on).")
@click.pass_context
def cli(ctx: click.Context, strict_plugins: bool) -> None:
    """VLADriveBench: is a driving VLA's chain-of-thought about the world, and connected to its action?"""
    get_registry(strict=strict_plugins or None)
    if strict_plugins:  # every plugin hook runs now, so that any failing one stops the command
        ctx.command._add_plugin_commands(ctx)


@cli.command("list-plugins")
@click.option("--json", "as_json", is_flag=True, help="Print the listing as JSON.")
def list_plugins(as_json: bool) -> None:
    """List every plugin: name, kind, distribution, version, status and what it registered."""
    from vladrivebench._scenarios.spec import check_scenario_packs

    registry = get_registry()
    click.get_current_context().find_root().command._add_plugin_commands(None)  # failures show below
    check_scenario_packs(registry)
    if as_json:
        click.echo(json.dumps([p.to_json() for p in registry.plugins], indent=2))
        return
    for info in registry.plugins:
        kinds = ", ".join(sorted(info.registered)) or "-"
        click.echo(f"{info.name}  [{info.status}]  kinds: {kinds}  ({info.distribution} {info.version})")
        if info.error:
            click.echo(f"    error: {info.error}")
        for kind in sorted(info.registered):
            names = info.registered[kind]
            if kind == "scenario":
                names = [_describe_scenario_source(n) for n in names]
            click.echo(f"    {kind}: {', '.join(names)}")


def _describe_scenario_source(path: str) -> str:
    """``…/scenarios (24 files)`` for a pack directory, the file's name for a single file."""
    from pathlib import Path

    source = Path(path)
    if source.is_dir():
        count = sum(1 for p in source.iterdir() if p.suffix.lower() in {".toml", ".json"})
        return f"{source} ({count} files)"
    return str(source)


def _add_command_modules() -> None:
    for module_name in COMMAND_MODULES:
        module = importlib.import_module(module_name)
        for command in module.COMMANDS:
            cli.add_command(command)


_add_command_modules()


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script: one-line errors, exit status 2 for user errors.

    Third-party warnings (transformers, statsmodels, …) are not printed unless Python was asked to show
    them (``python -W …`` or ``PYTHONWARNINGS``), so a refused command prints its one line and nothing else.
    """
    with warnings.catch_warnings():
        if not sys.warnoptions:
            warnings.simplefilter("ignore")
        return _main(argv)


def _main(argv: list[str] | None) -> int:
    try:
        outcome = cli.main(args=argv, prog_name="vdb", standalone_mode=False)
    except VdbError as exc:
        _error(str(exc))
        return exc.exit_code
    except click.UsageError as exc:
        if type(exc).__name__.startswith("NoArgsIsHelp"):  # bare `vdb`: show the help
            click.echo(exc.ctx.get_help() if exc.ctx else "", err=True)
            return 2
        where = f"{exc.ctx.command_path}: " if exc.ctx else ""
        _error(f"{where}{exc.format_message()}")
        return 2
    except click.ClickException as exc:
        _error(exc.format_message())
        return exc.exit_code
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except (click.Abort, KeyboardInterrupt):
        _error("interrupted")
        return 130
    except BrokenPipeError:
        return 0
    except OSError as exc:  # a path the command could not read or write: name it, no traceback
        _error(_describe_os_error(exc))
        return 2
    except MemoryError:
        _error("out of memory: the request is too large for this machine (fewer seeds, scenarios or workers)")
        return 2
    # without standalone mode, click returns the code of a `ctx.exit(n)` (or the command's return value)
    return outcome if isinstance(outcome, int) else 0


def _describe_os_error(exc: OSError) -> str:
    where = " → ".join(str(name) for name in (exc.filename, exc.filename2) if name)
    reason = exc.strerror or str(exc) or type(exc).__name__
    return f"{where}: {reason}" if where else reason


def _error(message: str) -> None:
    first = " ".join(message.strip().split("\n")[0].split())
    click.echo(f"vdb: error: {first}", err=True)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
