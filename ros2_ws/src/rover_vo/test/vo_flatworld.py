"""A flat textured world for the mast tests: a rover driving straight along +x on the
plane z = 0, its stereo head on a pan-tilt mast (the geometry of roi_network's mast test,
which puts the left camera at the drive angles where rover.yaml's ``base_to_left_camera``
has it), rendered for any mast angles by intersecting each pixel's ray with the ground.

The ground texture is three octaves of blurred noise, each faded by the ground footprint
of a pixel (a procedural mip-map: far ground is smooth, not aliased), so that corners are
stable where they are seen. The IMU reads gravity and a small gyro bias with white noise
(the rover never turns or tilts); ``/joint_states`` comes at 10 Hz and at every pair's
stamp, as the simulator writes it. Messages are rosbags' classes, so a stream can be fed
to the estimator or written to a bag.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from roi_network.mast import MastKinematics, pose_list

W, H, FX, CX, CY, BASELINE = 640, 480, 457.0, 319.5, 239.5, 0.2
DRIVE_TILT = math.radians(20.0)
TEXEL_M = 0.02
OCTAVES_TEXELS = (1.0, 4.0, 16.0)
START_NS = 1_700_000_000_000_000_000
GYRO_BIAS = (4e-4, -3e-4, 2e-4)
GYRO_NOISE = 1e-3  # rad/s per sample
JOINTS = ("mast_pan", "mast_tilt")

OPTICAL = Rotation.from_matrix(np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)).as_quat()
MAST = {
    "mast.pan_joint": "mast_pan", "mast.pan_origin": [0.4, 0.0, 1.3, 0, 0, 0, 1],
    "mast.pan_axis": [0, 0, 1], "mast.pan_limits": [-math.pi, math.pi],
    "mast.tilt_joint": "mast_tilt", "mast.tilt_origin": [0, 0, 0.24, 0, 0, 0, 1],
    "mast.tilt_axis": [0, 1, 0], "mast.tilt_limits": [-0.5, 1.2],
    "mast.head_to_left_camera": [0.0, 0.1, 0.0, *OPTICAL.tolist()],
}
KIN = MastKinematics.from_params(MAST)


def rover_params(mast: bool = True) -> dict:
    """Flat rover.yaml parameters of the world's rover (``mast``: with its mast.*)."""
    params = {"base_to_left_camera": pose_list(KIN.base_T_left(0.0, DRIVE_TILT)),
              "base_to_imu": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "imu_rate_hz": 50.0,
              "gyro_noise_density": 1.7e-4, "gyro_bias_random_walk": 2.0e-5, "gravity": 9.81}
    if mast:
        params.update(MAST)
    return params


@dataclass
class Frame:
    """A stereo pair: stamp (s from the start), rover x (m), mast angles (rad)."""

    t: float
    x: float
    pan: float = 0.0
    tilt: float = DRIVE_TILT


@dataclass
class Schedule:
    """Frames in time order, built by :meth:`drive`, :meth:`stand` and :meth:`look`."""

    frames: list[Frame] = field(default_factory=list)
    period_s: float = 2.0

    @property
    def t(self) -> float:
        return self.frames[-1].t if self.frames else 0.0

    @property
    def x(self) -> float:
        return self.frames[-1].x if self.frames else 0.0

    @property
    def mast(self) -> tuple[float, float]:
        f = self.frames[-1] if self.frames else Frame(0, 0)
        return f.pan, f.tilt

    def drive(self, n: int, step_m: float = 0.35, tilt: float | None = None) -> Schedule:
        """``n`` pairs ``step_m`` apart, the mast at (pan 0, ``tilt``: the last one's)."""
        tilt = self.mast[1] if tilt is None else tilt
        for _ in range(n):
            first = not self.frames
            self.frames.append(Frame(self.t + (0 if first else self.period_s),
                                     self.x + (0 if first else step_m), 0.0, tilt))
        return self

    def stand(self, n: int, pan: float | None = None, tilt: float | None = None,
              period_s: float = 5.0) -> Schedule:
        """``n`` pairs standing still ``period_s`` apart, the mast at (pan, tilt)."""
        pan0, tilt0 = self.mast
        pan = pan0 if pan is None else pan
        tilt = tilt0 if tilt is None else tilt
        for _ in range(n):
            self.frames.append(Frame(self.t + period_s, self.x, pan, tilt))
        return self

    def look(self, pans_deg: tuple[float, ...], tilt: float,
             period_s: float = 5.0) -> Schedule:
        """A panorama standing still: one pair at each pan angle (deg)."""
        for pan in pans_deg:
            self.stand(1, math.radians(pan), tilt, period_s)
        return self


#: A stop with a panorama, as the simulator takes it: two pairs at the drive pose, six
#: views 60 deg apart at 25 deg tilt, the mast back at the drive pose, two more pairs.
PANORAMA = (-150.0, -90.0, -30.0, 30.0, 90.0, 150.0)
PANORAMA_TILT = math.radians(25.0)


