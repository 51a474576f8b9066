"""``kv``: an Alpamayo-like VLA — vision tokens, a one-sentence CoT between markers, and a flow-matching
action head that cross-attends to the decoder's KV cache (vision + CoT).

The action head predicts longitudinal acceleration and path curvature at 10 Hz over 3 s by integrating a
learned velocity field from Gaussian noise (drawn from a ``torch.Generator`` pinned to the benchmark's
numpy stream) in a few Euler steps; the trajectory is the unicycle rollout of those controls from the
current speed. Because the head reads the cache of every decoder layer, whatever text sits between the
markers — generated or spliced — reaches the action.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F
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
    timestep_embedding,
)

ACCEL_SCALE = 3.0  # m/s² per unit of the head's normalised output
CURVATURE_SCALE = 0.1  # 1/m per unit


class FlowHead(nn.Module):
    """Flow-matching action expert: action chunks attend to each other and to every decoder layer's cache."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.chunk, self.steps = config.chunk, config.horizon_steps
        self.n_chunks = self.steps // self.chunk
        width, head_dim = config.head_width, config.hidden // config.heads
        self.kv_heads, self.head_dim = config.kv_heads, head_dim
        self.embed = nn.Linear(2 * self.chunk, width)
        self.position = nn.Parameter(torch.zeros(self.n_chunks, width))
        self.time = nn.Sequential(nn.Linear(width, width), nn.GELU(), nn.Linear(width, width))
        self.blocks = nn.ModuleList(_HeadBlock(width, self.kv_heads, head_dim) for _ in range(config.layers))
        self.out = nn.Sequential(nn.LayerNorm(width), nn.Linear(width, 2 * self.chunk))
        self.width = width

    def forward(self, x: torch.Tensor, t: torch.Tensor, kv: list[tuple[torch.Tensor, torch.Tensor]],
                key_mask: torch.Tensor | None) -> torch.Tensor:
        """Velocity of the flow at ``x`` ``(B, T, 2)`` and time ``t`` ``(B,)`` given the cache."""
        batch = x.shape[0]
        h = self.embed(x.reshape(batch, self.n_chunks, 2 * self.chunk)) + self.position
        h = h + self.time(timestep_embedding(t, self.width))[:, None]
        mask = None if key_mask is None else key_mask[:, None, None, :]
        for block, (keys, values) in zip(self.blocks, kv, strict=True):
            h = block(h, keys, values, mask)
        return self.out(h).reshape(batch, self.steps, 2)


class _HeadBlock(nn.Module):
    def __init__(self, width: int, kv_heads: int, head_dim: int):
        super().__init__()
        self.kv_heads, self.head_dim = kv_heads, head_dim
        self.norm1, self.norm2, self.norm3 = nn.LayerNorm(width), nn.LayerNorm(width), nn.LayerNorm(width)
        self.self_attn = nn.MultiheadAttention(width, 4, batch_first=True)
        self.query = nn.Linear(width, kv_heads * head_dim)
        self.cross_out = nn.Linear(kv_heads * head_dim, width)
        self.mlp = nn.Sequential(nn.Linear(width, 2 * width), nn.GELU(), nn.Linear(2 * width, width))

    def forward(self, h, keys, values, mask):
        a = self.norm1(h)
        h = h + self.self_attn(a, a, a, need_weights=False)[0]
        batch, n, _ = h.shape
        q = self.query(self.norm2(h)).reshape(batch, n, self.kv_heads, self.head_dim).transpose(1, 2)
        if keys.shape[0] != batch:  # one shared cache for several noise draws
            keys, values = keys.expand(batch, -1, -1, -1), values.expand(batch, -1, -1, -1)
        attended = F.scaled_dot_product_attention(q, keys, values, attn_mask=mask)
        h = h + self.cross_out(attended.transpose(1, 2).reshape(batch, n, -1))
        return h + self.mlp(self.norm3(h))


