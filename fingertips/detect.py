"""Fingertip detection on one depth frame: forest, Hough voting, heatmap, assignment."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, fields, replace
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fingertips.assignment import FINGER_NAMES, assign_detections
from fingertips.calibration import Calibration
from fingertips.candidates import (
    CANDIDATE_SOURCES,
    CandidateSource,
    FrameCandidates,
    candidate_features,
    forest_candidates,
    merge_candidates,
)
from fingertips.features import (
    backproject,
    foreground_pixels,
    intrinsics_array,
    mask_depth_range,
    nearest_band,
    probe_image,
    project,
    stride_for_budget,
    stride_for_spacing,
)
from fingertips.forest import FingertipForest, apply_probe_image, predict_leaves
from fingertips.geodesic import GeodesicCandidates, geodesic_candidates
from fingertips.heat_fusion import candidate_heat, fused_probability
from fingertips.heatmap import (
    CROP_CENTRES,
    HAND_BAND_M,
    HAND_DEPTH_RANGE_M,
    CropCentre,
    HandHeatmaps,
    HeatmapStage,
    heatmap_peaks,
    start_heatmaps,
)
from fingertips.judge import judged_probability
from fingertips.segmentation import SEGMENTATION_METHODS, SegmentationMethod, segment_hand
from fingertips.verify import verify_peaks
from fingertips.voting import (
    DEFAULT_VOTING,
    Votes,
    VotingConfig,
    apart_in_order,
    cast_votes,
    find_peaks,
)
from glovedb._validate import as_array, check_choice


@dataclass(frozen=True)
class Detection:
    """One detected fingertip.

    Attributes
    ----------
    u_px, v_px : float
        Projection into the image, pixels.
    x_m, y_m, z_m : float
        Position in the camera frame (OpenCV axes), metres.
    confidence : float
        With a calibrated model (:mod:`fingertips.calibration`): the probability
        that the detection lies within 15 mm of a fingertip, its ``tip_probability``
        mapped by the model's confidence map for its source. Without calibration (a
        model without maps or without a verifier): ``raw_confidence``.
    finger : str or None
        Finger name from the assignment to a posed model, None if unassigned or if no
        model was given.
    tip_probability : float or None
        The peak verifier's probability that this is a fingertip
        (:mod:`fingertips.verify`, or the heatmap's verifier); None if the
        model has no verifier.
    source : str
        ``"forest"`` (a vote peak, also when the geodesic stage proposed it too),
        ``"geodesic"`` (a geodesic finger candidate no vote peak was near,
        :mod:`fingertips.candidates`) or ``"heatmap"`` (a peak of the whole-hand
        heatmap, :mod:`fingertips.heatmap`).
    raw_confidence : float or None
        The confidence before calibration: the sum of the vote weights supporting the
        detection (:mod:`fingertips.voting`; 0 for a geodesic candidate without
        votes) or, for a heatmap detection, the mean heat of its cell. None means
        ``confidence`` is that raw value itself (no calibration).
    """

    u_px: float
    v_px: float
    x_m: float
    y_m: float
    z_m: float
    confidence: float
    finger: str | None = None
    tip_probability: float | None = None
    source: str = "forest"
    raw_confidence: float | None = None

    @property
    def uncalibrated_confidence(self) -> float:
        """The uncalibrated confidence (``raw_confidence``, else ``confidence``)."""
        return self.confidence if self.raw_confidence is None else self.raw_confidence


@dataclass(frozen=True)
class DetectorConfig:
    """Settings of detection on one frame.

    Attributes
    ----------
    c_thr : float
        Smallest confidence kept (see :mod:`fingertips.voting`).
    stride : int
        Pixel step of the evaluated grid when ``pixel_spacing_m`` is 0.
    pixel_spacing_m : float
        When positive, the stride is chosen per frame so that the grid samples the
        nearest surface about every ``pixel_spacing_m`` metres
        (:func:`fingertips.features.stride_for_spacing`): the cost per frame
        then hardly depends on resolution or distance.
    depth_band_m : float
        Only depth within this many metres behind the nearest surface is the hand
        (:func:`fingertips.features.nearest_band`); ``inf`` turns it off.
    max_pixels : int
        The stride grows until at most about this many pixels are evaluated (bounds
        the time per frame when a background surface lies within the band); 0: no
        bound. Vote weights scale with the stride, so confidences do not change.
    min_tip_probability : float
        Peaks whose verifier probability (:mod:`fingertips.verify`; when the heatmap
        stage is on and the model has a candidate judge, its probability from that and
        the heat of their map cell, :mod:`fingertips.judge`, or an older model's fusion,
        :mod:`fingertips.heat_fusion`) is below this are dropped; 0 keeps every peak
        above ``c_thr`` (and is the only value allowed for a model without a
        verifier). With a verifier, ``c_thr`` only selects the candidate peaks.
    heatmap_min_probability : float
        Peaks of the model's heatmap stage (:mod:`fingertips.heatmap`) whose
        verifier probability reaches this, and that lie farther than
        ``voting.min_separation_m`` from every forest detection and every more
        probable heat peak, are added to the detections; 0 turns the stage off (and is
        the only value allowed for a model without one). The stage also needs
        ``min_tip_probability`` > 0.
    segmentation : {"band", "surface"}
        How the hand's pixels are found (:func:`hand_depth`): ``"band"``, the depth
        within ``depth_band_m`` behind the nearest surface; ``"surface"``, bare-hand
        segmentation (:func:`fingertips.segmentation.segment_hand`: support planes
        removed, the nearest connected surface, the forearm cut), then the band.
    candidates : {"forest", "union"}
        What the verifier scores (:mod:`fingertips.candidates`): the forest's vote
        peaks, or those and the geodesic finger candidates of the hand depth
        (:func:`fingertips.geodesic.geodesic_candidates`), duplicates within
        ``voting.bandwidth_m`` merged. Detections closer than
        ``voting.min_separation_m`` to a more probable one (a stronger one without
        the verifier) are dropped.
    heatmap_centre : {"density", "fingers"}
        Where the heatmap stage centres its crop (:func:`fingertips.heatmap.crop_centre`):
        the nearest object's densest 12 cm, or the geodesic stage's finger candidates
        (the stage then runs for the crop even with ``candidates`` "forest"). A model's
        heatmap verifier is fitted with one rule and records it.
    voting : VotingConfig
    """

    c_thr: float = 3.0
    stride: int = 2
    pixel_spacing_m: float = 0.0
    depth_band_m: float = math.inf
    max_pixels: int = 0
    min_tip_probability: float = 0.0
    heatmap_min_probability: float = 0.0
    segmentation: SegmentationMethod = "band"
    candidates: CandidateSource = "forest"
    heatmap_centre: CropCentre = "density"
    voting: VotingConfig = DEFAULT_VOTING

    def __post_init__(self) -> None:
        check_choice("segmentation", self.segmentation, SEGMENTATION_METHODS)
        check_choice("candidates", self.candidates, CANDIDATE_SOURCES)
        check_choice("heatmap_centre", self.heatmap_centre, CROP_CENTRES)
        if not 0 < self.c_thr < math.inf:
            raise ValueError(f"c_thr: expected a positive, finite threshold, got {self.c_thr}")
        if self.stride < 1:
            raise ValueError(f"stride: expected at least 1, got {self.stride}")
        if self.pixel_spacing_m < 0:
            raise ValueError(f"pixel_spacing_m: expected >= 0, got {self.pixel_spacing_m}")
        if self.max_pixels < 0:
            raise ValueError(f"max_pixels: expected >= 0, got {self.max_pixels}")
        if not self.depth_band_m > 0:
            raise ValueError(f"depth_band_m: expected a positive depth, got {self.depth_band_m}")
        if not 0 <= self.min_tip_probability <= 1:
            raise ValueError(
                f"min_tip_probability: expected a probability, got {self.min_tip_probability}"
            )
        if not 0 <= self.heatmap_min_probability <= 1:
            raise ValueError(
                "heatmap_min_probability: expected a probability, "
                f"got {self.heatmap_min_probability}"
            )
        if self.heatmap_min_probability > 0 and self.min_tip_probability == 0:
            raise ValueError(
                "heatmap_min_probability: the heatmap stage needs min_tip_probability > 0"
            )

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready settings (``depth_band_m`` inf becomes None)."""
        values = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "voting"}
        if not math.isfinite(values["depth_band_m"]):
            values["depth_band_m"] = None
        values["voting"] = {f.name: getattr(self.voting, f.name) for f in fields(self.voting)}
        return values


