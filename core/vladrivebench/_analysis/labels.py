"""Labels of CoTs: the ground-truth context a labeler sees, the label store beside the logs, JSONL in/out,
and agreement (Cohen's κ) between two label sources.

The store is one append-only JSONL file per labeler, ``DIR/labels/<labeler>.jsonl``. Every line holds the
labels of one CoT under the key ``sha256(text + slots + canonical context + labeler name + version)`` and
the version-free ``content`` hash, so labelling the same CoT in the same situation again costs nothing,
and a new labeler version relabels exactly what it must. A kill while writing loses at most the chunk
being written; a torn last line is dropped on the next write.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from vladrivebench.errors import ConfigError, LogError
from vladrivebench.records import (
    LIGHT_COLOURS,
    STATED_ACTIONS,
    CoT,
    EgoState,
    GroundTruth,
    LabelInput,
    Labels,
)

LABELS_DIRNAME = "labels"
PROPERTIES = ("stated_action", "target_mentioned", "mention_slot", "light_colour", "hallucination",
              "contradiction")
"""The labelled properties, in the order agreement reports list them."""

_DECIMALS = 2  # positions and speeds in a context are rounded to 1 cm (cm/s) so hashes are stable


# -- context -------------------------------------------------------------------------------------------
def context_from_step(ego: EgoState | Mapping[str, Any],
                      ground_truth: GroundTruth | Mapping[str, Any]) -> dict[str, Any]:
    """The labeler's view of one step: the critical feature, every actor in the ego frame, the light.

    ``ego`` and ``ground_truth`` are the step's records (``StepRecord.ego`` / ``StepRecord.ground_truth``);
    their logged JSON form (dicts) is accepted too. An ego without a pose raises :class:`LogError`.
    """
    ego, ground_truth = _as_records(ego, ground_truth)
    x, y, yaw, speed = float(ego.x), float(ego.y), float(ego.yaw), float(ego.speed)
    cos, sin = math.cos(yaw), math.sin(yaw)
    actors = []
    critical_position = critical_speed = None
    critical_id = ground_truth.critical_id
    for actor in ground_truth.actors:
        dx, dy = float(actor.x) - x, float(actor.y) - y
        position = [_round(cos * dx + sin * dy), _round(-sin * dx + cos * dy)]
        entry = {"id": actor.actor_id, "kind": actor.kind, "position": position,
                 "speed": _round(float(actor.speed or 0.0)), "state": actor.state}
        actors.append(entry)
        if critical_id is not None and actor.actor_id == critical_id:
            critical_position, critical_speed = position, entry["speed"]
    return {
        "critical_kind": ground_truth.critical_kind,
        "critical_position": critical_position,
        "critical_speed": critical_speed,
        "distance_to_critical": _round_or_none(ground_truth.distance_to_critical),
        "blocking": bool(ground_truth.blocking),
        "light_state": ground_truth.light_state,
        "actors": actors,
        "ego_speed": _round(speed),
        "lead_gap": _round_or_none(ground_truth.lead_gap),
        "lead_speed": _round_or_none(ground_truth.lead_speed),
    }


def _as_records(ego: Any, ground_truth: Any) -> tuple[EgoState, GroundTruth]:
    from vladrivebench._logs.decode import ego_from_json, ground_truth_from_json

    # Dicts are read as before records: a missing speed is 0, a missing step and time do not matter here.
    try:
        if not isinstance(ego, EgoState):
            ego = ego_from_json({"speed": 0.0, **ego} if isinstance(ego, Mapping) else ego)
    except ValueError as exc:
        raise LogError(f"ego state without a usable pose ({exc}); expected x, y, yaw, speed") from None
    try:
        if not isinstance(ground_truth, GroundTruth):
            ground_truth = ground_truth_from_json({"step": 0, "time": 0.0, **ground_truth}
                                                  if isinstance(ground_truth, Mapping) else ground_truth)
    except ValueError as exc:
        raise LogError(f"unusable ground truth ({exc}); expected the fields of GroundTruth") from None
    return ego, ground_truth


def label_input(cot: CoT | Mapping[str, Any], context: Mapping[str, Any], key: str = "") -> LabelInput:
    """A :class:`LabelInput` from a step's :class:`CoT` (or its logged ``/cot`` dict) and a context."""
    if not isinstance(cot, CoT):
        from vladrivebench._logs.decode import cot_from_json

        try:
            cot = cot_from_json(cot)
        except ValueError as exc:
            raise LogError(f"unusable CoT ({exc}); expected text and slots") from None
    return LabelInput(text=cot.text, slots=dict(cot.slots), context=dict(context), key=key)


