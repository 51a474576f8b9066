"""CoT intervention conditions: what text replaces the model's own chain-of-thought at a step.

A *condition* turns the context of one step (the model's CoT format, the model's own CoT at that step,
other conditions' texts, texts harvested from baseline episodes) into an *injection*: one string for a
one-sentence model, or a mapping slot → text (in the model's slot order) for a multi-round model.

Kinds (Appendix F of the paper):

- ``selfsplice`` — the model's own CoT, decoded and re-injected (the zero-difference control);
- ``text`` — hand-crafted text written in the model's format (``sentence`` and/or ``slots``);
- ``harvest`` — a naturally generated CoT taken from a baseline step where the model braked (*origbrake*);
- ``shuffle`` — another condition's words shuffled with a fixed seed per slot;
- ``repeat`` — one token repeated ``count`` times in every slot, or as many times as it takes to match the
  token count of another condition's corresponding slot (``match``);
- ``ablation`` — another condition with one slot swapped for a donor's (by default the model's own).

Conditions come from the ``register_conditions`` hook (the core registers the paper's) and from TOML/JSON
files (:func:`load_conditions_file`); :class:`ConditionLibrary` holds them, answers parametric names such
as ``depicts-40`` and ``origbrake-swap-scene``, and checks references before anything runs.
"""

from __future__ import annotations

import re
import unicodedata
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vladrivebench._engine.options import load_data_file
from vladrivebench.errors import ConditionError, ConfigError, UnknownNameError
from vladrivebench.protocols import Condition, ConditionContext, Injection, TokenCounter
from vladrivebench.records import CoT, CoTFormat

INTENTS = ("brake", "accelerate", "none")
"""What a condition's text asks for: the direction a CoT-coupled model's trajectory should move."""

CONDITION_KINDS = ("selfsplice", "text", "harvest", "shuffle", "repeat", "ablation")

SELFSPLICE = "selfsplice"
RESERVED_NAMES = ("baseline", "openloop", "injected")
"""Names a condition may not take: the intervention run uses them for its own episodes."""
DEFAULT_SHUFFLE_SEED = 42
"""Slot i of a shuffled condition uses seed 42 + i (the paper's origbrake_shuffle used 42/43/44)."""


# -- the paper's injection texts (Appendix F, Tables 3 and 4), verbatim --------------------------------
A1_GREEN = (
    "The scene depicts an urban street during daytime with clear weather. The road is dry and "
    "well-maintained. The traffic light ahead is showing green. The surrounding buildings are multi-story "
    "structures typical of a city environment."
)
A1_RED = A1_GREEN.replace("showing green", "showing red")