DEFAULT_DETECTOR = DetectorConfig()
"""The default detection settings (immutable)."""


def detector_config_from_dict(table: Mapping[str, Any]) -> DetectorConfig:
    """Build a :class:`DetectorConfig` from a dict as written by :meth:`DetectorConfig.as_dict`.

    Raises
    ------
    ValueError
        For an unknown key.
    """
    known = {f.name for f in fields(DetectorConfig)}
    voting_known = {f.name for f in fields(VotingConfig)}
    unknown = (set(table) - known) | (set(table.get("voting", {})) - voting_known)
    if unknown:
        raise ValueError(f"detector: unknown settings {', '.join(sorted(unknown))}")
    values = {k: v for k, v in table.items() if k != "voting"}
    if values.get("depth_band_m", 0.0) is None:
        values["depth_band_m"] = math.inf
    return replace(DEFAULT_DETECTOR, voting=VotingConfig(**table.get("voting", {})), **values)


def model_detector_config(model: FingertipForest) -> DetectorConfig:
    """The detection settings recorded with a trained forest (defaults if none)."""
    return detector_config_from_dict(model.settings.get("detector", {}))


def hand_depth(
    depth_m: ArrayLike,
    model: FingertipForest,
    *,
    depth_band_m: float = math.inf,
    segmentation: SegmentationMethod = "band",
    intrinsics: ArrayLike | None = None,
) -> NDArray[np.float32]:
    """Depth restricted to the forest's working range and to the hand.

    Parameters
    ----------
    depth_m : (H, W) float
        Depth in metres, 0 where missing.
    model : FingertipForest
    depth_band_m : float
        See :class:`DetectorConfig`.
    segmentation : {"band", "surface"}
        See :class:`DetectorConfig`.
    intrinsics : (4,) float, optional
        ``(fx, fy, cx, cy)`` in pixels; needed by ``"surface"``.

    Returns
    -------
    (H, W) float32
        0 outside.
    """
    near, far = model.depth_range_m
    masked = mask_depth_range(depth_m, near_m=near, far_m=far)
    if check_choice("segmentation", segmentation, SEGMENTATION_METHODS) == "surface":
        if intrinsics is None:
            raise ValueError("intrinsics: needed by the surface segmentation")
        hand = segment_hand(masked, intrinsics).mask
        masked = np.where(hand, masked, np.float32(0.0))
    return nearest_band(masked, band_m=depth_band_m)


