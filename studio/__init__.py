"""The synthetic capture studio: renders ground-truth multi-camera sessions.

The public API, importable from here (``from bodymetry.studio import synthesize``);
each name is loaded on first use, so importing the package costs nothing.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "synth": ["SubjectSpec", "SynthConfig", "describe", "synthesize"],
        "evaluate": ["GroundTruth", "segment_and_score"],
        "people": ["MAX_PEOPLE", "Person", "draw_people"],
        "render": ["PeopleFrame"],
        "looks": ["Look", "recorded_look"],
    },
)
