"""``vdb label``, ``vdb metrics``, ``vdb report`` and ``vdb labels agree``."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import click

from vladrivebench._cli.progress import Progress
from vladrivebench.errors import ConfigError, VdbError

DEFAULT_CHUNK = 64


def _labeler(name: str, options: dict[str, Any], backends: str | None) -> Any:
    from vladrivebench._engine.registry import get_registry

    if backends is not None:
        options["backends"] = backends
    labeler = get_registry().create("labeler", name, options)
    version = getattr(labeler, "version", None)
    if not isinstance(version, str) or not version:
        raise VdbError(f"labeler {name!r} has no version string; labels are keyed by it")
    check = getattr(labeler, "check", None)
    if callable(check):
        check()  # raises VdbError (missing keys, unreachable servers) before anything is spent
    return labeler


def _default_labeler() -> str:
    from vladrivebench._engine.registry import get_registry

    return get_registry().default("labeler", "--labeler").name


def _label_progress(total: int) -> Progress:
    return Progress("labelled", total, unit="CoTs", close=True, interval=1.0)


def label_in_chunks(labeler: Any, name: str, items: Sequence[Any], on_chunk: Any, chunk: int,
                    progress: Progress | None = None) -> int:
    """Label ``items`` with ``label_batch`` chunk by chunk, handing each chunk's labels to ``on_chunk``."""
    from vladrivebench.records import Labels

    done = 0
    for start in range(0, len(items), chunk):
        batch = list(items[start:start + chunk])
        results = list(labeler.label_batch(batch))
        if len(results) != len(batch) or not all(isinstance(r, Labels) for r in results):
            raise VdbError(f"labeler {name!r} returned {len(results)} results for {len(batch)} CoTs "
                           f"(label_batch must return one Labels per item, in order)")
        on_chunk(batch, results)
        done += len(batch)
        if progress:
            progress.advance(count=len(batch))
    return done


# -- vdb label --------------------------------------------------------------------------------------------
@click.command("label")
@click.argument("directory", required=False, type=click.Path(path_type=Path))
@click.option("--labeler", "labeler_name", default=None,
              help="Registered labeler (default: the one a labeler plugin declares, e.g. lexicon).")
@click.option("--labeler-opt", "labeler_opts", multiple=True, metavar="KEY=VALUE", help="Labeler option (repeatable).")
@click.option("--backends", default=None, help="Backends of an LLM labeler (passed as its option 'backends').")
@click.option("--dry-run", is_flag=True, help="Print how many calls labelling would make (labeler's plan()).")
@click.option("--texts", type=click.Path(path_type=Path), default=None,
              help="Label a JSONL file of CoTs instead of a directory of episode logs.")
@click.option("--out", type=click.Path(path_type=Path), default=None, help="Output JSONL (with --texts).")
@click.option("--chunk", type=click.IntRange(min=1), default=DEFAULT_CHUNK, show_default=True,
              help="CoTs per label_batch call (a kill loses at most one chunk).")
@click.option("--quiet", is_flag=True, help="No progress on stderr.")
def label_command(directory: Path | None, labeler_name: str | None, labeler_opts: tuple[str, ...], backends: str | None,
                  dry_run: bool, texts: Path | None, out: Path | None, chunk: int, quiet: bool) -> None:
    """Label the CoTs of every episode in DIRECTORY (or of a JSONL file with --texts … --out …).

    Labels are stored in DIRECTORY/labels/<labeler>.jsonl keyed by a hash of text + context + labeler
    version: only what is not stored yet is labelled, so relabelling costs nothing.
    """
    from vladrivebench._engine.options import parse_options

    if (directory is None) == (texts is None):
        raise ConfigError("vdb label: give either a DIRECTORY of episode logs or --texts FILE.jsonl --out FILE.jsonl")
    if texts is not None and out is None and not dry_run:
        raise ConfigError("vdb label --texts: --out FILE.jsonl is required (where the labelled CoTs go)")
    if texts is not None and out is not None:
        from vladrivebench._cli.paths import check_output_file

        check_output_file(out, "--out", inputs=[texts])
    if directory is not None and out is not None:
        raise ConfigError("vdb label: --out goes with --texts; labels of a directory are stored in DIRECTORY/labels/")
    options = parse_options(labeler_opts, "--labeler-opt")
    if texts is not None:
        from vladrivebench._analysis.labels import read_jsonl

        entries = read_jsonl(texts)  # read (and validate) the input before building a paid labeler
        labeler_name = labeler_name or _default_labeler()
        labeler = _labeler(labeler_name, options, backends)
        _label_texts(labeler, labeler_name, entries, out, dry_run, chunk, quiet)
    else:
        labeler_name = labeler_name or _default_labeler()
        labeler = _labeler(labeler_name, options, backends)
        _label_directory(labeler, labeler_name, directory, dry_run, chunk, quiet)