PAPER_TEXTS: dict[str, dict[str, Any]] = {
    "accel": {
        "sentence": "Accelerate to maintain speed since the road ahead is clear and no obstacles are present.",
        "slots": (
            "The scene depicts a clear, sunny day with good visibility. The road is dry and well-maintained, "
            "with no visible obstacles or traffic. The surrounding area is lined with tall trees and a rocky "
            "outcrop on the left side. There are no pedestrians or other vehicles in sight. The traffic "
            "lights ahead are not visible from this angle.",
            "Car at <0.00, 30.00> directly in front of ego vehicle, moving at a similar speed, may influence "
            "following distance.",
            "You should accelerate and lane follow. The decision to accelerate is based on the current speed "
            "of 7.53 m/s and the absence of immediate obstacles or traffic constraints. Lane following is "
            "appropriate as there are no indications of needing to change lanes or turn, and the road ahead "
            "appears clear.",
        ),
    },
    "pedestrian": {
        "sentence": "Stop for the pedestrian in the lane because it is blocking the lane.",
        "slots": (
            A1_GREEN,
            "Pedestrian at <0.00, 10.00> standing in the lane, blocking the path.",
            "You should slow down and stop. A pedestrian is blocking the lane ahead, requiring the vehicle "
            "to yield.",
        ),
    },
    "car": {
        "sentence": "Stop for the stationary car in the lane because it is blocking the lane.",
        "slots": (
            A1_GREEN,
            "Car at <0.02, 29.98> directly in front of ego vehicle, moving at a similar speed, may influence "
            "following distance.",
            "You should maintain your current speed and follow the lane. The decision to maintain speed and "
            "follow the lane is influenced by the absence of immediate traffic or pedestrian obstacles. The "
            "stationary car ahead does not pose an immediate threat as it is far away and not in the same "
            "lane. The road conditions are favorable for continued travel without the need for lane changes "
            "or significant speed adjustments.",
        ),
    },
    "animal": {
        # The paper injected animal / red-light only into ORION; the sentences follow Table 3's style.
        "sentence": "Stop for the animal in the lane because it is blocking the lane.",
        "slots": (
            A1_GREEN,
            "Animal at <0.00, 10.00> placed in the lane, obstructing the path.",
            "You should slow down and stop. An animal is blocking the lane, requiring the vehicle to slow "
            "down.",
        ),
    },
    "red-light": {
        "sentence": "Stop for the red traffic light ahead because it requires the vehicle to stop.",
        "slots": (
            A1_RED,
            "Traffic light at <0.00, 20.00> showing red, requiring the ego vehicle to stop.",
            "You should slow down and stop. The traffic light ahead is red, requiring the vehicle to stop.",
        ),
    },
    "origbrake-paper": {
        "slots": (
            "The scene depicts an urban street flanked by multi-story buildings with a mix of architectural "
            "styles. The road is clear with no visible pedestrians or vehicles, except for one car ahead in "
            "the distance. The sky is clear, suggesting good weather conditions. The road surface appears "
            "smooth and well-maintained, with no obstacles present.",
            "Car at <-0.00, 30.00> directly in front of ego vehicle, stationary, may influence braking "
            "distance.",
            "You should keep and lanefollow. The decision to maintain speed and follow the lane is "
            "influenced by the absence of immediate traffic or pedestrian obstacles. The clear road "
            "conditions and lack of traffic signs suggest that continuing straight in the current lane is "
            "appropriate. The absence of other vehicles and pedestrians reduces the risk of sudden changes "
            "in driving behavior.",
        ),
    },
}

DEPICTS_COUNTS = (3, 10, 20, 30, 50, 80, 100, 150)
"""The repeat counts of the paper's depicts_N conditions (any N works through ``depicts-N``)."""


def _own_injection(ctx: ConditionContext) -> Injection:
    if ctx.cot_format.is_slotted:
        own = ctx.own.slots or {}
        return {slot: own.get(slot, "") for slot in ctx.slots}
    return ctx.own.text


def as_slots(injection: Injection, ctx: ConditionContext, who: str) -> dict[str, str]:
    """The injection as slot → text; a sentence model's text is the single slot ``"text"``."""
    if isinstance(injection, str):
        if ctx.cot_format.is_slotted:
            raise ConditionError(f"condition {who!r} gave one text but model {ctx.model_name!r} takes slots "
                                 f"{', '.join(ctx.slots)}")
        return {"text": injection}
    return dict(injection)


def from_slots(slots: Mapping[str, str], ctx: ConditionContext) -> Injection:
    return dict(slots) if ctx.cot_format.is_slotted else slots["text"]


# -- the kinds ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SelfSplice:
    """The model's own CoT at each step, decoded and re-injected (the zero-difference control)."""

    name: str = SELFSPLICE
    description: str = "the model's own CoT decoded and re-injected (zero-difference control)"
    intent: str = "none"
    kind: str = "selfsplice"

    def requires(self) -> tuple[str, ...]:
        return ()

    @property
    def per_step(self) -> bool:
        return True

    def resolve(self, ctx: ConditionContext) -> Injection:
        return _own_injection(ctx)

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "intent": self.intent, "description": self.description}


