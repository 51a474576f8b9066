"""The Alpamayo architecture's parts, built two ways that differ only in where the weights come from.

A :class:`Backbone` holds the Qwen3-VL model (``Qwen3VLForConditionalGeneration``), its tokenizer and image
processor, the *action expert* (a text decoder built from the VLM's own text config, without token
embeddings), the action projections and the trajectory-history tokenizer. :func:`tiny_backbone` builds all
of it with random weights from a seed (tests, CI, a smoke run on any machine); :func:`load_checkpoint`
loads a real Alpamayo checkpoint through the user's installed Alpamayo packages. Everything downstream
(prompt, CoT, splice, expert, flow matching, integration) is shared.
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from vladrivebench import ConfigError

#: Alpamayo's prompt tokens (names as in the released model) and the chat markers of Qwen3-VL.
COT_START, COT_END = "<|cot_start|>", "<|cot_end|>"
HISTORY_START, HISTORY, HISTORY_END = "<|traj_history_start|>", "<|traj_history|>", "<|traj_history_end|>"
FUTURE_START = "<|traj_future_start|>"
CHAT_TOKENS = ("<|im_start|>", "<|im_end|>")
ALPAMAYO_TOKENS = (COT_START, COT_END, HISTORY_START, HISTORY, HISTORY_END, FUTURE_START, *CHAT_TOKENS)

HISTORY_POSES = 16          # past ego poses, 10 Hz
HISTORY_TOKENS = 48         # 16 poses × (x, y, yaw)
ACTION_TOKENS = 64          # 6.4 s at 10 Hz, one token per step
ACTION_DIMS = 2             # (acceleration, curvature)
HISTORY_BINS = 64           # tiny history tokenizer: bins per value
#: Value ranges of the tiny history tokenizer: x back (m), y (m), yaw (rad), relative to the current pose.
HISTORY_RANGES = ((-40.0, 2.0), (-6.0, 6.0), (-0.6, 0.6))
ARCHITECTURES = ("alpamayo_r1",)


class ActionIn(nn.Module):
    """Noisy action ``(B, 64, 2)`` and flow time ``t`` → expert token embeddings ``(B, 64, hidden)``."""

    def __init__(self, hidden: int):
        super().__init__()
        self.hidden = hidden
        self.action = nn.Linear(ACTION_DIMS, hidden)
        self.time = nn.Sequential(nn.Linear(hidden, hidden), nn.SiLU(), nn.Linear(hidden, hidden))

    def forward(self, x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        half = self.hidden // 2
        freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32) / half)
        angles = t.reshape(-1, 1).float() * 1000.0 * freqs
        embedding = torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1).to(x.dtype)
        return self.action(x) + self.time(embedding)[:, None, :]


@dataclass
class Backbone:
    """Everything the adapter runs; ``source`` says where the weights came from (``tiny`` or a path)."""

    vlm: nn.Module
    tokenizer: Any
    image_processor: Any
    expert: nn.Module
    action_in: nn.Module
    action_out: nn.Module
    source: str
    accel_scale: float = 2.0       # m/s² per unit of the flow's first action dimension
    curvature_scale: float = 0.05  # 1/m per unit of the second
    history_encoder: Callable[[np.ndarray], list[int]] | None = None  # a checkpoint's own history tokenizer

    def token_id(self, token: str) -> int:
        return int(self.tokenizer.convert_tokens_to_ids(token))

    def history_ids(self, poses: np.ndarray) -> list[int]:
        """The 48 trajectory-history token ids of 16 past poses ``(16, 3)`` (x, y, yaw in the current ego
        frame): the checkpoint's own history tokenizer, or (tiny) each value quantised into
        ``HISTORY_BINS`` bins of its range, as tokens ``<h0>`` …"""
        if self.history_encoder is not None:
            return self.history_encoder(poses)
        ids = []
        for pose in poses:
            for value, (low, high) in zip(pose, HISTORY_RANGES, strict=True):
                level = int(np.clip(np.floor((value - low) / (high - low) * HISTORY_BINS), 0, HISTORY_BINS - 1))
                ids.append(self.token_id(f"<h{level}>"))
        return ids


def tiny_backbone(seed: int = 0, max_positions: int = 2048) -> Backbone:
    """A random-weight Alpamayo-architecture model (Qwen3-VL of width 32, two layers) built from ``seed``."""
    from vdb_adapter_transformers import tiny

    history = [f"<h{i}>" for i in range(HISTORY_BINS)]
    tokenizer = tiny.byte_tokenizer([*ALPAMAYO_TOKENS, *history])
    vlm = tiny.tiny_qwen3_vl(tokenizer, seed=seed, max_positions=max_positions)
    torch.manual_seed(seed + 1)
    expert, hidden = build_expert(vlm)
    action_in, action_out = ActionIn(hidden), nn.Linear(hidden, ACTION_DIMS)
    return Backbone(vlm, tokenizer, tiny.image_processor(vlm), expert.eval(), action_in.eval(), action_out.eval(),
                    "tiny")


def build_expert(vlm: nn.Module) -> tuple[nn.Module, int]:
    """The action expert: a text decoder of the VLM's own text config (its layers read the VLM's cache
    layer by layer), with no token embedding table — it is fed action embeddings only."""
    from transformers import AutoModel

    config = copy.deepcopy(vlm.config.get_text_config())
    config._attn_implementation = "sdpa"
    expert = AutoModel.from_config(config)
    expert.embed_tokens = None
    return expert, int(config.hidden_size)


def load_checkpoint(checkpoint: str, device: str, dtype: str) -> Backbone:
    """A real Alpamayo checkpoint through the user's installed Alpamayo package (``alpamayo_r1``).

    Untested here (no checkpoint, no GPU, no Alpamayo package in CI). Raises a one-line
    :class:`ConfigError` for a missing folder, another architecture or a missing package.
    """
    path = Path(checkpoint).expanduser()
    config_file = path / "config.json"
    if not config_file.is_file():
        raise ConfigError(f"model 'alpamayo' option checkpoint={checkpoint}: no checkpoint there (expected a "
                          f"folder with config.json and the weights of an Alpamayo 1 / 1.5 model)")
    try:
        model_type = json.loads(config_file.read_text(encoding="utf-8")).get("model_type")
    except (OSError, ValueError, AttributeError) as exc:
        raise ConfigError(f"model 'alpamayo' option checkpoint={checkpoint}: config.json is not readable JSON "
                          f"({exc})") from None
    if model_type not in ARCHITECTURES:
        raise ConfigError(f"model 'alpamayo' option checkpoint={checkpoint}: the checkpoint is a {model_type!r} "
                          f"model; expected one of: {', '.join(ARCHITECTURES)}")
    try:
        from alpamayo_r1.models.alpamayo_r1 import AlpamayoR1
    except ModuleNotFoundError:
        raise ConfigError("model 'alpamayo' option checkpoint needs NVIDIA's Alpamayo package (alpamayo_r1, from "
                          "github.com/NVlabs/alpamayo) installed in this environment") from None
    model = AlpamayoR1.from_pretrained(str(path), dtype=getattr(torch, dtype)).to(device).eval()
    return Backbone(model.vlm, model.tokenizer, model.processor.image_processor, model.expert,
                    model.action_in_proj, model.action_out_proj, str(path),
                    history_encoder=_checkpoint_history(model))


def _checkpoint_history(model: Any) -> Callable[[np.ndarray], list[int]]:
    """The checkpoint's own history tokenizer on poses ``(16, 3)``: xyz with z = 0, yaw as a rotation."""
    from alpamayo_r1.models.base_model import tokenize_history_trajectory

    def encode(poses: np.ndarray) -> list[int]:
        xyz = torch.zeros(1, 1, len(poses), 3)
        xyz[0, 0, :, :2] = torch.as_tensor(poses[:, :2], dtype=torch.float32)
        yaw = torch.as_tensor(poses[:, 2], dtype=torch.float32)
        rot = torch.zeros(1, 1, len(poses), 3, 3)
        rot[0, 0, :, 0, 0], rot[0, 0, :, 0, 1] = torch.cos(yaw), -torch.sin(yaw)
        rot[0, 0, :, 1, 0], rot[0, 0, :, 1, 1] = torch.sin(yaw), torch.cos(yaw)
        rot[0, 0, :, 2, 2] = 1.0
        data = {"ego_history_xyz": xyz, "ego_history_rot": rot}
        return [int(t) for t in tokenize_history_trajectory(model.hist_traj_tokenizer, data,
                                                             model.hist_token_start_idx)[0]]

    return encode