class KVNetwork(nn.Module):
    """Vision encoder + Llama decoder (built from a config) + flow-matching head."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        from transformers import LlamaForCausalLM

        self.config = config
        self.encoder = VisionEncoder(config.hidden)
        self.lm = LlamaForCausalLM(config.llama_config())
        self.head = FlowHead(config)

    def prefix_embeddings(self, images: torch.Tensor, ego: torch.Tensor) -> torch.Tensor:
        return self.encoder(images, ego)

    @torch.no_grad()
    def sample_controls(self, kv, key_mask, noise: torch.Tensor) -> torch.Tensor:
        """Integrate the flow from ``noise`` ``(B, T, 2)`` with Euler steps → normalised controls."""
        x, steps = noise, self.config.flow_steps
        for i in range(steps):
            t = torch.full((x.shape[0],), i / steps, device=x.device)
            x = x + self.head(x, t, kv, key_mask) / steps
        return x


def normalise_controls(controls: np.ndarray) -> np.ndarray:
    """Physical ``(…, T, 2)`` (m/s², 1/m) → the head's normalised units."""
    return np.asarray(controls) / np.array([ACCEL_SCALE, CURVATURE_SCALE])


def controls_to_trajectory(controls: np.ndarray, speed: float, dt: float) -> Trajectory:
    """Normalised ``(T, 2)`` (acceleration, curvature) → ego-frame waypoints by a unicycle rollout."""
    return rollout(controls[:, 0] * ACCEL_SCALE, controls[:, 1] * CURVATURE_SCALE, speed, dt)


def rollout(accel: np.ndarray, curvature: np.ndarray, speed: float, dt: float) -> Trajectory:
    """Acceleration (m/s²) and curvature (1/m) per step → waypoints (speed never goes below zero)."""
    x = y = heading = 0.0
    v = max(0.0, float(speed))
    xy = np.zeros((len(accel), 2))
    for k, (a, kappa) in enumerate(zip(accel, curvature, strict=True)):
        v_next = max(0.0, v + float(a) * dt)
        ds = 0.5 * (v + v_next) * dt
        heading_mid = heading + 0.5 * float(kappa) * ds
        x += ds * np.cos(heading_mid)
        y += ds * np.sin(heading_mid)
        heading += float(kappa) * ds
        v = v_next
        xy[k] = (x, y)
    times = dt * np.arange(1, len(accel) + 1)
    return Trajectory(times=times, xy=xy)


@dataclass
class KVState:
    """What a ``kv`` CoT carries: the decoder state after the end marker (the cache the head reads)."""

    decoder: toolkit.DecoderState
    token_ids: tuple[int, ...]


