"""The Alpamayo adapter: prompt, CoT, splice, action expert and trajectory (the VLAModel protocol).

Per step: the chat prompt (system turn; user turn with one labelled group of frames per camera, the
trajectory-history tokens, the route or command and the instruction; the assistant turn) is run once
through Qwen3-VL with positions from the model's own multimodal RoPE index; the assistant turn starts at
``<|cot_start|>`` and the CoT runs until ``<|cot_end|>``, then ``<|traj_future_start|>`` is fed. The action
expert attends non-causally over 64 action tokens to that cache, at the positions that follow it (cache
length + rope delta), and flow matching integrates its velocity field in 10 Euler steps from noise drawn
from the pinned RNG. The 64 (acceleration, curvature) pairs at 10 Hz are rolled out into 6.4 s of waypoints.
"""

from __future__ import annotations

import copy
import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from vdb_adapter_transformers import lockstep, toolkit
from vladrivebench import ConfigError, CoT, CoTFormat, Observation, Trajectory, TrajectorySpec

from .backbone import (
    ACTION_DIMS,
    ACTION_TOKENS,
    COT_END,
    COT_START,
    FUTURE_START,
    HISTORY,
    HISTORY_END,
    HISTORY_POSES,
    HISTORY_START,
    HISTORY_TOKENS,
    Backbone,
)

#: Alpamayo's four cameras (names of NVIDIA's PhysicalAI-AV data), in prompt order.
CAMERAS = ("camera_front_wide_120fov", "camera_front_tele_30fov", "camera_cross_left_120fov",
           "camera_cross_right_120fov")
CAMERA_ALIASES = {"front_wide": CAMERAS[0], "front_tele": CAMERAS[1], "cross_left": CAMERAS[2],
                  "cross_right": CAMERAS[3]}
SYSTEM = "You are a driving assistant that generates safe and accurate actions."
INSTRUCTION = "output the chain-of-thought reasoning of the driving process, then output the future trajectory."
RATE_HZ, FLOW_STEPS = 10.0, 10
SPLICE_WHAT = "model 'alpamayo' splice text"
ACCEL_LIMITS, CURVATURE_LIMIT = (-8.0, 4.0), 0.25


def camera_names(spec: str) -> tuple[str, ...]:
    """Camera names from a comma-separated option (full names or the short aliases)."""
    names = [n.strip() for n in str(spec).split(",") if n.strip()]
    if not names:
        raise ConfigError("model 'alpamayo' option cameras is empty; expected some of: " + ", ".join(CAMERA_ALIASES))
    out = []
    for name in names:
        full = CAMERA_ALIASES.get(name, name)
        if full not in CAMERAS:
            raise ConfigError(f"model 'alpamayo' option cameras: camera {name!r} is not one the model knows; "
                              f"expected some of: {', '.join(CAMERA_ALIASES)} (or {', '.join(CAMERAS)})")
        out.append(full)
    return tuple(out)


def parse_resolution(spec: str, minimum: int) -> tuple[int, int]:
    """``"HxW"`` → ``(H, W)``, each side at least ``minimum`` pixels (the vision encoder's merged patch)."""
    try:
        height, width = (int(v) for v in str(spec).lower().split("x"))
    except ValueError:
        raise ConfigError(f"model 'alpamayo' option resolution={spec}: expected HEIGHTxWIDTH in pixels, "
                          f"e.g. 320x576") from None
    if min(height, width) < minimum:
        raise ConfigError(f"model 'alpamayo' option resolution={spec}: too small for the vision encoder; each "
                          f"side must be at least {minimum} pixels (patch size × merge size)")
    return height, width


@dataclass
class AlpamayoState:
    """What an Alpamayo CoT carries: the VLM state after ``<|traj_future_start|>`` (the cache the expert
    reads) and the processor outputs of its prefix (for the fidelity check)."""

    decoder: toolkit.DecoderState
    inputs: Mapping[str, torch.Tensor]


