"""The answer every backend must give, and how a reply's text is checked against it.

An answer is one JSON object with exactly the fields of :data:`ANSWER_FIELDS`. A reply that is not such
an object, lacks a field, or puts a value outside its domain is *invalid*: it gives no vote at all, and
the reason is recorded. Nothing is ever filled in with a default.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from typing import Any

from vladrivebench import LIGHT_COLOURS, STATED_ACTIONS

from .backends import CUT_OFF_FINISHES, Reply

ANSWER_FIELDS = ("stated_action", "target_mentioned", "mention_slot", "light_colour", "hallucination",
                 "contradiction")

ANSWER_SCHEMA: dict[str, Any] = {
    "type": "object",
    "required": list(ANSWER_FIELDS),
    "properties": {
        "stated_action": {"enum": list(STATED_ACTIONS)},
        "target_mentioned": {"type": ["boolean", "null"]},
        "mention_slot": {"type": ["string", "null"]},
        "light_colour": {"enum": [*LIGHT_COLOURS, None]},
        "hallucination": {"type": "boolean"},
        "contradiction": {"type": "boolean"},
    },
}
"""The JSON schema of an answer, as shown to the models in the prompt."""


class InvalidAnswer(Exception):
    """A reply that gives no usable vote; the message says why in one line."""


def schema_text() -> str:
    """The answer schema as compact JSON, for the prompt."""
    return json.dumps(ANSWER_SCHEMA, separators=(", ", ": "))


def parse_reply(reply: Reply, slots: Sequence[str] = ()) -> dict[str, Any]:
    """The validated answer in ``reply``; :class:`InvalidAnswer` with the reason otherwise."""
    if reply.refusal:
        raise InvalidAnswer(f"refused: {_shorten(reply.refusal)}")
    if reply.text is None:
        cut = " (cut off by the output-token limit: raise ?max_tokens=N)" if reply.finish in CUT_OFF_FINISHES else ""
        raise InvalidAnswer(f"empty answer{cut} (finish reason {reply.finish!r})")
    try:
        answer = parse_answer_text(reply.text, slots)
    except InvalidAnswer as exc:
        if reply.finish in CUT_OFF_FINISHES:
            raise InvalidAnswer(f"{exc} (cut off by the output-token limit: raise ?max_tokens=N)") from None
        raise
    return answer


def parse_answer_text(text: str, slots: Sequence[str] = ()) -> dict[str, Any]:
    """Decode and validate an answer. ``slots`` are the CoT's slot names (empty for one-sentence CoTs)."""
    data = _decode_object(text)
    missing = [name for name in ANSWER_FIELDS if name not in data]
    if missing:
        raise InvalidAnswer(f"answer is missing field{'s' if len(missing) > 1 else ''} {', '.join(missing)}")
    answer = {
        "stated_action": _enum(data, "stated_action", STATED_ACTIONS, nullable=False),
        "target_mentioned": _boolean(data, "target_mentioned", nullable=True),
        "mention_slot": _slot(data, slots),
        "light_colour": _enum(data, "light_colour", LIGHT_COLOURS, nullable=True),
        "hallucination": _boolean(data, "hallucination", nullable=False),
        "contradiction": _boolean(data, "contradiction", nullable=False),
    }
    if answer["mention_slot"] is not None and answer["target_mentioned"] is not True:
        raise InvalidAnswer(f"mention_slot is {answer['mention_slot']!r} but target_mentioned is "
                            f"{json.dumps(answer['target_mentioned'])}")
    return answer


_FENCE = re.compile(r"^\s*```(?:json|JSON)?\s*\n?(.*?)\n?\s*```\s*$", re.DOTALL)


def _decode_object(text: str) -> dict[str, Any]:
    fenced = _FENCE.match(text)
    body = fenced.group(1) if fenced else text
    try:
        data = json.loads(body)
    except ValueError as exc:
        raise InvalidAnswer(f"answer is not valid JSON ({exc.args[0] if exc.args else exc}): "
                            f"{_shorten(text)!r}") from None
    if not isinstance(data, dict):
        raise InvalidAnswer(f"answer must be a JSON object, got {type(data).__name__}")
    return data


def _normalise(value: str) -> str:
    return re.sub(r"[\s-]+", "_", value.strip().lower())


def _enum(data: dict[str, Any], name: str, allowed: Sequence[str], *, nullable: bool) -> str | None:
    value = data[name]
    if value is None and nullable:
        return None
    if isinstance(value, str) and _normalise(value) in allowed:
        return _normalise(value)
    expected = ", ".join([*allowed, *(["null"] if nullable else [])])
    raise InvalidAnswer(f"{name} is {json.dumps(value)}, expected one of {expected}")


def _boolean(data: dict[str, Any], name: str, *, nullable: bool) -> bool | None:
    value = data[name]
    if isinstance(value, bool) or (value is None and nullable):
        return value
    raise InvalidAnswer(f"{name} is {json.dumps(value)}, expected true or false{' or null' if nullable else ''}")


def _slot(data: dict[str, Any], slots: Sequence[str]) -> str | None:
    value = data["mention_slot"]
    if not slots or value is None:
        return None  # a one-sentence CoT has no slot to name: mention_slot is not voted on then
    if isinstance(value, str) and value.strip() in slots:
        return value.strip()
    raise InvalidAnswer(f"mention_slot is {json.dumps(value)}, expected one of {', '.join(slots)} or null")


def _shorten(text: str, limit: int = 160) -> str:
    flat = " ".join(str(text).split())
    return flat if len(flat) <= limit else flat[: limit - 1] + "…"
