"""The versioned prompt file: loading, checking and rendering it for one CoT.

A prompt file is TOML with ``version``, ``system``, ``instructions``, ``template`` and ``[[examples]]``
(see ``prompts/v1.toml``, which documents every field). Loading checks everything, including that every
example's answer follows the answer schema, so a broken copy fails before any call is spent.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.resources
import json
import math
import numbers
import string
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vladrivebench import ConfigError, LabelInput, load_toml

from .answer import InvalidAnswer, parse_answer_text, schema_text

DEFAULT_PROMPT = "v1.toml"
PLACEHOLDERS = ("instructions", "schema", "examples", "ground_truth", "cot")
REQUIRED_PLACEHOLDERS = ("ground_truth", "cot")
KNOWN_CONTEXT = ("critical_kind", "critical_position", "critical_speed", "distance_to_critical", "blocking",
                 "light_state", "actors", "ego_speed", "lead_gap", "lead_speed")


def default_prompt_path() -> Path:
    """Where the shipped prompt file is installed (copy it to make your own)."""
    return Path(str(importlib.resources.files("vdb_labeler_ensemble.prompts").joinpath(DEFAULT_PROMPT)))


@dataclass(frozen=True)
class Example:
    """One few-shot example: a CoT (text or slots), its ground truth and the expected answer (JSON)."""

    text: str
    slots: dict[str, str]
    context: dict[str, Any]
    answer: str


@dataclass(frozen=True)
class Prompt:
    """A loaded prompt file. ``digest`` hashes its whole content, so any edit changes the cache keys."""

    version: str
    system: str
    instructions: str
    template: str
    examples: tuple[Example, ...]
    path: Path
    digest: str

    def render(self, item: LabelInput) -> tuple[str, str]:
        """The system and user messages for ``item``."""
        user = string.Template(self.template).substitute(
            instructions=self.instructions.strip() + "\n",
            schema=schema_text(),
            examples=self.examples_text,
            ground_truth=describe_context(item.context),
            cot=describe_cot(item.text, item.slots),
        )
        return self.system.strip(), user.strip() + "\n"

    @functools.cached_property
    def examples_text(self) -> str:
        """The few-shot examples as shown in every prompt (rendered once)."""
        blocks = []
        for number, example in enumerate(self.examples, 1):
            blocks.append(
                f"Example {number}\nGround truth:\n{describe_context(example.context)}\n\n"
                f"CoT:\n{describe_cot(example.text, example.slots)}\n\nAnswer:\n{example.answer}\n"
            )
        return "\n".join(blocks)


def load_prompt(path: str | Path | None = None) -> Prompt:
    """Load and check a prompt file (the shipped ``v1`` when ``path`` is empty)."""
    path = Path(path).expanduser() if path else default_prompt_path()
    what = "prompt file"
    data = load_toml(path, what)
    for key in ("version", "system", "instructions", "template"):
        if not isinstance(data.get(key), str) or not data[key].strip():
            raise ConfigError(f"{what} {path}: {key!r} must be a non-empty string")
    unknown = sorted(set(data) - {"version", "system", "instructions", "template", "examples"})
    if unknown:
        raise ConfigError(f"{what} {path}: unknown key {unknown[0]!r} "
                          f"(keys: version, system, instructions, template, examples)")
    _check_template(data["template"], path)
    examples = tuple(_example(raw, path, n) for n, raw in enumerate(data.get("examples", []), 1))
    digest = hashlib.sha256(json.dumps(data, sort_keys=True).encode("utf-8")).hexdigest()
    return Prompt(data["version"].strip(), data["system"], data["instructions"], data["template"],
                  examples, path, digest)


def _check_template(template: str, path: Path) -> None:
    fields = []
    for match in string.Template.pattern.finditer(template):
        if match.group("invalid") is not None:
            raise ConfigError(f"prompt file {path}: 'template' has a stray '$' (write $$ for a dollar sign)")
        name = match.group("named") or match.group("braced")
        if name:
            fields.append(name)
    unknown = [f for f in fields if f not in PLACEHOLDERS]
    if unknown:
        raise ConfigError(f"prompt file {path}: 'template' has unknown placeholder ${unknown[0]} "
                          f"(placeholders: {', '.join('$' + p for p in PLACEHOLDERS)})")
    for needed in REQUIRED_PLACEHOLDERS:
        if needed not in fields:
            raise ConfigError(f"prompt file {path}: 'template' must contain ${needed}")


def _example(raw: Any, path: Path, number: int) -> Example:
    where = f"prompt file {path}: example {number}"
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: must be a table with cot or slots, context and answer")
    text, slots = raw.get("cot", ""), raw.get("slots", {})
    if not isinstance(text, str) or not isinstance(slots, dict) or not all(isinstance(v, str) for v in slots.values()):
        raise ConfigError(f"{where}: 'cot' must be a string and 'slots' a table of strings")
    if bool(text) == bool(slots):
        raise ConfigError(f"{where}: give exactly one of 'cot' (one sentence) or 'slots' (named rounds)")
    try:
        context = json.loads(raw.get("context", ""))
    except ValueError as exc:
        raise ConfigError(f"{where}: 'context' must be a JSON object string ({exc})") from None
    if not isinstance(context, dict):
        raise ConfigError(f"{where}: 'context' must be a JSON object string")
    answer = raw.get("answer", "")
    try:
        parse_answer_text(answer if isinstance(answer, str) else "", list(slots))
    except InvalidAnswer as exc:
        raise ConfigError(f"{where}: 'answer' does not follow the answer schema: {exc}") from None
    return Example(text, dict(slots), context, answer.strip())


# -- rendering the ground truth and the CoT --------------------------------------------------------------


def describe_cot(text: str, slots: Mapping[str, str]) -> str:
    """One-sentence CoTs as they are; slotted CoTs as ``[name] text`` lines, in order."""
    if slots:
        return "\n".join(f"[{name}] {value}" for name, value in slots.items())
    return text if text.strip() else "(empty: the model wrote no CoT at this step)"


def describe_context(context: Mapping[str, Any]) -> str:
    """The ground truth of one step as short lines a model reads easily.

    Reads the keys of ``vladrivebench._analysis.labels.context_from_step``; any other key is shown as JSON.
    """
    lines = [_critical_line(context)]
    if context.get("light_state"):
        lines.append(f"- Traffic light state: {context['light_state']}")
    actors = context.get("actors")
    if isinstance(actors, list):
        listed = [_actor(actor) for actor in actors]
        lines.append("- Actors present (nothing else is there): " + ("; ".join(listed) if listed else "none"))
    gap, lead_speed = _number(context.get("lead_gap")), _number(context.get("lead_speed"))
    if gap is not None:
        moving = f", {_motion(lead_speed)}" if lead_speed is not None else ""
        lines.append(f"- Lead actor in the ego lane: {gap} m ahead{moving}")
    speed = _number(context.get("ego_speed"))
    if speed is not None:
        lines.append(f"- Ego speed: {speed} m/s")
    others = {k: v for k, v in context.items() if k not in KNOWN_CONTEXT}
    if others:
        lines.append(f"- Other ground truth: {json.dumps(others, sort_keys=True, default=str)}")
    return "\n".join(lines)


def _critical_line(context: Mapping[str, Any]) -> str:
    kind = context.get("critical_kind")
    if not kind:
        return "- Critical feature: none in this scene (target_mentioned must be null)"
    parts = [f"- Critical feature: {_kind(kind)}"]
    where = _position(context.get("critical_position"))
    if where:
        parts.append(f" {where}")
    along = _number(context.get("distance_to_critical"))
    if along is not None:
        parts.append(f"; {along} m along the route")
    motion = _motion(context.get("critical_speed"))
    if motion:
        parts.append(f"; {motion}")
    if "blocking" in context and kind in ("pedestrian", "car", "animal"):
        parts.append("; it blocks the ego lane" if context["blocking"] else "; it does not block the ego lane")
    return "".join(parts)


def _actor(actor: Any) -> str:
    if not isinstance(actor, Mapping):
        return str(actor)
    text = _kind(actor.get("kind", "unknown"))
    if actor.get("state"):
        text += f" ({actor['state']})"
    where = _position(actor.get("position"))
    if where:
        text += f" {where}"
    motion = _motion(actor.get("speed"))
    if motion and actor.get("kind") not in ("traffic_light", "stop_sign"):
        text += f", {motion}"
    return text


def _motion(speed: Any) -> str:
    value = _number(speed)
    if value is None:
        return ""
    return "stationary" if abs(value) < 0.05 else f"moving at {value} m/s"


def _kind(kind: Any) -> str:
    return str(kind).replace("_", " ")


def _position(position: Any) -> str:
    if not isinstance(position, (list, tuple)) or len(position) != 2:
        return ""
    x, y = (_number(v) for v in position)
    if x is None or y is None:
        return ""
    ahead = f"{abs(x)} m {'ahead' if x >= 0 else 'behind'}"
    side = "on the centre line" if y == 0 else f"{abs(y)} m to the {'left' if y > 0 else 'right'}"
    return f"at x={x}, y={y} ({ahead}, {side})"


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
        return None
    return round(float(value), 1)
