"""Delay languages, event-based languages and prefixes (Definitions 2-4, 6; eqs. (2)-(3)).

Expected values are worked out by hand from the paper's Examples 1-5 and from the
definition "data of step i is known at step k iff tau(i) <= k - i".
"""

import pickle

import numpy as np
import pytest

from netsense.sensing.delays import DelayLanguage, event_set, event_string


def test_example_1_and_3_language_and_reduction():
    L = DelayLanguage.each_delayed_at_most(2, 2)
    assert [("".join(map(str, w))) for w in L.words] == \
        ["00", "01", "02", "10", "11", "12", "20", "21", "22"]
    E = L.event_language()
    # Example 3: L^E' = {e01 e13, e01 e12, e00 e13, e00 e12, e00 e11, e00 e10}
    assert E.sequences == ((1, 3), (1, 2), (0, 3), (0, 2), (0, 1), (0, 0))
    assert [E.strings(a) for a in range(2)] == [("1", "11"), ("1", "10")]
    # 01 and 02 are indistinguishable over T = 2, so are 11/12 and 21/22
    assert E.word_to_sequence == (0, 1, 1, 2, 3, 3, 4, 5, 5)


def test_event_definitions_examples_2_and_4():
    assert event_set(0) == ("0", "1")
    assert event_set(1) == ("00", "01", "10", "11")
    assert event_string(1, 1) == "01"
    with pytest.raises(ValueError, match="event index"):
        event_string(1, 4)
    E = DelayLanguage.each_delayed_at_most(2, 2).event_language()
    assert E.prefixes(0) == ((1,), (1, 3))  # Example 4


def test_eq2_subscripts_hand_checked():
    L = DelayLanguage.each_delayed_at_most(2, 3)
    # word 2 0 1: k=0 nothing; k=1 data 1 ("01"); k=2 data 0 and 1 ("110")
    assert L.event_indices((2, 0, 1)) == (0, 1, 6)
    np.testing.assert_array_equal(L.event_matrix((2, 0, 1)),
                                  [[0, 0, 0], [0, 1, 0], [1, 1, 0]])
    # Example 5: E_1, E_2 of sequences e01 e13 and e01 e12
    E = DelayLanguage.each_delayed_at_most(2, 2).event_language()
    np.testing.assert_array_equal(E.event_matrix(0), [[1, 0], [1, 1]])
    np.testing.assert_array_equal(E.event_matrix(1), [[1, 0], [1, 0]])


def test_event_matrix_two_routes_agree_and_are_monotone():
    L = DelayLanguage.each_delayed_at_most(2, 4)
    E = L.event_language()
    for w, a in zip(L.words, E.word_to_sequence, strict=True):
        M = L.event_matrix(w)
        np.testing.assert_array_equal(M, E.event_matrix(a))
        for k in range(3):  # once received, a measurement stays available
            assert np.all(M[k + 1, : k + 1] >= M[k, : k + 1])


def test_reduced_size_batch_reactor_language():
    # tau(i) in {0,1,2}: steps 0..2 give 3 distinguishable cases each, step 3 gives 3
    # (0, 1, >=2), step 4 gives 2 (on time / late): 3^4 * 2 = 162
    E = DelayLanguage.each_delayed_at_most(2, 5).event_language()
    assert len(E) == 162
    assert len(DelayLanguage.each_delayed_at_most(2, 5).first_delayed().words) == 162


def test_prefix_tree_of_example_3():
    t = DelayLanguage.each_delayed_at_most(2, 2).event_language().prefix_tree()
    assert len(t) == 1 + 2 + 6
    root = t.children[0]
    assert set(root) == {0, 1}
    assert t.sequences[root[1]] == (0, 1)
    assert t.sequences[root[0]] == (2, 3, 4, 5)
    assert set(t.children[root[0]]) == {0, 1, 2, 3}
    assert t.path((0, 2)) == [0, root[0], t.children[root[0]][2]]


def test_at_most_missing_uses_never_arriving_delay():
    L = DelayLanguage.at_most_missing(1, 3)
    assert sorted(L.words) == [(0, 0, 0), (0, 0, 3), (0, 3, 0), (3, 0, 0)]
    np.testing.assert_array_equal(L.event_matrix((0, 3, 0))[:, 1], [0, 0, 0])
    assert DelayLanguage.from_words(["0x0"]).words == ((0, 3, 0),)


@pytest.mark.parametrize("kwargs, match", [
    (dict(words=((0, 1), (0,)), T=2), "length T"),
    (dict(words=((0, -1),), T=2), ">= 0"),
    (dict(words=((0, 1), (0, 1)), T=2), "distinct"),
    (dict(words=((0, 3),), T=2, tau_bar=2), "tau_bar"),
    (dict(words=(), T=2), "at least one"),
    (dict(words=((0,),), T=0), "T must"),
])
def test_inconsistent_languages_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        DelayLanguage(**kwargs)


def test_bad_word_strings_raise():
    with pytest.raises(ValueError, match="digits"):
        DelayLanguage.from_words(["0a"])
    with pytest.raises(ValueError, match="tau"):
        DelayLanguage.from_words(["00"]).first_delayed()


def test_channel_arrivals_and_truncation():
    s = DelayLanguage.from_words(["21210"]).channel().sampler(np.random.default_rng(0))
    got = [s.next() for _ in range(10)]
    assert got[:5] == [(), (), (0, 1), (), (2, 3, 4)]
    assert got[5:] == [(), (), (5, 6), (), (7, 8, 9)]
    cut = DelayLanguage.from_words(["02"]).channel().sampler(np.random.default_rng(0))
    assert [cut.next() for _ in range(4)] == [(0,), (), (2,), ()]
    keep = DelayLanguage.from_words(["02"]).channel(truncate=False).sampler(
        np.random.default_rng(0))
    assert [keep.next() for _ in range(4)] == [(0,), (), (2,), (1,)]


def test_channel_pickles_and_continues_identically():
    s = DelayLanguage.each_delayed_at_most(2, 3).channel().sampler(np.random.default_rng(3))
    for _ in range(4):
        s.next()
    s2 = pickle.loads(pickle.dumps(s))
    assert [s.next() for _ in range(12)] == [s2.next() for _ in range(12)]
    with pytest.raises(ValueError, match="weights"):
        DelayLanguage.from_words(["00", "01"]).channel(weights=[1.0])
