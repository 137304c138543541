"""End to end (issue 7): `bodymetry process` then `bodymetry evaluate` on the demo and on
four more studio sessions (other subjects, motions and seeds; the demo's rig, as a lab's
sessions share theirs; the fourth has no background clip and two bystanders), with the
default preset on all cores.

Per session: the paper's Figure 3 (actual, discriminative, disc. + generative,
GT + generative: mean and std over the frames that pass the quality gate), MPJPE,
the fit's mean silhouette IoU, frames left out and why, and the time per stage
(training, silhouettes, fitting; per frame: discriminative, annealing,
refinement) with the fitting time per kept frame and core.

Targets: disc. + generative |mean error| <= 15 mm height, <= 20 mm arm span, <= 2 kg
weight; per-frame std <= 25 mm, 25 mm, 3 kg; generative better than discriminative for
every biometric; mean IoU >= 0.90; <= 10 s per kept frame per core.

``python -m benchmarks pipeline --independent`` (or ``BODYMETRY_BENCH_INDEPENDENT=1``)
renders :data:`INDEPENDENT_SESSIONS` instead: six subjects whose geometry the model was
not built from (``--subject independent:...``, docs/studio.md), three in tight clothing
and three in the loose clothing layer with hair; the demo still runs first.
``--validation`` renders :data:`VALIDATION_SESSIONS`, four more such subjects held out
from every setting chosen on the independent six; ``--heavy`` renders
:data:`HEAVY_SESSIONS`, three more tight-clothed ones on the heaviest bank bodies
no other set uses; ``--fresh`` renders :data:`FRESH_SESSIONS`, three more
tight-clothed ones rendered after the last change chosen on the sets above;
``--looks`` renders :data:`LOOK_SESSIONS` (issue 32: neutral and wall-coloured
clothing in a plain grey room); ``--edge`` renders :data:`EDGE_SESSIONS` (issue 33:
the studio's edge bodies, by percentile of height, weight and age, children included,
tight clothing in the saturated colours) and adds :func:`edge_summary`;
``--edge-unseen``, ``--edge-fresh`` and ``--edge-fourth`` the same bodies with other
seeds and motions (:data:`EDGE_UNSEEN_SESSIONS`, :data:`EDGE_FRESH_SESSIONS`,
:data:`EDGE_FOURTH_SESSIONS`); ``--children`` three
children's sessions rendered after the ``body_accuracy`` caveat
(:data:`CHILDREN_SESSIONS`), with :func:`edge_summary`; ``--children-fresh`` six
rendered after the session stage left out the parts the camera does not resolve
(:data:`CHILDREN_FRESH_SESSIONS`), with :func:`edge_summary`;
``--contrast`` four in low-contrast clothing rendered after runs were held against the
sessions seen in like contrast (:data:`CONTRAST_SESSIONS`), with :func:`stated_accuracy`;
``--contrast-fresh`` six more rendered after every session stated a 95 % interval
(:data:`CONTRAST_FRESH_SESSIONS`), with :func:`stated_accuracy`;
``--loose-gaps`` four loose-clothed subjects with gaps of 6-20 mm beside four tight
ones, rendered after the outline check read the bare forearms and shins
(:data:`LOOSE_GAP_SESSIONS`; whether each loose one is warned and no tight one);
``--tight-night`` seven tight subjects rendered beside them (:data:`TIGHT_NIGHT_SESSIONS`);
``--shorts`` tight subjects in shorts and loose ones with small gaps (:data:`SHORTS_SESSIONS`);
``--skirts`` knee-length skirts (:data:`SKIRT_SESSIONS`: whether each run withholds what
the skirt makes wrong);
``--held-out`` renders
:data:`HELD_OUT_SESSIONS`, a replication of the four same-model sessions with new
subjects.

``BODYMETRY_BENCH_SESSIONS=a:b:c`` uses sessions rendered beforehand instead of
rendering the three studio sessions (the demo always runs). The discriminative
models are trained into a fresh cache, so the demo's run is a cold start
(training included) and the other sessions, on the same rig, reuse them;
``BODYMETRY_BENCH_WARM=1`` uses the user's cache instead; ``BODYMETRY_BENCH_SKIP_DEMO=1``
leaves the demo out (e.g. for ``--independent`` after a run of the default set).
``BODYMETRY_BENCH_WORKERS=N`` processes with N workers instead of all cores, and
``BODYMETRY_BENCH_FRAMES=N`` renders N frames per studio session instead of
:data:`FRAMES` (both are recorded in the result's ``setup``).

With the session stage on (the default), each biometric's check also gives the session
stage's error, its standard error, whether it is at least as accurate as the per-frame
mean, and whether it is within issue 15's targets (:data:`SESSION_TARGETS`); each
session gives the share of kept frames in the summary (>= :data:`MIN_FRAME_SHARE`) and
what the rescue did (``frames/rescue.json``).
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.bench_arm_evidence import arm_span_by_evidence
from bodymetry.capture.ground_truth import SubjectTruth
from bodymetry.cli import DEMO_SESSION
from bodymetry.estimation.arm_evidence import raised_frames
from bodymetry.estimation.body_model.geometry import mesh_volume
from bodymetry.estimation.run_config import ProcessConfig
from bodymetry.estimation.run_files import RunLayout, RunResults
from bodymetry.estimation.studio_accuracy import ADULT_AGE, CHILD_WEIGHT_SHARE

# Issue 15's session-stage targets on tight-clothed subjects are the runtime's own (a run's
# body_accuracy caveat holds like bodies to them; a child's weight to CHILD_WEIGHT_SHARE).
from bodymetry.estimation.studio_accuracy import TARGETS as SESSION_TARGETS
from bodymetry.fileio import load_npz
from bodymetry.frame_jobs import read_rescue
from bodymetry.process import process_session
from bodymetry.review.evaluation import evaluate_run
from bodymetry.studio.independent import IndependentSubject
from bodymetry.studio.looks import Look
from bodymetry.studio.synth import SubjectSpec, SynthConfig, synthesize

#: The extra studio sessions: (seed, motion, other SynthConfig fields). Rig of the demo
#: (seed 5). The last one is recorded as labs record: no empty-scene clip, and two
#: bystanders standing in the room (silhouettes from the learned segmenter and the
#: multi-view check).
SESSIONS = (
    (11, "walk_turn", {}),
    (12, "arm_raises", {}),
    (13, "reach", {}),
    (14, "mixed", {"background_clip": False, "bystanders": 2}),
)
#: A held-out replication of :data:`SESSIONS` (``python -m benchmarks pipeline
#: --held-out``): seeds never used before with the same motions and recording
#: conditions, rendered after the session stage and its comparison with the per-frame
#: mean (:func:`stage_comparison`) were settled on :data:`SESSIONS`. Seed 61 happens to
#: draw the same held-out body as seed 12 (body 93 of 100), with another motion.
HELD_OUT_SESSIONS = (
    (61, "walk_turn", {}),
    (62, "arm_raises", {}),
    (63, "reach", {}),
    (64, "mixed", {"background_clip": False, "bystanders": 2}),
)
#: Sessions of independent-geometry subjects on the demo's rig (issue 15): (seed, motion,
#: --subject text). These seeds were never used by a studio session before; each draws
#: another body of the bank (indices 16, 19, 43, 6, 9, 3). Kept frames (of 16) with a
#: wrist above the neck: 6, 6, 3 (tight); 6, 0 (walk_turn), 9 (loose).
INDEPENDENT_SESSIONS = (
    (43, "arm_raises", "independent:43"),
    (42, "reach", "independent:42"),
    (49, "mixed", "independent:49"),
    (46, "arm_raises", "independent:46,clothing=loose,hair=1"),
    (45, "walk_turn", "independent:45,clothing=loose,hair=1"),
    (56, "mixed", "independent:56,clothing=loose,hair=1"),
)
#: A held-out check of the independent set (issue 15), rendered after the outline
#: check's thresholds were set on :data:`INDEPENDENT_SESSIONS`: two tight, one in the
#: loose clothing layer without hair, one with both (bank bodies 20, 13, 45, 28).
#: ``python -m benchmarks pipeline --validation``.
VALIDATION_SESSIONS = (
    (71, "reach", "independent:71"),
    (72, "walk_turn", "independent:72"),
    (73, "arm_raises", "independent:73,clothing=loose,hair=0"),
    (74, "mixed", "independent:74,clothing=loose,hair=1"),
)
#: Issue 15's weight target missed on the heaviest held-out subject (seed 71, 94.9 kg):
#: does the weight error grow with the body? Three tight-clothed subjects on the three
#: heaviest bank bodies that no set above uses (bodies 42, 10 and 5: 101.4, 101.0 and
#: 89.5 kg, chosen by their true weight alone), seeds never used before.
#: ``python -m benchmarks pipeline --heavy``.
HEAVY_SESSIONS = (
    (81, "reach", "independent:81,body=42"),
    (82, "arm_raises", "independent:82,body=10"),
    (83, "mixed", "independent:83,body=5"),
)
#: The validation and heavy sets chose a change (the edge refinement's second pass,
#: 2026-12-03, which moved the weight of seeds 71 and 81 within issue 15's target), so
#: they no longer test it: three tight-clothed subjects rendered after it, seeds never
#: used before, on bank bodies no set above uses (29, 35 and 40, the bodies those seeds
#: draw), motions with the arms overhead, reaching and mixed.
#: ``python -m benchmarks pipeline --fresh``.
FRESH_SESSIONS = (
    (91, "arm_raises", "independent:91"),
    (92, "reach", "independent:92"),
    (96, "mixed", "independent:96"),
)
#: Issue 32: independent tight-clothed subjects in white, light grey, black and
#: wall-coloured clothing, in the plain grey room (one in the textured lab), hard and
#: soft light; seeds never used before, rendered after the evidence fusion's weights
#: were fitted (on other seeds). ``python -m benchmarks pipeline --looks``: each
#: session's share of kept frames in the summary must reach :data:`MIN_FRAME_SHARE`
#: and its session stage issue 15's targets.
LOOK_SESSIONS = (
    (311, "arm_raises", "independent:311", "clothing=white,room=plain,light=hard"),
    (312, "reach", "independent:312", "clothing=light_grey,room=plain,light=soft"),
    (313, "mixed", "independent:313", "clothing=black,room=plain,light=hard"),
    (314, "arm_raises", "independent:314", "clothing=wall,room=plain,light=soft"),
    (315, "walk_turn", "independent:315", "clothing=white,room=plain,light=soft"),
    (316, "reach", "independent:316", "clothing=wall,room=textured,light=hard"),
)
#: Issue 32: subjects in low-contrast clothing rendered after runs were held against the
#: studio's sessions seen in like contrast (``python -m benchmarks pipeline --contrast``):
#: does the outline contrast class them as their look says, and does the accuracy the
#: run states (``studio_accuracy``, the ``body_accuracy`` caveat) match their errors?
#: Seeds, bodies and looks never used before; one light grey in the textured lab.
CONTRAST_SESSIONS = (
    (421, "reach", "independent:421", "clothing=white,room=plain,light=hard"),
    (422, "arm_raises", "independent:422", "clothing=light_grey,room=plain,light=soft"),
    (423, "mixed", "independent:423", "clothing=wall,room=plain,light=hard"),
    (424, "arm_raises", "independent:424", "clothing=light_grey,room=textured,light=soft"),
)
#: Issue 32: six more in neutral and wall-coloured clothing, rendered after every
#: session stated a 95 % interval (``--contrast-fresh``): seeds, bodies and motions
#: never used, each look in a plain or textured room under hard or soft light.
CONTRAST_FRESH_SESSIONS = (
    (601, "reach", "independent:601", "clothing=white,room=plain,light=soft"),
    (602, "arm_raises", "independent:602", "clothing=light_grey,room=plain,light=hard"),
    (603, "mixed", "independent:603", "clothing=wall,room=plain,light=soft"),
    (604, "walk_turn", "independent:604", "clothing=black,room=plain,light=hard"),
    (605, "arm_raises", "independent:605", "clothing=white,room=textured,light=hard"),
    (606, "reach", "independent:606", "clothing=wall,room=textured,light=soft"),
)
#: Issue 32: the outline check in low contrast (``--contrast-clothing``), rendered after
#: it held low-contrast runs to their own threshold: four tight and two loose-clothed
#: subjects (the studio's loose shirt and shorts) in neutral and wall-coloured clothing,
#: seeds, bodies and motions never used.
CONTRAST_CLOTHING_SESSIONS = (
    (611, "arm_raises", "independent:611", "clothing=white,room=plain,light=hard"),
    (612, "reach", "independent:612", "clothing=light_grey,room=textured,light=soft"),
    (613, "walk_turn", "independent:613", "clothing=wall,room=plain,light=hard"),
    (614, "mixed", "independent:614", "clothing=light_grey,room=plain,light=soft"),
    (615, "arm_raises", "independent:615,clothing=loose", "clothing=white,room=plain,light=soft"),
    (616, "reach", "independent:616,clothing=loose", "clothing=light_grey,room=plain,light=hard"),
)
#: Issue 31: the outline check's loose-clothing warning on gaps near its limit
#: (``--loose-gaps``), rendered after it read the bare forearms and shins: the studio's
#: loose or draped shirt and shorts with gaps of 6-20 mm (``ease``) in saturated,
#: white, light grey and wall-coloured clothing, beside tight subjects in the same
#: looks (a heavy woman among them); seeds, bodies and motions never used. Whether
#: each loose subject is warned, and no tight one.
LOOSE_GAP_SESSIONS = (
    (
        831,
        "arm_raises",
        "independent:831,clothing=loose,ease=7",
        "clothing=white,room=textured,light=hard",
    ),
    (832, "reach", "independent:832", "clothing=wall,room=plain,light=hard"),
    (833, "walk_turn", "independent:833,clothing=loose,ease=20", "clothing=saturated"),
    (834, "mixed", "independent:834", "clothing=light_grey,room=textured,light=soft"),
    (
        835,
        "reach",
        "independent:835,clothing=draped,ease=6",
        "clothing=light_grey,room=plain,light=soft",
    ),
    (
        836,
        "arm_raises",
        "independent:836,edge=female_weight_p99",
        "clothing=white,room=plain,light=hard",
    ),
    (
        837,
        "mixed",
        "independent:837,clothing=loose,ease=9,hair=1",
        "clothing=wall,room=textured,light=soft",
    ),
    (838, "walk_turn", "independent:838", "clothing=black,room=plain,light=soft"),
)
#: Tight-clothed subjects rendered beside the loose-gap sessions (``--tight-night``,
#: 2026-12-07 night) to check the outline check raised no false warning: bank bodies
#: and the heaviest woman and man, mostly in neutral and wall-coloured clothing;
#: seeds, bodies and motions never used. Their weights join the studio's accuracy.
TIGHT_NIGHT_SESSIONS = (
    (815, "reach", "independent:815", "clothing=white,room=plain,light=soft"),
    (816, "arm_raises", "independent:816", "clothing=light_grey,room=plain,light=hard"),
    (817, "mixed", "independent:817", "clothing=wall,room=textured,light=soft"),
    (821, "reach", "independent:821", "clothing=white,room=plain,light=soft"),
    (822, "reach", "independent:822", "clothing=wall,room=textured,light=soft"),
    (823, "arm_raises", "independent:823,edge=male_weight_p99", "clothing=saturated"),
    (
        824,
        "walk_turn",
        "independent:824,edge=female_weight_p99",
        "clothing=light_grey,room=plain,light=hard",
    ),
)
#: Issue 31, skirts (``--skirts``, 2026-12-08): a tight top and a knee-length A-line skirt
#: (``clothing=skirt``, the shins bare) on the heaviest-looking bank body (twice), a woman
#: of 68, the thinnest woman, a girl of 10, white clothing in the plain room, a skirt only
#: 5 mm off the hips and the tallest man; rendered after the skirt was added to the
#: studio, seeds never used. Then five rendered after the "legs hidden" bound was set
#: on those (911-915: two dresses, the shortest woman in light grey, the girl of 6, the
#: woman of 80 in a skirt 30 mm off the hips).
SKIRT_SESSIONS = (
    (901, "walk_turn", "independent:901,clothing=skirt", "clothing=saturated"),
    (902, "arm_raises", "independent:902,clothing=skirt", "clothing=saturated"),
    (903, "reach", "independent:903,clothing=skirt", "clothing=saturated"),
    (
        904,
        "walk_turn",
        "independent:904,edge=female_weight_p01,clothing=skirt",
        "clothing=saturated",
    ),
    (905, "mixed", "independent:905,edge=girl_age10,clothing=skirt", "clothing=saturated"),
    (
        906,
        "arm_raises",
        "independent:906,clothing=skirt",
        "clothing=white,room=plain,light=hard",
    ),
    (907, "reach", "independent:907,clothing=skirt,ease=5", "clothing=saturated"),
    (908, "walk_turn", "independent:908,edge=male_height_p99,clothing=skirt", "clothing=saturated"),
    (911, "walk_turn", "independent:911,clothing=dress", "clothing=saturated"),
    (
        912,
        "reach",
        "independent:912,edge=female_height_p01,clothing=skirt",
        "clothing=light_grey,room=plain,light=soft",
    ),
    (913, "arm_raises", "independent:913,edge=girl_age6,clothing=skirt", "clothing=saturated"),
    (914, "mixed", "independent:914,edge=female_weight_p99,clothing=dress", "clothing=saturated"),
    (
        915,
        "walk_turn",
        "independent:915,edge=female_age80,clothing=skirt,ease=30",
        "clothing=saturated",
    ),
)
#: Issue 31, the outline check's bare-shin signature (``--shorts``, 2026-12-08): seven
#: tight subjects in shorts (``clothing=shorts``, the shins bare: seed 42's body
#: reaching, the woman of 80, the heaviest man, the thinnest woman, the girl of 6, light
#: grey and white) and five loose ones with gaps of 5-8 mm (a draped one, two with hair,
#: the heaviest man), rendered after the forearms were left out of it; seeds never used.
SHORTS_SESSIONS = (
    (871, "reach", "independent:871,body=19,clothing=shorts", "clothing=saturated"),
    (872, "arm_raises", "independent:872,edge=female_age80,clothing=shorts", "clothing=saturated"),
    (
        873,
        "walk_turn",
        "independent:873,edge=male_weight_p99,clothing=shorts",
        "clothing=saturated",
    ),
    (874, "mixed", "independent:874,edge=female_weight_p01,clothing=shorts", "clothing=saturated"),
    (875, "arm_raises", "independent:875,edge=girl_age6,clothing=shorts", "clothing=saturated"),
    (
        876,
        "reach",
        "independent:876,clothing=shorts",
        "clothing=light_grey,room=plain,light=soft",
    ),
    (877, "mixed", "independent:877,clothing=shorts", "clothing=white,room=textured,light=hard"),
    (881, "arm_raises", "independent:881,clothing=loose,ease=5", "clothing=saturated"),
    (
        882,
        "reach",
        "independent:882,clothing=loose,ease=6",
        "clothing=light_grey,room=plain,light=hard",
    ),
    (
        883,
        "mixed",
        "independent:883,clothing=draped,ease=8",
        "clothing=white,room=plain,light=soft",
    ),
    (884, "walk_turn", "independent:884,clothing=loose,ease=6,hair=1", "clothing=saturated"),
    (
        885,
        "arm_raises",
        "independent:885,edge=male_weight_p99,clothing=loose,ease=8",
        "clothing=saturated",
    ),
)
DEMO_RIG_SEED = 5
FRAMES = 400  # 16 kept frames each

#: Issue 33: the edge set, one session per edge body of the studio
#: (``--subject independent:SEED,edge=KEY``, docs/studio.md): the 1st and 99th
#: percentile of height and of weight for women and for men (aged 18-65), a woman of
#: 80 and children of 6, 10 and 14 years, all in tight clothing of the saturated
#: colours (the default look, so that silhouettes are not the problem), seeds never used
#: before, motions in turn. ``python -m benchmarks pipeline --edge``.
EDGE_SESSIONS = (
    (331, "arm_raises", "independent:331,edge=female_height_p01"),
    (332, "reach", "independent:332,edge=female_height_p99"),
    (333, "mixed", "independent:333,edge=female_weight_p01"),
    (334, "walk_turn", "independent:334,edge=female_weight_p99"),
    (335, "arm_raises", "independent:335,edge=male_height_p01"),
    (336, "reach", "independent:336,edge=male_height_p99"),
    (337, "mixed", "independent:337,edge=male_weight_p01"),
    (338, "walk_turn", "independent:338,edge=male_weight_p99"),
    (339, "arm_raises", "independent:339,edge=female_age80"),
    (340, "reach", "independent:340,edge=girl_age6"),
    (341, "mixed", "independent:341,edge=boy_age10"),
    (342, "arm_raises", "independent:342,edge=girl_age14"),
)
_EDGE_MOTIONS = ("arm_raises", "reach", "mixed", "walk_turn")


def edge_variant(seed_offset: int, motion_shift: int) -> tuple[tuple[int, str, str], ...]:
    """The edge bodies of :data:`EDGE_SESSIONS` again, each with its seed moved by
    ``seed_offset`` and its motion ``motion_shift`` places further along
    arm_raises -> reach -> mixed -> walk_turn: the same percentile bodies, drawn,
    dressed and moving as no earlier set rendered them."""
    return tuple(
        (
            seed + seed_offset,
            _EDGE_MOTIONS[(_EDGE_MOTIONS.index(motion) + motion_shift) % len(_EDGE_MOTIONS)],
            f"independent:{seed + seed_offset},edge={subject.rpartition('=')[2]}",
        )
        for seed, motion, subject in EDGE_SESSIONS
    )


#: Issue 33, the edge bodies again with seeds and motions the set above never gave
#: them (seed + 20, the next motion), rendered after the height was read from the
#: floor: ``--edge-unseen``.
EDGE_UNSEEN_SESSIONS = edge_variant(20, 1)
#: Issue 33, a third draw (seed + 120, the motion after that), rendered after the session
#: stage compared at full resolution, and never used to choose a setting:
#: ``--edge-fresh``.
EDGE_FRESH_SESSIONS = edge_variant(120, 2)
#: Issue 33, a fourth draw (seed + 220, the last motion each body had not moved in),
#: rendered after runs stated their 95 % interval, to check the interval on sessions the
#: studio's scored ones do not hold and the edge bodies once more: ``--edge-fourth``.
EDGE_FOURTH_SESSIONS = edge_variant(220, 3)
#: The edge sets by flag, in the order they were drawn.
EDGE_DRAWS = {
    "edge": EDGE_SESSIONS,
    "edge_unseen": EDGE_UNSEEN_SESSIONS,
    "edge_fresh": EDGE_FRESH_SESSIONS,
    "edge_fourth": EDGE_FOURTH_SESSIONS,
}
#: Issue 33, the arm span's evidence (``estimation/arm_evidence.py``): the arms-down
#: sessions of the sets above read the arm span high, so walking subjects (the arms by the
#: sides) are checked on bodies and seeds none of those sets used, beside two with the arms
#: raised or reaching, rendered after the ``arms_down`` caveat was written:
#: ``python -m benchmarks pipeline --arms``.
ARMS_SESSIONS = (
    (371, "walk_turn", "independent:371"),
    (372, "walk_turn", "independent:372"),
    (373, "walk_turn", "independent:373,edge=male_height_p99"),
    (374, "walk_turn", "independent:374,edge=girl_age14"),
    (375, "arm_raises", "independent:375"),
    (376, "reach", "independent:376,edge=female_weight_p01"),
)
#: Issue 33, the weight read from the posed bodies (``estimation/posed_weight.py``):
#: six subjects rendered after that change, seeds never used before, on bodies of the
#: bank and the edge set the change was not measured on in these motions (the heaviest
#: man, the heaviest woman, a man of 80, a boy of 6, the median woman), motions with
#: deep hip flexion among them: ``python -m benchmarks pipeline --weight``.
WEIGHT_SESSIONS = (
    (381, "reach", "independent:381"),
    (382, "mixed", "independent:382,edge=male_weight_p99"),
    (383, "arm_raises", "independent:383,edge=female_weight_p99"),
    (384, "walk_turn", "independent:384,edge=male_age80"),
    (385, "reach", "independent:385,edge=boy_age6"),
    (386, "mixed", "independent:386,edge=female_p50"),
)
#: Issue 33, the studio's accuracy on like bodies (``estimation/studio_accuracy.py``):
#: children rendered after the ``body_accuracy`` caveat was written, on seeds never used
#: before, in motions their bodies had not been rendered in before (both 6-year-olds, and
#: the 10-year-old, the sparsest validated body): ``python -m benchmarks pipeline --children``.
CHILDREN_SESSIONS = (
    (391, "mixed", "independent:391,edge=boy_age6"),
    (392, "arm_raises", "independent:392,edge=girl_age6"),
    (393, "reach", "independent:393,edge=boy_age10"),
)
#: Issue 33, children rendered after the session stage stopped aligning the parts of the
#: model the camera does not resolve (``SessionShapeConfig.thin_px``: a child's fingers),
#: on seeds never used before, each child of the edge set in a motion of its own:
#: ``python -m benchmarks pipeline --children-fresh``.
CHILDREN_FRESH_SESSIONS = (
    (591, "reach", "independent:591,edge=girl_age6"),
    (592, "walk_turn", "independent:592,edge=boy_age6"),
    (593, "arm_raises", "independent:593,edge=girl_age10"),
    (594, "mixed", "independent:594,edge=boy_age10"),
    (595, "reach", "independent:595,edge=girl_age14"),
    (596, "arm_raises", "independent:596,edge=boy_age14"),
)
TARGETS = {
    "height_mm": {"mean_error": 15.0, "std": 25.0},
    "arm_span_mm": {"mean_error": 20.0, "std": 25.0},
    "weight_kg": {"mean_error": 2.0, "std": 3.0},
}


#: Issue 15: the share of kept frames that must pass the quality gate.
MIN_FRAME_SHARE = 0.9


def _outfit(subject: str) -> str:
    """``loose`` or ``tight``: what an independent session's subject wears, from its
    ``--subject`` text or its folder name (``seed46_arm_raises_loose``); the draped
    garments, the skirt and the dress are loose ones."""
    garments = ("clothing=loose", "clothing=draped", "clothing=skirt", "clothing=dress")
    worn = any(g in subject for g in garments) or subject.endswith(("_loose", "_draped"))
    return "loose" if worn else "tight"


def _workers() -> int:
    """Worker processes: ``BODYMETRY_BENCH_WORKERS`` or all cores."""
    return int(os.environ.get("BODYMETRY_BENCH_WORKERS") or os.cpu_count() or 1)


def _frames() -> int:
    """Frames per studio session: ``BODYMETRY_BENCH_FRAMES`` or :data:`FRAMES`."""
    return int(os.environ.get("BODYMETRY_BENCH_FRAMES") or FRAMES)


def _render(
    folder: Path, seed: int, motion: str, options: dict, subject: str | None = None
) -> Path:
    config = SynthConfig(
        frames=_frames(),
        seed=seed,
        rig_seed=DEMO_RIG_SEED,
        motion=motion,
        subject=SubjectSpec.parse(subject, seed),
        calibration_frames=30,  # the true calibration.yaml is written; no clip is solved
        **options,
    )
    synthesize(folder, config, workers=_workers())
    return folder


def session_name(seed: int, motion: str, subject: str) -> str:
    """A rendered session's folder name: ``seed371_walk_turn_371_edge-girl_age14``."""
    return f"seed{seed}_{motion}_{subject.partition(':')[2].replace(',', '_').replace('=', '-')}"


