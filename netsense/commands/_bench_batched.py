"""``netsense bench batched``: the batched core against the bare kernel and VMAS.

The measurement lives in :mod:`netsense.speed`; this module only plugs it into
``netsense bench`` (see :mod:`netsense.commands.bench`).
"""

from netsense.speed import HELP, add_arguments, run

NAME = "batched"

__all__ = ["HELP", "NAME", "add_arguments", "run"]