def fingertip_votes(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    model: FingertipForest,
    *,
    config: DetectorConfig = DEFAULT_DETECTOR,
) -> Votes:
    """The forest's 3D fingertip votes for one depth frame.

    Parameters
    ----------
    depth_m : (H, W) float32
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    model : FingertipForest
        Trained forest; its working depth range selects the hand pixels.
    config : DetectorConfig
        Pixel grid, hand segmentation and voting settings.

    Returns
    -------
    Votes
    """
    return _frame_votes(depth_m, intrinsics_array(intrinsics), model, config)


def _frame_votes(
    depth_m: ArrayLike,
    camera: NDArray[np.float64],
    model: FingertipForest,
    config: DetectorConfig,
) -> Votes:
    """The votes of :func:`fingertip_votes`."""
    masked = _frame_hand_depth(depth_m, camera, model, config)
    return _hand_votes(masked, camera, model, config)[0]


def _frame_hand_depth(
    depth_m: ArrayLike,
    camera: NDArray[np.float64],
    model: FingertipForest,
    config: DetectorConfig,
) -> NDArray[np.float32]:
    """:func:`hand_depth` with the detector's settings."""
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    return hand_depth(
        depth,
        model,
        depth_band_m=config.depth_band_m,
        segmentation=config.segmentation,
        intrinsics=camera,
    )


