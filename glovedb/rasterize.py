"""Class-label images of the glove mesh by a compiled software rasteriser.

Database builds need only labels, and the triangles of the label mesh are about a
pixel large at the render size: for such images a rasteriser specialised to them is
several times faster than OpenGL (pyrender on Mesa's llvmpipe pays per-view scene
set-up and per-triangle overhead), needs no OpenGL context and starts at once. The
tracker's colour calibration and its warm-up use it too, with the depth of the
visible surface (:func:`rasterize_labels_and_depth`, :func:`model_label_image`).

It follows OpenGL's rules, so its images equal :class:`builder.render.GloveRenderer`'s
labels but for the rare pixel centre that lies on an edge to 1/256 pixel (tested):

- a pixel is covered when its centre lies inside the projected triangle; vertices
  snap to 1/256 pixel and edge tests are exact, with a tie rule that gives a centre
  on a shared edge to exactly one triangle;
- triangles facing away from the camera are culled (the mesh is closed);
- the nearest triangle wins (1/z interpolated, which is exact in the image); on
  equal depth the one drawn first.

Frames: ``p_cam = R @ p_hand + t`` (OpenCV camera), pixel ``(u, v) = (col, row)``
with ``u = fx * x / z + cx`` and pixel centres at integers.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from glovedb import _raster_kernels
from glovedb._validate import as_array
from glovedb.camera import CameraIntrinsics
from glovedb.mesh import HandMesh, pose_mesh
from glovedb.pattern import LabeledVertices

# Nearest depth a vertex may have; nearer views are an error (no clipping is done).
MIN_DEPTH_M = 0.01


def rasterize_labels(
    vertices_m: ArrayLike,
    faces: ArrayLike,
    face_labels: ArrayLike,
    rotations: ArrayLike,
    translations_m: ArrayLike,
    camera: CameraIntrinsics,
) -> NDArray[np.uint8]:
    """Label images of one posed mesh seen in many global poses.

    Parameters
    ----------
    vertices_m : (N, 3) float
        Mesh vertices, hand frame, metres.
    faces : (F, 3) int
        Counter-clockwise seen from outside.
    face_labels : (F,) uint8
        Class 1..255 of every triangle.
    rotations : (V, 3, 3) float
        ``cam_R_hand`` of every view.
    translations_m : (V, 3) float
        Wrist (hand-frame origin) in the camera frame of every view.
    camera : CameraIntrinsics

    Returns
    -------
    (V, H, W) uint8
        The label of the nearest triangle at every pixel centre, 0 for background.

    Raises
    ------
    ValueError
        For bad shapes, faces that index no vertex, or a vertex nearer to a camera
        than :data:`MIN_DEPTH_M` (or behind it).
    """
    args = (vertices_m, faces, face_labels, rotations, translations_m, camera)
    return _rasterize(*args, with_depth=False)[0]


def rasterize_labels_and_depth(
    vertices_m: ArrayLike,
    faces: ArrayLike,
    face_labels: ArrayLike,
    rotations: ArrayLike,
    translations_m: ArrayLike,
    camera: CameraIntrinsics,
) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """:func:`rasterize_labels` and the depth of the triangle seen at every pixel.

    Returns
    -------
    labels : (V, H, W) uint8
    depth_m : (V, H, W) float32
        Camera-frame z of the nearest triangle at each pixel centre, 0 for background.
    """
    args = (vertices_m, faces, face_labels, rotations, translations_m, camera)
    return _rasterize(*args, with_depth=True)


def model_label_image(
    mesh: HandMesh,
    split: LabeledVertices,
    posture_rad: ArrayLike,
    rotation: ArrayLike,
    translation_m: ArrayLike,
    intrinsics: CameraIntrinsics,
) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """Class labels and depth of the posed glove model as the camera would see them.

    Returns
    -------
    labels : (H, W) uint8
        0 where the model is not seen.
    depth_m : (H, W) float32
        0 where the model is not seen.
    """
    R = as_array("rotation", rotation, (3, 3), np.float64, finite=True)
    t = as_array("translation_m", translation_m, (3,), np.float64, finite=True)
    vertices = pose_mesh(mesh, posture_rad)[split.source_vertex]
    labels, depth = rasterize_labels_and_depth(
        vertices, split.faces, split.labels[split.faces[:, 0]], R[None], t[None], intrinsics
    )
    return labels[0], depth[0]


def _rasterize(
    vertices_m: ArrayLike,
    faces: ArrayLike,
    face_labels: ArrayLike,
    rotations: ArrayLike,
    translations_m: ArrayLike,
    camera: CameraIntrinsics,
    *,
    with_depth: bool,
) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """Checks the inputs of both public functions and runs the kernel."""
    vertices = as_array("vertices_m", vertices_m, (None, 3), np.float64, finite=True)
    triangles = as_array("faces", faces, (None, 3), np.int32, kind="iu")
    labels = as_array("face_labels", face_labels, (len(triangles),), np.uint8, kind="iu")
    view_rotations = as_array("rotations", rotations, (None, 3, 3), np.float64, finite=True)
    view_translations = as_array(
        "translations_m", translations_m, (len(view_rotations), 3), np.float64, finite=True
    )
    if len(triangles) and (triangles.min() < 0 or triangles.max() >= len(vertices)):
        raise ValueError(f"faces: indices must lie in 0..{len(vertices) - 1}")
    shape = (len(view_rotations), camera.height, camera.width)
    images = np.empty(shape, np.uint8)
    depth = np.empty(shape if with_depth else (1, 1, 1), np.float32)
    valid = _raster_kernels.rasterize_labels(
        np.ascontiguousarray(vertices),
        np.ascontiguousarray(triangles),
        np.ascontiguousarray(labels),
        np.ascontiguousarray(view_rotations),
        np.ascontiguousarray(view_translations),
        camera.fx,
        camera.fy,
        camera.cx,
        camera.cy,
        MIN_DEPTH_M,
        images,
        depth,
        with_depth,
    )
    if not valid:
        raise ValueError(f"a vertex lies nearer to a camera than {MIN_DEPTH_M} m")
    return images, depth
