"""One frame's generative fit: the energy of thesis ch. 6, summed and minimised.

``E = E_data + E_silhouette + E_prior + E_reference + E_limits + E_collision +
E_temporal + E_fingertips`` (one module each in :mod:`tracker.generative.energy`),
minimised over the 26 unknowns of :mod:`tracker.generative.model` by
:func:`tracker.generative.solver.levenberg_marquardt_steps`; while a user's hand
proportions are being estimated, over the 7 proportions as well.

The proportions are estimated over many frames by accumulating information, as a
recursive least-squares (Kalman) filter would: each frame's fit pulls them toward the
estimate so far with the residual ``L^T (p - p_est)``, where ``L L^T`` is the
information gathered from the earlier frames (starting at ``proportion_weight**2``
per factor); after the fit, the frame's information is the Schur complement of the
fit's normal matrix onto the proportions (the pose unknowns eliminated), which
includes the pull, so it adds up frame after frame. Directions the frames do not
observe keep little information and stay near the start. A finger's length is
estimated only in frames where that finger is extended (flexion of its three joints
adding up to less than ``extended_finger_deg`` at the start): a curled finger's
length and its flexion explain the same points, and fitting both drifts the length.
"""

from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass, field
from functools import cache

import numpy as np
from numpy.typing import NDArray

from glovedb.posture_prior import PosturePrior
from glovedb.proportions import FACTOR_RANGE, N_PROPORTIONS, HandProportions
from tracker.generative.energy.collision import collision_residuals
from tracker.generative.energy.data import NAME as DATA
from tracker.generative.energy.data import data_residuals, partners
from tracker.generative.energy.fingertips import fingertip_residuals
from tracker.generative.energy.limits import limit_residuals
from tracker.generative.energy.prior import prior_residuals
from tracker.generative.energy.reference import NAME as REFERENCE
from tracker.generative.energy.reference import (
    ReferenceBasis,
    hidden_joints,
    posture_information,
    reference_basis,
    reference_residuals,
    unseen_fingers,
)
from tracker.generative.energy.residuals import Residuals
from tracker.generative.energy.silhouette import NAME as SILHOUETTE
from tracker.generative.energy.silhouette import silhouette_residuals
from tracker.generative.energy.temporal import temporal_residuals
from tracker.generative.model import N_PARAMS, HandPose, HandSamples, PosedHand
from tracker.generative.observation import Observation
from tracker.generative.proportion_derivatives import ProportionDerivatives
from tracker.generative.solver import (
    Evaluation,
    Jacobian,
    eliminated_information,
    in_one_call,
    levenberg_marquardt_steps,
)

HIDDEN_EDGE_PX = 4.0
"""Pixels beyond the silhouette margin before a sample counts as hidden by an object."""

FLEXION_JOINTS = np.array([1, 2, 3] + [4 * f + k for f in range(1, 5) for k in (1, 2, 3)])
"""The three flexion angles of each finger, thumb first (the thumb's CMC flexion moves
it across the palm, its MCP and IP curl it)."""