def _hand_votes(
    masked: NDArray[np.float32],
    camera: NDArray[np.float64],
    model: FingertipForest,
    config: DetectorConfig,
) -> tuple[Votes, NDArray[np.float32]]:
    """The votes of :func:`fingertip_votes` and the probe image they come from
    (:func:`~fingertips.features.probe_image`, made once per frame) from the hand depth
    (:func:`_frame_hand_depth`)."""
    stride = config.stride
    if config.pixel_spacing_m > 0:
        stride = stride_for_spacing(masked, float(camera[0]), spacing_m=config.pixel_spacing_m)
    if config.max_pixels > 0:
        stride = max(stride, stride_for_budget(masked, config.max_pixels))
    pixels = foreground_pixels(masked, stride=stride)
    probes = probe_image(masked)
    prediction = predict_leaves(model, apply_probe_image(model, probes, pixels, camera))
    z = masked[pixels[:, 1], pixels[:, 0]]
    points = backproject(pixels, z, camera)
    area = (stride * z) ** 2 / np.float32(camera[0] * camera[1])
    votes = cast_votes(
        points, prediction.probability, prediction.offset_m, area, config=config.voting
    )
    return votes, probes


def _start_geodesic(
    masked: NDArray[np.float32],
    camera: NDArray[np.float64],
    config: DetectorConfig,
    *,
    heatmap: bool,
) -> Future[GeodesicCandidates] | None:
    """Start the geodesic stage in its worker thread when the candidates or, with
    ``heatmap``, the heatmap's crop centre need it.

    It runs while the forest votes (both are compiled loops that release the GIL), so
    that its 4-6 ms per VGA frame (median in ``glove bench fingertips``) overlap the
    forest's instead of adding to them.
    """
    if config.candidates == "union" or (heatmap and config.heatmap_centre == "fingers"):
        return _beside_the_forest().submit(geodesic_candidates, masked, camera)
    return None


def _geodesic_first(
    masked: NDArray[np.float32], camera: NDArray[np.float64]
) -> Future[GeodesicCandidates]:
    """The geodesic stage run now, on the calling thread, as a finished future.

    For the heatmap's ``"fingers"`` crop centre: the network cannot start before the
    geodesic stage ends, and the two in a row beside the forest (4 + 5 ms, slowed by
    sharing the cores with it) made every frame wait for the network. Alone the
    geodesic stage takes about 2.5 ms, then the network's passes run while the forest
    votes: ``glove bench fingertips`` on a 2-core machine, 13.2-13.7 -> 10.8-11.1 ms
    median per VGA frame, the same detections.
    """
    done: Future[GeodesicCandidates] = Future()
    done.set_result(geodesic_candidates(masked, camera))
    return done


def _candidates(
    masked: NDArray[np.float32],
    camera: NDArray[np.float64],
    model: FingertipForest,
    config: DetectorConfig,
    geodesic: Future[GeodesicCandidates] | None,
) -> tuple[FrameCandidates, NDArray[np.float32]]:
    """:func:`candidate_peaks` of the hand depth ``masked`` (:func:`_frame_hand_depth`),
    ``geodesic`` being its started geodesic stage (:func:`_start_geodesic`)."""
    votes, probes = _hand_votes(masked, camera, model, config)
    peaks = find_peaks(votes, c_thr=config.c_thr, config=config.voting)
    bandwidth = config.voting.bandwidth_m
    if config.candidates == "union" and geodesic is not None:
        candidates = merge_candidates(peaks, geodesic.result(), votes, bandwidth_m=bandwidth)
    else:
        candidates = forest_candidates(peaks)
    features = candidate_features(candidates, votes, probes, camera, bandwidth_m=bandwidth)
    return candidates, features


_GEODESIC_WORKER: list[ThreadPoolExecutor] = []