def _rescue_log(run: Path) -> dict:
    return {str(f): o.to_json() for f, o in read_rescue(RunLayout(run)).items()}


def _fitted_shapes(results: RunResults) -> dict:
    """The session stage's ν (None when it was not accepted) and each measured
    frame's generative ν, rounded to 6 digits."""
    session = results.session_shape
    return {
        "session": (
            [round(float(v), 6) for v in session.nu]
            if session is not None and session.ok and session.nu
            else None
        ),
        "generative": {
            str(f.frame): [round(float(v), 6) for v in f.estimates["generative"].state.nu[0]]
            for f in results.frames
            if f.ok and "generative" in f.estimates
        },
    }


def rendered_weight(session: Path, frames: list[int], truth: SubjectTruth | None) -> dict | None:
    """Issue 33: the weight of the body the studio rendered, in the poses it rendered.

    An independent subject was posed by linear blend skinning until 2026-12-07,
    which does not keep a body's volume (it loses some where joints bend, up to 3 L
    with the arms overhead), and by dual quaternion skinning since, which keeps it
    within about half a litre (``estimation/body_model/skinning.py``); the silhouettes show the
    posed bodies, so no method that reads them can see the rest body's volume.
    Each session is posed again the way it was rendered (``subject.json``'s
    ``skinning``; none named: linear blend).
    The pipeline reads its weight from its own posed bodies
    (``estimation/posed_weight.py``), right for a real person, whose volume does
    not change when they move; against the studio's rest weight it reads the
    skinning's loss as its own error. This gives the median over ``frames`` of
    the skinned nude body's volume times the truth's density (``weight_kg`` over
    ``volume_l``) beside the rest weight. None for a subject of our own model or
    without ground truth.

    Returns
    -------
    dict or None
        ``rest_kg``, ``posed_kg`` (median), ``posed_low_kg`` and ``posed_high_kg``
        (the frames' extremes) and ``loss_kg`` (posed less rest).
    """
    if truth is None or not str(truth.details.get("subject", "")).startswith("independent:"):
        return None
    rest, litres = truth.get("weight_kg"), truth.get("volume_l")
    if not rest or not litres or not frames:
        return None
    subject = IndependentSubject(SubjectSpec.parse(truth.details["subject"], 0).independent)
    states = load_npz(Path(session) / "ground_truth" / "states.npz")
    rows = [int(np.nonzero(states["frame"] == f)[0][0]) for f in frames]
    skinning = str(truth.details.get("skinning", "linear_blend"))
    verts = subject.skin(states["tau"][rows], states["theta"][rows], skinning=skinning)[0]
    kg_per_m3 = rest / litres * 1000.0
    posed = mesh_volume(verts, subject.bank.faces) * kg_per_m3
    median = float(np.median(posed))
    return {
        "rest_kg": round(rest, 3),
        "posed_kg": round(median, 3),
        "posed_low_kg": round(float(posed.min()), 3),
        "posed_high_kg": round(float(posed.max()), 3),
        "loss_kg": round(median - rest, 3),
    }