def _round(value: float) -> float:
    return round(float(value), _DECIMALS) + 0.0  # + 0.0 turns -0.0 into 0.0


def _round_or_none(value: Any) -> float | None:
    return None if value is None else _round(value)


# -- keys -----------------------------------------------------------------------------------------------
def canonical_json(obj: Any) -> str:
    """One canonical serialisation (sorted keys, no spaces, UTF-8) for hashing."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False)


def content_key(item: LabelInput) -> str:
    """sha256 of the CoT text, its slots and the canonical context: what a label depends on."""
    payload = canonical_json({"text": item.text, "slots": item.slots, "context": item.context})
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()


def label_key(item: LabelInput, labeler: str, version: str) -> str:
    """The store key: sha256 of text + slots + canonical context + labeler name + labeler version."""
    payload = canonical_json({"text": item.text, "slots": item.slots, "context": item.context,
                              "labeler": labeler, "version": version})
    return hashlib.sha256(payload.encode("utf-8")).hexdigest()


# -- labels <-> json ------------------------------------------------------------------------------------
_LABEL_FIELDS = {f.name for f in fields(Labels)}


def labels_from_json(data: Mapping[str, Any], where: str = "labels") -> Labels:
    """Labels from their JSON form, checking every value (one-line :class:`ConfigError` naming ``where``)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected an object of labels, got {type(data).__name__}")
    unknown = sorted(set(data) - _LABEL_FIELDS)
    if unknown:
        raise ConfigError(f"{where}: unknown label field {unknown[0]!r} (known: {', '.join(sorted(_LABEL_FIELDS))})")
    values = dict(data)
    action = values.get("stated_action", "none")
    if action not in STATED_ACTIONS:
        raise ConfigError(f"{where}: stated_action {action!r} is not one of {', '.join(STATED_ACTIONS)}")
    colour = values.get("light_colour")
    if colour is not None and colour not in LIGHT_COLOURS:
        raise ConfigError(f"{where}: light_colour {colour!r} is not one of {', '.join(LIGHT_COLOURS)} or null")
    for name in ("hallucination", "contradiction"):
        if not isinstance(values.get(name, False), bool):
            raise ConfigError(f"{where}: {name} must be true or false, got {values[name]!r}")
    if values.get("target_mentioned") not in (None, True, False):
        raise ConfigError(f"{where}: target_mentioned must be true, false or null")
    for name in ("mention_slot", "unlabelled"):
        if values.get(name) is not None and not isinstance(values[name], str):
            raise ConfigError(f"{where}: {name} must be a string or null")
    if not isinstance(values.get("details", {}), dict):
        raise ConfigError(f"{where}: details must be an object")
    return Labels(**values)


# -- the store beside the logs --------------------------------------------------------------------------
@dataclass(frozen=True)
class StoredLabel:
    """One line of a label store."""

    key: str
    content: str
    labeler: str
    version: str
    labels: Labels