def _beside_the_forest() -> ThreadPoolExecutor:
    """The one worker thread of the geodesic stage (made on first use)."""
    if not _GEODESIC_WORKER:
        _GEODESIC_WORKER.append(ThreadPoolExecutor(1, thread_name_prefix="glove-geodesic"))
    return _GEODESIC_WORKER[0]


def candidate_peaks(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    model: FingertipForest,
    *,
    config: DetectorConfig = DEFAULT_DETECTOR,
) -> tuple[FrameCandidates, NDArray[np.float32]]:
    """The frame's candidates and their verifier features.

    The candidates are the vote peaks above ``config.c_thr`` and, with
    ``config.candidates`` "union", the geodesic finger candidates
    (:func:`fingertips.candidates.merge_candidates`).

    Parameters
    ----------
    depth_m : (H, W) float32
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    model : FingertipForest
    config : DetectorConfig

    Returns
    -------
    candidates : FrameCandidates
        Strongest first.
    features : (K, len(UNION_FEATURES)) float32
        :func:`fingertips.candidates.candidate_features` of the candidates.
    """
    camera = intrinsics_array(intrinsics)
    masked = _frame_hand_depth(depth_m, camera, model, config)
    geodesic = _start_geodesic(masked, camera, config, heatmap=False)
    return _candidates(masked, camera, model, config, geodesic)


class VerifiedCandidates(NamedTuple):
    """What :func:`verified_candidates` returns: what the heatmap stage reads.

    Attributes
    ----------
    candidates : FrameCandidates
        Every candidate (:func:`candidate_peaks`), strongest first.
    probability : (K,) float32
        Their verifier probabilities.
    features : (K, len(UNION_FEATURES)) float32
        Their verifier features (:func:`fingertips.candidates.candidate_features`).
    hand_depth_m : (H, W) float32 or None
        The forest's hand depth when it is cut like the heatmap's crop centre needs it
        (:func:`fingertips.heatmap.hand_centre`), else None.
    geodesic : GeodesicCandidates or None
        The frame's geodesic stage when the candidates or the crop centre
        (``heatmap_centre`` "fingers") use it, else None.
    """

    candidates: FrameCandidates
    probability: NDArray[np.float32]
    features: NDArray[np.float32]
    hand_depth_m: NDArray[np.float32] | None
    geodesic: GeodesicCandidates | None


def verified_candidates(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    model: FingertipForest,
    *,
    config: DetectorConfig = DEFAULT_DETECTOR,
) -> VerifiedCandidates:
    """Candidates with their verifier probabilities, and what the heatmap stage reads.

    Parameters
    ----------
    depth_m : (H, W) float32
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
    model : FingertipForest
        With a peak verifier.
    config : DetectorConfig

    Returns
    -------
    VerifiedCandidates
        The probabilities are the peak verifier's own, never fused with the heat.
    """
    if model.verifier is None:
        raise ValueError("model: has no peak verifier (a [verifier] table)")
    camera = intrinsics_array(intrinsics)
    masked = _frame_hand_depth(depth_m, camera, model, config)
    geodesic = _start_geodesic(masked, camera, config, heatmap=True)
    candidates, features = _candidates(masked, camera, model, config, geodesic)
    same_cut = (
        np.allclose(model.depth_range_m, HAND_DEPTH_RANGE_M, rtol=1e-6)
        and config.depth_band_m == HAND_BAND_M
        and config.segmentation == "band"
    )
    return VerifiedCandidates(
        candidates,
        verify_peaks(model.verifier, features),
        features,
        masked if same_cut else None,
        None if geodesic is None else geodesic.result(),
    )