def evaluate_session(session: Path, run: Path, cache_dir: Path | None = None) -> dict:
    """Process and evaluate one session; the figures of this benchmark."""
    workers = _workers()
    t0 = time.perf_counter()
    results = process_session(session, run, ProcessConfig(workers=workers, cache_dir=cache_dir))
    t_process = time.perf_counter() - t0
    t0 = time.perf_counter()
    ev = evaluate_run(run, workers=workers).to_json()
    t_eval = time.perf_counter() - t0
    frames = results.frames
    fitted = [f for f in frames if f.fitted]
    per_frame = {
        k: round(float(np.mean([f.seconds[k] for f in fitted])), 2)
        for k in ("discriminative", "annealing", "refinement", "total")
    }
    table = ev["table"]
    checks = {}
    for key, target in TARGETS.items():
        row = table[key]
        err = row["generative"]["mean"] - row["actual"]
        checks[key] = {
            "mean_error": round(err, 2),
            "std": round(row["generative"]["std"], 2),
            "discriminative_error": round(row["discriminative"]["mean"] - row["actual"], 2),
            "pass_mean": abs(err) <= target["mean_error"],
            "pass_std": row["generative"]["std"] <= target["std"],
            "generative_better": abs(err) < abs(row["discriminative"]["mean"] - row["actual"]),
        }
        if "session" in row:
            s_err = row["session"]["mean"] - row["actual"]
            checks[key].update(
                session_error=round(s_err, 2),
                session_standard_error=round(row["session"]["std"], 2),
                session_at_least_as_accurate=abs(s_err) <= abs(err) + 1e-9,
                session_within_issue_15=abs(s_err) <= SESSION_TARGETS[key],
            )
    fitting = results.timing_seconds["fitting"]
    truth = SubjectTruth.read(Path(session) / "ground_truth")
    details = {} if truth is None else truth.details
    return {
        "session": str(session),
        "subject": details.get("subject"),
        "age_years": details.get("age_years"),
        "edge": details.get("edge"),
        "kept_frames": len(frames),
        "frames_in_summary": ev["frames"],
        "frame_share": round(ev["frames"] / max(len(frames), 1), 3),
        "frame_share_pass": ev["frames"] >= MIN_FRAME_SHARE * len(frames),
        "rescue": _rescue_log(run),
        "left_out": {str(f.frame): f.status for f in frames if not f.ok},
        "figure3": table,
        "mpjpe_mm": ev["mpjpe_mm"],
        "silhouette_iou_mean": round(ev["silhouette_iou_mean"], 4),
        "checks": checks,
        # Issue 15 item 4: the loose-clothing and hair check, as it comes.
        "outline": None if results.outline is None else results.outline.to_json(),
        # Issue 33: the measured frames with an arm raised (the arm span's evidence),
        # and the caveats the run states.
        "arm_raised_frames": list(raised_frames(results.frames) or ()),
        "caveats": [c.code for c in results.caveats],
        # Issue 32: how plainly capture saw the subject stand out (the studio's accuracy
        # holds a run against the sessions seen in like contrast).
        "outline_contrast": results.outline_contrast,
        "studio_accuracy": {k: a.to_json() for k, a in results.studio_accuracy.items()},
        # The 95 % interval the run stated (estimation/uncertainty.py): did it hold the truth?
        "intervals": {
            k: {**i.to_json(), "holds_truth": i.contains(table[k]["actual"])}
            for k, i in results.stated_intervals.items()
            if table.get(k, {}).get("actual") is not None
        },
        # Issue 33: the session weight read from the posed bodies, and the canonical one.
        "canonical_weight_kg": (
            None
            if results.session_shape is None or not results.session_shape.ok
            else round(results.session_shape.canonical_weight_kg, 3)
        ),
        # Issue 33: the studio's skinned body in the measured frames' poses (what their
        # silhouettes show), against which the posed weight can be read without the
        # skinning's loss.
        "rendered_weight": rendered_weight(session, [f.frame for f in frames if f.ok], truth),
        # Issue 33: how far the session stage's shape prior moved each value.
        "prior_pull": (
            {k: round(results.session_shape.prior_pull[k], 3) for k in SESSION_TARGETS}
            if results.session_shape is not None and results.session_shape.prior_pull
            else None
        ),
        # The fitted shapes, so that a change of a measurement's definition can be
        # scored again on these sessions without fitting them again.
        "shapes": _fitted_shapes(results),
        "models_reused": results.models_reused,
        "timing_seconds": {
            **results.timing_seconds,
            "process_wall_with_review": round(t_process, 1),
            "evaluate_wall": round(t_eval, 1),
            "per_frame_mean": per_frame,
            "fitting_per_kept_frame_per_core": round(fitting * workers / max(len(fitted), 1), 2),
            "workers": workers,
        },
    }


