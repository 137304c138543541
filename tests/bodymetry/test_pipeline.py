"""The step graph: one wiring of the steps, shared by both executors (bodymetry/pipeline.py)."""

from __future__ import annotations

import ast
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import bodymetry
from bodymetry import pipeline
from bodymetry.capture.people import Sighting
from bodymetry.errors import InputError
from bodymetry.estimation.records import FrameArrays, FrameRecord
from bodymetry.estimation.resolution import WorkingResolution
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunLayout
from bodymetry.estimation.view_selection import usable_view
from bodymetry.executors import DaskExecutor, Executor, LocalExecutor
from bodymetry.run_folder import config_fingerprint
from bodymetry.studio.rig import studio_rig

APP = Path(bodymetry.__file__).parent


def _step_references() -> dict[str, list[str]]:
    """Where each step is named in the application's code, outside its own definition:
    in pipeline.py, and in any module that imports steps from it."""
    names = {step.__name__ for step in pipeline.STEPS}
    found: dict[str, list[str]] = {n: [] for n in names}
    for path in sorted(APP.rglob("*.py")):
        tree = ast.parse(path.read_text())
        visible = set(names) if path.name == "pipeline.py" else set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module == "bodymetry.pipeline":
                visible |= {a.asname or a.name for a in node.names} & names
        # A reference inside a nested function (run_session's fit_all) counts for the
        # module-level function that holds it: the outermost function is the wiring.
        outer = [
            node
            for top in tree.body
            for node in ([top] if not isinstance(top, ast.ClassDef) else top.body)
            if isinstance(node, ast.FunctionDef)
        ]
        for func in outer:
            for node in ast.walk(func):
                if isinstance(node, ast.Name) and node.id in visible and func.name != node.id:
                    found[node.id].append(f"{path.name}:{func.name}:{node.lineno}")
    return {n: sorted(set(p)) for n, p in found.items()}


def test_each_step_has_one_call_site_in_run_session():
    """process and batch cannot wire a step differently: each step is named in one place."""
    for step, places in _step_references().items():
        assert len(places) == 1, f"{step} is wired in {places}"
        assert places[0].startswith("pipeline.py:run_session:"), places


def test_process_and_batch_run_the_session_graph_only():
    sources = {name: (APP / f"{name}.py").read_text() for name in ("process", "batch")}
    for name, text in sources.items():
        assert "run_session(" in text, name
        for step in pipeline.STEPS:
            assert f" {step.__name__}(" not in text, f"{name}.py calls {step.__name__}"


def test_both_executors_offer_what_the_graph_needs():
    wanted = {
        n for n in dir(Executor) if not n.startswith("_") and n not in ("read_method", "remote")
    }
    for cls in (LocalExecutor, DaskExecutor):
        assert wanted <= set(dir(cls)), cls
        assert cls.read_method in ("sequential", "seek")


def test_the_local_executor_holds_a_step_error_until_its_result_is_read():
    def boom() -> None:
        raise ValueError("bad input")

    with LocalExecutor(1) as ex:
        future = ex.submit(boom)
        assert isinstance(future.exception(), ValueError)
        chained = ex.submit(lambda x: x + 1, ex.submit(lambda: 1))
        assert chained.result() == 2
        assert ex.item(ex.submit(lambda: [3, 4]), 1).result() == 4
        assert ex.frame_chunks([0, 25, 50]) == [(0, 25, 50)]
        first = ex.shared("rig", lambda: object())
        assert ex.shared("rig", lambda: object()) is first


def test_capture_agreement_is_keyed_by_camera_without_the_views_not_judged():
    names = ("cam_00", "cam_01", "cam_02")
    assert pipeline.judged_agreement(names, (0.9, None, 0.61), 25) == {
        "cam_00": 0.9,
        "cam_02": 0.61,
    }
    assert pipeline.judged_agreement(names, (), 25) == {}  # capture judged nothing
    with pytest.raises(ValueError, match="frame 25: capture's agreement has 2 values for 3"):
        pipeline.judged_agreement(names, (0.9, 0.8), 25)
    for bad in (1.2, -0.1, float("nan")):
        with pytest.raises(ValueError, match=r"outside \[0, 1\]"):
            pipeline.judged_agreement(names, (0.9, bad, None), 25)


