"""What a user runs: ``cli`` (the installed commands and their shared helpers), ``demo``
(``make demo``), ``hil_bench`` (fault scenarios, ``hil-bench``), ``experiments`` (the
dissertation's measurements), ``fuzz`` (``hil-fuzz``'s library), ``examples`` (the host
library's guide) and three programs run as ``python -m tools.NAME``: ``build_compiled``,
``fuzz_inprocess`` and ``traffic_record``."""
