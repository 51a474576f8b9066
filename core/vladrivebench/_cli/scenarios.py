"""``vdb scenarios``: list (and validate) the registered scenarios, or show one in full."""

from __future__ import annotations

import json

import click


@click.command("scenarios")
@click.argument("spec", required=False, default="all")
@click.option("--json", "as_json", is_flag=True, help="Print the listing as JSON.")
@click.option("--show", is_flag=True, help="Print the full specification of each selected scenario (JSON).")
def scenarios_command(spec: str, as_json: bool, show: bool) -> None:
    """List scenarios: id, title, family, group, layout and source file.

    SPEC selects them like `vdb run --scenarios`: 'all' (default), ids (P.1,C.1), a family (pedestrian),
    a glob (TL.*) or scenario files (my_pack/x.toml), which are validated on the way.
    """
    from vladrivebench._scenarios.spec import resolve_scenarios, scenario_summary

    selected = resolve_scenarios(spec)
    if show:
        click.echo(json.dumps([s.to_json() for s in selected], indent=2))
        return
    rows = [scenario_summary(s) for s in selected]
    if as_json:
        click.echo(json.dumps(rows, indent=2))
        return
    columns = ("id", "family", "group", "layout", "command", "title", "source")
    table = [[_cell(row, col) for col in columns] for row in rows]
    widths = [max(len(col), *(len(r[i]) for r in table)) if table else len(col) for i, col in enumerate(columns)]
    click.echo("  ".join(col.ljust(w) for col, w in zip(columns, widths, strict=True)).rstrip())
    for r in table:
        click.echo("  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip())
    click.echo(f"{len(rows)} scenario{'s' if len(rows) != 1 else ''}", err=True)


def _cell(row: dict, column: str) -> str:
    value = row.get(column)
    if column == "source" and value:
        parts = value.replace("\\", "/").split("/")
        return "/".join(parts[-2:])
    return "-" if value is None else str(value)


COMMANDS = [scenarios_command]
