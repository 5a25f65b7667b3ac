"""Red-strip bearings from a robot's two fisheye images: the camera node's image-to-bearings core.

Every robot carries a red strip around its camera holder (Perera 2021, "Camera measurements"); two
180 deg fisheye lenses, back to back at the holder, see the whole circle. This module turns one
frame of each into the bearings of the red blobs in the robot frame (REP-103: x forward, y left,
angles counter-clockwise, radians in ``[-pi, pi)``), the measurement the filters' camera update
reads. It is plain numpy + OpenCV (``pip install swarm-phd[camera]``), with no ROS: the ROS 2
node (``ros/swarm_phd_camera``) only moves images in and bearings out.

Pipeline, per lens:

1. check the image (``uint8``, ``(height, width, 3)`` BGR, the calibrated size), else
   :class:`FrameError` naming the field; drop an unusable frame (``dark``: lens covered or no
   signal; ``saturated``: over-exposed; ``red_flood``: red covers a large part of the view),
   reported in :attr:`FrameBearings.dropped`, never an exception;
2. HSV colour thresholds: red hue (it wraps around 0 in OpenCV's 0-180 scale), enough
   saturation and value;
3. connected blobs (8-connectivity) of at least ``min_area_px`` pixels;
4. every blob pixel undistorted with the lens's calibrated fisheye model (OpenCV's
   Kannala-Brandt ``cv2.fisheye``: camera matrix ``K`` and four coefficients ``D``, inverted
   here to the lens's rim, :func:`undistort_angles`) into a ray in the camera frame (x right,
   y down, z along the optical axis); rays more than 90 deg off the axis belong to the other
   lens and are ignored, as are rays outside the horizon band ``max_elevation_deg`` (the
   strips are at the cameras' height);
5. the blob's bearing is the circular mean of its rays' azimuths, rotated by the lens's
   mounting yaw into the robot frame.

A blob cut by the seam between the lenses (at +-90 deg from the front lens's axis for a
back-to-back pair) appears in both, each half at its lens's rim; :func:`pair_bearings` merges
the two halves. Bearings are seen from the lens centres, taken at the robot's centre (a
back-to-back pair's centres are ~2 cm from it: parallax below asin(0.02 / r), 0.6 deg at 2 m).

Accuracy (``tests/test_fisheye_bearings.py``, frames rendered with ``cv2.fisheye.projectPoints``
from 3-D points on the strips of a simulator scene): an unoccluded strip's bearing is within
0.5 deg of its true bearing from 0.3 to 4 m (pixel quantisation: 1 px = 0.094 deg at 1920 px per
180 deg), a partly hidden one is biased toward its visible part (up to half its angular width).
Every red object is a bearing: the arena's red decoys are false positives here, as in the
simulator's camera model.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

TWO_PI = 2.0 * math.pi
DROP_REASONS = ("dark", "saturated", "red_flood")


class FrameError(ValueError):
    """A malformed image or calibration; the message names the field and the value."""


def _cv2():
    try:
        import cv2
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError(
            "fisheye bearings need OpenCV: pip install 'swarm-phd[camera]' "
            "(opencv-python-headless)"
        ) from exc
    return cv2


@dataclass(frozen=True, slots=True)
class FisheyeCalibration:
    """One lens: OpenCV fisheye intrinsics (``cv2.fisheye.calibrate``'s output) and mounting.

    Attributes
    ----------
    width_px, height_px : int
        The image size the calibration holds for.
    camera_matrix : tuple of 9 floats
        ``K`` row-major: ``fx, 0, cx, 0, fy, cy, 0, 0, 1`` (skew, if any, at index 1).
    distortion : tuple of 4 floats
        ``D = k1, k2, k3, k4`` of the Kannala-Brandt model
        ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``.
    yaw_rad : float
        Robot-frame bearing of the optical axis (REP-103): 0 for the front lens, pi for the back.
    """

    width_px: int
    height_px: int
    camera_matrix: tuple[float, ...]
    distortion: tuple[float, ...]
    yaw_rad: float = 0.0

    def __post_init__(self) -> None:
        for name in ("width_px", "height_px"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 2:
                raise FrameError(f"FisheyeCalibration.{name} must be an int >= 2, got {value!r}")
        k = np.asarray(self.camera_matrix, dtype=np.float64).reshape(-1)
        if k.size != 9 or not np.all(np.isfinite(k)):
            raise FrameError(
                f"FisheyeCalibration.camera_matrix must be 9 finite numbers, got "
                f"{self.camera_matrix!r}"
            )
        if not (k[0] > 0 and k[4] > 0 and k[3] == 0 and k[6] == 0 and k[7] == 0 and k[8] == 1):
            raise FrameError(
                "FisheyeCalibration.camera_matrix must be [fx, s, cx, 0, fy, cy, 0, 0, 1] with "
                f"fx, fy > 0, got {self.camera_matrix!r}"
            )
        d = np.asarray(self.distortion, dtype=np.float64).reshape(-1)
        if d.size != 4 or not np.all(np.isfinite(d)):
            raise FrameError(
                f"FisheyeCalibration.distortion must be 4 finite numbers (k1..k4), got "
                f"{self.distortion!r}"
            )
        if not math.isfinite(self.yaw_rad):
            raise FrameError(f"FisheyeCalibration.yaw_rad must be finite, got {self.yaw_rad!r}")
        theta = np.linspace(0.0, 0.5 * math.pi, 181)
        if not np.all(np.diff(_distorted_angle(theta, d)) > 0.0):
            # The model must map 0-90 deg one to one, or undistortion is ambiguous.
            raise FrameError(
                f"FisheyeCalibration.distortion {self.distortion!r} does not increase over "
                "0-90 deg off axis (not a lens OpenCV's fisheye model can invert there)"
            )

    @property
    def K(self) -> np.ndarray:  # noqa: N802 - OpenCV's name
        return np.asarray(self.camera_matrix, dtype=np.float64).reshape(3, 3)

    @property
    def D(self) -> np.ndarray:  # noqa: N802 - OpenCV's name
        return np.asarray(self.distortion, dtype=np.float64).reshape(4, 1)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "calibration") -> FisheyeCalibration:
        """From a mapping (a YAML file's content): ``image_width``, ``image_height``,
        ``camera_matrix`` (9 numbers, or ``{data: [...]}`` as ROS camera_info YAML writes it),
        ``distortion_coefficients`` (4, same forms) and ``yaw_deg``."""
        if not isinstance(data, Mapping):
            raise FrameError(f"{where}: expected a mapping, got {type(data).__name__}")
        known = {
            "image_width", "image_height", "camera_matrix", "distortion_coefficients",
            "yaw_deg", "camera_name", "distortion_model",
        }  # fmt: skip
        unknown = sorted(set(data) - known)
        if unknown:
            raise FrameError(f"{where}: unknown key {unknown[0]!r} (known: {sorted(known)})")
        model = data.get("distortion_model", "fisheye")
        if model not in ("fisheye", "equidistant"):
            raise FrameError(
                f"{where}.distortion_model must be 'fisheye' or 'equidistant', got {model!r}"
            )

        def numbers(key):
            if key not in data:
                raise FrameError(f"{where}.{key}: missing")
            value = data[key]
            if isinstance(value, Mapping):
                value = value.get("data")
            if not isinstance(value, (list, tuple)) or not all(
                type(v) in (int, float) for v in value
            ):
                raise FrameError(f"{where}.{key}: expected a list of numbers, got {value!r}")
            return tuple(float(v) for v in value)

        for key in ("image_width", "image_height"):
            if key not in data:
                raise FrameError(f"{where}.{key}: missing")
        yaw = data.get("yaw_deg", 0.0)
        if type(yaw) not in (int, float):
            raise FrameError(f"{where}.yaw_deg: expected a number, got {yaw!r}")
        return cls(
            width_px=data["image_width"],
            height_px=data["image_height"],
            camera_matrix=numbers("camera_matrix"),
            distortion=numbers("distortion_coefficients"),
            yaw_rad=math.radians(yaw),
        )


def _distorted_angle(theta: np.ndarray, d: np.ndarray) -> np.ndarray:
    t2 = theta * theta
    return theta * (1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))))


@dataclass(frozen=True, slots=True)
class RedBlobConfig:
    """Colour thresholds and blob tests (OpenCV 8-bit HSV: hue 0-179, saturation and value
    0-255).

    Attributes
    ----------
    hue_max_low, hue_min_high : int
        Red is hue <= ``hue_max_low`` or hue >= ``hue_min_high`` (it wraps around 0).
    saturation_min, value_min : int
        Minimum saturation and value of a red pixel (grey, white and dark pixels fail).
    min_area_px : int
        Fewest pixels of a blob (after the horizon band): the simulator's camera model uses the
        same test (``CameraConfig.min_blob_area_px``, 25 px).
    max_elevation_deg : float
        Keep pixels whose ray is at most this far above or below the horizon.
    dark_value_mean : float
        A frame whose mean value (V) is below this is dropped as ``dark``.
    saturated_fraction : float
        A frame with more than this fraction of pixels at 250+ in every channel is dropped as
        ``saturated``.
    red_fraction_max : float
        A frame with more than this fraction of red pixels is dropped as ``red_flood`` (a red
        object against the lens: no bearing can be trusted).
    rim_margin_deg : float
        A blob whose pixels come within this angle of its lens's 90 deg rim is cut by the
        seam between two lenses; two such blobs of different lenses at the same seam are one
        object (:func:`pair_bearings`).
    max_blobs : int
        At most this many bearings per lens (largest blobs first), as the bridge's limit.
    """

    hue_max_low: int = 10
    hue_min_high: int = 170
    saturation_min: int = 120
    value_min: int = 60
    min_area_px: int = 25
    max_elevation_deg: float = 15.0
    dark_value_mean: float = 8.0
    saturated_fraction: float = 0.5
    red_fraction_max: float = 0.25
    rim_margin_deg: float = 0.5
    max_blobs: int = 128

    def __post_init__(self) -> None:
        for name in ("hue_max_low", "hue_min_high", "saturation_min", "value_min"):
            value = getattr(self, name)
            upper = 179 if name.startswith("hue") else 255
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise FrameError(f"RedBlobConfig.{name} must be an int, got {value!r}")
            if not 0 <= value <= upper:
                raise FrameError(f"RedBlobConfig.{name} must be in [0, {upper}], got {value!r}")
        if not self.hue_max_low < self.hue_min_high:
            raise FrameError(
                f"RedBlobConfig.hue_max_low={self.hue_max_low} must be below "
                f"hue_min_high={self.hue_min_high}"
            )
        for name in ("min_area_px", "max_blobs"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise FrameError(f"RedBlobConfig.{name} must be an int >= 1, got {value!r}")
        for name, low, high in (
            ("max_elevation_deg", 0.0, 90.0),
            ("dark_value_mean", 0.0, 255.0),
            ("saturated_fraction", 0.0, 1.0),
            ("red_fraction_max", 0.0, 1.0),
            ("rim_margin_deg", 0.0, 90.0),
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise FrameError(f"RedBlobConfig.{name} must be a number, got {value!r}")
            if not low <= value <= high:
                raise FrameError(f"RedBlobConfig.{name} must be in [{low}, {high}], got {value!r}")


@dataclass(frozen=True, slots=True)
class FrameBearings:
    """The red blobs of one lens's frame (or of a merged pair).

    Attributes
    ----------
    bearings_rad : ndarray, shape (M,)
        Robot-frame bearings in ``[-pi, pi)``, increasing.
    areas_px : ndarray, shape (M,), int
        Pixels of each blob (in the horizon band).
    dropped : tuple of str
        Why frames were dropped (one of :data:`DROP_REASONS` per dropped frame); a dropped
        frame gives no bearings.
    at_rim : ndarray, shape (M,), bool
        The blob reaches its lens's 90 deg rim (cut by the seam between two lenses).
    """

    bearings_rad: np.ndarray
    areas_px: np.ndarray
    dropped: tuple[str, ...] = field(default=())
    at_rim: np.ndarray | None = None


def check_image(image: Any, calibration: FisheyeCalibration, name: str = "image") -> np.ndarray:
    """``image`` as a contiguous ``uint8`` ``(height, width, 3)`` BGR array, or
    :class:`FrameError` naming the field and the value."""
    if not isinstance(image, np.ndarray):
        raise FrameError(f"{name}: expected a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise FrameError(f"{name}.dtype must be uint8 (8-bit BGR), got {image.dtype}")
    expected = (calibration.height_px, calibration.width_px, 3)
    if image.shape != expected:
        raise FrameError(
            f"{name}.shape must be {expected} (the calibrated size, BGR), got {image.shape}"
        )
    return np.ascontiguousarray(image)


#: ``sensor_msgs/Image`` encodings :func:`decode_image` reads: where blue, green and red are.
ENCODINGS = {"bgr8": (0, 1, 2), "rgb8": (2, 1, 0), "bgra8": (0, 1, 2), "rgba8": (2, 1, 0)}


def decode_image(height: Any, width: Any, encoding: Any, step: Any, data: Any) -> np.ndarray:
    """A ``sensor_msgs/Image``'s fields as a ``uint8`` ``(height, width, 3)`` BGR array.

    ``data`` is the row-major byte buffer (``bytes``, ``bytearray``, ``array.array`` or a
    uint8 array), each row ``step`` bytes (padding allowed). Encodings: :data:`ENCODINGS`
    (8-bit colour). A malformed message raises :class:`FrameError` naming the field.
    """
    for name, value in (("height", height), ("width", width), ("step", step)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise FrameError(f"image.{name} must be a positive int, got {value!r}")
    if encoding not in ENCODINGS:
        raise FrameError(f"image.encoding must be one of {sorted(ENCODINGS)}, got {encoding!r}")
    channels = 4 if encoding.endswith("a8") else 3
    if step < width * channels:
        raise FrameError(
            f"image.step={step} is shorter than width x {channels} bytes = {width * channels}"
        )
    try:
        buf = np.frombuffer(memoryview(data).cast("B"), dtype=np.uint8)
    except TypeError:
        kind = type(data).__name__
        raise FrameError(f"image.data: expected a byte buffer, got {kind}") from None
    expected = height * step
    if buf.size != expected:
        raise FrameError(f"image.data has {buf.size} bytes, height x step = {expected}")
    rows = buf.reshape(height, step)[:, : width * channels].reshape(height, width, channels)
    blue, green, red = ENCODINGS[encoding]
    return np.ascontiguousarray(rows[:, :, [blue, green, red]])


def frame_bearings(
    image: Any, calibration: FisheyeCalibration, config: RedBlobConfig | None = None
) -> FrameBearings:
    """The red blobs of one lens's frame (see the module notes for the pipeline).

    Parameters
    ----------
    image : ndarray, shape (height, width, 3), uint8
        BGR (OpenCV's order; a ROS ``bgr8`` image, or ``rgb8`` reversed on the last axis).
    calibration : FisheyeCalibration
    config : RedBlobConfig, optional

    Raises
    ------
    FrameError
        Malformed image (not an array, not ``uint8``, wrong shape).
    """
    cv2 = _cv2()
    cfg = config if config is not None else RedBlobConfig()
    img = check_image(image, calibration)
    none = FrameBearings(np.zeros(0), np.zeros(0, dtype=np.intp), (), np.zeros(0, dtype=bool))
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    value = hsv[:, :, 2]
    if float(value.mean()) < cfg.dark_value_mean:
        return dataclasses.replace(none, dropped=("dark",))
    if float(np.count_nonzero(img.min(axis=2) >= 250)) > cfg.saturated_fraction * value.size:
        return dataclasses.replace(none, dropped=("saturated",))
    low = cv2.inRange(hsv, (0, cfg.saturation_min, cfg.value_min), (cfg.hue_max_low, 255, 255))
    high = cv2.inRange(hsv, (cfg.hue_min_high, cfg.saturation_min, cfg.value_min), (179, 255, 255))
    mask = cv2.bitwise_or(low, high)
    n_red = cv2.countNonZero(mask)
    if n_red > cfg.red_fraction_max * value.size:
        return dataclasses.replace(none, dropped=("red_flood",))
    if n_red < cfg.min_area_px:
        return none
    n_labels, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    big = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] >= cfg.min_area_px)
    big = big[big > 0]  # label 0: the background
    if big.size == 0:
        return none
    keep = np.zeros(n_labels, dtype=bool)
    keep[big] = True
    ys, xs = np.nonzero(keep[labels])
    label = labels[ys, xs]
    azimuth, theta, ok = _pixel_azimuths(xs, ys, calibration, cfg)
    label, azimuth, theta = label[ok], azimuth[ok], theta[ok]
    area = np.bincount(label, minlength=n_labels)
    reach = np.zeros(n_labels)
    np.maximum.at(reach, label, theta)
    s = np.bincount(label, weights=np.sin(azimuth), minlength=n_labels)
    c = np.bincount(label, weights=np.cos(azimuth), minlength=n_labels)
    blobs = np.flatnonzero(area >= cfg.min_area_px)
    if blobs.size > cfg.max_blobs:
        blobs = blobs[np.argsort(-area[blobs], kind="stable")[: cfg.max_blobs]]
    bearings = _wrap(np.arctan2(s[blobs], c[blobs]) + calibration.yaw_rad)
    at_rim = reach[blobs] >= 0.5 * math.pi - math.radians(cfg.rim_margin_deg)
    order = np.argsort(bearings, kind="stable")
    return FrameBearings(bearings[order], area[blobs][order].astype(np.intp), (), at_rim[order])


def _pixel_azimuths(xs, ys, calibration, cfg):
    """Camera-frame azimuths (rad, counter-clockwise seen from above: robot left positive) of
    pixel rays, and which rays count: less than 90 deg off the axis and in the horizon band."""
    theta, phi = undistort_angles(xs, ys, calibration)
    # Ray (sin t cos p, sin t sin p, cos t): x right, y down, z forward.
    sin_t = np.sin(theta)
    x, y, z = sin_t * np.cos(phi), sin_t * np.sin(phi), np.cos(theta)
    azimuth = np.arctan2(-x, z)  # robot left (camera -x) is a positive angle
    elevation = np.arcsin(np.clip(-y, -1.0, 1.0))
    ok = (theta < 0.5 * math.pi) & (np.abs(elevation) <= math.radians(cfg.max_elevation_deg))
    return azimuth, theta, ok


def undistort_angles(
    xs: np.ndarray, ys: np.ndarray, calibration: FisheyeCalibration
) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``(xs, ys)`` to ray angles through the lens's fisheye model: ``theta`` off the
    optical axis and ``phi`` around it (from camera +x toward +y, image right toward down).

    The model is OpenCV's ``cv2.fisheye`` (Kannala-Brandt: ``theta_d = theta (1 + k1 theta^2
    + k2 theta^4 + k3 theta^6 + k4 theta^8)``, ``(u, v) = K theta_d (cos phi, sin phi)``),
    inverted by Newton's method. ``cv2.fisheye.undistortPoints`` solves the same equation but
    clamps ``theta_d`` at 90 deg and returns ``tan(theta)``-scaled points, which loses a 180 deg
    lens's outer degrees (2.2 deg of bearing at the rim of a lens with ``theta_d(90 deg)`` =
    92 deg); the two agree where it does not clamp
    (``tests/test_fisheye_bearings.py``). Pixels beyond the model's 90 deg get ``theta`` >= 90
    deg (another lens's half of the circle).
    """
    k = calibration.K
    d = calibration.D.reshape(-1)
    v = (np.asarray(ys, dtype=np.float64) - k[1, 2]) / k[1, 1]
    u = (np.asarray(xs, dtype=np.float64) - k[0, 2] - k[0, 1] * v) / k[0, 0]
    theta_d = np.hypot(u, v)
    phi = np.arctan2(v, u)
    rim = float(_distorted_angle(np.array([0.5 * math.pi]), d)[0])
    beyond = theta_d >= rim
    target = np.minimum(theta_d, rim)
    theta = target.copy()
    for _ in range(30):
        t2 = theta * theta
        f = theta * (1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3])))) - target
        df = 1.0 + t2 * (3.0 * d[0] + t2 * (5.0 * d[1] + t2 * (7.0 * d[2] + t2 * 9.0 * d[3])))
        step = f / df
        theta -= step
        if np.all(np.abs(step) < 1e-12):
            break
    theta = np.clip(theta, 0.0, 0.5 * math.pi)
    theta[beyond] = 0.5 * math.pi
    return theta, phi


