"""``python -m tools.experiments [ARGS…]``: the dissertation's experiments
(:mod:`tools.experiments.dissertation`, as ``hil-bench experiments``)."""

from __future__ import annotations

import sys

from tools.experiments.dissertation import main

sys.exit(main())