def _label_texts(labeler: Any, name: str, entries: list, out: Path | None, dry_run: bool, chunk: int,
                 quiet: bool) -> None:
    from vladrivebench._analysis.labels import write_jsonl

    if dry_run:
        _print_plan(labeler, name, [e.item for e in entries])
        return
    if out.parent and not out.parent.is_dir():
        raise ConfigError(f"--out {out}: the folder {out.parent} does not exist")
    results: list = []
    label_in_chunks(labeler, name, [e.item for e in entries], lambda _batch, labels: results.extend(labels),
                    chunk, None if quiet or not entries else _label_progress(len(entries)))
    write_jsonl(out, entries, results)
    unlabelled = sum(1 for r in results if r.unlabelled)
    click.echo(f"labelled {len(entries)} CoTs with {name} {labeler.version} → {out}"
               + (f" ({unlabelled} unlabelled, reasons in the file)" if unlabelled else ""))


def label_directory(labeler: Any, name: str, directory: Path, *, dry_run: bool = False, chunk: int = 500,
                    quiet: bool = False) -> None:
    """Label every observational step of the logs in ``directory`` not yet in its label store."""
    _label_directory(labeler, name, directory, dry_run, chunk, quiet)


def _label_directory(labeler: Any, name: str, directory: Path, dry_run: bool, chunk: int, quiet: bool) -> None:
    from vladrivebench._analysis.dataset import label_items, observational, read_directory
    from vladrivebench._analysis.labels import LabelStore, label_key
    from vladrivebench._analysis.tables import AnalysisDataset

    episodes, notes = read_directory(directory)
    for note in notes:
        click.echo(f"vdb: warning: {note}", err=True)
    own = observational(AnalysisDataset(directory=directory, episodes=episodes))
    if not own:
        raise ConfigError(f"{directory}: every episode is an intervention run (injected CoTs); nothing to label")
    store = LabelStore(directory, name)
    pending, seen, total, stored = [], set(), 0, 0
    for _episode, _step, item in label_items(own):
        total += 1
        key = label_key(item, name, labeler.version)
        if key in store:
            stored += 1
        elif key not in seen:
            seen.add(key)
            pending.append((item, key))
    if dry_run:
        _print_plan(labeler, name, [item for item, _ in pending], stored=stored)
        return

    key_of = {id(item): key for item, key in pending}

    def store_chunk(batch: list, results: list) -> None:
        store.add([(item, key_of[id(item)], labels) for item, labels in zip(batch, results, strict=True)],
                  labeler.version)

    done = label_in_chunks(labeler, name, [item for item, _ in pending], store_chunk, chunk,
                           None if quiet or not pending else _label_progress(len(pending)))
    repeats = total - stored - done
    click.echo(f"labelled {done} new CoTs for {total} steps ({stored} already stored"
               + (f", {repeats} repeat a CoT in an identical situation" if repeats else "")
               + f") with {name} {labeler.version} → {store.path}")


def _print_plan(labeler: Any, name: str, items: list, stored: int = 0) -> None:
    plan = getattr(labeler, "plan", None)
    if not callable(plan):
        raise ConfigError(f"labeler {name!r} has no plan(): --dry-run needs a labeler that can estimate its calls "
                          f"(it would label {len(items)} CoTs)")
    result = plan(items)
    click.echo(f"{len(items)} CoTs to label with {name} {labeler.version}" + (f" ({stored} already stored)"
                                                                              if stored else ""))
    for backend, numbers in dict(result).items():
        click.echo(f"  {backend}: {numbers.get('calls', 0)} calls, {numbers.get('cached', 0)} cached")


# -- vdb metrics / vdb report -------------------------------------------------------------------------------
def _dataset(directory: Path, labeler: str | None, strict: bool):
    from vladrivebench._analysis.dataset import load_dataset

    return load_dataset(directory, labeler=labeler, strict=strict)


@click.command("metrics")
@click.argument("directory", type=click.Path(path_type=Path))
@click.option("--labeler", default=None, help="Which label store to read (default: the only one present).")
@click.option("--json", "as_json", is_flag=True, help="Print tables, plot data and notes as JSON.")
@click.option("--strict", is_flag=True, help="Fail on any unreadable log or failing metric instead of noting it.")
def metrics_command(directory: Path, labeler: str | None, as_json: bool, strict: bool) -> None:
    """Compute every registered metric on the episode logs in DIRECTORY and print the tables."""
    from vladrivebench._analysis.report import compute_all, dumps, render_text, to_json
    from vladrivebench._engine.registry import get_registry

    dataset = _dataset(directory, labeler, strict)
    sections = compute_all(dataset, get_registry(), strict=strict)
    click.echo(dumps(to_json(dataset, sections)) if as_json else render_text(dataset, sections), nl=not as_json)
    if as_json:
        click.echo("")


