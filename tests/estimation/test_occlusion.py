"""Pixels hidden behind someone nearer are unknown, not background (issue 29 item 2):
the chamfer likelihood, the contour refinement, the IoU and the frame's arrays."""

from __future__ import annotations

import importlib.util

import cv2
import numpy as np
import pytest

from bodymetry.estimation import generative
from bodymetry.estimation.body_model.model import BodyModel, BodyState
from bodymetry.estimation.contours import UNKNOWN_MARGIN_PX, prepare_contours
from bodymetry.estimation.fit import FitConfig, fit_frame
from bodymetry.estimation.generative import chamfer_costs, prepare_observation
from bodymetry.estimation.projection import project_silhouettes, view_ious
from bodymetry.estimation.records import FrameArrays
from bodymetry.estimation.refinement import ContourCost, RefineConfig
from bodymetry.fileio import save_npz
from bodymetry.studio.rig import studio_rig

LIKELIHOOD_BACKENDS = ["numpy"] + (["numba"] if importlib.util.find_spec("numba") else [])


@pytest.fixture(scope="module")
def scene():
    """A body seen by 3 cameras; in view 0 a box (someone nearer) covers its legs.

    Returns (model, cameras, truth, masks, occluded, box): ``masks`` the whole
    silhouettes, ``occluded`` the same with the box's pixels taken out of view 0,
    ``box`` (per view, None but in view 0) the occluder's pixels over the body.
    """
    model = BodyModel.load()
    cameras = studio_rig(3, (240, 180), seed=4)
    truth = BodyState([0.1, -0.2, 0.93], model.poses["apose"], np.zeros(model.n_shape))
    masks = project_silhouettes(
        model.pose(truth, lod=True).vertices[0], model.faces(lod=True), cameras
    )
    rows = np.flatnonzero(masks[0].any(axis=1))
    cols = np.flatnonzero(masks[0].any(axis=0))
    box = np.zeros_like(masks[0])
    # The lower half of the body, a few pixels wider than it (the occluder's own
    # pixels around the body are theirs, not unknown, beyond this box).
    box[(rows[0] + rows[-1]) // 2 :, max(cols[0] - 6, 0) : cols[-1] + 7] = True
    occluded = [m.copy() for m in masks]
    occluded[0] &= ~box
    return model, cameras, truth, list(masks), occluded, [box, None, None]


@pytest.mark.parametrize("backend", LIKELIHOOD_BACKENDS)
def test_hidden_pixels_as_unknown_cost_what_an_unoccluded_view_costs(scene, backend, monkeypatch):
    monkeypatch.setattr(generative, "BACKEND", backend)
    model, cameras, truth, masks, occluded, box = scene
    faces = model.faces(lod=True)
    verts = model.pose(truth, lod=True).vertices[0]
    whole = chamfer_costs(prepare_observation(cameras, masks, 0.5), verts, faces).sum()
    unknown = chamfer_costs(prepare_observation(cameras, occluded, 0.5, box), verts, faces).sum()
    background = chamfer_costs(prepare_observation(cameras, occluded, 0.5), verts, faces).sum()
    # The true body costs (nearly) nothing either way when the hidden legs are
    # unknown; marked background they cost their distance to the visible part.
    # The true body costs what it costs against its whole silhouette (the
    # downscaled masks' resampling, 0.39 px summed over the views) when the hidden
    # legs are unknown; marked background they cost their distance to the visible
    # part (15.6 px).
    assert unknown == pytest.approx(whole, abs=0.1)
    assert background > 10 * whole
    # The likelihood still finds the body: a shifted one costs more.
    shifted = chamfer_costs(
        prepare_observation(cameras, occluded, 0.5, box), verts + [0.05, 0, 0], faces
    ).sum()
    assert shifted > unknown + 0.5


def test_unknown_is_free_only_where_marked(scene):
    """The occluder's pixels beyond the unknown box are background: a body moved
    sideways out of the box into them costs as without any unknown pixels there."""
    model, cameras, truth, _masks, occluded, box = scene
    faces = model.faces(lod=True)
    verts = model.pose(truth, lod=True).vertices[0] + [0.0, 0.3, 0.0]
    obs_u = prepare_observation(cameras, occluded, 0.5, box)
    obs_b = prepare_observation(cameras, occluded, 0.5)
    # Views 1 and 2 have no unknown pixels: their costs are the same to the bit.
    np.testing.assert_array_equal(
        chamfer_costs(obs_u, verts, faces)[1:], chamfer_costs(obs_b, verts, faces)[1:]
    )


def test_no_unknown_pixels_leave_the_observation_unchanged(scene):
    _, cameras, _, masks, _, _ = scene
    plain = prepare_observation(cameras, masks, 0.5)
    for none in (None, [], [None] * 3, [np.zeros_like(m) for m in masks]):
        obs = prepare_observation(cameras, masks, 0.5, none)
        for a, b in zip(obs.dist_outside, plain.dist_outside, strict=True):
            np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="cam"):
        prepare_observation(cameras, masks, 0.5, [np.zeros((3, 3), bool), None, None])


