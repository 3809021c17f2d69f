"""Constants and small helpers shared by the tests (fixtures live in conftest.py)."""

from pathlib import Path

# ../shared/data beside the repository: present for developers and CI, absent for users.
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"

# A 72-entry database: open and pinch, 12 camera positions x 3 rolls, sizes 8/16/32.
SMALL_DATABASE = {
    "name": "small",
    "postures": {"named": ["open", "pinch"]},
    "views": {"subdivisions": 0, "rolls": 3},
    "images": {"sizes": [8, 16, 32], "render_size": 96},
}


def model_pose(posture="pinch", axis=(0.3, 1.0, 0.2), angle=0.5, at=(0.01, 0.02, 0.55)):
    """A named posture with the hand's back to the camera, turned by ``angle`` radians
    about ``axis``, its wrist at ``at`` (camera frame, metres): a generative-fit pose."""
    import numpy as np

    from glovedb.postures import named_posture
    from glovedb.rotations import axis_angle_to_matrix
    from tracker.generative.model import HandPose

    turn = axis_angle_to_matrix(np.array(axis) / np.linalg.norm(axis), angle)
    return HandPose.of(named_posture(posture), turn @ np.diag([1.0, -1.0, -1.0]), at)


def model_observation(samples, pose, *, max_points):
    """What a camera sees of the model in ``pose``, without OpenGL: its camera-facing
    samples as the glove points, their pixels as the hand mask, their depth as the
    observed depth (Kinect v1 intrinsics)."""
    import numpy as np

    from glovedb.camera import KINECT_V1
    from tracker.generative.model import PosedHand
    from tracker.generative.observation import observe
    from tracker.point_cloud import HandRegion, LabeledPointCloud

    hand = PosedHand(samples, pose)
    points, labels = hand.points_m[hand.facing], samples.labels[hand.facing]
    uv = np.rint(KINECT_V1.project(points)).astype(np.int64)
    depth = np.zeros((KINECT_V1.height, KINECT_V1.width), np.float32)
    order = np.argsort(-points[:, 2])  # nearest written last
    depth[uv[order, 1], uv[order, 0]] = points[order, 2]
    region = HandRegion(uv, labels, points[:, 2].astype(np.float32))
    cloud = LabeledPointCloud(points.astype(np.float32), labels)
    return observe(region, cloud, depth, KINECT_V1, max_points=max_points)


def write_format_1(source, target):
    """``target``: the database ``source`` in the layout of format 1, as the builder
    wrote it up to format 1 (sizes up to 16 chunked gzip, larger ones contiguous)."""
    import shutil

    import h5py

    from glovedb.database import GloveDatabase

    with GloveDatabase(source) as database:
        images = {size: database.images(size) for size in database.resolutions}
    shutil.copyfile(source, target)
    with h5py.File(target, "r+") as file:
        file.attrs["format_version"] = 1
        for size, stack in images.items():
            del file[f"tiny/{size}"]
            options = {}
            if size <= 16:
                rows = max(1, min(len(stack), (1 << 20) // (size * size)))
                options = {"chunks": (rows, size, size), "compression": "gzip"}
            file.create_dataset(f"tiny/{size}", data=stack, **options)
