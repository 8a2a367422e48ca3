"""``python -m tools.demo``: run :func:`tools.demo.script.main`."""

from tools.demo.script import main

raise SystemExit(main())