def detect_fingertips(
    depth_m: ArrayLike,
    intrinsics: ArrayLike,
    model: FingertipForest,
    *,
    model_tips_m: ArrayLike | None = None,
    config: DetectorConfig = DEFAULT_DETECTOR,
    lam: float = 1.2,
    distance_unit_m: float = 0.01,
) -> tuple[Detection, ...]:
    """Detect fingertips in a depth frame and, given a posed model, name their fingers.

    Parameters
    ----------
    depth_m : (H, W) float32
        Depth in metres, 0 where missing.
    intrinsics : (4,) float
        ``(fx, fy, cx, cy)`` in pixels.
    model : FingertipForest
        Trained forest (:func:`fingertips.forest.load_forest`).
    model_tips_m : (5, 3) float, optional
        Fingertips of the posed hand model in the camera frame (metres), in the order
        of :data:`FINGER_NAMES`. When given, detections are assigned to fingers by
        Eq. 11 of Tzionas et al. 2014.
    config : DetectorConfig
        Confidence threshold, pixel grid, hand segmentation and voting settings;
        :func:`model_detector_config` gives the ones recorded with a trained model.
    lam : float
        Weight lambda of the assignment.
    distance_unit_m : float
        Unit (metres) of the assignment's detection-to-finger distances.

    Returns
    -------
    tuple of Detection
        Strongest first: by calibrated confidence when the model has confidence maps
        (:mod:`fingertips.calibration`); else the forest's detections by vote weight
        (by verifier probability when verified), then the heatmap's by probability.
    """
    camera = intrinsics_array(intrinsics)
    if config.min_tip_probability > 0 and model.verifier is None:
        raise ValueError(
            "min_tip_probability: the model has no peak verifier; use 0 or a model "
            "trained with a [verifier] table"
        )
    if config.heatmap_min_probability > 0 and model.heatmap is None:
        raise ValueError(
            "heatmap_min_probability: the model has no heatmap stage; use 0 or a model "
            "trained with a [heatmap] table"
        )
    depth = as_array("depth_m", depth_m, (None, None), np.float32, kind="fiu")
    if model.verifier is None and config.candidates == "forest":
        votes = _frame_votes(depth, camera, model, config)
        peaks = find_peaks(votes, c_thr=config.c_thr, config=config.voting)
        detections = _candidate_detections(forest_candidates(peaks), None, camera)
    elif model.verifier is None:
        masked = _frame_hand_depth(depth, camera, model, config)
        geodesic = _start_geodesic(masked, camera, config, heatmap=False)
        candidates = _candidates(masked, camera, model, config, geodesic)[0]
        keep = _separated(candidates, candidates.confidences, config.voting.min_separation_m)
        detections = _candidate_detections(candidates, None, camera, keep)
    else:
        # The heatmap's network runs in its own thread while the forest votes; with the
        # "fingers" crop centre, after the geodesic stage it needs, run first.
        heatmap = model.heatmap if config.heatmap_min_probability > 0 else None
        fingers = heatmap is not None and config.heatmap_centre == "fingers"
        heat = None
        if heatmap is not None and not fingers:
            heat = start_heatmaps(depth, camera, heatmap)
        masked = _frame_hand_depth(depth, camera, model, config)
        if heatmap is not None and fingers:
            geodesic = _geodesic_first(masked, camera)
            heat = start_heatmaps(depth, camera, heatmap, geodesic=geodesic)
        else:
            geodesic = _start_geodesic(masked, camera, config, heatmap=False)
        candidates, features = _candidates(masked, camera, model, config, geodesic)
        probability = verify_peaks(model.verifier, features)
        heatmaps = None if heat is None else heat.result()
        tip_probability = probability
        if heatmaps is not None and heatmap is not None and heatmap.judge is not None:
            heat_there = candidate_heat(heatmaps, candidates.positions_m)
            tip_probability = judged_probability(heatmap.judge, probability, heat_there, features)
        elif heatmaps is not None and heatmap is not None and heatmap.fusion is not None:
            heat_there = candidate_heat(heatmaps, candidates.positions_m)
            tip_probability = fused_probability(heatmap.fusion, probability, heat_there)
        # With the verifier off (min_tip_probability 0) the vote weight ranks, as without one.
        rank_by = tip_probability if config.min_tip_probability > 0 else candidates.confidences
        keep = (tip_probability >= config.min_tip_probability) & _separated(
            candidates, rank_by, config.voting.min_separation_m
        )
        detections = _candidate_detections(candidates, tip_probability, camera, keep)
        if heatmaps is not None and heatmap is not None:
            # The heatmap's verifier reads the peak verifier's own probabilities.
            detections += _heatmap_detections(
                depth, camera, heatmap, config, candidates, probability, detections, heatmaps
            )
        if model.calibration is not None:
            detections = calibrated_detections(detections, model.calibration)
    if model_tips_m is None:
        return detections
    return name_fingers(
        detections,
        model_tips_m,
        c_thr=config.c_thr,
        min_tip_probability=config.min_tip_probability,
        heatmap_min_probability=config.heatmap_min_probability,
        lam=lam,
        distance_unit_m=distance_unit_m,
    )


