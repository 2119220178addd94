"""``python -m netsense.speed``: the batched speed benchmark (see :func:`netsense.speed.main`)."""

from netsense.speed import main

raise SystemExit(main())
