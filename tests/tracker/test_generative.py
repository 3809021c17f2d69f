"""The generative fit: model Jacobians, every energy term's Jacobian, the solver,
tracking-loss signals and the estimation of a user's hand proportions.

Observations here are made from the model's own samples (no OpenGL): the camera-facing
samples of a hand in a known pose are the observed glove points, their pixels the
observed hand mask and their depth the observed depth.
"""

from dataclasses import replace

import numpy as np
import pytest
from helpers import model_observation, model_pose

from glovedb.hand_model import JOINT_NAMES, make_skeleton
from glovedb.mesh import HandMesh, make_hand_mesh, skin, skinning_matrices
from glovedb.pattern import load_pattern, split_by_label
from glovedb.posture_prior import fit_posture_prior, load_posture_prior, with_task_postures
from glovedb.postures import named_posture
from glovedb.proportions import FACTOR_RANGE, HandProportions, proportioned_mesh
from glovedb.rotations import axis_angle_to_matrix, geodesic_angle
from tracker.generative.energy.collision import collision_residuals
from tracker.generative.energy.data import data_residuals, partners
from tracker.generative.energy.fingertips import fingertip_residuals
from tracker.generative.energy.limits import limit_residuals
from tracker.generative.energy.prior import prior_residuals
from tracker.generative.energy.reference import (
    posture_information,
    reference_basis,
    reference_residuals,
    unseen_fingers,
)
from tracker.generative.energy.residuals import Residuals
from tracker.generative.energy.silhouette import silhouette_residuals
from tracker.generative.energy.temporal import temporal_residuals
from tracker.generative.fit import FitSettings, fit_frame, fit_frame_steps
from tracker.generative.model import (
    _SHAPE_FREE,
    KEYPOINT_BONES,
    N_PARAMS,
    HandPose,
    PosedHand,
    hand_samples,
)
from tracker.generative.observation import look_up
from tracker.generative.proportion_derivatives import PROPORTION_STEP
from tracker.generative.solver import levenberg_marquardt_steps, run_to_end


@pytest.fixture(scope="module")
def samples():
    mesh = make_hand_mesh(make_skeleton(), spacing_m=0.003)
    return hand_samples(mesh, split_by_label(mesh, load_pattern()))


_pose = model_pose


def _observation(samples, pose):
    """What a camera sees of the model in ``pose`` (:func:`helpers.model_observation`)."""
    return model_observation(samples, pose, max_points=600)


def _numeric(function, pose, columns=range(N_PARAMS), eps=1e-6):
    """Central differences of ``function(pose) -> (M,)`` by the 26 unknowns."""
    out = []
    for k in columns:
        step = np.zeros(N_PARAMS)
        step[k] = eps
        out.append((function(pose.step(step)) - function(pose.step(-step))) / (2 * eps))
    return np.stack(out, axis=1)


def test_model_jacobians_match_central_differences(samples):
    pose = _pose("power")
    hand = PosedHand(samples, pose)
    ids = np.arange(0, len(samples), 53)
    numeric = _numeric(lambda p: PosedHand(samples, p).points_m[ids].ravel(), pose)
    np.testing.assert_allclose(hand.vertex_jacobian(ids).reshape(-1, N_PARAMS), numeric, atol=1e-6)
    numeric = _numeric(lambda p: PosedHand(samples, p).keypoints_m.ravel(), pose)
    keypoints = hand.keypoint_jacobian(np.arange(21)).reshape(-1, N_PARAMS)
    np.testing.assert_allclose(keypoints, numeric, atol=1e-6)
    on_bones = hand.bone_point_jacobian(hand.keypoints_m, KEYPOINT_BONES).reshape(-1, N_PARAMS)
    np.testing.assert_allclose(on_bones, numeric, atol=1e-6)