def calibrated_detections(
    detections: Sequence[Detection], calibration: Calibration
) -> tuple[Detection, ...]:
    """Detections with calibrated confidences, most confident first (ties keep their order).

    Each ``confidence`` becomes the calibration's probability for the detection's
    source and ``tip_probability``; the previous confidence moves to
    ``raw_confidence``.

    Raises
    ------
    ValueError
        For a detection without ``tip_probability`` (made without a verifier), or of a
        source the calibration has no map for.
    """
    calibrated = []
    for d in detections:
        if d.tip_probability is None:
            raise ValueError("detections: calibration needs each detection's tip_probability")
        calibrated.append(
            replace(
                d,
                confidence=calibration.confidence(d.source, d.tip_probability),
                raw_confidence=d.uncalibrated_confidence,
            )
        )
    order = np.argsort([-d.confidence for d in calibrated], kind="stable")
    return tuple(calibrated[k] for k in order)


def _separated(
    candidates: FrameCandidates, score: NDArray[np.float32], separation_m: float
) -> NDArray[np.bool_]:
    """Whether each candidate lies ``separation_m`` or farther from every candidate of a
    larger score (ties: the earlier one) that is itself kept, ``(K,)`` bool.

    Vote peaks are already that far apart; a geodesic candidate just beyond the merge
    radius of a peak is not."""
    order = np.argsort(-score, kind="stable")
    return apart_in_order(candidates.positions_m, order, separation_m)


def _candidate_detections(
    candidates: FrameCandidates,
    tip_probability: NDArray[np.float32] | None,
    camera: NDArray[np.float64],
    keep: NDArray[np.bool_] | None = None,
) -> tuple[Detection, ...]:
    """The kept candidates (with their verifier probabilities, if any) as detections."""
    uv = project(candidates.positions_m.astype(np.float64), camera)
    index = np.arange(len(candidates)) if keep is None else np.flatnonzero(keep)
    return tuple(
        Detection(
            u_px=float(uv[k, 0]),
            v_px=float(uv[k, 1]),
            x_m=float(candidates.positions_m[k, 0]),
            y_m=float(candidates.positions_m[k, 1]),
            z_m=float(candidates.positions_m[k, 2]),
            confidence=float(candidates.confidences[k]),
            tip_probability=None if tip_probability is None else float(tip_probability[k]),
            source="forest" if candidates.from_forest[k] else "geodesic",
        )
        for k in index
    )


def _heatmap_detections(
    depth_m: NDArray[np.float32],
    camera: NDArray[np.float64],
    stage: HeatmapStage,
    config: DetectorConfig,
    candidates: FrameCandidates,
    candidate_probability: NDArray[np.float32],
    forest_detections: tuple[Detection, ...],
    heatmaps: HandHeatmaps,
) -> tuple[Detection, ...]:
    """The heatmap's accepted peaks, most probable first, each farther than the voting's
    ``min_separation_m`` from every forest detection and every more probable one;
    ``heatmaps`` are the frame's (:func:`fingertips.heatmap.start_heatmaps`)."""
    peaks, probability = heatmap_peaks(
        depth_m,
        camera,
        stage,
        candidates.positions_m,
        candidates.confidences,
        candidate_probability,
        min_tip_probability=config.min_tip_probability,
        heatmaps=heatmaps,
    )
    separation = config.voting.min_separation_m
    taken = list(detection_points(forest_detections))
    order = []
    for k in np.argsort(-probability, kind="stable"):  # most probable first
        if probability[k] < config.heatmap_min_probability:
            break
        if all(np.linalg.norm(peaks.xyz_m[k] - point) > separation for point in taken):
            order.append(k)
            taken.append(peaks.xyz_m[k])
    return tuple(
        Detection(
            u_px=float(peaks.uv_px[k, 0]),
            v_px=float(peaks.uv_px[k, 1]),
            x_m=float(peaks.xyz_m[k, 0]),
            y_m=float(peaks.xyz_m[k, 1]),
            z_m=float(peaks.xyz_m[k, 2]),
            confidence=float(peaks.values[k]),
            tip_probability=float(probability[k]),
            source="heatmap",
        )
        for k in order
    )


