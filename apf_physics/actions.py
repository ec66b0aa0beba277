"""The nine moves of SPEC §2 (thesis Table 1), in the thesis's order."""

import numpy as np

ACTION_NAMES = ("up", "down", "left", "right", "left-up", "left-down", "right-up", "right-down", "stay")
ACTIONS = np.array(
    [(0, 1), (0, -1), (-1, 0), (1, 0), (-1, 1), (-1, -1), (1, 1), (1, -1), (0, 0)], dtype=float
)  # displacement per control step, world units
