"""``python -m pipeline.cli``: the same as the ``gflow`` command."""

from pipeline.runtime.trace import mark

mark("cli start")
from pipeline.cli.main import main  # noqa: E402

mark("cli imported")
raise SystemExit(main())