@click.command("report")
@click.argument("directory", type=click.Path(path_type=Path))
@click.option("--format", "fmt", type=click.Choice(["md", "latex", "html"]), default="html", show_default=True)
@click.option("--out", type=click.Path(path_type=Path), required=True, help="The report file to write.")
@click.option("--labeler", default=None, help="Which label store to read (default: the only one present).")
@click.option("--strict", is_flag=True, help="Fail on any unreadable log or failing metric instead of noting it.")
def report_command(directory: Path, fmt: str, out: Path, labeler: str | None, strict: bool) -> None:
    """Write a report (the paper's tables side by side per model, and plots) of the logs in DIRECTORY."""
    from vladrivebench._analysis.report import compute_all, write_report
    from vladrivebench._cli.paths import check_output_file
    from vladrivebench._engine.registry import get_registry

    check_output_file(out, "--out", runs=[directory])
    dataset = _dataset(directory, labeler, strict)
    sections = compute_all(dataset, get_registry(), strict=strict)
    written = write_report(dataset, sections, fmt, out)
    tables = sum(len(s.tables) for s in sections)
    plots = sum(len(s.plots) for s in sections)
    click.echo(f"wrote {written[0]} ({tables} tables, {plots} plots"
               + (f", {len(written) - 1} PNG files beside it" if len(written) > 1 else "") + ")")
    for note in dataset.notes:
        click.echo(f"vdb: note: {note}", err=True)


# -- vdb labels agree -------------------------------------------------------------------------------------------
@click.group("labels")
def labels_group() -> None:
    """Work with label files (JSONL): agreement between two label sources."""


@labels_group.command("agree")
@click.argument("first", type=click.Path(path_type=Path))
@click.argument("second", type=click.Path(path_type=Path))
@click.option("--by", "by", metavar="FIELD", default=None,
              help="Also report κ per group of items with the same value of FIELD (a top-level field of the "
                   "JSONL items, e.g. style or source).")
@click.option("--json", "as_json", is_flag=True, help="Print the agreement as JSON.")
def agree_command(first: Path, second: Path, by: str | None, as_json: bool) -> None:
    """Cohen's κ per property between two label sources (e.g. a labeler against a gold file).

    Each is a JSONL label file (items matched by "id"; every line needs a "labels" object) or a run's
    label store DIR/labels/NAME.jsonl (items matched by CoT + context), so two labelers of one run compare.
    A property an item's "labels" object leaves out is missing: counted and reported, never read as
    none/false.
    """
    from vladrivebench._analysis.labels import agreement_by, load_label_source, source_agreement
    from vladrivebench._analysis.report import dumps

    if by is not None and not by.strip():
        raise ConfigError("--by: expected the name of a field of the JSONL items (e.g. style), got an empty string")
    a, b = load_label_source(first), load_label_source(second)
    report = source_agreement(a, b)
    if report.compared == 0:
        raise ConfigError(f"{first} and {second} have no labelled item in common (items are matched by \"id\")")
    if all(p.n == 0 for p in report.properties):
        side = first if all(p.missing_a for p in report.properties) else second
        raise ConfigError(f"{side}: no compared item states any label (every \"labels\" object lacks "
                          f"stated_action, target_mentioned, …); nothing to compare")
    groups = agreement_by(a, b, by) if by is not None else {}
    if as_json:
        data = report.to_json()
        if by is not None:
            data["by"] = by
            data["groups"] = {name: group.to_json() for name, group in groups.items()}
        click.echo(dumps(data))
        return
    _print_agreement(report, first, second)
    if by is not None:
        _print_groups(groups, by)


def _print_agreement(report: Any, first: Path, second: Path) -> None:
    click.echo(f"{report.compared} items compared ({first.name} vs {second.name})")
    for label, ids in (("only in " + first.name, report.only_in_a), ("only in " + second.name, report.only_in_b),
                       ("unlabelled in either", report.unlabelled)):
        if ids:
            click.echo(f"  {len(ids)} {label}: {', '.join(ids[:5])}{' …' if len(ids) > 5 else ''}")
    for prop in report.properties:
        kappa = "—" if prop.kappa is None else f"{prop.kappa:.3f}"
        agree = "—" if prop.agreement is None else f"{100 * prop.agreement:.1f}%"
        click.echo(f"\n{prop.prop}: κ = {kappa}, agreement {agree}, n = {prop.n}" + (f" ({prop.note})" if prop.note else ""))
        if prop.categories:
            width = max(len(c) for c in prop.categories + ("A \\ B",)) + 1
            click.echo("  " + "A \\ B".ljust(width) + "".join(c.rjust(width) for c in prop.categories))
            for cat, row in zip(prop.categories, prop.confusion, strict=True):
                click.echo("  " + cat.ljust(width) + "".join(str(v).rjust(width) for v in row))


def _print_groups(groups: dict[str, Any], by: str) -> None:
    """One line per group: κ (agreement, n) per property; missing labels counted per group."""
    click.echo(f"\nby {by}: κ (agreement, n) per property")
    for name, group in groups.items():
        cells = []
        for prop in group.properties:
            kappa = "—" if prop.kappa is None else f"{prop.kappa:.2f}"
            agree = "—" if prop.agreement is None else f"{100 * prop.agreement:.0f}%"
            missing = prop.missing_a + prop.missing_b
            cells.append(f"{prop.prop} {kappa} ({agree}, {prop.n}{f', {missing} missing' if missing else ''})")
        click.echo(f"  {name} [{group.compared}]: " + "; ".join(cells))


COMMANDS = [label_command, metrics_command, report_command, labels_group]
