"""The freshness-index distributed observer (Section IV, eqs. (7)-(14)).

Each agent ``i`` keeps an estimate of every substate ``z^{(j)}`` and a freshness index
``tau_i^{(j)}`` that records how old its information about substate ``j`` is relative to
the source ``j`` (``omega`` until it has heard anything). At each step:

* the source ``j`` runs its local observer eq. (7) on its own substate and keeps
  ``tau_j^{(j)} = 0``;
* a non-source adopts, per substate, the estimate of the freshest transmitting
  in-neighbour if that neighbour is strictly fresher (eqs. (8)-(10), (13)), propagating it
  with ``A_jj`` and its own estimates of the lower substates; otherwise it runs open loop
  (eq. (12)) and ages its index by one (eq. (14)) or stays at omega (eq. (11)).

Under joint strong connectivity (Assumption 1) every index is finite from step
``(N-1)T`` on (Lemma 3) and at most ``2(N-1)T`` afterwards (Lemma 5); with Theorem 1's
gains every agent's error decays at the designed rate ``max_j rho_j`` (Theorem 1), with
deadbeat gains it vanishes to rounding after ``n + 2N(N-1)T`` steps (Corollary 1). In
floating point this holds because Lemma 1's zero pattern is exact
(``docs/theory.md``: the error recursion and what is measured).

Tie-break: among equally fresh neighbours the smallest node index is adopted.
"""

from __future__ import annotations

from netsense.kernels import update as kernels
from netsense.observers.base import DistributedObserver


class FreshnessObserver(DistributedObserver):
    """Freshness-index observer; see the module docstring and :class:`DistributedObserver`.

    Examples
    --------
    >>> import netsense as ns
    >>> plant = ns.fig1_scalar()
    >>> obs = ns.FreshnessObserver.from_plant(plant, deadbeat=True)
    >>> graphs = ns.fig1_graphs().sequence(6)
    >>> x = np.array([1.0])
    >>> for k in range(6):
    ...     obs.step(plant.measure(x), graphs[k])
    ...     x = plant.step(x)
    >>> bool(np.allclose(obs.estimates[:, 0], x[0]))
    True
    """

    def _select(self, Z, tau, nbr, valid, tx):
        src, self.last_slot = kernels.freshness_choice(tau, nbr, valid, tx)
        self.last_source = src
        return kernels.gather_substates(Z, src, self.block_of), kernels.advance_indices(tau, src)
