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
from vdb_adapter_transformers import toolkit
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
    """The Alpamayo 1 / 1.5 architecture as a VLADriveBench model (VLAModel, TokenCounter, FidelityCheck)."""

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

    # -- protocol ------------------------------------------------------------------------------------------
    def reset(self, seed: int) -> None:
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
        if not isinstance(text, str):
            raise ConfigError(f"model 'alpamayo' writes one sentence; a splice needs one text, got slots "
                              f"{', '.join(text)}")
        prefix, inputs = self.prefix_state(obs)
        state = toolkit.splice_tokens(self.backbone.vlm, prefix, self.encode(text), self.start_id, self.end_id,
                                      mode=self.splice_mode, what="model 'alpamayo' splice text")
        state = toolkit.feed_token(self.backbone.vlm, state, self.future_id)
        return CoT(text=text, state=AlpamayoState(state, inputs), spliced=True)

    def decode_action(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> Trajectory:
        """Flow matching over the expert from pinned noise, then the rollout of the controls."""
        state = self._state_of(obs, cot)
        controls = self.sample_controls(state.decoder, toolkit.torch_generator(rng))
        return controls_to_trajectory(controls, obs.ego.speed, 1.0 / RATE_HZ)

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

    @torch.no_grad()
    def sample_controls(self, decoder: toolkit.DecoderState, generator: torch.Generator) -> np.ndarray:
        """(acceleration m/s², curvature 1/m) × 64: 10 Euler steps of the expert's velocity field from
        noise drawn from ``generator``, the expert attending to ``decoder``'s cache without a causal mask."""
        b = self.backbone
        dtype = _dtype(b)
        x = torch.randn(1, ACTION_TOKENS, ACTION_DIMS, generator=generator).to(self.device, dtype)
        positions = decoder.next_position_ids(ACTION_TOKENS).to(self.device)
        mask = torch.zeros(1, 1, ACTION_TOKENS, decoder.length + ACTION_TOKENS, dtype=dtype, device=self.device)
        for k in range(FLOW_STEPS):
            t = torch.full((1,), k / FLOW_STEPS, dtype=dtype, device=self.device)
            hidden = b.expert(inputs_embeds=b.action_in(x, t), position_ids=positions, cache=decoder.cache,
                              attention_mask=mask, use_cache=True).last_hidden_state
            decoder.cache.crop(-ACTION_TOKENS)  # the expert's own keys never stay in the VLM's cache
            x = x + b.action_out(hidden) / FLOW_STEPS
        actions = x[0].float().cpu().numpy().astype(np.float64)
        accel = np.clip(actions[:, 0] * b.accel_scale, *ACCEL_LIMITS)
        curvature = np.clip(actions[:, 1] * b.curvature_scale, -CURVATURE_LIMIT, CURVATURE_LIMIT)
        return np.stack([accel, curvature], axis=1)

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
