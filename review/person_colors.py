"""Each person's colour in the review outputs (report overlays, Rerun, MCAP).

A fixed palette, so that a person has the same colour in every output of a run
and in every run: person 0 keeps the colours of a one-subject run (the paper's
Figure 4: model silhouette dark red, overlap with the observed silhouette
orange); the observed silhouette stays light blue for everyone. Ids beyond the
palette reuse it from the start.
"""

from __future__ import annotations

#: Per person id (cyclic): the model silhouette's colour (RGB) and the colour of the
#: pixels where model and observed silhouette overlap (RGB).
PERSON_PALETTE: tuple[tuple[tuple[int, int, int], tuple[int, int, int]], ...] = (
    ((170, 20, 30), (255, 150, 0)),  # dark red / orange (the paper's Figure 4)
    ((110, 40, 170), (235, 110, 210)),  # purple / pink
    ((20, 110, 50), (185, 220, 40)),  # dark green / yellow-green
    ((120, 70, 20), (240, 200, 60)),  # brown / gold
)


def person_rgb(person: int) -> tuple[int, int, int]:
    """The colour of person ``person``'s model (RGB, 0-255)."""
    return PERSON_PALETTE[person % len(PERSON_PALETTE)][0]


def person_overlap_rgb(person: int) -> tuple[int, int, int]:
    """The colour where person ``person``'s model covers their observed silhouette (RGB)."""
    return PERSON_PALETTE[person % len(PERSON_PALETTE)][1]


def person_hex(person: int) -> str:
    """:func:`person_rgb` as a CSS colour (``#aa141e``)."""
    return "#{:02x}{:02x}{:02x}".format(*person_rgb(person))
