"""What the host is told of the calibration rig: the board's dimples, the table, the anchors.

The touch calibration (``armctl calibrate``, :mod:`host.arm.touches`) touches the probe's
ball (:data:`protocol.robot.ARM_PROBE_TIP_M`) into conical dimples of a board, onto a table,
and into two anchor dimples on the arm's mounting bracket.  The host knows the dimples'
*spacing* exactly (they are drilled on a CNC: :data:`DIMPLE_PITCH_M`), the anchors' positions
in the base frame to the bracket's drawing, and the board's and table's poses only roughly
(:data:`BOARD_ORIGIN_M`, :data:`BOARD_RPY`, :data:`TABLE_TOP_Z_M`: where they were set down,
to a centimetre and a few degrees).  The emulator's ``calibration`` scene builds the rig from
these same figures, the board and table placed off their nominal poses by a seeded amount.

Frames: the arm's base frame (m; ``z`` up, ``x`` forward).  The board's frame has its origin
at dimple (0, 0) (the seated ball's centre), ``x`` along its rows, ``z`` out of its face.  A
dimple's point is where the probe ball's centre sits when seated in it.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np

from host.arm.kinematics import rpy_to_matrix

#: The board's dimples: a grid of :data:`DIMPLE_GRID` (rows along the board's ``x``,
#: columns along its ``y``) at this pitch (m).
DIMPLE_PITCH_M: Final = 0.06
DIMPLE_GRID: Final = (4, 3)
#: A dimple's cone: its mouth's radius (m) and its walls' slope from the board's face (rad):
#: a ball landing within the mouth slides to the bottom under the probe's push.
DIMPLE_MOUTH_RADIUS_M: Final = 0.015
DIMPLE_SLOPE_RAD: Final = math.radians(45.0)
#: The board's nominal pose in the base frame: dimple (0, 0)'s point (m) and the board's
#: orientation (roll, pitch, yaw, rad): lying flat on the table in front of the arm.
BOARD_ORIGIN_M: Final = (0.40, -0.06, -0.44)
BOARD_RPY: Final = (0.0, 0.0, 0.0)
#: The table's top (m, base frame, nominal) and where the probe touches it: two rows of
#: :data:`TABLE_ROW_TOUCHES` along ``x`` (centre and half-length, m), at ``y`` =
#: ±:data:`TABLE_ROW_Y_M` either side of the board (whose dimples' mouths reach to
#: ``|y|`` = 0.075 m): clear of it.
TABLE_TOP_Z_M: Final = -0.50
TABLE_TOUCH_CENTRE_XY_M: Final = (0.47, 0.0)
TABLE_TOUCH_HALF_M: Final = 0.10
TABLE_ROW_Y_M: Final = 0.16
TABLE_ROW_TOUCHES: Final = 3
#: The height (m, base frame) the ball crosses the rig at between one group of touches and
#: the next (a board, a row of the table, an anchor): 70 mm above the board's dimples'
#: mouths, above the anchors'.
TRAVEL_Z_M: Final = -0.36
#: Where the probe's ball waits before and after the touches (m, base frame, probe down):
#: above the table's near edge, reached from the hanging arm without crossing the table.
READY_M: Final = (0.25, 0.0, -0.45)
#: The anchor dimples on the mounting bracket, to its drawing (points, m, base frame; axes
#: pointing up).
ANCHOR_POINTS_M: Final = ((0.30, 0.16, -0.38), (0.30, -0.16, -0.38))


def dimple_points() -> np.ndarray:
    """Every dimple's point in the board's frame (n×3, m), row by row."""
    rows, cols = DIMPLE_GRID
    return np.array([(DIMPLE_PITCH_M * i, DIMPLE_PITCH_M * j, 0.0)
                     for i in range(rows) for j in range(cols)])


def board_rotation(rpy: tuple[float, float, float] = BOARD_RPY) -> np.ndarray:
    """The board's orientation (3×3, its axes in the base frame) for ``rpy`` (rad)."""
    return rpy_to_matrix(rpy)


def nominal_dimples() -> np.ndarray:
    """Where the host expects each dimple (n×3, m, base frame): the nominal pose."""
    out: np.ndarray = np.asarray(BOARD_ORIGIN_M) + dimple_points() @ board_rotation().T
    return out


def table_points() -> list[tuple[float, float, int]]:
    """The table touches in order: ``(x, y, row)`` (m, base frame; row 0 or 1), one row
    along ``x`` and back along the other, so consecutive touches of a row are neighbours."""
    cx, cy = TABLE_TOUCH_CENTRE_XY_M
    xs = np.linspace(cx - TABLE_TOUCH_HALF_M, cx + TABLE_TOUCH_HALF_M, TABLE_ROW_TOUCHES)
    rows = ((0, cy - TABLE_ROW_Y_M, xs), (1, cy + TABLE_ROW_Y_M, xs[::-1]))
    return [(float(x), float(y), row) for row, y, line in rows for x in line]
