"""Loading a directory of episode logs and their labels into the dataset every metric receives.

Bad logs never produce a silently wrong table: a truncated log contributes its complete steps and a note
saying so; a corrupt or incompatible one is left out with a note naming the file and the reason (or, with
``strict=True``, stops everything with that one line); steps without labels are counted and reported.
"""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vladrivebench._analysis.alignment import (
    action_head_set,
    cot_action_set,
    relaxed_aligned,
    strict_aligned,
    time_to_collision,
)
from vladrivebench._analysis.labels import (
    LabelStore,
    content_key,
    context_from_step,
    label_input,
    stored_labelers,
)
from vladrivebench._analysis.tables import AnalysisDataset, episode_key
from vladrivebench.errors import ConfigError, LogError
from vladrivebench.records import LabelInput, Labels

ZONES = ("far", "med", "near", "past")
"""Distance zones along the route to the critical feature: far > 20 m, med 10–20 m, near < 10 m, past < 0."""


def distance_zone(distance: float | None) -> str | None:
    """The paper's zone of a distance to the critical feature (``None`` when there is no feature)."""
    if distance is None or not math.isfinite(distance):
        return None
    if distance < 0.0:
        return "past"
    if distance < 10.0:
        return "near"
    if distance <= 20.0:
        return "med"
    return "far"


# -- per-step view --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StepView:
    """What the quality and alignment metrics read of one logged step."""

    step: int
    distance: float | None
    zone: str | None
    speed: float
    v_des: float | None
    travelled: float
    ttc: float
    critical_kind: str | None
    light_state: str | None
    labels: Labels | None

    def cot_set(self) -> tuple[str, ...] | None:
        """The CoT's action set (Appendix B), ``None`` without labels or a stated action."""
        if self.labels is None:
            return None
        return cot_action_set(self.labels.stated_action, self.speed, self.ttc)

    def head_set(self) -> tuple[str, ...] | None:
        return None if self.v_des is None else action_head_set(self.speed, self.v_des)

    def aligned(self, strict: bool = False) -> bool | None:
        """Relaxed (or strict) alignment of this step, ``None`` when it is not scored."""
        cot, head = self.cot_set(), self.head_set()
        if cot is None or head is None:
            return None
        return strict_aligned(cot, head) if strict else relaxed_aligned(cot, head)


def step_views(dataset: AnalysisDataset, episode: Any) -> list[StepView]:
    """The steps of ``episode`` as :class:`StepView` (cached on the dataset)."""
    cache = dataset.extra.setdefault("step_views", {})
    key = episode_key(episode)
    if key not in cache:
        cache[key] = _build_views(dataset, episode)
    return cache[key]


def _build_views(dataset: AnalysisDataset, episode: Any) -> list[StepView]:
    views, travelled, previous = [], 0.0, None
    for record in episode.steps:
        ego, truth = record.ego, record.ground_truth
        x, y, speed = float(ego.x), float(ego.y), float(ego.speed)
        if previous is not None:
            travelled += math.hypot(x - previous[0], y - previous[1])
        previous = (x, y)
        distance = truth.distance_to_critical
        v_des = record.control.v_des
        views.append(StepView(
            step=record.step,
            distance=None if distance is None else float(distance),
            zone=distance_zone(None if distance is None else float(distance)),
            speed=speed,
            v_des=None if v_des is None else float(v_des),
            travelled=travelled,
            ttc=time_to_collision(truth.lead_gap, speed, truth.lead_speed),
            critical_kind=truth.critical_kind,
            light_state=truth.light_state,
            labels=dataset.labels_for(episode, record.step),
        ))
    return views


# -- episode identity -------------------------------------------------------------------------------------
def scenario_group(episode: Any) -> str:
    """The paper's table row of an episode's scenario (``group``), else its family or id."""
    scenario = episode.meta.get("scenario") or {}
    return str(scenario.get("group") or scenario.get("family") or scenario.get("id") or "?")


def is_intervention(episode: Any) -> bool:
    """Episodes written by ``vdb intervene`` (their CoT may be injected): not observational data."""
    return bool(episode.meta.get("intervention"))


def observational(dataset: AnalysisDataset) -> list[Any]:
    """The episodes the quality and alignment metrics read: the models' own runs."""
    return [e for e in dataset.episodes if not is_intervention(e)]


def model_labels(episodes: Sequence[Any]) -> dict[str, str]:
    """A display name per episode (by :func:`episode_key`): the model name plus the options that differ between its runs."""
    options_by_name: dict[str, list[dict]] = {}
    for episode in episodes:
        model = episode.meta.get("model") or {}
        options_by_name.setdefault(str(model.get("name", "?")), []).append(dict(model.get("options") or {}))
    varying = {name: sorted({k for opts in all_opts for k in opts
                             if any(o.get(k) != opts.get(k) for o in all_opts)})
               for name, all_opts in options_by_name.items()}
    labels = {}
    for episode in episodes:
        model = episode.meta.get("model") or {}
        name = str(model.get("name", "?"))
        options = model.get("options") or {}
        shown = ", ".join(f"{k}={options.get(k)}" for k in varying[name])
        labels[episode_key(episode)] = f"{name} ({shown})" if shown else name
    return labels


def ordered_models(dataset: AnalysisDataset, episodes: Iterable[Any]) -> list[str]:
    """Model display names in order of first appearance (episodes are sorted by path)."""
    labels = dataset.extra.get("model_labels") or model_labels(dataset.episodes)
    return list(dict.fromkeys(labels[episode_key(e)] for e in episodes))


