"""Red-strip bearings from fisheye frames (swarm_core/perception/fisheye_bearings.py), no ROS.

The frames are rendered here from a simulator scene: each red strip, red decoy, post, wall and
box is a set of small 3-D quads (cylinders for the round objects) at its height, projected with
``cv2.fisheye.projectPoints`` through the calibrated lens and painted far to near, so nearer
objects hide farther ones. Nothing here uses the bearing model or the undistortion under test;
the truth is the scene's geometry and an identity buffer rendered the same way (which strips
are whole, partly hidden or hidden in each frame).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from swarm_core.perception.fisheye_bearings import (  # noqa: E402
    FisheyeCalibration,
    FrameError,
    RedBlobConfig,
    frame_bearings,
    pair_bearings,
)
from swarm_env.sensors.scene_builder import SceneBuilder, make_arena_scene  # noqa: E402

W, H = 1920, 1080  # the Perera 2021 study's cameras
D = (0.03, -0.01, 0.002, -0.0005)  # a mild fisheye distortion, increasing over 0-90 deg
THETA_D_90 = (math.pi / 2) * (1 + sum(k * (math.pi / 2) ** (2 * i + 2) for i, k in enumerate(D)))
F = 950.0 / THETA_D_90  # 90 deg off axis lands 950 px from the centre: the whole half circle
K = (F, 0.0, 959.5, 0.0, F, 539.5, 0.0, 0.0, 1.0)
FRONT = FisheyeCalibration(W, H, K, D, yaw_rad=0.0)
BACK = FisheyeCalibration(W, H, K, D, yaw_rad=math.pi)
LENSES = (FRONT, BACK)

LENS_HEIGHT_M = 0.15  # the lenses and the red strips around the camera holders
STRIP_HALF_M = 0.0075  # 15 mm strips (CameraConfig.strip_height_m)
OBJECT_TOP_M = 0.30
RED = (35, 30, 200)  # BGR: hue ~178, saturated
GREY = (105, 110, 112)
ORANGE = (0, 128, 255)  # hue 15: not red
N_SIDES = 120


def faces_of_cylinder(cx, cy, radius, bands, ident):
    """Outward quads of a vertical cylinder: ``bands`` = [(z0, z1, colour, is_red)]."""
    phi = np.linspace(0.0, 2 * math.pi, N_SIDES + 1)
    out = []
    for z0, z1, colour, red in bands:
        for a, b in zip(phi[:-1], phi[1:], strict=True):
            pa = (cx + radius * math.cos(a), cy + radius * math.sin(a))
            pb = (cx + radius * math.cos(b), cy + radius * math.sin(b))
            normal = (math.cos(0.5 * (a + b)), math.sin(0.5 * (a + b)))
            quad = np.array([[*pa, z0], [*pb, z0], [*pb, z1], [*pa, z1]])
            out.append((quad, normal, colour, ident if red else -1))
    return out


def faces_of_segment(a, b, z1=OBJECT_TOP_M, piece_m=0.05):
    """Both sides of a wall or box side, in short pieces (straight lines bend in a fisheye)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    n = max(1, int(math.ceil(np.linalg.norm(b - a) / piece_m)))
    t = np.linspace(0.0, 1.0, n + 1)
    out = []
    for t0, t1 in zip(t[:-1], t[1:], strict=True):
        p, q = a + t0 * (b - a), a + t1 * (b - a)
        quad = np.array([[*p, 0.0], [*q, 0.0], [*q, z1], [*p, z1]])
        out.append((quad, None, GREY, -1))
    return out


