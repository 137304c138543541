"""The capture stage of bodymetry (``bodymetry.capture``; see docs/design.md).

The public API, importable from here (``from bodymetry.capture import load_session``);
each name is loaded on first use, so importing the package costs nothing.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "session": ["BoardSpec", "Session", "SessionCamera", "load_session", "save_session"],
        "ground_truth": ["StudioRecord", "SubjectTruth"],
        "ingest": ["SyncReport", "check_sync", "read_frame_sets"],
        "background": ["BackgroundModel", "SubtractionConfig", "subtract"],
        "masks": ["CleanupConfig", "clean_mask", "refine_edges"],
        "segmentation": [
            "CaptureConfig",
            "SilhouetteFrame",
            "background_models",
            "segment_session",
        ],
        "fusion": ["FusionConfig", "FusionWeights", "fuse", "view_features"],
        "overlays": ["overlay", "save_silhouette_frame"],
        "person": ["PersonConfig", "PersonSegmenter", "segmenter_available"],
        "consistency": ["HullConfig", "visual_hull"],
        "landmarks": ["LandmarkConfig", "principal_point_offsets", "triangulate_landmarks"],
    },
)
