"""Entry point ``neural``: registers the ``kv`` and ``qa`` reference models and ``vdb train-neural``.

Registration imports nothing heavy; torch and transformers are imported by the factories.
"""

from __future__ import annotations

import vladrivebench


def make_kv(splice_mode: str = "sequential", weights_dir: str | None = None, threads: int = 1,
            device: str = "cpu"):
    """The Alpamayo-like ``kv`` model (options: splice_mode=sequential|prefill, weights_dir, threads, device)."""
    from .kv_model import KVModel

    return KVModel(splice_mode=splice_mode, weights_dir=weights_dir, threads=threads, device=device)


def make_qa(splice_mode: str = "sequential", weights_dir: str | None = None, threads: int = 1,
            device: str = "cpu"):
    """The ORION-like ``qa`` model (options: splice_mode=sequential|prefill, weights_dir, threads, device)."""
    from .qa_model import QAModel

    return QAModel(splice_mode=splice_mode, weights_dir=weights_dir, threads=threads, device=device)


@vladrivebench.hookimpl
def register_models(register):
    register("kv", make_kv, description="neural Alpamayo-like VLA: one-sentence CoT, flow-matching head on the KV cache")
    register("qa", make_qa, description="neural ORION-like VLA: three QA rounds, planner on a planning token")


@vladrivebench.hookimpl
def register_commands(cli):
    from .train import train_command

    cli.add_command(train_command)


@vladrivebench.hookimpl
def register_defaults(register):
    # it sees only the camera, so the camera is rendered; it was trained with the MPC tracker
    # its 8 episodes advance in lockstep through one model (vdb run --batch 8): one batched call per step
    register("demo", "kv", priority=10, controller="mpc", sim_options={}, model_options={}, batch=8,
             about="the neural kv model (Alpamayo-like, trained here), camera only")