@dataclass(frozen=True)
class TextCondition:
    """Hand-crafted text: ``sentence`` for one-sentence models, ``slots`` for multi-round models.

    ``slots`` is either a mapping slot name → text, or a sequence of texts given in the model's slot order
    (the paper's ORION texts are A1 scene, A2 objects, A3 decision).
    """

    name: str
    sentence: str | None = None
    slots: Mapping[str, str] | tuple[str, ...] | None = None
    intent: str = "none"
    description: str = ""
    kind: str = "text"

    def requires(self) -> tuple[str, ...]:
        return ()

    @property
    def per_step(self) -> bool:
        return False

    def resolve(self, ctx: ConditionContext) -> Injection:
        if not ctx.cot_format.is_slotted:
            if self.sentence is None:
                raise ConditionError(f"condition {self.name!r} has no one-sentence text, which model "
                                     f"{ctx.model_name!r} needs (give it a 'sentence')")
            return self.sentence
        if self.slots is None:
            raise ConditionError(f"condition {self.name!r} has no per-slot texts, which model "
                                 f"{ctx.model_name!r} needs for slots {', '.join(ctx.slots)} (give it 'slots')")
        if isinstance(self.slots, Mapping):
            missing = [s for s in ctx.slots if s not in self.slots]
            extra = [s for s in self.slots if s not in ctx.slots]
            if missing or extra:
                what = f"lacks slot {missing[0]!r}" if missing else f"has unknown slot {extra[0]!r}"
                raise ConditionError(f"condition {self.name!r} {what}; model {ctx.model_name!r} takes slots "
                                     f"{', '.join(ctx.slots)}")
            return {s: self.slots[s] for s in ctx.slots}
        if len(self.slots) != len(ctx.slots):
            raise ConditionError(f"condition {self.name!r} has {len(self.slots)} slot texts; model "
                                 f"{ctx.model_name!r} takes {len(ctx.slots)} ({', '.join(ctx.slots)})")
        return dict(zip(ctx.slots, self.slots, strict=True))

    def to_json(self) -> dict[str, Any]:
        slots = dict(self.slots) if isinstance(self.slots, Mapping) else (list(self.slots) if self.slots else None)
        return {"name": self.name, "kind": self.kind, "intent": self.intent, "description": self.description,
                "sentence": self.sentence, "slots": slots}


@dataclass(frozen=True)
class HarvestCondition:
    """A naturally generated CoT harvested from a baseline step where the model braked (*origbrake*).

    The intervention driver harvests it once per run (:func:`harvest_braking_cot`) from the baseline
    episode of the harvest route and first seed, so every seed and step receives the same text.
    """

    name: str
    intent: str = "brake"
    description: str = "the model's own CoT from the baseline step where it braked hardest"
    kind: str = "harvest"

    def requires(self) -> tuple[str, ...]:
        return ()

    @property
    def per_step(self) -> bool:
        return False

    def resolve(self, ctx: ConditionContext) -> Injection:
        try:
            return ctx.harvested[self.name]
        except KeyError:
            raise ConditionError(f"condition {self.name!r} has not been harvested from a baseline episode "
                                 f"yet") from None

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "intent": self.intent, "description": self.description}


@dataclass(frozen=True)
class ShuffleCondition:
    """``base``'s words shuffled, slot i with seed ``seeds[i]`` (fixed, so the text is the same every step)."""

    name: str
    base: str
    seeds: tuple[int, ...] = (DEFAULT_SHUFFLE_SEED,)
    intent: str = "none"
    description: str = ""
    kind: str = "shuffle"

    def requires(self) -> tuple[str, ...]:
        return (self.base,)

    @property
    def per_step(self) -> bool:
        return False  # unless its base is; the library works that out

    def seed_for(self, index: int) -> int:
        return self.seeds[index] if index < len(self.seeds) else self.seeds[-1] + index - len(self.seeds) + 1

    def resolve(self, ctx: ConditionContext) -> Injection:
        slots = as_slots(ctx.resolve(self.base), ctx, self.base)
        shuffled = {slot: shuffle_words(text, self.seed_for(i)) for i, (slot, text) in enumerate(slots.items())}
        return from_slots(shuffled, ctx)

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "intent": self.intent, "description": self.description,
                "base": self.base, "seeds": list(self.seeds)}