def test_proportion_jacobian_matches_central_differences(samples):
    pose = _pose("open")
    stretched = samples.with_proportions(HandProportions(1.05, (1.1, 1.0, 0.95, 1.0, 1.2), 1.1))
    hand = PosedHand(stretched, pose)
    ids = np.arange(0, len(samples), 97)
    base = stretched.proportions.as_vector()
    numeric = []
    for k in range(7):
        up, down = base.copy(), base.copy()
        up[k] += 1e-6
        down[k] -= 1e-6
        moved = [
            PosedHand(samples.with_proportions(HandProportions.from_vector(v)), pose).points_m[ids]
            for v in (up, down)
        ]
        numeric.append((moved[0] - moved[1]) / 2e-6)
    np.testing.assert_allclose(hand.proportion_jacobian(ids), np.stack(numeric, 2), atol=2e-3)
    # The batched forward differences are those of re-resting and skinning the samples
    # once per stepped proportion.
    model = stretched.model
    chosen = HandMesh(model.skeleton, model.rest_vertices_m[ids], model.faces, model.weights[ids])
    columns = []
    for k in range(7):
        stepped = base.copy()
        stepped[k] += PROPORTION_STEP
        moved = proportioned_mesh(chosen, HandProportions.from_vector(stepped))
        posed = skin(moved, skinning_matrices(pose.posture_rad, moved.skeleton))[0]
        columns.append(posed @ pose.rotation.T + pose.translation_m - hand.points_m[ids])
    reference = np.stack(columns, 2) / PROPORTION_STEP
    np.testing.assert_allclose(hand.proportion_jacobian(ids), reference, atol=1e-9)


def test_proportion_derivatives_do_not_depend_on_which_samples_are_asked_first(samples):
    # Computed per sample when first asked for: the same values as all at once, in
    # any order, with repeated ids, and given to a hand posed elsewhere.
    pose = _pose("open")
    stretched = samples.with_proportions(HandProportions(1.05, (1.1, 1.0, 0.95, 1.0, 1.2), 1.1))
    everything = PosedHand(stretched, pose).proportion_jacobian(np.arange(len(samples)))
    hand = PosedHand(stretched, pose)
    rng = np.random.default_rng(0)
    for _ in range(3):
        ids = rng.integers(0, len(samples), 200)
        np.testing.assert_array_equal(hand.proportion_jacobian(ids), everything[ids])
    moved = PosedHand(stretched, _pose("fist"), proportion_derivatives=hand.proportion_derivatives)
    ids = np.arange(0, len(samples), 7)
    np.testing.assert_array_equal(moved.proportion_jacobian(ids), everything[ids])
    assert not np.array_equal(
        PosedHand(stretched, _pose("fist")).proportion_jacobian(ids), everything[ids]
    )


def test_proportion_jacobian_at_the_top_of_the_factor_range(samples):
    # A fit may clip a factor to the top of its range; stepping it up would leave the
    # range (a ValueError once): the derivative then steps down.
    pose = _pose("open")
    top = FACTOR_RANGE[1]
    largest = samples.with_proportions(HandProportions(top, (1.0, 1.0, 1.0, 1.0, top), 1.0))
    ids = np.arange(0, len(samples), 97)
    base = largest.proportions.as_vector()
    numeric = []
    for k in range(7):
        down = base.copy()
        down[k] -= 1e-6
        moved = PosedHand(samples.with_proportions(HandProportions.from_vector(down)), pose)
        numeric.append((PosedHand(largest, pose).points_m[ids] - moved.points_m[ids]) / 1e-6)
    got = PosedHand(largest, pose).proportion_jacobian(ids)
    np.testing.assert_allclose(got, np.stack(numeric, 2), atol=2e-3)


def _check_term(make, pose, *, atol=1e-6, rtol=1e-4):
    """The term's Jacobian against central differences of its residuals."""
    residuals = make(pose)
    assert len(residuals) > 0, "the case must exercise the term"
    numeric = _numeric(lambda p: make(p).values, pose)
    np.testing.assert_allclose(residuals.jacobian, numeric, atol=atol, rtol=rtol)