def pair_bearings(
    images: tuple[Any, ...],
    calibrations: tuple[FisheyeCalibration, ...],
    config: RedBlobConfig | None = None,
) -> FrameBearings:
    """The red blobs of a robot's lenses, one frame each, in the robot frame.

    A blob cut by the seam between two lenses (half way between their axes: +-90 deg for a
    back-to-back pair) shows as one blob at each lens's rim: two rim blobs of different lenses
    at the same seam are one object, merged into the pixel-weighted circular mean of their
    bearings. A dropped frame leaves the other lenses' bearings (its reason is in
    ``dropped``).
    """
    cfg = config if config is not None else RedBlobConfig()
    if len(images) != len(calibrations) or not images:
        raise FrameError(f"pair_bearings: {len(images)} images for {len(calibrations)} lenses")
    parts = [frame_bearings(im, cal, cfg) for im, cal in zip(images, calibrations, strict=True)]
    dropped = tuple(reason for p in parts for reason in p.dropped)
    bearings = np.concatenate([p.bearings_rad for p in parts])
    areas = np.concatenate([p.areas_px for p in parts]).astype(np.float64)
    lens = np.concatenate([np.full(p.bearings_rad.size, i) for i, p in enumerate(parts)])
    rim = np.concatenate([p.at_rim for p in parts if p.at_rim is not None] or [np.zeros(0, bool)])
    # The seam each rim blob is cut by: the nearest one half way between neighbouring axes.
    axes = np.sort(_wrap([c.yaw_rad for c in calibrations]))
    seams = _wrap(axes + 0.5 * np.diff(np.r_[axes, axes[0] + TWO_PI]))
    seam = np.argmin(np.abs(_wrap(bearings[:, None] - seams[None, :])), axis=1)
    group = np.arange(bearings.size)
    if len(calibrations) > 1:
        for i in np.flatnonzero(rim):
            for j in np.flatnonzero(rim & (lens != lens[i]) & (seam == seam[i])):
                group[group == group[j]] = group[i]
    out_b, out_a = [], []
    for g in np.unique(group):
        members = group == g
        w = areas[members]
        b = bearings[members]
        out_b.append(math.atan2(np.dot(w, np.sin(b)), np.dot(w, np.cos(b))))
        out_a.append(int(w.sum()))
    merged = _wrap(np.asarray(out_b, dtype=np.float64))
    order = np.argsort(merged, kind="stable")
    at_rim = np.zeros(merged.size, dtype=bool)
    return FrameBearings(merged[order], np.asarray(out_a, np.intp)[order], dropped, at_rim)


def _wrap(angle):
    return (np.asarray(angle, dtype=np.float64) + math.pi) % TWO_PI - math.pi