@dataclass(frozen=True)
class RepeatCondition:
    """``token`` repeated ``count`` times in every slot, or matched to ``match``'s token count per slot."""

    name: str
    token: str
    count: int | None = None
    match: str | None = None
    intent: str = "none"
    description: str = ""
    kind: str = "repeat"

    def requires(self) -> tuple[str, ...]:
        return (self.match,) if self.match else ()

    @property
    def per_step(self) -> bool:
        return False

    def repeats_to_match(self, text: str, ctx: ConditionContext) -> int:
        """How many repeats of ``token`` give (about) the token count of ``text`` under the model's tokenizer."""
        per_token = max(1, ctx.count_tokens(self.token))
        return max(1, round(ctx.count_tokens(text) / per_token))

    def resolve(self, ctx: ConditionContext) -> Injection:
        if self.match is None:
            texts = {slot: repeat_token(self.token, self.count or 1) for slot in (ctx.slots or ("text",))}
            return from_slots(texts, ctx)
        target = as_slots(ctx.resolve(self.match), ctx, self.match)
        texts = {slot: repeat_token(self.token, self.repeats_to_match(t, ctx)) for slot, t in target.items()}
        return from_slots(texts, ctx)

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "intent": self.intent, "description": self.description,
                "token": self.token, "count": self.count, "match": self.match}


@dataclass(frozen=True)
class AblationCondition:
    """``base`` with slot ``slot`` swapped for ``donor``'s text of that slot; the other slots are kept."""

    name: str
    base: str
    slot: str
    donor: str = SELFSPLICE
    intent: str = "none"
    description: str = ""
    kind: str = "ablation"

    def requires(self) -> tuple[str, ...]:
        return (self.base, self.donor)

    @property
    def per_step(self) -> bool:
        return False

    def resolve(self, ctx: ConditionContext) -> Injection:
        if not ctx.cot_format.is_slotted:
            raise ConditionError(f"condition {self.name!r} swaps slot {self.slot!r}, but model "
                                 f"{ctx.model_name!r} writes one sentence (ablation needs a slotted format)")
        if self.slot not in ctx.slots:
            raise ConditionError(f"condition {self.name!r} swaps slot {self.slot!r}; model {ctx.model_name!r} "
                                 f"takes slots {', '.join(ctx.slots)}")
        base = as_slots(ctx.resolve(self.base), ctx, self.base)
        donor = as_slots(ctx.resolve(self.donor), ctx, self.donor)
        return {**base, self.slot: donor[self.slot]}

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "kind": self.kind, "intent": self.intent, "description": self.description,
                "base": self.base, "slot": self.slot, "donor": self.donor}


# -- text operations ------------------------------------------------------------------------------------
def shuffle_words(text: str, seed: int) -> str:
    """The words of ``text`` (split on whitespace) in a random order fixed by ``seed``."""
    import numpy as np  # here, not at the top: registering the conditions must not import numpy

    words = text.split()
    order = np.random.default_rng(seed).permutation(len(words))
    return " ".join(words[i] for i in order)


def repeat_token(token: str, count: int) -> str:
    """``token`` repeated ``count`` times, separated by single spaces."""
    return " ".join([token] * count)


def text_problem(text: Any) -> str | None:
    """Why no model can take ``text`` (not a string, empty, control characters), else ``None``."""
    if not isinstance(text, str):
        return f"must be a string, got {type(text).__name__}"
    if not text.strip():
        return "is empty"
    for ch in text:
        if ch not in "\n\t" and unicodedata.category(ch) in ("Cc", "Cs", "Co", "Cn"):
            return f"contains the control or unassigned character U+{ord(ch):04X}"
    return None


# -- library --------------------------------------------------------------------------------------------
_DEPICTS = re.compile(r"^depicts-(\d+)$")
_SWAP = re.compile(r"^(?P<base>.+)-swap-(?P<slot>[A-Za-z0-9_]+)$")
MAX_REPEAT = 100_000


