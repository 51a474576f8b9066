"""Train the reference models from a seed: ``python -m vdb_model_neural.train --model kv --seed 0``
(or ``vdb train-neural --model both --seed 0``).

1. The expert drives randomised variants of the scenario suite in the kinematic simulator (:mod:`.data`).
2. A byte-level BPE tokenizer is trained on the model's CoT corpus with ``tokenizers``.
3. The network (vision encoder + ``LlamaForCausalLM`` built from a config + head) is trained with AdamW:
   * ``kv``: next-token loss on the expert's sentence + flow-matching loss on the expert's controls, and on a
     share of rows the sentence is replaced by a *counterfactual* (opposite decision) whose target follows
     it (no next-token loss there) — so the action depends on the CoT (Alpamayo-like coupling);
   * ``qa``: next-token loss on the three answers + planner loss on the expert's controls (smooth L1 on the
     planner's mean, Gaussian likelihood for its deviation), and on a share of rows
     the answers are swapped with another sample's (coherent but wrong) while the planner target stays the
     true one — so the planner relies on vision and not on what the CoT says (ORION-like).
4. Weights (safetensors), config and tokenizer are written to ``weights/`` (or ``--out``).

Everything random derives from the seed; the wall time of each stage is printed.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

DEFAULTS = {
    "kv": {"steps": 3600, "batch": 48, "lr": 2e-3, "counterfactual_share": 0.4, "veto_share": 0.8,
           "veto_weight": 3.0, "vocab": 640},
    "qa": {"steps": 2700, "batch": 24, "lr": 2e-3, "mismatch_share": 0.5, "plan_weight": 5.0, "nll_weight": 0.2,
           "vocab": 768},
}


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _schedule(step: int, total: int, lr: float) -> float:
    import math

    warm = max(1, total // 20)
    if step < warm:
        return lr * (step + 1) / warm
    return lr * 0.5 * (1 + math.cos(math.pi * (step - warm) / max(1, total - warm)))


def train_kv(dataset, seed: int, steps: int | None = None, threads: int = 2, log=_log, batch: int | None = None):
    """Train the ``kv`` network on ``dataset``; returns ``(network, codec, config)``."""
    import numpy as np
    import torch
    from torch.nn import functional as F
    from transformers import DynamicCache

    from .common import ModelConfig, TextCodec, configure_torch, ego_features
    from .kv_model import KVNetwork, normalise_controls

    settings = dict(DEFAULTS["kv"], steps=steps or DEFAULTS["kv"]["steps"], batch=batch or DEFAULTS["kv"]["batch"])
    configure_torch(threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng([seed, 0x4B56])
    codec = TextCodec.train(dataset.sentences + dataset.cf_sentences, settings["vocab"])
    config = ModelConfig(kind="kv", vocab_size=codec.vocab_size, context=256, max_cot_tokens=40,
                         training={"seed": seed, **settings, "samples": len(dataset)})
    network = KVNetwork(config)
    ids = codec.ids
    true_ids = [[ids["<cot>"], *codec.encode(t), ids["</cot>"]] for t in dataset.sentences]
    cf_ids = [[ids["<cot>"], *codec.encode(t), ids["</cot>"]] for t in dataset.cf_sentences]
    targets = torch.tensor(normalise_controls(dataset.sentence_controls), dtype=torch.float32)
    cf_targets = torch.tensor(normalise_controls(dataset.cf_controls), dtype=torch.float32)
    ego = ego_features(dataset.speeds, dataset.commands)
    perception = torch.tensor(dataset.perception, dtype=torch.float32)
    probe = _perception_probe(network)
    params = list(network.parameters()) + list(probe.parameters())
    optimiser = torch.optim.AdamW(params, lr=settings["lr"], weight_decay=0.01)
    network.train()
    started = time.perf_counter()
    for step in range(settings["steps"]):
        rows = rng.integers(0, len(dataset), settings["batch"])
        # Rows where vision overrides a "clear road" CoT get it more often: the veto is what the model must
        # not unlearn against the many rows where a counterfactual is obeyed.
        share = np.where(dataset.cf_vetoed[rows], settings["veto_share"], settings["counterfactual_share"])
        counterfactual = rng.random(len(rows)) < share
        seqs = [cf_ids[r] if c else true_ids[r] for r, c in zip(rows, counterfactual, strict=True)]
        token_ids, real = _pad(seqs, ids["<pad>"])
        images = _augment(dataset.images[rows], rng)
        prefix = network.prefix_embeddings(images, ego[rows])
        embeds = torch.cat([prefix, network.lm.get_input_embeddings()(token_ids)], dim=1)
        mask = torch.cat([torch.ones(len(rows), prefix.shape[1], dtype=torch.bool), real], dim=1)
        out = network.lm(inputs_embeds=embeds, attention_mask=mask.long(), cache=DynamicCache(),
                         use_cache=True)
        logits = out.logits[:, prefix.shape[1] : -1]
        lm_mask = real[:, 1:] & torch.from_numpy(~counterfactual)[:, None]
        lm_loss = F.cross_entropy(logits[lm_mask], token_ids[:, 1:][lm_mask])
        x1 = torch.where(torch.from_numpy(counterfactual)[:, None, None], cf_targets[rows], targets[rows])
        x0 = torch.randn_like(x1)
        t = torch.sigmoid(torch.randn(len(rows)))  # logit-normal flow times
        xt = (1 - t)[:, None, None] * x0 + t[:, None, None] * x1
        kv = [(layer.keys, layer.values) for layer in out.cache.layers]
        velocity = network.head(xt, t, kv, mask)
        # A vetoed "clear road" row weighs more: braking for a salient obstacle against the CoT is the one
        # place where vision must beat the text, and such rows are few.
        vetoed = torch.from_numpy(counterfactual & dataset.cf_vetoed[rows])
        row_weight = 1.0 + (settings["veto_weight"] - 1.0) * vetoed.float()
        flow_loss = ((velocity - (x1 - x0)).pow(2).mean(dim=(1, 2)) * row_weight).sum() / row_weight.sum()
        aux_loss = _perception_loss(probe, prefix, perception[rows])
        loss = lm_loss + flow_loss + aux_loss
        _update(optimiser, params, loss, _schedule(step, settings["steps"], settings["lr"]))
        if step % 200 == 0 or step == settings["steps"] - 1:
            log(f"  kv step {step:5d}  lm {lm_loss.item():.3f}  flow {flow_loss.item():.3f}  "
                f"perception {aux_loss.item():.3f}  "
                f"{time.perf_counter() - started:.0f} s")
    return network.eval(), codec, config


def train_qa(dataset, seed: int, steps: int | None = None, threads: int = 2, log=_log, batch: int | None = None):
    """Train the ``qa`` network on ``dataset``; returns ``(network, codec, config)``."""
    import numpy as np
    import torch
    from torch.nn import functional as F

    from .common import ModelConfig, TextCodec, configure_torch, ego_features
    from .kv_model import normalise_controls
    from .qa_model import QUESTIONS, SLOTS, QANetwork

    settings = dict(DEFAULTS["qa"], steps=steps or DEFAULTS["qa"]["steps"], batch=batch or DEFAULTS["qa"]["batch"])
    configure_torch(threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng([seed, 0x5141])
    corpus = [s[slot] for s in dataset.slots for slot in SLOTS] + list(QUESTIONS.values())
    codec = TextCodec.train(corpus, settings["vocab"])
    config = ModelConfig(kind="qa", vocab_size=codec.vocab_size, context=640, max_cot_tokens=48,
                         training={"seed": seed, **settings, "samples": len(dataset)})
    network = QANetwork(config)
    ids = codec.ids
    questions = {slot: codec.encode(QUESTIONS[slot]) for slot in SLOTS}
    answers = [{slot: codec.encode(s[slot]) for slot in SLOTS} for s in dataset.slots]
    targets = torch.tensor(normalise_controls(qa_targets(dataset)), dtype=torch.float32)
    ego = ego_features(dataset.speeds, dataset.commands)
    perception = torch.tensor(dataset.perception, dtype=torch.float32)
    probe = _perception_probe(network)
    params = list(network.parameters()) + list(probe.parameters())
    optimiser = torch.optim.AdamW(params, lr=settings["lr"], weight_decay=0.01)
    network.train()
    started = time.perf_counter()
    for step in range(settings["steps"]):
        rows = rng.integers(0, len(dataset), settings["batch"])
        mismatched = rng.random(len(rows)) < settings["mismatch_share"]
        donors = np.where(mismatched, rng.integers(0, len(dataset), len(rows)), rows)
        seqs, supervised = [], []
        for donor in donors:
            seq, sup = [], []
            for slot in SLOTS:
                seq += questions[slot]
                sup += [False] * len(questions[slot])
                answer = [ids["<a>"], *answers[donor][slot], ids["</a>"]]
                seq += answer
                sup += [False] + [True] * (len(answer) - 1)  # predict each answer token and the end marker
            seqs.append(seq + [ids["<plan>"]])
            supervised.append(sup + [False])
        token_ids, real = _pad(seqs, ids["<pad>"])
        sup_mask, _ = _pad(supervised, False)
        images = _augment(dataset.images[rows], rng)
        prefix = network.prefix_embeddings(images, ego[rows])
        embeds = torch.cat([prefix, network.lm.get_input_embeddings()(token_ids)], dim=1)
        mask = torch.cat([torch.ones(len(rows), prefix.shape[1], dtype=torch.bool), real], dim=1)
        out = network.lm(inputs_embeds=embeds, attention_mask=mask.long(), output_hidden_states=True)
        p = prefix.shape[1]
        logits = out.logits[:, p - 1 : -1]  # position j predicts token j
        lm_mask = sup_mask.bool() & torch.from_numpy(~mismatched)[:, None]
        lm_loss = F.cross_entropy(logits[lm_mask], token_ids[lm_mask])
        plan_pos = p + real.sum(dim=1) - 1
        hidden = out.hidden_states[-1][torch.arange(len(rows)), plan_pos]
        mean, log_std = network.plan_distribution(hidden, prefix)
        plan_loss = F.smooth_l1_loss(mean, targets[rows])
        # The deviation is learnt by likelihood around the (detached) mean: how far the expert's controls
        # scatter for what the model sees; the mean's own fit stays the smooth-L1 one.
        nll_loss = F.gaussian_nll_loss(mean.detach(), targets[rows], torch.exp(2.0 * log_std), eps=1e-8)
        aux_loss = _perception_loss(probe, prefix, perception[rows])
        loss = lm_loss + settings["plan_weight"] * plan_loss + settings["nll_weight"] * nll_loss + aux_loss
        _update(optimiser, params, loss, _schedule(step, settings["steps"], settings["lr"]))
        if step % 200 == 0 or step == settings["steps"] - 1:
            log(f"  qa step {step:5d}  lm {lm_loss.item():.3f}  plan {plan_loss.item():.3f}  "
                f"nll {nll_loss.item():.3f}  "
                f"perception {aux_loss.item():.3f}  "
                f"{time.perf_counter() - started:.0f} s")
    return network.eval(), codec, config


def qa_targets(dataset):
    """The ``qa`` planner's targets ``(N, 30, 2)``: the expert's plan, except that a "stop" decision
    brakes from now on, uniformly to the stop point (approaching a far one at walking pace) — the profile
    ``kv`` learns. The expert's own plan brakes as late as comfort allows; a planner that regresses it to
    within a few metres, from a lamp that is a pixel or two wide, brakes too late and runs the light."""
    import numpy as np

    stopping = np.array([d == "stop" for d in dataset.decisions])
    return np.where(stopping[:, None, None], dataset.sentence_controls, dataset.controls)


def _perception_probe(network):
    """A training-only head that reads the vision tokens and predicts the ground truth's perception targets
    (stop?, critical kind, blocking?, distance, light colour): it teaches the small encoder to see
    obstacles and lights quickly; it is not part of the saved model."""
    from torch import nn

    from .data import PERCEIVED_KINDS, PERCEIVED_LIGHTS

    grid = network.encoder.n_tokens - 1
    outputs = 3 + len(PERCEIVED_KINDS) + len(PERCEIVED_LIGHTS)
    return nn.Sequential(nn.Flatten(), nn.Linear(grid * network.config.hidden, 128), nn.GELU(),
                         nn.Linear(128, outputs))


def _perception_loss(probe, prefix, targets):
    from torch.nn import functional as F

    from .data import PERCEIVED_KINDS

    out = probe(prefix[:, :-1])  # the vision tokens (the last prefix token is the ego's)
    k = len(PERCEIVED_KINDS)
    present = targets[:, 1] > 0
    distance = F.smooth_l1_loss(out[:, 2][present], targets[:, 3][present]) if present.any() else out.sum() * 0
    return (F.binary_cross_entropy_with_logits(out[:, 0], targets[:, 0])
            + F.binary_cross_entropy_with_logits(out[:, 1], targets[:, 2])
            + 10.0 * distance
            + F.cross_entropy(out[:, 3 : 3 + k], targets[:, 1].long())
            + F.cross_entropy(out[:, 3 + k :], targets[:, 4].long()))


SHIFT_PIXELS = (0, 1)
"""Largest random shift of a training image, (horizontal, vertical) pixels. Not sideways: a sideways shift
looks like a turn of the car while the steering target stays the same, and a model trained with ±2 px
drifted out of its lane."""
GAIN_RANGE = (0.9, 1.1)
"""Random brightness gain of a training image."""


def _augment(images, rng):
    """Camera images ``(N, H, W, 3)`` uint8 → ``(N, 3, H, W)`` floats, each shifted by up to
    :data:`SHIFT_PIXELS` (edges repeated) and brightened or darkened a little: the decision must come from
    what is in the scene, not from where a building edge falls on the pixel grid (without this the small
    encoder flipped its reading of a red lamp between frames a few centimetres apart)."""
    import numpy as np
    import torch
    from torch.nn import functional as F

    from .common import image_batch

    batch = image_batch(images)
    dx_max, dy_max = SHIFT_PIXELS
    padded = F.pad(batch, (dx_max, dx_max, dy_max, dy_max), mode="replicate")
    height, width = batch.shape[-2:]
    dx = rng.integers(0, 2 * dx_max + 1, len(batch))
    dy = rng.integers(0, 2 * dy_max + 1, len(batch))
    gain = torch.from_numpy(rng.uniform(*GAIN_RANGE, len(batch)).astype(np.float32))
    shifted = torch.stack([padded[i, :, y : y + height, x : x + width] for i, (x, y) in enumerate(zip(dx, dy, strict=True))])
    return (shifted * gain[:, None, None, None]).clamp(0.0, 1.0)


def _pad(seqs, pad):
    import torch

    width = max(len(s) for s in seqs)
    dtype = torch.bool if isinstance(pad, bool) else torch.long
    out = torch.full((len(seqs), width), pad, dtype=dtype)
    real = torch.zeros((len(seqs), width), dtype=torch.bool)
    for i, s in enumerate(seqs):
        out[i, : len(s)] = torch.tensor(s, dtype=dtype)
        real[i, : len(s)] = True
    return out, real


def _update(optimiser, params, loss, lr) -> None:
    import torch

    for group in optimiser.param_groups:
        group["lr"] = lr
    optimiser.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(params, 1.0)
    optimiser.step()


def run(models: list[str], seed: int, episodes: int, steps: int | None, out: Path | None, threads: int,
        data_cache: Path | None = None) -> dict:
    """Generate data once, train each model, save its bundle; returns wall times per stage (s).

    With ``data_cache``, the dataset is read from that ``.npz`` if it exists, else generated and written
    there (so two models can be trained in parallel processes from one generation)."""
    from .common import save_bundle
    from .data import Dataset, generate

    times = {}
    started = time.perf_counter()
    if data_cache is not None and data_cache.is_file():
        dataset = Dataset.load(data_cache)
        _log(f"data: {len(dataset)} samples read from {data_cache}")
    else:
        _log(f"generating data: {episodes} expert episodes (seed {seed})")
        dataset = generate(seed, episodes, progress=_log, workers=threads)
        if data_cache is not None:
            dataset.save(data_cache)
    times["data"] = time.perf_counter() - started
    _log(f"data: {len(dataset)} samples in {times['data']:.0f} s")
    trainers = {"kv": train_kv, "qa": train_qa}
    for name in models:
        t0 = time.perf_counter()
        network, codec, config = trainers[name](dataset, seed, steps=steps, threads=threads)
        config.training["wall_time_s"] = round(time.perf_counter() - t0, 1)
        paths = save_bundle(name, network, config, codec, out)
        times[name] = time.perf_counter() - t0
        _log(f"{name}: trained in {times[name]:.0f} s -> {paths['weights']}")
    times["total"] = time.perf_counter() - started
    return times


def _passive_threads() -> None:
    """Let torch's OpenMP threads sleep rather than spin while they wait for each other (unless the
    environment says otherwise; read when torch first loads). On a machine shared with other jobs a
    spinning thread burns the time slice its partner needs: training ran ~15× slower so. The results are
    the same either way (same threads, same work split)."""
    import os

    os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


@click.command("train-neural")
@click.option("--model", "model", type=click.Choice(["kv", "qa", "both"]), default="both", show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--episodes", type=click.IntRange(1), default=420, show_default=True,
              help="Expert episodes of randomised scenario variants to learn from.")
@click.option("--steps", type=click.IntRange(1), default=None, help="Optimiser steps (default per model).")
@click.option("--out", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where to write the bundles (default: the plugin's weights/ folder).")
@click.option("--threads", type=click.IntRange(1), default=2, show_default=True,
              help="Torch threads, and processes driving the expert episodes.")
@click.option("--data-cache", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="An .npz to read the expert data from, or to write it to (generated from --seed).")
def train_command(model: str, seed: int, episodes: int, steps: int | None, out: Path | None, threads: int,
                  data_cache: Path | None) -> None:
    """Rebuild the neural reference models' weights from a seed (expert data → tokenizer → training)."""
    _passive_threads()
    models = ["kv", "qa"] if model == "both" else [model]
    times = run(models, seed, episodes, steps, out, threads, data_cache)
    click.echo("wall time: " + ", ".join(f"{k} {v:.0f} s" for k, v in times.items()))


if __name__ == "__main__":  # pragma: no cover
    import subprocess

    sys.exit(subprocess.call([sys.executable, "-m", "vladrivebench", "train-neural", *sys.argv[1:]]))
