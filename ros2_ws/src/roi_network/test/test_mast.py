"""The mast helper: kinematics from rover.yaml parameters, camera pose at a stamp."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from roi_network.mast import (
    NO_JOINT_STATES,
    STALE_JOINT_STATES,
    CameraPoser,
    MastError,
    MastKinematics,
    pose_list,
    pose_matrix,
    same_pose,
)

OPTICAL = Rotation.from_matrix(np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)).as_quat()


def mast_params(**over):
    p = {
        "mast.pan_joint": "mast_pan", "mast.pan_origin": [0.4, 0.0, 1.3, 0, 0, 0, 1],
        "mast.pan_axis": [0, 0, 1], "mast.pan_limits": [-math.pi, math.pi],
        "mast.tilt_joint": "mast_tilt", "mast.tilt_origin": [0, 0, 0.24, 0, 0, 0, 1],
        "mast.tilt_axis": [0, 1, 0], "mast.tilt_limits": [-0.5, 1.2],
        "mast.head_to_left_camera": [0.0, 0.1, 0.0, *OPTICAL],
    }
    p.update(over)
    return p


def test_forward_kinematics_points_the_optical_axis():
    kin = MastKinematics.from_params(mast_params())
    m = kin.base_T_left(0.0, math.radians(20))
    np.testing.assert_allclose(m[:3, 3], [0.4, 0.1, 1.54], atol=1e-12)
    z = m[:3, 2]  # optical axis in base_link: forward and 20 deg down
    np.testing.assert_allclose(z, [math.cos(math.radians(20)), 0, -math.sin(math.radians(20))],
                               atol=1e-12)
    m = kin.base_T_left(math.pi / 2, 0.0)  # panned left: looks along +y, camera moved
    np.testing.assert_allclose(m[:3, 2], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(m[:3, 3], [0.3, 0.0, 1.54], atol=1e-12)


def test_params_round_trip_and_no_mast():
    kin = MastKinematics.from_params(mast_params())
    again = MastKinematics.from_params(kin.to_params())
    assert same_pose(kin.base_T_left(0.3, 0.2), again.base_T_left(0.3, 0.2), 1e-9, 1e-9)
    assert MastKinematics.from_params({"mast.pan_joint": ""}) is None
    assert MastKinematics.from_params({}) is None
    np.testing.assert_allclose(pose_matrix(pose_list(kin.pan_origin), "x"), kin.pan_origin)


@pytest.mark.parametrize("field,value", [("mast.pan_axis", [0, 0, 0]),
                                         ("mast.tilt_limits", [1.0, 0.0]),
                                         ("mast.tilt_origin", [0, 0, 0])])
def test_malformed_fields_are_named(field, value):
    with pytest.raises(MastError, match=field):
        MastKinematics.from_params(mast_params(**{field: value}))


def test_missing_field_is_named():
    p = mast_params()
    del p["mast.head_to_left_camera"]
    with pytest.raises(MastError, match=r"mast\.head_to_left_camera"):
        MastKinematics.from_params(p)


def test_interpolates_between_bracketing_samples():
    poser = CameraPoser.from_params(mast_params(), tolerance_s=0.1)
    poser.add(10.0, ["mast_pan", "mast_tilt"], [0.0, 0.2])
    poser.add(10.1, ["mast_tilt", "mast_pan", "wheel"], [0.2, 0.1, 5.0])
    pose = poser.pose_at(10.05)
    assert pose.joints == pytest.approx((0.05, 0.2))
    expected = poser.kinematics.base_T_left(0.05, 0.2)
    np.testing.assert_allclose(pose.base_T_left, expected)
    assert poser.pose_at(10.17).joints == pytest.approx((0.1, 0.2))  # nearest, in tolerance


def test_misses_are_counted_by_reason():
    poser = CameraPoser.from_params(mast_params(), tolerance_s=0.1)
    assert poser.pose_at(1.0) == NO_JOINT_STATES
    poser.add(10.0, ["mast_pan", "mast_tilt"], [0.0, 0.2])
    assert poser.pose_at(10.5) == STALE_JOINT_STATES
    assert poser.pose_at(9.0) == STALE_JOINT_STATES
    assert poser.misses == {NO_JOINT_STATES: 1, STALE_JOINT_STATES: 2}


def test_unknown_joint_names_are_an_error_naming_them():
    poser = CameraPoser.from_params(mast_params())
    with pytest.raises(MastError, match=r"'mast_tilt'.*'pan', 'tilt'"):
        poser.add(1.0, ["pan", "tilt"], [0.0, 0.0])
    with pytest.raises(MastError, match="outside"):
        poser.add(1.0, ["mast_pan", "mast_tilt"], [0.0, 2.0])
    with pytest.raises(MastError, match="not finite"):
        poser.add(1.0, ["mast_pan", "mast_tilt"], [float("nan"), 0.0])


def test_fixed_camera_needs_no_joint_states():
    fixed = [0.4, 0.1, 1.54, *OPTICAL]
    poser = CameraPoser.from_params({"base_to_left_camera": fixed})
    assert not poser.has_mast
    np.testing.assert_allclose(poser.pose_at(3.0).base_T_left, pose_matrix(fixed, "f"))
    with pytest.raises(MastError, match="base_to_left_camera"):
        CameraPoser.from_params({})