#: A session stage error worse than the per-frame mean's by this many standard errors
#: of the difference is significantly worse (about 2.5 % one-sided for a normal error).
SIGNIFICANT_Z = 2.0


def stage_comparison(sessions: list[dict]) -> dict:
    """Issue 15: is the session stage at least as accurate as the per-frame mean?

    Per biometric, over the sessions whose session stage measured it:

    - ``mean_absolute_error`` and ``rms_error`` of the per-frame mean (disc. +
      generative) and of the session stage, and ``session_at_least_as_accurate``:
      both no larger for the session stage (the table's accuracy);
    - per session, ``difference``, the session's absolute error less the per-frame
      mean's (negative: the session stage is nearer the truth), and ``z``, that
      difference over ``sqrt(se_session² + se_per_frame²)``, where the per-frame
      mean's standard error is its standard deviation over ``sqrt(n)`` and the
      session's is the stage's own (a one-frame session has no per-frame standard
      error: None, and the z uses the session's alone). Both estimates come from
      the same frames, so their errors are positively correlated and this ``z``
      understates how distinguishable a difference is, in either direction;
    - ``sessions_at_least_as_accurate``: how many sessions have ``difference <= 0``;
      ``significantly_worse``: the sessions with ``z >= SIGNIFICANT_Z``.

    Parameters
    ----------
    sessions : list of dict
        :func:`evaluate_session` results.

    Returns
    -------
    dict
        Per biometric key the block above; ``all_biometrics`` is True when the
        session stage is at least as accurate over the sessions on every biometric
        and significantly worse in none. Empty without any session stage.
    """
    out: dict = {}
    for key in TARGETS:
        rows = []
        for s in sessions:
            row = s["figure3"][key]
            if "session" not in row:
                continue
            pf, st = row["generative"], row["session"]
            e_pf, e_s = pf["mean"] - row["actual"], st["mean"] - row["actual"]
            # One frame has no spread to take a standard error from: the session's
            # own standard error is then all the z has.
            se_pf = pf["std"] / np.sqrt(pf["n"]) if pf["n"] > 1 else None
            spread = float(np.hypot(se_pf or 0.0, st["std"]))  # the session's "std": its SE
            diff = abs(e_s) - abs(e_pf)
            rows.append(
                {
                    "session": Path(s["session"]).name,
                    "per_frame_error": round(e_pf, 2),
                    "per_frame_standard_error": None if se_pf is None else round(se_pf, 2),
                    "session_error": round(e_s, 2),
                    "session_standard_error": round(st["std"], 2),
                    "difference": round(diff, 2),
                    "z": round(diff / spread, 2) if spread > 0 else None,
                }
            )
        if not rows:
            continue
        e_pf = np.array([r["per_frame_error"] for r in rows])
        e_s = np.array([r["session_error"] for r in rows])
        mae = {"per_frame": float(np.abs(e_pf).mean()), "session": float(np.abs(e_s).mean())}
        rms = {
            "per_frame": float(np.sqrt((e_pf**2).mean())),
            "session": float(np.sqrt((e_s**2).mean())),
        }
        out[key] = {
            "sessions": rows,
            "mean_absolute_error": {k: round(v, 2) for k, v in mae.items()},
            "rms_error": {k: round(v, 2) for k, v in rms.items()},
            "session_at_least_as_accurate": bool(
                mae["session"] <= mae["per_frame"] and rms["session"] <= rms["per_frame"]
            ),
            "sessions_at_least_as_accurate": (
                f"{sum(r['difference'] <= 0 for r in rows)}/{len(rows)}"
            ),
            "significantly_worse": [
                r["session"] for r in rows if r["z"] is not None and r["z"] >= SIGNIFICANT_Z
            ],
        }
    if out:
        out["all_biometrics"] = all(
            b["session_at_least_as_accurate"] and not b["significantly_worse"] for b in out.values()
        )
    return out


