"""Named postures: all required ones exist, lie within limits, and mean what they say."""

import numpy as np
import pytest

from glovedb.hand_model import forward_kinematics, within_limits
from glovedb.postures import REQUIRED_POSTURES, load_named_postures, named_posture


def test_every_required_posture_exists_within_limits():
    postures = load_named_postures()
    assert set(REQUIRED_POSTURES) <= set(postures)
    for name, posture in postures.items():
        assert posture.shape == (20,) and posture.dtype == np.float64
        assert within_limits(posture), name


def test_open_is_all_zeros():
    np.testing.assert_array_equal(named_posture("open"), np.zeros(20))


@pytest.mark.parametrize(("name", "fingers"), [("pinch", [8]), ("tripod", [8, 12]), ("ok", [8])])
def test_contact_postures_bring_the_thumb_tip_to_the_fingers(name, fingers):
    keypoints = forward_kinematics(named_posture(name)).keypoints_m[0]
    for tip in fingers:
        # Tip keypoints sit on the finger ends, two pads of about 8 mm apart.
        assert np.linalg.norm(keypoints[4] - keypoints[tip]) < 0.02


def test_fist_curls_every_fingertip_below_the_palm():
    keypoints = forward_kinematics(named_posture("fist")).keypoints_m[0]
    assert np.all(keypoints[[8, 12, 16, 20], 2] < -0.02)
    assert np.all(keypoints[[8, 12, 16, 20], 1] < keypoints[[5, 9, 13, 17], 1] + 0.01)


def test_unknown_posture_lists_the_known_ones():
    with pytest.raises(ValueError, match="known: open"):
        named_posture("wave")


def test_bad_posture_file_is_rejected(tmp_path):
    path = tmp_path / "postures.toml"
    path.write_text("[claw]\nindex_pip_flex = 170\n")
    with pytest.raises(ValueError, match="outside the joint limits"):
        load_named_postures(path)
    path.write_text("[claw]\nindex_knuckle = 10\n")
    with pytest.raises(ValueError, match="unknown joint"):
        load_named_postures(path)