class ConditionLibrary:
    """Every known condition by name, plus the parametric names ``depicts-<N>`` and ``<base>-swap-<slot>``.

    ``sources`` maps a name to where it was defined (plugin name or file) for messages and manifests.
    """

    def __init__(self, conditions: Iterable[Condition] = (), sources: Mapping[str, str] | None = None):
        self._conditions: dict[str, Condition] = {}
        self.sources: dict[str, str] = {}
        for cond in conditions:
            self.add(cond, (sources or {}).get(cond.name, "built-in"))

    def add(self, condition: Condition, source: str = "", *, replace: bool = False) -> None:
        if condition.name in RESERVED_NAMES:
            raise ConditionError(f"condition {condition.name!r} from {source or '?'}: the name is reserved for "
                                 f"the intervention run's own episodes; pick another")
        if condition.name in self._conditions and not replace:
            raise ConditionError(f"condition {condition.name!r} from {source or '?'} is already defined by "
                                 f"{self.sources.get(condition.name, '?')} (set replace = true to override)")
        self._conditions[condition.name] = condition
        self.sources[condition.name] = source

    def names(self) -> list[str]:
        return sorted(self._conditions)

    def __contains__(self, name: str) -> bool:
        try:
            self.get(name)
        except UnknownNameError:
            return False
        return True

    def get(self, name: str) -> Condition:
        """The condition called ``name``; parametric names are built on demand; unknown → UnknownNameError."""
        if name in self._conditions:
            return self._conditions[name]
        depicts = _DEPICTS.match(name)
        if depicts:
            count = int(depicts.group(1))
            if not 1 <= count <= MAX_REPEAT:
                raise ConditionError(f"condition {name!r}: the repeat count must be between 1 and {MAX_REPEAT}")
            return RepeatCondition(name, "depicts", count=count,
                                   description=f"'depicts' repeated {count} times in every slot")
        swap = _SWAP.match(name)
        if swap and swap.group("base") in self._conditions:
            base, slot = swap.group("base"), swap.group("slot")
            return AblationCondition(name, base, slot, description=f"{base} with its {slot} slot swapped for "
                                     f"the model's own")
        raise UnknownNameError("condition", name, self.names() + ["depicts-<N>", "<condition>-swap-<slot>"])

    def closure(self, names: Sequence[str]) -> list[Condition]:
        """The named conditions and everything they build on, dependencies first; cycles are errors."""
        order: list[Condition] = []
        state: dict[str, str] = {}

        def visit(name: str, chain: tuple[str, ...]) -> None:
            if state.get(name) == "done":
                return
            if state.get(name) == "visiting":
                raise ConditionError(f"conditions form a cycle: {' -> '.join(chain + (name,))}")
            state[name] = "visiting"
            cond = self.get(name)
            for dep in cond.requires():
                visit(dep, chain + (name,))
            state[name] = "done"
            order.append(cond)

        for name in names:
            visit(name, ())
        return order

    def is_per_step(self, name: str) -> bool:
        """Whether ``name``'s injection can change between steps (it reads the model's own CoT)."""
        cond = self.get(name)
        return cond.per_step or any(self.is_per_step(dep) for dep in cond.requires())

    def harvest_names(self, names: Sequence[str]) -> list[str]:
        """The harvest conditions that ``names`` need, directly or through other conditions."""
        return [c.name for c in self.closure(names) if c.kind == "harvest"]


@dataclass
class StepResolver:
    """Resolves conditions at one step, memoising each injection (a condition used twice is built once)."""

    library: ConditionLibrary
    cot_format: CoTFormat
    own: CoT
    harvested: Mapping[str, Injection] = field(default_factory=dict)
    count_tokens: Callable[[str], int] = lambda text: len(text.split())
    model_name: str = "model"
    _memo: dict[str, Injection] = field(default_factory=dict)

    def __call__(self, name: str) -> Injection:
        if name not in self._memo:
            ctx = ConditionContext(self.cot_format, self.own, self, self.harvested, self.count_tokens,
                                   self.model_name)
            self._memo[name] = self.library.get(name).resolve(ctx)
        return self._memo[name]


def injection_problem(injection: Any, cot_format: CoTFormat, count_tokens: Callable[[str], int],
                      allow_empty: bool = False) -> str | None:
    """Why a model of ``cot_format`` cannot take ``injection`` (shape, text, token limit), else ``None``.

    ``allow_empty`` accepts empty (or blank) texts: at a step they come from the model's own CoT, and an
    empty own CoT is a valid CoT whose splice is the empty splice.
    """
    if cot_format.is_slotted:
        if not isinstance(injection, Mapping):
            return f"must be one text per slot ({', '.join(cot_format.slots)}), got {type(injection).__name__}"
        if list(injection) != list(cot_format.slots):
            return f"has slots {', '.join(injection)}; expected {', '.join(cot_format.slots)}"
        texts = list(injection.items())
    else:
        if not isinstance(injection, str):
            return f"must be one sentence (a string), got {type(injection).__name__}"
        texts = [("text", injection)]
    for slot, text in texts:
        where = "" if slot == "text" else f"slot {slot!r} "
        problem = None if allow_empty and isinstance(text, str) and not text.strip() else text_problem(text)
        if problem:
            return f"{where}{problem}"
        if cot_format.max_tokens is not None:
            tokens = count_tokens(text)
            if tokens > cot_format.max_tokens:
                return f"{where}has {tokens} tokens; the model takes at most {cot_format.max_tokens}"
    return None