def check_processor(backbone: Backbone, where: str) -> None:
    """Refuse, in one line, a tokenizer or image processor that does not match the VLM: the Alpamayo tokens
    and the image placeholder must be known (the placeholder with the id the model expects), no token id may
    fall outside the model's embeddings, and the image processor must cut patches as the vision tower does."""
    tokenizer, config = backbone.tokenizer, backbone.vlm.config
    unknown = [t for t in ALPAMAYO_TOKENS if _unknown(tokenizer, t)]
    if unknown:
        raise ConfigError(f"model 'alpamayo' {where}: the tokenizer does not know {', '.join(unknown)}; expected "
                          f"an Alpamayo tokenizer with the tokens {', '.join(ALPAMAYO_TOKENS)}")
    pad = tokenizer.convert_tokens_to_ids("<|image_pad|>")
    if pad != config.image_token_id:
        raise ConfigError(f"model 'alpamayo' {where}: the tokenizer's <|image_pad|> is id {pad}, the model's "
                          f"image token is {config.image_token_id}; expected the processor of this checkpoint")
    embeddings = backbone.vlm.get_input_embeddings().num_embeddings
    if len(tokenizer) > embeddings:
        raise ConfigError(f"model 'alpamayo' {where}: the tokenizer has {len(tokenizer)} tokens, the model "
                          f"embeds {embeddings}; expected the tokenizer of this checkpoint")
    vision = config.vision_config
    for name, expected in (("patch_size", vision.patch_size), ("merge_size", vision.spatial_merge_size),
                           ("temporal_patch_size", getattr(vision, "temporal_patch_size", None))):
        found = getattr(backbone.image_processor, name, None)
        if expected is not None and found != expected:
            raise ConfigError(f"model 'alpamayo' {where}: the image processor's {name} is {found}, the vision "
                              f"tower's is {expected}; expected the image processor of this checkpoint")


def _unknown(tokenizer: Any, token: str) -> bool:
    ids = tokenizer.convert_tokens_to_ids(token)
    return ids is None or ids == tokenizer.unk_token_id or tokenizer.convert_ids_to_tokens(ids) != token