@dataclass(frozen=True)
class FitSettings:
    """Weights and settings of the generative fit; every field has a default.

    Residual units: metres for the geometric terms, standard deviations for the
    prior, radians for the limits. A weight ``w`` on a metre residual means that
    ``1 / w`` metres cost as much as one standard deviation of the posture prior at
    ``prior_weight = 1``.

    Attributes
    ----------
    iterations : int
        Levenberg-Marquardt solves per hypothesis. Most warm fits use them all (172
        of 240 on a Tr3 render at 6), but more do not help (12 changed nothing) and
        fewer did not hurt: chosen on Tr3 and Tr5 rendered with another noise seed,
        1.76 / 1.66 degrees at 4 against 1.88 / 1.68 at 5 and 1.90 / 1.70 at 6, and
        a warm fit takes 6.7 ms instead of 8.4.
    tolerance : float
        A kept step that lowers the energy by less than this share ends the solve.
    max_points : int
        Observed glove points used by the data term: the cloud subsampled to between
        this many and twice as many (:func:`tracker.generative.observation.observe`).
        Fewer cost accuracy: on the validation renders (Tr1-Tr5 with noise seed 7,
        Tr3-Tr5 with seed 8) 1,000 raised the mean posture error by 0.04-0.17 degrees
        and the rotation error by 0.03-0.09 on every sequence (2026-11-28).
    sample_spacing : int
        The model surface is every n-th vertex of the glove mesh, split by color
        (:func:`tracker.generative.model.hand_samples`).
    data_weight : float
        Per metre of RMS point-to-plane distance (the residuals are divided by the
        square root of the number of points).
    data_huber_m : float
        Point-to-plane distances beyond this count linearly.
    data_gate_m : float
        Observed points farther than this from every model sample of their color
        are not paired.
    data_depth_scale : float
        Observed points are paired with model samples by a distance whose component
        along the optical axis counts this much (the sensor's noise lies along its
        rays; :mod:`tracker.generative.energy.data`).
    silhouette_weight : float
        Per metre of RMS distance of model samples outside the observed hand.
    silhouette_margin_px : float
        Distance from the observed hand mask that costs nothing.
    depth_margin_m : float
        Depth tolerance of "in front of" and "hidden behind" the observed surface.
    silhouette_samples : int
        Camera-facing model samples examined by the silhouette term.
    prior_weight : float
        Per standard deviation of the posture prior.
    task_prior_spread : float
        Standard deviations of the prior's component around each posture of the
        database (the task's postures, :mod:`glovedb.posture_prior`), relative to the
        natural prior's; 0 leaves the database's postures out of the prior. Chosen
        with ``task_prior_offset`` on Tr1-Tr5 rendered with other noise seeds and on
        free finger motion tracked with DB_20postures (docs/tracker.md).
    task_prior_offset : float
        What explaining a posture by a task posture instead of the natural prior
        costs, squared standard deviations of the prior.
    task_prior_max_postures : int
        A database with more distinct postures than this covers natural postures
        rather than a task's, and leaves the prior natural: its many components would
        quantise the postures (free finger motion tracked with natural1000's postures,
        1,323 of them: 4.21 degrees with them against 3.84 without). Any value between
        the task databases measured (3 and 20 postures) and natural1000 gives the
        same results on them.
    limit_weight : float
        Per radian beyond a joint limit.
    collision_weight : float
        Per metre of overlap of two fingers.
    temporal_weight : float
        Per metre of RMS keypoint motion from the previous frame.
    temporal_scale_m : float
        Keypoint motion beyond this costs less and less (Cauchy loss).
    reference_weight : float
        Per radian of departure from the start's posture along a posture direction
        the data does not observe (:mod:`tracker.generative.energy.reference`).
    reference_scale_deg : float
        Departures beyond this cost less and less (Cauchy loss), degrees.
    observed_information : float
        Information of the data and silhouette terms about a posture direction
        (their weighted energy per radian², global motion eliminated) at which the
        reference weight along it is divided by sqrt(2); better observed directions
        are held less.
    hidden_reference_weight : float
        Per radian, for joints whose finger an object hides at the start, or that the
        data does not see (``unseen_finger_share``).
    unseen_finger_share : float
        A finger with fewer paired observed points than this share of its
        camera-facing samples at the start, most of them behind the observed depth,
        is unseen and held like a hidden one; 0 turns this off.
    fingertip_weight : float
        Per metre of a named fingertip detection beyond its dead band.
    fingertip_deadband_m : float
    proportion_weight : float
        While estimating proportions: the information about the length scale and the
        palm width before the first frame, per unit of factor change (module
        docstring).
    finger_length_weight : float
        The same for each finger's length factor.
    extended_finger_deg : float
        A finger counts as extended, and its length is estimated, when the flexion
        of its three joints adds up to less than this, degrees.
    """

    iterations: int = 4
    tolerance: float = 1e-3
    max_points: int = 1500
    sample_spacing: int = 2
    data_weight: float = 1000.0
    data_huber_m: float = 0.004
    data_gate_m: float = 0.03
    data_depth_scale: float = 0.5
    silhouette_weight: float = 300.0
    silhouette_margin_px: float = 2.0
    depth_margin_m: float = 0.012
    silhouette_samples: int = 400
    prior_weight: float = 0.3
    task_prior_spread: float = 0.5
    task_prior_offset: float = 0.5
    task_prior_max_postures: int = 100
    limit_weight: float = 30.0
    collision_weight: float = 300.0
    temporal_weight: float = 15.0
    temporal_scale_m: float = 0.02
    reference_weight: float = 2.0
    reference_scale_deg: float = 10.0
    observed_information: float = 0.01
    hidden_reference_weight: float = 20.0
    unseen_finger_share: float = 0.05
    fingertip_weight: float = 300.0
    fingertip_deadband_m: float = 0.015
    proportion_weight: float = 3.0
    finger_length_weight: float = 6.0
    extended_finger_deg: float = 60.0

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"FitSettings.{name}: expected a number >= 0, got {value}")
        if min(self.iterations, self.sample_spacing, self.silhouette_samples) < 1:
            raise ValueError(
                "FitSettings: iterations, sample_spacing and silhouette_samples must be >= 1"
            )
        if self.observed_information <= 0:
            raise ValueError(
                f"FitSettings.observed_information: expected > 0, got {self.observed_information}"
            )
        if self.max_points < 30:
            raise ValueError(f"FitSettings.max_points: expected >= 30, got {self.max_points}")


