"""The Tango spacecraft (PRISMA mission) as SPEED+ describes it: body frame and keypoints.

Body frame T: origin on the centre of the rear (-z) face, +z through the solar-panel
face. Coordinates are full scale, metres (docs/architecture.md section 7); multiply by the mock-up
scale for the testbed model.
"""

from __future__ import annotations

import numpy as np

#: The 11 public SPEED+ keypoints (11, 3), full scale, metres. 0-3: solar-panel face
#: (z = 0.3215); 4-7: the opposite face (z = 0); 8-10: antenna tips.
KEYPOINTS_M = np.array([
    [-0.37, -0.385, 0.3215],
    [-0.37, 0.385, 0.3215],
    [0.37, 0.385, 0.3215],
    [0.37, -0.385, 0.3215],
    [-0.37, -0.264, 0.0],
    [-0.37, 0.304, 0.0],
    [0.37, 0.304, 0.0],
    [0.37, -0.264, 0.0],
    [-0.5427, 0.4877, 0.2535],
    [0.5427, 0.4877, 0.2591],
    [0.305, -0.579, 0.2515],
])
KEYPOINTS_M.setflags(write=False)

#: z of the solar-panel face, full scale (m).
SOLAR_PANEL_Z_M = 0.3215
#: Centre of the body's bounding box, full scale (m).
BODY_CENTRE_M = np.array([0.0, 0.0, SOLAR_PANEL_Z_M / 2])
