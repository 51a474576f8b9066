"""Entry point ``alpamayo``: registers the Alpamayo-architecture model. Registration imports nothing heavy."""

from __future__ import annotations

import vladrivebench

TINY_RESOLUTION, CHECKPOINT_RESOLUTION = "64x128", "320x576"
DTYPES = ("float32", "bfloat16", "float16")


def make_alpamayo(checkpoint: str | None = None, device: str = "cpu", dtype: str = "float32",
                  cameras: str = "front_wide,front_tele,cross_left,cross_right", frames: int = 1,
                  resolution: str | None = None, seed: int = 0, max_cot_tokens: int = 24,
                  splice_mode: str = "sequential", threads: int = 1):
    """The Alpamayo 1 / 1.5 architecture on Qwen3-VL.

    Weights: a tiny random-weight model built from ``seed`` (default), or ``checkpoint`` = a folder of a
    real Alpamayo checkpoint, loaded through the installed Alpamayo package on ``device`` in ``dtype``.
    ``cameras`` (comma-separated), ``frames`` per camera, ``resolution`` (HxW the frames are resized to;
    default 64x128 tiny, 320x576 checkpoint), ``max_cot_tokens``, ``splice_mode`` (sequential|prefill),
    ``threads`` (torch CPU threads).
    """
    from vladrivebench import ConfigError

    from .model import AlpamayoModel, camera_names, parse_resolution

    if dtype not in DTYPES:
        raise ConfigError(f"model 'alpamayo' option dtype={dtype}: expected one of: {', '.join(DTYPES)}")
    if splice_mode not in ("sequential", "prefill"):
        raise ConfigError(f"model 'alpamayo' option splice_mode={splice_mode}: expected sequential or prefill")
    for option, value, low in (("frames", frames, 1), ("max_cot_tokens", max_cot_tokens, 1), ("threads", threads, 1)):
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            raise ConfigError(f"model 'alpamayo' option {option}={value}: expected an integer ≥ {low}")
    names = camera_names(cameras)
    import torch

    torch.set_num_threads(threads)
    backbone = _backbone(checkpoint, device, dtype, seed)
    minimum = backbone.image_processor.patch_size * backbone.image_processor.merge_size
    size = parse_resolution(resolution or (CHECKPOINT_RESOLUTION if checkpoint else TINY_RESOLUTION), minimum)
    if checkpoint is None:
        from vdb_adapter_transformers import tiny

        backbone.image_processor = tiny.image_processor(backbone.vlm, size[0] * size[1], size[0] * size[1])
    from .backbone import check_processor

    check_processor(backbone, f"option checkpoint={checkpoint}" if checkpoint else "(tiny model)")
    return AlpamayoModel(backbone, names, frames, size, max_cot_tokens, splice_mode, device)


def _backbone(checkpoint, device, dtype, seed):
    from .backbone import load_checkpoint, tiny_backbone

    if checkpoint is not None:
        return load_checkpoint(str(checkpoint), device, dtype)
    if device != "cpu" or dtype != "float32":
        from vladrivebench import ConfigError

        raise ConfigError(f"model 'alpamayo': the tiny random-weight model runs on cpu in float32 (got device="
                          f"{device}, dtype={dtype}); device and dtype are for a checkpoint")
    return tiny_backbone(int(seed))


@vladrivebench.hookimpl
def register_models(register):
    register("alpamayo", make_alpamayo, description="Alpamayo 1/1.5 architecture on Qwen3-VL (tiny random weights, "
                                                    "or a real checkpoint): CoT + flow-matching action expert on the KV cache")