def test_data_term_jacobian(samples):
    truth = _pose("pinch")
    observation = _observation(samples, truth)
    start = truth.step(np.r_[0.01, -0.01, 0.0, 0.002, 0.0, 0.001, np.zeros(20)])

    def make(pose):
        return data_residuals(
            PosedHand(samples, pose), observation.points_m, observation.labels,
            weight=1000.0, huber_m=1.0, gate_m=0.03,
        )[0]  # fmt: skip

    # The Jacobian leaves out the normals' turn (a few per cent) and the differences
    # see the rare pair whose partner changes within the step: nearly all agree.
    residuals = make(start)
    numeric = _numeric(lambda p: make(p).values, start)
    close = np.isclose(residuals.jacobian, numeric, atol=0.05, rtol=0.05)
    assert close.mean() > 0.995


def test_silhouette_term_pulls_in_the_model_and_ignores_what_is_hidden(samples):
    truth = _pose("open")
    observation = _observation(samples, truth)
    shifted = truth.step(np.r_[0, 0, 0, 0.03, 0, 0, np.zeros(20)])  # 3 cm to the right
    settings = dict(weight=300.0, margin_px=2.0, depth_margin_m=0.012, max_samples=400)
    at_truth, outside_truth = silhouette_residuals(
        PosedHand(samples, truth), observation, **settings
    )
    moved, outside = silhouette_residuals(PosedHand(samples, shifted), observation, **settings)
    assert outside_truth < 0.02 and at_truth.energy < 1e-3
    assert outside > 0.1
    # The pull points back: one Gauss-Newton step on x reduces the energy.
    step = -np.linalg.lstsq(moved.jacobian[:, 3:4], moved.values, rcond=None)[0]
    assert step[0] < -0.005
    # The same model behind a nearer object (depth 0.2 m everywhere) costs nothing.
    hidden = replace(observation, depth_m=np.full_like(observation.depth_m, 0.2))
    assert silhouette_residuals(PosedHand(samples, shifted), hidden, **settings)[0].energy == 0
    # A wall 0.4 m behind the hand, seen wherever the hand is not. The hand 1.5 mm
    # (about 1.3 px) aside has samples just off the mask, within the margin: they cost
    # nothing, as without the wall, and are not pushed back to the wall's depth.
    wall_depth = observation.depth_m.copy()
    wall_depth[observation.outside_px > 0] = truth.translation_m[2] + 0.4
    wall = replace(observation, depth_m=wall_depth)
    aside = PosedHand(samples, truth.step(np.r_[0, 0, 0, 0.0015, 0, 0, np.zeros(20)]))
    no_wall, _ = silhouette_residuals(aside, observation, **settings)
    with_wall, _ = silhouette_residuals(aside, wall, **settings)
    assert with_wall.energy == pytest.approx(no_wall.energy) and with_wall.energy < 1e-3


def test_prior_limits_temporal_and_fingertip_jacobians(samples):
    pose = _pose("power")
    prior = load_posture_prior()
    _check_term(lambda p: prior_residuals(PosedHand(samples, p), prior, weight=0.3), pose)
    near = HandPose(pose.posture_rad + np.radians(2.0) * np.cos(np.arange(20)), pose.rotation,
                    pose.translation_m)  # fmt: skip
    task = with_task_postures(prior, [pose.posture_rad], spread=0.5, offset=0.5)
    assert prior_residuals(PosedHand(samples, near), task, weight=0.3).values[-1] > 0
    _check_term(lambda p: prior_residuals(PosedHand(samples, p), task, weight=0.3), near)
    beyond = HandPose(
        pose.posture_rad + np.radians(120.0) * (np.arange(20) % 3 == 1),
        pose.rotation,
        pose.translation_m,
    )
    _check_term(lambda p: limit_residuals(PosedHand(samples, p), weight=30.0), beyond)
    previous = PosedHand(samples, _pose("open")).keypoints_m
    _check_term(
        lambda p: temporal_residuals(PosedHand(samples, p), previous, weight=100.0, scale_m=1e9),
        pose,
    )
    targets = PosedHand(samples, pose).keypoints_m[[4, 8, 12, 16, 20]] + 0.03
    targets[2] = np.nan
    _check_term(
        lambda p: fingertip_residuals(PosedHand(samples, p), targets, weight=300.0, deadband_m=0.0),
        pose,
    )


