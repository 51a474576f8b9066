"""The ensemble labeler: every CoT to every backend, a majority vote per label, a tie-breaker for splits.

A batch is labelled in two rounds. First each distinct (backend, prompt, CoT, context) not yet in the
cache is sent, at most ``concurrency`` calls in flight per backend; then the items whose vote is split are
sent to the tie-breaker, and only those. Each stored label records every backend's vote (or why it gave
none), the tie-breaker's, how each label was decided and the prompt version; an item that cannot be
decided is ``Labels(unlabelled=reason)``, never a default.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO
from urllib.parse import urlsplit

import httpx
import numpy as np
from vladrivebench import ConfigError, LabelInput, Labels
from vladrivebench.cli import Progress

from . import LABELER_NAME, __version__
from .answer import InvalidAnswer, parse_reply
from .backends import BackendSpec, Reply, parse_backend, parse_backends
from .cache import ResponseCache, cache_key, default_cache_path
from .client import BackendClient, CallFailed, Jitter, Redactor, RetryPolicy
from .prompt import Prompt, load_prompt
from .vote import Decision, decide, describe_splits


@dataclass(frozen=True)
class _Call:
    """One request to send: which backend, the rendered messages, and its cache key."""

    backend: BackendSpec
    key: str
    system: str
    user: str


Outcome = Reply | CallFailed
"""What one call came to: a reply (possibly a refusal or an invalid answer) or a failure."""


class EnsembleLabeler:
    """Labels CoTs with several LLM backends and a majority vote (see the module docstring).

    ``backends`` and ``tie_breaker`` take the spec syntax of :mod:`vdb_labeler_ensemble.backends`.
    ``cache`` is a SQLite file (``None`` keeps replies in memory only). ``sleep``, ``clock``,
    ``progress_stream``, ``environ`` and ``http`` are for tests and embedding.
    """

    name = LABELER_NAME

    def __init__(
        self,
        backends: str | Sequence[Any],
        *,
        tie_breaker: str | Mapping[str, Any] | None = None,
        cache: str | Path | None = None,
        concurrency: int = 4,
        max_retries: int = 5,
        timeout: float = 60.0,
        prompt: str | Path | None = None,
        min_votes: int | None = None,
        max_retry_after: float = 300.0,
        progress: bool = True,
        seed: int = 0,
        sleep: Callable[[float], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        progress_stream: TextIO | None = None,
        environ: Mapping[str, str] | None = None,
        http: httpx.Client | None = None,
    ):
        self.backends = parse_backends(backends, "backends")
        self.tie_breaker = parse_backend(tie_breaker, "tie_breaker") if tie_breaker else None
        _check_tie_breaker(self.tie_breaker, self.backends)
        self.min_votes = len(self.backends) // 2 + 1 if not min_votes else int(min_votes)
        if not 1 <= self.min_votes <= len(self.backends):
            raise ConfigError(f"min_votes={self.min_votes}: must be between 1 and the number of backends "
                              f"({len(self.backends)})")
        self.concurrency, self.timeout = concurrency, timeout
        self.policy = RetryPolicy(max_retries=max_retries, max_retry_after=max_retry_after)
        self.prompt: Prompt = load_prompt(prompt)
        self.cache = ResponseCache(cache)
        self.version = self._version()
        self._progress, self._progress_stream = progress, progress_stream
        self._stop = threading.Event()  # set on an interrupt: retrying workers give up instead of waiting
        self._sleep = sleep if sleep is not None else self._stop.wait
        self._clock = clock
        self._environ = os.environ if environ is None else environ
        self._jitter = Jitter(np.random.default_rng(seed))
        self._redact = Redactor()
        self._http = http
        self._own_http = http is None
        self._clients: dict[str, BackendClient] | None = None

    def __repr__(self) -> str:
        return f"EnsembleLabeler(backends={[b.name for b in self.backends]}, version={self.version!r})"

    # -- the Labeler protocol ------------------------------------------------------------------------
    def label(self, item: LabelInput) -> Labels:
        """Labels for one CoT."""
        return self.label_batch([item])[0]

    def label_batch(self, items: Sequence[LabelInput]) -> list[Labels]:
        """Labels for many CoTs, in order; calls run concurrently and every reply is cached at once."""
        items = list(items)
        if not items:
            return []
        self.check()
        self._stop.clear()
        rendered = [self.prompt.render(item) for item in items]
        main_calls = [self._calls_for(item, msgs, self.backends) for item, msgs in zip(items, rendered, strict=True)]
        outcomes = self._run([c for calls in main_calls for c in calls], "ensemble")
        votes = [self._votes(item, calls, outcomes) for item, calls in zip(items, main_calls, strict=True)]
        decisions = [self._decide(item, answers) for item, (answers, _) in zip(items, votes, strict=True)]
        tie_calls: dict[int, _Call] = {}
        if self.tie_breaker is not None:
            tie_calls = {i: self._calls_for(items[i], rendered[i], [self.tie_breaker])[0]
                         for i, d in enumerate(decisions) if d.needs_tie_breaker}
            outcomes.update(self._run(list(tie_calls.values()), "tie-breaker"))
        return [self._labels(item, votes[i], decisions[i], tie_calls.get(i), outcomes)
                for i, item in enumerate(items)]

    # -- what the `vdb label` command calls ----------------------------------------------------------
    def check(self) -> None:
        """Check keys and reach every base URL (a TCP connection, not a call); one-line ConfigError if not."""
        if self._clients is not None:
            return
        keys: dict[str, str | None] = {}
        for spec in self._all_backends():
            key = spec.find_key(self._environ)
            if key is None and spec.key_required:
                raise ConfigError(spec.missing_key_message())
            keys[spec.name] = key
            if key:
                self._redact.add(key)
        for spec in self._all_backends():
            self._probe(spec)
        if self._http is None:
            self._http = httpx.Client(
                timeout=httpx.Timeout(self.timeout, connect=min(self.timeout, 10.0)),
                limits=httpx.Limits(max_connections=self.concurrency * len(self._all_backends())),
            )
        self._clients = {
            spec.name: BackendClient(spec, keys[spec.name], self._http, self.policy, sleep=self._sleep,
                                     clock=self._clock, jitter=self._jitter, redact=self._redact, stop=self._stop)
            for spec in self._all_backends()
        }

    def plan(self, items: Sequence[LabelInput]) -> dict[str, dict[str, int]]:
        """For ``--dry-run``: per backend, how many calls a run would make and how many are cached.

        The tie-breaker is asked only about split votes, so its ``calls`` is an upper bound: the items whose
        cached votes are known to split, plus every item whose votes are not all in yet; ``at_least``
        counts the first kind only.
        """
        items = list(items)
        rendered = [self.prompt.render(item) for item in items]
        calls = [self._calls_for(item, msgs, self.backends) for item, msgs in zip(items, rendered, strict=True)]
        cached = self.cache.get_many(c.key for item_calls in calls for c in item_calls)
        plan: dict[str, dict[str, int]] = {}
        for spec in self.backends:
            keys = {c.key for item_calls in calls for c in item_calls if c.backend.name == spec.name}
            hits = sum(k in cached for k in keys)
            plan[spec.name] = {"calls": len(keys) - hits, "cached": hits}
        if self.tie_breaker is not None:
            plan[self.tie_breaker.name] = self._plan_tie_breaker(items, rendered, calls, cached)
        return plan

    def close(self) -> None:
        """Close the HTTP client (if this labeler made it) and the cache."""
        if self._own_http and self._http is not None:
            self._http.close()
        self.cache.close()

    def __enter__(self) -> EnsembleLabeler:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals -----------------------------------------------------------------------------------
    def _all_backends(self) -> list[BackendSpec]:
        return [*self.backends, *([self.tie_breaker] if self.tie_breaker else [])]

    def _version(self) -> str:
        votes = json.dumps([[b.identity() for b in self.backends],
                            self.tie_breaker.identity() if self.tie_breaker else None, self.min_votes])
        votes_digest = hashlib.sha256(votes.encode("utf-8")).hexdigest()[:8]
        return f"ensemble-{__version__}+prompt.{self.prompt.version}.{self.prompt.digest[:8]}+votes.{votes_digest}"

    def _probe(self, spec: BackendSpec) -> None:
        parts = urlsplit(spec.base_url)
        port = parts.port or (443 if parts.scheme == "https" else 80)
        try:
            with socket.create_connection((parts.hostname, port), timeout=min(self.timeout, 5.0)):
                pass
        except OSError as exc:
            reason = exc.strerror or type(exc).__name__
            raise ConfigError(f"backend {spec.name!r}: cannot reach {spec.base_url} ({reason}): start the "
                              f"server, or fix the URL after '@' in {spec.text or spec.name!r}") from None

    def _calls_for(self, item: LabelInput, messages: tuple[str, str], specs: Sequence[BackendSpec]) -> list[_Call]:
        system, user = messages
        return [_Call(spec, cache_key(spec.identity(), self.prompt.version, self.prompt.digest, item.text,
                                      item.slots, item.context), system, user) for spec in specs]

    def _run(self, calls: Sequence[_Call], what: str) -> dict[str, Outcome]:
        """Every call's outcome by cache key: cached replies first, the rest sent concurrently."""
        outcomes: dict[str, Outcome] = dict(self.cache.get_many(c.key for c in calls))
        pending = list({c.key: c for c in calls if c.key not in outcomes}.values())
        progress = Progress(what, len(pending), len(outcomes), stream=self._progress_stream or sys.stderr,
                            clock=self._clock, enabled=self._progress)
        by_backend: dict[str, list[_Call]] = {}
        for call in pending:
            by_backend.setdefault(call.backend.name, []).append(call)
        pools = [ThreadPoolExecutor(self.concurrency, thread_name_prefix=f"vdb-{name}") for name in by_backend]
        try:
            futures: dict[Future[Outcome], _Call] = {}
            for pool, backend_calls in zip(pools, by_backend.values(), strict=True):
                futures.update({pool.submit(self._send, call): call for call in backend_calls})
            remaining = set(futures)
            while remaining:
                # A bounded wait keeps the main thread responsive to Ctrl-C on every platform.
                finished, remaining = wait(remaining, timeout=0.5, return_when="FIRST_COMPLETED")
                for future in finished:
                    outcome = future.result()
                    outcomes[futures[future].key] = outcome
                    progress.advance(failed=isinstance(outcome, CallFailed))
        except BaseException:
            self._stop.set()  # Ctrl-C: calls in flight finish or fail fast; their replies are already cached
            raise
        finally:
            for pool in pools:
                pool.shutdown(wait=True, cancel_futures=True)
        return outcomes

    def _send(self, call: _Call) -> Outcome:
        assert self._clients is not None
        try:
            reply = self._clients[call.backend.name].call(call.system, call.user)
        except CallFailed as exc:
            return exc
        self.cache.put(call.key, call.backend.name, call.backend.model, self.prompt.version, reply)
        return reply

    def _votes(self, item: LabelInput, calls: Sequence[_Call],
               outcomes: Mapping[str, Outcome]) -> tuple[dict[str, dict[str, Any]], dict[str, dict[str, Any]]]:
        """The valid answers by backend, and every backend's vote record (answer or error)."""
        answers: dict[str, dict[str, Any]] = {}
        record: dict[str, dict[str, Any]] = {}
        for call in calls:
            try:
                answer = self._answer(outcomes[call.key], item)
            except (CallFailed, InvalidAnswer) as exc:
                record[call.backend.name] = {"error": self._redact(str(exc))}
            else:
                answers[call.backend.name] = answer
                record[call.backend.name] = {"answer": answer}
        return answers, record

    @staticmethod
    def _answer(outcome: Outcome, item: LabelInput) -> dict[str, Any]:
        if isinstance(outcome, CallFailed):
            raise outcome
        return parse_reply(outcome, list(item.slots))

    def _decide(self, item: LabelInput, answers: Mapping[str, dict[str, Any]],
                tie_answer: Mapping[str, Any] | None = None) -> Decision:
        return decide(answers, has_critical=bool(item.context.get("critical_kind")), slotted=bool(item.slots),
                      min_votes=self.min_votes, tie_answer=tie_answer)

    def _labels(self, item: LabelInput, votes: tuple[dict[str, Any], dict[str, Any]],
                decision: Decision, tie_call: _Call | None, outcomes: Mapping[str, Outcome]) -> Labels:
        answers, record = votes
        tie_record: dict[str, Any] | None = None
        reason = decision.reason
        if decision.reason is not None and len(answers) < self.min_votes:
            errors = "; ".join(f"{name}: {r['error']}" for name, r in record.items() if "error" in r)
            reason = (f"too few valid answers: {len(answers)} of {len(self.backends)} backends "
                      f"(need {self.min_votes}): {errors}")
        elif decision.needs_tie_breaker:
            decision, tie_record, reason = self._break_tie(item, answers, decision, tie_call, outcomes)
        details = {
            "prompt_version": self.prompt.version,
            "prompt_digest": self.prompt.digest[:12],
            "backends": [spec.name for spec in self.backends],
            "votes": record,
            "tie_breaker": tie_record,
            "decided_by": decision.decided_by,
        }
        common = {"details": details, "labeler": self.name, "version": self.version}
        if decision.values is None:
            return Labels(unlabelled=reason or "undecided", **common)
        return Labels(**decision.values, **common)

    def _break_tie(self, item: LabelInput, answers: Mapping[str, dict[str, Any]], decision: Decision,
                   tie_call: _Call | None, outcomes: Mapping[str, Outcome]) -> tuple[Decision, dict[str, Any] | None, str | None]:
        split = describe_splits(decision.tied)
        if tie_call is None:
            return decision, None, (f"no majority for {split}, and no tie_breaker is set "
                                    f"(--labeler-opt tie_breaker=KIND:MODEL)")
        name = tie_call.backend.name
        try:
            tie_answer = self._answer(outcomes[tie_call.key], item)
        except (CallFailed, InvalidAnswer) as exc:
            error = self._redact(str(exc))
            return decision, {"backend": name, "error": error}, f"no majority for {split}, and the tie-breaker {name} gave no answer: {error}"
        final = self._decide(item, answers, tie_answer)
        record = {"backend": name, "answer": tie_answer, "fields": sorted(decision.tied)}
        if final.values is None:
            picked = ", ".join(f"{f}={json.dumps(tie_answer.get(f))}" for f in final.tied)
            return final, record, f"no majority for {split}, and the tie-breaker {name} answered {picked}, not one of the tied values"
        return final, record, None

    def _plan_tie_breaker(self, items: Sequence[LabelInput], rendered: Sequence[tuple[str, str]],
                          calls: Sequence[Sequence[_Call]], cached: Mapping[str, Reply]) -> dict[str, int]:
        assert self.tie_breaker is not None
        known: list[str] = []
        possible = 0
        for item, msgs, item_calls in zip(items, rendered, calls, strict=True):
            if not all(c.key in cached for c in item_calls):
                possible += 1
                continue
            answers, _ = self._votes(item, item_calls, cached)
            if self._decide(item, answers).needs_tie_breaker:
                known.append(self._calls_for(item, msgs, [self.tie_breaker])[0].key)
        unique = set(known)
        hits = len(self.cache.get_many(unique))
        return {"calls": len(unique) - hits + possible, "cached": hits, "at_least": len(unique) - hits}


