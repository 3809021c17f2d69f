"""The skinned glove mesh: generated from the hand's signed distance, posed by LBS.

The rest mesh is the zero level set of :func:`glovedb.shape.hand_distance` meshed
with surface nets, its vertices projected onto the exact surface. Skinning weights
come from the distance of each rest vertex to each bone's core (the palm slab's
polygon and wrist axis, the finger segments' axes): a vertex is owned by its nearest
bone and blends into neighbours whose cores are nearly as close, which gives smooth
bends over about a finger radius around every joint.

Posing is linear blend skinning (LBS)::

    v = sum_b w_b * hand_T_bone_b(theta) @ inv(hand_T_bone_b(0)) @ v_rest
"""

from __future__ import annotations

import functools
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb import _mesh_kernels
from glovedb._files import write_atomically
from glovedb._validate import as_array
from glovedb.cache import cache_folder, source_digest
from glovedb.hand_model import N_BONES, N_JOINTS, Skeleton, forward_kinematics, make_skeleton
from glovedb.shape import HandShape, hand_distance, make_hand_shape, polygon_distance
from glovedb.surface_nets import surface_nets

DEFAULT_SPACING_M = 0.002
# Width of the blend between a vertex's nearest bone and the others (metres of extra
# core distance per e-fold of weight), and the smallest weight kept.
_BLEND_WIDTH_M = 0.0015
_MIN_WEIGHT = 0.01


@dataclass(frozen=True)
class HandMesh:
    """A skinned triangle mesh of the glove hand.

    Attributes
    ----------
    skeleton : Skeleton
        The skeleton the mesh is rigged to.
    rest_vertices_m : (V, 3) float64
        Vertices in the hand frame at the rest posture (all angles zero).
    faces : (F, 3) int64
        Counter-clockwise seen from outside.
    weights : (V, 16) float32
        Skinning weights; every row sums to one.
    """

    skeleton: Skeleton
    rest_vertices_m: NDArray[np.float64]
    faces: NDArray[np.int64]
    weights: NDArray[np.float32]

    @functools.cached_property
    def dominant_bone(self) -> NDArray[np.int64]:
        """``(V,)`` the bone with the largest weight at each vertex (read-only; kept:
        the fit asks for it every frame, and the argmax over the weights cost 0.16 ms)."""
        bone = np.argmax(self.weights, axis=1)
        bone.setflags(write=False)
        return bone

    def rerested(self, skeleton: Skeleton, rest_vertices_m: NDArray[np.float64]) -> HandMesh:
        """The same faces and weights on another skeleton and rest vertices, keeping
        what the weights alone decide (:attr:`dominant_bone`, computed here once): a
        fit that estimates the hand proportions re-rests its samples at every step."""
        mesh = HandMesh(skeleton, rest_vertices_m, self.faces, self.weights)
        mesh.__dict__["dominant_bone"] = self.dominant_bone
        return mesh


def make_hand_mesh(
    skeleton: Skeleton | None = None, *, spacing_m: float = DEFAULT_SPACING_M
) -> HandMesh:
    """Generate the glove hand mesh and its skinning weights.

    Parameters
    ----------
    skeleton : Skeleton, optional
        Defaults to the default hand length.
    spacing_m : float
        Grid spacing of the mesher; vertices are roughly this far apart. 2 mm gives
        about 12,000 vertices.

    Returns
    -------
    HandMesh
    """
    if not 0.0005 <= spacing_m <= 0.01:
        raise ValueError(f"spacing_m: expected 0.0005-0.01 m, got {spacing_m}")
    skeleton = skeleton or make_skeleton()
    shape = make_hand_shape(skeleton)
    # Surface nets can join two sheets at one edge where a cell is ambiguous (a
    # saddle); shifting the grid by a fraction of a cell removes such coincidences.
    for shift in _GRID_SHIFTS:
        vertices, faces = _mesh_level_set(shape, skeleton, spacing_m, shift * spacing_m)
        if _is_two_manifold(faces):
            break
    else:
        raise RuntimeError("could not mesh the hand without non-manifold edges")
    vertices = _project_to_surface(vertices, shape, spacing_m)
    return HandMesh(skeleton, vertices, faces, skinning_weights(vertices, shape, skeleton))


