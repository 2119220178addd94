"""Sub-commands of the ``netsense`` CLI, one module each (see :mod:`netsense.cli`).

Command modules must import heavy dependencies inside ``run`` so that ``netsense --help``
stays fast and works with the core install only.

Top layer. May import everything but :mod:`netsense.cli`.
"""