def test_camera_warnings_name_an_unreliable_camera_once_and_not_as_unseen():
    """A camera left out as unreliable in every frame saw the person: it is named by the
    unreliable warning (with capture's bound when known), not as a covered camera."""
    names = ("cam_00", "cam_01", "cam_02")

    def record(frame: int) -> FrameRecord:
        return FrameRecord(
            frame,
            "ok",
            flags={"cam_01": ("unreliable",)},
            person_pixels={"cam_00": 5000, "cam_01": 5000, "cam_02": 0},
            view_agreement={"cam_00": 0.95, "cam_01": 0.5 + frame / 100},
        )

    warnings = pipeline.camera_warnings([record(0), record(25)], names, bound=0.8)
    assert warnings == [
        "camera 'cam_02' saw no person in any of the 2 kept frames (covered, black or "
        "pointing away?); it contributed nothing to the measurements",
        "cam_01: silhouette unreliable in 2 of 2 kept frames (agreement 0.50-0.75 < 0.80), "
        "left out of those frames' fits",
    ]
    assert pipeline.camera_warnings([], names) == []


def _landmark_frames(rig, persons: int, n_frames: int = 6) -> list[pipeline.SegmentedFrame]:
    """Kept frames whose per-camera landmarks show camera 1 off by (8, -3) px, with
    ``persons`` people counted in view."""
    rng = np.random.default_rng(1)
    frames = []
    for k in range(n_frames):
        points = rng.uniform([-0.4, -0.4, 0.1], [0.4, 0.4, 1.8], (33, 3))
        views = [np.column_stack([c.project(points), np.ones(33)]) for c in rig]
        views[1][:, :2] += (8.0, -3.0)
        frames.append(pipeline.SegmentedFrame(25 * k, (), (), None, tuple(views), persons=persons))
    return frames


def test_the_calibration_check_leaves_out_frames_with_more_than_one_person(tmp_path):
    rig = studio_rig(4, (640, 480), seed=5)
    prepared = pipeline.PreparedRun(
        session=None,
        layout=RunLayout(tmp_path),
        cameras=rig,
        calibration_source="test",
        resolution=WorkingResolution.full(rig),
        calibrated=rig,
    )
    config = ProcessConfig()
    alone = pipeline.check_calibration(prepared, _landmark_frames(rig, 1), config)
    assert alone.calibrated[1] is not rig[1] and alone.calibrated[0] is rig[0]
    # Two people in every frame: each view's landmarks may be another person's, so
    # the cameras are not judged by them, and the run says so.
    crowded = pipeline.check_calibration(prepared, _landmark_frames(rig, 2), config)
    assert crowded.calibrated is rig
    assert crowded.warnings == (
        "calibration check: 6 kept frames have more than one person in view, whose "
        "landmarks may be different people in different cameras; the calibration was not "
        "checked and is used as given",
    )
    mixed = _landmark_frames(rig, 1) + _landmark_frames(rig, 2, n_frames=2)
    partly = pipeline.check_calibration(prepared, mixed, config)
    assert partly.calibrated[1] is not rig[1]
    assert "2 kept frames" in partly.warnings[0] and "left out" in partly.warnings[0]
    # Where capture told the people apart, each person's own landmarks count.
    told = [
        replace(s, people=(Sighting(np.zeros(3), (None,) * 4, s.view_landmarks, (False,) * 4),))
        for s in _landmark_frames(rig, 2)
    ]
    apart = pipeline.check_calibration(prepared, told, config)
    assert apart.calibrated[1] is not rig[1]
    assert len(apart.warnings) == 1 and "cam_01" in apart.warnings[0]  # the shift, nothing else


