"""Compiled greedy one-to-one matching of the association (`association.choose`): the gated pairs, ordered by
their d2 (NumPy's argsort, then the exact ties by map point, then detection), taken while both are free.

Checked by: tests/estimator/test_association.py (greedy against an all-pairs loop,
    ::test_pair_order_is_lexsort_with_ties, ::test_pair_order_of_any_floats_is_lexsort)
"""

from __future__ import annotations

import numpy as np

from .jit import njit


@njit(cache=True)
def greedy_one_to_one(order, j, i, m, n):
    """Walk the pairs in `order` (ascending d2, ties by j then i) and take each whose map point and detection
    are both still free: the global greedy matching by smallest d2.

    Checked by: tests/estimator/test_association.py::test_matches_brute_force_and_is_one_to_one
    """
    used_j = np.zeros(m, dtype=np.bool_)
    used_i = np.zeros(n, dtype=np.bool_)
    chosen = np.zeros(len(j), dtype=np.bool_)
    for k in order:
        if not used_j[j[k]] and not used_i[i[k]]:
            used_j[j[k]] = True
            used_i[i[k]] = True
            chosen[k] = True
    return chosen


@njit(cache=True)
def take(order, j, i, d2, m, n):
    """The gated pairs (j, i, d2) taken by `greedy_one_to_one` in `order` (`association.order_by_d2`): (j, i, d2)
    of the chosen, in the pairs' order (`association.choose`).

    Checked by: tests/estimator/test_association.py::test_matches_brute_force_and_is_one_to_one
    """
    chosen = greedy_one_to_one(order, j, i, m, n)
    return j[chosen], i[chosen], d2[chosen]


@njit(cache=True)
def order_ties(order, j, i, d2, n):
    """`order`, an argsort of d2 (stable or not), with each run of equal d2 put in (j, i, index) order: then
    it is np.lexsort((i, j, d2)) (n: the detections' count, for the key j n + i). Rewritten in place, and
    returned.

    Checked by: tests/estimator/test_association.py::test_pair_order_is_lexsort_with_ties,
        ::test_pair_order_of_any_floats_is_lexsort
    """
    s = 0
    while s < len(order):
        e = s + 1
        while e < len(order) and d2[order[e]] == d2[order[s]]:
            e += 1
        if e - s > 1:
            run = np.sort(order[s:e])  # ties of (j, i) too go by index, whatever the argsort
            key = np.empty(e - s, np.int64)
            for t in range(e - s):
                key[t] = j[run[t]] * n + i[run[t]]
            order[s:e] = run[np.argsort(key, kind="mergesort")]
        s = e
    return order
