"""One frame's generative fit: the energy of thesis ch. 6, summed and minimised.

``E = E_data + E_silhouette + E_prior + E_limits + E_collision + E_temporal +
E_fingertips`` (one module each in :mod:`tracker.generative.energy`), minimised over
the 26 unknowns of :mod:`tracker.generative.model` by
:func:`tracker.generative.solver.levenberg_marquardt`; while a user's hand
proportions are being estimated, over the 7 proportions as well, with a pull toward
the current estimate (``proportion_weight``) that keeps one frame from moving them
far.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from glovedb.posture_prior import PosturePrior
from glovedb.proportions import FACTOR_RANGE, N_PROPORTIONS, HandProportions
from tracker.generative.energy.collision import collision_residuals
from tracker.generative.energy.data import data_residuals
from tracker.generative.energy.fingertips import fingertip_residuals
from tracker.generative.energy.limits import limit_residuals
from tracker.generative.energy.prior import prior_residuals
from tracker.generative.energy.reference import NAME as REFERENCE
from tracker.generative.energy.reference import reference_residuals
from tracker.generative.energy.residuals import Residuals
from tracker.generative.energy.silhouette import silhouette_residuals
from tracker.generative.energy.temporal import temporal_residuals
from tracker.generative.model import N_PARAMS, HandPose, HandSamples, PosedHand
from tracker.generative.observation import Observation
from tracker.generative.solver import levenberg_marquardt


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
        Levenberg-Marquardt solves per hypothesis.
    max_points : int
        Observed glove points used by the data term.
    data_weight : float
        Per metre of RMS point-to-plane distance (the residuals are divided by the
        square root of the number of points).
    data_huber_m : float
        Point-to-plane distances beyond this count linearly.
    data_gate_m : float
        Observed points farther than this from every model sample of their color
        are not paired.
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
    limit_weight : float
        Per radian beyond a joint limit.
    collision_weight : float
        Per metre of overlap of two fingers.
    temporal_weight : float
        Per metre of RMS keypoint motion from the previous frame.
    reference_weight : float
        Per radian of a joint angle's departure from the start's posture.
    reference_scale_deg : float
        Departures beyond this cost less and less (Cauchy loss), degrees.
    fingertip_weight : float
        Per metre of a named fingertip detection beyond its dead band.
    fingertip_deadband_m : float
    proportion_weight : float
        While estimating proportions: per unit of factor change from the current
        estimate in one frame.
    """

    iterations: int = 6
    max_points: int = 500
    data_weight: float = 1000.0
    data_huber_m: float = 0.006
    data_gate_m: float = 0.03
    silhouette_weight: float = 300.0
    silhouette_margin_px: float = 2.0
    depth_margin_m: float = 0.012
    silhouette_samples: int = 400
    prior_weight: float = 0.3
    limit_weight: float = 30.0
    collision_weight: float = 300.0
    temporal_weight: float = 15.0
    reference_weight: float = 2.0
    reference_scale_deg: float = 10.0
    fingertip_weight: float = 300.0
    fingertip_deadband_m: float = 0.015
    proportion_weight: float = 10.0

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"FitSettings.{name}: expected a number >= 0, got {value}")
        if self.iterations < 1 or self.max_points < 30 or self.silhouette_samples < 1:
            raise ValueError(
                "FitSettings: iterations >= 1, max_points >= 30 and silhouette_samples >= 1"
            )


