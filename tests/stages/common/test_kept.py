"""The bounded cache (stages/common/kept.py): an answer computed once per key, the least
recently used dropped first."""

import pytest

from stages.common.kept import Kept


def test_an_answer_is_computed_once_and_the_least_recently_used_goes_first():
    computed = []
    kept = Kept(2)

    def answer(key):
        return kept.get(key, lambda: computed.append(key) or f"answer {key}")

    assert answer("a") == "answer a" and answer("b") == "answer b" and answer("a") == "answer a"
    assert computed == ["a", "b"]
    answer("c")  # "b" was used least recently
    assert len(kept) == 2 and computed == ["a", "b", "c"]
    answer("a")
    answer("b")
    assert computed == ["a", "b", "c", "b"]


def test_a_cache_of_nothing_is_refused():
    with pytest.raises(ValueError, match="at least one"):
        Kept(0)