def name_fingers(
    detections: Sequence[Detection],
    model_tips_m: ArrayLike,
    *,
    c_thr: float,
    min_tip_probability: float = 0.0,
    heatmap_min_probability: float = 0.0,
    lam: float = 1.2,
    distance_unit_m: float = 0.01,
) -> tuple[Detection, ...]:
    """Name the fingers of detections by Eq. 11 of Tzionas et al. 2014.

    A detection's weight ``w_s`` (the cost of leaving it unassigned is ``lam * w_s``)
    is its uncalibrated confidence (the vote weight) over ``c_thr``, as in the paper,
    or, for verified detections (``min_tip_probability > 0``), its verifier
    probability over
    ``min_tip_probability`` (over ``heatmap_min_probability`` for the heatmap's
    detections): in every case 1 at the threshold that kept it.

    Parameters
    ----------
    detections : sequence of Detection
    model_tips_m : (5, 3) float
        Fingertips of a posed hand model in the camera frame (metres), in the order of
        :data:`FINGER_NAMES`.
    c_thr : float
        The confidence threshold the detections were kept with.
    min_tip_probability : float
        The verifier threshold they were kept with (0: none).
    heatmap_min_probability : float
        The heatmap verifier's threshold (used only for heatmap detections).
    lam : float
        Weight lambda of the assignment.
    distance_unit_m : float
        Unit (metres) of the assignment's detection-to-finger distances.

    Returns
    -------
    tuple of Detection
        The same detections with ``finger`` set (None: left unassigned).
    """
    tips = as_array("model_tips_m", model_tips_m, (len(FINGER_NAMES), 3), np.float64)
    positions = detection_points(detections)
    verified = min_tip_probability > 0 and all(d.tip_probability is not None for d in detections)
    if any(d.source == "heatmap" for d in detections) and not heatmap_min_probability > 0:
        raise ValueError("heatmap_min_probability: needed to weigh the heatmap's detections")
    if verified:  # each probability over the threshold that kept it
        thresholds = {
            "forest": min_tip_probability,
            "geodesic": min_tip_probability,
            "heatmap": heatmap_min_probability,
        }
        weights = np.array(
            [float(d.tip_probability or 0.0) for d in detections], dtype=np.float64
        ) / np.array([thresholds[d.source] for d in detections], dtype=np.float64)
        threshold = 1.0
    else:
        weights = np.array([d.uncalibrated_confidence for d in detections], dtype=np.float64)
        threshold = c_thr
    assignment = assign_detections(
        positions, weights, tips, c_thr=threshold, lam=lam, distance_unit_m=distance_unit_m
    )
    return tuple(
        replace(d, finger=FINGER_NAMES[t] if t >= 0 else None)
        for d, t in zip(detections, assignment.finger_of_detection, strict=True)
    )


def detection_points(detections: Sequence[Detection]) -> NDArray[np.float64]:
    """Camera-frame positions ``(K, 3)`` of detections, metres."""
    return np.array([[d.x_m, d.y_m, d.z_m] for d in detections], dtype=np.float64).reshape(-1, 3)


def fingertips_output(detections: Sequence[Detection]) -> list[dict[str, Any]]:
    """The ``fingertips`` list of a ``poses.jsonl`` record (docs/conventions.md)."""
    return [
        {
            "finger": d.finger,
            "u_px": d.u_px,
            "v_px": d.v_px,
            "x_m": d.x_m,
            "y_m": d.y_m,
            "z_m": d.z_m,
            "confidence": d.confidence,
        }
        for d in detections
    ]
