"""Compiled loops of :mod:`glovedb.mesh`, which documents and checks their inputs."""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(nogil=True, cache=True)
def accumulate_face_normals(
    vertices: NDArray[np.float64], faces: NDArray[np.int64], normals: NDArray[np.float64]
) -> None:
    """Add every face's area-weighted normal (the cross product of two edges) to its
    three corners in ``normals (V, 3)``, which the caller zeroes."""
    for face in range(faces.shape[0]):
        a, b, c = faces[face, 0], faces[face, 1], faces[face, 2]
        e1x = vertices[b, 0] - vertices[a, 0]
        e1y = vertices[b, 1] - vertices[a, 1]
        e1z = vertices[b, 2] - vertices[a, 2]
        e2x = vertices[c, 0] - vertices[a, 0]
        e2y = vertices[c, 1] - vertices[a, 1]
        e2z = vertices[c, 2] - vertices[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        for corner in (a, b, c):
            normals[corner, 0] += nx
            normals[corner, 1] += ny
            normals[corner, 2] += nz


@numba.njit(nogil=True, cache=True)
def blend_skin(
    weights: NDArray[np.float32],
    matrices: NDArray[np.float64],
    rest: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """Linear blend skinning: ``out[n, v] = sum_b weights[v, b] * matrices[n, b] @
    (rest[v], 1)`` for ``weights (V, B)``, ``matrices (N, B, 3, 4)``, ``rest (V, 3)``
    into ``out (N, V, 3)``, over each vertex's non-zero weights in bone order."""
    blended = np.empty((3, 4))
    for n in range(matrices.shape[0]):
        for v in range(weights.shape[0]):
            blended[:] = 0.0
            for b in range(weights.shape[1]):
                w = np.float64(weights[v, b])
                if w != 0.0:
                    for i in range(3):
                        for j in range(4):
                            blended[i, j] += w * matrices[n, b, i, j]
            for i in range(3):
                out[n, v, i] = (
                    blended[i, 0] * rest[v, 0]
                    + blended[i, 1] * rest[v, 1]
                    + blended[i, 2] * rest[v, 2]
                    + blended[i, 3]
                )