class AlpamayoModel:
    """The Alpamayo 1 / 1.5 architecture as a VLADriveBench model (VLAModel, BatchedModel, ConditionBatch,
    TokenCounter, FidelityCheck)."""

    def __init__(self, backbone: Backbone, cameras: Sequence[str], frames: int, resolution: tuple[int, int],
                 max_cot_tokens: int, splice_mode: str, device: str = "cpu"):
        self.backbone, self.cameras, self.frames = backbone, tuple(cameras), int(frames)
        self.resolution, self.max_cot_tokens, self.splice_mode = resolution, int(max_cot_tokens), splice_mode
        self.device = device
        self.fidelity_tolerance = 1e-4 if _dtype(backbone) == torch.float32 else 5e-2
        b = backbone
        self.start_id, self.end_id, self.future_id = b.token_id(COT_START), b.token_id(COT_END), b.token_id(FUTURE_START)
        self.banned = self._banned_ids()
        limit = toolkit.context_limit(b.vlm) - self._prefix_bound() - 3 - ACTION_TOKENS
        if limit < 1:
            raise ConfigError(f"model 'alpamayo': {len(self.cameras)} cameras × {self.frames} frames at "
                              f"{resolution[0]}x{resolution[1]} leave no room for a CoT in the context of "
                              f"{toolkit.context_limit(b.vlm)} positions; use fewer cameras, frames or pixels")
        self.cot_format = CoTFormat("sentence", max_tokens=limit)
        self.trajectory_spec = TrajectorySpec(ACTION_TOKENS / RATE_HZ, RATE_HZ)
        self._prefix_key: tuple | None = None
        self._prefix: tuple[toolkit.DecoderState, dict] | None = None
        self._batch_key: tuple | None = None
        self._batch_rows: dict[tuple, tuple[toolkit.DecoderState, dict]] = {}

    # -- protocol ------------------------------------------------------------------------------------------
    def reset(self, seed: int) -> None:
        """A new episode: forget the memo of the last observation's prompt cache (the batch memo of
        :meth:`prefix_rows` depends on its call alone and may stay)."""
        self._prefix_key, self._prefix = None, None

    def generate_cot(self, obs: Observation, rng: np.random.Generator) -> CoT:
        """Greedy CoT from ``<|cot_start|>`` until ``<|cot_end|>`` (greedy decoding draws nothing from ``rng``)."""
        prefix, inputs = self.prefix_state(obs)
        tokens, state = toolkit.generate_between_markers(self.backbone.vlm, prefix, self.start_id, self.end_id,
                                                         self.max_cot_tokens, banned=self.banned)
        state = toolkit.feed_token(self.backbone.vlm, state, self.future_id)
        return CoT(text=self.backbone.tokenizer.decode(tokens), state=AlpamayoState(state, inputs))

    def splice_cot(self, obs: Observation, text: str | dict[str, str], rng: np.random.Generator) -> CoT:
        """The state the model would hold had it written ``text`` itself (an empty text is the empty splice)."""
        prefix, inputs = self.prefix_state(obs)
        state = toolkit.splice_tokens(self.backbone.vlm, prefix, self.splice_ids(text), self.start_id, self.end_id,
                                      mode=self.splice_mode, what=SPLICE_WHAT)
        state = toolkit.feed_token(self.backbone.vlm, state, self.future_id)
        return CoT(text=text, state=AlpamayoState(state, inputs), spliced=True)

    def decode_action(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> Trajectory:
        """Flow matching over the expert from pinned noise, then the rollout of the controls."""
        state = self._state_of(obs, cot)
        controls = self.sample_controls(state.decoder, toolkit.torch_generator(rng))
        return controls_to_trajectory(controls, obs.ego.speed, 1.0 / RATE_HZ)

    # -- lockstep batches (BatchedModel) and conditions over one prefix (ConditionBatch) ---------------------
    def generate_cot_batch(self, observations: Sequence[Observation], rngs: Sequence[np.random.Generator]
                           ) -> list[CoT]:
        """Greedy CoTs for B observations in lockstep: the distinct observations' prompts, with all their
        frames through the vision tower at once, in one prefill (:meth:`prefix_rows`), then one Qwen3-VL
        pass per token for every row, each row at its own multimodal-RoPE positions."""
        decoder, inputs = self._lockstep_prefix(observations)
        texts = lockstep.generate_lockstep(decoder, self.start_id, self.end_id, self.max_cot_tokens,
                                           banned=self.banned)
        decoder.feed([self.future_id] * decoder.rows)
        return [CoT(text=self.backbone.tokenizer.decode(t), state=self._row_state(decoder, i, t, inputs[i]))
                for i, t in enumerate(texts)]

    def splice_cot_batch(self, observations: Sequence[Observation], texts: Sequence[str],
                         rngs: Sequence[np.random.Generator]) -> list[CoT]:
        """``splice_cot`` for B observations, fed column by column exactly as :meth:`generate_cot_batch`
        feeds its own tokens (whatever :attr:`splice_mode`): splicing a batch's own CoTs back gives
        bit-identical caches."""
        token_lists = [self.splice_ids(text) for text in texts]
        decoder, inputs = self._lockstep_prefix(observations)
        for length, tokens in zip(decoder.lengths.tolist(), token_lists, strict=True):
            toolkit.check_splice_fits(self.backbone.vlm, int(length), len(tokens) + 1, SPLICE_WHAT)
        lockstep.splice_lockstep(decoder, token_lists, self.start_id, self.end_id)
        decoder.feed([self.future_id] * decoder.rows)
        return [CoT(text=text, state=self._row_state(decoder, i, t, inputs[i]), spliced=True)
                for i, (text, t) in enumerate(zip(texts, token_lists, strict=True))]

    def decode_action_batch(self, observations: Sequence[Observation], cots: Sequence[CoT],
                            rngs: Sequence[np.random.Generator]) -> list[Trajectory]:
        """``decode_action`` for B (observation, CoT) pairs in one flow integration: the expert attends over
        the rows' caches right-padded into one (padding masked), each row at its own positions, row i's
        noise drawn from ``rngs[i]`` as alone."""
        states = [self._state_of(obs, cot).decoder for obs, cot in zip(observations, cots, strict=True)]
        layers, key_mask = lockstep.padded_cache(states)
        positions = torch.cat([s.next_position_ids(ACTION_TOKENS) for s in states], dim=-2)
        noise = torch.cat([self.noise(toolkit.torch_generator(rng)) for rng in rngs])
        controls = self.integrate_flow(lockstep.cache_of(layers), key_mask, positions, noise)
        return [controls_to_trajectory(c, obs.ego.speed, 1.0 / RATE_HZ)
                for c, obs in zip(controls, observations, strict=True)]

    def decode_batch(self, obs: Observation, texts: Sequence[str], rng: np.random.Generator) -> list[Trajectory]:
        """One trajectory per spliced text over the observation's one shared prompt cache (its vision prefix
        computed once): the texts spliced together (:func:`toolkit.splice_batch`), the expert run once
        for all, every text with the same pinned noise. Equal to one-by-one splices up to rounding."""
        prefix, _ = self.prefix_state(obs)
        batch = toolkit.splice_batch(self.backbone.vlm, prefix, [self.splice_ids(t) for t in texts], self.start_id,
                                     self.end_id, self.backbone.tokenizer.pad_token_id, mode=self.splice_mode,
                                     after=[self.future_id])
        lengths = batch.key_mask.sum(dim=1)
        positions = (lengths + batch.rope_deltas.view(-1)).view(-1, 1) + torch.arange(ACTION_TOKENS, device=lengths.device)
        noise = self.noise(toolkit.torch_generator(rng)).expand(len(texts), -1, -1)
        controls = self.integrate_flow(batch.cache, batch.key_mask, positions.unsqueeze(0).expand(3, -1, -1), noise)
        return [controls_to_trajectory(c, obs.ego.speed, 1.0 / RATE_HZ) for c in controls]

    def state_digest(self, cot: CoT) -> str:
        """SHA-256 of the VLM cache the expert reads (prefix, markers, CoT, ``<|traj_future_start|>``)."""
        if not isinstance(cot.state, AlpamayoState):
            raise ConfigError("this CoT was not produced by model 'alpamayo' (no KV cache to digest)")
        return toolkit.kv_digest(cot.state.decoder)

    # -- capabilities ------------------------------------------------------------------------------------
    def count_tokens(self, text: str) -> int:
        """How many tokens ``text`` takes in the CoT."""
        return len(self.encode(text))

    def fidelity_check(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> tuple[float, float]:
        """The CoT's cache against Qwen3-VL's own forward pass over prefix + the same tokens (positions by
        the model), and the largest waypoint distance between the trajectories decoded from each with
        the same draw of ``rng``."""
        state = self._state_of(obs, cot)
        native = toolkit.native_state(self.backbone.vlm, state.inputs, state.decoder.tokens)
        cache_diff = toolkit.cache_difference(state.decoder, native)
        twin = copy.deepcopy(rng)
        ours = self.sample_controls(state.decoder, toolkit.torch_generator(rng))
        theirs = self.sample_controls(native, toolkit.torch_generator(twin))
        dt = 1.0 / RATE_HZ
        a = controls_to_trajectory(ours, obs.ego.speed, dt).xy
        b = controls_to_trajectory(theirs, obs.ego.speed, dt).xy
        return cache_diff, float(np.max(np.linalg.norm(a - b, axis=1)))

    # -- the parts -----------------------------------------------------------------------------------------
    def encode(self, text: str) -> list[int]:
        return [int(t) for t in self.backbone.tokenizer(text, add_special_tokens=False)["input_ids"]]

    def splice_ids(self, text: Any) -> list[int]:
        """The token ids of a splice text (one sentence; slots are refused in one line)."""
        if not isinstance(text, str):
            raise ConfigError(f"model 'alpamayo' writes one sentence; a splice needs one text, got slots "
                              f"{', '.join(text)}")
        return self.encode(text)

    def noise(self, generator: torch.Generator) -> torch.Tensor:
        """The flow's starting noise ``(1, 64, 2)``, drawn from ``generator`` on the CPU (same on every device)."""
        return torch.randn(1, ACTION_TOKENS, ACTION_DIMS, generator=generator)

    @torch.no_grad()
    def sample_controls(self, decoder: toolkit.DecoderState, generator: torch.Generator) -> np.ndarray:
        """(acceleration m/s², curvature 1/m) × 64: 10 Euler steps of the expert's velocity field from
        noise drawn from ``generator``, the expert attending to ``decoder``'s cache without a causal mask."""
        positions = decoder.next_position_ids(ACTION_TOKENS)
        return self.integrate_flow(decoder.cache, None, positions, self.noise(generator))[0]

    @torch.no_grad()
    def integrate_flow(self, cache: Any, key_mask: torch.Tensor | None, positions: torch.Tensor,
                       noise: torch.Tensor) -> np.ndarray:
        """Controls ``(B, 64, 2)`` from noise ``(B, 64, 2)``: the expert's 64 action tokens of each row at
        ``positions`` (``(3, B, 64)``) attend, without a causal mask, to that row's cache positions where
        ``key_mask`` ``(B, length)`` is true (all when it is ``None``) and to one another. The expert's
        keys are cropped off the cache after every Euler step."""
        b = self.backbone
        dtype = _dtype(b)
        x = noise.to(self.device, dtype)
        rows, length = x.shape[0], cache.get_seq_length()
        mask = torch.zeros(rows, 1, ACTION_TOKENS, length + ACTION_TOKENS, dtype=dtype, device=self.device)
        if key_mask is not None:
            hidden_keys = ~key_mask.to(self.device)[:, None, None, :]
            mask[..., :length] = mask[..., :length].masked_fill(hidden_keys, torch.finfo(dtype).min)
        positions = positions.to(self.device)
        for k in range(FLOW_STEPS):
            t = torch.full((rows,), k / FLOW_STEPS, dtype=dtype, device=self.device)
            hidden = b.expert(inputs_embeds=b.action_in(x, t), position_ids=positions, cache=cache,
                              attention_mask=mask, use_cache=True).last_hidden_state
            cache.crop(-ACTION_TOKENS)  # the expert's own keys never stay in the VLM's cache
            x = x + b.action_out(hidden) / FLOW_STEPS
        actions = x.float().cpu().numpy().astype(np.float64)
        accel = np.clip(actions[..., 0] * b.accel_scale, *ACCEL_LIMITS)
        curvature = np.clip(actions[..., 1] * b.curvature_scale, -CURVATURE_LIMIT, CURVATURE_LIMIT)
        return np.stack([accel, curvature], axis=-1)

    @torch.no_grad()
    def prefix_state(self, obs: Observation) -> tuple[toolkit.DecoderState, dict]:
        """A fresh fork of the observation's prompt cache (computed once per observation) and its inputs."""
        frames = self.camera_frames(obs)
        key = _observation_key(obs, frames)
        if key != self._prefix_key:
            inputs = self.prompt_inputs(obs, frames)
            self._prefix = (toolkit.encode_inputs(self.backbone.vlm, inputs), inputs)
            self._prefix_key = key
        state, inputs = self._prefix
        return toolkit.fork(state), inputs

    def prefix_rows(self, observations: Sequence[Observation]) -> list[tuple[toolkit.DecoderState, dict]]:
        """Each observation's prompt cache (batch 1, never to be fed) and processor inputs.

        The distinct observations of the call, in order, go through Qwen3-VL in one batched prefill
        (:func:`lockstep.encode_inputs_batch`: every frame of every row through the vision tower at once).
        The result depends only on the call's list of observations — never on earlier calls — so the same
        list always gets the same bits: the memo keeps only the last list's rows (a step's generation, its
        selfsplice and its conditions share them; a model state as large as a batch's prompts is kept once).
        """
        framesets = [self.camera_frames(obs) for obs in observations]
        keys = [_observation_key(obs, frames) for obs, frames in zip(observations, framesets, strict=True)]
        if tuple(keys) != self._batch_key:
            self._batch_key, self._batch_rows = None, {}  # free the old rows before the new prefill
            first = {key: i for i, key in reversed(list(enumerate(keys)))}
            distinct = list(dict.fromkeys(keys))
            inputs = [self.prompt_inputs(observations[first[k]], framesets[first[k]]) for k in distinct]
            states = lockstep.encode_inputs_batch(self.backbone.vlm, inputs)
            self._batch_key, self._batch_rows = tuple(keys), dict(zip(distinct, zip(states, inputs, strict=True), strict=True))
        return [self._batch_rows[key] for key in keys]

    def camera_frames(self, obs: Observation) -> dict[str, list[np.ndarray]]:
        """``frames`` images per camera, oldest first, resized to the model's resolution.

        Reads ``obs.cameras`` (name → frames) when the observation has it; a camera it lacks — and every
        camera of an observation with only ``obs.image`` — gets the front image, replicated over the frames.
        """
        rig = getattr(obs, "cameras", None) or {}
        out = {}
        for name in self.cameras:
            found = _lookup(rig, name)
            images = _frame_list(found) if found is not None else [obs.image]
            images = ([images[0]] * (self.frames - len(images)) + images)[-self.frames:]
            out[name] = [_resize(image, self.resolution) for image in images]
        return out

    def prompt_inputs(self, obs: Observation, frames: Mapping[str, list[np.ndarray]]) -> dict[str, torch.Tensor]:
        """Processor outputs of the chat prompt up to (without) ``<|cot_start|>``, history tokens fused in."""
        from vdb_adapter_transformers import tiny

        b = self.backbone
        images = [image for name in self.cameras for image in frames[name]]
        inputs = tiny.vlm_inputs(b.tokenizer, b.image_processor, self.prompt_text(obs), images)
        ids = inputs["input_ids"]
        slots = ids[0] == b.token_id(HISTORY)
        ids[0, slots] = torch.tensor(b.history_ids(history_poses(obs)), dtype=torch.long)
        return {k: v.to(self.device) if isinstance(v, torch.Tensor) else v for k, v in inputs.items()}

    def prompt_text(self, obs: Observation) -> str:
        vision = "<|vision_start|><|image_pad|><|vision_end|>"
        cameras = "".join(f"{_label(name)}: {vision * self.frames}\n" for name in self.cameras)
        route = getattr(obs, "route", None) or getattr(obs, "route_text", None) or obs.command
        return (f"<|im_start|>system\n{SYSTEM}<|im_end|>\n<|im_start|>user\n{cameras}"
                f"{HISTORY_START}{HISTORY * HISTORY_TOKENS}{HISTORY_END}route: {route}\n{INSTRUCTION}<|im_end|>\n"
                f"<|im_start|>assistant\n")

    def _prefix_bound(self) -> int:
        """An upper bound on the prompt's length: every image at the processor's largest size."""
        longest = self.backbone.image_processor.size["longest_edge"]
        merge = self.backbone.image_processor.merge_size
        patch = self.backbone.image_processor.patch_size
        per_image = max(1, longest // (patch * patch * merge * merge)) + 4
        text = 200 + len(self.encode("route: " + "x" * 40)) + HISTORY_TOKENS
        return len(self.cameras) * (self.frames * per_image + 16) + text

    def _banned_ids(self) -> list[int]:
        """Never generated: the prompt's special tokens, the history tokens, and (byte tokenizer of the tiny
        model) every byte that is not printable ASCII or is ``|``, so every CoT decodes to a text that
        encodes back to the very same tokens."""
        b = self.backbone
        special = [int(i) for i in b.tokenizer.all_special_ids if int(i) != self.end_id]
        if b.source != "tiny":
            return special
        keep = {self.end_id} | {i for ch in map(chr, range(0x20, 0x7F)) if ch != "|" for i in self.encode(ch)}
        return sorted(set(special) | (set(range(len(b.tokenizer))) - keep))

    def _lockstep_prefix(self, observations: Sequence[Observation]) -> tuple[lockstep.LockstepDecoder, list[dict]]:
        rows = self.prefix_rows(observations)
        decoder = lockstep.LockstepDecoder.from_states(self.backbone.vlm, [state for state, _ in rows],
                                                       self.backbone.tokenizer.pad_token_id)
        return decoder, [inputs for _, inputs in rows]

    def _row_state(self, decoder: lockstep.LockstepDecoder, row: int, text: Sequence[int], inputs: dict
                   ) -> AlpamayoState:
        """Row ``row`` of a lockstep batch after ``<|traj_future_start|>``, its fed tokens as alone."""
        fed = (self.start_id, *text, self.end_id, self.future_id)
        return AlpamayoState(decoder.row_state(row, fed), inputs)

    def _state_of(self, obs: Observation, cot: CoT) -> AlpamayoState:
        if isinstance(cot.state, AlpamayoState):
            return cot.state
        return self.splice_cot(obs, cot.text, np.random.default_rng(0)).state


def history_poses(obs: Observation) -> np.ndarray:
    """16 past ego poses ``(x, y, yaw)`` in the current ego frame, oldest first.

    From ``obs.ego_history`` (a sequence of poses with ``x``, ``y``, ``yaw``, or rows ``(x, y, yaw)``, in
    the world frame) when the observation has it; else extrapolated back at the current speed.
    """
    history = getattr(obs, "ego_history", None)
    ego = obs.ego
    if history is not None and len(history):
        rows = [(p.x, p.y, p.yaw) if hasattr(p, "x") else tuple(p)[:3] for p in history][-HISTORY_POSES:]
        rows = [rows[0]] * (HISTORY_POSES - len(rows)) + rows
        poses = []
        for x, y, yaw in rows:
            ex, ey = ego.to_ego_frame(float(x), float(y))
            poses.append((ex, ey, float(yaw) - ego.yaw))
        return np.array(poses)
    back = -ego.speed / RATE_HZ * np.arange(HISTORY_POSES, 0, -1)
    return np.stack([back, np.zeros(HISTORY_POSES), np.zeros(HISTORY_POSES)], axis=1)


def controls_to_trajectory(controls: np.ndarray, speed: float, dt: float) -> Trajectory:
    """Unicycle rollout of (acceleration, curvature) per step from ``speed`` at the origin, heading +x."""
    x = y = heading = 0.0
    v = float(speed)
    xy = np.zeros((len(controls), 2))
    for k, (accel, kappa) in enumerate(controls):
        v_next = max(0.0, v + float(accel) * dt)
        ds = 0.5 * (v + v_next) * dt
        mid = heading + 0.5 * float(kappa) * ds
        x, y = x + ds * np.cos(mid), y + ds * np.sin(mid)
        heading += float(kappa) * ds
        v = v_next
        xy[k] = (x, y)
    return Trajectory(times=dt * np.arange(1, len(controls) + 1), xy=xy)


def _dtype(backbone: Backbone) -> torch.dtype:
    return next(backbone.vlm.parameters()).dtype


def _label(name: str) -> str:
    return next((short for short, full in CAMERA_ALIASES.items() if full == name), name).replace("_", " ")


def _lookup(rig: Mapping[str, Any], name: str) -> Any:
    short = next((s for s, full in CAMERA_ALIASES.items() if full == name), name)
    for key in (name, short):
        if key in rig:
            return rig[key]
    return None


def _frame_list(value: Any) -> list[np.ndarray]:
    """Frames of one camera of a rig: an ``(H, W, 3)`` image, an ``(F, H, W, 3)`` array, a sequence of
    images, or an object with ``frames`` / ``images``."""
    for attribute in ("frames", "images"):
        if hasattr(value, attribute):
            value = getattr(value, attribute)
    if isinstance(value, np.ndarray):
        return [value] if value.ndim == 3 else list(value)
    return [np.asarray(v) for v in value]


def _resize(image: np.ndarray, resolution: tuple[int, int]) -> np.ndarray:
    from PIL import Image

    image = np.ascontiguousarray(image, dtype=np.uint8)
    if image.shape[:2] == resolution:
        return image
    return np.asarray(Image.fromarray(image).resize((resolution[1], resolution[0]), Image.BILINEAR))


def _observation_key(obs: Observation, frames: Mapping[str, list[np.ndarray]]) -> tuple:
    digest = hashlib.blake2b(digest_size=16)
    for images in frames.values():
        for image in images:
            digest.update(image.tobytes())
    history = history_poses(obs)
    return (obs.scenario_id, obs.step, obs.time, obs.ego.speed, obs.command, digest.hexdigest(), history.tobytes())
