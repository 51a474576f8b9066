"""Reading a CoT: entity mentions, action claims and light colours, each with its scope.

The reader is context-free: it says what the text *claims* (a pedestrian is present, standing, at
<0.00, 10.00>; the ego should slow down; the light is red), and whether each claim is asserted, negated
("no pedestrians"), hedged ("watch for pedestrians"), or sequential ("then accelerate"). The labeler
then judges those claims against the ground truth.

Coordinates follow ORION's bird's-eye convention ``<lateral, forward>``; the sign of the lateral
coordinate is not relied upon (conventions differ), only its magnitude.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from typing import Any

# -- vocabulary ---------------------------------------------------------------------------------------
ROAD_USERS = ("pedestrian", "car", "animal", "cyclist")
INFRASTRUCTURE = ("traffic_light", "stop_sign")

ENTITY_PATTERNS: tuple[tuple[str, str], ...] = (
    # longer, more specific names first: their spans are taken before shorter ones can match inside them
    ("traffic_light", r"traffic\s+lights?|traffic\s+signals?|(?:red|green|yellow|amber)\s+lights?"
                      r"|(?<!turn\s)(?<!crossing\s)(?<!railroad\s)\bsignals?\b|\b(?:the|a)\s+lights?\b(?!\s+(?:rain|snow|fog|wind|traffic))"
                      r"|\b(?:red|green|yellow|amber|the|a)\s+(?:(?:protected|left|right|straight|through|turn|left-turn"
                      r"|right-turn|protected-left|protected-right|arrow|red|green|yellow|amber)\s+){1,2}(?:lights?|signals?)\b"
                      r"|\b(?:the|a)\s+lamps?\b"),
    ("stop_sign", r"stop\s+signs?|\b(?:the|a)\s+sign\b"),
    ("hazard", r"speed\s+bumps?|traffic\s+cones?|\bcones?\b"
               r"|construction(?!\s+(?:vehicles?|trucks?|vans?|workers?))|road\s*works?|barriers?|barricades?"
               r"|debris|potholes?"),
    ("cyclist", r"cyclists?|bicyclists?|bicycles?|bikes?|bikers?|motorcyclists?|scooters?"),
    ("pedestrian", r"pedestrians?|persons?|people|\bman\b|\bmen\b|woman|women|child(?:ren)?|\bkids?\b"
                   r"|jaywalkers?|walkers?|someone|somebody|\bboy\b|\bgirl\b"),
    ("car", r"cars?|vehicles?|sedans?|\bsuvs?\b|trucks?|\bvans?\b|\bbus(?:es)?\b|lorr(?:y|ies)|taxis?"
            r"|pickups?|motorcycles?"),
    ("animal", r"animals?|\bdogs?\b|\bcats?\b|\bdeer\b|horses?|\bcows?\b|sheep"),
    ("obstacle", r"obstacles?|obstructions?"),
    ("traffic", r"\btraffic\b(?!\s+(?:lights?|signals?|signs?|cones?|constraints?|conditions?|rules?|laws?|regulations?))"),
)
"""(kind, regex) of every entity the reader knows. ``traffic`` is a vague word for vehicles: it counts in
negations ("no traffic") but is never a mention nor a fabricated entity. ``obstacle`` is generic."""

_ENTITY_RES = tuple((kind, re.compile(rf"\b(?:{pattern})\b")) for kind, pattern in ENTITY_PATTERNS)
_EGO_BEFORE = re.compile(r"\b(?:ego|our|my|own)\s+$")
_EGO_AFTER = re.compile(r"^\s+to\s+(?!the\b|a\b|an\b)")  # "requiring the vehicle to stop": the ego
_BARE_ARTICLE = re.compile(r"\b(?:the|ego)\s+$")  # ... but "the crossing vehicle to pass" is another road user
_EGO_FRONT = re.compile(r"\bin\s+front\s+of\s+(?:the\s+)?$")  # "standing in front of the car": the ego
_LOCATED = re.compile(r"^\s+(?:ahead|in|on|at|parked|stopped|stationary|that|which|is|pos\d+)\b")

ACTION_PATTERNS: tuple[tuple[str, str], ...] = (
    ("keep_distance", r"(?:adapt|adjust)(?:s|ing)?\s+(?:the\s+|our\s+|its\s+)?speed\s+to\s+(?:maintain|keep)\s+"
                      r"(?:a\s+)?(?:safe\s+)?(?:following\s+)?(?:distance|gap)"
                      r"|keep(?:s|ing)?\s+(?:a\s+)?(?:safe\s+)?(?:following\s+)?(?:distance|gap)"
                      r"|maintain(?:s|ing)?\s+(?:a\s+)?(?:safe\s+)?(?:following\s+)?(?:distance|gap)"
                      r"|follow(?:s|ing)?\s+(?:\w+\s+){0,5}at\s+a\s+(?:safe\s+)?distance"
                      r"|follow(?:s|ing)?\s+the\s+(?:lead|leading|preceding)\s+(?:vehicle|car)"),
    ("decelerating", r"slow(?:s|ing)?\s+down|decelerat\w*|brak(?:e|es|ing)(?!\s+distance)"
                     r"|stop(?:s|ping)?(?!\s+(?:signs?|lines?|distance))|halt(?:s|ing)?|yield(?:s|ing)?"
                     r"|wait\b(?!\s+for\s+(?:a\s+)?(?:\w+\s+)?gap)|(?:adapt|adjust)(?:s|ing)?\s+(?:the\s+|our\s+|its\s+)?speed"
                     r"|eas(?:e|es|ing)\s+off|gradually\s+slowing|gently\s+slowing|stay(?:s|ing)?\s+put"
                     r"|remain(?:s|ing)?\s+(?:stationary|still)|keep(?:s|ing)?\s+stationary|(?:is|are)\s+not\s+moving"
                     r"|reduc(?:e|es|ing)\s+(?:the\s+|our\s+|its\s+)?speed|ease\s+off|give\s+way"
                     r"|hold\s+(?:our\s+)?position|remain\s+stopped|stay\s+stopped|come\s+to\s+a\s+(?:complete\s+)?halt"),
    ("accelerating", r"accelerat(?:e|es|ing|ion)|speed(?:s|ing)?\s+up|resum(?:e|es|ing)"
                     r"|pick(?:s|ing)?\s+up\s+speed|increas(?:e|es|ing)\s+(?:the\s+|our\s+)?speed|go\s+faster"
                     r"|build(?:s|ing)?\s+(?:up\s+)?speed|gain(?:s|ing)?\s+speed"
                     r"|creep(?:s|ing)?\s+(?:forward|ahead)|mov(?:e|es|ing)\s+off|pull(?:s|ing)?\s+away"),
    ("maintaining", r"maintain(?:s|ing)?\s+(?:the\s+|your\s+|its\s+|our\s+|a\s+)?(?:current\s+|same\s+|constant\s+"
                    r"|steady\s+|present\s+)?(?:speed|pace|velocity)"
                    r"|keep(?:s|ing)?\s+(?:the\s+|your\s+|our\s+|my\s+|its\s+|a\s+)?(?:current\s+|same\s+|constant\s+|steady\s+)?speed"
                    r"|keep(?:s|ing)?\s+(?:going|driving|moving|cruising|rolling)|keep\s+and\b|continu(?:e|es|ing|ed)"
                    r"|proceed(?:s|ing)?|cruis(?:e|ing)\s+(?:on|along)|go(?:ing)?\s+(?:straight|through|ahead)"
                    r"|at\s+(?:the|a)\s+(?:current|same|constant|steady)\s+speed|carry\s+on|hold\s+(?:the\s+)?speed"
                    r"|drive\s+through|driv(?:e|es|ing)\s+(?:fast|slowly|normally|with\s+(?:a\s+)?normal\s+speed)"),
)
"""(stated action, regex), in the order their spans are taken (keep distance before maintaining)."""

_ACTION_RES = tuple((name, re.compile(rf"\b(?:{pattern})\b")) for name, pattern in ACTION_PATTERNS)
_GO = ("accelerating", "maintaining")

# -- scope cues ---------------------------------------------------------------------------------------
_NEG_CUE = re.compile(r"\bno\b(?!\s+(?:need|longer|matter|sign\s+of\s+slowing))|\bwithout\b|\bnone\s+of\b"
                      r"|\bnor\b|\bneither\b|\bnot\s+any\b|\b(?:absence|lack|free|clear|devoid)\s+of\b")
_NEG_AFTER = re.compile(r"\b(?:is|are|was|were)\s+not\s+(?:visible|present|detected|seen|there|around)\b"
                        r"|\bnot\s+(?:visible|present|detected|seen)\b|\bnowhere\b")
_NEG_QUALIFIER = re.compile(r"\b(?:other|immediate|nearby|further|additional|close|more|significant)\b")
_EXCEPTION = re.compile(r"\b(?:except|other\s+than|apart\s+from|aside\s+from|besides|save\s+for)\b")
_TENTATIVE_CUE = re.compile(r"\b(?:might|may|could)\s+(?:also\s+)?be\b|\bpossibly\b|\bprobably\b|\blikely\b"
                            r"|\b(?:appears|seems)\s+to\s+be\b|\bwhat\s+(?:looks|appears)\s+like\b")
_HEDGE_CUE = re.compile(r"\b(?:watch|look|looking|watching)\s+(?:out\s+)?for\b|\b(?:cautious|careful|aware|alert|wary"
                        r"|mindful)\s+(?:of|for)\b|\bin\s+case\b|\b(?:potential|possible|possibly|any|if|whether"
                        r"|might|could|may)\b")
_CLAUSE_BREAK = re.compile(r"[,:]|\b(?:except|but|so|because|since|while|although|though|then|however|whereas|yet"
                           r"|as|once|until|when|after|before|if|besides|apart|aside)\b|\bother\s+than\b"
                           r"|\band\s+(?=(?:a|an|the|one|there|it|we|you)\b)")
_ACTION_NEGATION = re.compile(r"(?:\bnot|n't|\bno\s+need\s+to|\bwithout|\bnever|\bavoid(?:ing)?|\bnor|\bcannot)"
                              r"\s+(?:\w+\s+){0,2}$")
_SEQUENTIAL = re.compile(r"\b(?:then|afterwards|later|once|until|when|whenever|if|unless|after|before)\b")
_LEADING_SUBORDINATE = re.compile(r"^\s*(?:after|once|when|if|before|until|unless)\b[^,]*,")
_LEADING_CONDITION = re.compile(r"^\s*(?:if|unless|in\s+case|should)\b[^,]*,")
_CONDITION_AFTER = re.compile(r"^[^.;:]*?\b(?:only\s+(?:if|when|once|after)|provided\s+(?:that\b)?|as\s+long\s+as)\b")
_PREPARE = re.compile(r"\b(?:prepare|prepares|preparing|get\s+ready|getting\s+ready|ready)\s+to\s+$")
_APPROACH = re.compile(r"\bstill\s+far\b|\bfar\s+away\b|\bfar\s+ahead\b|\bin\s+the\s+distance\b|\bfor\s+now\b"
                       r"|\bwhile\s+approaching\b|\bas\s+we\s+approach\b|\btoward\b|\btowards\b")
_HALT = re.compile(r"\bstop|\bhalt|\bremain\s+stopped|\bstay\s+stopped")
_BLOCKING = re.compile(r"\b(?:blocking|blocks|blocked|obstructing|obstructs|obstructed)\b")
_NOT_BEFORE = re.compile(r"(?:\bnot|n't|\bno\s+longer)\s+(?:\w+\s+){0,1}$")

MOVING_WORDS = (r"moving|moves|moved|overtaking|overtakes|driving|drives|walking|walks|walked|crossing|crosses"
                r"|crossed|running|runs|approaching|approaches|pulling\s+out|passing|oncoming|travell?ing|slowing|braking"
                r"|decelerating|maintaining\s+(?:a\s+)?(?:steady\s+)?(?:pace|speed)")
STATIONARY_WORDS = r"stationary|stopped|parked|standing|stands|waiting|idle|immobile|not\s+moving|halted"
_MOVING = re.compile(rf"\b(?:{MOVING_WORDS})\b")
_STATIONARY = re.compile(rf"\b(?:{STATIONARY_WORDS})\b")
_PRE_ATTRIBUTE = re.compile(rf"\b({MOVING_WORDS}|{STATIONARY_WORDS})\s+(?:(?!the\b|a\b|an\b|our\b)\w+\s+)?$")
_ATTR_STOP_SENTENCE = re.compile(r"[;:.]|\b(?:may|might|could|will|because|since)\b")
_ATTR_STOP = re.compile(r"[,;:.]|\b(?:and|then|but|because|since|so|to|until|while|when|once|as|after|before|or"
                        r"|if|may|might|could|will)\b")

_COLOURS = {"red": "red", "green": "green", "yellow": "yellow", "amber": "yellow"}
_COLOUR_BEFORE = re.compile(r"\b(red|green|yellow|amber)\s+(?:(?!the\b|a\b|and\b|or\b)[\w-]+\s+){0,2}(?:traffic\s+)?$")
_COLOUR_INSIDE = re.compile(r"\b(red|green|yellow|amber)\b")
_COLOUR_AFTER = re.compile(r"^(?:\s+(?:ahead|is|are|was|has|have|had|now|currently|still|showing|shows|showed|show"
                           r"|turned|turning|turns|turn|displaying|displays|lit|already|just|changed|changing|changes|change|switches"
                           r"|switched|to|at|pos\d+"
                           r"|in|front|of|us|the|for|our|lane|direction))*?\s+(red|green|yellow|amber)\b")
_FUTURE = re.compile(r"\b(?:until|once|when|wait\s+for|waiting\s+for|after|before|if|unless)\b")

_COORD = re.compile(r"[<⟨(\[]\s*(-?\d+(?:\.\d+)?)\s*,\s*(-?\d+(?:\.\d+)?)\s*[>⟩)\]]")
_SENTENCE_SPLIT = re.compile(r"(?<=[.!?;])\s+")
_ORION_SUBJECT = re.compile(r"^\s*(?:the\s+|a\s+|an\s+)?(?:\w+\s+){0,2}?(\w+)\s+at\s+pos(\d+)\b")


# -- what the text claims -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Mention:
    """One entity the text names, with its status and what it says about it."""

    kind: str
    word: str
    slot: str | None
    status: str  # "asserted", "tentative" ("might be a pedestrian"), "negated", "hedged" ("watch for …")
    qualified: bool = False  # a negation limited by "other", "immediate", "except" … ("no other vehicles")
    position: tuple[float, float] | None = None  # (forward, lateral magnitude-bearing), metres
    motion: frozenset[str] = frozenset()  # {"moving"} / {"stationary"}
    blocking: bool = False
    colour: str | None = None  # traffic lights: the colour stated for it now (not a future one)

    @property
    def asserted(self) -> bool:
        return self.status == "asserted"

    @property
    def named(self) -> bool:
        """Named as (possibly) present: asserted or tentative — what counts as a mention."""
        return self.status in ("asserted", "tentative")


@dataclass(frozen=True)
class Claim:
    """One longitudinal action the text states or demands for the ego."""

    action: str  # a stated-action group
    phrase: str
    slot: str | None
    current: bool  # False when negated, sequential ("then accelerate") or conditional
    anticipatory: bool = False  # "prepare to stop"; a go while the obstacle is "still far away" / "for now"
    halt: bool = False  # a stop to standstill ("stop", "halt"), not merely slowing
    purpose: bool = False  # the purpose of the command before it ("stop to keep distance"): one decision


@dataclass
class Reading:
    """Everything the text claims, in text order (slots in their order)."""

    mentions: list[Mention] = field(default_factory=list)
    claims: list[Claim] = field(default_factory=list)
    slots: tuple[str | None, ...] = ()


def read(text: str, slots: dict[str, str] | None = None) -> Reading:
    """Read a CoT: slot by slot for slotted formats, else the whole text."""
    reading = Reading()
    parts = list(slots.items()) if slots else [(None, text)]
    reading.slots = tuple(name for name, _ in parts)
    for slot, part in parts:
        first_claim = len(reading.claims)
        for sentence in _SENTENCE_SPLIT.split(part.strip()):
            if sentence.strip():
                _read_sentence(sentence, slot, reading)
        if _APPROACH.search(part.lower()):  # "You should keep and lanefollow. The car ahead is still far away."
            reading.claims[first_claim:] = [_replace(c, anticipatory=True) if go_or_stop(c.action) == "go" else c
                                            for c in reading.claims[first_claim:]]
    return reading


def _read_sentence(raw: str, slot: str | None, reading: Reading) -> None:
    positions: list[tuple[float, float]] = []

    def keep_position(match: re.Match) -> str:
        lateral, forward = float(match.group(1)), float(match.group(2))
        positions.append((forward, lateral))
        return f" pos{len(positions) - 1} "

    text = _COORD.sub(keep_position, raw.lower())
    text = re.sub(r",\s*(which|who)\b", r" \1", text)
    text = re.sub(r"\s+", " ", text)
    breaks = [m.start() for m in _CLAUSE_BREAK.finditer(text)]
    subject_kind, subject_position = _orion_subject(text, positions)
    mentions = _mentions(text, slot, breaks, positions, subject_kind, subject_position)
    reading.mentions.extend(mentions)
    _pronoun_colour(text, reading)
    reading.claims.extend(_claims(text, slot))


_PRONOUN_COLOUR = re.compile(r"\bit\s+(?:is\s+|has\s+)?(?:now\s+|currently\s+|still\s+|just\s+)?(?:shows?|showing"
                             r"|displays?|displaying|is|turned|turns|changed\s+to|changes\s+to)\s+(red|green|yellow|amber)\b")


def _pronoun_colour(text: str, reading: Reading) -> None:
    """``There is a traffic light ahead; it shows amber``: the pronoun's colour is the light's, when no light
    has a colour yet (a future "until it turns green" is no statement)."""
    match = _PRONOUN_COLOUR.search(text)
    if not match or _FUTURE.search(text[: match.start()]) or any(m.colour for m in reading.mentions):
        return
    lights = [i for i, m in enumerate(reading.mentions) if m.kind == "traffic_light" and m.asserted]
    if lights:
        reading.mentions[lights[-1]] = _replace(reading.mentions[lights[-1]], colour=_COLOURS[match.group(1)])


def _orion_subject(text: str, positions: list) -> tuple[str | None, tuple[float, float] | None]:
    """``Car at <0.00, 30.00> …``: the sentence is about this entity (ORION's objects answer)."""
    match = _ORION_SUBJECT.match(text)
    if not match:
        return None, None
    head = match.group(0)
    for kind, regex in _ENTITY_RES:
        if regex.search(head):
            return kind, positions[int(match.group(2))]
    return None, None


def _clause(breaks: list[int], offset: int, length: int) -> tuple[int, int]:
    start = max((b for b in breaks if b < offset), default=0)
    end = min((b for b in breaks if b > offset), default=length)
    return start, end


def _mentions(text: str, slot: str | None, breaks: list[int], positions: list, subject_kind: str | None,
              subject_position: tuple[float, float] | None) -> list[Mention]:
    taken: list[tuple[int, int]] = []
    found: list[tuple[int, Mention]] = []
    for kind, regex in _ENTITY_RES:
        for match in regex.finditer(text):
            start, end = match.span()
            if any(s < end and start < e for s, e in taken):
                continue
            if kind == "car" and _is_ego(text, start, end):
                continue
            taken.append((start, end))
            found.append((start, _mention(text, match, kind, slot, breaks, positions, subject_kind,
                                          subject_position)))
    found.sort(key=lambda pair: pair[0])
    mentions = _pronoun_motion(text, found)
    if _BLOCKING.search(text) and not _negated_blocking(text):
        for i, m in enumerate(mentions):
            if m.asserted and m.kind not in INFRASTRUCTURE + ("traffic", "hazard"):
                mentions[i] = _replace(m, blocking=True)
                break
    return mentions


_PRONOUN_CLAUSE = re.compile(r"\b(?:because|as|since|and|while)\s+(?:it|they)\s+(?:is|are|was|were|has|have)\b([^,;.]*)")


def _pronoun_motion(text: str, found: list[tuple[int, Mention]]) -> list[Mention]:
    """``the lead vehicle because it is stopped ahead``: the pronoun's motion belongs to the road user before it."""
    mentions = [m for _, m in found]
    for clause in _PRONOUN_CLAUSE.finditer(text):
        words = clause.group(1)
        claimed = {name for regex, name in ((_MOVING, "moving"), (_STATIONARY, "stationary"))
                   if (hit := regex.search(words)) and not _NOT_BEFORE.search(words[: hit.start()])}
        before = [i for i, (start, m) in enumerate(found)
                  if start < clause.start() and m.asserted and m.kind in ROAD_USERS]
        if len(claimed) == 1 and before and not mentions[before[-1]].motion:
            mentions[before[-1]] = _replace(mentions[before[-1]], motion=frozenset(claimed))
    return mentions


def _is_ego(text: str, start: int, end: int) -> bool:
    """``ego vehicle``, ``the vehicle to yield``, ``in front of the car``, ``The car moves off as …``: the text
    speaks of the ego."""
    before, after = text[:start], text[end:]
    if _EGO_BEFORE.search(before) or _narrated_ego(text, start, end):
        return True
    if _EGO_AFTER.match(after) and _BARE_ARTICLE.search(before):
        return True
    return bool(_EGO_FRONT.search(before)) and not _LOCATED.match(after)


def _narrated_ego(text: str, start: int, end: int) -> bool:
    """A sentence that opens with "the car" / "the vehicle" doing an ego command ("The car slows down because
    …", BDD-X-style narration) narrates the ego in the third person."""
    if text[start:end] not in ("car", "vehicle") or not _NARRATED_EGO.match(text[:start] + " "):
        return False
    rest = re.sub(r"^\s+(?:is\s+|then\s+|now\s+)?", "", text[end:])
    return any(regex.match(rest) for _, regex in _ACTION_RES)


def _negated_blocking(text: str) -> bool:
    return all(_NOT_BEFORE.search(text[: m.start()]) for m in _BLOCKING.finditer(text))


def _mention(text: str, match: re.Match, kind: str, slot: str | None, breaks: list[int], positions: list,
             subject_kind: str | None, subject_position: tuple[float, float] | None) -> Mention:
    start, end = match.span()
    c_start, c_end = _clause(breaks, start, len(text))
    before, after = text[c_start:start], text[end:c_end]
    status, qualified = "asserted", False
    negations = list(_NEG_CUE.finditer(before))
    if negations:
        status = "negated"
        qualified = bool(_NEG_QUALIFIER.search(before[negations[-1].end():]) or _EXCEPTION.search(text[end:]))
    elif _NEG_AFTER.search(after):
        status = "negated"
    elif _TENTATIVE_CUE.search(before):
        status = "tentative"
    elif _HEDGE_CUE.search(before):
        status = "hedged"
    position = _position_after(text[end:], positions)
    # "Car at <0.02, 29.98> directly in front …, moving at a similar speed": the sentence describes it
    describes_sentence = subject_kind == kind and (position is not None or _is_sentence_subject(text, start))
    if position is None and describes_sentence:
        position = subject_position
    motion = _motion(text, start, end, whole_sentence=describes_sentence)
    colour = _colour(text, match, before) if kind == "traffic_light" and status == "asserted" else None
    return Mention(kind, match.group(0), slot, status, qualified, position, motion, False, colour)


def _is_sentence_subject(text: str, start: int) -> bool:
    head = _ORION_SUBJECT.match(text)
    return head is not None and start < head.end()


def _position_after(rest: str, positions: list) -> tuple[float, float] | None:
    found = re.match(r"^\s+(?:\w+\s+){0,1}?at\s+pos(\d+)\b", rest)
    return positions[int(found.group(1))] if found else None


def _motion(text: str, start: int, end: int, whole_sentence: bool) -> frozenset[str]:
    claims: set[str] = set()
    pre = _PRE_ATTRIBUTE.search(text[:start])
    if pre:
        claims.add("moving" if _MOVING.fullmatch(pre.group(1)) else "stationary")
    if whole_sentence:
        window = re.sub(r"\b(?:ego|our)\s+vehicle\b", " ", text[end:])
        window = _ATTR_STOP_SENTENCE.split(window)[0]
    else:
        window = _ATTR_STOP.split(text[end:])[0]
        window = " ".join(window.split()[:6])
    for regex, name in ((_MOVING, "moving"), (_STATIONARY, "stationary")):
        hit = regex.search(window)
        if hit and not _NOT_BEFORE.search(window[: hit.start()]):
            claims.add(name)
    return frozenset(claims)


def _colour(text: str, match: re.Match, before: str) -> str | None:
    if _FUTURE.search(before):
        return None
    inside = _COLOUR_INSIDE.search(match.group(0))
    if inside:
        return _COLOURS[inside.group(1)]
    pre = _COLOUR_BEFORE.search(text[: match.start()])
    if pre:
        return _COLOURS[pre.group(1)]
    post = _COLOUR_AFTER.match(text[match.end():])
    if post:
        gap = text[match.end(): match.end() + post.start(1)]
        if not _FUTURE.search(gap) and not re.search(r"\bnot\b", gap):
            return _COLOURS[post.group(1)]
    return None


# -- who does what: the reading of a clause around an action verb -------------------------------------------
_DETERMINER_BEFORE = re.compile(r"\b(?:a|an|the|full|complete|standstill|from)\s+$")
_EGO_STOP_VERB = re.compile(r"\b(?:come|comes|coming|came|slow|slows|slowing|brake|brakes|braking|bring|brings|bringing"
                            r"|roll|rolls|rolling|decelerat\w*)\b(?:\s+\w+){0,2}\s+to\s+(?:a\s+)?(?:full\s+|complete\s+)?$")
_PURPOSE_BEFORE = re.compile(r"(?:\bin\s+order|\bso\s+as)?\s*\bto\s+$")
_OTHER_SUBJECT = re.compile(r"(?:\b(?:it|they|object|objects)\b|\b(?:cars?|vehicles?|sedans?|suvs?|trucks?|vans?|bus|buses"
                            r"|pickups?|motorcycles?|cyclists?|pedestrians?|traffic|queue|someone|people|person)\b)"
                            r"(?:\s+(?:ahead|in\s+front|in\s+our\s+lane|alongside|that|which|who|is|are|was|were|has|have|had|also"
                            r"|currently|now|still|gradually|slowly|suddenly|\w+ly"
                            r"|(?:com(?:e|es|ing)|about|start(?:s|ing)|begin(?:s|ning)|going)\s+to(?:\s+a)?(?:\s+(?:full|complete))?))*\s+$")
_EGO_SUBJECT = re.compile(r"\b(?:ego(?:\s+(?:vehicle|car))?|we|i|our\s+(?:car|vehicle))\b(?:\s+\w+){0,3}\s+$")
_EGO_OPENS = re.compile(r"^\s*(?:the\s+ego\b|we\b|i\b|our\s+(?:car|vehicle)\b)")
_NARRATED_EGO = re.compile(r"^\s*(?:then\s+|now\s+)?the\s+(?:(?:car|vehicle)\s+(?:is\s+|then\s+|now\s+)?)?$")
_PROGRESSIVE_HEADING = re.compile(r"\b(?:is|are)\s+$")


def _condition_follows(text: str, end: int) -> bool:
    """``proceed only if the crossing is clear``: a condition after the command, before the next command."""
    match = _CONDITION_AFTER.match(text[end:])
    if not match:
        return False
    between = text[end: end + match.start(0) + len(match.group(0))]
    return not any(regex.search(between) for _, regex in _ACTION_RES)


def _is_noun_stop(text: str, start: int, phrase: str) -> bool:
    """``a standstill stop``, ``requires a stop``, ``approaching a stop``: the noun, not the ego's command —
    unless an ego stopping verb governs it (``come to a stop``, ``brake gently to a stop``)."""
    if not phrase.startswith("stop"):
        return False
    before = text[:start]
    return bool(_DETERMINER_BEFORE.search(before)) and not _EGO_STOP_VERB.search(before)


def _other_actor_subject(text: str, start: int, clause_start: int) -> bool:
    """The verb's subject is another road user (``the lead car ahead braking``, ``the object is stationary``,
    ``it is going ahead``), not the ego (``the ego vehicle should stop``) nor an imperative (``Stop``)."""
    before = text[clause_start:start]
    if _EGO_SUBJECT.search(before) or _NARRATED_EGO.match(text[:start]):
        return False
    subject = _OTHER_SUBJECT.search(before)
    if subject and subject.group(0).split()[0] == "it" and _EGO_OPENS.match(text):
        return False  # "The ego vehicle is steering left, and it is driving slowly": "it" is the ego
    return bool(subject)


def _claims(text: str, slot: str | None) -> list[Claim]:
    taken: list[tuple[int, int]] = []
    found: list[tuple[int, Claim]] = []
    prior_end = _LEADING_SUBORDINATE.match(text)
    subject_breaks = [0] + [m.end() for m in re.finditer(r"[,;:]|\b(?:so|but|then|while|and\s+(?=the\s+ego|we\b|i\b))\b", text)]
    for action, regex in _ACTION_RES:
        for match in regex.finditer(text):
            start, end = match.span()
            if any(s < end and start < e for s, e in taken):
                continue
            taken.append((start, end))
            phrase = match.group(0)
            clause_start = max(b for b in subject_breaks if b <= start)
            if _is_noun_stop(text, start, phrase) or _other_actor_subject(text, start, clause_start):
                continue
            if phrase.startswith("go") and "straight" in phrase and _PROGRESSIVE_HEADING.search(text[:start]):
                continue  # "the ego vehicle is going straight": its heading, not a speed
            before = text[:start]
            negated = bool(_ACTION_NEGATION.search(before))
            conditional = bool(_LEADING_CONDITION.match(text)) or _condition_follows(text, end)
            if prior_end and start < prior_end.end():
                sequential = True
            else:
                scope_start = prior_end.end() if prior_end else 0
                sequential = bool(_SEQUENTIAL.search(text[scope_start:start]))
            purpose = bool(_PURPOSE_BEFORE.search(before)) and not _ACTION_NEGATION.search(before)
            anticipatory = bool(_PREPARE.search(before)) if action == "decelerating" else bool(_APPROACH.search(text))
            found.append((start, Claim(action, phrase, slot, not (negated or sequential or conditional), anticipatory,
                                       bool(_HALT.search(phrase)), purpose)))
    found.sort(key=lambda pair: pair[0])
    found = [(start, c) for i, (start, c) in enumerate(found)
             if not (c.phrase in ("continued", "continuing") and i + 1 < len(found)
                     and found[i + 1][0] == start + len(c.phrase) + 1)]
    claims = [_participle_sequence(text, start, c, i) for i, (start, c) in enumerate(found)]
    # a purpose ("stop to keep distance") belongs to the command before it; the first claim is no purpose
    return [c if i and c.purpose else _replace(c, purpose=False) for i, c in enumerate(claims)]


_PARTICIPLE_CLAUSE = re.compile(r",\s*(?:then\s+)?\w+ing\b(?:\s+\w+){0,3}\s+$")


def _participle_sequence(text: str, start: int, claim: Claim, index: int) -> Claim:
    """``The ego vehicle proceeds along the road, coming to a halt at the light``: a participle clause after
    a narrated command tells what happens next — a sequence, not a second current command."""
    if index and claim.current and _PARTICIPLE_CLAUSE.search(text[:start]):
        return _replace(claim, current=False)
    return claim


def _replace(record: Any, **changes: Any) -> Any:
    return replace(record, **changes)


def go_or_stop(action: str) -> str | None:
    """``"go"`` for accelerating/maintaining, ``"stop"`` for decelerating, ``None`` otherwise."""
    if action in _GO:
        return "go"
    return "stop" if action == "decelerating" else None
