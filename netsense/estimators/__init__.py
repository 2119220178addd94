"""Layer 5 — centralised estimators of the other papers, usable on their own.

Kalman filtering with intermittent observations (KFIO) and the centralised oracle filter
(:mod:`.kalman`, :mod:`.oracle`), the robust filter with measurement droppings (RSEIO,
:mod:`.robust`), online proximal least squares (OSE/OASE, :mod:`.online`, bounds in
:mod:`.online_analysis`) and equalized-recovery observers for delayed data
(:mod:`.equalized`, LP design in :mod:`.equalized_design`). The distributed observers use
some of them as source-node estimators (:mod:`netsense.observers.source_estimators`).

May import: :mod:`netsense.kernels`, :mod:`netsense.sensing`, :mod:`netsense.systems`,
:mod:`netsense.graphs`.
"""
