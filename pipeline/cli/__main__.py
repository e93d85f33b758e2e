"""``python -m pipeline.cli``: the same as the ``gflow`` command."""

from pipeline.cli.main import main

raise SystemExit(main())