def panorama_schedule(with_panorama: bool = True, period_s: float = 5.0,
                      drive: int = 6, stand: int = 2) -> Schedule:
    """Drive ``drive`` pairs, stop (``stand`` pairs at the drive pose, the panorama if
    ``with_panorama``, ``stand`` more; ``period_s`` apart), drive ``drive`` more."""
    s = Schedule().drive(drive).stand(stand, period_s=period_s)
    if with_panorama:
        s.look(PANORAMA, PANORAMA_TILT, period_s)
    return s.stand(stand, 0.0, DRIVE_TILT, period_s).drive(drive)


class World:
    """The textured ground and the renderer."""

    def __init__(self, seed: int = 3, size: int = 2048) -> None:
        rng = np.random.default_rng(seed)
        self.octaves = []
        for sigma, weight in zip(OCTAVES_TEXELS, (18.0, 20.0, 22.0), strict=True):
            pad = int(4 * sigma) + 1  # a periodic blur: the texture tiles the plane
            noise = np.pad(rng.normal(size=(size, size)).astype(np.float32), pad, "wrap")
            o = cv2.GaussianBlur(noise, (0, 0), sigma)[pad:-pad, pad:-pad]
            self.octaves.append(o * (weight / float(o.std())))
        self.size = size
        self.rng = np.random.default_rng(seed + 1)
        v, u = np.mgrid[0:H, 0:W].astype(np.float64)
        self.rays = np.stack([(u - CX) / FX, (v - CY) / FX, np.ones_like(u)], axis=-1)

    def render(self, world_T_cam: np.ndarray) -> np.ndarray:
        """8-bit grey image of the ground seen by a camera (4x4 pose, optical frame)."""
        R, c = world_T_cam[:3, :3], world_T_cam[:3, 3]
        d = self.rays @ R.T
        hit = d[..., 2] < -1e-6
        s = np.where(hit, -c[2] / np.where(hit, d[..., 2], -1.0), 0.0)
        gx, gy = c[0] + s * d[..., 0], c[1] + s * d[..., 1]
        # Ground footprint of a pixel along the view: range / f, stretched by the grazing.
        norm = np.linalg.norm(d, axis=-1)
        footprint = s * norm / FX / np.maximum(-d[..., 2] / norm, 0.02)
        mx = (gx / TEXEL_M).astype(np.float32)
        my = (gy / TEXEL_M).astype(np.float32)
        img = np.full((H, W), 128.0, np.float32)
        for sigma, octave in zip(OCTAVES_TEXELS, self.octaves, strict=True):
            val = cv2.remap(octave, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
            fade = np.exp(-(footprint / (2.0 * sigma * TEXEL_M)) ** 2)
            img += np.where(hit, val * fade, 0.0).astype(np.float32)
        img += self.rng.normal(0.0, 1.0, img.shape).astype(np.float32)
        return np.clip(img, 0, 255).astype(np.uint8)

    def stereo(self, x: float, pan: float, tilt: float) -> tuple[np.ndarray, np.ndarray]:
        world_T_base = np.eye(4)
        world_T_base[0, 3] = x
        left = world_T_base @ KIN.base_T_left(pan, tilt)
        right = left.copy()
        right[:3, 3] += left[:3, 0] * BASELINE
        return self.render(left), self.render(right)


class Messages:
    """rosbags message builders of the world's sensors."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.ts = get_typestore(Stores.ROS2_JAZZY)
        self.T = self.ts.types

    def header(self, t_ns: int, frame: str = ""):
        stamp = self.T["builtin_interfaces/msg/Time"](sec=t_ns // 10**9, nanosec=t_ns % 10**9)
        return self.T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def image(self, t_ns: int, img: np.ndarray):
        data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].ravel()
        return self.T["sensor_msgs/msg/CompressedImage"](
            header=self.header(t_ns), format="mono8; jpeg compressed mono8", data=data)

    def info(self, t_ns: int, right: bool):
        T = self.T
        tx = -FX * BASELINE if right else 0.0
        return T["sensor_msgs/msg/CameraInfo"](
            header=self.header(t_ns), height=H, width=W, distortion_model="plumb_bob",
            d=np.zeros(5), k=np.array([FX, 0, CX, 0, FX, CY, 0, 0, 1.0]), r=np.eye(3).ravel(),
            p=np.array([FX, 0, CX, tx, 0, FX, CY, 0, 0, 0, 1.0, 0]), binning_x=0, binning_y=0,
            roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                      width=0, do_rectify=False))

    def imu(self, t_ns: int, gyro: np.ndarray, accel: np.ndarray):
        T = self.T
        v3 = T["geometry_msgs/msg/Vector3"]
        return T["sensor_msgs/msg/Imu"](
            header=self.header(t_ns, "imu_link"),
            orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0]),
            angular_velocity=v3(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=v3(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
            linear_acceleration_covariance=np.zeros(9))

    def joints(self, t_ns: int, q: tuple[float, float], names=JOINTS):
        return self.T["sensor_msgs/msg/JointState"](
            header=self.header(t_ns), name=list(names), position=np.array(q, float),
            velocity=np.zeros(len(q)), effort=np.zeros(0))


def mast_angles(schedule: Schedule, t: float) -> tuple[float, float]:
    """The mast at ``t`` (s from the start): at each frame's angles from 1 s before it to
    0.2 s after it, slewing linearly in between."""
    keys_t, keys_q = [], []
    for f in schedule.frames:
        keys_t += [f.t - 1.0, f.t + 0.2]
        keys_q += [(f.pan, f.tilt)] * 2
    q = np.array(keys_q)
    return float(np.interp(t, keys_t, q[:, 0])), float(np.interp(t, keys_t, q[:, 1]))


def stream(schedule: Schedule, world: World | None = None, joint_states: bool = True,
           joint_names: tuple[str, ...] = JOINTS, joint_offset_s: float = 0.0,
           joints_until_s: float | None = None, seed: int = 5) -> list[tuple[str, object]]:
    """``(topic, msg)`` of the schedule in stamp order: 50 Hz IMU from 1 s before the first
    pair, /joint_states at 10 Hz and at each pair (before its images; stamps moved by
    ``joint_offset_s``, none after ``joints_until_s``), each pair with its camera infos."""
    world = world or World()
    msgs = Messages()
    rng = np.random.default_rng(seed)
    events: list[tuple[float, int, str, object]] = []  # (t, order, topic, builder)
    t_end = schedule.t + 0.5
    for k in range(int((t_end + 1.0) * 50)):
        t = -1.0 + k / 50.0
        gyro = np.asarray(GYRO_BIAS) + rng.normal(0, GYRO_NOISE, 3)
        accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.01, 3)
        events.append((t, 0, "/imu/data", ("imu", gyro, accel)))
    if joint_states:
        stamps = [k / 10.0 for k in range(-10, int(t_end * 10) + 1)]
        stamps += [f.t for f in schedule.frames]
        for t in sorted(set(round(s, 9) for s in stamps)):
            if joints_until_s is not None and t > joints_until_s:
                continue
            events.append((t + joint_offset_s, 1, "/joint_states", ("joints", t)))
    for f in schedule.frames:
        events.append((f.t, 2, "pair", ("pair", f)))
    events.sort(key=lambda e: (e[0], e[1]))
    out: list[tuple[str, object]] = []
    for t, _, topic, spec in events:
        t_ns = START_NS + round(t * 1e9)
        if spec[0] == "imu":
            out.append((topic, msgs.imu(t_ns, spec[1], spec[2])))
        elif spec[0] == "joints":
            out.append((topic, msgs.joints(t_ns, mast_angles(schedule, spec[1]), joint_names)))
        else:
            f = spec[1]
            left, right = world.stereo(f.x, f.pan, f.tilt)
            out += [("/stereo/left/image_raw/compressed", msgs.image(t_ns, left)),
                    ("/stereo/left/camera_info", msgs.info(t_ns, False)),
                    ("/stereo/right/image_raw/compressed", msgs.image(t_ns, right)),
                    ("/stereo/right/camera_info", msgs.info(t_ns, True))]
    return out


def truth_x(schedule: Schedule) -> dict[int, float]:
    """Stamp (ns) -> the rover's x at each pair."""
    return {START_NS + round(f.t * 1e9): f.x for f in schedule.frames}


def write_bag(messages: list[tuple[str, object]], out: Path, mast: bool = True) -> Path:
    """A bag directory (rosbag/ MCAP and rover.yaml) of the messages."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = Messages().ts
    out.mkdir(parents=True)
    types = {"/imu/data": "sensor_msgs/msg/Imu", "/joint_states": "sensor_msgs/msg/JointState",
             "/stereo/left/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
             "/stereo/right/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
             "/stereo/left/camera_info": "sensor_msgs/msg/CameraInfo",
             "/stereo/right/camera_info": "sensor_msgs/msg/CameraInfo"}
    with Writer(out / "rosbag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, types[topic], typestore=ts)
            t_ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            writer.write(conns[topic], t_ns, ts.serialize_cdr(msg, types[topic]))
    params = rover_params(mast)
    nested: dict = {}
    for key, value in params.items():
        if isinstance(value, list):  # ROS wants one type a sequence: [0.4, 0.0, 1.3, 0.0...]
            value = [float(v) for v in value]
        head, _, tail = key.partition(".")
        if tail:
            nested.setdefault(head, {})[tail] = value
        else:
            nested[key] = value
    (out / "rover.yaml").write_text(yaml.safe_dump({"/**": {"ros__parameters": nested}}))
    return out
