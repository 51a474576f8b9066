"""Building blocks the two reference models share: camera encoder, ego token, tokenizer, weight bundles.

A *bundle* is what a trained model is on disk, all in ``weights/``: ``<name>.safetensors`` (tensors only,
loaded with safetensors — never pickle), ``<name>.config.json`` (architecture and training settings) and
``<name>.tokenizer.json`` (a ``tokenizers`` BPE trained on the expert's CoT corpus).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F
from vladrivebench import NAV_COMMANDS, ConfigError, VdbError

IMAGE_HEIGHT, IMAGE_WIDTH = 80, 160
"""The encoder's input size (the kinematic camera's default); other sizes are resized by area averaging."""

LAMP_CHANNELS = 8
SPECIAL_TOKENS = ("<pad>", "<cot>", "</cot>", "<a>", "</a>", "<plan>")
WEIGHTS_DIR = Path(__file__).parent / "weights"


class WeightsError(VdbError):
    """A weights bundle that is missing, corrupt or does not fit the model."""


def rebuild_command(name: str) -> str:
    return f"python -m vdb_model_neural.train --model {name} --seed 0"


# -- inputs ------------------------------------------------------------------------------------------
def image_batch(images: list[np.ndarray] | np.ndarray) -> torch.Tensor:
    """Camera images ``(H, W, 3)`` uint8 → ``(N, 3, 80, 160)`` floats in [0, 1] (area-averaged resize)."""
    array = np.stack([np.asarray(im) for im in images]) if isinstance(images, list) else np.asarray(images)
    if array.ndim != 4 or array.shape[-1] != 3:
        raise ValueError(f"camera images must be (N, H, W, 3), got {array.shape}")
    tensor = torch.from_numpy(np.ascontiguousarray(array)).permute(0, 3, 1, 2).float() / 255.0
    if tensor.shape[-2:] != (IMAGE_HEIGHT, IMAGE_WIDTH):
        tensor = F.interpolate(tensor, size=(IMAGE_HEIGHT, IMAGE_WIDTH), mode="area")
    return tensor


def ego_features(speeds: list[float] | np.ndarray, commands: list[str]) -> torch.Tensor:
    """Ego speed and navigation command as a feature vector per sample: ``(N, 1 + len(NAV_COMMANDS))``."""
    rows = []
    for speed, command in zip(speeds, commands, strict=True):
        onehot = [1.0 if command == c else 0.0 for c in NAV_COMMANDS]
        rows.append([float(speed) / 10.0, *onehot])
    return torch.tensor(rows, dtype=torch.float32)


class VisionEncoder(nn.Module):
    """A small CNN: camera image → a grid of ``rows × cols`` vision tokens of the decoder's width.

    Strided convolutions keep the spatial layout (where in the image an obstacle is, and how big), and a
    learned position embedding per grid cell lets the decoder tell left from right and near from far.
    """

    def __init__(self, hidden: int, channels: int = 32, rows: int = 3, cols: int = 6):
        super().__init__()
        self.rows, self.cols = rows, cols
        # A patchifying first layer (4×4, stride 4) keeps the cost low at full resolution while a single
        # lit lamp pixel still reaches a feature.
        self.convs = nn.Sequential(
            nn.Conv2d(3, channels, 4, stride=4), nn.GELU(),
            nn.Conv2d(channels, channels, 3, stride=2, padding=1), nn.GELU(),
            nn.Conv2d(channels, channels, 3, stride=2, padding=1), nn.GELU(),
        )
        # Per-pixel colour features max-pooled over each grid cell: a lit lamp is one pixel at every
        # distance on this camera, and a strided convolution mixes it with its dark housing before any
        # pooling; a per-pixel branch keeps "this cell holds a saturated red/yellow/green pixel" intact.
        # One layer is enough: a saturated lamp colour is linearly separable from every other colour drawn.
        self.lamps = nn.Sequential(nn.Linear(3, LAMP_CHANNELS), nn.ReLU())
        self.project = nn.Linear(2 * channels, hidden)
        self.project_zoom = nn.Linear(2 * channels + LAMP_CHANNELS, hidden)
        self.project_lamp = nn.Linear(LAMP_CHANNELS, hidden)
        self.position = nn.Parameter(torch.zeros(2 * rows * cols, hidden))
        self.ego = nn.Linear(1 + len(NAV_COMMANDS), hidden)

    @property
    def n_tokens(self) -> int:
        return 2 * self.rows * self.cols + 2

    def forward(self, images: torch.Tensor, ego: torch.Tensor) -> torch.Tensor:
        """``(N, 3, H, W)`` images and ``(N, F)`` ego features → ``(N, 2·rows·cols + 2, hidden)`` prefix:
        the whole view, a 2× zoom on the road ahead (where distant obstacles and lights are a few pixels),
        a lamp token and the ego token."""
        height, width = images.shape[-2:]
        rows, cols = slice(int(0.3 * height), int(0.7 * height)), slice(int(0.25 * width), int(0.75 * width))
        zoomed = F.interpolate(images[:, :, rows, cols], scale_factor=2.0, mode="nearest")
        # Per-pixel colour features at native resolution (channels last: a linear layer per pixel, cheaper on CPU
        # than 1×1 convolutions) above the lower 30 % of the view (road surface, never a lamp), max-pooled
        # over the road-ahead cells and over the whole upper view.
        pixels = self.lamps(images[:, :, : rows.stop].permute(0, 2, 3, 1).contiguous())
        lamps = F.adaptive_max_pool2d(pixels[:, rows, cols].permute(0, 3, 1, 2), (self.rows, self.cols))
        whole = self.project(self._cells(self._grid(images)))
        ahead_tokens = self.project_zoom(self._cells(torch.cat([self._grid(zoomed), lamps], dim=1)))
        tokens = torch.cat([whole, ahead_tokens], dim=1) + self.position
        # The strongest lamp-like pixel anywhere in view, in a token of its own: whether a light is lit, and
        # which colour, must not depend on the buildings that happen to share its grid cell.
        lamp = self.project_lamp(pixels.flatten(1, 2).max(dim=1).values).unsqueeze(1)
        return torch.cat([tokens, lamp, self.ego(ego).unsqueeze(1)], dim=1)

    def _grid(self, images: torch.Tensor) -> torch.Tensor:
        """``(N, 2·channels, rows, cols)``: mean and max of the convolution features over each grid cell
        (max pooling keeps small bright things, a distant pedestrian, that averaging dilutes)."""
        features = self.convs(images)
        return torch.cat([F.adaptive_avg_pool2d(features, (self.rows, self.cols)),
                          F.adaptive_max_pool2d(features, (self.rows, self.cols))], dim=1)

    @staticmethod
    def _cells(grid: torch.Tensor) -> torch.Tensor:
        return grid.flatten(2).transpose(1, 2)


def timestep_embedding(t: torch.Tensor, dim: int) -> torch.Tensor:
    """Sinusoidal embedding of flow times ``t`` in [0, 1], ``(N,)`` → ``(N, dim)``."""
    half = dim // 2
    freqs = torch.exp(-math.log(1000.0) * torch.arange(half, dtype=torch.float32) / half)
    angles = t.float()[:, None] * 1000.0 * freqs[None]
    return torch.cat([torch.sin(angles), torch.cos(angles)], dim=-1)


# -- tokenizer ---------------------------------------------------------------------------------------
class TextCodec:
    """A trained ``tokenizers`` byte-level BPE plus the ids of the marker tokens."""

    def __init__(self, tokenizer: Any):
        self.tokenizer = tokenizer
        self.ids = {tok: tokenizer.token_to_id(tok) for tok in SPECIAL_TOKENS}

    @classmethod
    def train(cls, corpus: list[str], vocab_size: int) -> TextCodec:
        from tokenizers import Tokenizer, decoders, models, pre_tokenizers, trainers

        tokenizer = Tokenizer(models.BPE())
        # One token per digit: a number has a single tokenization, so a generated BEV coordinate decodes
        # and re-encodes to the same ids (what a bit-identical selfsplice needs).
        tokenizer.pre_tokenizer = pre_tokenizers.Sequence([
            pre_tokenizers.Digits(individual_digits=True), pre_tokenizers.ByteLevel(add_prefix_space=False)])
        tokenizer.decoder = decoders.ByteLevel()
        trainer = trainers.BpeTrainer(vocab_size=vocab_size, special_tokens=list(SPECIAL_TOKENS),
                                      initial_alphabet=pre_tokenizers.ByteLevel.alphabet(), show_progress=False)
        tokenizer.train_from_iterator(corpus, trainer=trainer)
        return cls(tokenizer)

    @classmethod
    def from_json(cls, text: str) -> TextCodec:
        from tokenizers import Tokenizer

        return cls(Tokenizer.from_str(text))

    def to_json(self) -> str:
        return self.tokenizer.to_str()

    @property
    def vocab_size(self) -> int:
        return self.tokenizer.get_vocab_size()

    def encode(self, text: str) -> list[int]:
        return self.tokenizer.encode(text, add_special_tokens=False).ids

    def decode(self, ids: list[int]) -> str:
        return self.tokenizer.decode(list(ids), skip_special_tokens=True)

    @property
    def special_ids(self) -> list[int]:
        return list(self.ids.values())


# -- bundles -----------------------------------------------------------------------------------------
@dataclass
class ModelConfig:
    """Architecture of a reference model (saved as ``<name>.config.json`` beside the weights)."""

    kind: str
    hidden: int = 64
    layers: int = 3
    heads: int = 4
    kv_heads: int = 2
    intermediate: int = 160
    vocab_size: int = 512
    context: int = 256
    max_cot_tokens: int = 40
    horizon_steps: int = 30
    rate_hz: float = 10.0
    head_width: int = 48
    flow_steps: int = 8
    chunk: int = 5
    training: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ModelConfig:
        data = json.loads(text)
        return cls(**data)

    def llama_config(self):
        from transformers import LlamaConfig

        return LlamaConfig(
            vocab_size=self.vocab_size, hidden_size=self.hidden, intermediate_size=self.intermediate,
            num_hidden_layers=self.layers, num_attention_heads=self.heads, num_key_value_heads=self.kv_heads,
            max_position_embeddings=self.context, tie_word_embeddings=True, pad_token_id=0,
            bos_token_id=None, eos_token_id=None,
        )


def bundle_paths(name: str, directory: Path | None = None) -> dict[str, Path]:
    directory = Path(directory) if directory else WEIGHTS_DIR
    return {
        "weights": directory / f"{name}.safetensors",
        "config": directory / f"{name}.config.json",
        "tokenizer": directory / f"{name}.tokenizer.json",
    }


def save_bundle(name: str, module: nn.Module, config: ModelConfig, codec: TextCodec,
                directory: Path | None = None) -> dict[str, Path]:
    """Write weights (safetensors), config and tokenizer; each file appears complete or not at all."""
    from safetensors.torch import save_file

    paths = bundle_paths(name, directory)
    paths["weights"].parent.mkdir(parents=True, exist_ok=True)
    tensors = {k: v.detach().contiguous().clone() for k, v in module.state_dict().items()}
    _atomic(paths["weights"], lambda p: save_file(tensors, str(p), metadata={"model": name}))
    _atomic(paths["config"], lambda p: p.write_text(config.to_json()))
    _atomic(paths["tokenizer"], lambda p: p.write_text(codec.to_json()))
    return paths


def _atomic(path: Path, write) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    tmp.replace(path)


def load_bundle(name: str, directory: Path | None = None) -> tuple[ModelConfig, TextCodec, dict[str, torch.Tensor]]:
    """Config, tokenizer and tensors of a bundle; a one-line :class:`WeightsError` naming the file and
    the command that rebuilds it when any file is missing or corrupt."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    paths = bundle_paths(name, directory)
    fix = f"rebuild it with: {rebuild_command(name)}"
    for what, path in paths.items():
        if not path.is_file():
            raise WeightsError(f"{what} file {path} of neural model {name!r} is missing; {fix}")
    try:
        config = ModelConfig.from_json(paths["config"].read_text())
    except (ValueError, TypeError) as exc:
        raise WeightsError(f"config file {paths['config']} is corrupt ({_first_line(exc)}); {fix}") from None
    try:
        codec = TextCodec.from_json(paths["tokenizer"].read_text())
    except Exception as exc:  # tokenizers raises its own exception type for malformed JSON
        raise WeightsError(f"tokenizer file {paths['tokenizer']} is corrupt ({_first_line(exc)}); {fix}") from None
    try:
        tensors = load_file(str(paths["weights"]))
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        raise WeightsError(f"weights file {paths['weights']} is corrupt ({_first_line(exc)}); {fix}") from None
    return config, codec, tensors