def token_counter(model: Any) -> Callable[[str], int]:
    """The model's own token count when it is a :class:`~vladrivebench.TokenCounter`, else a word count."""
    if isinstance(model, TokenCounter):
        return model.count_tokens
    return lambda text: len(text.split())


# -- braking-step harvest -------------------------------------------------------------------------------
@dataclass(frozen=True)
class HarvestedText:
    """A harvested injection and where it came from (recorded in the run's results)."""

    injection: Injection
    episode: str
    step: int
    brake: float

    def to_json(self) -> dict[str, Any]:
        return {"injection": self.injection, "episode": self.episode, "step": self.step, "brake": self.brake}


def harvest_braking_cot(steps: Iterable[tuple[int, Mapping[str, Any], Mapping[str, Any]]],
                        cot_format: CoTFormat, episode: str) -> HarvestedText | None:
    """The CoT of the step where the model braked hardest (earliest on ties), or ``None`` if it never braked.

    ``steps`` yields ``(step, cot, control)`` with the logged CoT (``text``, ``slots``) and control
    (``brake``) dicts of a baseline episode.
    """
    best: tuple[float, int, Mapping[str, Any]] | None = None
    for step, cot, control in steps:
        brake = float(control.get("brake", 0.0) or 0.0)
        if brake > 0.0 and (best is None or brake > best[0]):
            best = (brake, step, cot)
    if best is None:
        return None
    brake, step, cot = best
    if cot_format.is_slotted:
        slots = cot.get("slots") or {}
        injection: Injection = {s: str(slots.get(s, "")) for s in cot_format.slots}
    else:
        injection = str(cot.get("text", ""))
    return HarvestedText(injection, episode, step, brake)


# -- built-ins and files --------------------------------------------------------------------------------
def builtin_conditions() -> list[Condition]:
    """The paper's conditions (Appendix F): selfsplice, accel, brake texts, origbrake and its probes."""
    intents = {"accel": "accelerate", "origbrake-paper": "brake"}
    described = {
        "accel": "road is clear, accelerate (Table 3 / Table 4 Accel)",
        "pedestrian": "stop for a pedestrian blocking the lane",
        "car": "stop for a stationary car in the lane (ORION's A3 text is the paper's, which says maintain)",
        "animal": "stop for an animal blocking the lane",
        "red-light": "stop for a red traffic light",
        "origbrake-paper": "the paper's ORION origbrake text (slotted models only)",
    }
    conds: list[Condition] = [SelfSplice()]
    for name, texts in PAPER_TEXTS.items():
        conds.append(TextCondition(name, texts.get("sentence"), texts.get("slots"),
                                   intent=intents.get(name, "brake"), description=described[name]))
    conds += [
        HarvestCondition("origbrake"),
        ShuffleCondition("origbrake-shuffle", "origbrake", (42, 43, 44), intent="brake",
                         description="origbrake's words shuffled per slot (seeds 42/43/44)"),
        RepeatCondition("depicts-all", "depicts", match="origbrake",
                        description="'depicts' repeated to match the token count of each origbrake slot"),
    ]
    conds += [RepeatCondition(f"depicts-{n}", "depicts", count=n, description=f"'depicts' repeated {n} times")
              for n in DEPICTS_COUNTS]
    return conds


_FIELDS: dict[str, set[str]] = {
    "selfsplice": set(),
    "text": {"sentence", "slots"},
    "harvest": set(),
    "shuffle": {"base", "seeds", "seed"},
    "repeat": {"token", "count", "match"},
    "ablation": {"base", "slot", "donor"},
}
_COMMON = {"kind", "intent", "description", "replace"}


