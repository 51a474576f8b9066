"""The prompt file (shipped, copied, edited, broken) and the SQLite cache keyed by everything that matters."""

from __future__ import annotations

import io

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from vdb_labeler_ensemble.backends import Reply, parse_backend
from vdb_labeler_ensemble.cache import ResponseCache, cache_key
from vdb_labeler_ensemble.labeler import EnsembleLabeler
from vdb_labeler_ensemble.prompt import default_prompt_path, describe_context, load_prompt
from vdb_labeler_ensemble.testing import EMPTY, PEDESTRIAN, item
from vladrivebench import ConfigError


def test_the_shipped_prompt_is_v1_and_its_examples_follow_the_schema():
    prompt = load_prompt()
    assert prompt.version == "v1" and len(prompt.examples) >= 5 and prompt.path == default_prompt_path()
    system, user = prompt.render(item("x", "Brake for the person.", PEDESTRIAN))
    assert "one JSON object" in system
    assert user.rstrip().endswith("CASE-x Brake for the person.\n\nAnswer:".rstrip())
    assert "pedestrian at x=18.0, y=0.4 (18.0 m ahead, 0.4 m to the left)" in user
    assert '"required": ["stated_action", "target_mentioned"' in user
    assert user.count("Example ") == len(prompt.examples)


def test_slotted_cots_and_empty_scenes_render_readably():
    _, user = load_prompt().render(item("s", context=EMPTY, slots={"scene": "Road.", "decision": "Go."}))
    assert "[scene] CASE-s Road.\n[decision] Go." in user
    assert "Critical feature: none in this scene (target_mentioned must be null)" in user
    assert "Actors present (nothing else is there): none" in describe_context(EMPTY)


@settings(deadline=None)
@given(st.dictionaries(st.sampled_from(["critical_kind", "critical_position", "ego_speed", "actors", "lead_gap",
                                        "blocking", "other"]),
                       st.one_of(st.none(), st.floats(), st.text(max_size=8), st.booleans(),
                                 st.lists(st.one_of(st.floats(), st.dictionaries(st.text(max_size=5), st.floats())),
                                          max_size=3)), max_size=6))
def test_any_context_renders_and_never_shows_a_non_finite_number(context):
    text = describe_context(context)
    assert text.startswith("- Critical feature:")
    assert "=nan" not in text and "=inf" not in text and "nan m/s" not in text


def copy_prompt(tmp_path, old: str = "", new: str = ""):
    text = default_prompt_path().read_text()
    path = tmp_path / "mine.toml"
    path.write_text(text.replace(old, new, 1) if old else text)
    return path


@pytest.mark.parametrize("old, new, expected", [
    ('version = "v1"', 'version = ""', "'version' must be a non-empty string"),
    ("\n$cot\n", "\nthe cot\n", "'template' must contain $cot"),
    ("\n$examples\n", "\n$exemples\n", "unknown placeholder $exemples"),
    ("Now label this CoT.", "Now label this CoT for $5.", "stray '$'"),
    ('"stated_action": "decelerating", "target_mentioned": true', '"stated_action": "braking", "target_mentioned": true',
     "example 1: 'answer' does not follow the answer schema: stated_action is \"braking\""),
    ('cot = "A pedestrian', 'cot = ""\nfoo = "A pedestrian', "example 1: give exactly one of 'cot'"),
    ('version = "v1"', 'version = "v1"\ncolour = "blue"', "unknown key 'colour'"),
    ('version = "v1"', 'version = "v1', "not valid TOML"),
])
def test_a_broken_prompt_copy_is_one_line(tmp_path, old, new, expected):
    with pytest.raises(ConfigError) as raised:
        load_prompt(copy_prompt(tmp_path, old, new))
    assert expected in str(raised.value) and "\n" not in str(raised.value)


def test_an_edited_prompt_changes_version_and_cache_keys(tmp_path):
    same = EnsembleLabeler("openai:m", prompt=copy_prompt(tmp_path), cache=None, progress_stream=io.StringIO())
    shipped = EnsembleLabeler("openai:m", cache=None, progress_stream=io.StringIO())
    assert same.version == shipped.version
    edited_path = copy_prompt(tmp_path, 'version = "v1"', 'version = "v1-mine"')
    edited = EnsembleLabeler("openai:m", prompt=edited_path, cache=None, progress_stream=io.StringIO())
    assert "prompt.v1-mine." in edited.version and edited.version != shipped.version
    reworded = EnsembleLabeler("openai:m", prompt=copy_prompt(tmp_path, "careful annotator", "strict annotator"),
                               cache=None, progress_stream=io.StringIO())
    assert reworded.prompt.version == "v1" and reworded.version != shipped.version  # digest, not just the name
    keys = {lab._calls_for(item("k"), lab.prompt.render(item("k")), lab.backends)[0].key
            for lab in (shipped, edited, reworded)}
    assert len(keys) == 3


parts = st.fixed_dictionaries({
    "model": st.sampled_from(["a", "b"]), "temperature": st.sampled_from(["0", "0.5"]),
    "version": st.sampled_from(["v1", "v2"]), "digest": st.sampled_from(["d1", "d2"]),
    "text": st.text(max_size=20), "slots": st.dictionaries(st.sampled_from(["scene", "decision"]), st.text(max_size=5)),
    "context": st.dictionaries(st.sampled_from(["critical_kind", "ego_speed"]),
                               st.one_of(st.none(), st.integers(0, 3), st.sampled_from(["car", "pedestrian"]))),
})


def key_of(p):
    spec = parse_backend(f"openai:{p['model']}?temperature={p['temperature']}")
    return cache_key(spec.identity(), p["version"], p["digest"], p["text"], p["slots"], p["context"])


@settings(deadline=None)
@given(parts, parts)
def test_cache_keys_are_equal_exactly_when_everything_that_matters_is(a, b):
    same = all(a[k] == b[k] for k in a) and list(a["slots"]) == list(b["slots"])
    assert (key_of(a) == key_of(b)) == same


def test_the_cache_persists_and_survives_reopening(tmp_path):
    path = tmp_path / "deep" / "cache.sqlite"
    cache = ResponseCache(path)
    cache.put("k1", "openai:m", "m", "v1", Reply('{"x": 1}', None, "stop"))
    cache.put("k2", "openai:m", "m", "v1", Reply(None, "refused", "stop"))
    cache.close()
    again = ResponseCache(path)
    assert again.get_many(["k1", "k2", "k3"]) == {"k1": Reply('{"x": 1}', None, "stop"),
                                                  "k2": Reply(None, "refused", "stop")}
    assert len(again) == 2
    memory = ResponseCache(None)
    assert memory.get_many(["k1"]) == {} and memory.path is None