@dataclass(frozen=True)
class FrameFit:
    """Outcome of :func:`fit_frame`.

    Attributes
    ----------
    pose : HandPose
    hand : PosedHand
        The hand model posed at ``pose``.
    proportions : HandProportions
        Those the fit ended with (the start's unless they were estimated).
    energy : float
        Energy at ``pose`` without the reference term (which differs between starts).
    start_energy : float
    terms : dict of str to float
        Energy of every term at ``pose``.
    matched : float
        Share of the observed glove points within ``data_gate_m`` of the model
        surface of their color.
    outside : float
        Share of the model's camera-facing samples that project outside the
        observed hand and are not hidden by something in front.
    rms_m : float
        RMS point-to-plane distance of the paired points (before the Huber loss).
    iterations : int
    hidden : (20,) bool or None
        Joints whose finger an object hid at the start or the data did not see (held
        by the reference term).
    proportion_information : (7, 7) float64 or None
        When the proportions were estimated: the information about them after this
        frame (module docstring), to give to the next frame's fit.
    """

    pose: HandPose
    hand: PosedHand
    proportions: HandProportions
    energy: float
    start_energy: float
    terms: dict[str, float] = field(default_factory=dict)
    matched: float = 0.0
    outside: float = 1.0
    rms_m: float = np.inf
    iterations: int = 0
    hidden: NDArray[np.bool_] | None = None
    proportion_information: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class _State:
    pose: HandPose
    samples: HandSamples


def frame_energy(
    samples: HandSamples,
    pose: HandPose,
    observation: Observation,
    *,
    settings: FitSettings,
    prior: PosturePrior,
    previous_keypoints_m: NDArray[np.float64] | None = None,
    tip_targets_m: NDArray[np.float64] | None = None,
    reference: ReferenceBasis | None = None,
    proportions: bool = False,
    proportion_derivatives: ProportionDerivatives | None = None,
    hand: PosedHand | None = None,
    partners_at_pose: NDArray[np.int64] | None = None,
) -> tuple[list[Residuals], dict[str, float], PosedHand]:
    """Every term's residuals at one pose, and the fit's quality measures.

    ``hand``, if given, is the hand already posed at ``pose`` (``samples`` and
    ``proportion_derivatives`` are then not used to pose it again);
    ``partners_at_pose`` the data term's pairing there, if already found
    (:func:`tracker.generative.energy.data.partners`).

    Returns
    -------
    terms : list of Residuals
    quality : dict
        ``matched``, ``outside`` and ``rms_m`` (see :class:`FrameFit`).
    hand : PosedHand
        The hand posed at ``pose``.
    """
    if hand is None:
        hand = PosedHand(samples, pose, proportion_derivatives=proportion_derivatives)
    s = settings
    data, matched = data_residuals(
        hand, observation.points_m, observation.labels, weight=s.data_weight,
        huber_m=s.data_huber_m, gate_m=s.data_gate_m, depth_scale=s.data_depth_scale,
        proportions=proportions, nearest=partners_at_pose,
    )  # fmt: skip
    silhouette, outside = silhouette_residuals(
        hand, observation, weight=s.silhouette_weight, margin_px=s.silhouette_margin_px,
        depth_margin_m=s.depth_margin_m, max_samples=s.silhouette_samples,
        proportions=proportions,
    )  # fmt: skip
    terms = [
        data,
        silhouette,
        prior_residuals(hand, prior, weight=s.prior_weight),
        limit_residuals(hand, weight=s.limit_weight),
        collision_residuals(hand, weight=s.collision_weight),
    ]
    if previous_keypoints_m is not None and s.temporal_weight > 0:
        terms.append(
            temporal_residuals(
                hand, previous_keypoints_m, weight=s.temporal_weight, scale_m=s.temporal_scale_m
            )
        )
    if reference is not None:
        terms.append(
            reference_residuals(hand, reference, scale_rad=np.radians(s.reference_scale_deg))
        )
    if tip_targets_m is not None and s.fingertip_weight > 0:
        terms.append(
            fingertip_residuals(
                hand, tip_targets_m, weight=s.fingertip_weight, deadband_m=s.fingertip_deadband_m
            )
        )
    raw = data.values * np.sqrt(max(len(observation.points_m), 1)) / s.data_weight
    rms = float(np.sqrt(np.mean(raw**2))) if len(raw) else np.inf
    return terms, {"matched": matched, "outside": outside, "rms_m": rms}, hand


