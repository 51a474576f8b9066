"""``qa``: an ORION-like VLA — three QA rounds (scene; critical objects with BEV coordinates; decision)
appended to the context after the vision tokens, then a planning token whose final hidden state feeds a
planner that outputs waypoints over 3 s.

The planner reads the planning token's hidden state together with a compact read-out of the vision
tokens (computed before any text, so no text reaches the planner through it): a three-layer decoder of
width 64 does not route enough of the scene into one token for the planner to stop on vision alone, and
the recipe asks for a planner that relies on vision. Text still reaches the plan through the planning
token — which is what the intervention measures. It predicts acceleration and curvature per step and
rolls them out from the current speed into waypoints (the same unicycle rollout as ``kv``): a small
planner that predicts positions directly drifts sideways when it hedges between stopping and going.

The planner is stochastic, as a real planner's sampling is: it predicts a mean and a standard deviation
per control and step (a heteroscedastic Gaussian, the deviation learnt by maximum likelihood from how far
the expert's controls scatter around the mean for what the model sees), and ``decode_action`` draws the
controls from it with standard normal noise from the pinned ``action`` stream — the same noise for the
baseline and every spliced condition of a step, different noise for another seed. The answers are sampled
too (ORION's temperature 0.1 and top-p 0.75 by default), from the pinned ``cot`` stream.

Each round feeds its question (one prefill pass, identical for generation and splicing) and then the
answer between ``<a>`` and ``</a>``; splicing replaces the answers (intercepting the rounds, as the paper
did for ORION). The planner reads only the planning token's hidden state, so :meth:`QAModel.state_digest`
hashes that vector together with the cache.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from vdb_adapter_transformers import toolkit
from vladrivebench import ConfigError, CoT, CoTFormat, Observation, Trajectory, TrajectorySpec

from . import batching
from .common import (
    BundledModel,
    ModelConfig,
    TextCodec,
    VisionEncoder,
    ego_features,
    image_batch,
)
from .kv_model import _observation_key, controls_to_trajectory

SLOTS = ("scene", "objects", "decision")
VISION_READOUT = 8  # features per vision token the planner reads
LOG_STD_RANGE = (-7.0, 0.0)
"""Bounds of the planner's log standard deviation (normalised control units: 1 is 3 m/s² or 0.1 1/m)."""
QUESTIONS = {
    "scene": "Q: Describe the driving scene.",
    "objects": "Q: Which objects matter, and where are they?",
    "decision": "Q: What should the ego vehicle do?",
}


class QANetwork(nn.Module):
    """Vision encoder + Llama decoder (built from a config) + planner on the planning token."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        from transformers import LlamaForCausalLM

        self.config = config
        self.encoder = VisionEncoder(config.hidden)
        self.lm = LlamaForCausalLM(config.llama_config())
        width = config.head_width * 4
        self.plan_norm = nn.LayerNorm(config.hidden)
        self.vision_readout = nn.Linear(config.hidden, VISION_READOUT)
        self.planner = nn.Sequential(
            nn.Linear(config.hidden + self.encoder.n_tokens * VISION_READOUT, width), nn.GELU(),
            nn.Linear(width, width), nn.GELU(), nn.Linear(width, config.horizon_steps * 4),
        )

    def prefix_embeddings(self, images: torch.Tensor, ego: torch.Tensor) -> torch.Tensor:
        return self.encoder(images, ego)

    def plan_distribution(self, hidden: torch.Tensor, vision: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Planning-token hidden states ``(B, hidden)`` and vision tokens ``(B, n, hidden)`` → mean and log
        standard deviation ``(B, T, 2)`` each of the normalised controls (acceleration, curvature)."""
        features = torch.cat([self.plan_norm(hidden), self.vision_readout(vision).flatten(1)], dim=-1)
        out = self.planner(features).reshape(hidden.shape[0], self.config.horizon_steps, 4)
        low, high = LOG_STD_RANGE  # a smooth bound: the deviation's gradient never vanishes at an edge
        return out[..., :2], low + (high - low) * torch.sigmoid(out[..., 2:])

    def plan(self, hidden: torch.Tensor, vision: torch.Tensor, noise: torch.Tensor | None = None,
             scale: float = 1.0) -> torch.Tensor:
        """Normalised controls ``(B, T, 2)`` drawn as mean + ``scale`` · deviation · ``noise`` (standard
        normal, ``(B, T, 2)``; the mean without it). ``controls_to_trajectory`` makes them waypoints."""
        mean, log_std = self.plan_distribution(hidden, vision)
        if noise is None or scale == 0.0:
            return mean
        return mean + scale * torch.exp(log_std) * noise.to(mean.device)