def model_of(dataset: AnalysisDataset, episode: Any) -> str:
    """The model's label in tables: its name, with its options when several configurations share it."""
    labels = dataset.extra.setdefault("model_labels", model_labels(dataset.episodes))
    return labels[episode_key(episode)]


# -- loading --------------------------------------------------------------------------------------------
def read_directory(directory: Path | str, *, strict: bool = False) -> tuple[list[Any], list[str]]:
    """Every readable episode under ``directory`` and notes on those that are not (fully) readable."""
    from vladrivebench._logs.episodes import find_episodes, read_episode

    episodes, notes = [], []
    paths = find_episodes(directory)
    notes += [f"left out {_relative(p, directory)}: a link to {os.readlink(p)}, which does not exist"
              for p in sorted(Path(directory).rglob("*.mcap")) if p.is_symlink() and not p.exists()]
    for path in paths:
        try:
            episodes.append(read_episode(path))
            continue
        except LogError as exc:
            if strict:
                raise
            first_error = str(exc)
        try:
            recovered = read_episode(path, recover=True)
        except LogError:
            notes.append(f"left out {_relative(path, directory)}: {first_error.split(': ', 1)[-1]}")
            continue
        episodes.append(recovered)
        notes.append(f"{_relative(path, directory)} is truncated: its {len(recovered.steps)} complete steps are "
                     f"used, the rest of the episode and its result are missing")
    if not episodes:
        raise LogError(f"episode directory {directory}: none of the {len(paths)} episode logs is readable "
                       f"({notes[0] if notes else 'no logs'})")
    return episodes, notes


def _relative(path: Path, directory: Path | str) -> str:
    try:
        return str(Path(path).relative_to(directory))
    except ValueError:
        return str(path)


def choose_labeler(directory: Path | str, labeler: str | None) -> str | None:
    """The label store to read: the one asked for, else the only one present (``None`` if none)."""
    present = stored_labelers(directory)
    if labeler is not None:
        return labeler
    if not present:
        return None
    if len(present) == 1:
        return present[0]
    raise ConfigError(f"{directory} holds labels of several labelers ({', '.join(present)}): "
                      f"choose one with --labeler NAME")


def label_items(episodes: Iterable[Any]) -> list[tuple[Any, int, LabelInput]]:
    """``(episode, step, LabelInput)`` for every step of the observational episodes given."""
    items = []
    for episode in episodes:
        for record in episode.steps:
            context = context_from_step(record.ego, record.ground_truth)
            items.append((episode, record.step, label_input(record.cot, context)))
    return items


def load_dataset(directory: Path | str, *, labeler: str | None = None, strict: bool = False) -> AnalysisDataset:
    """Episodes of ``directory`` (recursively) with the labels of ``labeler`` (default: the only store)."""
    directory = Path(directory)
    episodes, notes = read_directory(directory, strict=strict)
    dataset = AnalysisDataset(directory=directory, episodes=episodes, notes=list(notes))
    dataset.extra["model_labels"] = model_labels(episodes)
    name = choose_labeler(directory, labeler)
    own = observational(dataset)
    if name is None:
        if own:
            dataset.note(f"no labels: the quality and alignment tables need them; run `vdb label {directory}`")
        return dataset
    attach_labels(dataset, LabelStore(directory, name), own)
    return dataset


def attach_labels(dataset: AnalysisDataset, store: LabelStore, episodes: Sequence[Any]) -> None:
    """Look up every step's labels in ``store`` by content and note what is missing or unlabelled."""
    dataset.labeler = store.labeler
    missing: Counter = Counter()
    reasons: Counter = Counter()
    versions: Counter = Counter()
    total = 0
    for episode, step, item in label_items(episodes):
        total += 1
        found = store.latest(content_key(item))
        if found is None:
            missing[_relative(episode.path, dataset.directory)] += 1
            continue
        versions[found.version] += 1
        dataset.labels[(episode_key(episode), step)] = found.labels
        if found.labels.unlabelled:
            reasons[found.labels.unlabelled] += 1
    labelled = total - sum(missing.values()) - sum(reasons.values())
    version_text = ", ".join(f"{v} ×{n}" for v, n in sorted(versions.items())) or "-"
    dataset.extra["label_summary"] = {"labeler": store.labeler, "steps": total, "labelled": labelled,
                                      "missing": sum(missing.values()), "unlabelled": sum(reasons.values()),
                                      "versions": dict(versions)}
    if missing:
        worst = ", ".join(f"{eid} ({n})" for eid, n in missing.most_common(3))
        dataset.note(f"{sum(missing.values())} of {total} steps have no {store.labeler} labels (in {len(missing)} "
                     f"episodes, e.g. {worst}); they are left out of every labelled table — run "
                     f"`vdb label {dataset.directory} --labeler {store.labeler}`")
    if reasons:
        listed = "; ".join(f"{n}× {r}" for r, n in reasons.most_common(3))
        dataset.note(f"{sum(reasons.values())} steps are unlabelled by {store.labeler} and left out: {listed}")
    if len(versions) > 1:
        dataset.note(f"labels come from several {store.labeler} versions ({version_text}): relabel for one")
    if store.skipped_lines:
        dataset.note(f"{store.skipped_lines} damaged lines in {store.path} were ignored (those steps are "
                     f"relabelled by the next `vdb label`)")
