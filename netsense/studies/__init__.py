"""Tools — experiment drivers that run observers: the paper's illustrative example
(:mod:`.examples`, behind ``netsense demo``) and topology sweeps (:mod:`.sweep`, behind
``netsense sweep``).

May import every layer up to :mod:`netsense.env`, and :mod:`netsense.grid`, :mod:`netsense.rl`
and :mod:`netsense.benchmark`.
"""