def load_state(name: str, module: nn.Module, tensors: dict[str, torch.Tensor], directory: Path | None = None) -> None:
    """Load tensors into ``module``, strictly: a missing, extra or misshapen tensor is a WeightsError."""
    path = bundle_paths(name, directory)["weights"]
    expected = module.state_dict()
    problems = sorted(set(expected) ^ set(tensors))
    problems += [k for k in expected if k in tensors and tensors[k].shape != expected[k].shape]
    if problems:
        raise WeightsError(f"weights file {path} does not fit model {name!r} (first mismatch: {problems[0]}); "
                           f"rebuild it with: {rebuild_command(name)}")
    module.load_state_dict(tensors, strict=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def configure_torch(threads: int = 1) -> None:
    """Deterministic kernels and a fixed thread count, so a step is reproducible bit for bit."""
    torch.use_deterministic_algorithms(True)
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)


class BundledModel:
    """What the ``kv`` and ``qa`` models share: options checked, torch configured, the weights bundle
    loaded (safetensors only) into ``network_class``; ``_setup`` does the rest. ``from_network`` wraps an
    in-memory network (training, tests) without reading weights files."""

    name: str
    network_class: type

    device = "cpu"

    default_sampling: tuple[float, float] = (0.0, 1.0)
    """(temperature, top_p) of the CoT sampling when the options do not say."""

    def __init__(self, splice_mode: str = "sequential", weights_dir: str | None = None, threads: int = 1,
                 device: str = "cpu", temperature: float | None = None, top_p: float | None = None):
        from vdb_adapter_transformers.toolkit import SPLICE_MODES

        from .sampling import Sampler, TokenMemo

        self.sampler = Sampler.checked(self.name, *self._sampling(temperature, top_p))
        self.token_memo = TokenMemo()

        if splice_mode not in SPLICE_MODES:
            raise ConfigError(f"model {self.name!r} option splice_mode={splice_mode!r} is not known "
                              f"(expected one of: {', '.join(SPLICE_MODES)})")
        if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= 256:
            raise ConfigError(f"model {self.name!r} option threads must be a whole number between 1 and 256, "
                              f"got {threads!r}")
        configure_torch(threads)
        directory = Path(weights_dir) if weights_dir else None
        config, codec, tensors = load_bundle(self.name, directory)
        network = self.network_class(config)
        load_state(self.name, network, tensors, directory)
        self.device = _check_device(self.name, device)
        self._setup(network.to(self.device).eval(), codec, splice_mode)

    @classmethod
    def from_network(cls, network: nn.Module, codec: TextCodec, splice_mode: str = "sequential",
                     temperature: float | None = None, top_p: float | None = None):
        from .sampling import Sampler, TokenMemo

        model = cls.__new__(cls)
        model.sampler = Sampler.checked(cls.name, *model._sampling(temperature, top_p))
        model.token_memo = TokenMemo()
        model._setup(network.eval(), codec, splice_mode)
        return model

    def _sampling(self, temperature: float | None, top_p: float | None) -> tuple[object, object]:
        default_temperature, default_top_p = self.default_sampling
        return (default_temperature if temperature is None else temperature,
                default_top_p if top_p is None else top_p)

    def _setup(self, network: nn.Module, codec: TextCodec, splice_mode: str) -> None:
        raise NotImplementedError


def _check_device(model: str, device: Any) -> str:
    """A torch device the model can run on (``cpu``, ``cuda``, ``cuda:1``, ``mps``), else a one-line error.

    The lockstep-batched methods move their inputs to the device; on a device other than ``cpu`` the
    per-episode methods run as a batch of one (so results are those of ``--batch``, up to floating point).
    """
    try:
        parsed = torch.device(str(device))
    except (RuntimeError, TypeError):
        raise ConfigError(f"model {model!r} option device={device!r} is not a torch device "
                          f"(expected cpu, cuda, cuda:N or mps)") from None
    if parsed.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"model {model!r} option device={device!r}: this torch has no CUDA device")
    if parsed.type == "mps" and not torch.backends.mps.is_available():
        raise ConfigError(f"model {model!r} option device={device!r}: this torch has no MPS device")
    return str(parsed)