def test_reference_jacobian_and_weights_follow_what_the_data_observes(samples):
    pose = _pose("power")
    # Joint 0 is seen directly; joint 1 only together with a global translation, which
    # explains it as well (the Schur complement removes it); the rest is unseen.
    jacobian = np.zeros((3, N_PARAMS))
    jacobian[0, 6 + 0] = 10.0
    jacobian[1, 6 + 1] = 10.0
    jacobian[1, 3] = 10.0
    jacobian[2, 3] = 1e-3
    information = posture_information([Residuals("data", np.zeros(3), jacobian)])
    assert information[0, 0] == pytest.approx(100.0)
    assert abs(information[1, 1]) < 1e-3
    hidden = np.zeros(20, dtype=bool)
    hidden[7] = True
    basis = reference_basis(
        pose.posture_rad, information, weight=2.0, observed_information=0.25,
        hidden=hidden, hidden_weight=20.0,
    )  # fmt: skip
    # Effective weight per joint: the norm of its column in the weighted directions.
    held = np.linalg.norm(
        basis.weights[basis.robust, None] * basis.directions[basis.robust], axis=0
    )
    assert held[0] == pytest.approx(2.0 / np.sqrt(1 + 100.0 / 0.25), rel=1e-6)
    np.testing.assert_allclose(held[1:], 2.0, rtol=1e-3)
    assert basis.weights[~basis.robust] == pytest.approx([20.0])
    np.testing.assert_array_equal(basis.directions[~basis.robust][0], np.eye(20)[7])
    away = HandPose(
        pose.posture_rad + 0.02 * np.cos(np.arange(20)), pose.rotation, pose.translation_m
    )
    _check_term(lambda p: reference_residuals(PosedHand(samples, p), basis, scale_rad=1e9), away)


def test_the_reference_leaves_observed_fingers_free(samples):
    """Index flexion is plain to see on an open hand: the reference hardly holds it,
    and a start 12 degrees off is pulled back to the truth."""
    truth = _pose("open")
    observation = _observation(samples, truth)
    settings = FitSettings(iterations=15)
    start_posture = truth.posture_rad.copy()
    index_mcp = JOINT_NAMES.index("index_mcp_flex")
    start_posture[index_mcp] += np.radians(12.0)
    start = HandPose(start_posture, truth.rotation, truth.translation_m)
    terms = [
        data_residuals(
            PosedHand(samples, start), observation.points_m, observation.labels,
            weight=settings.data_weight, huber_m=settings.data_huber_m, gate_m=settings.data_gate_m,
        )[0],
        silhouette_residuals(
            PosedHand(samples, start), observation, weight=settings.silhouette_weight,
            margin_px=settings.silhouette_margin_px, depth_margin_m=settings.depth_margin_m,
            max_samples=settings.silhouette_samples,
        )[0],
    ]  # fmt: skip
    basis = reference_basis(
        start_posture, posture_information(terms), weight=settings.reference_weight,
        observed_information=settings.observed_information,
    )  # fmt: skip
    held = np.linalg.norm(basis.weights[:, None] * basis.directions, axis=0)
    assert held[index_mcp] < 0.25 * settings.reference_weight
    fit = fit_frame(samples, observation, start, settings=settings, prior=load_posture_prior())
    error = np.degrees(abs(fit.pose.posture_rad[index_mcp] - truth.posture_rad[index_mcp]))
    assert error < 2.0


