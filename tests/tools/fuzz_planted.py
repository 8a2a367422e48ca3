"""A test-only fmcb with a planted defect, registered only by the fuzzing tests.

``fmcb.param_set`` with parameter index :data:`HANGING_INDEX` never replies and leaves the
node deaf from then on (a handler stuck in a loop, as a real MCU would be).
"""

from __future__ import annotations

from typing import Any

from firmware_py.fmcb import FmcbApp
from firmware_py.hand_node import DEFERRED, Request

#: The parameter index that hangs the planted fmcb.
HANGING_INDEX = 0xFFFF  # the top of the index range, where off-by-one checks break
#: What ``APP_PROGRAMS["fmcb"]`` names to run this program.
PROGRAM = "tests.tools.fuzz_planted:HangingFmcbApp"


class HangingFmcbApp(FmcbApp):
    """The fmcb application with a handler that hangs on one field value."""

    def _on_param_set(self, req: Request) -> Any:
        if req.fields["index"] == HANGING_INDEX:
            self.pogo.set_receiver(lambda data, t_us: None)  # stuck: hears nothing more
            return DEFERRED  # and never answers
        return super()._on_param_set(req)