def _sighting(x: float, masks, occluded=None) -> Sighting:
    c = len(masks)
    return Sighting(
        np.array([x, 0.0, 1.0]), tuple(masks), (None,) * c, tuple(occluded or (False,) * c)
    )


def test_choose_person_follows_one_person_through_the_frames(tmp_path):
    rig = studio_rig(3, (64, 48), seed=5)
    prepared = pipeline.PreparedRun(
        None, RunLayout(tmp_path), rig, "test", WorkingResolution.full(rig), rig
    )
    blank = np.zeros((48, 64), bool)

    def mask(k: int) -> np.ndarray:
        m = blank.copy()
        m[10:30, 5 * k : 5 * k + 4] = True
        return m

    # Person 0 stands at x=0, person 1 at x=1.5; frame 25 lists them the other way
    # round, frame 50 has person 1 only, and person 1 is hidden in camera 2 at frame 0.
    seg = [
        pipeline.SegmentedFrame(0, (blank,) * 3, ((),) * 3, None, (), persons=2, people=(
            _sighting(0.0, [mask(1), mask(2), mask(3)]),
            _sighting(1.5, [mask(4), mask(5), mask(6)], (False, False, True)),
        )),
        pipeline.SegmentedFrame(25, (blank,) * 3, ((),) * 3, None, (), persons=2, people=(
            _sighting(1.4, [mask(7), None, mask(8)]),
            _sighting(0.1, [mask(9), mask(10), mask(11)]),
        )),
        pipeline.SegmentedFrame(50, (blank,) * 3, ((),) * 3, None, (), persons=1, people=(
            _sighting(1.3, [mask(1), mask(1), mask(1)]),
        )),
    ]  # fmt: skip
    plan = pipeline.plan_persons(prepared, seg, ProcessConfig())
    assert plan.ids == (0, 1) and plan.told_apart and plan.several
    assert (
        pipeline.plan_persons(prepared, seg, ProcessConfig(largest=True)) == pipeline.PersonPlan()
    )
    zero = pipeline.choose_person(prepared, seg, ProcessConfig(), 0)
    assert [f.frame for f in zero] == [0, 25, 50]
    assert all(np.array_equal(a, mask(k)) for a, k in zip(zero[1].masks, (9, 10, 11), strict=True))
    assert zero[2].flags == (("empty", "absent"),) * 3 and not any(m.any() for m in zero[2].masks)
    one = pipeline.choose_person(prepared, seg, ProcessConfig(), 1)
    assert one[0].flags == ((), (), ("occluded",))
    assert zero[0].unknown == () and one[0].unknown == ()
    # Person 0 is partly hidden in camera 1 at frame 0: those pixels are unknown to
    # their fit (the view stays in it), and the fit's job carries them.
    covered = mask(2) & ~mask(1)
    covered[30:40] = True
    partly = [replace(seg[0], people=(replace(seg[0].people[0], hidden=(None, covered, None)),
                                      seg[0].people[1])), *seg[1:]]  # fmt: skip
    zero = pipeline.choose_person(prepared, partly, ProcessConfig(), 0)
    assert zero[0].flags == ((),) * 3
    assert zero[0].unknown[0] is None and zero[0].unknown[2] is None
    assert np.array_equal(zero[0].unknown[1], covered) and zero[1].unknown == ()
    # Person 0's detection in camera 0 at frame 25 mixed them with person 1: that
    # view is left out, and named for it.
    mixed = [seg[0], replace(seg[1], people=(seg[1].people[0], replace(
        seg[1].people[1], mixed=(True, False, False)))), seg[2]]  # fmt: skip
    either = pipeline.choose_person(prepared, mixed, ProcessConfig(), 0)
    assert either[1].flags == (("mixed",), (), ())
    assert not usable_view(int(either[1].masks[0].sum()), either[1].flags[0])
    # Each person's own outline contrast (capture's) goes with their frames, so one
    # seen in low contrast among others is held to the low-contrast sessions.
    contrasts = (replace(seg[0].people[0], contrast=0.8), replace(seg[0].people[1], contrast=1.9))
    seen = [replace(seg[0], people=contrasts), *seg[1:]]
    chosen = pipeline.choose_person(prepared, seen, ProcessConfig(), 0)
    assert [f.contrast for f in chosen] == [0.8, None, None]
    assert pipeline.choose_person(prepared, seen, ProcessConfig(), 1)[0].contrast == 1.9
    models = pipeline.RigModels("key", tmp_path, True, 0.0)
    job = pipeline.fit_job_of(prepared, models, zero[0], ProcessConfig(person=0))
    assert np.array_equal(job.unknown[1], covered) and job.unknown[0] is None
    assert pipeline.fit_job_of(prepared, models, zero[1], ProcessConfig()).unknown == []
    assert one[1].flags == ((), ("empty",), ()) and not one[1].masks[1].any()
    assert np.array_equal(one[2].masks[0], mask(1)) and one[2].people == ()
    assert pipeline.plan_persons(prepared, seg, ProcessConfig(person=1)).ids == (1,)
    with pytest.raises(InputError, match=r"followed 2 people.*0 to 1"):
        pipeline.plan_persons(prepared, seg, ProcessConfig(person=2))
    nobody = [replace(s, people=()) for s in seg]
    with pytest.raises(InputError, match="told no people apart"):
        pipeline.plan_persons(prepared, nobody, ProcessConfig(person=0))
    assert pipeline.plan_persons(prepared, nobody, ProcessConfig()) == pipeline.PersonPlan()
    hull = [replace(s, people=tuple(replace(p, source="hull") for p in s.people)) for s in seg]
    with pytest.raises(InputError, match="splitting the multi-view hull"):
        pipeline.plan_persons(prepared, hull, ProcessConfig(person=0))
    # The hull's split is too coarse to measure: the run measures the one subject.
    assert pipeline.plan_persons(prepared, hull, ProcessConfig()) == pipeline.PersonPlan()