def scene_faces(scene, observer, orange_posts=()):
    """Every quad of the scene in the observer's robot frame (x forward, y left, z up from the
    lenses). Robots: a grey camera holder with its red strip (the observer's own is skipped);
    red decoys: grey with a red band at the strips' height; posts: grey (or orange)."""
    o = scene.robot_xy[observer]
    yaw = scene.robot_yaw[observer]
    c, s = math.cos(yaw), math.sin(yaw)

    def local(xy):
        d = np.asarray(xy, float) - o
        return (c * d[0] + s * d[1], -s * d[0] + c * d[1])

    faces = []
    lo, hi = LENS_HEIGHT_M - STRIP_HALF_M, LENS_HEIGHT_M + STRIP_HALF_M
    for i in range(scene.circle_xy.shape[0]):
        owner = scene.circle_owner[i]
        if owner == observer:
            continue
        x, y = local(scene.circle_xy[i])
        r = scene.circle_radius_m[i]
        if scene.circle_red[i]:
            base = 0.05 if owner >= 0 else 0.0
            top = LENS_HEIGHT_M + 0.05 if owner >= 0 else OBJECT_TOP_M
            bands = [(base, lo, GREY, False), (lo, hi, RED, True), (hi, top, GREY, False)]
            faces += faces_of_cylinder(x, y, r, bands, ident=i)
        elif owner < 0:  # a post
            colour = ORANGE if i in orange_posts else GREY
            faces += faces_of_cylinder(x, y, r, [(0.0, OBJECT_TOP_M, colour, False)], ident=i)
    for a, b in zip(scene.segment_a, scene.segment_b, strict=True):
        faces += faces_of_segment(local(a), local(b))
    for quad, *_ in faces:
        quad[:, 2] -= LENS_HEIGHT_M
    return faces


def clip_to_front(poly, z_min=1e-4):
    """The part of a convex 3-D polygon (camera frame) in front of the lens, z >= z_min
    (Sutherland-Hodgman against one plane): a face cut by the lens's 90 deg rim keeps its
    visible part, so an object straddling the seam reaches each lens's rim."""
    out = []
    for k in range(poly.shape[0]):
        p, q = poly[k], poly[(k + 1) % poly.shape[0]]
        if p[2] >= z_min:
            out.append(p)
        if (p[2] >= z_min) != (q[2] >= z_min):
            t = (z_min - p[2]) / (q[2] - p[2])
            out.append(p + t * (q - p))
    return np.array(out).reshape(-1, 3)


