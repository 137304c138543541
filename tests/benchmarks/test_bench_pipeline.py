"""The pipeline benchmark's comparison of the session stage with the per-frame mean."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from benchmarks.bench_pipeline import (
    MIN_FRAME_SHARE,
    SIGNIFICANT_Z,
    _fitted_shapes,
    edge_summary,
    stage_comparison,
)
from bodymetry.estimation.body_model.model import BodyState


def _session(name: str, errors: dict[str, tuple[float, float, float, float]]) -> dict:
    """A session result whose Figure 3 has, per biometric, (per-frame error, its std
    over 16 frames, session error, session standard error) around a truth of 100."""
    table = {}
    for key in ("height_mm", "arm_span_mm", "weight_kg"):
        e_pf, std, e_s, se = errors.get(key, (1.0, 4.0, 0.5, 0.5))
        table[key] = {
            "actual": 100.0,
            "generative": {"mean": 100.0 + e_pf, "std": std, "n": 16},
            "session": {"mean": 100.0 + e_s, "std": se, "n": 16},
        }
    return {"session": f"/somewhere/{name}", "figure3": table}


def test_known_errors_give_known_table():
    sessions = [
        _session("a", {"arm_span_mm": (-10.0, 8.0, -4.0, 1.0)}),
        _session("b", {"arm_span_mm": (0.5, 8.0, -3.0, 1.0)}),
    ]
    out = stage_comparison(sessions)
    arm = out["arm_span_mm"]
    assert arm["mean_absolute_error"] == {"per_frame": 5.25, "session": 3.5}
    assert arm["rms_error"]["per_frame"] == pytest.approx(np.sqrt((100 + 0.25) / 2), abs=0.01)
    assert arm["rms_error"]["session"] == pytest.approx(np.sqrt((16 + 9) / 2), abs=0.01)
    assert arm["session_at_least_as_accurate"] is True
    assert arm["sessions_at_least_as_accurate"] == "1/2"
    # b: |−3| − |0.5| = 2.5 over hypot(8/4, 1) = 2.236: z 1.12, not significant.
    b = arm["sessions"][1]
    assert b["session"] == "b" and b["difference"] == 2.5
    assert b["z"] == pytest.approx(2.5 / np.hypot(2.0, 1.0), abs=0.01)
    assert arm["significantly_worse"] == []
    assert out["all_biometrics"] is True


def test_a_significantly_worse_session_fails_the_table():
    # Session stage 6 units off with tight standard errors where the per-frame mean is exact.
    worse = _session("worse", {"weight_kg": (0.0, 1.0, 6.0, 0.5)})
    out = stage_comparison([_session("a", {}), worse])
    weight = out["weight_kg"]
    assert weight["sessions"][1]["z"] >= SIGNIFICANT_Z
    assert weight["significantly_worse"] == ["worse"]
    assert weight["session_at_least_as_accurate"] is False
    assert out["all_biometrics"] is False


def test_sessions_without_a_session_stage_are_left_out():
    plain = _session("plain", {})
    for row in plain["figure3"].values():
        del row["session"]
    assert stage_comparison([plain]) == {}
    out = stage_comparison([plain, _session("a", {})])
    assert [r["session"] for r in out["height_mm"]["sessions"]] == ["a"]


def test_a_one_frame_session_has_no_per_frame_standard_error():
    """One frame: no spread to take the per-frame mean's standard error from; the z
    uses the session's alone, and the table stays valid JSON (no NaN)."""
    one = _session("one", {"height_mm": (2.0, 0.0, 3.0, 0.5)})
    one["figure3"]["height_mm"]["generative"]["n"] = 1
    row = stage_comparison([one])["height_mm"]["sessions"][0]
    assert row["per_frame_standard_error"] is None
    assert row["z"] == pytest.approx(1.0 / 0.5)
    json.dumps(stage_comparison([one]), allow_nan=False)


def test_every_studio_set_has_its_own_seeds_and_the_held_out_sets_their_own_bodies():
    """The held-out, heavy and fresh sets are only held out if no other set used their seeds
    or, for subjects the model was not built from, their bank bodies."""
    from benchmarks.bench_pipeline import (
        FRESH_SESSIONS,
        HEAVY_SESSIONS,
        INDEPENDENT_SESSIONS,
        STUDIO_SETS,
        VALIDATION_SESSIONS,
    )
    from bodymetry.studio.independent import IndependentSpec, committed_bank

    sets = [studio.rows for studio in STUDIO_SETS.values()]
    seeds = [s[0] for group in sets for s in group]
    assert len(seeds) == len(set(seeds))
    n = len(committed_bank())

    def bodies(group):
        return {IndependentSpec.parse(s[2].split(":", 1)[1]).index(n) for s in group}

    independent, validation, heavy, fresh = (
        bodies(g)
        for g in (INDEPENDENT_SESSIONS, VALIDATION_SESSIONS, HEAVY_SESSIONS, FRESH_SESSIONS)
    )
    assert not independent & validation and not heavy & (independent | validation)
    assert not fresh & (independent | validation | heavy) and len(fresh) == len(FRESH_SESSIONS)