def test_a_person_seen_in_too_few_frames_is_named_not_measured():
    rig = studio_rig(3, (64, 48), seed=5)
    prepared = pipeline.PreparedRun(None, None, rig, "test", WorkingResolution.full(rig), rig)
    blank = np.zeros((48, 64), bool)
    masks = [blank] * 3
    # Person 0 in all ten frames, a passer-by at x=2 in one of them.
    seg = [
        pipeline.SegmentedFrame(
            f, (blank,) * 3, ((),) * 3, None, (),
            people=(_sighting(0.0, masks),) + ((_sighting(2.0, masks),) if f == 30 else ()),
        )
        for f in range(0, 100, 10)
    ]  # fmt: skip
    plan = pipeline.plan_persons(prepared, seg, ProcessConfig())
    assert plan.ids == (0,) and not plan.told_apart and not plan.several
    (warning,) = plan.warnings
    assert "person 1 was seen in only 1 of 10 kept frames" in warning
    # With a second person in three of the ten frames, both are measured.
    seg = [
        replace(s, people=(*s.people[:1], _sighting(2.0, masks))) if s.frame in (30, 40, 50) else s
        for s in seg
    ]
    plan = pipeline.plan_persons(prepared, seg, ProcessConfig())
    assert plan.ids == (0, 1) and plan.warnings == () and plan.layout_person(1) == 1


def test_the_chosen_person_is_a_setting_of_the_run():
    with pytest.raises(InputError, match="person"):
        ProcessConfig(person=-1)
    base = config_fingerprint(ProcessConfig())
    assert config_fingerprint(ProcessConfig(person=0)) != base
    assert config_fingerprint(ProcessConfig(person=1)) != config_fingerprint(
        ProcessConfig(person=0)
    )
    assert pipeline.needs_every_frame(ProcessConfig(person=0))
    assert config_fingerprint(ProcessConfig(largest=True)) != base
    with pytest.raises(InputError, match="choose one"):
        ProcessConfig(person=0, largest=True)


