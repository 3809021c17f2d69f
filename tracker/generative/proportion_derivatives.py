"""Derivatives of the posed samples by the hand proportions, per sample on demand.

While a user's proportions are estimated, the fit's data and silhouette rows also need
each sample's derivative by the 7 proportions
(:meth:`glovedb.proportions.HandProportions.as_vector`). They are forward differences
(backward for a factor at the top of its range, which a step up would leave): the
samples of the hand with the proportions and with each one stepped, re-rested and
skinned as :func:`~glovedb.proportions.proportioned_mesh` and
:func:`~glovedb.mesh.skin` would. Per bone only the 3 x 4 re-resting and posing maps
differ between the eight hands, so they are computed once (the eight skeletons'
kinematics) and each sample blends them over its weighted bones in a compiled loop
(:func:`tracker.generative._kernels.proportion_differences`).

They change little over one frame's solve, so the fit computes them at its start and
uses them at every iteration; and a frame's terms ask for about a quarter of the
samples (those facing the camera and paired with an observed point, or on the
silhouette's edge: 840-970 of the default mesh's 3,771 on the calibrating frames of
the rendered Tr3 sequence), so each sample's derivatives are computed when first
asked for and kept. A sample's values do not depend on which others are computed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb.hand_model import N_JOINTS, Skeleton, bone_transforms_per_skeleton
from glovedb.proportions import (
    FACTOR_RANGE,
    N_PROPORTIONS,
    HandProportions,
    bone_stretch,
    proportioned_skeleton,
)
from tracker.generative import _kernels

PROPORTION_STEP = 1e-3
"""Forward-difference step of every proportion factor."""


class ProportionDerivatives:
    """``(3, 7)`` derivatives of each sample (camera frame) by the proportions, at one
    pose, computed for a sample when first asked for.

    Parameters
    ----------
    bones, bone_weights : (S, B) int64, float64
        Each sample's weighted bones (-1 padded) and their weights
        (``HandSamples._bone_lists``).
    model_rest_m : (S, 3) float
        The samples at rest on the model's skeleton.
    model_skeleton : Skeleton
    model_rest_inverse : (16, 4, 4) float
        Inverse bone transforms at rest of the model's skeleton.
    proportions : HandProportions
        Those of the hand whose derivatives these are.
    posture_rad : (20,) float
    rotation : (3, 3) float
        The hand's rotation (camera frame).
    """

    def __init__(
        self,
        bones: NDArray[np.int64],
        bone_weights: NDArray[np.float64],
        model_rest_m: NDArray[np.float64],
        model_skeleton: Skeleton,
        model_rest_inverse: NDArray[np.float64],
        proportions: HandProportions,
        posture_rad: NDArray[np.float64],
        rotation: NDArray[np.float64],
    ) -> None:
        base = proportions.as_vector()
        # A factor at the top of its range is stepped down (a backward difference).
        self.steps = (
            np.where(base + PROPORTION_STEP <= FACTOR_RANGE[1], 1.0, -1.0) * PROPORTION_STEP
        )
        vectors = np.tile(base, (N_PROPORTIONS + 1, 1))
        vectors[1:] += np.diag(self.steps)
        postures = np.stack([np.asarray(posture_rad, dtype=np.float64), np.zeros(N_JOINTS)])
        stepped = [HandProportions.from_vector(vector) for vector in vectors]
        # One kinematics for the posture and the rest of each skeleton.
        bone_transforms = bone_transforms_per_skeleton(
            postures, [proportioned_skeleton(model_skeleton, p) for p in stepped]
        )  # (8, 2, 16, 4, 4): posed, at rest
        posed, rest = bone_transforms[:, 0], bone_transforms[:, 1]
        stretches = np.stack([bone_stretch(p) for p in stepped])
        self._rest_maps = np.ascontiguousarray((rest @ stretches @ model_rest_inverse)[..., :3, :])
        self._pose_maps = np.ascontiguousarray((posed @ np.linalg.inv(rest))[..., :3, :])
        self._bones, self._bone_weights = bones, bone_weights
        self._model_rest = np.ascontiguousarray(model_rest_m, dtype=np.float64)
        self._rotation = np.ascontiguousarray(rotation, dtype=np.float64)
        self._rows = np.empty((len(bones), 3, N_PROPORTIONS))
        self._done = np.zeros(len(bones), dtype=bool)

    def rows(self, sample_ids: ArrayLike) -> NDArray[np.float64]:
        """``(P, 3, 7)`` the derivatives of ``sample_ids (P,)``."""
        ids = np.asarray(sample_ids, dtype=np.int64)
        missing = np.unique(ids[~self._done[ids]])
        if len(missing):
            computed = np.empty((len(missing), 3, N_PROPORTIONS))
            _kernels.proportion_differences(
                self._bones[missing], self._bone_weights[missing], self._model_rest[missing],
                self._rest_maps, self._pose_maps, self._rotation, self.steps, computed,
            )  # fmt: skip
            self._rows[missing] = computed
            self._done[missing] = True
        return self._rows[ids]
