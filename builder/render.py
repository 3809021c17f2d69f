"""Headless rendering of the glove hand: color, exact class labels and metric depth.

Uses pyrender on EGL (a GPU when there is one, Mesa's software rasteriser when not).
pyrender renders through a 4x multisampled framebuffer, which blends class labels at
edges; :class:`_SingleSampleRenderer` gives its framebuffer one sample so that every
label pixel is exactly one class and rendering is deterministic.

Frames: the scene holds the posed hand in its own frame and the camera is placed at
``hand_T_cam`` for the global pose ``p_cam = R @ p_hand + t``; the camera's OpenGL
axes (x right, y up, looking down -z) are the OpenCV axes turned by
:data:`_CV_T_GL`, the one place where the two conventions meet.
"""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from dataclasses import dataclass
from typing import Any

import numpy as np
import pyrender
from numpy.typing import ArrayLike, NDArray
from OpenGL import GL

from glovedb._closing import Closing
from glovedb._validate import as_array
from glovedb.camera import CameraIntrinsics
from glovedb.hand_model import N_JOINTS
from glovedb.mesh import HandMesh, make_hand_mesh, pose_mesh, vertex_normals
from glovedb.pattern import GlovePattern, load_pattern, split_by_label

# OpenGL camera axes expressed in the OpenCV camera frame.
_CV_T_GL = np.diag([1.0, -1.0, -1.0, 1.0])


def _camera_pose(rotation: ArrayLike, translation_m: ArrayLike) -> NDArray[np.float64]:
    """pyrender camera pose in the hand frame for the global pose ``cam_T_hand``.

    The scene holds the hand in its own frame; the camera sits at ``hand_T_cam`` and
    its OpenGL axes are the OpenCV axes turned by :data:`_CV_T_GL`.
    """
    cam_R_hand = as_array("rotation", rotation, (3, 3), np.float64, finite=True)
    translation = as_array("translation_m", translation_m, (3,), np.float64, finite=True)
    hand_T_cam = np.eye(4)
    hand_T_cam[:3, :3] = cam_R_hand.T
    hand_T_cam[:3, 3] = -cam_R_hand.T @ translation
    return hand_T_cam @ _CV_T_GL


_Z_NEAR_M, _Z_FAR_M = 0.05, 10.0


def _srgb_to_linear(srgb: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of the sRGB transfer curve, per channel in 0..1."""
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


class _SingleSampleRenderer(pyrender.Renderer):
    """pyrender's renderer with a single-sample framebuffer (no anti-aliasing)."""

    def _configure_main_framebuffer(self) -> None:
        dims_before = self._main_fb_dims
        super()._configure_main_framebuffer()
        if self._main_fb_dims == dims_before:
            return
        width, height = self._main_fb_dims
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_cb_ms)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA, width, height)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._main_db_ms)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_DEPTH_COMPONENT24, width, height)


class _OffscreenRenderer(pyrender.OffscreenRenderer):
    """An offscreen renderer that uses :class:`_SingleSampleRenderer`."""

    _renderer: Any
    _platform: Any

    def _create(self) -> None:
        super()._create()
        self._renderer.delete()
        self._renderer = _SingleSampleRenderer(self.viewport_width, self.viewport_height)

    def delete(self) -> None:
        """Free this renderer's context without terminating the shared EGL display.

        pyrender's EGL platform calls ``eglTerminate`` on delete, which would kill the
        contexts of every other renderer in the process.
        """
        platform = self._platform
        if platform is None or getattr(platform, "_egl_display", None) is None:
            super().delete()
            return
        from OpenGL import EGL

        platform.make_current()
        self._renderer.delete()
        display, context = platform._egl_display, platform._egl_context
        EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)
        if context is not None:
            EGL.eglDestroyContext(display, context)
        platform._egl_context = None
        platform._egl_display = None
        self._renderer = None
        self._platform = None


@dataclass(frozen=True)
class LabelRendering:
    """Class labels and depth of one view of the glove hand.

    Attributes
    ----------
    labels : (H, W) uint8
        Glove class 1..10 of each pixel, 0 for background.
    depth_m : (H, W) float32
        Distance along the optical axis (z), 0 for background.
    """

    labels: NDArray[np.uint8]
    depth_m: NDArray[np.float32]


