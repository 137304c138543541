"""The estimation stage of bodymetry: body model, features, discriminative and generative
fitting, the session stage, biometrics, and the run's records and files.

The public API, importable from here (``from bodymetry.estimation import RunResults``);
each name is loaded on first use, so importing the package costs nothing (and the
compiled kernels load only with the code that uses them).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "body_model.model": ["BodyModel", "BodyState", "shipped_model"],
        "body_model.biometrics": ["Biometrics", "measure"],
        "fit": [
            "FitConfig",
            "FrameFit",
            "fit_frame",
            "refit_frame",
            "session_gate",
            "shared_body_model",
        ],
        "training": ["DiscriminativeModels", "TrainConfig", "load_or_train", "rig_key"],
        "session_shape": ["SessionShapeConfig", "fit_session_shape"],
        "resolution": ["WorkingResolution"],
        "run_config": ["ProcessConfig"],
        "records": ["STAGES", "FrameArrays", "FrameRecord", "SessionGate", "SessionShape", "Stat"],
        "run_files": ["Evaluation", "RunLayout", "RunManifest", "RunResults", "StudyResults"],
        "caveats": ["CAVEAT_CODES", "Caveat", "run_caveats"],
        "view_features": ["silhouette_features"],
        "view_selection": [
            "LEAVE_OUT_FLAGS",
            "MIN_PIXELS",
            "LeftOutView",
            "blank_unusable",
            "left_out_views",
            "usable_camera_frames",
            "usable_view",
            "usable_views",
        ],
        "rdf": ["rdf"],
        "shape_context": ["ShapeContextConfig", "shape_context_descriptors"],
        "codebook": ["Codebook", "fit_codebook"],
    },
)
