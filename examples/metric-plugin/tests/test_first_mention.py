"""The example metric, registered in an isolated registry (nothing installed is relied upon), checked with
the conformance kit of ``vladrivebench.testing`` and its pytest fixtures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from vdb_metric_example import plugin
from vladrivebench import Actor, Control, CoT, EgoState, GroundTruth, Labels, Observation, Trajectory
from vladrivebench.labels import LabelStore, label_key
from vladrivebench.metrics import AnalysisDataset
from vladrivebench.testing import (
    EpisodeWriter,
    check_metric,
    compute_all,
    label_items,
    load_dataset,
    read_directory,
)


def write(path: Path, mention_below: float | None) -> None:
    meta = {"episode_id": path.stem, "model": {"name": "m", "options": {}},
            "scenario": {"id": "P.1", "group": "Pedestrian (in-lane)"}, "seed": 0}
    trajectory = Trajectory(np.array([1.0]), np.array([[1.0, 0.0]]))
    with EpisodeWriter(path, meta) as writer:
        for step in range(70):
            x = step * 0.5
            truth = GroundTruth(step, step * 0.1, (Actor("p", "pedestrian", 40.0, 0.0),), "p", "pedestrian", 40.0 - x)
            obs = Observation(step, step * 0.1, np.zeros((1, 1, 3), np.uint8), EgoState(x, 0.0, 0.0, 5.0),
                              "follow_lane", truth)
            said = mention_below is not None and 40.0 - x < mention_below
            writer.write_step(obs, CoT("pedestrian ahead" if said else "clear"), trajectory, Control(0, 0, 0, 5.0))
        writer.finish({"terminal": "route_complete"})


def test_the_metric_conforms(vdb_registry, vdb_dataset):
    """The conformance kit: tables whose every cell has a count, ids and titles, deterministic."""
    registry = vdb_registry(("first-mention", plugin))
    (table,) = check_metric(registry.create("metric", "first_mention"), vdb_dataset)
    assert [row.labels for row in table.rows] == [("Pedestrian (in-lane)",), ("Traffic light (red)",)]


def test_first_mention_table(tmp_path, vdb_registry):
    for i, below in enumerate([30.0, 20.0, 10.0, None]):
        write(tmp_path / f"e{i}.mcap", below)
    episodes, _ = read_directory(tmp_path)
    store = LabelStore(tmp_path, "hand")
    store.add([(item, label_key(item, "hand", "1"), Labels(target_mentioned=item.text.startswith("pedestrian")))
               for _, _, item in label_items(episodes)], "1")
    dataset: AnalysisDataset = load_dataset(tmp_path)
    registry = vdb_registry(("first-mention", plugin), core=True)
    sections = compute_all(dataset, registry)
    names = [s.metric for s in sections]
    assert names.index("first_mention") == names.index("mention_rate") + 1
    table = next(s for s in sections if s.metric == "first_mention").tables[0]
    median, never = table.cell("Pedestrian (in-lane)", 0), table.cell("Pedestrian (in-lane)", 1)
    assert (median.value, median.count) == (19.5, 3)  # first mentions at 29.5, 19.5 and 9.5 m
    assert (never.value, never.count) == (1.0, 4)