def edge_summary(sessions: list[dict]) -> dict:
    """Issue 33: the edge set's table and the discriminative stage's height error.

    Parameters
    ----------
    sessions : list of dict
        :func:`evaluate_session` results of edge-body sessions (others are skipped).

    Returns
    -------
    dict
        ``subjects``: per session its edge key, age, true height and weight, the
        session stage's errors (height mm, arm span mm, weight kg), the weight target
        (1.5 kg, or :data:`CHILD_WEIGHT_SHARE` of the true weight for a child), the
        share of kept frames measured, the discriminative stage's height error, how
        far the session stage's shape prior moved each value (``prior_pull``, None
        for runs without it) and whether the session is within issue 33's targets;
        ``discriminative_height``: the mean absolute (and largest) discriminative
        height error over the set; ``all_within``: every subject within the targets
        with >= 90 % of kept frames.
    """
    rows = []
    for s in sessions:
        edge = s.get("edge")
        if not edge:
            continue
        table, checks = s["figure3"], s["checks"]
        actual_weight = table["weight_kg"]["actual"]
        child = float(s.get("age_years") or edge["age_years"]) < ADULT_AGE
        weight_target = (
            CHILD_WEIGHT_SHARE * actual_weight if child else SESSION_TARGETS["weight_kg"]
        )
        targets = {**SESSION_TARGETS, "weight_kg": weight_target}
        errors = {k: checks[k].get("session_error") for k in SESSION_TARGETS}
        within = {k: errors[k] is not None and abs(errors[k]) <= targets[k] for k in targets}
        rows.append(
            {
                "edge": edge["key"],
                "target": edge["target"],
                "age_years": edge["age_years"],
                "height_mm": round(table["height_mm"]["actual"], 1),
                "weight_kg": round(actual_weight, 2),
                "session_error": errors,
                "weight_target_kg": round(weight_target, 2),
                "frame_share": s["frame_share"],
                "discriminative_height_error_mm": checks["height_mm"]["discriminative_error"],
                "prior_pull": s.get("prior_pull"),
                "within_issue_33": all(within.values()) and s["frame_share_pass"],
                "within": within,
            }
        )
    if not rows:
        return {}
    disc = np.abs([r["discriminative_height_error_mm"] for r in rows])
    return {
        "subjects": rows,
        "discriminative_height": {
            "mean_absolute_error_mm": round(float(disc.mean()), 1),
            "max_absolute_error_mm": round(float(disc.max()), 1),
        },
        "within_issue_33": f"{sum(r['within_issue_33'] for r in rows)}/{len(rows)}",
        "all_within": all(r["within_issue_33"] for r in rows),
    }