def render(faces, calibration, rng=None, only=None):
    """(BGR image, identity image) of one lens: quads facing the lens, far to near.
    ``only``: render that red identity alone (nothing occludes it)."""
    yaw = calibration.yaw_rad
    c, s = math.cos(yaw), math.sin(yaw)
    image = np.empty((H, W, 3), np.uint8)
    image[: H // 2] = (150, 150, 145)
    image[H // 2 :] = (70, 75, 80)
    ident = np.full((H, W), -1, np.int32)
    items = []
    for quad, normal, colour, red_id in faces:
        if only is not None and red_id != only:
            continue
        centre = quad.mean(axis=0)
        if normal is not None and normal[0] * -centre[0] + normal[1] * -centre[1] <= 0.0:
            continue  # the back of a cylinder
        # Robot frame -> this lens's frame -> OpenCV camera (x right, y down, z forward).
        fx, fy = c * quad[:, 0] + s * quad[:, 1], -s * quad[:, 0] + c * quad[:, 1]
        cam = clip_to_front(np.stack([-fy, -quad[:, 2], fx], axis=1))
        if cam.shape[0] < 3:
            continue  # beyond this lens's half of the circle
        items.append((np.linalg.norm(centre), cam, colour, red_id, normal, centre))
    items.sort(key=lambda item: -item[0])
    for _, cam, colour, red_id, normal, centre in items:
        pts, _ = cv2.fisheye.projectPoints(
            cam.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), calibration.K, calibration.D
        )
        poly = np.round(pts.reshape(-1, 2) * 16).astype(np.int32)  # 4 fractional bits
        shade = 1.0
        if normal is not None:
            view = -centre[:2] / max(np.linalg.norm(centre[:2]), 1e-9)
            shade = 0.65 + 0.35 * float(np.dot(normal, view))
        col = tuple(int(v * shade) for v in colour)
        cv2.fillConvexPoly(image, poly, col, lineType=cv2.LINE_8, shift=4)
        cv2.fillConvexPoly(ident, poly, int(red_id), lineType=cv2.LINE_8, shift=4)
    if rng is not None:
        noisy = image.astype(np.int16) + rng.normal(0.0, 4.0, image.shape).astype(np.int16)
        image = np.clip(noisy, 0, 255).astype(np.uint8)
    return image, ident


def truth(scene, observer, faces, min_area=25):
    """Per red circle: (true bearing, half angular width, state, range) with state "whole" (at
    least 95 % of its strip's pixels, when rendered alone, survive, and no other red object
    touches it in bearing), "hidden" (fewer than the blob area) or "partial"."""
    o, yaw = scene.robot_xy[observer], scene.robot_yaw[observer]
    out = {}
    seen = {lens: render(faces, lens)[1] for lens in LENSES}
    for i in np.flatnonzero(scene.circle_red & (scene.circle_owner != observer)):
        d = scene.circle_xy[i] - o
        dist = math.hypot(*d)
        bearing = (math.atan2(d[1], d[0]) - yaw + math.pi) % (2 * math.pi) - math.pi
        alone = sum(np.count_nonzero(render(faces, lens, only=i)[1] == i) for lens in LENSES)
        shown = sum(np.count_nonzero(seen[lens] == i) for lens in LENSES)
        half = math.asin(min(scene.circle_radius_m[i] / dist, 1.0))
        if shown >= 0.95 * alone and alone >= min_area:
            state = "whole"
        elif shown < min_area:
            state = "hidden"
        else:
            state = "partial"
        out[i] = (bearing, half, state, dist)
    # Red objects whose strips overlap in bearing (all are at the lenses' height) show as one
    # blob: neither is "whole" on its own.
    for i, (bearing, half, state, dist) in out.items():
        if state == "whole" and any(
            j != i and s_j != "hidden" and angle_diff(b_j, bearing) <= half + h_j + 0.02
            for j, (b_j, h_j, s_j, _) in out.items()
        ):
            out[i] = (bearing, half, "partial", dist)
    return out


def angle_diff(a, b):
    return np.abs((np.asarray(a) - b + math.pi) % (2 * math.pi) - math.pi)


def check(found, expected, tol_deg=0.5):
    """Every whole strip has one bearing within ``tol_deg``; a partly hidden one has at most
    one, within its angular half width; every bearing belongs to a visible red object."""
    used = np.zeros(found.size, bool)
    for i, (bearing, half, state, dist) in expected.items():
        near = angle_diff(found, bearing)
        if state == "whole":
            hits = np.flatnonzero(near <= math.radians(tol_deg))
            assert hits.size == 1, (i, math.degrees(bearing), dist, np.degrees(found))
            used[hits] = True
        elif state == "partial":
            used |= near <= half + math.radians(tol_deg)
    assert used.all(), np.degrees(found[~used])


# ---------------------------------------------------------------------------- accuracy


@pytest.mark.parametrize("range_m", [0.3, 0.6, 1.0, 2.0, 3.0, 3.5])
def test_unoccluded_strips_all_around_match_the_rendered_truth(range_m):
    """Seven teammates around the observer at one range, two of them across the seam between
    the lenses (+-90 deg), one nearly behind: seven bearings within 0.5 deg."""
    rng = np.random.default_rng(int(range_m * 10))
    bearings = np.deg2rad([0.0, 51.0, 90.6, 140.0, -165.0, -90.0, -40.0])
    bearings += rng.uniform(-0.5, 0.5, bearings.size) * math.radians(1.0)
    b = SceneBuilder()
    b.add_robot(0.0, 0.0, yaw_rad=0.3)
    for a in bearings:
        b.add_robot(range_m * math.cos(a + 0.3), range_m * math.sin(a + 0.3))
    b.add_post(-0.9, 1.2)  # an orange post: a colour that is not red
    scene = b.build()
    orange = {int(np.flatnonzero(scene.circle_owner == -1)[0])}
    faces = scene_faces(scene, 0, orange_posts=orange)
    expected = truth(scene, 0, faces)
    images = tuple(render(faces, lens, rng)[0] for lens in LENSES)
    got = pair_bearings(images, LENSES)
    assert got.dropped == ()
    assert got.bearings_rad.size == 7, np.degrees(got.bearings_rad)
    check(got.bearings_rad, expected)
    assert np.all(np.diff(got.bearings_rad) > 0) and np.all(np.abs(got.bearings_rad) <= math.pi)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_arena_frames_match_the_rendered_truth_with_decoys_and_occlusion(seed):
    """A simulator arena (20 robots, red decoys, posts, boxes, walls), seen by robot 0: every
    whole strip or decoy within 3.5 m is one bearing within 0.5 deg; hidden ones give none;
    a partly hidden one at most one, inside its angular width."""
    rng = np.random.default_rng(seed)
    scene = make_arena_scene(rng)
    faces = scene_faces(scene, 0)
    expected = truth(scene, 0, faces)
    expected = {i: t for i, t in expected.items() if t[3] <= 3.5 or t[2] == "hidden"}
    images = tuple(render(faces, lens, rng)[0] for lens in LENSES)
    got = pair_bearings(images, LENSES)
    far = [
        t[0] for t in truth(scene, 0, faces).values() if t[3] > 3.5 and t[2] != "hidden"
    ]  # beyond 3.5 m a strip may or may not pass the area test: either is right
    keep = np.array([not np.any(angle_diff(far, g) < 0.02) for g in got.bearings_rad], bool)
    check(got.bearings_rad[keep], expected)
    states = [t[2] for t in expected.values()]
    assert states.count("whole") >= 3 and states.count("hidden") >= 1, states


def test_one_lens_alone_sees_only_its_half():
    rng = np.random.default_rng(5)
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(1.0, 0.2)  # ahead
    b.add_robot(-1.0, -0.4)  # behind
    scene = b.build()
    faces = scene_faces(scene, 0)
    front = frame_bearings(render(faces, FRONT, rng)[0], FRONT)
    back = frame_bearings(render(faces, BACK, rng)[0], BACK)
    np.testing.assert_allclose(front.bearings_rad, [math.atan2(0.2, 1.0)], atol=math.radians(0.5))
    np.testing.assert_allclose(back.bearings_rad, [math.atan2(-0.4, -1.0)], atol=math.radians(0.5))


# ---------------------------------------------------------------------------- bad input


def test_malformed_images_raise_naming_the_field():
    good = np.zeros((H, W, 3), np.uint8)
    cases = [
        (None, "expected a numpy array, got NoneType"),
        (good.tolist()[:2], "expected a numpy array, got list"),
        (good.astype(np.float32), "image.dtype must be uint8"),
        (good[:, :, 0], r"image.shape must be \(1080, 1920, 3\)"),
        (np.zeros((H, W, 4), np.uint8), r"got \(1080, 1920, 4\)"),
        (np.zeros((W, H, 3), np.uint8), r"got \(1920, 1080, 3\)"),
        (np.zeros((0, 0, 3), np.uint8), r"got \(0, 0, 3\)"),
    ]
    for image, message in cases:
        with pytest.raises(FrameError, match=message):
            frame_bearings(image, FRONT)


def test_unusable_frames_are_dropped_and_counted_not_raised():
    rng = np.random.default_rng(3)
    b = SceneBuilder()
    b.add_robot(0.0, 0.0)
    b.add_robot(1.0, 0.3)
    b.add_robot(-1.2, 0.1)
    faces = scene_faces(b.build(), 0)
    front, back = (render(faces, lens, rng)[0] for lens in LENSES)
    empty = np.zeros_like(front)
    white = np.full_like(front, 255)
    red = np.empty_like(front)
    red[:] = RED
    for image, reason in ((empty, "dark"), (white, "saturated"), (red, "red_flood")):
        got = frame_bearings(image, FRONT)
        assert got.dropped == (reason,) and got.bearings_rad.size == 0
        pair = pair_bearings((image, back), LENSES)
        assert pair.dropped == (reason,)
        np.testing.assert_allclose(pair.bearings_rad, [math.atan2(0.1, -1.2)], atol=0.01)
    # A plain frame with no red at all is not a drop: no bearings.
    grey = np.full_like(front, 120)
    assert frame_bearings(grey, FRONT).bearings_rad.size == 0
    assert frame_bearings(grey, FRONT).dropped == ()


def test_calibration_and_config_errors_name_the_field():
    with pytest.raises(FrameError, match="camera_matrix must be"):
        FisheyeCalibration(W, H, (F, 0, 1, 0, -F, 1, 0, 0, 1), D)
    with pytest.raises(FrameError, match="distortion must be 4 finite numbers"):
        FisheyeCalibration(W, H, K, (0.1, 0.2))
    with pytest.raises(FrameError, match="does not increase over 0-90 deg"):
        FisheyeCalibration(W, H, K, (-0.5, 0.0, 0.0, 0.0))
    with pytest.raises(FrameError, match="width_px must be an int >= 2, got 0"):
        FisheyeCalibration(0, H, K, D)
    with pytest.raises(FrameError, match="hue_max_low=20 must be below hue_min_high=10"):
        RedBlobConfig(hue_max_low=20, hue_min_high=10)
    with pytest.raises(FrameError, match=r"min_area_px must be an int >= 1, got 0"):
        RedBlobConfig(min_area_px=0)
    data = {
        "image_width": W,
        "image_height": H,
        "camera_matrix": {"rows": 3, "cols": 3, "data": list(K)},
        "distortion_model": "equidistant",
        "distortion_coefficients": {"rows": 1, "cols": 4, "data": list(D)},
        "yaw_deg": 180,
    }
    back = FisheyeCalibration.from_dict(data)
    assert back == BACK
    for change, message in (
        ({"yaw_deg": "back"}, "calibration.yaw_deg: expected a number"),
        ({"camera_matrix": [1, 2]}, "camera_matrix must be 9 finite numbers"),
        ({"distortion_model": "plumb_bob"}, "distortion_model must be 'fisheye'"),
        ({"lens": 1}, "unknown key 'lens'"),
    ):
        with pytest.raises(FrameError, match=message):
            FisheyeCalibration.from_dict({**data, **change})
    with pytest.raises(FrameError, match="image_width: missing"):
        FisheyeCalibration.from_dict({k: v for k, v in data.items() if k != "image_width"})


def test_undistortion_is_opencvs_fisheye_model_to_the_rim():
    """The inversion agrees with ``cv2.fisheye.undistortPoints`` wherever OpenCV does not clamp
    the distorted angle (below 90 deg), and with ``cv2.fisheye.projectPoints`` to the rim."""
    from swarm_core.perception.fisheye_bearings import undistort_angles

    rng = np.random.default_rng(0)
    theta = rng.uniform(0.0, 0.5 * math.pi - 1e-3, 2000)
    phi = rng.uniform(-math.pi, math.pi, 2000)
    rays = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    pix, _ = cv2.fisheye.projectPoints(
        rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), FRONT.K, FRONT.D
    )
    pix = pix.reshape(-1, 2)
    got_theta, got_phi = undistort_angles(pix[:, 0], pix[:, 1], FRONT)
    np.testing.assert_allclose(got_theta, theta, atol=1e-9)
    np.testing.assert_allclose(angle_diff(got_phi, phi), 0.0, atol=1e-9)
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 30, 1e-12)
    norm = cv2.fisheye.undistortPoints(pix.reshape(-1, 1, 2), FRONT.K, FRONT.D, criteria=criteria)
    unclamped = theta < 1.3  # theta_d below 90 deg for this lens
    tan_t = np.hypot(norm[:, 0, 0], norm[:, 0, 1])
    np.testing.assert_allclose(np.arctan(tan_t)[unclamped], theta[unclamped], atol=1e-7)