def load_conditions_file(path: Path | str) -> list[tuple[Condition, bool]]:
    """Conditions defined in a TOML or JSON file, with their ``replace`` flag.

    The file has a table ``conditions`` whose keys are condition names::

        [conditions.cyclist]
        intent = "brake"
        sentence = "Stop for the cyclist in the lane because it is blocking the lane."
        slots = ["The scene depicts …", "Cyclist at <0.00, 10.00> …", "You should slow down and stop."]

    Every problem is one :class:`ConditionError` line naming the file, the condition and the field.
    """
    path = Path(path)
    try:
        data = load_data_file(path, "conditions file")
    except ConfigError as exc:
        raise ConditionError(str(exc)) from None
    where = f"conditions file {path}"
    unknown_top = [k for k in data if k != "conditions"]
    if unknown_top:
        raise ConditionError(f"{where}: unknown top-level key {unknown_top[0]!r} (expected a 'conditions' table)")
    table = data.get("conditions")
    if not isinstance(table, Mapping) or not table:
        raise ConditionError(f"{where}: expected a non-empty 'conditions' table of name → condition")
    return [_parse_condition(str(name), spec, where) for name, spec in table.items()]


def _parse_condition(name: str, spec: Any, where: str) -> tuple[Condition, bool]:
    here = f"{where}: condition {name!r}"
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.+-]*", name):
        raise ConditionError(f"{here}: names may hold letters, digits and _ . + - only")
    if name in RESERVED_NAMES:
        raise ConditionError(f"{here}: the name is reserved for the run's own episodes; pick another")
    if not isinstance(spec, Mapping):
        raise ConditionError(f"{here}: expected a table of fields, got {type(spec).__name__}")
    kind = spec.get("kind", "text")
    if kind not in CONDITION_KINDS or kind == "selfsplice":
        raise ConditionError(f"{here}: field 'kind' must be one of {', '.join(CONDITION_KINDS[1:])}, got {kind!r}")
    unknown = [k for k in spec if k not in _FIELDS[kind] | _COMMON]
    if unknown:
        allowed = ", ".join(sorted(_FIELDS[kind] | _COMMON))
        raise ConditionError(f"{here}: unknown field {unknown[0]!r} for kind {kind!r} (allowed: {allowed})")
    intent = spec.get("intent", "brake" if kind == "harvest" else "none")
    if intent not in INTENTS:
        raise ConditionError(f"{here}: field 'intent' must be one of {', '.join(INTENTS)}, got {intent!r}")
    description = _string(spec, "description", here, required=False, allow_empty=True) or ""
    replace = spec.get("replace", False)
    if not isinstance(replace, bool):
        raise ConditionError(f"{here}: field 'replace' must be true or false, got {replace!r}")
    common = {"intent": intent, "description": description}
    return _BUILDERS[kind](name, spec, here, common), replace


def _string(spec: Mapping, key: str, here: str, *, required: bool = True, allow_empty: bool = False) -> str | None:
    if key not in spec:
        if required:
            raise ConditionError(f"{here}: missing field {key!r}")
        return None
    value = spec[key]
    problem = None if allow_empty and value == "" else text_problem(value)
    if problem:
        raise ConditionError(f"{here}: field {key!r} {problem}")
    return value