def _fitted() -> SimpleNamespace:
    """What the registration reads of a FrameRecord: fitted, and where the body stood."""
    at = SimpleNamespace(state=SimpleNamespace(tau=np.array([[0.0, 0.0, 1.0]])))
    return SimpleNamespace(fitted=True, estimates={"generative": at})


def _registration_run(tmp_path, shift: tuple[int, int]) -> tuple[pipeline.PreparedRun, dict]:
    """A run folder whose 5 frames' model silhouettes sit ``shift`` px off the observed
    ones in camera 1 and exactly on them in cameras 0, 2 and 3."""
    rig = studio_rig(4, (160, 120), seed=5)
    layout = RunLayout(tmp_path)
    layout.frames_dir.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for frame in range(5):
        model = np.zeros((120, 160), bool)
        y, x = rng.integers(20, 40), rng.integers(40, 80)
        model[y : y + 70, x : x + 25] = True
        model[y + 10 : y + 18, x + 25 : x + 60] = True  # an arm
        observed = {c.name: model for c in rig}
        observed["cam_01"] = np.roll(np.roll(model, shift[1], 0), shift[0], 1)
        arrays = FrameArrays(observed, {c.name: model for c in rig})
        np.savez_compressed(layout.frame_arrays(frame), **arrays.to_arrays())
        layout.frame_record(frame).write_text("{}")
    prepared = pipeline.PreparedRun(
        session=None,
        layout=layout,
        cameras=rig,
        calibration_source="test",
        resolution=WorkingResolution.full(rig),
        calibrated=rig,
    )
    return prepared, {None: {f: _fitted() for f in range(5)}}


def test_a_camera_the_fitted_bodies_show_off_is_shifted_and_its_frames_fitted_again(tmp_path):
    prepared, records = _registration_run(tmp_path, (2, -1))
    config = ProcessConfig()
    registered = pipeline.register_cameras(prepared, config, records)
    rig = prepared.calibrated
    moved = registered.calibrated[1].K - rig[1].K
    np.testing.assert_allclose(moved[:2, 2], [2.0, -1.0], atol=0.5)
    assert [registered.calibrated[c] is rig[c] for c in range(4)] == [True, False, True, True]
    assert registered.unregistered is rig and registered.rig is rig  # models stay cached
    assert len(registered.warnings) == 1 and "'cam_01'" in registered.warnings[0]
    # Every frame's record is gone (fitted again through the shifted camera); the
    # offsets are recorded, and a resumed run applies exactly them.
    assert prepared.layout.recorded_frames() == []
    assert prepared.layout.registration.is_file()
    resumed = pipeline.apply_registration(prepared, config)
    np.testing.assert_array_equal(resumed.calibrated[1].K, registered.calibrated[1].K)
    assert resumed.warnings == registered.warnings
    # It runs once: the registered run's own fits are not measured again.
    assert pipeline.register_cameras(registered, config, records) is registered


def test_registration_leaves_a_registered_rig_and_a_disabled_one_alone(tmp_path):
    prepared, records = _registration_run(tmp_path / "exact", (0, 0))
    same = pipeline.register_cameras(prepared, ProcessConfig(), records)
    assert same.calibrated is prepared.calibrated and same.unregistered is None
    assert prepared.layout.recorded_frames() == list(range(5))  # nothing to fit again
    assert prepared.layout.registration.is_file()  # the measured offsets, all under the bound
    off, records = _registration_run(tmp_path / "off", (3, 0))
    config = ProcessConfig().with_overrides(["registration.enabled=false"])
    assert pipeline.register_cameras(off, config, records) is off
    assert not off.layout.registration.is_file()
    assert config_fingerprint(config) != config_fingerprint(ProcessConfig())