@dataclass(frozen=True)
class Rendering(LabelRendering):
    """Shaded color, class labels and depth of one view of the glove hand.

    Attributes
    ----------
    color : (H, W, 3) uint8
        Shaded sRGB image.
    """

    color: NDArray[np.uint8]


class GloveRenderer(Closing):
    """Renders the skinned glove hand for one camera; reuse it across many calls.

    Parameters
    ----------
    camera : CameraIntrinsics
    mesh : HandMesh, optional
        Defaults to :func:`~glovedb.mesh.make_hand_mesh`.
    pattern : GlovePattern, optional
        Defaults to :func:`~glovedb.pattern.load_pattern`.
    background_rgb : (3,) int
        Color of pixels the hand does not cover.

    Notes
    -----
    One OpenGL context lives as long as the object; call :meth:`close` (or use it as
    a context manager) to free it. Build one renderer per process: contexts must not
    cross a ``fork``.
    """

    def __init__(
        self,
        camera: CameraIntrinsics,
        *,
        mesh: HandMesh | None = None,
        pattern: GlovePattern | None = None,
        background_rgb: tuple[int, int, int] = (0, 0, 0),
    ) -> None:
        self.camera = camera
        self.mesh = mesh if mesh is not None else make_hand_mesh()
        self.pattern = pattern if pattern is not None else load_pattern()
        # Split vertices on patch borders so every triangle's corners carry its color.
        split = split_by_label(self.mesh, self.pattern)
        self._source_vertex = split.source_vertex
        self._faces = split.faces.astype(np.uint32)
        vertex_label = split.labels
        self._label_colors = np.repeat(vertex_label[:, None] / 255.0, 3, axis=1)
        # pyrender's lit shader writes gamma-encoded output: hand it linear colors.
        palette = _srgb_to_linear(self.pattern.palette()[vertex_label] / 255.0)
        self._shade_colors = np.concatenate([palette, np.ones((len(palette), 1))], axis=1)

        background = np.append(np.asarray(background_rgb) / 255.0, 1.0)
        self._color_scene = pyrender.Scene(bg_color=background, ambient_light=[0.45] * 3)
        self._label_scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 1.0], ambient_light=[0.0] * 3)
        gl_camera = pyrender.IntrinsicsCamera(
            camera.fx,
            camera.fy,
            camera.cx + 0.5,  # pyrender measures from the pixel corner, OpenCV the centre
            camera.cy + 0.5,
            znear=_Z_NEAR_M,
            zfar=_Z_FAR_M,
        )
        self._camera_nodes = {
            "color": self._color_scene.add(gl_camera, pose=_CV_T_GL),
            "label": self._label_scene.add(gl_camera, pose=_CV_T_GL),
        }
        # The light travels with the camera, so it hangs below the camera node.
        key_light = pyrender.DirectionalLight(color=np.ones(3), intensity=1.6)
        self._color_scene.add(key_light, parent_node=self._camera_nodes["color"])
        self._material = pyrender.MetallicRoughnessMaterial(
            baseColorFactor=[1.0, 1.0, 1.0, 1.0], metallicFactor=0.0, roughnessFactor=0.9
        )
        self._renderer: _OffscreenRenderer | None = _OffscreenRenderer(camera.width, camera.height)
        self._nodes: dict[str, pyrender.Node] = {}

    def render(
        self, posture_rad: ArrayLike, rotation: ArrayLike, translation_m: ArrayLike
    ) -> Rendering:
        """Shaded color, labels and depth of the hand in one pose.

        Parameters
        ----------
        posture_rad : (20,) float
        rotation : (3, 3) float
            ``cam_R_hand``.
        translation_m : (3,) float
            Wrist position in the camera frame.

        Returns
        -------
        Rendering
        """
        hand_vertices = self._posed_hand(posture_rad)
        pose = _camera_pose(rotation, translation_m)
        normals = vertex_normals(hand_vertices, self.mesh.faces)[self._source_vertex]
        self._set_mesh("color", hand_vertices[self._source_vertex], normals, self._shade_colors)
        self._color_scene.set_pose(self._camera_nodes["color"], pose)
        color, _ = self._live_renderer().render(self._color_scene)
        self._set_mesh("label", hand_vertices[self._source_vertex], None, self._label_colors)
        labels = self._render_label_view(pose)
        return Rendering(labels.labels, labels.depth_m, np.ascontiguousarray(color[..., :3]))

    def render_labels(
        self,
        posture_rad: ArrayLike,
        rotation: ArrayLike,
        translation_m: ArrayLike,
        *,
        mesh: HandMesh | None = None,
    ) -> LabelRendering:
        """Labels and depth only (faster). Arguments as :meth:`render_label_views`."""
        return self.render_label_views(
            posture_rad, np.asarray(rotation)[None], np.asarray(translation_m)[None], mesh=mesh
        )[0]

    def render_label_views(
        self,
        posture_rad: ArrayLike,
        rotations: ArrayLike,
        translations_m: ArrayLike,
        *,
        mesh: HandMesh | None = None,
    ) -> list[LabelRendering]:
        """Labels and depth of one posture seen in many global poses.

        The mesh is posed and uploaded once; only the camera moves, which makes this
        much faster than one :meth:`render_labels` call per view.

        Parameters
        ----------
        posture_rad : (20,) float
        rotations : (V, 3, 3) float
            ``cam_R_hand`` of every view.
        translations_m : (V, 3) float
        mesh : HandMesh, optional
            Another hand of this renderer's mesh topology, e.g. its
            :func:`~glovedb.proportions.proportioned_mesh` (same faces; the patches
            keep their colors, stretched with the hand). Default: the renderer's mesh.

        Returns
        -------
        list of LabelRendering
            One per view, in order.
        """
        rotations = as_array("rotations", rotations, (None, 3, 3), np.float64, finite=True)
        translations = as_array(
            "translations_m", translations_m, (len(rotations), 3), np.float64, finite=True
        )
        hand_vertices = self._posed_hand(posture_rad, mesh)
        self._set_mesh("label", hand_vertices[self._source_vertex], None, self._label_colors)
        return [
            self._render_label_view(_camera_pose(rotation, translation))
            for rotation, translation in zip(rotations, translations, strict=True)
        ]

    def close(self) -> None:
        """Release the OpenGL context; closing twice is harmless."""
        if self._renderer is not None:
            self._renderer.delete()
            self._renderer = None

    def _live_renderer(self) -> _OffscreenRenderer:
        if self._renderer is None:
            raise ValueError("the renderer is closed")
        return self._renderer

    def _posed_hand(
        self, posture_rad: ArrayLike, mesh: HandMesh | None = None
    ) -> NDArray[np.float64]:
        posture = as_array("posture_rad", posture_rad, (N_JOINTS,), np.float64, finite=True)
        if mesh is None:
            mesh = self.mesh
        elif not np.array_equal(mesh.faces, self.mesh.faces):
            raise ValueError("mesh: expected the renderer's mesh topology (the same faces)")
        return pose_mesh(mesh, posture)

    def _render_label_view(self, camera_pose: NDArray[np.float64]) -> LabelRendering:
        self._label_scene.set_pose(self._camera_nodes["label"], camera_pose)
        flags = pyrender.RenderFlags.FLAT
        labels, depth = self._live_renderer().render(self._label_scene, flags=flags)
        return LabelRendering(np.ascontiguousarray(labels[..., 0]), depth.astype(np.float32))

    def _set_mesh(
        self,
        which: str,
        positions: NDArray[np.float64],
        normals: NDArray[np.float64] | None,
        colors: NDArray[np.float64],
    ) -> None:
        scene = self._color_scene if which == "color" else self._label_scene
        if which in self._nodes:
            scene.remove_node(self._nodes[which])
        primitive = pyrender.Primitive(
            positions=positions.astype(np.float32),
            normals=None if normals is None else normals.astype(np.float32),
            color_0=colors.astype(np.float32),
            indices=self._faces,
            material=self._material,
        )
        self._nodes[which] = scene.add(pyrender.Mesh([primitive]))
