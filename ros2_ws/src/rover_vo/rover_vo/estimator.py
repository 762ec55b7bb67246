"""The estimator (OpenVINS ``VioManager``): takes the sensor messages in arrival order, pairs
left and right images, and runs each stereo pair through zero-velocity detection, feature
tracking, motion estimation against the keyframe, VO + IMU fusion and the covariance
update. Bad input is counted by kind, logged once per kind, and the pose continues
IMU-propagated with a growing covariance.

The node (``vo_node.py``) and the offline CLI (``cli.py``) both call :meth:`VoEstimator.feed`
with the same messages.

Steps (docs/rover_vo.md, Method): 1 pair and order, 2 IMU propagation, 3 camera pose,
4 zero velocity, 5 tracking, 6 stereo and reconstruction, 7 outlier rejection and motion,
8 covariance, 9 gravity, 10 sun heading.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from roi_network.camera_info import camera_info_problem
from roi_network.images import RAW_ENCODINGS, StereoHalves, StereoRectifiers, describe
from roi_network.mast import (
    NO_JOINT_STATES,
    STALE_JOINT_STATES,
    CameraPoser,
    MastError,
    MastKinematics,
    same_pose,
)
from rover_vo import messages as m
from rover_vo.arrivals import WAIT_FRAMES, Arrivals
from rover_vo.config import ROVER_PARAMETERS, VoConfig
from rover_vo.features import stereo_match, track
from rover_vo.keyframes import Keyframe, make_keyframe
from rover_vo.motion import MotionEstimate, estimate_motion, refine_motion
from rover_vo.propagator import ImuInterval, Propagator
from rover_vo.rig import RigError, StereoRig, rig_from_camera_info
from rover_vo.state import N_ERR, OdomState, step_noise, systematic_prior
from rover_vo.sun_heading import (
    MAX_SAMPLE_AGE_S,
    Site,
    SunHeading,
    SunSensorModel,
    vector_problem,
)
from rover_vo.zero_velocity import image_motion_px, is_stationary

#: Layout of :meth:`VoEstimator.snapshot` (a restarted node refuses other layouts).
SNAPSHOT_VERSION = 1

#: Prior 1-sigma of the gyro's turn-on bias (rad/s).
GYRO_BIAS_SIGMA0 = 5.0e-3
#: Accelerometer samples this long before a frame are averaged for gravity (s).
TILT_WINDOW_S = 0.5
#: The period of /joint_states assumed until two have come (s): the simulator's 10 Hz.
JOINT_STATE_PERIOD_S = 0.1
#: The reference frame is replaced when fewer than this fraction of its points are still
#: tracked.
REFERENCE_MIN_TRACKED = 0.3
#: Position noise added per frame without vision, even when the last step stood still (m).
PROPAGATION_FLOOR_M = 0.05
#: Heading noise added per frame with neither vision nor gyro (deg).
UNSEEN_ROTATION_SIGMA_DEG = 10.0
#: After a restart, 1-sigma motion over the gap nobody watched, as a fraction of the
#: fastest speed and turn rate seen before it, times the gap.
RESUME_MOTION_FRACTION = 0.5

#: A vision step at this fraction of the fastest speed seen or more is a drive step: the
#: prediction a lost track is retried with after a stop (the standing steps of a stop
#: predict no motion when the rover drives on).
DRIVE_SPEED_FRACTION = 0.5
#: A mast that holds a new camera pose for this many pairs in a row gets a new reference
#: frame there (a new drive tilt); fewer, and the pose is waited out (a panorama's views).
MAST_SETTLE_FRAMES = 3

#: Kinds of bad input counted in /vo/status (``bad_input.<kind>``).
BAD_INPUT_KINDS = (
    "corrupt_image", "unsupported_encoding", "bad_image_size", "missing_left",
    "missing_right", "missing_camera_info",
    "bad_camera_info", "imu_gap", "imu_nan", "imu_duplicate", "imu_out_of_order",
    "stereo_duplicate", "stereo_out_of_order", "textureless", "overexposed", "vision_failed",
    NO_JOINT_STATES, STALE_JOINT_STATES, "bad_joint_state", "sun_nan", "sun_not_unit",
    "sun_out_of_order", "sun_no_mount", "sun_wrong_frame", "sun_not_sun", "internal_error",
)

#: No /sun_sensor sample for this many of its periods (at least ``SUN_OUTAGE_MIN_S``)
#: by a pair: the sun is out of sight, said once.
SUN_OUTAGE_PERIODS = 5
SUN_OUTAGE_MIN_S = 2.0
#: A pair takes the newest sun sample at least this much older than itself (s): one the
#: node has surely received by then, as the offline run has, so both take the same.
SUN_LEAD_S = 0.1


@dataclass
class VoOutput:
    """One odometry output, at a stereo pair's stamp.

    Attributes:
        state: ``odom_T_base`` and its covariance ``[x y z rx ry rz]`` (odom frame).
        linear, angular: body-frame velocity (m/s, rad/s) over the last interval.
        source: ``vision``, ``zero_velocity``, ``imu_propagation``, ``initial`` or
            ``resumed``.
        stamp_ns: the pair's header stamp, exact (ns).
    """

    state: OdomState
    linear: np.ndarray
    angular: np.ndarray
    source: str
    stamp_ns: int = 0


@dataclass
class FrameStats:
    """Per-frame figures for /vo/status and the report."""

    features: int = 0
    stereo_matches: int = 0
    tracked: int = 0
    inliers: int = 0
    rms_px: float = float("nan")
    keyframe: bool = False


@dataclass
class _Pair:
    t_ns: int
    left: Any = None
    right: Any = None


@dataclass
class Counters:
    """Running totals."""

    pairs: int = 0
    vision: int = 0
    zero_velocity: int = 0
    propagated: int = 0
    keyframes: int = 0
    imu: int = 0
    joint_states: int = 0
    mast_moved: int = 0  # pairs not measured: the camera was off the reference's pose
    no_joint_states: int = 0  # pairs with no joint state within the tolerance
    mast_reanchors: int = 0  # references started at a new camera pose
    drive_step_predictions: int = 0  # lost tracks after a stop retried with the drive step
    bad: Counter = field(default_factory=Counter)


class VoEstimator:
    """Stereo + IMU visual odometry over a stream of messages.

    Args:
        config: options.
        params: flat rover.yaml parameters (extrinsics, IMU noise, gravity, the mast's
            ``mast.*``).
        log: ``log(level, text)``; default: the ``rover_vo`` Python logger.
        raise_joint_state_errors: a ``/joint_states`` message the mast cannot read
            (unknown joint names, angles outside the limits) raises
            :class:`~roi_network.mast.MastError` (the offline CLI) instead of being counted
            as ``bad_joint_state``, logged once, and left out (the node).

    Raises:
        MastError: rover.yaml's mast is malformed (the message names the field).
    """

    def __init__(self, config: VoConfig, params: dict[str, Any],
                 log: Callable[[int, str], None] | None = None,
                 raise_joint_state_errors: bool = False) -> None:
        self.cfg = config
        self.params = dict(params)
        # The camera's pose in base_link: fixed (rig.base_T_left), or on a mast whose
        # angles come on /joint_states.
        self.mast = MastKinematics.from_params(self.params)
        self.poser = CameraPoser(self.mast) if self.mast is not None else None
        self.raise_joint_state_errors = raise_joint_state_errors
        self._last_camera: np.ndarray | None = None  # last pose from a joint state
        self._settling: tuple[np.ndarray, int] | None = None  # new pose, pairs at it
        self._after_mast = False  # the last pair was a mast frame: the rover stood
        self.use_imu = config.use_imu
        # The IMU's constants: rover.yaml's, else the defaults.
        rover = {k: float(self.params.get(k, ROVER_PARAMETERS[k])) for k in (
            "gyro_noise_density", "gyro_bias_random_walk", "accel_bias_random_walk",
            "gravity", "imu_rate_hz")}
        self.gyro_noise_density = rover["gyro_noise_density"]
        self.gyro_bias_random_walk = rover["gyro_bias_random_walk"]
        self.gravity = rover["gravity"]
        self.imu_rate = rover["imu_rate_hz"]
        # The newest stamp and the rate of each input: how long a pair waits for each.
        self.arrivals = Arrivals({"imu": 1.0 / self.imu_rate, "joints": JOINT_STATE_PERIOD_S})
        self._log = log or (lambda level, text: logging.getLogger("rover_vo").log(level, text))
        self.rig: StereoRig | None = None
        self.info: dict[str, Any] = {"left": None, "right": None}
        # Why the last CameraInfo of a side was not taken (None: it was).
        self.info_problem: dict[str, str | None] = {"left": None, "right": None}
        self.propagator: Propagator | None = None
        self._imu_prebuffer: list[tuple[float, np.ndarray, np.ndarray]] = []
        # Images waiting for their other half, then pairs waiting for the IMU (by stamp).
        self.halves = StereoHalves(self.cfg.features.stereo_sync_tolerance_s,
                                   "features.stereo_sync_tolerance_s")
        self.pairs: dict[int, _Pair] = {}
        self.lone_detail: dict[int, str] = {}  # why a lone half's partner did not pair
        # The topics the images arrive on (either transport), for the messages.
        self.image_topics = {"left": m.TOPIC_LEFT, "right": m.TOPIC_RIGHT}
        # Each side's rectifier of its last CameraInfo (identity for rectified images).
        self.rectifiers = StereoRectifiers(lambda text: self._log(logging.INFO, text),
                                           "features.rectify")
        self.last_pair_ns: int | None = None
        self.state: OdomState | None = None
        self.kf: Keyframe | None = None
        self.last_image: np.ndarray | None = None
        self.last_step = (np.eye(3), np.zeros(3))  # last moving step b0_T_b1 (prediction)
        # The last drive step's translation (DRIVE_SPEED_FRACTION): how the rover drives on
        # after a stop.
        self.drive_step: np.ndarray | None = None
        self.velocity = (np.zeros(3), np.zeros(3))
        self.source = "initializing"
        self.stats = FrameStats()
        self.counts = Counters()
        #: The first and the last bad input said, by kind (what /vo/status and the
        #: offline CLI's errors quote).
        self.first_bad: dict[str, str] = {}
        self.last_bad = ""
        self._imu_gap_open = False
        self.max_speed = 0.0  # fastest horizontal speed output so far (m/s)
        self.max_turn_rate = 0.0  # fastest turn (yaw rate) output so far (rad/s)
        self._resume: dict[str, Any] | None = None
        # 10. Sun heading: rover.yaml's sun sensor and site (none: no sun updates).
        sensor = SunSensorModel.from_params(self.params)
        self._sun_off = False  # rover.yaml has a sun sensor, the updates are switched off
        if sensor is not None and not config.imu.sun_heading:
            self._log(logging.INFO, f"{m.TOPIC_SUN}: rover.yaml has a sun sensor; heading "
                      "updates off (imu.sun_heading: false)")
            sensor = None
            self._sun_off = True
        site, why = Site.from_params(self.params) if sensor is not None else (None, None)
        self.sun = SunHeading(sensor, site, rover["accel_bias_random_walk"], self.gravity)
        self._sun_pending: list[tuple[float, np.ndarray]] = []
        self._sun_last: float | None = None  # newest sample's stamp
        self._sun_said: set[str] = set()
        self._sun_first_pair: float | None = None  # when the outage clock starts
        self.sun_refused = None
        if sensor is not None and site is None:
            self.sun_refused = f"{m.TOPIC_SUN}: sun updates refused: {why}"
        elif sensor is not None and not self.use_imu:
            self.sun_refused = (f"{m.TOPIC_SUN}: sun updates off in mode '{config.mode}' "
                                "(the level frame needs the IMU's gravity)")
        if self.sun_refused is not None:
            self._log(logging.WARNING, self.sun_refused)

    # -- restart ----------------------------------------------------------------------------
    def snapshot(self) -> dict[str, Any] | None:
        """What a restarted estimator needs to continue this odom frame (JSON-ready): the
        latest state and covariance, body velocity, last step, fastest speed and turn rate,
        gyro bias; None before the first pose."""
        if self.state is None:
            return None
        s = self.state
        snap: dict[str, Any] = {
            "version": SNAPSHOT_VERSION, "t": s.t, "R": s.R.tolist(), "p": s.p.tolist(),
            "P": s.P[:N_ERR, :N_ERR].tolist(), "distance_m": s.distance_m,
            "linear": [float(v) for v in self.velocity[0]],
            "max_speed": self.max_speed, "max_turn_rate": self.max_turn_rate,
            "last_step": [Rotation.from_matrix(self.last_step[0]).as_rotvec().tolist(),
                          [float(v) for v in self.last_step[1]]],
        }
        if self.propagator is not None:
            snap["gyro_bias"] = self.propagator.bias.tolist()
            snap["gyro_bias_cov"] = self.propagator.bias_cov.tolist()
        return snap

    def resume(self, snap: dict[str, Any]) -> None:
        """Continue the odom frame of a :meth:`snapshot` (the node was restarted): the
        first pair starts from the saved pose, moved straight on at the saved velocity
        over the gap, its covariance grown by the motion nobody saw
        (``RESUME_MOTION_FRACTION`` of the fastest speed and turn rate seen, times the
        gap), instead of a new odom frame at the identity (which would tear the
        LN and the map -> odom estimate built on the old one apart).

        Raises:
            ValueError: a snapshot of another version or with a missing or bad field.
        """
        try:
            if snap.get("version") != SNAPSHOT_VERSION:
                raise ValueError(f"version {snap.get('version')!r}, expected "
                                 f"{SNAPSHOT_VERSION}")
            parsed = {
                "t": float(snap["t"]), "R": np.asarray(snap["R"], float).reshape(3, 3),
                "p": np.asarray(snap["p"], float).reshape(3),
                "P": np.asarray(snap["P"], float).reshape(N_ERR, N_ERR),
                "distance_m": float(snap["distance_m"]),
                "linear": np.asarray(snap["linear"], float).reshape(3),
                "max_speed": float(snap["max_speed"]),
                "max_turn_rate": float(snap["max_turn_rate"]),
                "last_step": np.asarray(snap["last_step"], float).reshape(2, 3),
            }
            if "gyro_bias" in snap:
                parsed["gyro_bias"] = np.asarray(snap["gyro_bias"], float).reshape(3)
                parsed["gyro_bias_cov"] = np.asarray(snap["gyro_bias_cov"], float).reshape(3, 3)
        except (KeyError, TypeError) as exc:
            raise ValueError(f"field {exc}") from None
        if not all(np.all(np.isfinite(v)) for v in parsed.values()):
            raise ValueError("non-finite values")
        self._resume = parsed

    # -- input ----------------------------------------------------------------------------
    def bad(self, kind: str, detail: str) -> None:
        """Count a bad input; log the first of each kind."""
        self.counts.bad[kind] += 1
        self.last_bad = detail
        self.first_bad.setdefault(kind, detail)
        if self.counts.bad[kind] == 1:
            self._log(logging.WARNING, f"{detail} (first '{kind}'; further ones are counted in "
                      "/vo/status, not logged)")

    def feed(self, topic: str, msg: Any) -> list[VoOutput]:
        """Take one message of an input topic; returns the odometry outputs it completes.

        A message that cannot be used (a non-finite IMU value, a stamp going back in time,
        a CameraInfo without a focal length...) is counted, named the first time with its
        topic, stamp and field, and skipped: the odometry goes on.
        """
        # 1. Pair and order: halves paired here, filed by _file_pairs, released in time
        # order by _drain, rectified by _decode.
        if topic == m.TOPIC_IMU:
            self._feed_imu(msg)
        elif topic == m.TOPIC_JOINT_STATES:
            self._feed_joint_state(msg)
        elif topic in (m.TOPIC_LEFT_INFO, m.TOPIC_RIGHT_INFO):
            self._feed_camera_info(topic, msg)
        elif topic in m.IMAGE_TOPICS:
            self._feed_image(topic, msg)
        elif topic == m.TOPIC_SUN:
            self._feed_sun(msg)
            return []
        else:
            return []
        self._file_pairs(force=False)
        return self._drain(force=False)

    def finish(self) -> list[VoOutput]:
        """Process whatever is still waiting (end of a bag)."""
        self._file_pairs(force=True)
        return self._drain(force=True)

    def _feed_image(self, topic: str, msg: Any) -> None:
        side = m.side_of(topic)
        self.image_topics[side] = topic
        t_ns = m.stamp_ns(msg)
        t = m.seconds(t_ns)
        previous = self.arrivals.newest(side)
        if previous is not None and t < previous:
            self.bad("stereo_out_of_order", f"{topic} at {t:.3f} s: stamp before the "
                     f"previous {side} image's ({previous:.3f} s): image skipped")
            return
        if self.last_pair_ns is not None and t_ns <= self.last_pair_ns:
            kind = "stereo_duplicate" if t_ns == self.last_pair_ns else "stereo_out_of_order"
            self.bad(kind, f"{topic} at {t:.3f} s: stamp not after the last processed pair's "
                     f"({self.last_pair_ns * 1e-9:.3f} s): image skipped")
            return
        key = self.halves.add(side, t_ns, msg)
        if key is None:
            self.bad("stereo_duplicate", f"{topic} at {t:.3f} s: a second image of this "
                     "stamp: skipped")
            return
        self.arrivals.note(side, t)

    def _feed_sun(self, msg: Any) -> None:
        """One /sun_sensor sample: checked (frame, a finite unit vector, its stamp after
        the last), then held for the next pair at or after its stamp (step 10)."""
        if self._sun_off:
            return
        t, frame, v = m.sun_vector(msg)
        topic = m.TOPIC_SUN
        sensor = self.sun.sensor
        if sensor is None:
            self.bad("sun_no_mount", f"{topic} at {t:.3f} s: frame '{frame}' has no mount in "
                     "rover.yaml (no sun_sensor.frame, sun_sensor.base_to_sensor): sample "
                     "not used")
            return
        if frame != sensor.frame:
            self.bad("sun_wrong_frame", f"{topic} at {t:.3f} s: frame '{frame}' is not "
                     f"rover.yaml's sun_sensor.frame '{sensor.frame}' (no mount for it): "
                     "sample not used")
            return
        problem = vector_problem(v)
        if problem is not None:
            what = ("not finite" if problem == "sun_nan" else
                    f"of norm {np.linalg.norm(v):.4f}, not a unit vector")
            self.bad(problem, f"{topic} at {t:.3f} s: vector ({v[0]:.4g}, {v[1]:.4g}, "
                     f"{v[2]:.4g}) is {what}: sample skipped")
            return
        if self._sun_last is not None and t <= self._sun_last:
            self.bad("sun_out_of_order", f"{topic} at {t:.3f} s: stamp not after the previous "
                     f"sample's ({self._sun_last:.3f} s): sample skipped")
            return
        self._sun_last = t
        self.sun.samples += 1
        if self.sun.usable and self.use_imu:
            self._sun_pending.append((t, v))
            del self._sun_pending[:-64]

    def _sun_say(self, kind: str, level: int, text: str) -> None:
        """Log ``text`` the first time ``kind`` happens."""
        if kind not in self._sun_said:
            self._sun_said.add(kind)
            self._log(level, text)

    def _sun_update(self, t: float, out: VoOutput) -> None:
        """10. Sun heading: the newest held sample at least ``SUN_LEAD_S`` before the
        pair's stamp updates the heading of the state and of the reference frame
        (:mod:`rover_vo.sun_heading`);
        ``out`` then carries the updated state. No sample for a while: said once."""
        if not self.sun.usable or not self.use_imu or self.propagator is None:
            return
        cut = t - SUN_LEAD_S
        due = [s for s in self._sun_pending if s[0] <= cut]
        self._sun_pending = [s for s in self._sun_pending if s[0] > cut]
        if not due or t - due[-1][0] > MAX_SAMPLE_AGE_S:
            self._sun_outage(t)
            return
        if out.source != "zero_velocity":
            self.sun.in_motion += 1  # in motion the tilt is not known well enough
            return
        ts, v = due[-1]
        R_then_now = np.eye(3)
        if t - ts > 1e-6:
            iv = self.propagator.interval(ts, t)
            if iv is not None:
                R_then_now = iv.R
        # Standing still the mean specific force is gravity: roll and pitch from it.
        iv = self.propagator.interval(t - TILT_WINDOW_S, t)
        f = iv.mean_accel if iv is not None else None
        if f is None or abs(np.linalg.norm(f) - self.gravity) > 0.05 * self.gravity:
            return
        yaw = np.arctan2(self.state.R[1, 0], self.state.R[0, 0])
        attitude = Rotation.from_euler("z", yaw).as_matrix() @ self._gravity_tilt(f)
        meas = self.sun.measure(ts, v, R_then_now, attitude)
        if meas.problem in ("below_horizon", "elevation_mismatch"):
            self.bad("sun_not_sun", f"{m.TOPIC_SUN} at {ts:.3f} s: not the sun: "
                     f"{meas.detail}: sample skipped")
            return
        if meas.problem == "near_zenith":
            self.sun.near_zenith += 1
            self._sun_say("near_zenith", logging.INFO, f"{m.TOPIC_SUN} at {ts:.3f} s: "
                          f"{meas.detail}: no heading update while it is that high")
            return
        kf_state = self.kf.state if self.kf is not None else None
        result = self.sun.apply(meas, self.state, kf_state, t)
        if result == "initialized":
            sigma = self.sun.heading_sigma_deg(self.state.P)
            self._log(logging.INFO, f"{m.TOPIC_SUN} at {ts:.3f} s: sun heading on: the odom "
                      f"frame's x axis lies at grid yaw {math.degrees(self.sun.psi0):.2f} deg "
                      f"(1-sigma {sigma:.2f} deg), sun at {math.degrees(meas.elevation):.1f} "
                      "deg elevation")
        elif result == "rejected":
            self._sun_say("rejected", logging.WARNING, (
                f"{m.TOPIC_SUN} at {ts:.3f} s: heading {self.sun.last_innovation_deg:+.2f} deg "
                f"off the estimate, beyond its uncertainty (1-sigma "
                f"{self.sun.heading_sigma_deg(self.state.P):.2f} deg, the sample's "
                f"{math.degrees(math.sqrt(meas.variance)):.2f} deg): sample rejected (further "
                "ones counted in /vo/status sun.rejected)"))
        out.state = self.state.copy()

    def _sun_outage(self, t: float) -> None:
        """Say once why no sample updates the heading by the pair at ``t``."""
        rate = self.sun.sensor.rate_hz
        limit = max(SUN_OUTAGE_PERIODS / rate if rate > 0 else 0.0, SUN_OUTAGE_MIN_S)
        since = self._sun_last if self._sun_last is not None else self._sun_first_pair
        if since is None or t - since < limit:
            return
        self.sun.outages += 0 if self.sun.in_outage else 1
        self.sun.in_outage = True
        _, el = self.sun.site.sun_grid(t)
        last = (f"the last at {self._sun_last:.3f} s" if self._sun_last is not None
                else "none yet")
        if el <= 0.0:
            self._sun_say("night", logging.WARNING, (
                f"{m.TOPIC_SUN}: no sun by the pair at {t:.3f} s ({last}): the ephemeris puts "
                f"it {math.degrees(-el):.1f} deg below the horizon: heading from the gyro "
                "alone until a sample comes"))
        else:
            self._sun_say("silent", logging.WARNING, (
                f"{m.TOPIC_SUN}: no sample for {t - since:.1f} s by the pair at {t:.3f} s "
                f"({last}; the sun {math.degrees(el):.1f} deg up: outside the sensor's field "
                "of view or shadowed): heading from the gyro alone until a sample comes"))

    def _feed_camera_info(self, topic: str, msg: Any) -> None:
        side = "left" if topic == m.TOPIC_LEFT_INFO else "right"
        problem = camera_info_problem(msg, side)
        if problem is not None:
            self.info_problem[side] = f"{topic} at {m.stamp_s(msg):.3f} s: {problem}"
            self.bad("bad_camera_info", f"{self.info_problem[side]}: message skipped")
            return
        self.info_problem[side] = None
        self.info[side] = msg

    def _file_pairs(self, force: bool) -> None:
        """Move pairs, oldest first, from :attr:`halves` to :attr:`pairs`: the complete
        ones, and a half whose partner will not come: the other camera's images have gone
        past its stamp, or its own camera has taken ``WAIT_FRAMES`` newer images since
        (``force``: all, the end of the bag). A waiting half holds the pairs after it
        back, so that pairs are processed in time order; a lone half is processed as it
        is (counted missing, the IMU carries the odometry)."""
        tolerance_s = self.halves.tolerance_in_use_ns() * 1e-9 if self.halves.tolerance_ns else 0
        for key in sorted(self.halves.slots):
            slot = self.halves.slots[key]
            if len(slot) == 1:
                side = next(iter(slot))
                other = "right" if side == "left" else "left"
                t = m.seconds(key)
                partner = self.arrivals.newest(other)
                passed = partner is not None and partner > t + tolerance_s
                if not (force or passed or self.arrivals.newer(side, t) >= WAIT_FRAMES):
                    break
                self.lone_detail[key] = self.halves.lone_detail(key)
            self.halves.pop(key)
            self.pairs[key] = _Pair(key, slot.get("left"), slot.get("right"))

    @property
    def has_mast(self) -> bool:
        """Whether the camera moves on a mast (rover.yaml ``mast.*``; reads /joint_states)."""
        return self.poser is not None

    def _feed_joint_state(self, msg: Any) -> None:
        if self.poser is None:
            return  # a rover without a mast: its joints (wheels...) are not the camera's
        t, names, positions = m.joint_state(msg)
        try:
            self.poser.add(t, names, positions)
        except MastError as exc:
            if self.raise_joint_state_errors:
                raise
            self.bad("bad_joint_state", f"{exc}: message at {t:.3f} s left out")
            return
        self.arrivals.note("joints", t)
        self.counts.joint_states += 1

    def _joints_ready(self, t: float) -> bool:
        """A pair at ``t`` waits for a joint state at or after it, unless the other inputs
        have run ``WAIT_PERIODS`` joint-state periods past it (/joint_states never came,
        or stopped)."""
        if self.poser is None:
            return True
        return self.arrivals.covers("joints", t) or self.arrivals.overdue("joints", t)

    def _imu_ready(self, t: float) -> bool:
        """A pair at ``t`` waits for an IMU sample at or after it (the gyro covers its
        interval), unless the other inputs have run ``WAIT_PERIODS`` IMU periods past it
        (the IMU is silent)."""
        if not self.use_imu:
            return True
        return self.arrivals.covers("imu", t) or self.arrivals.overdue("imu", t)

    def _infos_ready(self, t: float) -> bool:
        """A pair at ``t`` waits for both camera infos until its camera has taken
        ``WAIT_FRAMES`` newer images."""
        if self.info["left"] is not None and self.info["right"] is not None:
            return True
        return max(self.arrivals.newer(side, t) for side in ("left", "right")) >= WAIT_FRAMES

    def _feed_imu(self, msg: Any) -> None:
        t = m.stamp_s(msg)
        gyro, accel = m.imu_sample(msg)
        problem = m.imu_problem(msg)
        if problem is not None:
            self.bad("imu_nan", f"{m.TOPIC_IMU} at {t:.3f} s: {problem}: sample skipped")
            return
        previous = self.arrivals.newest("imu")
        if previous is not None and t <= previous:
            if t == previous:
                self.bad("imu_duplicate", f"{m.TOPIC_IMU} at {t:.3f} s: stamp repeats the "
                         "previous sample's: sample skipped")
            else:
                self.bad("imu_out_of_order", f"{m.TOPIC_IMU} at {t:.3f} s: stamp before the "
                         f"previous sample's ({previous:.3f} s): sample skipped")
            return
        self.arrivals.note("imu", t)
        if self.propagator is None:
            # Extrinsics of the IMU come with the rig; hold samples until then.
            self._imu_prebuffer.append((t, gyro, accel))
            del self._imu_prebuffer[:-int(self.imu_rate * 30)]
            return
        kind = self.propagator.add(t, gyro, accel)
        if kind is not None:
            self.bad(kind, f"{m.TOPIC_IMU} at {t:.3f} s: {kind.replace('imu_', '')}: "
                     "sample skipped")
        else:
            self.counts.imu += 1

    def _drain(self, force: bool) -> list[VoOutput]:
        """Process pairs in time order once each is ready: both images, the camera infos,
        the IMU up to its stamp and, on a mast, a joint state at or after it; each input
        waited for a few of its own periods at most (:mod:`rover_vo.arrivals`), so that
        the first pose comes with the first pair's IMU and a dead sensor costs no more
        than that wait. Over DDS, topics arrive in any interleaving. A pair does not wait
        for the sun: it takes the samples come by then (the node takes the queued ones
        first, as it does the IMU's).
        """
        out: list[VoOutput] = []
        while self.pairs:
            t_ns = min(self.pairs)
            pair = self.pairs[t_ns]
            t = m.seconds(t_ns)
            ready = (self._infos_ready(t) and self._imu_ready(t) and self._joints_ready(t))
            if not (ready or force):
                break
            del self.pairs[t_ns]
            result = self._process_pair(pair)
            if result is not None:
                result.stamp_ns = t_ns
                out.append(result)
        return out

    # -- one stereo pair ----------------------------------------------------------------------
    def _ensure_rig(self) -> bool:
        if self.rig is not None:
            return True
        if self.info["left"] is None or self.info["right"] is None:
            return False
        try:
            self.rig = rig_from_camera_info(self.info["left"], self.info["right"], self.params)
        except RigError as exc:
            self.bad("bad_camera_info", str(exc))
            self.info = {"left": None, "right": None}
            return False
        self.propagator = Propagator(self.rig.base_R_imu, self.gyro_noise_density,
                                     self.gyro_bias_random_walk, GYRO_BIAS_SIGMA0)
        for t, g, a in self._imu_prebuffer:
            if self.propagator.add(t, g, a) is None:
                self.counts.imu += 1
        self._imu_prebuffer = []
        if self._resume is not None and "gyro_bias" in self._resume:
            self.propagator.bias = self._resume["gyro_bias"].copy()
            self.propagator.bias_cov = self._resume["gyro_bias_cov"].copy()
        return True

    def _decode(self, pair: _Pair) -> tuple[np.ndarray, np.ndarray] | None:
        """The pair's ``(left, right)`` images, rectified; None (counted) when unusable."""
        t = pair.t_ns * 1e-9
        left_topic = self.image_topics["left"]
        if pair.left is None or pair.right is None:
            side = "left" if pair.left is None else "right"
            other = "right" if side == "left" else "left"
            self.bad(f"missing_{side}", f"{self.image_topics[side]} at {t:.3f} s: no {side} "
                     f"image beside the {other} one{self.lone_detail.pop(pair.t_ns, '')}: "
                     "pair not used")
            return None
        if not self._ensure_rig():
            self.bad("missing_camera_info", self._no_camera_info(t))
            return None
        decoded = {}
        for side, msg in (("left", pair.left), ("right", pair.right)):
            topic = self.image_topics[side]
            encoding = getattr(msg, "encoding", None)
            if encoding is not None and str(encoding) not in RAW_ENCODINGS:
                self.bad("unsupported_encoding", f"{topic} at {t:.3f} s: encoding "
                         f"'{encoding}' is not one rover_vo reads ({', '.join(RAW_ENCODINGS)})"
                         ": pair not used")
                return None
            img = m.decode_image(msg)
            if img is None:
                self.bad("corrupt_image", f"{topic} at {t:.3f} s: image does not decode "
                         f"({describe(msg)}): pair not used")
                return None
            decoded[side] = img
        problem = self._size_problem(t, decoded)
        if problem is not None:
            self.bad("bad_image_size", f"{problem}: pair not used")
            return None
        images = []
        for side in ("left", "right"):
            img = decoded[side]
            if self.cfg.features.rectify:
                try:
                    img = self.rectifiers(side, self.info[side], img)
                except ValueError as exc:
                    self.bad("bad_camera_info", str(exc))
                    return None
            images.append(img)
        left = images[0]
        small = left[::4, ::4]
        if np.mean(small >= 250) > 0.5:
            self.bad("overexposed", f"{left_topic} at {t:.3f} s: image is over-exposed "
                     "(more than half its pixels saturated): pair not used")
            return None
        if float(small.std()) < 2.0:
            self.bad("textureless", f"{left_topic} at {t:.3f} s: image has no texture (grey "
                     "level sigma < 2): pair not used")
            return None
        return images[0], images[1]

    def _no_camera_info(self, t: float) -> str:
        """Why a pair at ``t`` has no rig: the sides without a usable CameraInfo, and what
        was wrong with the last one of each."""
        topics = {"left": m.TOPIC_LEFT_INFO, "right": m.TOPIC_RIGHT_INFO}
        lacking = [s for s in ("left", "right") if self.info[s] is None] or ["left", "right"]
        said = []
        for side in lacking:
            why = self.info_problem[side]
            said.append(f"{topics[side]} ({'the last one: ' + why if why else 'none came'})")
        return (f"no usable CameraInfo by the pair at {t:.3f} s: {'; '.join(said)}: pair "
                "not used")

    def _size_problem(self, t: float, decoded: dict[str, np.ndarray]) -> str | None:
        """What is wrong with the sizes of a pair's images, naming the image that is off:
        against its own CameraInfo, against the other half, against the rig's (the first
        CameraInfo's) size; None when they agree."""
        infos = {"left": m.TOPIC_LEFT_INFO, "right": m.TOPIC_RIGHT_INFO}
        for side in ("left", "right"):
            h, w = decoded[side].shape[:2]
            info = self.info[side]
            if (h, w) != (int(info.height), int(info.width)):
                return (f"{self.image_topics[side]} at {t:.3f} s: image is {w}x{h}, its "
                        f"CameraInfo ({infos[side]}) says {info.width}x{info.height}")
        (hl, wl), (hr, wr) = decoded["left"].shape[:2], decoded["right"].shape[:2]
        if (hl, wl) != (hr, wr):
            return (f"{self.image_topics['right']} at {t:.3f} s: image is {wr}x{hr} beside "
                    f"the left one's {wl}x{hl} (the two images of a pair must be of one size)")
        if (hl, wl) != (self.rig.height, self.rig.width):
            return (f"{self.image_topics['left']} at {t:.3f} s: image is {wl}x{hl}, the "
                    f"first CameraInfo (the rig's calibration) {self.rig.width}x"
                    f"{self.rig.height}")
        return None

    def _process_pair(self, pair: _Pair) -> VoOutput | None:
        out = self._process_pair_images(pair)
        if out is not None and self.sun.sensor is not None:
            if self._sun_first_pair is None:
                self._sun_first_pair = out.state.t
            self._sun_update(out.state.t, out)
        return out

    def _process_pair_images(self, pair: _Pair) -> VoOutput | None:
        t = pair.t_ns * 1e-9
        self.last_pair_ns = pair.t_ns
        self.counts.pairs += 1
        self.stats = FrameStats()
        images = self._decode(pair)
        if self.state is None:
            if images is None:
                return None
            return self._initialize(t, *images, base_T_left=self._camera_at(t))
        # 2. IMU propagation: the gyro over the interval (rotation prior: _vision, _predict).
        iv = self._imu_interval(self.state.t, t)
        if images is None:
            return self._propagate(t, iv)
        # 3. Camera pose: a pair taken off the reference's camera pose measures the mast,
        # not the rover.
        camera = self._camera_at(t)
        if not same_pose(camera, self.kf.base_T_left):
            return self._mast_moved(t, iv, camera, images)
        self._settling = None
        left = images[0]
        # 4. Zero velocity. Detection: standing still, nothing moves (no drift at stops).
        flow = image_motion_px(self.last_image, left, self.kf.tracked[self.kf.alive])
        if is_stationary(flow, iv, self.cfg.imu):
            out = self._zero_velocity(t, iv, left)
        else:
            out = self._vision(t, iv, images)
        self._after_mast = False
        return out

    def _camera_at(self, t: float) -> np.ndarray:
        """The left camera's pose in base_link at ``t``: the fixed one, or the mast's at the
        joint angles of ``t``. Without a joint state within the tolerance (counted), the
        last known pose, or before any, rover.yaml's ``base_to_left_camera`` (the drive
        pose)."""
        if self.poser is None:
            return self.rig.base_T_left
        pose = self.poser.pose_at(t)
        if not isinstance(pose, str):
            self._last_camera = pose.base_T_left
            return pose.base_T_left
        self.counts.no_joint_states += 1
        topic = m.TOPIC_JOINT_STATES
        used = ("the last known joint angles" if self._last_camera is not None else
                "rover.yaml's base_to_left_camera (the drive pose)")
        if pose == NO_JOINT_STATES:
            self.bad(pose, f"{topic}: no joint state of the mast "
                     f"({', '.join(self.mast.joints)}) by the pair at {t:.3f} s: the "
                     f"camera is taken at {used}")
        else:
            self.bad(pose, f"{topic}: no joint state within {self.poser.tolerance_s:g} s of "
                     f"the pair at {t:.3f} s (newest at {self.poser.last_stamp:.3f} s): the "
                     f"camera is taken at {used}")
        return self.rig.base_T_left if self._last_camera is None else self._last_camera

    def _mast_moved(self, t: float, iv: ImuInterval | None, camera: np.ndarray,
                    images: tuple[np.ndarray, np.ndarray]) -> VoOutput:
        """A pair off the reference's camera pose: the rover is held as at a stop (the
        IMU alone decides whether it stands still), and the reference is kept for the
        mast's return. A new pose held for ``MAST_SETTLE_FRAMES`` pairs gets a new
        reference."""
        self.counts.mast_moved += 1
        self._after_mast = True
        n = 1
        if self._settling is not None and same_pose(camera, self._settling[0]):
            n = self._settling[1] + 1
        self._settling = (camera if n == 1 else self._settling[0], n)
        if iv is None or iv.max_rate < self.cfg.imu.zero_velocity_gyro_rad_s:
            # Standing still by the gyro (without one: a mast moves at stops).
            out = self._zero_velocity(t, iv, None)
        else:
            out = self._propagate(t, iv, standing=True)
        if n >= MAST_SETTLE_FRAMES:
            self._log(logging.INFO, f"camera pose in base_link changed and held for {n} "
                      f"pairs at {t:.3f} s: a new reference frame there")
            self._new_keyframe(*images, base_T_left=camera)
            self.last_image = images[0]
            self.counts.mast_reanchors += 1
            self._settling = None
        return out

    def _imu_interval(self, t0: float, t1: float) -> ImuInterval | None:
        if not self.use_imu or self.propagator is None:
            return None
        iv = self.propagator.interval(t0, t1)
        if iv is None or iv.gap > self.cfg.imu.max_gap_s:
            gap = (t1 - t0) if iv is None else iv.gap
            self.bad("imu_gap", f"{m.TOPIC_IMU}: no sample for {gap:.2f} s before "
                     f"{t1:.3f} s (gyro held or unused)")
            if iv is None:
                return None
        return iv

    def _gravity_tilt(self, accel_b: np.ndarray) -> np.ndarray:
        """Roll and pitch (as ``odom_R_base`` with zero yaw) of a mean specific force."""
        up = accel_b / np.linalg.norm(accel_b)
        # The rotation taking body 'up' to odom z; its yaw is removed below.
        R = Rotation.align_vectors([[0, 0, 1]], [up])[0].as_matrix()
        yaw = np.arctan2(R[1, 0], R[0, 0])
        return Rotation.from_euler("z", -yaw).as_matrix() @ R

    def _initialize(self, t: float, left: np.ndarray, right: np.ndarray,
                    base_T_left: np.ndarray) -> VoOutput:
        if self._resume is not None:
            resumed = self._resumed_state(t)
            if resumed is not None:
                self.state = resumed
                self._new_keyframe(left, right, base_T_left)
                self.last_image = left
                self.source = "resumed"
                return VoOutput(self.state.copy(), np.zeros(3), np.zeros(3), "resumed")
        R0 = np.eye(3)
        if self.use_imu and self.propagator is not None:
            iv = self.propagator.interval(t - 1.0, t)
            if iv is not None:
                R0 = self._gravity_tilt(iv.mean_accel)  # gravity gives roll and pitch
        c = self.cfg.covariance
        self.state = OdomState(t, R0, P=systematic_prior(
            c.scale_sigma, c.heading_rate_sigma_deg_per_100m))
        self._new_keyframe(left, right, base_T_left)
        self.last_image = left
        self.source = "initial"
        return VoOutput(self.state.copy(), np.zeros(3), np.zeros(3), "initial")

    def _resumed_state(self, t: float) -> OdomState | None:
        """The saved state carried over the gap to ``t`` (see :meth:`resume`); None (and
        a fresh odom frame) when the snapshot is newer than the pair."""
        snap, self._resume = self._resume, None
        gap = t - snap["t"]
        if gap < 0:
            self._log(logging.WARNING, f"saved state at {snap['t']:.3f} s is newer than the "
                      f"first pair ({t:.3f} s): not resumed, a new odom frame starts")
            return None
        # The rover went on at its last velocity, or stopped, or turned: the prediction holds
        # the heading and goes straight on, and the covariance takes half the fastest
        # speed and turn seen so far, times the gap (1 sigma: a rover at full speed or
        # turning at full rate the whole gap is 2 sigma off).
        v = snap["linear"]
        dp = np.array([v[0], v[1], 0.0]) * gap
        sigma_p = RESUME_MOTION_FRACTION * snap["max_speed"] * gap
        sigma_yaw = RESUME_MOTION_FRACTION * snap["max_turn_rate"] * gap
        Q = np.zeros((6, 6))
        Q[:2, :2] = np.eye(2) * sigma_p**2
        Q[2, 2] = (0.1 * sigma_p) ** 2
        Q[5, 5] = min(sigma_yaw, np.pi) ** 2
        base = OdomState(snap["t"], snap["R"], snap["p"], snap["P"], snap["distance_m"])
        new = base.compose(t, np.eye(3), dp, Q)
        self.max_speed, self.max_turn_rate = snap["max_speed"], snap["max_turn_rate"]
        self.last_step = (Rotation.from_rotvec(snap["last_step"][0]).as_matrix(),
                          snap["last_step"][1].copy())
        self._log(logging.WARNING, f"resumed the odom frame of the saved state at "
                  f"{snap['t']:.3f} s after a {gap:.1f} s gap: moved "
                  f"{np.linalg.norm(dp):.2f} m at the saved velocity, 1-sigma "
                  f"{sigma_p:.2f} m and {np.degrees(sigma_yaw):.1f} deg added")
        return new

    def _new_keyframe(self, left: np.ndarray, right: np.ndarray,
                      base_T_left: np.ndarray | None = None) -> None:
        """A new reference frame at the current state, its camera at ``base_T_left``
        (default: the current reference's)."""
        f = self.cfg.features
        rig = self.rig
        T = self.kf.base_T_left if base_T_left is None else base_T_left
        if T is not rig.base_T_left:
            rig = dataclasses.replace(rig, base_T_left=T)
        self.kf, n_corners, n_stereo = make_keyframe(self.state, left, right, rig,
                                                     f.max_corners, f.max_depth_m)
        self.counts.keyframes += 1
        self.stats.keyframe = True
        self.stats.features, self.stats.stereo_matches = n_corners, n_stereo

    def _output(self, new: OdomState, source: str, moving: bool) -> VoOutput:
        dt = max(new.t - self.state.t, 1e-6)
        dR = self.state.R.T @ new.R
        dp = self.state.R.T @ (new.p - self.state.p)
        if moving:
            self.last_step = (dR, dp)
        self.velocity = (dp / dt, Rotation.from_matrix(dR).as_rotvec() / dt)
        if moving:
            self.max_speed = max(self.max_speed, float(np.linalg.norm(self.velocity[0][:2])))
            self.max_turn_rate = max(self.max_turn_rate, abs(float(self.velocity[1][2])))
        self.state = new
        self.source = source
        return VoOutput(new.copy(), *self.velocity, source)

    def _zero_velocity(self, t: float, iv: ImuInterval | None,
                       left: np.ndarray | None) -> VoOutput:
        """Standing still: the pose held. ``left`` becomes the last image (None: a mast
        frame, whose view is not the reference's)."""
        self.counts.zero_velocity += 1
        new = self.state.copy()
        new.t = t
        if iv is not None:
            self.propagator.update_bias_at_rest(t, iv, self.imu_rate)
            new.R = self._tilt_update(new.R, iv, stationary=True)
            self.kf.state.R = self._tilt_update(self.kf.state.R, iv, stationary=True)
        if left is not None:
            self.last_image = left
        self.stats.tracked = self.kf.n_alive
        return self._output(new, "zero_velocity", moving=False)

    def _tilt_update(self, R: np.ndarray, iv: ImuInterval, stationary: bool) -> np.ndarray:
        """Roll and pitch pulled toward the accelerometer's gravity (yaw untouched)."""
        f = iv.mean_accel
        g = self.gravity
        if abs(np.linalg.norm(f) - g) > 0.05 * g:
            return R  # accelerating: the mean specific force is not gravity
        up_b = R.T @ np.array([0.0, 0.0, 1.0])
        f_hat = f / np.linalg.norm(f)
        axis = np.cross(up_b, f_hat)
        s = np.linalg.norm(axis)
        if s < 1e-12:
            return R
        angle = np.arctan2(s, up_b @ f_hat)
        sigma_meas = np.radians(self.cfg.imu.accel_tilt_sigma_deg) / (3.0 if stationary else 1)
        sigma_state = np.sqrt(max(self.state.cov[3, 3] + self.state.cov[4, 4], 1e-12) / 2)
        gain = sigma_state**2 / (sigma_state**2 + sigma_meas**2)
        # R' = R Exp(phi) with Exp(-phi) up_b -> f_hat: phi = -angle * axis.
        return R @ Rotation.from_rotvec(-gain * angle * axis / s).as_matrix()

    def _predict(self, iv: ImuInterval | None) -> tuple[np.ndarray, np.ndarray]:
        """Predicted body motion of this interval: gyro rotation, last step's translation
        (none right after mast frames: the rover stood while its mast moved)."""
        dR_last, dp_last = self.last_step
        if self._after_mast:
            dp_last = np.zeros(3)
        return (iv.R if iv is not None else dR_last), dp_last

    def _propagate(self, t: float, iv: ImuInterval | None, standing: bool = False,
                   step: np.ndarray | None = None) -> VoOutput:
        """No usable image: dead-reckon with the gyro and the last step (``step``: that
        translation instead; ``standing``: none, a mast frame at a stop), covariance
        growing."""
        self.counts.propagated += 1
        dR, dp = self._predict(iv)
        if step is not None:
            dp = step
        if standing:
            dp = np.zeros(3)
        cov = self.cfg.covariance
        step = float(np.linalg.norm(dp))
        Q = step_noise(step, cov.propagation_translation_sigma,
                       cov.rotation_sigma_deg_per_sqrt_m * 10.0)
        # Unseen, the rover may also have moved when the last step says it stood still.
        Q[:3, :3] += np.eye(3) * PROPAGATION_FLOOR_M**2
        if iv is None:
            # No gyro: the rotation is the last step's guess; a turn may have started.
            Q[3:, 3:] += np.eye(3) * np.radians(UNSEEN_ROTATION_SIGMA_DEG) ** 2
        else:
            Q[3:, 3:] += iv.cov  # the gyro's own integration noise and bias uncertainty
        new = self.state.compose(t, dR, dp, Q)
        return self._output(new, "imu_propagation", moving=False)

    def _cam(self) -> tuple[np.ndarray, np.ndarray]:
        """The reference's camera pose in base_link (the current pair's: step 3)."""
        T = self.kf.base_T_left
        return T[:3, :3], T[:3, 3]

    def _camera_from_keyframe(self, odom_R_b: np.ndarray, odom_p_b: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Left-camera transform keyframe -> a body pose (``x_cur = R x_kf + t``)."""
        R_bc, p_bc = self._cam()
        kf = self.kf.state
        Rk, pk = kf.R @ R_bc, kf.R @ p_bc + kf.p
        Rc, pc = odom_R_b @ R_bc, odom_R_b @ p_bc + odom_p_b
        return Rc.T @ Rk, Rc.T @ (pk - pc)

    def _predict_pixels(self, X: np.ndarray, idx: np.ndarray, dR: np.ndarray, dp: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Where keyframe points ``X`` land if the body moves by ``(dR, dp)`` from the last
        state: ``(cur_R_kf, cur_t_kf, points in the current camera, pixels)``."""
        rig = self.rig  # intrinsics; the camera's pose is the reference's (_cam)
        R_guess, t_guess = self._camera_from_keyframe(self.state.R @ dR,
                                                      self.state.p + self.state.R @ dp)
        Xp = X @ R_guess.T + t_guess
        in_front = Xp[:, 2] > 0.1
        predicted = self.kf.tracked[idx].copy()
        predicted[in_front] = (Xp[in_front, :2] / Xp[in_front, 2:]) * [rig.fx, rig.fy] + [
            rig.cx, rig.cy]
        return R_guess, t_guess, Xp, predicted

    def _track_and_estimate(self, t: float, iv: ImuInterval | None, images: tuple,
                            idx: np.ndarray, dR: np.ndarray, dp: np.ndarray
                            ) -> tuple[np.ndarray, np.ndarray, MotionEstimate | None,
                                       MotionEstimate | None]:
        """Steps 5-7 for the predicted body motion ``(dR, dp)``: the keyframe points
        ``idx`` tracked into the pair, matched in its right image, and the motion; returns
        ``(tracked pixels, tracked mask, vision-only estimate, fused estimate)`` (None
        when the motion was not found)."""
        cfg, rig, kf = self.cfg, self.rig, self.kf
        left, right = images
        X = kf.points[idx]
        need = cfg.motion.min_inliers
        # 5. Tracking: LK from the keyframe's own image (no tracking drift accumulates over
        # its span), starting where the predicted motion puts each keyframe point.
        R_guess, t_guess, Xp, predicted = self._predict_pixels(X, idx, dR, dp)
        uv, ok = track(kf.image, left, kf.corners[idx], predicted)
        # Fallbacks: from the last image (a shorter hop); without a gyro, a few turn rates
        # around the last one (a turn starting is what the last step cannot predict); then
        # with no prediction at all.
        if ok.sum() < need:
            uv, ok = track(self.last_image, left, kf.tracked[idx], predicted)
        if ok.sum() < need and iv is None:
            for yaw in np.radians([-5.0, 5.0, -10.0, 10.0, -15.0, 15.0]):
                turn = Rotation.from_euler("z", yaw).as_matrix() @ dR
                guess = self._predict_pixels(X, idx, turn, dp)
                uv2, ok2 = track(self.last_image, left, kf.tracked[idx], guess[3])
                if ok2.sum() >= need:
                    uv, ok = uv2, ok2
                    R_guess, t_guess, Xp, predicted = guess
                    break
        if ok.sum() < need:
            uv, ok = track(self.last_image, left, kf.tracked[idx])
        in_front = Xp[:, 2] > 0.1
        self.stats.tracked = int(ok.sum())
        est = est_vo = None
        if ok.sum() >= cfg.motion.min_inliers:
            # 6. Stereo and reconstruction (points triangulated in make_keyframe).
            # Right image: each tracked corner is searched where its predicted depth puts it.
            disp_guess = np.where(in_front, rig.fx * rig.baseline_m / np.maximum(Xp[:, 2], 0.5),
                                  3.0)[ok]
            disparity, sok = stereo_match(left, right, uv[ok], rig.fx, rig.baseline_m,
                                          disp_guess)
            uv_r = np.full((int(ok.sum()), 2), np.nan)
            uv_r[sok] = uv[ok][sok] - np.column_stack([disparity[sok], np.zeros(sok.sum())])
            prior = prior_cov = None
            if iv is not None:
                prior, prior_cov = self._gyro_prior(kf.state.t, t)
            # 7. Outlier rejection and motion: PnP RANSAC, refinement, then the gyro prior.
            K = rig.camera_matrix
            est_vo = estimate_motion(X[ok], uv[ok], uv_r, K, rig.baseline_m, cfg.motion,
                                     R_guess, t_guess)
            est = est_vo
            if est_vo is not None and prior is not None:
                # VO + IMU fusion: the same inliers, the gyro rotation as a prior.
                inl = est_vo.inliers
                est = refine_motion(X[ok][inl], uv[ok][inl], uv_r[inl], K, rig.baseline_m,
                                    est_vo.R, est_vo.t, cfg.motion, prior, prior_cov)
                est.inliers = inl
        return uv, ok, est_vo, est

    def _vision(self, t: float, iv: ImuInterval | None, images: tuple) -> VoOutput:
        cfg, kf = self.cfg, self.kf
        left, right = images
        R_bc, p_bc = self._cam()
        dR, dp = self._predict(iv)
        idx = np.flatnonzero(kf.alive)
        uv, ok, est_vo, est = self._track_and_estimate(t, iv, images, idx, dR, dp)
        # A rover that stood (its last step a standing one) and whose image now moves
        # drives on at its pace: when the track is lost, the last drive step is tried as
        # the prediction, and is the dead-reckoned step if that fails too.
        resumed = (self.drive_step is not None and not self._after_mast
                   and not np.allclose(self.drive_step, dp))
        if est is None and resumed:
            self.counts.drive_step_predictions += 1
            retry = self._track_and_estimate(t, iv, images, idx, dR, self.drive_step)
            if retry[3] is not None:
                uv, ok, est_vo, est = retry
        if est is None:
            self.bad("vision_failed", f"{self.image_topics['left']}: too few tracked inliers "
                     f"at {t:.3f} s (motion from the IMU and the last step)")
            out = self._propagate(t, iv, step=self.drive_step if resumed else None)
            # The keyframe is lost: start a new one where the propagated pose puts us.
            self._new_keyframe(left, right)
            self.last_image = left
            return out
        self.counts.vision += 1
        inl = est.inliers
        self.stats.inliers, self.stats.rms_px = int(inl.sum()), est.rms_px
        # Body motion keyframe -> current from the camera motion.
        kf_R_cur_c, kf_p_cur_c = est.R.T, -est.R.T @ est.t
        kf_R_b = R_bc @ kf_R_cur_c @ R_bc.T
        kf_p_b = R_bc @ kf_p_cur_c + p_bc - kf_R_b @ p_bc
        # 8. Covariance: the refinement's covariance against the distance model, composed.
        cov_cam = est.cov
        rot = np.zeros((6, 6))
        rot[:3, :3] = rot[3:, 3:] = R_bc
        cov_b = rot @ cov_cam @ rot.T
        c = self.cfg.covariance
        span = float(np.linalg.norm(kf_p_b))
        Q = step_noise(span, c.translation_sigma_per_m, c.rotation_sigma_deg_per_sqrt_m, cov_b)
        new = kf.state.compose(t, kf_R_b, kf_p_b, Q)
        new.distance_m = self.state.distance_m + float(np.linalg.norm(new.p - self.state.p))
        # Track bookkeeping: outliers and lost corners leave the keyframe.
        alive = np.zeros(len(kf.points), bool)
        alive[idx[np.flatnonzero(ok)[inl]]] = True
        kf.tracked[idx[ok]] = uv[ok]
        kf.alive = alive
        kf.frames += 1
        out = self._output(new, "vision", moving=True)
        # A step at half the fastest speed seen or more is the rover driving, not standing.
        speed = float(np.linalg.norm(self.velocity[0][:2]))
        if speed >= DRIVE_SPEED_FRACTION * self.max_speed > 0.0:
            self.drive_step = self.last_step[1]
        self.last_image = left
        tracked_frac = kf.n_alive / max(len(kf.points), 1)
        w = cfg.window
        # The last frame becomes the reference once it is far enough from it (each pair of
        # a 0.45 m-spaced bag; every few pairs of a camera that streams), or tracking thins.
        turn = np.degrees(Rotation.from_matrix(kf_R_b).magnitude())
        if (span >= w.frame_to_frame_min_travel_m or turn >= w.frame_to_frame_min_turn_deg
                or tracked_frac < REFERENCE_MIN_TRACKED):
            if iv is not None:
                # Gyro bias from the vision rotation over the keyframe span (one update per
                # keyframe: the frames inside a span share their measurements).
                R_vo_b = R_bc @ est_vo.R.T @ R_bc.T
                rot3 = R_bc @ est_vo.cov[:3, :3] @ R_bc.T
                self.propagator.update_bias_from_rotation(kf.state.t, t, R_vo_b, rot3)
                # 9. Gravity from the accelerometer just before the frame (the body tilts as
                # it drives over relief: a mean over the whole span would lag).
                recent = self.propagator.interval(t - TILT_WINDOW_S, t)
                if recent is not None:
                    self.state.R = self._tilt_update(self.state.R, recent, stationary=False)
            self._new_keyframe(left, right)
            self.stats.inliers = int(inl.sum())
        return out

    def _gyro_prior(self, t0: float, t1: float) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The gyro's ``cur_R_kf`` (left camera) over ``[t0, t1]`` and its covariance."""
        iv = self.propagator.interval(t0, t1)
        if iv is None:
            return None, None
        R_bc, _ = self._cam()
        kf_R_cur = R_bc.T @ iv.R @ R_bc
        cov_c = R_bc.T @ iv.cov @ R_bc
        cur_R_kf = kf_R_cur.T
        return cur_R_kf, kf_R_cur.T @ cov_c @ kf_R_cur

    # -- status ---------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        """Figures for /vo/status: per-frame counts, state and bad-input totals."""
        s, c = self.stats, self.counts
        out: dict[str, Any] = {
            "state": self.source,
            "features": s.features, "stereo_matches": s.stereo_matches, "tracked": s.tracked,
            "inliers": s.inliers, "reprojection_rms_px": round(s.rms_px, 3),
            "keyframe": s.keyframe, "pairs": c.pairs, "vision_frames": c.vision,
            "zero_velocity_frames": c.zero_velocity, "propagated_frames": c.propagated,
            "keyframes": c.keyframes, "imu_samples": c.imu,
            "joint_state_samples": c.joint_states, "mast_moved_frames": c.mast_moved,
            "frames_without_joint_states": c.no_joint_states,
            "mast_reanchors": c.mast_reanchors,
            "drive_step_predictions": c.drive_step_predictions,
            "distance_m": round(self.state.distance_m, 3) if self.state else 0.0,
        }
        if self.propagator is not None:
            out["gyro_bias_rad_s"] = [round(float(b), 6) for b in self.propagator.bias]
        out.update(self.sun_status())
        for kind in BAD_INPUT_KINDS:
            out[f"bad_input.{kind}"] = c.bad.get(kind, 0)
        out["last_bad_input"] = self.last_bad
        return out

    def sun_status(self) -> dict[str, Any]:
        """The sun heading's figures (``sun.*`` in /vo/status)."""
        sun = self.sun
        t = self.state.t if self.state is not None else None
        if sun.sensor is None:
            state = "off"
        elif self.sun_refused is not None:
            state = "refused"
        elif sun.psi0 is None:
            state = "waiting"
        elif sun.in_outage:
            state = "no_sun"
        else:
            state = "updating"
        P = self.state.P if self.state is not None else np.zeros((N_ERR, N_ERR))
        psi0 = math.degrees(sun.psi0) if sun.psi0 is not None else math.nan
        return {"sun.state": state, "sun.samples": sun.samples, "sun.updates": sun.updates,
                "sun.rejected": sun.rejected, "sun.near_zenith": sun.near_zenith,
                "sun.in_motion": sun.in_motion,
                "sun.outages": sun.outages, "sun.heading_bounded": sun.bounded(t),
                "sun.odom_grid_yaw_deg": round(psi0, 4),
                "sun.heading_sigma_deg": round(sun.heading_sigma_deg(P), 4),
                "sun.elevation_deg": round(sun.last_elevation_deg, 3)}

    def bad_input_summary(self) -> str:
        """One line of the bad input so far: each kind's count and the first one said."""
        return "; ".join(f"{kind} x{n} (first: {self.first_bad.get(kind, '?')})"
                         for kind, n in sorted(self.counts.bad.items()))
