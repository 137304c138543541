"""Clothing-like display colours of the 15 body parts (order of ``skeleton.PARTS``).

The synthetic studio dresses its bodies in these colours and the review outputs
(meshes, plots, recordings) paint fitted bodies with them, so both sides read them
from here, below both.
"""

from __future__ import annotations

import numpy as np

#: (15, 3) uint8: one clothing-like RGB colour per body part (order of ``skeleton.PARTS``).
PART_COLORS = np.array(
    [
        [60, 70, 120],  # pelvis
        [180, 60, 60],  # torso
        [230, 190, 160],  # head
        [180, 60, 60],
        [230, 190, 160],
        [230, 190, 160],  # left arm: sleeve, skin, skin
        [180, 60, 60],
        [230, 190, 160],
        [230, 190, 160],  # right arm
        [60, 70, 120],
        [60, 70, 120],
        [40, 40, 40],  # left leg: trousers, trousers, shoe
        [60, 70, 120],
        [60, 70, 120],
        [40, 40, 40],  # right leg
    ],
    dtype=np.uint8,
)
