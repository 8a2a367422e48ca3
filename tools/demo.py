"""``make demo``: the project's main job on the built-in material when no hardware is given.

Until the emulator lands this decodes the built-in sample capture of a palm USB session
(``tools/samples/hand_session.hex``) with ``handbus`` and prints the frames it recovers.
"""

from __future__ import annotations

import sys
from pathlib import Path

from tools import handbus

SAMPLE = Path(__file__).parent / "samples" / "hand_session.hex"


def main() -> int:
    """Decode the sample capture and print one JSON line per frame, then the counters."""
    print(f"# handbus decode --hex {SAMPLE.relative_to(Path.cwd()) if SAMPLE.is_relative_to(Path.cwd()) else SAMPLE}",
          flush=True)
    return handbus.main(["decode", "--hex", str(SAMPLE)])


if __name__ == "__main__":
    sys.exit(main())
