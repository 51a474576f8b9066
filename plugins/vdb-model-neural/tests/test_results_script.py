"""The README regeneration script: every command that runs episodes gets the lockstep batch size."""

from __future__ import annotations

from vdb_model_neural.results import experiments, with_batch

SEEDS = {"open": 1, "qa_open": 1, "closed": 1, "safety": 1, "driving": 1, "suite": 1}


def test_every_run_and_intervene_command_gets_the_batch_and_nothing_else_does():
    for _, commands in experiments(SEEDS):
        for command in with_batch(commands, 16):
            runs_episodes = command[0] in ("run", "intervene")
            assert (command[-2:] == ["--batch", "16"]) == runs_episodes
            assert command.count("--batch") == int(runs_episodes)