@dataclass(frozen=True)
class FrameFit:
    """Outcome of :func:`fit_frame`.

    Attributes
    ----------
    pose : HandPose
    proportions : HandProportions
        Those the fit ended with (the start's unless they were estimated).
    energy : float
        Energy at ``pose`` without the reference term (which differs between starts):
        what starts are compared by.
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
    """

    pose: HandPose
    proportions: HandProportions
    energy: float
    start_energy: float
    terms: dict[str, float] = field(default_factory=dict)
    matched: float = 0.0
    outside: float = 1.0
    rms_m: float = np.inf
    iterations: int = 0


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
    reference_rad: NDArray[np.float64] | None = None,
    proportions: bool = False,
) -> tuple[list[Residuals], dict[str, float]]:
    """Every term's residuals at one pose, and the fit's quality measures.

    Returns
    -------
    terms : list of Residuals
    quality : dict
        ``matched``, ``outside`` and ``rms_m`` (see :class:`FrameFit`).
    """
    hand = PosedHand(samples, pose)
    s = settings
    data, matched = data_residuals(
        hand, observation.points_m, observation.labels, weight=s.data_weight,
        huber_m=s.data_huber_m, gate_m=s.data_gate_m, proportions=proportions,
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
        terms.append(temporal_residuals(hand, previous_keypoints_m, weight=s.temporal_weight))
    if reference_rad is not None and s.reference_weight > 0:
        terms.append(
            reference_residuals(
                hand, reference_rad, weight=s.reference_weight,
                scale_rad=np.radians(s.reference_scale_deg),
            )
        )  # fmt: skip
    if tip_targets_m is not None and s.fingertip_weight > 0:
        terms.append(
            fingertip_residuals(
                hand, tip_targets_m, weight=s.fingertip_weight, deadband_m=s.fingertip_deadband_m
            )
        )
    raw = data.values * np.sqrt(max(len(observation.points_m), 1)) / s.data_weight
    rms = float(np.sqrt(np.mean(raw**2))) if len(raw) else np.inf
    return terms, {"matched": matched, "outside": outside, "rms_m": rms}


def fit_frame(
    samples: HandSamples,
    observation: Observation,
    start: HandPose,
    *,
    settings: FitSettings,
    prior: PosturePrior,
    previous_keypoints_m: NDArray[np.float64] | None = None,
    tip_targets_m: NDArray[np.float64] | None = None,
    estimate_proportions: bool = False,
) -> FrameFit:
    """Fit the hand to one frame from a start pose (module docstring).

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

    Returns
    -------
    FrameFit
    """
    anchor = samples.proportions.as_vector()
    kwargs = {
        "settings": settings,
        "prior": prior,
        "previous_keypoints_m": previous_keypoints_m,
        "tip_targets_m": tip_targets_m,
        "reference_rad": start.posture_rad,
        "proportions": estimate_proportions,
    }

    def evaluate(state: _State) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        terms, _ = frame_energy(state.samples, state.pose, observation, **kwargs)  # type: ignore[arg-type]
        residual = np.concatenate([t.values for t in terms])
        jacobian = np.concatenate([t.jacobian for t in terms])
        if not estimate_proportions:
            return residual, jacobian
        by_proportions = np.concatenate(
            [
                t.proportion_jacobian
                if t.proportion_jacobian is not None
                else np.zeros((len(t), N_PROPORTIONS))
                for t in terms
            ]
        )
        pull = settings.proportion_weight * (state.samples.proportions.as_vector() - anchor)
        residual = np.concatenate([residual, pull])
        jacobian = np.block(
            [
                [jacobian, by_proportions],
                [
                    np.zeros((N_PROPORTIONS, N_PARAMS)),
                    settings.proportion_weight * np.eye(N_PROPORTIONS),
                ],
            ]
        )
        return residual, jacobian

    def advance(state: _State, delta: NDArray[np.float64]) -> _State:
        pose = state.pose.step(delta[:N_PARAMS])
        if not estimate_proportions:
            return _State(pose, state.samples)
        factors = np.clip(state.samples.proportions.as_vector() + delta[N_PARAMS:], *FACTOR_RANGE)
        return _State(pose, state.samples.with_proportions(HandProportions.from_vector(factors)))

    result = levenberg_marquardt(
        evaluate, advance, _State(start, samples), iterations=settings.iterations
    )
    terms, quality = frame_energy(
        result.state.samples,
        result.state.pose,
        observation,
        **{**kwargs, "proportions": False},  # type: ignore[arg-type]
    )
    return FrameFit(
        pose=result.state.pose,
        proportions=result.state.samples.proportions,
        energy=sum(t.energy for t in terms if t.name != REFERENCE),
        start_energy=result.start_energy,
        terms={t.name: t.energy for t in terms},
        matched=quality["matched"],
        outside=quality["outside"],
        rms_m=quality["rms_m"],
        iterations=result.iterations,
    )
