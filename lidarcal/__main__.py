"""``python -m lidarcal`` is the ``lidarcal`` command."""

from lidarcal.cli import main

raise SystemExit(main())