def stated_accuracy(sessions: list[dict]) -> list[dict]:
    """Per session: its outline contrast, the accuracy the run stated for each core
    measurement (the studio's like sessions: scope, count, RMS, mean), its session-stage
    error, and whether the ``body_accuracy`` caveat was raised."""
    rows = []
    for s in sessions:
        f3 = s["figure3"]
        rows.append(
            {
                "session": Path(s["session"]).name,
                "outline_contrast": s.get("outline_contrast"),
                "caveats": s["caveats"],
                **{
                    key: {
                        "error": round(f3[key]["session"]["mean"] - f3[key]["actual"], 2)
                        if "session" in f3[key]
                        else None,
                        "stated": s["studio_accuracy"].get(key),
                    }
                    for key in SESSION_TARGETS
                },
            }
        )
    return rows


@dataclass(frozen=True)
class StudioSet:
    """One set of studio sessions the benchmark renders (``--<name>``, :data:`STUDIO_SETS`).

    Attributes
    ----------
    rows : tuple of tuple
        ``(seed, motion, options)`` for sessions of our own body model, ``(seed,
        motion, subject)`` or ``(seed, motion, subject, look)`` for the others.
    folder : callable
        A row's rendered session folder name.
    edge_summary : bool
        The result adds :func:`edge_summary` (edge bodies and children).
    stated_accuracy : bool
        The result adds :func:`stated_accuracy` (sessions held against those seen in
        like contrast).
    """

    rows: tuple
    folder: Callable[[tuple], str]
    edge_summary: bool = False
    stated_accuracy: bool = False

    def render(self, root: Path, row: tuple) -> Path:
        """Render ``row`` into ``root``/its folder."""
        seed, motion, *rest = row
        if len(rest) == 1 and isinstance(rest[0], dict):  # our own body model's
            return _render(root / self.folder(row), seed, motion, rest[0])
        options = {"look": Look.parse(rest[1])} if len(rest) == 2 else {}
        return _render(root / self.folder(row), seed, motion, options, rest[0])