def test_ros_images_decode_to_bgr_and_malformed_ones_name_the_field():
    """``sensor_msgs/Image`` fields to a BGR array: the colour order of each encoding and row
    padding (``step`` > width x channels) are honoured; a bad field raises FrameError."""
    from swarm_core.perception.fisheye_bearings import decode_image

    rng = np.random.default_rng(1)
    bgr = rng.integers(0, 256, (4, 5, 3), dtype=np.uint8)
    padded = np.zeros((4, 17), np.uint8)
    padded[:, :15] = bgr.reshape(4, 15)
    np.testing.assert_array_equal(decode_image(4, 5, "bgr8", 17, padded.tobytes()), bgr)
    rgb = bgr[:, :, ::-1].copy()
    np.testing.assert_array_equal(decode_image(4, 5, "rgb8", 15, bytearray(rgb.tobytes())), bgr)
    rgba = np.concatenate([rgb, np.full((4, 5, 1), 255, np.uint8)], axis=2)
    np.testing.assert_array_equal(decode_image(4, 5, "rgba8", 20, rgba.reshape(-1)), bgr)
    for args, message in (
        ((4, 5, "mono8", 5, b"\0" * 20), "image.encoding must be one of"),
        ((4, 5, "bgr8", 14, b"\0" * 56), "image.step=14 is shorter than width x 3 bytes = 15"),
        ((4, 5, "bgr8", 15, b"\0" * 59), "image.data has 59 bytes, height x step = 60"),
        ((0, 5, "bgr8", 15, b""), "image.height must be a positive int, got 0"),
        ((4, 5, "bgr8", 15, [0] * 60), "image.data: expected a byte buffer, got list"),
    ):
        with pytest.raises(FrameError, match=message):
            decode_image(*args)