def initial_proportion_weights(settings: FitSettings) -> NDArray[np.float64]:
    """``(7,)`` square roots of the information about each proportion before the first
    frame (``proportion_weight`` for the scale and the palm, ``finger_length_weight``
    for the fingers)."""
    weights = np.full(N_PROPORTIONS, settings.finger_length_weight)
    weights[[0, -1]] = settings.proportion_weight
    return weights


def fit_frame_steps(
    samples: HandSamples,
    observation: Observation,
    start: HandPose,
    *,
    settings: FitSettings,
    prior: PosturePrior,
    previous_keypoints_m: NDArray[np.float64] | None = None,
    tip_targets_m: NDArray[np.float64] | None = None,
    estimate_proportions: bool = False,
    proportion_information: NDArray[np.float64] | None = None,
    hold_unseen: bool = False,
) -> Generator[None, None, FrameFit]:
    """Fit the hand to one frame from a start pose (module docstring), yielding after
    each solver iteration but the last (:func:`fit_frame` runs it in one call; the
    tracker's deferred lookups spread it over frames, :mod:`tracker.background`).

    Parameters
    ----------
    samples : HandSamples
        The hand model (its proportions are the start's).
    observation : Observation
    start : HandPose
    settings : FitSettings
    prior : PosturePrior
    previous_keypoints_m : (21, 3) float, optional
        The previous frame's fitted keypoints (temporal term).
    tip_targets_m : (5, 3) float, optional
        Named fingertip detections, NaN rows for none (fingertip term).
    estimate_proportions : bool
        Also fit the hand proportions.
    proportion_information : (7, 7) float, optional
        The information about them from earlier frames (``FrameFit.
        proportion_information``); ``proportion_weight**2 * I`` if not given.
    hold_unseen : bool
        Hold the fingers the camera does not see (``unseen_finger_share``) at the
        start's angles: for a start from the previous frame's solution, not from a
        database posture, which is a guess.

    Returns
    -------
    FrameFit
        What the generator returns.
    """
    anchor = samples.proportions.as_vector()
    information = (
        np.diag(initial_proportion_weights(settings) ** 2)
        if proportion_information is None
        else np.asarray(proportion_information, dtype=np.float64)
    )
    pull_rows = np.linalg.cholesky(information).T
    flexion = np.degrees(start.posture_rad[FLEXION_JOINTS].reshape(5, 3).sum(axis=1))
    extended = (flexion < settings.extended_finger_deg).astype(np.float64)
    start_hand = PosedHand(samples, start)
    hidden = hidden_joints(
        start_hand,
        observation,
        margin_px=settings.silhouette_margin_px + HIDDEN_EDGE_PX,
        depth_margin_m=settings.depth_margin_m,
    )
    start_partners = None  # the data term's pairing at the start, when needed twice
    if hold_unseen and settings.unseen_finger_share > 0:
        start_partners = partners(
            start_hand, observation.points_m, observation.labels,
            gate_m=settings.data_gate_m, depth_scale=settings.data_depth_scale,
        )  # fmt: skip
        hidden |= unseen_fingers(
            start_hand, observation, share=settings.unseen_finger_share,
            gate_m=settings.data_gate_m, depth_scale=settings.data_depth_scale,
            depth_margin_m=settings.depth_margin_m, nearest=start_partners,
        )  # fmt: skip
    kwargs = {
        "settings": settings,
        "prior": prior,
        "previous_keypoints_m": previous_keypoints_m,
        "tip_targets_m": tip_targets_m,
        "reference": None,  # set at the first evaluation, which is at the start
        "proportions": estimate_proportions,
        # The proportions' derivatives change little over one frame's solve: those at
        # the start serve every iteration.
        "proportion_derivatives": start_hand.proportion_derivatives
        if estimate_proportions
        else None,
    }
    first = _State(start, samples)

    # The evaluation of least energy so far: its energy, state, terms, quality, posed
    # hand and Jacobian (a function). The solver keeps exactly the steps that lower the
    # energy, so this is the evaluation of the state it ends on, also when it refused
    # its last steps (re-evaluating that state cost a sixth of a frame's fit).
    best: list[tuple[float, _State, list[Residuals], dict[str, float], PosedHand, Jacobian]] = []

    def evaluate(state: _State) -> Evaluation:
        at_start = state is first
        terms, quality, hand = frame_energy(
            state.samples, state.pose, observation, hand=start_hand if at_start else None,
            partners_at_pose=start_partners if at_start else None, **kwargs,  # type: ignore[arg-type]
        )  # fmt: skip
        if kwargs["reference"] is None and settings.reference_weight > 0:
            observed = [t for t in terms if t.name in (DATA, SILHOUETTE)]
            basis = reference_basis(
                start.posture_rad, posture_information(observed),
                weight=settings.reference_weight,
                observed_information=settings.observed_information, hidden=hidden,
                hidden_weight=settings.hidden_reference_weight,
            )  # fmt: skip
            kwargs["reference"] = basis
            scale_rad = np.radians(settings.reference_scale_deg)
            terms.append(reference_residuals(hand, basis, scale_rad=scale_rad))
        residual = np.concatenate([t.values for t in terms])
        if estimate_proportions:
            pull = pull_rows @ (state.samples.proportions.as_vector() - anchor)
            residual = np.concatenate([residual, pull])

        @cache
        def jacobian() -> NDArray[np.float64]:
            by_pose = np.concatenate([t.jacobian for t in terms])
            if not estimate_proportions:
                return by_pose
            by_proportions = np.concatenate(
                [
                    t.proportion_jacobian
                    if t.proportion_jacobian is not None
                    else np.zeros((len(t), N_PROPORTIONS))
                    for t in terms
                ]
            )
            by_proportions[:, 1:6] *= extended
            return np.block(
                [[by_pose, by_proportions], [np.zeros((N_PROPORTIONS, N_PARAMS)), pull_rows]]
            )

        energy = float(residual @ residual)  # as the solver computes it
        if not best or energy < best[0][0]:
            best[:] = [(energy, state, terms, quality, hand, jacobian)]
        return residual, jacobian

    def advance(state: _State, delta: NDArray[np.float64]) -> _State:
        pose = state.pose.step(delta[:N_PARAMS])
        if not estimate_proportions:
            return _State(pose, state.samples)
        factors = np.clip(state.samples.proportions.as_vector() + delta[N_PARAMS:], *FACTOR_RANGE)
        return _State(pose, state.samples.with_proportions(HandProportions.from_vector(factors)))

    result = yield from levenberg_marquardt_steps(
        evaluate, advance, first, iterations=settings.iterations,
        tolerance=settings.tolerance,
    )  # fmt: skip
    assert best and best[0][1] is result.state  # the solver ends on its least energy
    _, _, terms, quality, hand, jacobian_at_end = best[0]
    information_after = None
    if estimate_proportions:
        jacobian = jacobian_at_end()
        information_after = eliminated_information(jacobian.T @ jacobian, N_PARAMS, ridge=1e-9)
    return FrameFit(
        pose=result.state.pose,
        hand=hand,
        proportions=result.state.samples.proportions,
        energy=sum(t.energy for t in terms if t.name != REFERENCE),
        start_energy=result.start_energy,
        terms={t.name: t.energy for t in terms},
        matched=quality["matched"],
        outside=quality["outside"],
        rms_m=quality["rms_m"],
        iterations=result.iterations,
        hidden=hidden,
        proportion_information=information_after,
    )


fit_frame = in_one_call(fit_frame_steps, "fit_frame")
