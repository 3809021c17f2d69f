"""Surface nets: a closed triangle mesh from a signed distance sampled on a grid.

Naive surface nets (Gibson 1998): every grid cell whose corners change sign gets one
vertex at the mean of the zero crossings on its edges; every grid edge that changes
sign gets a quad joining the four cells around it. The result is closed and
consistently oriented (normals point toward positive distance) whenever the field is
positive on the whole boundary of the grid.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb._validate import as_array

# Cell corner offsets and the 12 cell edges as pairs of corner indices.
_CORNERS = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
_EDGES = np.array(
    [(a, b) for a in range(8) for b in range(a + 1, 8)
     if np.abs(_CORNERS[a] - _CORNERS[b]).sum() == 1]
)  # fmt: skip


def surface_nets(
    values: ArrayLike, origin_m: ArrayLike, spacing_m: float
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Mesh the zero level set of a sampled signed distance.

    Parameters
    ----------
    values : (X, Y, Z) float
        Signed distance at grid points ``origin_m + spacing_m * (i, j, k)``; negative
        inside. Must be positive on the grid's boundary.
    origin_m : (3,) float
    spacing_m : float

    Returns
    -------
    vertices_m : (V, 3) float64
    faces : (F, 3) int64
        Counter-clockwise seen from outside.
    """
    field = as_array("values", values, (None, None, None), np.float64, finite=True)
    origin = as_array("origin_m", origin_m, (3,), np.float64, finite=True)
    boundary = np.concatenate(
        [field[[0, -1]].ravel(), field[:, [0, -1]].ravel(), field[:, :, [0, -1]].ravel()]
    )
    if np.any(boundary <= 0):
        raise ValueError("values: the surface touches the grid boundary; enlarge the grid")
    inside = field < 0
    nx, ny, nz = field.shape
    corner_values = np.stack(
        [field[i : nx - 1 + i, j : ny - 1 + j, k : nz - 1 + k] for i, j, k in _CORNERS], -1
    )
    corner_inside = corner_values < 0
    active = corner_inside.any(-1) & ~corner_inside.all(-1)
    cells = np.argwhere(active)
    cell_values = corner_values[active]
    va, vb = cell_values[:, _EDGES[:, 0]], cell_values[:, _EDGES[:, 1]]
    crossing = (va < 0) != (vb < 0)
    t = np.where(crossing, va / np.where(crossing, va - vb, 1.0), 0.0)
    points = _CORNERS[_EDGES[:, 0]] + t[..., None] * (
        _CORNERS[_EDGES[:, 1]] - _CORNERS[_EDGES[:, 0]]
    )
    local = (points * crossing[..., None]).sum(1) / crossing.sum(1, keepdims=True)
    vertices = origin + spacing_m * (cells + local)

    cell_index = np.full((nx - 1, ny - 1, nz - 1), -1, dtype=np.int64)
    cell_index[active] = np.arange(len(cells))
    quads = []
    for axis in range(3):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        changes = inside != np.roll(inside, -1, axis=axis)
        changes = np.take(changes, np.arange(field.shape[axis] - 1), axis=axis)
        edges = np.argwhere(changes)
        edges = edges[(edges[:, u] > 0) & (edges[:, v] > 0)]
        ring = []
        for du, dv in ((-1, -1), (0, -1), (0, 0), (-1, 0)):
            cell = edges.copy()
            cell[:, u] += du
            cell[:, v] += dv
            ring.append(cell_index[cell[:, 0], cell[:, 1], cell[:, 2]])
        quad = np.stack(ring, -1)
        starts_inside = inside[edges[:, 0], edges[:, 1], edges[:, 2]]
        quads.append(np.where(starts_inside[:, None], quad, quad[:, ::-1]))
    quad = np.concatenate(quads)
    return vertices, _split_quads(vertices, quad)


def _split_quads(vertices: NDArray[np.float64], quads: NDArray[np.int64]) -> NDArray[np.int64]:
    """Two triangles per quad, cut along the shorter diagonal."""
    d02 = np.linalg.norm(vertices[quads[:, 0]] - vertices[quads[:, 2]], axis=1)
    d13 = np.linalg.norm(vertices[quads[:, 1]] - vertices[quads[:, 3]], axis=1)
    short02 = (d02 <= d13)[:, None]
    first = np.where(short02, quads[:, [0, 1, 2]], quads[:, [0, 1, 3]])
    second = np.where(short02, quads[:, [0, 2, 3]], quads[:, [1, 2, 3]])
    return np.concatenate([first, second]).astype(np.int64)