def test_contour_points_at_the_unknown_border_are_dropped(scene):
    _model, cameras, _truth, _masks, occluded, box = scene
    plain = prepare_contours(cameras, occluded, 0.5, max_points=10_000)
    marked = prepare_contours(cameras, occluded, 0.5, max_points=10_000, unknown=box)
    # Full-resolution points back from the working scale (x' = (x + 0.5) s - 0.5).
    full = (marked.points[0] + 0.5) / 0.5 - 0.5
    near = cv2.dilate(box[0].astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    ij = np.round(full).astype(int)
    assert not near[ij[:, 1], ij[:, 0]].any()
    # The legs' cut edge was the only outline there: what is left is the rest.
    dropped = len(plain.points[0]) - len(marked.points[0])
    assert dropped > 0 and len(marked.points[0]) > 0.5 * len(plain.points[0])
    for c in (1, 2):
        np.testing.assert_array_equal(marked.points[c], plain.points[c])
    assert UNKNOWN_MARGIN_PX >= 1
    # Working pixels on the box are unknown, others not.
    assert marked.unknown[0] is not None and marked.unknown[1] is None
    inside = np.argwhere(marked.unknown[0])[:1, ::-1].astype(float)
    assert marked.in_unknown(0, inside).all() and not marked.in_unknown(1, inside).any()


def test_the_contour_cost_ignores_the_outline_behind_the_occluder(scene):
    model, cameras, truth, masks, occluded, box = scene
    config = RefineConfig(image_scale=0.5, full_mesh=False, outline_offsets=False)
    y = truth.vector()[0]

    def cost(observed, unknown=None) -> float:
        obs = prepare_contours(cameras, observed, 0.5, config.max_points, unknown)
        return ContourCost(model, obs, config).evaluate(y)[0]

    whole, unknown, background = cost(masks), cost(occluded, box), cost(occluded)
    # Marked background the legs' outline pairs with the cut edge, far from it.
    assert background > 5 * whole
    assert unknown < 2 * whole + 0.05


def test_iou_leaves_unknown_pixels_out(scene):
    model, cameras, truth, _masks, occluded, box = scene
    model_masks = project_silhouettes(
        model.pose(truth, lod=True).vertices[0], model.faces(lod=True), cameras
    )
    used = [True] * 3
    plain = view_ious(cameras, model_masks, occluded, used)
    marked = view_ious(cameras, model_masks, occluded, used, box)
    assert plain[cameras.names[0]] < 0.8  # the hidden legs count against the fit
    assert marked[cameras.names[0]] == pytest.approx(1.0)
    assert marked[cameras.names[1]] == plain[cameras.names[1]]
    assert view_ious(cameras, model_masks, occluded, used, None) == plain


def test_frame_arrays_keep_unknown_masks_and_old_files_still_load(tmp_path, scene):
    _, cameras, _, masks, _, box = scene
    names = cameras.names
    arrays = FrameArrays(observed=dict(zip(names, masks, strict=True)), unknown={names[0]: box[0]})
    path = tmp_path / "000000.npz"
    save_npz(path, arrays.to_arrays())
    back = FrameArrays.load(path)
    assert list(back.unknown) == [names[0]]
    np.testing.assert_array_equal(back.unknown[names[0]], box[0])
    assert back.unknown_of(names)[1:] == [None, None]
    # A file written before unknown masks existed: none.
    old = {k: v for k, v in arrays.to_arrays().items() if not k.startswith("unknown/")}
    save_npz(path, old)
    assert FrameArrays.load(path).unknown == {}
    assert FrameArrays.load(path).unknown_of(names) == [None, None, None]


def test_frame_arrays_keep_clothing_masks_and_old_files_still_load(tmp_path, scene):
    _, cameras, _, masks, _, box = scene
    names = cameras.names
    worn = masks[1] & ~box[0]
    arrays = FrameArrays(observed=dict(zip(names, masks, strict=True)), clothing={names[1]: worn})
    path = tmp_path / "000000.npz"
    save_npz(path, arrays.to_arrays())
    back = FrameArrays.load(path)
    assert list(back.clothing) == [names[1]] and back.unknown == {}
    np.testing.assert_array_equal(back.clothing[names[1]], worn)
    assert back.clothing_of(names) == [None, back.clothing[names[1]], None]
    # A file written before clothing masks existed: none.
    old = {k: v for k, v in arrays.to_arrays().items() if not k.startswith("clothing/")}
    save_npz(path, old)
    assert FrameArrays.load(path).clothing == {}


def test_a_frames_arrays_keep_capture_s_clothing_where_the_silhouette_is(scene):
    # Every view unreadable: the frame fails before any fit, with what capture saw.
    _, cameras, _, masks, _, box = scene
    names = cameras.names
    everywhere = np.ones_like(masks[0])
    fit = fit_frame(
        0, masks, [["unreadable"]] * 3, cameras, None, FitConfig(),
        clothing=[everywhere, None, box[0]],
    )  # fmt: skip
    assert not fit.record.fitted
    assert list(fit.arrays.clothing) == [names[0], names[2]]
    np.testing.assert_array_equal(fit.arrays.clothing[names[0]], masks[0])
    np.testing.assert_array_equal(fit.arrays.clothing[names[2]], box[0] & masks[2])
