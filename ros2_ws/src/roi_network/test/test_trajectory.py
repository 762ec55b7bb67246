"""The shared trajectory files: TUM poses and their pose covariance."""

import numpy as np
import pytest

from roi_network.trajectory import (
    POSE_COVARIANCE_FIELDS,
    read_pose_covariance_rows,
    read_tum_rows,
    write_pose_covariance,
    write_tum,
)


def test_tum_and_pose_covariance_round_trip(tmp_path):
    t = np.array([1.5, 2.25, 3.0])
    p = np.array([[0.0, 0.0, 0.0], [1.25, -2.0, 0.5], [3.0, 4.0, -1.0]])
    q = np.array([[0, 0, 0, 1], [0, 0, np.sin(0.3), np.cos(0.3)], [0, 0, 1, 0]], float)
    write_tum(tmp_path / "a.tum", t, p, q, header="test poses")
    rows = read_tum_rows(tmp_path / "a.tum")
    assert (tmp_path / "a.tum").read_text().startswith("# test poses\n")
    np.testing.assert_allclose(rows, np.column_stack([t, p, q]), atol=1e-6)
    a = np.arange(36.0).reshape(6, 6) * 1e-3
    covs = np.stack([a @ a.T + np.eye(6) * k for k in (1.0, 2.0, 3.0)])
    write_pose_covariance(tmp_path / "c.txt", t, covs, note="unit test")
    text = (tmp_path / "c.txt").read_text()
    assert text.startswith(f"# {POSE_COVARIANCE_FIELDS} (unit test)\n")
    stamps, back = read_pose_covariance_rows(tmp_path / "c.txt")
    np.testing.assert_allclose(stamps, t)
    np.testing.assert_allclose(back, covs, rtol=1e-6)
    # A ROS message's 36 values write the same row as the 6x6 matrix.
    write_pose_covariance(tmp_path / "d.txt", t, covs.reshape(3, 36), note="unit test")
    assert (tmp_path / "d.txt").read_text() == text


def test_bad_rows_name_the_file_and_line(tmp_path):
    bad = tmp_path / "bad.tum"
    bad.write_text("# t x y z qx qy qz qw\n1 0 0 0 0 0 0 1\n2 0 0 0 0 0 1\n")
    with pytest.raises(ValueError, match=r"bad\.tum:3: expected 8 finite numbers"):
        read_tum_rows(bad)
    bad.write_text("# nothing\n")
    with pytest.raises(ValueError, match=r"bad\.tum: no poses"):
        read_tum_rows(bad)
    assert read_tum_rows(bad, allow_empty=True).shape == (0, 8)  # a run with no pose
    bad.write_text("1,0,0,0,0,0,0,1\n2\t0\t0\t0\t0\t0\t0\t1\n")  # commas, tabs
    assert read_tum_rows(bad)[:, 0].tolist() == [1.0, 2.0]
    cov = tmp_path / "cov.txt"
    c = np.eye(6)
    c[1, 1] = -0.5
    cov.write_text("1.0 " + " ".join(str(v) for v in np.eye(6).ravel()) + "\n"
                   + "2.0 " + " ".join(str(v) for v in c.ravel()) + "\n")
    with pytest.raises(ValueError, match=r"cov\.txt:2: negative variance"):
        read_pose_covariance_rows(cov)
    with pytest.raises(ValueError, match="36"):
        write_pose_covariance(tmp_path / "x.txt", [1.0], [np.eye(3)])
    assert not (tmp_path / "x.txt").exists()