def test_a_finger_the_data_does_not_see_is_held(samples):
    """Without the observed points on the thumb, and with the observed depth 3 cm
    in front of it (the camera sees the palm there), the thumb's four joints are
    unseen and the others are not; a fit then keeps the thumb where it started instead
    of letting it wander. Missing points alone, with nothing in front, do not make a
    finger unseen."""
    truth = _pose("open")
    observation = _observation(samples, truth)
    hand = PosedHand(samples, truth)
    share = FitSettings().unseen_finger_share
    pairing = {"gate_m": 0.03, "depth_scale": 0.5, "depth_margin_m": 0.012}
    assert not unseen_fingers(hand, observation, share=share, **pairing).any()
    thumb = np.isin(samples.mesh.dominant_bone, [1, 2, 3])
    gap = np.linalg.norm(
        observation.points_m[:, None, :] - hand.points_m[None, thumb, :], axis=2
    ).min(axis=1)
    kept = gap > 0.005
    without_points = replace(
        observation, points_m=observation.points_m[kept], labels=observation.labels[kept]
    )
    assert not unseen_fingers(hand, without_points, share=share, **pairing).any()
    thumb_facing = np.flatnonzero(thumb & hand.facing)
    pixels = look_up(observation, hand.points_m[thumb_facing])
    depth = observation.depth_m.copy()  # the box around the thumb, 15 px wider
    rows = slice(max(pixels.row.min() - 15, 0), pixels.row.max() + 16)
    cols = slice(max(pixels.col.min() - 15, 0), pixels.col.max() + 16)
    depth[rows, cols] = hand.points_m[thumb_facing, 2].min() - 0.03
    without_thumb = replace(without_points, depth_m=depth)
    unseen = unseen_fingers(hand, without_thumb, share=share, **pairing)
    assert unseen.tolist() == [True] * 4 + [False] * 16
    # The fit pairs the start's points once for this test and its data term: the same
    # answers either way.
    points, labels = without_thumb.points_m, without_thumb.labels
    found = partners(hand, points, labels, gate_m=0.03, depth_scale=0.5)
    given = unseen_fingers(hand, without_thumb, share=share, nearest=found, **pairing)
    assert given.tolist() == unseen.tolist()
    term = {"weight": 1000.0, "huber_m": 0.01, "gate_m": 0.03, "depth_scale": 0.5}
    paired_here, matched_here = data_residuals(hand, points, labels, **term)
    paired_before, matched_before = data_residuals(hand, points, labels, nearest=found, **term)
    np.testing.assert_array_equal(paired_here.values, paired_before.values)
    np.testing.assert_array_equal(paired_here.jacobian, paired_before.jacobian)
    assert matched_here == matched_before > 0.5
    start_posture = truth.posture_rad.copy()
    start_posture[JOINT_NAMES.index("thumb_cmc_abd")] += np.radians(15.0)
    start = HandPose(start_posture, truth.rotation, truth.translation_m)
    prior = load_posture_prior()
    moved = {}
    for label, settings in (("held", FitSettings()), ("free", FitSettings(unseen_finger_share=0))):
        fit = fit_frame(
            samples, without_thumb, start, settings=settings, prior=prior, hold_unseen=True
        )
        assert fit.hidden is not None and fit.hidden[:4].all() == (label == "held")
        moved[label] = np.degrees(np.abs(fit.pose.posture_rad[:4] - start_posture[:4]).max())
    assert moved["held"] < 1.0 < moved["free"]


def test_task_postures_hold_what_the_camera_does_not_see(samples):
    # A power grasp seen from the back: the distal joints and the thumb barely change
    # what the camera sees, and the natural prior pulls them toward its mean. With the
    # database's postures in the prior they stay at the task's grasp.
    truth = _pose("power")
    observation = _observation(samples, truth)
    prior = load_posture_prior()
    task = with_task_postures(prior, [named_posture(n) for n in ("open", "pinch", "power")],
                              spread=0.5, offset=0.5)  # fmt: skip
    errors = {}
    for name, used in (("natural", prior), ("task", task)):
        fit = fit_frame(samples, observation, truth, settings=FitSettings(iterations=10),
                        prior=used)  # fmt: skip
        errors[name] = np.degrees(np.abs(fit.pose.posture_rad - truth.posture_rad).mean())
    assert errors["task"] < 0.5 * errors["natural"]