def cached_hand_mesh(
    skeleton: Skeleton | None = None,
    *,
    spacing_m: float = DEFAULT_SPACING_M,
    folder: str | os.PathLike[str] | None = None,
) -> HandMesh:
    """:func:`make_hand_mesh`, kept in the cache folder after the first time.

    Generating the mesh takes about half a second; loading it, a few milliseconds
    (the tracker's start, every build worker).
    The file name is a hash of the skeleton, the spacing and the source of the modules
    that make the mesh, so any change makes a new mesh. A cache that cannot be read
    or written is passed over (the mesh is then generated).

    Parameters
    ----------
    skeleton : Skeleton, optional
    spacing_m : float
    folder : path, optional
        Default :func:`glovedb.cache.cache_folder` ``/ "meshes"``.

    Returns
    -------
    HandMesh
        Equal, array by array, to ``make_hand_mesh(skeleton, spacing_m=spacing_m)``.
    """
    skeleton = skeleton or make_skeleton()
    digest = source_digest(*_MESH_SOURCES)
    digest.update(f"{np.__version__} {spacing_m!r}".encode())
    for array in (skeleton.offsets_m, skeleton.rest_before, skeleton.rest_after):
        digest.update(np.ascontiguousarray(array, np.float64).tobytes())
    digest.update(np.ascontiguousarray(skeleton.lengths_m, np.float64).tobytes())
    digest.update(np.float64(skeleton.hand_length_m).tobytes())
    path = Path(folder or cache_folder() / "meshes") / f"hand-{digest.hexdigest()[:16]}.npz"
    try:
        with np.load(path, allow_pickle=False) as stored:
            return HandMesh(
                skeleton,
                stored["rest_vertices_m"].astype(np.float64),
                stored["faces"].astype(np.int64),
                stored["weights"].astype(np.float32),
            )
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        pass  # not there yet, or unreadable: make it
    mesh = make_hand_mesh(skeleton, spacing_m=spacing_m)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomically(  # whole or absent, also with two processes at once
            path,
            lambda file: np.savez(
                file,
                rest_vertices_m=mesh.rest_vertices_m,
                faces=mesh.faces,
                weights=mesh.weights,
            ),
        )
    except OSError:
        pass  # a read-only home: the next run generates it again
    return mesh


# What decides the mesh's arrays: these modules' source is part of its cache key.
_MESH_SOURCES = ("mesh", "_mesh_kernels", "shape", "surface_nets", "hand_model", "capsules")

_GRID_SHIFTS = (0.0, 0.31, 0.57, 0.13, 0.79)