class LabelStore:
    """Append-only labels of one labeler for one directory of episode logs (``DIR/labels/NAME.jsonl``)."""

    def __init__(self, directory: Path | str, labeler: str):
        self.directory = Path(directory)
        self.labeler = labeler
        self.path = self.directory / LABELS_DIRNAME / f"{labeler}.jsonl"
        self.by_key: dict[str, StoredLabel] = {}
        self.by_content: dict[str, StoredLabel] = {}
        self.skipped_lines = 0
        self._load()

    def _load(self) -> None:
        if not self.path.exists():
            return
        try:
            raw = self.path.read_bytes()
        except OSError as exc:
            raise LogError(f"label store {self.path}: cannot read ({exc.strerror})") from None
        for number, line in enumerate(raw.split(b"\n"), start=1):
            if not line.strip():
                continue
            try:
                entry = json.loads(line)
                stored = StoredLabel(entry["key"], entry["content"], entry["labeler"], entry["version"],
                                     labels_from_json(entry["labels"], f"{self.path}:{number}"))
            except (ValueError, KeyError, TypeError, ConfigError):
                self.skipped_lines += 1  # a torn line from a killed writer: relabelled on the next run
                continue
            self.by_key[stored.key] = stored
            self.by_content[stored.content] = stored  # the latest write of a content wins

    def __contains__(self, key: str) -> bool:
        return key in self.by_key

    def __len__(self) -> int:
        return len(self.by_key)

    def get(self, key: str) -> Labels | None:
        found = self.by_key.get(key)
        return found.labels if found else None

    def latest(self, content: str) -> StoredLabel | None:
        """The most recently stored labels of a CoT content, whatever the labeler version."""
        return self.by_content.get(content)

    def add(self, entries: Sequence[tuple[LabelInput, str, Labels]], version: str) -> None:
        """Append ``(item, key, labels)`` entries, flushed and fsynced before returning."""
        if not entries:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._drop_torn_tail()
        lines = []
        for item, key, labels in entries:
            stored = StoredLabel(key, content_key(item), self.labeler, version, labels)
            lines.append(json.dumps({"key": key, "content": stored.content, "labeler": self.labeler,
                                     "version": version, "labels": labels.to_json()}, ensure_ascii=False))
            self.by_key[key] = stored
            self.by_content[stored.content] = stored
        with self.path.open("a", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n")
            fh.flush()
            os.fsync(fh.fileno())

    def _drop_torn_tail(self) -> None:
        if not self.path.exists() or self.path.stat().st_size == 0:
            return
        with self.path.open("rb+") as fh:
            fh.seek(-1, os.SEEK_END)
            if fh.read(1) == b"\n":
                return
            fh.seek(0)
            data = fh.read()
            fh.truncate(data.rfind(b"\n") + 1)


def stored_labelers(directory: Path | str) -> list[str]:
    """The labelers that have a store in ``directory`` (sorted)."""
    folder = Path(directory) / LABELS_DIRNAME
    return sorted(p.stem for p in folder.glob("*.jsonl")) if folder.is_dir() else []


# -- standalone JSONL -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class JsonlItem:
    """One line of a standalone JSONL file: an id, the CoT to label, and labels when the line has them."""

    id: str
    item: LabelInput
    labels: Labels | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    stated: tuple[str, ...] = ()  # the properties the line's "labels" object names (others are missing)


_CONTEXT_KINDS = {"critical_kind": (str, type(None)), "light_state": (str, type(None)),
                  "actors": (list,), "ego_speed": (int, float), "critical_position": (list, type(None))}


def read_jsonl(path: Path | str, *, need_labels: bool = False) -> list[JsonlItem]:
    """Read a JSONL file of CoTs (see the field documentation in the labeler guide).

    Each line: ``id`` (string or number, required), ``text`` (string) and/or ``slots``
    (object slot → string; when ``text`` is missing it is the slots joined in order), ``context`` (object:
    ``critical_kind``, ``critical_position``, ``light_state``, ``actors``, ``ego_speed``, …) and optionally
    ``labels``. Every problem is one :class:`ConfigError` naming the file and line.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read ({exc})") from None
    items, seen = [], set()
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        where = f"{path}:{number}"
        try:
            data = json.loads(line)
        except ValueError as exc:
            raise ConfigError(f"{where}: not valid JSON ({exc.args[0]})") from None
        entry = _jsonl_item(data, number, where, need_labels)
        if entry.id in seen:
            raise ConfigError(f"{where}: duplicate id {entry.id!r} (ids must be unique within a file)")
        seen.add(entry.id)
        items.append(entry)
    if not items:
        raise ConfigError(f"{path}: no CoTs (expected one JSON object a line)")
    return items


def _jsonl_item(data: Any, number: int, where: str, need_labels: bool) -> JsonlItem:
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a JSON object, got {type(data).__name__}")
    ident = data.get("id")
    if "id" in data and (not isinstance(ident, (str, int)) or isinstance(ident, bool)):
        raise ConfigError(f"{where}: id must be a string or an integer")
    slots = data.get("slots") or {}
    if not isinstance(slots, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in slots.items()):
        raise ConfigError(f"{where}: slots must be an object of slot name → text")
    text = data.get("text")
    if text is None:
        if not slots:
            raise ConfigError(f"{where}: needs \"text\" (a string) or \"slots\" (an object of texts)")
        text = CoT.join_slots(slots)
    if not isinstance(text, str):
        raise ConfigError(f"{where}: text must be a string")
    context = data.get("context") or {}
    if not isinstance(context, dict):
        raise ConfigError(f"{where}: context must be an object")
    for name, kinds in _CONTEXT_KINDS.items():
        value = context.get(name)
        if name in context and (not isinstance(value, kinds) or isinstance(value, bool)):
            raise ConfigError(f"{where}: context.{name} has the wrong type ({type(value).__name__})")
    labels = None
    if "labels" in data:
        labels = labels_from_json(data["labels"], f"{where}: labels")
    elif need_labels:
        raise ConfigError(f"{where}: no \"labels\" object (a label file needs one on every line)")
    if "id" not in data:  # never numbered silently: an edited file would match other items
        raise ConfigError(f"{where}: missing \"id\" (a string or an integer, unique within the file)")
    extra = {k: v for k, v in data.items() if k not in {"id", "text", "slots", "context", "labels"}}
    stated = tuple(p for p in PROPERTIES if p in data["labels"]) if labels is not None else ()
    return JsonlItem(str(ident), LabelInput(text=text, slots=slots, context=context, key=str(ident)), labels, extra,
                     stated)


def write_jsonl(path: Path | str, items: Sequence[JsonlItem], labels: Sequence[Labels]) -> None:
    """Write ``items`` with their ``labels`` as JSONL, atomically (a partial file never replaces a good one)."""
    path = Path(path)
    lines = []
    for entry, label in zip(items, labels, strict=True):
        line = {"id": entry.id, "text": entry.item.text}
        if entry.item.slots:
            line["slots"] = entry.item.slots
        line["context"] = entry.item.context
        line.update(entry.extra)
        line["labels"] = label.to_json()
        lines.append(json.dumps(line, ensure_ascii=False))
    tmp = path.with_name(path.name + ".partial")
    try:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")
        os.replace(tmp, path)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot write ({exc.strerror})") from None


@dataclass(frozen=True)
class LabelSource:
    """The labels of one source by item, which properties each item's labels state, and its other fields.

    ``present[id]`` holds the properties the item's ``labels`` object names: a property it leaves out is
    *missing* (counted and reported by :func:`agreement`), never read as ``none`` or ``false``. ``fields[id]``
    holds the item's other top-level fields of a JSONL file (``style``, ``source`` …) for grouping.
    """

    labels: dict[str, Labels]
    present: dict[str, frozenset[str]]
    fields: dict[str, dict[str, Any]]


def read_label_source(path: Path | str) -> dict[str, Labels]:
    """Labels by item from a JSONL label file (``id`` → labels) or a label store of a run directory
    (``DIR/labels/NAME.jsonl``: content hash → the latest labels), so two labelers of one run compare too."""
    return load_label_source(path).labels


def load_label_source(path: Path | str) -> LabelSource:
    """A :class:`LabelSource` from a JSONL label file or a run's label store (see :func:`read_label_source`)."""
    path = Path(path)
    try:
        first = next((line for line in path.open(encoding="utf-8") if line.strip()), "")
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read ({exc})") from None
    try:
        head = json.loads(first) if first else {}
    except ValueError:
        head = {}
    if isinstance(head, dict) and {"key", "content", "labeler", "labels"} <= set(head):
        store = LabelStore(path.parent.parent, path.stem)
        labels = {content: stored.labels for content, stored in store.by_content.items()}
        return LabelSource(labels, {k: frozenset(PROPERTIES) for k in labels}, {k: {} for k in labels})
    entries = read_jsonl(path, need_labels=True)
    return LabelSource({e.id: e.labels for e in entries},
                       {e.id: frozenset(e.stated) for e in entries}, {e.id: dict(e.extra) for e in entries})


# -- agreement ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PropertyAgreement:
    """Agreement of two label sources on one property."""

    prop: str
    n: int
    agreement: float | None
    kappa: float | None
    categories: tuple[str, ...]
    confusion: tuple[tuple[int, ...], ...]
    note: str = ""
    missing_a: int = 0  # items compared whose labels in the first source do not state this property
    missing_b: int = 0

    def to_json(self) -> dict[str, Any]:
        return {"property": self.prop, "n": self.n, "agreement": self.agreement, "kappa": self.kappa,
                "categories": list(self.categories), "confusion": [list(r) for r in self.confusion],
                "missing_in_a": self.missing_a, "missing_in_b": self.missing_b, "note": self.note}


@dataclass(frozen=True)
class AgreementReport:
    """κ per property plus what could not be compared."""

    properties: tuple[PropertyAgreement, ...]
    compared: int
    only_in_a: tuple[str, ...]
    only_in_b: tuple[str, ...]
    unlabelled: tuple[str, ...]

    def to_json(self) -> dict[str, Any]:
        return {"compared": self.compared, "only_in_a": list(self.only_in_a), "only_in_b": list(self.only_in_b),
                "unlabelled": list(self.unlabelled), "properties": [p.to_json() for p in self.properties]}


def category(prop: str, labels: Labels) -> str:
    """The category of ``prop`` as a string (``None`` → ``"none"``; target on a step with no target → ``"n/a"``)."""
    value = getattr(labels, prop)
    if prop == "target_mentioned" and value is None:
        return "n/a"
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return str(value)


def cohen_kappa(pairs: Sequence[tuple[str, str]]) -> PropertyAgreement:
    """Cohen's κ (statsmodels ``cohens_kappa``) and the confusion table of ``(a, b)`` category pairs."""
    from statsmodels.stats.inter_rater import cohens_kappa

    cats = tuple(sorted({c for pair in pairs for c in pair}))
    index = {c: i for i, c in enumerate(cats)}
    table = [[0] * len(cats) for _ in cats]
    for a, b in pairs:
        table[index[a]][index[b]] += 1
    n = len(pairs)
    if n == 0:
        return PropertyAgreement("", 0, None, None, cats, tuple(map(tuple, table)), "nothing to compare")
    agreement = sum(table[i][i] for i in range(len(cats))) / n
    if len(cats) == 1:
        return PropertyAgreement("", n, agreement, None, cats, tuple(map(tuple, table)),
                                 "κ undefined: both sources put every item in one category")
    kappa = float(cohens_kappa(table, return_results=False))
    note = "" if math.isfinite(kappa) else "κ undefined (chance agreement is 1)"
    return PropertyAgreement("", n, agreement, kappa if math.isfinite(kappa) else None, cats,
                             tuple(map(tuple, table)), note)


def agreement(a: Mapping[str, Labels], b: Mapping[str, Labels],
              properties: Iterable[str] = PROPERTIES, *,
              present_a: Mapping[str, frozenset[str]] | None = None,
              present_b: Mapping[str, frozenset[str]] | None = None) -> AgreementReport:
    """Cohen's κ per property between two label sources keyed by item id (unlabelled items left out).

    ``present_a`` / ``present_b`` give the properties each item's labels state (all, when not given); a
    property missing on either side leaves that item out of that property and is counted as missing.
    """
    common = [k for k in a if k in b]
    unlabelled = tuple(k for k in common if a[k].unlabelled or b[k].unlabelled)
    usable = [k for k in common if not (a[k].unlabelled or b[k].unlabelled)]
    results = []
    for prop in properties:
        in_a = [k for k in usable if present_a is None or prop in present_a.get(k, PROPERTIES)]
        in_b = {k for k in usable if present_b is None or prop in present_b.get(k, PROPERTIES)}
        pairs = [(category(prop, a[k]), category(prop, b[k])) for k in in_a if k in in_b]
        if prop == "mention_slot":  # only meaningful where someone named a slot
            pairs = [p for p in pairs if p != ("none", "none")]
        result = cohen_kappa(pairs)
        missing_a, missing_b = len(usable) - len(in_a), len(usable) - len(in_b)
        note = result.note
        if missing_a or missing_b:
            note = (note + "; " if note else "") + f"label missing in {missing_a} (first) / {missing_b} (second) items"
        results.append(PropertyAgreement(prop, result.n, result.agreement, result.kappa, result.categories,
                                         result.confusion, note, missing_a, missing_b))
    return AgreementReport(tuple(results), len(usable), tuple(k for k in a if k not in b),
                           tuple(k for k in b if k not in a), unlabelled)


def source_agreement(a: LabelSource, b: LabelSource, properties: Iterable[str] = PROPERTIES,
                     ids: Iterable[str] | None = None) -> AgreementReport:
    """:func:`agreement` of two :class:`LabelSource` s (missing labels counted), optionally on some items."""
    keep = None if ids is None else set(ids)
    a_labels = {k: v for k, v in a.labels.items() if keep is None or k in keep}
    b_labels = {k: v for k, v in b.labels.items() if keep is None or k in keep}
    return agreement(a_labels, b_labels, properties, present_a=a.present, present_b=b.present)


NO_GROUP = "(none)"
"""The group of items that have no value for the ``--by`` field."""


def agreement_by(a: LabelSource, b: LabelSource, by: str,
                 properties: Iterable[str] = PROPERTIES) -> dict[str, AgreementReport]:
    """κ per group of items, grouped by the value of their field ``by`` (``style``, ``source`` …) in the
    first source, else the second; items without it form :data:`NO_GROUP`. A field that no item of either
    source has is a :class:`ConfigError`."""
    common = [k for k in a.labels if k in b.labels]
    if not any(by in a.fields.get(k, {}) or by in b.fields.get(k, {}) for k in common):
        known = sorted({f for src in (a, b) for k in common for f in src.fields.get(k, {})})
        raise ConfigError(f"--by {by}: no item in common has a field {by!r} "
                          f"(fields of the items: {', '.join(known) if known else 'none besides id, text, slots, context, labels'})")
    groups: dict[str, list[str]] = {}
    for k in common:
        value = a.fields.get(k, {}).get(by, b.fields.get(k, {}).get(by))
        name = NO_GROUP if value is None else value if isinstance(value, str) else canonical_json(value)
        groups.setdefault(name, []).append(k)
    props = tuple(properties)
    return {name: source_agreement(a, b, props, ids) for name, ids in sorted(groups.items())}


def label_counts(labels: Iterable[Labels], prop: str) -> Counter:
    """How often each category of ``prop`` occurs."""
    return Counter(category(prop, lab) for lab in labels)
