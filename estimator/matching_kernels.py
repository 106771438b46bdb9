"""Compiled greedy one-to-one matching of the association (`association.associate`): the gated pairs ordered by
their d2 (a radix sort of its bits, exact ties by map point, then detection), then taken while both are free.

Checked by: tests/estimator/test_association.py (greedy against an all-pairs loop,
    ::test_pair_order_is_lexsort_with_ties, ::test_radix_argsort_is_the_stable_argsort)
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
def choose(j, i, d2, gate, m, n):
    """The candidate pairs (j, i, d2) with d2 <= gate (NaN never), ordered by `order_by_d2` and taken by
    `greedy_one_to_one`: (j, i, d2) of the chosen, in the candidates' order (`association.choose`).

    Checked by: tests/estimator/test_association.py::test_matches_brute_force_and_is_one_to_one
    """
    inside = np.flatnonzero(d2 <= gate)
    jg, ig, dg = j[inside], i[inside], d2[inside]
    chosen = greedy_one_to_one(order_by_d2(jg, ig, dg, n), jg, ig, m, n)
    return jg[chosen], ig[chosen], dg[chosen]


@njit(cache=True)
def order_by_d2(j, i, d2, n):
    """np.lexsort((i, j, d2)): ascending d2, ties by j, then i: a radix sort of d2 (`_radix_argsort`), then the
    rare exact ties put in (j, i, index) order.

    Checked by: tests/estimator/test_association.py::test_pair_order_is_lexsort_with_ties,
        ::test_radix_argsort_is_the_stable_argsort
    """
    return _order_ties(_radix_argsort(d2), j, i, d2, n)


_SIGN = np.int64(-2**63)  # the sign bit of an int64


@njit(cache=True)
def _radix_argsort(x):
    """np.argsort(x, kind="stable") of floats without NaN, as a least-significant-digit radix sort of their bits in
    six passes of 11 bits (a pass whose digit all keys share is skipped). A float's bits order as an unsigned
    integer once a positive one's sign bit is set and a negative one's every bit flipped (-0.0 taken as 0.0,
    which it equals). Half the time of NumPy's default argsort on the gated pairs' d2 of a city drive (50-65
    against 95-110 us for 2,300 pairs).
    """
    n = len(x)
    key = x.view(np.int64).copy()
    for q in range(n):
        key[q] = ~key[q] if key[q] < 0 and key[q] != _SIGN else key[q] | _SIGN  # -0.0 as 0.0
    order = np.arange(n)
    tkey, tord = np.empty(n, np.int64), np.empty(n, np.int64)
    count = np.empty(2049, np.int64)
    for shift in range(0, 66, 11):  # >> is arithmetic: the top digit's sign-extended bits keep it monotonic
        count[:] = 0
        for q in range(n):
            count[((key[q] >> shift) & 2047) + 1] += 1
        shared = False
        for c in range(2048):
            shared = shared or count[c + 1] == n
            count[c + 1] += count[c]
        if shared:
            continue
        for q in range(n):
            d = (key[q] >> shift) & 2047
            tkey[count[d]] = key[q]
            tord[count[d]] = order[q]
            count[d] += 1
        key, tkey = tkey, key
        order, tord = tord, order
    return order


@njit(cache=True)
def _order_ties(order, j, i, d2, n):
    s = 0
    while s < len(order):
        e = s + 1
        while e < len(order) and d2[order[e]] == d2[order[s]]:
            e += 1
        if e - s > 1:
            run = np.sort(order[s:e])  # ties of (j, i) too go by index (the sort of d2 is stable: a safeguard)
            key = np.empty(e - s, np.int64)
            for t in range(e - s):
                key[t] = j[run[t]] * n + i[run[t]]
            order[s:e] = run[np.argsort(key, kind="mergesort")]
        s = e
    return order