def _mesh_level_set(
    shape: HandShape, skeleton: Skeleton, spacing_m: float, shift_m: float
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Surface nets on a grid that covers the rest hand with a margin."""
    rest = forward_kinematics(np.zeros(N_JOINTS), skeleton).keypoints_m[0]
    margin = 0.025 * skeleton.hand_length_m / 0.19 + 3 * spacing_m
    half_x, half_z = shape.wrist_half_axes_m
    low = np.minimum(rest.min(0), [-half_x, shape.wrist_y_range_m[0], -half_z]) - margin + shift_m
    high = np.maximum(rest.max(0), [half_x, 0.0, half_z]) + margin
    axes = [np.arange(lo, hi, spacing_m) for lo, hi in zip(low, high, strict=True)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    # Narrow band: the distance is evaluated exactly only near the surface. Elsewhere
    # the value of the nearest point of a grid 4x coarser is used; the distance is
    # 1-Lipschitz, so that value has the right sign (with a safety factor of 1.5).
    coarse_points = grid[::4, ::4, ::4]
    coarse = hand_distance(coarse_points.reshape(-1, 3), shape).reshape(coarse_points.shape[:3])
    nearest = tuple(
        np.minimum((np.arange(grid.shape[axis]) + 2) // 4, coarse.shape[axis] - 1)
        for axis in range(3)
    )
    values = coarse[np.ix_(*nearest)]
    band = np.abs(values) < 1.5 * np.sqrt(3) * 3 * spacing_m
    values[band] = hand_distance(grid[band], shape)
    return surface_nets(values, low, spacing_m)


def _is_two_manifold(faces: NDArray[np.int64]) -> bool:
    """Whether every undirected edge is shared by exactly two faces."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return bool(np.all(counts == 2))


def _project_to_surface(
    vertices: NDArray[np.float64], shape: HandShape, spacing_m: float, steps: int = 2
) -> NDArray[np.float64]:
    """Newton steps along the numerical gradient toward the zero level set."""
    eps = 0.25 * spacing_m
    for _ in range(steps):
        distance = hand_distance(vertices, shape)
        gradient = np.stack(
            [
                hand_distance(vertices + eps * axis, shape)
                - hand_distance(vertices - eps * axis, shape)
                for axis in np.eye(3)
            ],
            -1,
        ) / (2 * eps)
        norm_sq = np.maximum(np.einsum("ij,ij->i", gradient, gradient), 1e-12)
        step = (distance / norm_sq)[:, None] * gradient
        # A step longer than a grid cell would jump across a thin feature: skip it.
        vertices = np.where(
            np.linalg.norm(step, axis=1, keepdims=True) < spacing_m, vertices - step, vertices
        )
    return vertices


def bone_core_distances(
    points: ArrayLike, shape: HandShape, skeleton: Skeleton
) -> NDArray[np.float64]:
    """Distance from rest-posture points to the core of every bone.

    The palm's core is the palm polygon (at z = 0) joined to the wrist axis; a
    finger bone's core is its segment from proximal joint to distal joint (or tip).

    Parameters
    ----------
    points : (N, 3) float
        Hand frame, rest posture.

    Returns
    -------
    (N, 16) float64
    """
    p = as_array("points", points, (None, 3), np.float64)
    distances = np.empty((len(p), N_BONES))
    planar = np.maximum(polygon_distance(p[:, :2], shape.palm_polygon_m), 0.0)
    low, high = shape.wrist_y_range_m
    along_wrist = np.maximum(np.maximum(low - p[:, 1], p[:, 1] - high), 0.0)
    wrist_axis = np.sqrt(p[:, 0] ** 2 + p[:, 2] ** 2 + along_wrist**2)
    distances[:, 0] = np.minimum(np.hypot(planar, p[:, 2]), wrist_axis)
    rest = forward_kinematics(np.zeros(N_JOINTS), skeleton).bone_transforms[0]
    for bone in range(1, N_BONES):
        start = rest[bone, :3, 3]
        end = start + rest[bone, :3, 1] * skeleton.lengths_m[bone]
        axis = end - start
        t = np.clip((p - start) @ axis / (axis @ axis), 0.0, 1.0)
        distances[:, bone] = np.linalg.norm(p - start - t[:, None] * axis, axis=1)
    return distances


def skinning_weights(
    vertices: ArrayLike, shape: HandShape, skeleton: Skeleton
) -> NDArray[np.float32]:
    """LBS weights ``(V, 16)`` float32 from bone-core distances (see module docstring).

    Weights fall off by ``e`` every ``_BLEND_WIDTH_M`` of extra distance to a bone's
    core compared with the nearest core, so a joint blends over about a finger radius
    on each side; weights under ``_MIN_WEIGHT`` are dropped.
    """
    distances = bone_core_distances(vertices, shape, skeleton)
    nearest = np.argmin(distances, axis=1)
    excess = distances - distances[np.arange(len(distances)), nearest][:, None]
    weights = np.exp(-excess / _BLEND_WIDTH_M)
    # A vertex blends only along its own chain: a finger vertex with the palm and its
    # own finger's bones, a palm vertex with the fingers' first segments; never with
    # a neighbouring finger that happens to be close.
    finger = (np.arange(N_BONES) - 1) // 3
    own_finger = (finger[None, :] == finger[nearest][:, None]) & (nearest[:, None] > 0)
    first_segments = ((np.arange(N_BONES) - 1) % 3 == 0)[None, :] & (nearest[:, None] == 0)
    allowed = own_finger | first_segments
    allowed[:, 0] = True
    weights[~allowed] = 0.0
    weights[weights < _MIN_WEIGHT] = 0.0
    return (weights / weights.sum(axis=1, keepdims=True)).astype(np.float32)


def skinning_matrices(posture_rad: ArrayLike, skeleton: Skeleton) -> NDArray[np.float64]:
    """``(N, 16, 3, 4)`` rest-to-posed bone transforms for ``(N, 20)`` postures."""
    posture = np.asarray(posture_rad, dtype=np.float64).reshape(-1, N_JOINTS)
    # The rest pose rides along as the last row so forward kinematics runs once.
    both = forward_kinematics(np.vstack([posture, np.zeros(N_JOINTS)]), skeleton).bone_transforms
    return (both[:-1] @ np.linalg.inv(both[-1]))[:, :, :3, :]


def skin(mesh: HandMesh, matrices: ArrayLike) -> NDArray[np.float64]:
    """Linear blend skinning of the mesh with given bone matrices.

    Parameters
    ----------
    mesh : HandMesh
    matrices : (N, 16, 3, 4) float
        From :func:`skinning_matrices`.

    Returns
    -------
    (N, V, 3) float64
        Hand frame.
    """
    matrices = as_array("matrices", matrices, (None, N_BONES, 3, 4), np.float64)
    vertices = np.empty((len(matrices), len(mesh.rest_vertices_m), 3))
    # A compiled loop over each vertex's non-zero weights (at most 3 of 16 on the
    # generated meshes): 0.08 ms for the 3,771 samples of the tracker's default mesh
    # on the AMD machine of docs/tracker.md, where a (V, 16) @ (16, 12) product and an
    # einsum took 0.17 ms.
    _mesh_kernels.blend_skin(
        np.ascontiguousarray(mesh.weights, dtype=np.float32), np.ascontiguousarray(matrices),
        np.ascontiguousarray(mesh.rest_vertices_m, dtype=np.float64), vertices,
    )  # fmt: skip
    return vertices


def pose_mesh(mesh: HandMesh, posture_rad: ArrayLike) -> NDArray[np.float64]:
    """Vertices of the mesh in one or many postures, hand frame.

    Parameters
    ----------
    mesh : HandMesh
    posture_rad : (20,) or (N, 20) float

    Returns
    -------
    (V, 3) or (N, V, 3) float64
        Matching the input's batch shape.
    """
    posture = as_array("posture_rad", posture_rad, (..., N_JOINTS), np.float64, finite=True)
    vertices = skin(mesh, skinning_matrices(posture.reshape(-1, N_JOINTS), mesh.skeleton))
    return vertices.reshape(posture.shape[:-1] + vertices.shape[-2:])


def vertex_normals(vertices: ArrayLike, faces: ArrayLike) -> NDArray[np.float64]:
    """Area-weighted unit vertex normals.

    Parameters
    ----------
    vertices : (V, 3) float
    faces : (F, 3) int

    Returns
    -------
    (V, 3) float64
    """
    v = np.ascontiguousarray(as_array("vertices", vertices, (None, 3), np.float64))
    f = np.ascontiguousarray(as_array("faces", faces, (None, 3), kind="iu"), dtype=np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"faces: vertex indices must be in 0..{len(v) - 1}")
    normals = np.zeros_like(v)
    _mesh_kernels.accumulate_face_normals(v, f, normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.maximum(length, 1e-12)
