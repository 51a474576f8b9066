"""The lexicon labeler passes the conformance kit (vladrivebench.testing) on sample and logged CoTs."""

from __future__ import annotations

import pytest
from vdb_labeler_lexicon import plugin
from vladrivebench.testing import (
    check_bad_options,
    check_labeler,
    label_items,
    read_directory,
    sample_label_items,
)


@pytest.mark.parametrize("filter_phantom_car", [False, True])
def test_the_lexicon_labeler_conforms(vdb_registry, vdb_episode_dir, filter_phantom_car):
    registry = vdb_registry(("lexicon", plugin))
    labeler = registry.create("labeler", "lexicon", {"filter_phantom_car": filter_phantom_car})
    episodes, _ = read_directory(vdb_episode_dir)
    logged = [item for _, _, item in label_items(episodes)]
    check_labeler(labeler, sample_label_items() + logged[::7], name="lexicon")


def test_bad_lexicon_options_are_one_line_errors(vdb_registry):
    registry = vdb_registry(("lexicon", plugin))
    check_bad_options(lambda options: registry.create("labeler", "lexicon", options),
                      [{"filter_phantom_car": "maybe"}], name="lexicon")