def _own_model_folder(row: tuple) -> str:
    return f"seed{row[0]}_{row[1]}"


def _outfit_folder(row: tuple) -> str:
    return f"seed{row[0]}_{row[1]}_{_outfit(row[2])}"


def _edge_folder(row: tuple) -> str:
    return f"seed{row[0]}_{row[1]}_{row[2].rpartition('=')[2]}"


def _look_folder(row: tuple) -> str:
    return f"seed{row[0]}_{row[1]}_{Look.parse(row[3]).label.replace('/', '_')}"


def _look_outfit_folder(row: tuple) -> str:
    """:func:`_look_folder` with the outfit (``..._loose``: :func:`_outfit` reads it back)."""
    return f"{_look_folder(row)}_{_outfit(row[2])}"


def _subject_folder(row: tuple) -> str:
    return session_name(*row)


#: The sets, by the flag that picks one (none: ``default``; ``BODYMETRY_BENCH_INDEPENDENT``
#: set: ``independent``).
STUDIO_SETS: dict[str, StudioSet] = {
    "default": StudioSet(SESSIONS, _own_model_folder),
    "held_out": StudioSet(HELD_OUT_SESSIONS, _own_model_folder),
    "independent": StudioSet(INDEPENDENT_SESSIONS, _outfit_folder),
    "validation": StudioSet(VALIDATION_SESSIONS, _outfit_folder),
    "heavy": StudioSet(HEAVY_SESSIONS, _outfit_folder),
    "fresh": StudioSet(FRESH_SESSIONS, _outfit_folder),
    "looks": StudioSet(LOOK_SESSIONS, _look_folder),
    "contrast": StudioSet(CONTRAST_SESSIONS, _look_folder, stated_accuracy=True),
    "contrast_fresh": StudioSet(CONTRAST_FRESH_SESSIONS, _look_folder, stated_accuracy=True),
    "contrast_clothing": StudioSet(CONTRAST_CLOTHING_SESSIONS, _look_folder, stated_accuracy=True),
    "loose_gaps": StudioSet(LOOSE_GAP_SESSIONS, _look_outfit_folder, stated_accuracy=True),
    "tight_night": StudioSet(TIGHT_NIGHT_SESSIONS, _look_outfit_folder, stated_accuracy=True),
    "shorts": StudioSet(SHORTS_SESSIONS, _look_outfit_folder, stated_accuracy=True),
    "skirts": StudioSet(SKIRT_SESSIONS, _look_outfit_folder, stated_accuracy=True),
    **{name: StudioSet(rows, _edge_folder, edge_summary=True) for name, rows in EDGE_DRAWS.items()},
    "arms": StudioSet(ARMS_SESSIONS, _subject_folder),
    "weight": StudioSet(WEIGHT_SESSIONS, _subject_folder),
    "children": StudioSet(CHILDREN_SESSIONS, _subject_folder, edge_summary=True),
    "children_fresh": StudioSet(CHILDREN_FRESH_SESSIONS, _subject_folder, edge_summary=True),
}


