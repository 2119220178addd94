"""The paper's bounds on the freshness indices and on convergence, as functions of ``N, T``.

What a network researcher asks of the freshness-index observer (Section IV) on a switching
pattern that satisfies Assumption 1 with period ``T``:

* every index is finite from ``(N-1)T`` on (Lemma 3, :func:`lemma3_bound`); the proof's
  argument gives the sharper ``NT - 1`` (:func:`sharp_index_bound`), which some graphs
  attain;
* afterwards no index exceeds ``2(N-1)T`` (Lemma 5, :func:`lemma5_bound`);
* with deadbeat gains the estimate is exact after ``n + 2N(N-1)T`` steps (Corollary 1,
  :func:`corollary1_bound`); with Theorem 1's rate-ordered gains the error bound of eq. (33)
  starts at ``(2N-1)(N-1)T`` (:func:`theorem1_onset`).

The measured counterparts are :func:`netsense.graphs.aoi.trigger_step`,
:func:`netsense.graphs.aoi.worst_index` and :func:`netsense.observers.run.steps_to_tolerance`.
"""

from __future__ import annotations

__all__ = ["corollary1_bound", "lemma3_bound", "lemma5_bound", "sharp_index_bound",
           "theorem1_onset"]


# ----------------------------------------------------------------------------- bounds
def lemma3_bound(N: int, T: int | float) -> float:
    """``(N-1)T``: every index is finite from this step on (Lemma 3, eq. (15))."""
    return (N - 1) * T


def lemma5_bound(N: int, T: int | float) -> float:
    """``2(N-1)T``: bound on every index for ``k >= (N-1)T`` (Lemma 5, eq. (17))."""
    return 2 * (N - 1) * T


def sharp_index_bound(N: int, T: int | float) -> float:
    """``NT - 1``: a sharper form of Lemma 5 (not in the paper), attained by some graphs.

    For ``k >= (N-1)T`` every index satisfies ``tau_i^{(j)}[k] <= NT - 1``. Proof: call
    information about substate ``j`` *as fresh as* ``t`` when its index is at most
    ``k - t``. Freshness as fresh as ``t`` never gets lost (an agent adopts only strictly
    fresher data, eqs. (9), (13), and otherwise ages by one, eq. (14)), and an agent with
    an in-neighbour holding it gets it (the rule adopts the freshest neighbour, or keeps
    something at least as fresh). In window ``[wT, (w+1)T)`` the union graph is strongly
    connected, so some edge leaves the set of agents holding data as fresh as ``wT``: the
    set grows by one agent per window, and by ``(w + N - 1)T`` all ``N`` agents hold data
    as fresh as ``wT``. For ``k`` in window ``w'``, take ``w = w' - N + 1``: the age is at
    most ``k - (w' - N + 1)T <= NT - 1``. The static directed ring (``T = 1``: ``N - 1``)
    and random jointly connected graphs (e.g. ``N = 4``, ``T = 4``: 15) attain it.
    """
    return N * T - 1


def corollary1_bound(n: int, N: int, T: int | float) -> float:
    """``n + 2N(N-1)T``: deadbeat gains give zero error from this step on (Corollary 1)."""
    return n + 2 * N * (N - 1) * T


def theorem1_onset(N: int, T: int | float) -> float:
    """``(2N-1)(N-1)T``: the step from which the rate bound of eq. (33) holds (Theorem 1)."""
    return (2 * N - 1) * (N - 1) * T
