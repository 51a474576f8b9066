"""Entry point ``neural``: registers the ``kv`` and ``qa`` reference models and ``vdb train-neural``.

Registration imports nothing heavy; torch and transformers are imported by the factories.
"""

from __future__ import annotations

import vladrivebench


def make_kv(splice_mode: str = "sequential", weights_dir: str | None = None, threads: int = 1,
            device: str = "cpu", temperature: float = 0.6, top_p: float = 0.98):
    """The Alpamayo-like ``kv`` model (options: splice_mode=sequential|prefill, weights_dir, threads, device,
    temperature and top_p of its CoT sampling: Alpamayo's 0.6 and 0.98; temperature=0 is greedy)."""
    from .kv_model import KVModel

    return KVModel(splice_mode=splice_mode, weights_dir=weights_dir, threads=threads, device=device,
                   temperature=temperature, top_p=top_p)


def make_qa(splice_mode: str = "sequential", weights_dir: str | None = None, threads: int = 1,
            device: str = "cpu", temperature: float = 0.1, top_p: float = 0.75, plan_noise: float = 1.0):
    """The ORION-like ``qa`` model (options: splice_mode=sequential|prefill, weights_dir, threads, device,
    temperature and top_p of its answer sampling: ORION's 0.1 and 0.75, temperature=0 is greedy; plan_noise:
    the scale of its planner's learnt deviation, 0 plans the mean)."""
    from .qa_model import QAModel

    return QAModel(splice_mode=splice_mode, weights_dir=weights_dir, threads=threads, device=device,
                   temperature=temperature, top_p=top_p, plan_noise=plan_noise)


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