def studio_set(**flags: bool) -> tuple[str, StudioSet]:
    """The set the flags pick (at most one).

    Raises
    ------
    ValueError
        For more than one flag, or one that names no set.
    """
    chosen = [name for name, on in flags.items() if on]
    unknown = [name for name in chosen if name not in STUDIO_SETS]
    if unknown:
        raise ValueError(f"pipeline: no studio set {unknown}; sets: {', '.join(STUDIO_SETS)}")
    if len(chosen) > 1:
        raise ValueError(f"pipeline: one studio set at a time, got {chosen}")
    if chosen:
        return chosen[0], STUDIO_SETS[chosen[0]]
    name = "independent" if os.environ.get("BODYMETRY_BENCH_INDEPENDENT") else "default"
    return name, STUDIO_SETS[name]


def studio_folders(root: Path, studios: Sequence[StudioSet]) -> list[Path]:
    """The sessions of ``BODYMETRY_BENCH_SESSIONS`` (rendered beforehand, colon-separated),
    else every row of ``studios`` rendered into ``root``."""
    reuse = os.environ.get("BODYMETRY_BENCH_SESSIONS")
    if reuse:
        return [Path(p) for p in reuse.split(":") if p]
    return [studio.render(root, row) for studio in studios for row in studio.rows]


def run(**flags: bool) -> dict:
    _, studio = studio_set(**flags)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        folders = studio_folders(tmp, [studio])
        cache = None if os.environ.get("BODYMETRY_BENCH_WARM") else tmp / "cache"
        skip_demo = bool(os.environ.get("BODYMETRY_BENCH_SKIP_DEMO"))
        out = [] if skip_demo else [evaluate_session(Path(DEMO_SESSION), tmp / "run_demo", cache)]
        out += [evaluate_session(f, tmp / f"run_{f.name}", cache) for f in folders]
    described = [f.name for f in folders]
    workers = _workers()
    return {
        "setup": (
            f"{'' if skip_demo else 'demo + '}{len(folders)} studio sessions "
            f"({_frames()} frames, every 25th kept; "
            f"{described}; the demo's rig), "
            f"default preset, {workers} worker{'s' if workers > 1 else ''}"
        ),
        "sessions": out,
        **({"edge_summary": edge_summary(out)} if studio.edge_summary else {}),
        **({"stated_accuracy": stated_accuracy(out)} if studio.stated_accuracy else {}),
        "arm_evidence": arm_span_by_evidence(out),
        # Loose clothing biases both stages alike: the stages are compared on the rest.
        "stage_comparison": stage_comparison(
            [s for s in out if _outfit(Path(s["session"]).name) != "loose"]
        ),
        "all_pass": all(
            c["pass_mean"] and c["pass_std"] and c["generative_better"]
            for s in out
            for c in s["checks"].values()
        )
        and all(s["silhouette_iou_mean"] >= 0.9 and s["frame_share_pass"] for s in out),
    }
