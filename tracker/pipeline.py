"""The tracker: from one RGB-D frame to the hand's posture and 6D pose.

Per frame:

1. **classify** every pixel's color with the lookup table (:mod:`tracker.classify`);
2. **segment** the hand's glove pixels, build the labeled point cloud
   (:mod:`tracker.point_cloud`) and the fit's view of the frame
   (:mod:`tracker.generative.observation`); too few glove pixels means "no hand";
3. **fit** the articulated hand by minimising the energy of
   :mod:`tracker.generative.fit` (data, silhouette with occlusion, posture prior,
   joint limits, collision, temporal and fingertip terms), starting from the previous
   frame's solution;
4. **look up** a second start in the database when there is no previous solution,
   when the fit from it fails the quality test, or every ``reinit_every`` frames:
   the tiny images of the hand's pixels give a posture and a rotation
   (:class:`glovedb.lookup.DatabaseIndex`, candidates re-ranked by their distance to
   the previous posture, :func:`temporal_scores`); the database's views look along
   the optical axis, so a hand seen off-axis is turned by ``R_ray``, the smallest
   rotation taking +z to the ray through the hand's pixels; the skinned model is
   placed there and aligned by color-sensitive ICP (:mod:`tracker.icp`); the fit
   from this start competes with the first: the lower energy wins (the periodic
   lookup of a tracked hand runs off the frame, :mod:`tracker.background`);
5. **check** the winner: a fit that pairs too few observed points with the model,
   shows model surface where the camera sees none, or lies too far from the points
   (``min_matched``, ``max_outside``, ``max_rms_m``) is "no hand", and the next frame
   starts from the lookup again: a wrong pose is never reported as found;
6. while the user's **hand proportions** are unknown, the first
   ``calibration_frames`` fits estimate them too (:mod:`glovedb.proportions`);
7. report keypoints with their visibility (:mod:`tracker.generative.visibility`),
   fingertips, a confidence (:func:`fit_quality`) and per-stage timings.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._closing import Closing
from glovedb._threads import single_threaded_blas
from glovedb._validate import as_array
from glovedb.camera import KINECT_V1, CameraIntrinsics
from glovedb.hand_model import (
    FINGERS,
    FINGERTIP_KEYPOINTS,
    N_JOINTS,
    forward_kinematics,
    make_skeleton,
)
from glovedb.lookup import DatabaseIndex, default_cascade
from glovedb.mesh import HandMesh, cached_hand_mesh, pose_mesh, vertex_normals
from glovedb.pattern import load_pattern, split_by_label
from glovedb.posture_prior import load_posture_prior, with_task_postures
from glovedb.proportions import HandProportions, proportioned_mesh
from glovedb.rasterize import model_label_image
from glovedb.rotations import axis_angle_to_matrix
from glovedb.search import InterpolatedPose, interpolate_pose, parse_cascade
from glovedb.tiny_images import tiny_images_from_pixels
from tracker.background import DeferredLookup, Job, carried_start
from tracker.classify import ColorTable, nominal_table
from tracker.frames import Frame
from tracker.generative.fit import FitSettings, FrameFit, fit_frame, fit_frame_steps
from tracker.generative.model import HandPose, HandSamples, PosedHand, hand_samples
from tracker.generative.observation import Observation, observe
from tracker.generative.visibility import keypoint_visibility
from tracker.icp import IcpResult, color_icp
from tracker.point_cloud import HandRegion, LabeledPointCloud, hand_region, labeled_point_cloud
from tracker.smoothing import PoseFilter, PoseFilterSettings

if TYPE_CHECKING:  # the fingertip detector loads only when a model is asked for
    from fingertips.detect import Detection
    from fingertips.detector import FingertipDetector

STAGES = (
    "classify", "segment", "fingertips", "lookup", "icp", "fit", "background", "total",
)  # fmt: skip
"""Per-frame ``timing_ms`` keys in pipeline order (``fingertips`` only with a fingertip
model, ``lookup`` and ``icp`` only in frames where the database offered a start within
the frame; ``background`` in the frames that run a step of a lookup deferred off its
frame, :mod:`tracker.background`). ``total`` is the frame's latency: preparation
(classify, segment) and tracking, the deferred step included."""


@dataclass(frozen=True)
class TrackerSettings:
    """How the tracker works; every field has a sensible default.

    Attributes
    ----------
    cascade : str or None
        Database lookup cascade (:func:`glovedb.search.parse_cascade`); None picks
        :func:`glovedb.lookup.default_cascade` for the database's sizes.
    z_range_m : (float, float)
        Working depth range; glove colors outside it are ignored.
    min_glove_pixels : int
        Fewer hand pixels than this means no hand.
    min_confidence : float
        A fit whose confidence (:func:`fit_confidence`, after the rigid ICP) is below
        this means no hand: glove-colored things that are not the glove (a red
        shirt, a blue sleeve) look up nothing close and fit nothing. Tracked glove
        frames of the synthetic sequences score 0.3 or more, such scenes below 1e-4.
    icp_iterations : int
    icp_stride : int
        Use every n-th point of the cloud in ICP (thesis Figure 4.11).
    icp_max_points : int
        And at most this many.
    smoothing : PoseFilterSettings or None
        Speed-adaptive (One Euro) filtering of the reported pose
        (:mod:`tracker.smoothing`); None reports the fit's pose unfiltered.
    frame_rate_hz : float
        Frame rate assumed for the smoothing when frames carry no timestamps.
    fit : FitSettings
        Weights and settings of the generative fit (:mod:`tracker.generative.fit`).
    reinit_every : int
        While tracking, the database lookup offers a second start every this many
        frames (and whenever the fit from the previous frame fails the quality test);
        the fit with the lower energy wins. 1 looks up every frame. The periodic
        lookups pause while the hand's proportions are estimated (``calibrating``):
        those fits cost more, and on Tr3 and Tr5 rendered with noise seed 7 the
        lookups at frames 10 and 20 changed the mean posture error by 0.00 and 0.01
        degrees.
    lookup_delay_frames : int
        The periodic lookups (``reinit_every``) of a tracked hand run off the frame,
        one step per frame (the lookup, the ICP, each iteration of the fit), and their
        fit is used this many frames later (:mod:`tracker.background`), which runs the
        steps still left: when it has the lower energy, that frame starts from its
        correction. 0 runs them within the frame, where their fit competes on that
        frame's energy (slower frames; on the synthetic sequences 0-0.06 deg less
        posture error). With 2 the collecting frame runs the ICP and the whole fit
        (8-12 ms); with a frame for every step (``lookup_fit_iterations + 2``) no frame
        runs more than one iteration of it (about 4 ms), but the correction comes
        later (fits of 4 iterations over 6 frames: Tr3 2.04 instead of 1.92 deg, Tr5
        1.77 instead of 1.72, Tr1 1.11 instead of 1.13; 3 frames cost the validation
        renders named under ``lookup_fit_iterations`` 0.04 deg, 0.974 against 0.936).
        The lookups that a failed or suspect fit asks for (``relook_outside``) always
        run within the frame.
    lookup_fit_iterations : int
        At most this many Levenberg-Marquardt iterations in the fit from a periodic
        lookup's start that runs off the frame (``lookup_delay_frames``; the other
        fits take ``fit.iterations``, 4). That fit only offers a second start: when it
        wins, the warm fits of the frames after it go on from it. Its last iterations
        ran in the collecting frame and set the 99th percentile of the latency. Chosen
        on the validation renders (Tr1-Tr5 with noise seed 7, Tr3-Tr5 with seed 8;
        mean posture error): 4 iterations 0.936 deg, 3 0.934, 2 0.943; on Tr3
        (``glove bench track``'s sequence) the 99th percentile of those steps fell from
        12.7 to 9.2 ms.
    relook_outside : float
        The lookup also offers a second start when the warm fit leaves this share
        more of its model surface outside the observed hand than usual (the running
        mean over the last frames, which a misregistered camera raises): a sign that
        fingers went where the warm start cannot follow (curling out of sight behind
        the palm).
    min_matched : float
        A fit that pairs fewer of the observed glove points with the model surface
        of their color (within ``fit.data_gate_m``) is not trusted: no hand.
    max_outside : float
        Nor one whose camera-facing model surface lies outside the observed hand
        (and is not hidden by something in front) by more than this share.
    max_rms_m : float
        Nor one whose paired points lie farther from the model surface (RMS, metres).
    min_fit_confidence : float
        Nor one whose confidence (:func:`fit_quality`) is lower. Chosen on the
        synthetic sequences: tracked frames score 0.49 or more (Tr1, Tr3, other hand
        sizes, a ball in front, 3 px misregistration); a hand fitted into a wrong
        local minimum while a ball hid 45 % of it, 0.37.
    min_start_confidence : float
        What a fit must score when there is no previous frame (the first frame,
        after a loss): a start has no history behind it, and while an object hides
        much of the hand the lookup's start can reach a wrong minimum that passes
        ``min_fit_confidence`` (0.45, 13 degrees off, as a 4 cm ball left the
        fingers). Chosen on the synthetic sequences: their starts score 0.62 or
        more.
    hand_proportions : HandProportions or None
        The user's hand proportions (:mod:`glovedb.proportions`); None (the default)
        estimates them online over the first ``calibration_frames`` tracked frames
        and then keeps them.
    calibration_frames : int
        Fits that estimate the proportions (0: keep the model's).
    calibration_iterations : int
        At most this many Levenberg-Marquardt iterations in those fits (the others
        take ``fit.iterations``, 4). The proportions' seven extra unknowns made a
        calibrating fit cost twice a plain one (17 against 8.5 ms with 6 iterations
        each); with 3 it costs 9.8 ms, and the 30 calibrating frames no longer stand
        out in the latency. Chosen on Tr3 and Tr5 rendered with noise seed 7 and
        checked on the renders of the dim cluttered room, free finger motion and the
        0.17 m and longer-fingered hands: the proportions came out the same to three
        decimals and the mean posture errors within 0.01 degrees.
    lookup_candidates : int
        Entries the cascade's last stage keeps for the temporal re-ranking (at least
        its own k are blended).
    temporal_prior_px : float
        Matching error (pixels at the last stage's size) added per radian of mean
        absolute joint-angle difference between a candidate's posture and the
        previous frame's; 0 turns the re-ranking off.
    fingertip_model : str or None
        A fingertip model (``.npz``, :mod:`fingertips.forest`), or
        ``"default"`` for the shipped one: its detections take part in the
        generative fit. None (the default) detects no fingertips.
    mesh_spacing_m : float
        Resolution of the model's mesh (ICP and the generative fit's samples).
    workers : int or None
        Search threads (None: all cores).
    """

    cascade: str | None = None
    z_range_m: tuple[float, float] = (0.2, 1.5)
    min_glove_pixels: int = 150
    min_confidence: float = 0.02
    icp_iterations: int = 25
    icp_stride: int = 1
    icp_max_points: int = 500
    smoothing: PoseFilterSettings | None = field(default_factory=PoseFilterSettings)
    frame_rate_hz: float = 30.0
    mesh_spacing_m: float = 0.003
    fit: FitSettings = field(default_factory=FitSettings)
    reinit_every: int = 10
    lookup_delay_frames: int = 2
    lookup_fit_iterations: int = 3
    relook_outside: float = 0.03
    min_matched: float = 0.6
    max_outside: float = 0.3
    max_rms_m: float = 0.008
    min_fit_confidence: float = 0.4
    min_start_confidence: float = 0.55
    hand_proportions: HandProportions | None = None
    calibration_frames: int = 30
    calibration_iterations: int = 3
    lookup_candidates: int = 10
    temporal_prior_px: float = 1.0
    fingertip_model: str | None = None
    workers: int | None = None

    def __post_init__(self) -> None:
        if not self.frame_rate_hz > 0:
            raise ValueError(f"frame_rate_hz: expected > 0, got {self.frame_rate_hz}")
        if self.reinit_every < 1:
            raise ValueError(f"reinit_every: expected >= 1, got {self.reinit_every}")
        if self.lookup_delay_frames < 0:
            raise ValueError(f"lookup_delay_frames: expected >= 0, got {self.lookup_delay_frames}")
        if self.calibration_frames < 0:
            raise ValueError(f"calibration_frames: expected >= 0, got {self.calibration_frames}")
        if self.lookup_fit_iterations < 1:
            raise ValueError(
                f"lookup_fit_iterations: expected >= 1, got {self.lookup_fit_iterations}"
            )
        if self.calibration_iterations < 1:
            raise ValueError(
                f"calibration_iterations: expected >= 1, got {self.calibration_iterations}"
            )
        names = ("min_matched", "max_outside", "min_fit_confidence", "min_start_confidence")
        for name in (*names, "relook_outside"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name}: expected 0 to 1, got {getattr(self, name)}")


def fit_confidence(lookup_error_px: float, icp: IcpResult) -> float:
    """How much a frame's fit can be trusted, in [0, 1].

    A good lookup (a pixel or two of matching error at the cascade's last stage) and a
    tight, well-supported rigid fit (a residual of millimetres, most points kept):
    ``exp(-error / 4 px) * exp(-cost / 1 cm) * min(1, inliers / 0.8)``.

    Parameters
    ----------
    lookup_error_px : float
        Matching error of the best database entry at the last stage.
    icp : IcpResult
        Its ``cost_m`` (RMS residual, metres) and ``inlier_fraction``.

    Returns
    -------
    float
    """
    return float(
        np.exp(-lookup_error_px / 4.0)
        * np.exp(-icp.cost_m / 0.01)
        * min(1.0, icp.inlier_fraction / 0.8)
    )


@dataclass(frozen=True)
class TrackingResult:
    """What the tracker says about one frame (docs/conventions.md "Tracking output").

    Pose fields are ``None`` when ``hand_found`` is false. ``fingertips`` are the
    fitted model's; ``fingertip_detections`` are the depth detections the refinement
    used (named by Eq. 11 where assigned), None when the tracker has no fingertip
    model or found no hand (the detector runs after the glove fit).
    """

    frame: int
    hand_found: bool
    posture_rad: NDArray[np.float64] | None = None
    rotation: NDArray[np.float64] | None = None
    translation_m: NDArray[np.float64] | None = None
    keypoints_3d_m: NDArray[np.float64] | None = None
    keypoints_2d_px: NDArray[np.float64] | None = None
    fingertips: tuple[dict[str, Any], ...] = ()
    confidence: float = 0.0
    timing_ms: dict[str, float] = field(default_factory=dict)
    fingertip_detections: tuple[Detection, ...] | None = None
    keypoint_visibility: tuple[str, ...] = ()
    timestamp_s: float | None = None

    def as_record(self) -> dict[str, Any]:
        """The ``poses.jsonl`` object of this frame."""
        record: dict[str, Any] = {
            "frame": self.frame,
            "timestamp_s": None if self.timestamp_s is None else round(self.timestamp_s, 6),
            "hand_found": self.hand_found,
        }
        if self.hand_found:
            assert self.posture_rad is not None and self.rotation is not None
            assert self.translation_m is not None and self.keypoints_3d_m is not None
            assert self.keypoints_2d_px is not None
            record.update(
                posture_rad=_rounded(self.posture_rad, 6),
                rotation=_rounded(self.rotation, 6),
                translation_m=_rounded(self.translation_m, 5),
                keypoints_3d_m=_rounded(self.keypoints_3d_m, 5),
                keypoints_2d_px=_rounded(self.keypoints_2d_px, 2),
                fingertips=list(self.fingertips),
                confidence=round(self.confidence, 4),
                keypoint_visibility=list(self.keypoint_visibility),
            )
            if self.fingertip_detections is not None:
                from fingertips.detect import fingertips_output

                record["fingertip_detections"] = fingertips_output(self.fingertip_detections)
        record["timing_ms"] = {k: round(v, 3) for k, v in self.timing_ms.items()}
        return record


@dataclass(frozen=True)
class PreparedFrame:
    """A frame with the work that needs no tracking state done
    (:meth:`Tracker.prepare`).

    Attributes
    ----------
    frame : Frame
    region : HandRegion
        The hand's glove pixels.
    cloud : LabeledPointCloud
        Their points.
    observation : Observation or None
        The fit's view of the frame; None when it shows too little glove for a hand.
    timing_ms : dict of str to float
        ``classify`` and ``segment`` milliseconds.
    """

    frame: Frame
    region: HandRegion
    cloud: LabeledPointCloud
    observation: Observation | None
    timing_ms: dict[str, float]


class Tracker(Closing):
    """Tracks the glove hand frame after frame with one posture database.

    Parameters
    ----------
    database : str or Path
        A posture database file.
    settings : TrackerSettings, optional
    color_table : ColorTable, optional
        Defaults to the table from the glove pattern's nominal colors.

    Attributes
    ----------
    skeleton : Skeleton
        The hand model's skeleton with the current proportions (the user's once
        estimated); :attr:`mesh` is its mesh.

    Notes
    -----
    While a tracker is open, BLAS runs on one thread in this process
    (:func:`glovedb._threads.single_threaded_blas`); :meth:`close` restores it.
    """

    def __init__(
        self,
        database: str | Path,
        *,
        settings: TrackerSettings | None = None,
        color_table: ColorTable | None = None,
    ) -> None:
        self.settings = settings or TrackerSettings()
        self.fingertips = _fingertip_detector(self.settings.fingertip_model)
        self.index = DatabaseIndex(database)
        pattern = load_pattern()
        self.color_table = color_table or nominal_table(pattern)
        self.model_mesh = cached_hand_mesh(
            make_skeleton(self.index.hand_length_m), spacing_m=self.settings.mesh_spacing_m
        )
        self.split = split_by_label(self.model_mesh, pattern)
        self.prior = load_posture_prior()
        fit = self.settings.fit
        if fit.task_prior_spread > 0:
            task = with_task_postures(
                self.prior,
                self.index.postures_rad,
                spread=fit.task_prior_spread,
                offset=fit.task_prior_offset,
            )
            if len(task.task_postures_rad) <= fit.task_prior_max_postures:
                self.prior = task
        self._model_samples = hand_samples(
            self.model_mesh, self.split, spacing=self.settings.fit.sample_spacing
        )
        self._mesh: HandMesh | None = None
        self._set_proportions(self.settings.hand_proportions or HandProportions())
        self._proportion_information: NDArray[np.float64] | None = None
        self._calibrated = (
            0 if self.settings.hand_proportions is None else self.settings.calibration_frames
        )
        self._smoother = PoseFilter(self.settings.smoothing) if self.settings.smoothing else None
        self._last_time_s: float | None = None
        self._sizes = self.index.resolutions
        self.cascade = self.settings.cascade or default_cascade(self._sizes)
        stages = parse_cascade(self.cascade, sizes=self._sizes)  # a bad cascade fails here
        self._blend = stages[-1].k
        wide = max(self._blend, self.settings.lookup_candidates)
        self._search_cascade = ",".join(
            f"{stage.size}:{max(stage.k, wide)}" for stage in stages
        )  # every stage keeps at least as many as the widened last one
        parse_cascade(self._search_cascade, sizes=self._sizes)
        self._previous_posture: NDArray[np.float64] | None = None
        self._previous: PosedHand | None = None
        self._since_lookup = 0
        self._frame_index = 0
        self._background: DeferredLookup[FrameFit, FrameFit | None] | None = (
            DeferredLookup(self.settings.lookup_delay_frames)
            if self.settings.lookup_delay_frames > 0
            else None
        )
        # Running mean of the accepted fits' outside share (kept by reset: it belongs
        # to the camera's registration more than to the sequence).
        self._outside_level = 0.0
        # One BLAS thread while this tracker lives (see glovedb._threads); set last,
        # so that a tracker that fails to open leaves the process as it was.
        self._blas_limit = single_threaded_blas()
        self._warm_up()

    @property
    def proportions(self) -> HandProportions:
        """The hand proportions in use (the estimate so far while calibrating)."""
        return self.samples.proportions

    @property
    def calibrating(self) -> bool:
        """Whether the hand proportions are still being estimated."""
        return self._calibrated < self.settings.calibration_frames

    @property
    def mesh(self) -> HandMesh:
        """The hand model's mesh with the current proportions, re-rested when first
        asked for after they changed: while they are estimated, each frame changes them
        and few frames need the mesh (a lookup's ICP, the overlay), and re-resting its
        vertices cost 0.7 ms."""
        if self._mesh is None:
            self._mesh = proportioned_mesh(self.model_mesh, self.proportions)
        return self._mesh

    def _set_proportions(self, proportions: HandProportions) -> None:
        self._set_samples(self._model_samples.with_proportions(proportions))

    def _set_samples(self, samples: HandSamples) -> None:
        self.samples = samples
        self.skeleton = samples.skeleton
        self._mesh = None

    def _warm_up(self) -> None:
        """Run the compiled kernels once, so the first frames are not slow (numba loads
        or compiles them on first use): the search, then the ICP, the fit and the
        visibility test on the model's own label image seen at half a metre. Without the
        second part the first frame took 70-80 ms instead of about 30; the first pose
        comes no later, since that time is spent here instead."""
        square = np.stack(np.meshgrid(np.arange(8.0), np.arange(8.0)), -1).reshape(-1, 2)
        stacks = tiny_images_from_pixels(square, np.ones(len(square), np.uint8), self._sizes)
        self.index.search({size: stack[0] for size, stack in stacks.items()}, self._search_cascade)
        vertex_normals(self.model_mesh.rest_vertices_m, self.model_mesh.faces)
        pose = HandPose(np.zeros(N_JOINTS), np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 0.5]))
        labels, depth = model_label_image(
            self.mesh, self.split, pose.posture_rad, pose.rotation, pose.translation_m, KINECT_V1
        )
        color = np.zeros((*labels.shape, 3), np.uint8)
        prepared = self._segmented(Frame(-1, color, depth, KINECT_V1), labels, {})
        if prepared.observation is None:  # settings that ask for more glove than that
            return
        looked_up = InterpolatedPose(pose.posture_rad, pose.rotation, np.ones(1), True)
        self._aligned_start(prepared, looked_up, 0.0, self.mesh)
        # The first frame's fit (from a lookup's start, estimating the proportions
        # unless they are given), one iteration, started off the observed hand so that
        # every term has rows. Kernels only later frames use load there: loading them
        # here would delay the first pose.
        start = HandPose(pose.posture_rad + 0.2, pose.rotation, pose.translation_m + 0.01)
        settings = replace(self.settings.fit, iterations=1)
        fitted = fit_frame(
            self.samples, prepared.observation, start, settings=settings, prior=self.prior,
            estimate_proportions=self.calibrating,
        )  # fmt: skip
        frame = prepared.frame
        keypoint_visibility(
            fitted.hand, frame.depth_m, frame.intrinsics.pinhole,
            margin_m=self.settings.fit.depth_margin_m,
        )  # fmt: skip

    def prepare(self, frame: Frame) -> PreparedFrame:
        """Classify and segment ``frame`` (steps 1-2 of the module docstring).

        Needs no earlier frame, so a reader can prepare the next frames while
        one is tracked (:func:`tracker.run.track_source`).
        """
        clock = time.perf_counter()
        labels = self.color_table.classify(frame.color)
        classified = {"classify": (time.perf_counter() - clock) * 1000.0}
        return self._segmented(frame, labels, classified)

    def _segmented(
        self, frame: Frame, labels: NDArray[np.uint8], timing: dict[str, float]
    ) -> PreparedFrame:
        """:meth:`prepare` of a frame already classified into ``labels``."""
        now = time.perf_counter()
        region = hand_region(labels, frame.depth_m, z_range_m=self.settings.z_range_m)
        cloud = labeled_point_cloud(region, frame.intrinsics)
        observation = None
        if len(region) >= self.settings.min_glove_pixels and len(cloud) >= 30:
            observation = observe(
                region, cloud, frame.depth_m, frame.intrinsics,
                max_points=self.settings.fit.max_points,
            )  # fmt: skip
        timing["segment"] = (time.perf_counter() - now) * 1000.0
        return PreparedFrame(frame, region, cloud, observation, timing)

    def track(self, frame: Frame | PreparedFrame) -> TrackingResult:
        """Estimate the hand in one frame (see the module docstring); ``frame`` may
        come prepared (:meth:`prepare`)."""
        prepared = frame if isinstance(frame, PreparedFrame) else self.prepare(frame)
        frame = prepared.frame
        timing = dict(prepared.timing_ms)
        started = clock = time.perf_counter()
        self._frame_index += 1

        def lap(stage: str) -> None:
            nonlocal clock
            now = time.perf_counter()
            timing[stage] = timing.get(stage, 0.0) + (now - clock) * 1000.0
            clock = now

        observation = prepared.observation
        if observation is None:
            return self._not_found(prepared, timing, started)
        warm = None if self._previous is None else self._previous.pose
        start = warm
        if warm is not None and self._background is not None:
            collected = self._background.collect(self._frame_index)
            if collected is not None:
                warm_fit, background_fit = collected
                lap("background")
                if (
                    background_fit is not None
                    and self._trusted(background_fit)
                    and background_fit.energy < warm_fit.energy
                ):
                    start = carried_start(background_fit.pose, warm_fit.pose, warm)
        detections, tip_targets = None, None
        fits: list[FrameFit] = []
        if warm is not None and start is not None:
            if self.fingertips is not None:
                detections = self._named_detections(frame, warm)
                tip_targets = tip_targets_of(detections)
                lap("fingertips")
            # The warm pose, or it corrected by a background lookup: both hold unseen
            # fingers.
            fits.append(self._fit(observation, start, tip_targets, warm=True))
            lap("fit")
        self._since_lookup += 1
        # Not while calibrating: those fits cost more than others, and a deferred
        # lookup's steps on top of them set the latency's 99th percentile.
        periodic = self._since_lookup >= self.settings.reinit_every and not self.calibrating
        suspect = bool(fits) and (
            not self._trusted(fits[0])
            or fits[0].outside > self._outside_level + self.settings.relook_outside
        )
        if not fits or suspect or periodic:
            self._since_lookup = 0
            if not suspect and fits and self._background is not None:
                if not self._background.busy:
                    job = self._background_job(prepared, tip_targets)
                    self._background.submit(self._frame_index, fits[0], job)
            else:
                if self._background is not None:
                    self._background.discard()
                looked_up = self._lookup_start(
                    prepared, lap, previous_posture=self._previous_posture, mesh=self.mesh
                )
                if looked_up is not None:
                    if self.fingertips is not None and detections is None:
                        detections = self._named_detections(frame, looked_up)
                        tip_targets = tip_targets_of(detections)
                        lap("fingertips")
                    fits.append(self._fit(observation, looked_up, tip_targets))
                    lap("fit")
        if self._background is not None and self._background.advance() > 0.0:
            lap("background")
        trusted = [fit for fit in fits if self._trusted(fit, starting=warm is None)]
        if not trusted:
            return self._not_found(prepared, timing, started)
        best = min(trusted, key=lambda fit: fit.energy)
        if self.calibrating and best.proportion_information is not None:
            # The fit's last samples are the model's re-rested with these proportions
            # (and keep what was computed on them: rest transforms, finger cones).
            self._set_samples(best.hand.samples)
            self._proportion_information = best.proportion_information
            self._calibrated += 1
        hand = best.hand
        self._previous = hand
        self._outside_level += 0.1 * (best.outside - self._outside_level)
        posture, rotation, translation = (
            best.pose.posture_rad,
            best.pose.rotation,
            best.pose.translation_m,
        )
        if self._smoother is not None:
            posture, rotation, translation = self._smoother(
                posture, rotation, translation, self._frame_interval(frame)
            )
        self._previous_posture = posture
        confidence = fit_quality(best.matched, best.outside, best.rms_m)
        result = self._result(frame, posture, rotation, translation, confidence)
        result["keypoint_visibility"] = keypoint_visibility(
            hand, frame.depth_m, frame.intrinsics.pinhole,
            margin_m=self.settings.fit.depth_margin_m,
        )  # fmt: skip
        lap("fit")
        timing["total"] = _latency_ms(prepared, started)
        return TrackingResult(
            **result, timestamp_s=frame.timestamp_s, timing_ms=timing,
            fingertip_detections=detections,
        )  # fmt: skip

    def run_deferred_step(self) -> float:
        """Run one step of the pending periodic lookup (:mod:`tracker.background`), if
        it has steps left; the milliseconds it took, 0 when none ran.

        For a caller that would otherwise wait for its next frame (a reader still
        decoding it): the frame that collects the lookup's fit then finds it done
        instead of running its steps. The poses are the same (the job's inputs were
        fixed when it was submitted); only where its time goes changes.
        """
        if self._background is None or not self._background.has_steps:
            return 0.0
        return self._background.advance()

    def reset(self) -> None:
        """Forget the past frames (start of a new sequence); keep the proportions."""
        if self._smoother is not None:
            self._smoother.reset()
        if self._background is not None:
            self._background.discard()
        self._last_time_s = None
        self._previous_posture = None
        self._previous = None
        self._since_lookup = 0

    def _frame_interval(self, frame: Frame) -> float:
        """Seconds since the last tracked frame: from the timestamps when the source
        gives them, else one period of ``frame_rate_hz``."""
        period = 1.0 / self.settings.frame_rate_hz
        now, last = frame.timestamp_s, self._last_time_s
        self._last_time_s = now
        if now is None or last is None or not now > last:
            return period
        return min(now - last, 10 * period)

    def _trusted(self, fit: FrameFit, *, starting: bool = False) -> bool:
        """Whether a fit explains the observed hand well enough to report it."""
        return fit_trusted(fit.matched, fit.outside, fit.rms_m, self.settings, starting=starting)

    def _fit(
        self,
        observation: Observation,
        start: HandPose,
        tip_targets: NDArray[np.float64] | None,
        *,
        warm: bool = False,
    ) -> FrameFit:
        """Fit the frame from ``start``; ``warm``: the start is the previous frame's
        solution, corrected or not (the fit then holds the fingers the camera does not
        see)."""
        previous = None if self._previous is None else self._previous.keypoints_m
        settings = self.settings.fit
        if self.calibrating:
            iterations = min(settings.iterations, self.settings.calibration_iterations)
            settings = replace(settings, iterations=iterations)
        return fit_frame(
            self.samples, observation, start, settings=settings, prior=self.prior,
            previous_keypoints_m=previous, tip_targets_m=tip_targets,
            estimate_proportions=self.calibrating,
            proportion_information=self._proportion_information, hold_unseen=warm,
        )  # fmt: skip

    def _background_job(
        self, prepared: PreparedFrame, tip_targets: NDArray[np.float64] | None
    ) -> Job[FrameFit | None]:
        """The lookup, ICP and fit of ``prepared`` as a deferred job in steps (the
        lookup, the ICP, each of the fit's iterations; :mod:`tracker.background`): it
        reads what it needs of the tracker's state now (the state moves on while it
        runs) and returns the fit, None when the lookup found no start."""
        assert prepared.observation is not None
        observation = prepared.observation
        previous_posture, mesh, samples = self._previous_posture, self.mesh, self.samples
        previous = None if self._previous is None else self._previous.keypoints_m
        iterations = min(self.settings.fit.iterations, self.settings.lookup_fit_iterations)
        settings = replace(self.settings.fit, iterations=iterations)

        def job() -> Job[FrameFit | None]:
            looked_up = self._database_pose(prepared, previous_posture=previous_posture)
            yield
            start = None if looked_up is None else self._aligned_start(prepared, *looked_up, mesh)
            if start is None:
                return None
            yield
            return (
                yield from fit_frame_steps(
                    samples, observation, start, settings=settings, prior=self.prior,
                    previous_keypoints_m=previous, tip_targets_m=tip_targets,
                )
            )  # fmt: skip

        return job()

    def _lookup_start(
        self,
        prepared: PreparedFrame,
        lap: Callable[[str], None],
        *,
        previous_posture: NDArray[np.float64] | None,
        mesh: HandMesh,
    ) -> HandPose | None:
        """The database's posture and rotation, aligned by color ICP; None when the
        lookup or the alignment finds nothing glove-like (:func:`fit_confidence`).

        Reads no tracker state that changes between frames (a deferred job runs it in
        two steps): the previous frame's posture (temporal re-ranking) and the hand
        mesh (ICP) come as arguments.
        """
        looked_up = self._database_pose(prepared, previous_posture=previous_posture)
        lap("lookup")
        if looked_up is None:
            return None
        start = self._aligned_start(prepared, *looked_up, mesh)
        lap("icp")
        return start

    def _database_pose(
        self, prepared: PreparedFrame, *, previous_posture: NDArray[np.float64] | None
    ) -> tuple[InterpolatedPose, float] | None:
        """The database's blended posture and rotation for the frame's hand pixels and
        the best candidate's chamfer error; None when they hold no hand."""
        region = prepared.region
        stacks = tiny_images_from_pixels(
            region.pixels_uv.astype(np.float64), region.labels, self._sizes
        )
        query = {size: stack[0] for size, stack in stacks.items()}
        if not all(image.any() for image in query.values()):
            # Glove-colored pixels too scattered to be a hand (noise in a dark room):
            # no tiny image keeps a glove cell.
            return None
        search = self.index.search(query, self._search_cascade, workers=self.settings.workers)
        candidate_postures = self.index.entry_postures(search.entry_ids)
        scores = temporal_scores(
            search.errors,
            candidate_postures,
            previous_posture,
            self.settings.temporal_prior_px,
        )
        order = np.argsort(scores, kind="stable")[: self._blend]
        pose = interpolate_pose(
            scores[order],
            candidate_postures[order],
            self.index.entry_rotations(search.entry_ids[order]),
        )
        if not pose.valid:
            return None
        return pose, float(search.errors[order[0]])

    def _aligned_start(
        self, prepared: PreparedFrame, pose: InterpolatedPose, error: float, mesh: HandMesh
    ) -> HandPose | None:
        """The looked-up ``pose`` placed on the frame's ray and aligned by color ICP;
        None when the alignment finds nothing glove-like (:func:`fit_confidence` of it
        and the lookup's chamfer ``error``)."""
        frame, region, cloud = prepared.frame, prepared.region, prepared.cloud
        posture = pose.posture_rad
        centre_px = region.pixels_uv.mean(axis=0)
        rotation = _ray_rotation(frame.intrinsics, centre_px) @ pose.rotation
        surface = pose_mesh(mesh, posture)
        normals = vertex_normals(surface, mesh.faces)
        model, model_normals = surface[self.split.source_vertex], normals[self.split.source_vertex]
        translation = self._initial_translation(cloud.points_m, model, model_normals, rotation)
        points = cloud.subsample(self.settings.icp_stride)
        step = max(1, len(points) // self.settings.icp_max_points)
        icp = color_icp(
            points.points_m[::step],
            points.labels[::step],
            model,
            model_normals,
            self.split.labels,
            rotation,
            translation,
            iterations=self.settings.icp_iterations,
        )
        if fit_confidence(error, icp) < self.settings.min_confidence:
            return None
        return HandPose(posture, icp.rotation, icp.translation_m)

    def _named_detections(self, frame: Frame, pose: HandPose) -> tuple[Detection, ...]:
        """Fingertips detected in the frame's depth, named by Eq. 11 against the
        fingertips of the model at ``pose``."""
        assert self.fingertips is not None
        tips = self._posed_keypoints(pose.posture_rad, pose.rotation, pose.translation_m)
        return self.fingertips.detect(
            frame.depth_m, frame.intrinsics.pinhole, model_tips_m=tips[list(FINGERTIP_KEYPOINTS)]
        )

    def _posed_keypoints(
        self,
        posture: NDArray[np.float64],
        rotation: NDArray[np.float64],
        translation: NDArray[np.float64],
    ) -> NDArray[np.float64]:
        """``(21, 3)`` keypoints of the hand model in ``posture`` at the pose, camera frame."""
        return forward_kinematics(posture, self.skeleton).keypoints_m[0] @ rotation.T + translation

    def _initial_translation(
        self,
        cloud_m: NDArray[np.float32],
        model: NDArray[np.float64],
        normals: NDArray[np.float64],
        rotation: NDArray[np.float64],
    ) -> NDArray[np.float64]:
        """Put the centroid of the model's visible side on the cloud's centroid."""
        centroid = cloud_m.mean(axis=0).astype(np.float64)
        viewing = centroid / np.linalg.norm(centroid)
        facing = (normals @ rotation.T) @ viewing < 0
        visible = model[facing] if facing.any() else model
        return centroid - rotation @ visible.mean(axis=0)

    def _result(
        self,
        frame: Frame,
        posture: NDArray[np.float64],
        rotation: NDArray[np.float64],
        translation: NDArray[np.float64],
        confidence: float,
    ) -> dict[str, Any]:
        keypoints = self._posed_keypoints(posture, rotation, translation)
        pixels = frame.intrinsics.project(keypoints)
        fingertips = tuple(
            {
                "finger": finger,
                "u_px": round(float(pixels[tip, 0]), 2),
                "v_px": round(float(pixels[tip, 1]), 2),
                "x_m": round(float(keypoints[tip, 0]), 5),
                "y_m": round(float(keypoints[tip, 1]), 5),
                "z_m": round(float(keypoints[tip, 2]), 5),
                "confidence": round(confidence, 4),
            }
            for finger, tip in zip(FINGERS, FINGERTIP_KEYPOINTS, strict=True)
        )
        return {
            "frame": frame.index,
            "hand_found": True,
            "posture_rad": posture,
            "rotation": rotation,
            "translation_m": translation,
            "keypoints_3d_m": keypoints,
            "keypoints_2d_px": pixels,
            "fingertips": fingertips,
            "confidence": confidence,
        }

    def _not_found(
        self, prepared: PreparedFrame, timing: dict[str, float], started: float
    ) -> TrackingResult:
        self.reset()
        timing["total"] = _latency_ms(prepared, started)
        frame = prepared.frame
        return TrackingResult(
            frame=frame.index, hand_found=False, timestamp_s=frame.timestamp_s, timing_ms=timing
        )

    def close(self) -> None:
        if self._background is not None:
            self._background.discard()
        self.index.close()
        self._blas_limit.restore_original_limits()


def _latency_ms(prepared: PreparedFrame, started: float) -> float:
    """Milliseconds of a frame's preparation and of its tracking since ``started``."""
    return sum(prepared.timing_ms.values()) + (time.perf_counter() - started) * 1000.0


def fit_trusted(
    matched: float, outside: float, rms_m: float, settings: TrackerSettings, *, starting: bool
) -> bool:
    """The quality test of a fit (``min_matched``, ``max_outside``, ``max_rms_m`` and
    the confidence of :func:`fit_quality`: ``min_start_confidence`` when ``starting``,
    without a previous frame, else ``min_fit_confidence``)."""
    s = settings
    least = s.min_start_confidence if starting else s.min_fit_confidence
    return (
        matched >= s.min_matched
        and outside <= s.max_outside
        and rms_m <= s.max_rms_m
        and fit_quality(matched, outside, rms_m) >= least
    )


def fit_quality(matched: float, outside: float, rms_m: float) -> float:
    """Confidence in [0, 1] of a generative fit: the share of the observed glove points
    it explains, times the share of its visible surface the camera sees, times
    ``exp(-rms / 5 mm)`` of the paired points' distance to the surface."""
    return float(max(0.0, matched) * max(0.0, 1.0 - outside) * np.exp(-rms_m / 0.005))


def temporal_scores(
    errors: ArrayLike,
    postures_rad: ArrayLike,
    previous_rad: ArrayLike | None,
    prior_px_per_rad: float,
) -> NDArray[np.float64]:
    """Matching errors plus a pull toward the previous frame's posture.

    The tracker ranks the lookup's candidates by these scores and blends the best
    with weights from them (:func:`glovedb.search.interpolate_pose`).

    Parameters
    ----------
    errors : (k,) float
        Matching errors of the candidates, pixels (``inf``: never preferred).
    postures_rad : (k, 20) float
        Their postures.
    previous_rad : (20,) float or None
        The previous frame's posture; None ranks by error alone.
    prior_px_per_rad : float
        Pixels of error per radian of mean absolute joint-angle difference.

    Returns
    -------
    (k,) float64
        ``error + prior_px_per_rad * mean(|posture - previous|)``, pixels; the errors
        alone without a previous posture.
    """
    error = as_array("errors", errors, (None,), np.float64, kind="fiu")
    postures = as_array("postures_rad", postures_rad, (len(error), N_JOINTS), np.float64)
    if not prior_px_per_rad >= 0:
        raise ValueError(f"prior_px_per_rad: must be 0 or more, got {prior_px_per_rad}")
    if previous_rad is None or prior_px_per_rad == 0:
        return error
    previous = as_array("previous_rad", previous_rad, (N_JOINTS,), np.float64)
    return error + prior_px_per_rad * np.abs(postures - previous).mean(axis=1)


def tip_targets_of(detections: Sequence[Detection]) -> NDArray[np.float64]:
    """The refinement's fingertip targets from named detections.

    Parameters
    ----------
    detections : sequence of Detection
        With ``finger`` set by :func:`fingertips.detect.name_fingers` (Eq. 11
        names each finger at most once) or None.

    Returns
    -------
    (5, 3) float64
        Camera-frame position of each finger's detection, thumb first, metres; NaN
        rows for fingers without one.
    """
    from fingertips.detect import detection_points

    targets = np.full((len(FINGERS), 3), np.nan)
    named = [d for d in detections if d.finger is not None]
    targets[[FINGERS.index(str(d.finger)) for d in named]] = detection_points(named)
    return targets


def _fingertip_detector(model: str | None) -> FingertipDetector | None:
    """The fingertip detector of ``TrackerSettings.fingertip_model`` (None: none)."""
    if model is None:
        return None
    from fingertips.detector import FingertipDetector

    return FingertipDetector(None if model == "default" else model)


def _ray_rotation(intrinsics: CameraIntrinsics, pixel: NDArray[np.float64]) -> NDArray[np.float64]:
    """Smallest rotation taking the optical axis (+z) to the ray through ``pixel``."""
    ray = intrinsics.back_project(pixel, 1.0)
    ray /= np.linalg.norm(ray)
    axis = np.cross([0.0, 0.0, 1.0], ray)
    angle = np.arccos(np.clip(ray[2], -1.0, 1.0))
    return axis_angle_to_matrix(axis, angle)


def _rounded(array: NDArray, digits: int) -> list:
    return np.round(np.asarray(array, dtype=np.float64), digits).tolist()