def _edge_session(key: str, age: float, weight: float, errors: dict, share: float) -> dict:
    """An edge session result: session-stage errors per biometric, the discriminative
    stage's height error ``errors["disc"]`` and the share of kept frames measured."""
    table = {
        "height_mm": {"actual": 1500.0},
        "arm_span_mm": {"actual": 1400.0},
        "weight_kg": {"actual": weight},
    }
    checks = {k: {"session_error": errors[k], "discriminative_error": 0.0} for k in table}
    checks["height_mm"]["discriminative_error"] = errors["disc"]
    return {
        "session": f"/somewhere/{key}",
        "age_years": age,
        "edge": {"key": key, "target": "median", "age_years": age},
        "figure3": table,
        "checks": checks,
        "frame_share": share,
        "frame_share_pass": share >= MIN_FRAME_SHARE,
    }


def test_edge_summary_uses_a_childs_weight_share_and_averages_the_discriminative_error():
    ok = {"height_mm": -9.0, "arm_span_mm": 14.0, "disc": -120.0}
    sessions = [
        # A 21 kg child: 3 % is 0.63 kg, so 0.6 kg passes and 0.7 kg fails.
        _edge_session("girl_age6", 6.0, 21.0, {**ok, "weight_kg": 0.6}, 1.0),
        _edge_session("boy_age6", 6.0, 21.0, {**ok, "weight_kg": -0.7, "disc": 60.0}, 1.0),
        # An adult keeps 1.5 kg; a share of kept frames below 90 % fails.
        _edge_session("male_p50", 45.0, 70.0, {**ok, "weight_kg": 1.4, "disc": 30.0}, 0.85),
        {"session": "/somewhere/plain", "edge": None},  # not an edge session: left out
    ]
    out = edge_summary(sessions)
    rows = {r["edge"]: r for r in out["subjects"]}
    assert list(rows) == ["girl_age6", "boy_age6", "male_p50"]
    assert rows["girl_age6"]["weight_target_kg"] == pytest.approx(0.63)
    assert rows["girl_age6"]["within_issue_33"] is True
    assert rows["boy_age6"]["within"]["weight_kg"] is False
    assert rows["male_p50"]["within"] == {"height_mm": True, "arm_span_mm": True, "weight_kg": True}
    assert rows["male_p50"]["within_issue_33"] is False  # 85 % of kept frames
    assert out["discriminative_height"] == {
        "mean_absolute_error_mm": 70.0,
        "max_absolute_error_mm": 120.0,
    }
    assert out["within_issue_33"] == "1/3" and out["all_within"] is False
    assert edge_summary([{"session": "x", "edge": None}]) == {}


def test_edge_set_has_every_required_edge_body_once():
    """Issue 33: >= 10 subjects: 1st/99th percentile height and weight for women and
    men, an elderly subject and children of 6, 10 and 14, tight clothing."""
    from benchmarks.bench_pipeline import EDGE_SESSIONS
    from bodymetry.studio.independent import IndependentSpec

    specs = [IndependentSpec.parse(s[2].split(":", 1)[1]) for s in EDGE_SESSIONS]
    keys = [spec.edge for spec in specs]
    assert len(keys) >= 10 and len(set(keys)) == len(keys)
    for sex in ("female", "male"):
        for measure in ("height", "weight"):
            assert {f"{sex}_{measure}_p01", f"{sex}_{measure}_p99"} <= set(keys)
    assert any(k.endswith("_age80") for k in keys)
    for age in (6, 10, 14):
        assert any(k.endswith(f"_age{age}") for k in keys)
    assert all(spec.clothing == "tight" and not spec.hair for spec in specs)


def test_every_draw_of_the_edge_set_has_every_edge_body_with_a_motion_of_its_own():
    from benchmarks.bench_pipeline import EDGE_DRAWS, EDGE_SESSIONS

    def key(subject: str) -> str:
        return subject.rpartition("=")[2]

    draws = list(EDGE_DRAWS.values())
    assert draws[0] is EDGE_SESSIONS and len(draws) == 4
    for variant in draws:
        assert [key(s[2]) for s in variant] == [key(s[2]) for s in EDGE_SESSIONS]
    for rows in zip(*draws, strict=True):
        seeds, motions = [r[0] for r in rows], [r[1] for r in rows]
        # Each body moves in four different motions under four different seeds.
        assert len(set(seeds)) == 4 and len(set(motions)) == 4
        for seed, _, subject in rows:
            assert subject.startswith(f"independent:{seed},")