@dataclass
class QAState:
    """What a ``qa`` CoT carries: the decoder state after the planning token, each slot's token ids and
    the observation's vision tokens (the planner's second input)."""

    decoder: toolkit.DecoderState
    token_ids: dict[str, tuple[int, ...]]
    vision: torch.Tensor


class QAModel(BundledModel):
    """The ``qa`` reference VLA (VLAModel and BatchedModel protocols). Options: ``splice_mode``,
    ``weights_dir``, ``threads``, ``device`` (``cpu`` by default; e.g. ``cuda``), ``temperature`` and
    ``top_p`` of its answer sampling (ORION's 0.1 and 0.75; ``temperature=0`` is greedy) and ``plan_noise``
    (the scale of the planner's learnt deviation, default 1; 0 plans the mean)."""

    name = "qa"
    default_sampling = (0.1, 0.75)
    plan_noise = 1.0

    def __init__(self, splice_mode: str = "sequential", weights_dir: str | None = None, threads: int = 1,
                 device: str = "cpu", temperature: float | None = None, top_p: float | None = None,
                 plan_noise: float = 1.0):
        self.plan_noise = checked_plan_noise(plan_noise)
        super().__init__(splice_mode=splice_mode, weights_dir=weights_dir, threads=threads, device=device,
                         temperature=temperature, top_p=top_p)

    network_class = QANetwork

    def _setup(self, network: QANetwork, codec: TextCodec, splice_mode: str) -> None:
        self.network, self.codec, self.splice_mode = network, codec, splice_mode
        self.config = network.config
        self.questions = {slot: codec.encode(QUESTIONS[slot]) for slot in SLOTS}
        fixed = network.encoder.n_tokens + sum(len(q) + 2 for q in self.questions.values()) + 1
        self.cot_format = CoTFormat("slots", slots=SLOTS, max_tokens=self.config.context - fixed)
        self.trajectory_spec = TrajectorySpec(self.config.horizon_steps / self.config.rate_hz, self.config.rate_hz)
        self._prefix_key: tuple | None = None
        self._prefix: toolkit.DecoderState | None = None
        self._vision: torch.Tensor | None = None

    # -- protocol ------------------------------------------------------------------------------------
    def reset(self, seed: int) -> None:
        """A new episode: forget the cached prefix and the tokens sampled in earlier episodes."""
        self._prefix_key, self._prefix = None, None
        self.token_memo.clear()

    def generate_cot(self, obs: Observation, rng: np.random.Generator) -> CoT:
        """Three QA rounds, each answer sampled (one draw from ``rng``, the pinned ``cot`` stream, per
        token; greedy at temperature 0), then the planning token."""
        if self.device != "cpu":
            return self.generate_cot_batch([obs], [rng])[0]
        ids, lm = self.codec.ids, self.network.lm
        state = self.prefix_state(obs)
        slots, token_ids = {}, {}
        pick = self.sampler.picker(rng)
        for slot in SLOTS:
            state = toolkit.feed_tokens(lm, state, self.questions[slot], mode="prefill")
            tokens, state = toolkit.generate_between_markers(lm, state, ids["<a>"], ids["</a>"],
                                                             self.config.max_cot_tokens,
                                                             banned=self.codec.special_ids, pick=pick)
            slots[slot], token_ids[slot] = self._remember(tokens), tuple(tokens)
        state = toolkit.feed_token(lm, state, ids["<plan>"])
        return CoT(text=CoT.join_slots(slots), slots=slots, state=QAState(state, token_ids, self._vision))

    def splice_cot(self, obs: Observation, text: str | dict[str, str], rng: np.random.Generator) -> CoT:
        """Replace the three answers with ``text`` (slot → text), then the planning token."""
        _check_slots(text)
        if self.device != "cpu":
            return self.splice_cot_batch([obs], [text], [rng])[0]
        ids, lm = self.codec.ids, self.network.lm
        state = self.prefix_state(obs)
        token_ids = {}
        for slot in SLOTS:
            state = toolkit.feed_tokens(lm, state, self.questions[slot], mode="prefill")
            tokens = self.token_memo.tokens(text[slot], self.codec.encode)
            remaining = self.config.context - state.length - 2 - self._after(slot)
            if len(tokens) > remaining:
                raise toolkit.SpliceTooLongError(
                    f"model 'qa' splice text for slot {slot!r} is {len(tokens)} tokens; with the vision "
                    f"prefix, questions and earlier answers the context of {self.config.context} positions "
                    f"leaves room for at most {max(remaining, 0)} tokens")
            state = toolkit.splice_tokens(lm, state, tokens, ids["<a>"], ids["</a>"], mode=self.splice_mode,
                                          what=f"model 'qa' splice text for slot {slot!r}")
            token_ids[slot] = tuple(tokens)
        state = toolkit.feed_token(lm, state, ids["<plan>"])
        slots = {slot: text[slot] for slot in SLOTS}
        return CoT(text=CoT.join_slots(slots), slots=slots, state=QAState(state, token_ids, self._vision),
                   spliced=True)

    def decode_action(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> Trajectory:
        """Waypoints from the planning token's hidden state: controls drawn from the planner's Gaussian with
        noise from ``rng`` (the pinned ``action`` stream)."""
        if self.device != "cpu":
            return self.decode_action_batch([obs], [cot], [rng])[0]
        state = self._state_of(obs, cot)
        with torch.no_grad():
            controls = self.network.plan(state.decoder.last_hidden, state.vision, self.noise(rng),
                                         self.plan_noise)[0].numpy().astype(np.float64)
        return controls_to_trajectory(controls, obs.ego.speed, 1.0 / self.config.rate_hz)

    def noise(self, rng: np.random.Generator) -> torch.Tensor:
        """The planner's standard normal noise ``(1, T, 2)`` for one step, from one draw of ``rng``."""
        generator = toolkit.torch_generator(rng)
        return torch.randn(1, self.config.horizon_steps, 2, generator=generator)

    def _remember(self, tokens: list[int]) -> str:
        """The text of sampled ``tokens``; a splice of that text will feed these very tokens."""
        text = self.codec.decode(tokens)
        self.token_memo.remember(text, tokens, self.codec.encode(text))
        return text

    # -- lockstep batches (BatchedModel) --------------------------------------------------------------
    def generate_cot_batch(self, observations: list[Observation], rngs: list[np.random.Generator]) -> list[CoT]:
        """Three sampled QA rounds for B observations in lockstep (one pass per question, one per token),
        row i drawing from ``rngs[i]`` as it would alone."""
        ids = self.codec.ids
        decoder, vision = self._lockstep_prefix(observations)
        answers: dict[str, list[list[int]]] = {}
        for slot in SLOTS:
            decoder.feed_block(self.questions[slot])
            answers[slot] = batching.generate_lockstep(decoder, ids["<a>"], ids["</a>"], self.config.max_cot_tokens,
                                                       banned=self.codec.special_ids, sampler=self.sampler,
                                                       rngs=rngs)
        decoder.feed([ids["<plan>"]] * decoder.rows)
        return [self._batch_cot(decoder, vision, i, {s: answers[s][i] for s in SLOTS}, None)
                for i in range(decoder.rows)]

    def splice_cot_batch(self, observations: list[Observation], texts: list[dict[str, str]],
                         rngs: list[np.random.Generator]) -> list[CoT]:
        """``splice_cot`` for B observations, fed exactly as :meth:`generate_cot_batch` feeds its rounds:
        splicing a batch's own answers gives bit-identical states."""
        for text in texts:
            _check_slots(text)
        ids = self.codec.ids
        tokens = [{slot: self.token_memo.tokens(text[slot], self.codec.encode) for slot in SLOTS} for text in texts]
        decoder, vision = self._lockstep_prefix(observations)
        for slot in SLOTS:
            decoder.feed_block(self.questions[slot])
            batching.splice_lockstep(decoder, [t[slot] for t in tokens], ids["<a>"], ids["</a>"])
        decoder.feed([ids["<plan>"]] * decoder.rows)
        return [self._batch_cot(decoder, vision, i, tokens[i], texts[i]) for i in range(decoder.rows)]

    def decode_action_batch(self, observations: list[Observation], cots: list[CoT],
                            rngs: list[np.random.Generator]) -> list[Trajectory]:
        """``decode_action`` for B pairs with one planner call; row i's noise comes from ``rngs[i]``."""
        states = [self._state_of(obs, cot) for obs, cot in zip(observations, cots, strict=True)]
        hidden = torch.cat([s.decoder.last_hidden for s in states])
        vision = torch.cat([s.vision for s in states])
        noise = torch.cat([self.noise(rng) for rng in rngs])
        with torch.no_grad():
            controls = self.network.plan(hidden, vision, noise, self.plan_noise).cpu().numpy().astype(np.float64)
        dt = 1.0 / self.config.rate_hz
        return [controls_to_trajectory(c, obs.ego.speed, dt) for c, obs in zip(controls, observations, strict=True)]

    def _batch_cot(self, decoder: batching.LockstepDecoder, vision: torch.Tensor, row: int,
                   token_ids: dict[str, list[int]], spliced: dict[str, str] | None) -> CoT:
        slots = dict(spliced) if spliced is not None else {s: self._remember(token_ids[s]) for s in SLOTS}
        fed = tuple(t for s in SLOTS for t in token_ids[s])
        state = QAState(decoder.row_state(row, fed), {s: tuple(token_ids[s]) for s in SLOTS}, vision[row:row + 1])
        return CoT(text=CoT.join_slots(slots), slots=slots, state=state, spliced=spliced is not None)

    @torch.no_grad()
    def _lockstep_prefix(self, observations: list[Observation]) -> tuple[batching.LockstepDecoder, torch.Tensor]:
        images = image_batch([o.image for o in observations]).to(self.device)
        ego = ego_features([o.ego.speed for o in observations], [o.command for o in observations]).to(self.device)
        embeds = self.network.prefix_embeddings(images, ego)
        return batching.LockstepDecoder.from_embeddings(self.network.lm, embeds, self.codec.ids["<pad>"]), embeds

    def state_digest(self, cot: CoT) -> str:
        """SHA-256 of the cache and of the planner's inputs (planning token's hidden state, vision tokens)."""
        if not isinstance(cot.state, QAState):
            raise ConfigError("this CoT was not produced by model 'qa' (no decoder state to digest)")
        return toolkit.kv_digest(cot.state.decoder, extra=[cot.state.decoder.last_hidden, cot.state.vision])

    # -- extras --------------------------------------------------------------------------------------
    def count_tokens(self, text: str) -> int:
        return len(self.token_memo.tokens(text, self.codec.encode))

    @torch.no_grad()
    def prefix_state(self, obs: Observation) -> toolkit.DecoderState:
        key = _observation_key(obs)
        if key != self._prefix_key:
            embeds = self.network.prefix_embeddings(image_batch([obs.image]),
                                                    ego_features([obs.ego.speed], [obs.command]))
            self._prefix = toolkit.encode_prefix(self.network.lm, embeds)
            self._vision = embeds
            self._prefix_key = key
        return toolkit.fork(self._prefix)

    def _after(self, slot: str) -> int:
        """Positions still needed after ``slot``'s answer: later questions, their markers, the plan token."""
        later = SLOTS[SLOTS.index(slot) + 1 :]
        return sum(len(self.questions[s]) + 2 for s in later) + 1

    def _state_of(self, obs: Observation, cot: CoT) -> QAState:
        if isinstance(cot.state, QAState):
            return cot.state
        return self.splice_cot(obs, cot.slots, np.random.default_rng(0)).state


def checked_plan_noise(value: object) -> float:
    """The ``plan_noise`` option (a number from 0 to 10), else a one-line :class:`ConfigError`."""
    import math

    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) \
            or not 0.0 <= value <= 10.0:
        raise ConfigError(f"model 'qa' option plan_noise must be a number between 0 (the planner's mean) and 10, "
                          f"got {value!r}")
    return float(value)


def _check_slots(text: object) -> None:
    if isinstance(text, str) or not isinstance(text, dict) or set(text) != set(SLOTS):
        got = "one text" if isinstance(text, str) else f"slots {', '.join(text) or 'none'}"
        raise ConfigError(f"model 'qa' takes slots {', '.join(SLOTS)}; the splice gave {got}")
