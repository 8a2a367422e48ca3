"""``python -m tools.demo``: run :func:`tools.demo.command.main`."""

from tools.demo.command import main

raise SystemExit(main())