def _check_tie_breaker(tie_breaker: BackendSpec | None, backends: Sequence[BackendSpec]) -> None:
    if tie_breaker is None:
        return
    for spec in backends:
        if tie_breaker.same_model(spec):
            raise ConfigError(f"tie_breaker {tie_breaker.name!r} is also a voting backend, so its vote is "
                              f"already counted: choose a different model as tie-breaker")
        if tie_breaker.name == spec.name:
            raise ConfigError(f"tie_breaker name {tie_breaker.name!r} is used by a voting backend: "
                              f"give it a distinct name with ?name=ALIAS")


def build_labeler(
    backends: Any,
    tie_breaker: Any = "",
    cache: Any = "",
    concurrency: Any = 4,
    max_retries: Any = 5,
    timeout: Any = 60.0,
    prompt: Any = "",
    min_votes: Any = 0,
    max_retry_after: Any = 300.0,
    progress: Any = True,
    seed: Any = 0,
) -> EnsembleLabeler:
    """Build the labeler from user options (strings from the command line or values from TOML); every
    option is checked before any call is spent. This is the ``ensemble`` labeler's registered factory.

    ``backends``: comma-separated ``KIND:MODEL[@BASE_URL][?key_env=VAR&name=ALIAS…]`` (or a list);
    ``tie_breaker``: one more backend, asked only when a label's vote is split; ``cache``: a SQLite file
    path, empty for the default (``$VDB_CACHE_DIR`` or the user's cache directory), ``off`` to keep
    replies in memory only; ``concurrency``: calls in flight per backend; ``max_retries``, ``timeout``,
    ``max_retry_after`` (seconds); ``prompt``: your prompt file; ``min_votes``: valid answers needed
    (default: a majority of the backends).
    """
    return EnsembleLabeler(
        backends,
        tie_breaker=tie_breaker or None,
        cache=_cache_option(cache),
        concurrency=_whole("concurrency", concurrency, 1),
        max_retries=_whole("max_retries", max_retries, 0),
        timeout=_positive("timeout", timeout),
        prompt=str(prompt) if prompt else None,
        min_votes=_whole("min_votes", min_votes, 0),
        max_retry_after=_positive("max_retry_after", max_retry_after),
        progress=_flag("progress", progress),
        seed=_whole("seed", seed, 0),
    )


def _cache_option(value: Any) -> Path | None:
    if value is False or (isinstance(value, str) and value.strip().lower() in {"off", "none", "false", "memory"}):
        return None
    if value in ("", None, True):
        return default_cache_path()
    return Path(str(value))


def _whole(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"labeler 'ensemble': option {name} must be a whole number >= {minimum}, got {value!r}")
    return value


def _positive(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise ConfigError(f"labeler 'ensemble': option {name} must be a number of seconds > 0, got {value!r}")
    return float(value)


def _flag(name: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"labeler 'ensemble': option {name} must be true or false, got {value!r}")
    return value