class KVModel(BundledModel):
    """The ``kv`` reference VLA (VLAModel and BatchedModel protocols). Options: ``splice_mode``
    (``sequential`` or ``prefill``), ``weights_dir`` (a folder with ``kv.safetensors`` & co.), ``threads``,
    ``device`` (``cpu`` by default; e.g. ``cuda``), ``temperature`` and ``top_p`` of its CoT sampling
    (Alpamayo's defaults, 0.6 and 0.98; ``temperature=0`` is greedy)."""

    name = "kv"
    default_sampling = (0.6, 0.98)

    network_class = KVNetwork

    def _setup(self, network: KVNetwork, codec: TextCodec, splice_mode: str) -> None:
        self.network, self.codec, self.splice_mode = network, codec, splice_mode
        self.config = network.config
        prefix = network.encoder.n_tokens
        self.cot_format = CoTFormat("sentence", max_tokens=self.config.context - prefix - 2)
        self.trajectory_spec = TrajectorySpec(self.config.horizon_steps / self.config.rate_hz, self.config.rate_hz)
        self._prefix_key: tuple | None = None
        self._prefix: toolkit.DecoderState | None = None

    # -- protocol ------------------------------------------------------------------------------------
    def reset(self, seed: int) -> None:
        """A new episode: forget the cached prefix and the tokens sampled in earlier episodes."""
        self._prefix_key, self._prefix = None, None
        self.token_memo.clear()

    def generate_cot(self, obs: Observation, rng: np.random.Generator) -> CoT:
        """A CoT between ``<cot>`` and ``</cot>``, sampled with the model's temperature and top-p (one draw
        from ``rng``, the pinned ``cot`` stream, per token; greedy at temperature 0)."""
        if self.device != "cpu":
            return self.generate_cot_batch([obs], [rng])[0]
        ids = self.codec.ids
        tokens, state = toolkit.generate_between_markers(
            self.network.lm, self.prefix_state(obs), ids["<cot>"], ids["</cot>"], self.config.max_cot_tokens,
            banned=self.codec.special_ids, pick=self.sampler.picker(rng))
        return CoT(text=self._remember(tokens), state=KVState(state, tuple(tokens)))

    def _remember(self, tokens: list[int]) -> str:
        """The text of sampled ``tokens``; a splice of that text will feed these very tokens."""
        text = self.codec.decode(tokens)
        self.token_memo.remember(text, tokens, self.codec.encode(text))
        return text

    def splice_cot(self, obs: Observation, text: str | dict[str, str], rng: np.random.Generator) -> CoT:
        """Re-encode ``text`` into the cache between the markers (sequential or prefill mode)."""
        if self.device != "cpu":
            return self.splice_cot_batch([obs], [text], [rng])[0]
        if not isinstance(text, str):
            raise ConfigError(f"model 'kv' writes one sentence; a splice needs one text, got slots "
                              f"{', '.join(text)}")
        tokens = self.token_memo.tokens(text, self.codec.encode)
        ids = self.codec.ids
        state = toolkit.splice_tokens(self.network.lm, self.prefix_state(obs), tokens, ids["<cot>"],
                                      ids["</cot>"], mode=self.splice_mode, what="model 'kv' splice text")
        return CoT(text=text, state=KVState(state, tuple(tokens)), spliced=True)

    # -- lockstep batches (BatchedModel) --------------------------------------------------------------
    def generate_cot_batch(self, observations: list[Observation], rngs: list[np.random.Generator]) -> list[CoT]:
        """Sampled CoTs for B observations, row i drawing from ``rngs[i]`` as it would alone: one
        vision-prefix pass and one decoder pass per token for all."""
        ids = self.codec.ids
        decoder = self._lockstep_prefix(observations)
        texts = batching.generate_lockstep(decoder, ids["<cot>"], ids["</cot>"], self.config.max_cot_tokens,
                                           banned=self.codec.special_ids, sampler=self.sampler, rngs=rngs)
        return [CoT(text=self._remember(t), state=KVState(decoder.row_state(i, t), tuple(t)))
                for i, t in enumerate(texts)]

    def splice_cot_batch(self, observations: list[Observation], texts: list[str],
                         rngs: list[np.random.Generator]) -> list[CoT]:
        """``splice_cot`` for B observations, column by column exactly as :meth:`generate_cot_batch` feeds
        them: splicing a batch's own CoTs gives bit-identical caches."""
        ids, token_lists = self.codec.ids, []
        for text in texts:
            if not isinstance(text, str):
                raise ConfigError(f"model 'kv' writes one sentence; a splice needs one text, got slots "
                                  f"{', '.join(text)}")
            token_lists.append(self.token_memo.tokens(text, self.codec.encode))
        decoder = self._lockstep_prefix(observations)
        batching.splice_lockstep(decoder, token_lists, ids["<cot>"], ids["</cot>"])
        return [CoT(text=text, state=KVState(decoder.row_state(i, t), tuple(t)), spliced=True)
                for i, (text, t) in enumerate(zip(texts, token_lists, strict=True))]

    def decode_action_batch(self, observations: list[Observation], cots: list[CoT],
                            rngs: list[np.random.Generator]) -> list[Trajectory]:
        """``decode_action`` for B (observation, CoT) pairs in one flow integration over a padded cache;
        row i's noise comes from ``rngs[i]`` exactly as alone."""
        states = [self._state_of(obs, cot).decoder for obs, cot in zip(observations, cots, strict=True)]
        kv, key_mask = batching.padded_cache(states)
        noise = torch.cat([self.noise(rng, 1) for rng in rngs]).to(self.device)
        controls = self.network.sample_controls(kv, key_mask, noise).cpu().numpy()
        dt = 1.0 / self.config.rate_hz
        return [controls_to_trajectory(c.astype(np.float64), obs.ego.speed, dt)
                for c, obs in zip(controls, observations, strict=True)]

    @torch.no_grad()
    def _lockstep_prefix(self, observations: list[Observation]) -> batching.LockstepDecoder:
        images = image_batch([o.image for o in observations]).to(self.device)
        ego = ego_features([o.ego.speed for o in observations], [o.command for o in observations]).to(self.device)
        return batching.LockstepDecoder.from_embeddings(self.network.lm, self.network.prefix_embeddings(images, ego),
                                                        self.codec.ids["<pad>"])

    def decode_action(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> Trajectory:
        """Sample controls with noise from ``rng`` (pinned), roll them out into waypoints."""
        if self.device != "cpu":
            return self.decode_action_batch([obs], [cot], [rng])[0]
        state = self._state_of(obs, cot)
        noise = self.noise(rng, 1)
        controls = self.network.sample_controls(state.decoder.keys_values(), None, noise)[0].numpy()
        return controls_to_trajectory(controls.astype(np.float64), obs.ego.speed, 1.0 / self.config.rate_hz)

    def state_digest(self, cot: CoT) -> str:
        """SHA-256 of the KV cache the action head reads (vision prefix + markers + CoT)."""
        if not isinstance(cot.state, KVState):
            raise ConfigError("this CoT was not produced by model 'kv' (no KV cache to digest)")
        return toolkit.kv_digest(cot.state.decoder)

    # -- extras --------------------------------------------------------------------------------------
    def count_tokens(self, text: str) -> int:
        """How many tokens ``text`` takes (the condition library matches repeat counts with it)."""
        return len(self.token_memo.tokens(text, self.codec.encode))

    def noise(self, rng: np.random.Generator, batch: int) -> torch.Tensor:
        """The flow's starting noise, one draw repeated over ``batch`` rows (same noise for every condition)."""
        generator = toolkit.torch_generator(rng)
        draw = torch.randn(1, self.config.horizon_steps, 2, generator=generator)
        return draw.expand(batch, -1, -1).contiguous()

    def decode_batch(self, obs: Observation, texts: list[str], rng: np.random.Generator) -> list[Trajectory]:
        """Trajectories for several spliced texts at once, over one shared vision-prefix cache.

        Every text gets the same pinned noise; results equal one-by-one prefill splices up to rounding.
        """
        ids = self.codec.ids
        batch = toolkit.splice_batch(self.network.lm, self.prefix_state(obs),
                                     [self.token_memo.tokens(t, self.codec.encode) for t in texts],
                                     ids["<cot>"], ids["</cot>"], ids["<pad>"], mode="prefill")
        noise = self.noise(rng, len(texts))
        controls = self.network.sample_controls(batch.keys_values(), batch.key_mask, noise).numpy()
        dt = 1.0 / self.config.rate_hz
        return [controls_to_trajectory(c.astype(np.float64), obs.ego.speed, dt) for c in controls]

    @torch.no_grad()
    def prefix_state(self, obs: Observation) -> toolkit.DecoderState:
        """A fresh fork of the observation's vision-prefix cache (computed once per observation)."""
        key = _observation_key(obs)
        if key != self._prefix_key:
            images = image_batch([obs.image])
            ego = ego_features([obs.ego.speed], [obs.command])
            embeds = self.network.prefix_embeddings(images, ego)
            self._prefix = toolkit.encode_prefix(self.network.lm, embeds)
            self._prefix_key = key
        return toolkit.fork(self._prefix)

    def _state_of(self, obs: Observation, cot: CoT) -> KVState:
        if isinstance(cot.state, KVState):
            return cot.state
        spliced = self.splice_cot(obs, cot.text, np.random.default_rng(0))
        return spliced.state


def _observation_key(obs: Observation) -> tuple:
    import hashlib

    image = np.ascontiguousarray(obs.image)
    return (obs.scenario_id, obs.step, obs.time, obs.ego.speed, obs.command,
            hashlib.blake2b(image.tobytes(), digest_size=16).hexdigest(), image.shape)