def test_the_fitted_shapes_are_kept_so_a_session_can_be_measured_again():
    rng = np.random.default_rng(3)
    nus = rng.normal(size=(3, 12))

    def frame(k: int, ok: bool = True) -> SimpleNamespace:
        state = BodyState(np.zeros((1, 3)), np.zeros((1, 37)), nus[k][None])
        return SimpleNamespace(
            frame=25 * k, ok=ok, estimates={"generative": SimpleNamespace(state=state)}
        )

    session = SimpleNamespace(ok=True, nu=tuple(nus.mean(axis=0)))
    results = SimpleNamespace(session_shape=session, frames=[frame(0), frame(1, False), frame(2)])
    shapes = json.loads(json.dumps(_fitted_shapes(results)))  # JSON as written
    assert list(shapes["generative"]) == ["0", "50"]  # the failed frame left out
    np.testing.assert_allclose(shapes["generative"]["50"], nus[2], atol=5e-7)
    np.testing.assert_allclose(shapes["session"], nus.mean(axis=0), atol=5e-7)
    withheld = SimpleNamespace(session_shape=SimpleNamespace(ok=False, nu=()), frames=[])
    assert _fitted_shapes(withheld) == {"session": None, "generative": {}}


def test_one_flag_picks_one_studio_set_and_every_set_names_its_sessions_apart(monkeypatch):
    from benchmarks.bench_pipeline import STUDIO_SETS, StudioSet, studio_set
    from benchmarks.bench_pipeline import _outfit as bench_outfit

    monkeypatch.delenv("BODYMETRY_BENCH_INDEPENDENT", raising=False)
    assert studio_set() == ("default", STUDIO_SETS["default"])
    assert studio_set(looks=False) == ("default", STUDIO_SETS["default"])
    assert studio_set(edge_fourth=True)[1].edge_summary
    assert studio_set(contrast_fresh=True)[1].stated_accuracy
    monkeypatch.setenv("BODYMETRY_BENCH_INDEPENDENT", "1")
    assert studio_set()[0] == "independent" and studio_set(looks=True)[0] == "looks"
    with pytest.raises(ValueError, match="one studio set at a time"):
        studio_set(looks=True, contrast=True)
    with pytest.raises(ValueError, match=r"no studio set \['bogus'\]"):
        studio_set(bogus=True)
    folders = [studio.folder(row) for studio in STUDIO_SETS.values() for row in studio.rows]
    assert len(folders) == len(set(folders))
    assert all(isinstance(studio, StudioSet) and studio.rows for studio in STUDIO_SETS.values())
    assert STUDIO_SETS["contrast_fresh"].folder(STUDIO_SETS["contrast_fresh"].rows[0]) == (
        "seed601_reach_white_plain_soft"
    )
    # The loose-gap set's folders say what each subject wears, as _outfit reads it.
    gaps = STUDIO_SETS["loose_gaps"]
    worn = [bench_outfit(gaps.folder(row)) for row in gaps.rows]
    assert worn == [bench_outfit(row[2]) for row in gaps.rows]
    assert gaps.folder(gaps.rows[0]) == "seed831_arm_raises_white_textured_hard_loose"
    assert worn.count("loose") == 4 and worn.count("tight") == 4
    # Each kind of row renders with its options and subject (the renderer stubbed).
    import benchmarks.bench_pipeline as bench

    calls = []
    monkeypatch.setattr(bench, "_render", lambda *args: calls.append(args) or args[0])
    root = Path("/nowhere")
    for name in ("default", "independent", "edge", "arms", "contrast_fresh"):
        STUDIO_SETS[name].render(root, STUDIO_SETS[name].rows[0])
    own, independent, edge, arms, look = calls
    assert own == (root / "seed11_walk_turn", 11, "walk_turn", {})
    assert independent[1:] == (43, "arm_raises", {}, "independent:43")
    assert independent[0] == root / "seed43_arm_raises_tight"
    assert edge[0].name == "seed331_arm_raises_female_height_p01" and edge[3] == {}
    assert arms[4] == "independent:371" and arms[0].name == "seed371_walk_turn_371"
    assert look[3]["look"].label == "white/plain/soft" and look[4] == "independent:601"
    # Sessions rendered beforehand stand in for the rows (BODYMETRY_BENCH_SESSIONS).
    calls.clear()
    studios = [STUDIO_SETS["contrast_fresh"], STUDIO_SETS["contrast_clothing"]]
    monkeypatch.delenv("BODYMETRY_BENCH_SESSIONS", raising=False)
    rendered = bench.studio_folders(root, studios)
    assert len(rendered) == len(calls) == 12 and rendered[6].name.startswith("seed611_")
    monkeypatch.setenv("BODYMETRY_BENCH_SESSIONS", "/a/s1::/b/s2")
    assert bench.studio_folders(root, studios) == [Path("/a/s1"), Path("/b/s2")]
    assert len(calls) == 12  # nothing rendered