def test_fingertips_without_targets_add_nothing(samples):
    hand = PosedHand(samples, _pose("power"))
    residuals = fingertip_residuals(hand, np.full((5, 3), np.nan), weight=300.0, deadband_m=0.01)
    assert len(residuals) == 0 and residuals.jacobian.shape == (0, N_PARAMS)


def test_collision_term_pushes_crossed_fingers_apart(samples):
    crossed = named_posture("open")
    crossed[JOINT_NAMES.index("index_mcp_abd")] = np.radians(-20)
    crossed[JOINT_NAMES.index("middle_mcp_abd")] = np.radians(20)
    pose = HandPose(crossed, _pose().rotation, _pose().translation_m)
    residuals = collision_residuals(PosedHand(samples, pose), weight=300.0)
    assert len(residuals) > 0
    assert len(collision_residuals(PosedHand(samples, _pose("open")), weight=300.0)) == 0
    # The Jacobian leaves out how the cones' radii change as the closest points slide.
    _check_term(
        lambda p: collision_residuals(PosedHand(samples, p), weight=300.0),
        pose,
        atol=0.2,
        rtol=0.05,
    )
    # A damped Gauss-Newton step separates the fingers.
    step = -0.5 * np.linalg.lstsq(residuals.jacobian, residuals.values, rcond=None)[0]
    after = collision_residuals(PosedHand(samples, pose.step(step)), weight=300.0)
    assert after.energy < 0.9 * residuals.energy


def test_prior_is_the_gaussian_of_its_examples():
    rng = np.random.default_rng(0)
    examples = rng.normal(0.3, 0.2, size=(5000, 20))
    prior = fit_posture_prior(examples, floor_deg=1e-3)
    np.testing.assert_allclose(prior.mean_rad, 0.3, atol=0.02)
    whitened = (examples - prior.mean_rad) @ prior.whitening.T
    np.testing.assert_allclose(np.cov(whitened, rowvar=False), np.eye(20), atol=1e-6)
    with pytest.raises(ValueError, match="floor_deg"):
        fit_posture_prior(examples, floor_deg=0)


def _rosenbrock(x):
    """Rosenbrock as residuals (1 - x, 10 (y - x^2)), minimum at (1, 1), and their
    Jacobian."""
    residual = np.array([1 - x[0], 10 * (x[1] - x[0] ** 2)])
    return residual, np.array([[-1.0, 0.0], [-20 * x[0], 10.0]])


def test_samples_with_proportions_carry_what_the_proportions_do_not_change(samples):
    computed = {name: getattr(samples, name) for name in _SHAPE_FREE}
    stretched = samples.with_proportions(HandProportions(1.05, (1.1, 1.0, 0.95, 1.0, 1.2), 1.1))
    fresh = replace(stretched)  # the same samples, nothing cached
    for name, value in computed.items():
        assert stretched.__dict__[name] is value  # carried, not computed again
        for carried, recomputed in zip(
            np.atleast_1d(value), np.atleast_1d(getattr(fresh, name)), strict=True
        ):
            np.testing.assert_array_equal(carried, recomputed)
    assert not np.array_equal(stretched._rest_inverse, samples._rest_inverse)
    # Samples that never computed them compute them once, for themselves and the new
    # samples (the tracker re-rests its model's samples at every calibrating frame).
    model = replace(samples)
    first = model.with_proportions(HandProportions(1.1))
    second = model.with_proportions(HandProportions(0.9))
    for name in _SHAPE_FREE:
        assert first.__dict__[name] is model.__dict__[name] is second.__dict__[name]


def test_solver_minimises_a_known_least_squares_problem():
    def evaluate(x):
        residual, jacobian = _rosenbrock(x)
        return residual, lambda: jacobian

    result = run_to_end(
        levenberg_marquardt_steps(
            evaluate, lambda x, d: x + d, np.array([-1.2, 1.0]), iterations=100
        )
    )
    np.testing.assert_allclose(result.state, [1.0, 1.0], atol=1e-4)
    assert result.energy < 1e-8 < result.start_energy