def _int(value: Any, key: str, here: str, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low or (high is not None and value > high):
        bound = f"between {low} and {high}" if high is not None else f"≥ {low}"
        raise ConditionError(f"{here}: field {key!r} must be an integer {bound}, got {value!r}")
    return value


def _build_text(name: str, spec: Mapping, here: str, common: dict) -> Condition:
    sentence = _string(spec, "sentence", here, required=False)
    slots = spec.get("slots")
    if slots is not None:
        if isinstance(slots, Mapping):
            if not slots:
                raise ConditionError(f"{here}: field 'slots' must name at least one slot")
            for slot, text in slots.items():
                problem = text_problem(text)
                if problem:
                    raise ConditionError(f"{here}: field 'slots.{slot}' {problem}")
            slots = dict(slots)
        elif isinstance(slots, list) and slots:
            for i, text in enumerate(slots):
                problem = text_problem(text)
                if problem:
                    raise ConditionError(f"{here}: field 'slots[{i}]' {problem}")
            slots = tuple(slots)
        else:
            raise ConditionError(f"{here}: field 'slots' must be a table slot → text or a list of texts, "
                                 f"got {slots!r}")
    if sentence is None and slots is None:
        raise ConditionError(f"{here}: a text condition needs 'sentence' (one-sentence models) and/or 'slots' "
                             f"(multi-round models)")
    return TextCondition(name, sentence, slots, **common)


def _build_harvest(name: str, spec: Mapping, here: str, common: dict) -> Condition:
    return HarvestCondition(name, intent=common["intent"], description=common["description"] or
                            HarvestCondition.description)


def _build_shuffle(name: str, spec: Mapping, here: str, common: dict) -> Condition:
    base = _string(spec, "base", here)
    if "seeds" in spec and "seed" in spec:
        raise ConditionError(f"{here}: give either 'seed' or 'seeds', not both")
    if "seeds" in spec:
        seeds = spec["seeds"]
        if not isinstance(seeds, list) or not seeds:
            raise ConditionError(f"{here}: field 'seeds' must be a non-empty list of integers, got {seeds!r}")
        seeds = tuple(_int(s, "seeds", here, 0) for s in seeds)
    else:
        seeds = (_int(spec.get("seed", DEFAULT_SHUFFLE_SEED), "seed", here, 0),)
    return ShuffleCondition(name, base, seeds, **common)


def _build_repeat(name: str, spec: Mapping, here: str, common: dict) -> Condition:
    token = _string(spec, "token", here)
    if len(token.split()) != 1:
        raise ConditionError(f"{here}: field 'token' must be one word without spaces, got {token!r}")
    has_count, has_match = "count" in spec, "match" in spec
    if has_count == has_match:
        raise ConditionError(f"{here}: a repeat condition needs exactly one of 'count' (e.g. 50) or 'match' "
                             f"(a condition name)")
    count = _int(spec["count"], "count", here, 1, MAX_REPEAT) if has_count else None
    match = _string(spec, "match", here) if has_match else None
    return RepeatCondition(name, token, count=count, match=match, **common)


def _build_ablation(name: str, spec: Mapping, here: str, common: dict) -> Condition:
    base = _string(spec, "base", here)
    slot = _string(spec, "slot", here)
    donor = _string(spec, "donor", here, required=False) or SELFSPLICE
    return AblationCondition(name, base, slot, donor, **common)


_BUILDERS: dict[str, Callable[[str, Mapping, str, dict], Condition]] = {
    "text": _build_text,
    "harvest": _build_harvest,
    "shuffle": _build_shuffle,
    "repeat": _build_repeat,
    "ablation": _build_ablation,
}


def build_library(registry: Any = None, files: Sequence[Path | str] = ()) -> ConditionLibrary:
    """The conditions registered through ``register_conditions`` (every plugin) plus those in ``files``.

    Registered factories are called with no arguments and must return a :class:`Condition` whose
    ``name`` equals the registered name; files are applied in order and may ``replace`` a condition.
    """
    from vladrivebench._engine.registry import get_registry

    registry = registry or get_registry()
    library = ConditionLibrary()
    for comp in registry.components("condition"):
        cond = comp.factory()
        if not isinstance(cond, Condition):
            raise ConditionError(f"condition {comp.name!r} (plugin {comp.plugin!r}) is not a condition object: "
                                 f"it lacks name/kind/intent/requires/resolve")
        if cond.name != comp.name:
            raise ConditionError(f"condition registered as {comp.name!r} by plugin {comp.plugin!r} calls "
                                 f"itself {cond.name!r}")
        library.add(cond, f"plugin {comp.plugin}")
    for path in files:
        for cond, replace in load_conditions_file(path):
            library.add(cond, f"file {path}", replace=replace)
    return library


def check_references(library: ConditionLibrary, names: Sequence[str]) -> list[Condition]:
    """The closure of ``names`` with every reference checked (unknown names and cycles are errors)."""
    for name in names:
        library.get(name)
    return library.closure(names)
