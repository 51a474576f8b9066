"""Properties of the cut: the kept text is the CoT's own beginning, at most k % of it, growing with k."""

from __future__ import annotations

import math

from hypothesis import given
from hypothesis import strategies as st
from vdb_paradigm_truncation.truncate import cut, share, truncate, word_ends

words = st.text(alphabet="abcdefgh.,", min_size=1, max_size=6)
spaces = st.sampled_from([" ", "  ", "\n", "\t "])
texts = st.lists(st.tuples(words, spaces), max_size=12).map(lambda parts: "".join(w + s for w, s in parts).rstrip())
segment_lists = st.lists(texts, min_size=1, max_size=3)
levels = st.floats(min_value=0, max_value=100, allow_nan=False)


def n_words(text: str) -> int:
    return len(text.split())


@given(segment_lists, levels)
def test_words_kept_are_the_first_floor_k_percent(segments, level):
    kept, used, total = truncate(segments, level)
    assert total == sum(n_words(t) for t in segments)
    assert used == (total if level >= 100 else math.floor(level * total / 100 + 1e-9))
    assert sum(n_words(t) for t in kept) == used
    assert used <= total * level / 100 + 1e-9 or level >= 100


@given(segment_lists, levels)
def test_the_kept_text_is_the_cots_own_beginning_segment_by_segment(segments, level):
    kept, _, _ = truncate(segments, level)
    assert len(kept) == len(segments)
    cut_seen = False
    for original, piece in zip(segments, kept, strict=True):
        assert original.startswith(piece)
        if cut_seen:
            assert piece == ""  # after the cut every segment is empty
        if piece != original:
            cut_seen = True


@given(segment_lists, levels, levels)
def test_more_of_the_cot_is_kept_at_a_higher_level(segments, a, b):
    low, high = sorted((a, b))
    assert truncate(segments, low)[1] <= truncate(segments, high)[1]


@given(segment_lists)
def test_the_whole_and_nothing(segments):
    assert truncate(segments, 100)[0] == list(segments)
    assert truncate(segments, 0)[0] == ["" for _ in segments]


@given(segment_lists, levels)
def test_a_token_budget_is_never_exceeded(segments, level):
    def count(text):  # two tokens per word, as a sub-word tokenizer might
        return 2 * n_words(text)

    kept, used, total = truncate(segments, level, count)
    assert total == sum(count(t) for t in segments)
    assert used == sum(count(t) for t in kept)
    if level < 100:
        assert used <= share(level, total)
        assert share(level, total) - used < 2  # one more word would not fit


def test_cut_and_word_ends():
    assert word_ends("Stop  now.") == [4, 10]
    assert cut("Stop  now. Then go", 2) == "Stop  now."
    assert cut("Stop now", 0) == "" and cut("Stop now", 5) == "Stop now"