@pytest.mark.parametrize("iterations", [1, 2, 5, 100])
def test_solver_asks_for_the_jacobian_only_where_it_linearises(iterations):
    evaluated, linearised = [], []

    def evaluate(x):
        residual, jacobian = _rosenbrock(x)
        evaluated.append((x, float(residual @ residual)))

        def jacobian_at_x():
            linearised.append(x)
            return jacobian

        return residual, jacobian_at_x

    result = run_to_end(
        levenberg_marquardt_steps(
            evaluate, lambda x, d: x + d, np.array([-1.2, 1.0]), iterations=iterations
        )
    )
    # The kept states: the start and every evaluation that lowered the energy.
    kept, lowest = [], np.inf
    for x, energy in evaluated:
        if energy < lowest:
            kept.append(x)
            lowest = energy
    assert result.state is kept[-1]
    # Each kept state is linearised once, in order, but the last where the solver
    # stopped right after keeping it (its evaluation was the last); refused ones never.
    ended_on_a_kept_step = evaluated[-1][0] is kept[-1]
    assert len(linearised) == len(kept) - ended_on_a_kept_step
    assert all(a is b for a, b in zip(linearised, kept, strict=False))
    if iterations == 100:
        assert len(evaluated) > len(kept)  # the solver refused steps on the way


def test_fit_recovers_a_perturbed_pose_and_posture(samples):
    truth = _pose("pinch")
    observation = _observation(samples, truth)
    wrong = HandPose(
        truth.posture_rad + np.radians(8.0) * np.sin(np.arange(20)),
        axis_angle_to_matrix(np.array([0.0, 1.0, 0.0]), np.radians(8.0)) @ truth.rotation,
        truth.translation_m + [0.01, -0.008, 0.01],
    )
    fit = fit_frame(
        samples, observation, wrong, settings=FitSettings(iterations=25), prior=load_posture_prior()
    )
    assert geodesic_angle(fit.pose.rotation, truth.rotation) < np.radians(1.5)
    assert np.linalg.norm(fit.pose.translation_m - truth.translation_m) < 0.002
    keypoints = PosedHand(samples, fit.pose).keypoints_m - PosedHand(samples, truth).keypoints_m
    assert np.sqrt(np.mean(np.sum(keypoints**2, axis=1))) < 0.004
    assert fit.matched > 0.95 and fit.outside < 0.05 and fit.energy < fit.start_energy


def test_a_stepped_fit_yields_between_iterations_and_ends_where_the_fit_ends(samples):
    truth = _pose("pinch")
    observation = _observation(samples, truth)
    start = HandPose(truth.posture_rad + 0.1, truth.rotation, truth.translation_m + 0.005)
    settings = FitSettings(iterations=4, tolerance=0.0)
    prior = load_posture_prior()
    whole = fit_frame(samples, observation, start, settings=settings, prior=prior)
    steps = fit_frame_steps(samples, observation, start, settings=settings, prior=prior)
    pauses = 0
    while True:
        try:
            next(steps)
        except StopIteration as finished:
            stepped = finished.value
            break
        pauses += 1
    assert pauses == whole.iterations - 1 == 3
    np.testing.assert_array_equal(stepped.pose.posture_rad, whole.pose.posture_rad)
    np.testing.assert_array_equal(stepped.pose.translation_m, whole.pose.translation_m)
    assert stepped.energy == whole.energy < whole.start_energy


def test_a_fit_far_from_the_data_explains_little(samples):
    """The signals the tracker's loss detection reads: a hand fitted to the wrong
    place pairs few points and shows much surface where the camera sees none."""
    truth = _pose("open")
    observation = _observation(samples, truth)
    far = HandPose(named_posture("fist"), truth.rotation, truth.translation_m + [0.12, 0.0, 0.0])
    fit = fit_frame(
        samples, observation, far, settings=FitSettings(iterations=2), prior=load_posture_prior()
    )
    assert fit.matched < 0.5 or fit.outside > 0.3


