"""ProcessConfig: one preset table, validation, --set overrides, JSON round trip."""

from __future__ import annotations

import json

import pytest

from bodymetry.errors import InputError
from bodymetry.estimation.fit import PRESETS, FitConfig
from bodymetry.estimation.refinement import RefineConfig
from bodymetry.estimation.resolution import DEFAULT_WORKING_PERSON_PX
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.run_folder import config_fingerprint
from bodymetry.settings import apply_overrides, parse_override


def test_presets_come_from_the_one_table():
    for name, (annealing, refinement) in PRESETS.items():
        config = ProcessConfig.preset(name)
        assert config.quality == name
        assert config.fit.annealing == annealing and config.fit.refinement == refinement
    fast, best = PRESETS["fast"][0], PRESETS["best"][0]
    assert fast.n_particles < best.n_particles


@pytest.mark.parametrize("quality", ["ultra", ""])
def test_unknown_preset_is_refused(quality):
    with pytest.raises(InputError, match="quality: expected one of fast, default, best"):
        ProcessConfig.preset(quality)


def test_overrides_reach_nested_fields_with_short_keys():
    config = ProcessConfig.preset("fast").with_overrides(
        [
            "annealing.n_particles=120",  # short for fit.annealing.n_particles
            "fit.refinement.iterations=25",
            "training.n_train=500",
            "workers=2",
            "min_iou=0.85",
            "annealing.min_std=[0.01, 0.02, 0.03]",
        ]
    )
    assert config.fit.annealing.n_particles == 120
    assert config.fit.annealing.n_layers == PRESETS["fast"][0].n_layers  # untouched
    assert config.fit.refinement.iterations == 25
    assert config.training.n_train == 500
    assert config.workers == 2 and config.fit.min_iou == 0.85
    assert config.fit.annealing.min_std == (0.01, 0.02, 0.03)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("annealing.n_particles=0", r"fit\.annealing: n_particles: expected >= 1, got 0"),
        ("annealing.n_particles=many", r"n_particles: expected an integer, got 'many'"),
        ("annealing.n_particles=1.5", r"n_particles: expected an integer, got 1\.5"),
        ("refinement.nope=1", r"fit\.refinement: unknown setting 'nope'"),
        ("nope=1", r"config: unknown setting 'nope'"),
        ("workers", r"expected KEY=VALUE"),
        ("seed.x=1", r"'seed' has no sub-settings"),
        ("min_iou=2", r"min_iou: expected in \[0, 1\], got 2"),
        ("review=maybe", r"review: expected true or false"),
        ("annealing.min_std=[1, 2]", r"min_std: expected 3 values, got 2"),
        ("session_shape.tolerance=1e-x", r"tolerance: expected a number, got '1e-x'"),
        ("training.n_train=10", r"n_train >= 50"),
    ],
)
def test_bad_overrides_name_the_setting(override, message):
    with pytest.raises(InputError, match=message):
        ProcessConfig().with_overrides([override])


def test_json_round_trip_is_exact():
    config = ProcessConfig.preset("best", workers=3).with_overrides(["annealing.shrink=0.8"])
    data = json.loads(json.dumps(config.to_json()))  # through strict JSON
    assert ProcessConfig.from_json(data) == config
    # results.json adds keys of its own beside the config (the models' cache key).
    assert ProcessConfig.from_json({**data, "models": "abc"}) == config


def test_a_recorded_fit_config_with_a_wrong_type_is_refused():
    data = ProcessConfig().to_json()
    data["fit"]["annealing"]["n_layers"] = "ten"
    with pytest.raises(InputError, match=r"config\.fit\.annealing\.n_layers: expected an integer"):
        ProcessConfig.from_json(data)


def test_pdf_needs_the_review():
    with pytest.raises(InputError, match="pdf"):
        ProcessConfig(review=False, pdf=True)


def test_parse_override_reads_yaml_scalars():
    assert parse_override("a.b=3") == (["a", "b"], 3)
    assert parse_override("a=1e-5") == (["a"], 1e-5)
    assert parse_override("a=0.5") == (["a"], 0.5)
    assert parse_override("a=true") == (["a"], True)
    assert parse_override("a=[1, 2]") == (["a"], [1, 2])
    assert parse_override("a=text") == (["a"], "text")


def test_exponent_notation_without_a_dot_is_a_number():
    # Plain PyYAML reads "1e-5" (no dot) as a string; --set values go through the
    # project's YAML loader (fileio.parse_yaml), which reads it as a number.
    config = ProcessConfig().with_overrides(
        ["session_shape.tolerance=1e-5", "refinement.tolerance=2E-4"]
    )
    assert config.session_shape.tolerance == 1e-5
    assert config.fit.refinement.tolerance == 2e-4
    with pytest.raises(InputError, match=r"n_particles: expected an integer, got 100\.0"):
        ProcessConfig().with_overrides(["annealing.n_particles=1e2"])


def test_overrides_leave_the_original_untouched():
    base = FitConfig()
    changed = apply_overrides(base, ["refinement.iterations=3"])
    assert base.refinement == RefineConfig() and changed.refinement.iterations == 3


def test_working_person_px_is_a_setting_and_part_of_the_fingerprint():
    base = ProcessConfig()
    assert base.working_person_px == DEFAULT_WORKING_PERSON_PX
    assert base.with_overrides(["working_person_px=480"]).working_person_px == 480.0
    assert base.with_overrides(["working_person_px=null"]).working_person_px is None
    assert base.to_json()["working_person_px"] == DEFAULT_WORKING_PERSON_PX
    assert ProcessConfig.from_json(base.to_json()) == base
    with pytest.raises(InputError, match="working_person_px: expected a height in pixels > 0"):
        base.with_overrides(["working_person_px=0"])
    # Another target changes the results: a run of it does not resume this one.
    other = base.with_overrides(["working_person_px=200"])
    assert config_fingerprint(other) != config_fingerprint(base)
    assert config_fingerprint(base.with_overrides(["workers=1"])) == config_fingerprint(base)


def test_process_config_switches_the_stage_off():
    on = ProcessConfig()
    off = on.with_overrides(["session_shape.enabled=false"])
    assert on.session_shape.enabled and not off.session_shape.enabled
    # It changes no frame's fit: a run resumes with either setting.
    assert config_fingerprint(on) == config_fingerprint(off)
    with pytest.raises(InputError):
        on.with_overrides(["session_shape.frame_scale=0.1"])