def test_proportions_are_recovered_from_frames_of_a_larger_hand(samples):
    truth = HandProportions(1.1, (1.0, 1.12, 1.12, 1.12, 1.12), 1.0)
    person = samples.with_proportions(truth)
    estimate = samples
    prior = load_posture_prior()
    settings = FitSettings(iterations=8, temporal_weight=0.0, tolerance=1e-6)
    poses = [_pose(name, angle=a) for name in ("open", "pinch", "open") for a in (0.2, 0.6, -0.4)]
    information = None
    for pose in poses:
        fit = fit_frame(
            estimate, _observation(person, pose), pose, settings=settings, prior=prior,
            estimate_proportions=True, proportion_information=information,
        )  # fmt: skip
        assert fit.proportion_information is not None
        if information is not None:  # information only adds up
            assert np.all(np.linalg.eigvalsh(fit.proportion_information - information) > -1e-6)
        information = fit.proportion_information
        estimate = estimate.with_proportions(fit.proportions)
    found = estimate.proportions.as_vector()
    assert abs(found[0] - 1.1) < 0.03
    assert np.all(np.abs(found[2:5] * found[0] - 1.12 * 1.1) < 0.06)


def test_noise_along_the_rays_does_not_shrink_the_estimated_hand(samples):
    """Depth noise lies along the camera's rays; pairing by plain 3D distance lets
    points measured too deep pair with the surface receding beside them, which pulls
    the hand smaller (data.py's docstring). The default pairing counts depth half."""
    rng = np.random.default_rng(0)
    poses = [_pose(name, angle=a) for name in ("open", "pinch", "open") for a in (0.2, 0.6, -0.4)]
    observations = []
    for pose in poses:
        observation = _observation(samples, pose)
        points = observation.points_m
        along = 1.0 + rng.normal(0.0, 0.003, len(points)) / np.linalg.norm(points, axis=1)
        observations.append(replace(observation, points_m=points * along[:, None]))
    scale, default = {}, FitSettings().data_depth_scale
    for depth_scale in (1.0, default):
        settings = FitSettings(
            iterations=8, temporal_weight=0.0, tolerance=1e-6, data_depth_scale=depth_scale
        )
        estimate, information = samples, None
        for pose, observation in zip(poses, observations, strict=True):
            fit = fit_frame(
                estimate, observation, pose, settings=settings, prior=load_posture_prior(),
                estimate_proportions=True, proportion_information=information,
            )  # fmt: skip
            information = fit.proportion_information
            estimate = estimate.with_proportions(fit.proportions)
        scale[depth_scale] = estimate.proportions.as_vector()[0]
    assert abs(scale[default] - 1.0) < 0.008
    assert abs(scale[1.0] - 1.0) > 1.5 * abs(scale[default] - 1.0)


def test_directional_rows_are_the_projected_vertex_jacobian(samples):
    hand = PosedHand(samples, _pose("power"))
    ids = np.arange(0, len(samples), 11)
    directions = np.random.default_rng(3).normal(size=(len(ids), 3))
    expected = np.einsum("pi,pik->pk", directions, hand.vertex_jacobian(ids))
    np.testing.assert_allclose(hand.directional_rows(ids, directions), expected, atol=1e-12)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: FitSettings(data_weight=-1.0), "data_weight"),
        (lambda: FitSettings(iterations=0), "iterations"),
        (lambda: FitSettings(max_points=10), "max_points"),
        (lambda: FitSettings(observed_information=0.0), "observed_information"),
    ],
)
def test_fit_settings_refuse_bad_values(make, message):
    with pytest.raises(ValueError, match=message):
        make()


@pytest.mark.parametrize(
    ("field", "value"),
    [("reinit_every", 0), ("min_matched", 1.5), ("min_fit_confidence", -0.1),
     ("calibration_frames", -1), ("frame_rate_hz", 0.0)],
)  # fmt: skip
def test_tracker_settings_refuse_bad_values(field, value):
    from tracker.pipeline import TrackerSettings

    with pytest.raises(ValueError, match=field):
        TrackerSettings(**{field: value})
