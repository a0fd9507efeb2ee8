"""The --video frames: what each panel draws and where, and the check of the written file."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from itg_vision import video
from itg_vision.arm import ArmSpec
from itg_vision.camera import Rig, default_rig_path
from itg_vision.detect import Detection
from itg_vision.errors import UserError
from itg_vision.urdf import LED_RGB

BACKGROUND = ((200, 100, 10), (10, 100, 200))  # RGB, one per camera


@pytest.fixture
def written(monkeypatch):
    """The frames the recorder hands to OpenCV's writer."""
    frames = []

    class Writer:
        def write(self, frame):
            frames.append(frame.copy())

        def release(self):
            pass

    monkeypatch.setattr(video, "open_writer",
                        lambda path, fps, size: (Writer(), path.with_suffix(".mp4"), "test"))
    return frames


def _eye(detections, reasons=None):
    """A two-link eye on the planar rig whose last look is two flat views (``reasons``: why a
    marker was missed at that look, as Observation.reasons)."""
    rig = Rig.from_yaml(default_rig_path("two-link"))
    W, H = rig.cameras[0].size
    views = tuple(np.full((H, W, 3), c, np.uint8) for c in BACKGROUND)
    return SimpleNamespace(arm=ArmSpec.from_args("two-link"), estimate_rig=rig,
                           last_observation=SimpleNamespace(frames=lambda: views,
                                                            detections=detections,
                                                            reasons=reasons or {}))


def test_a_led_found_but_rejected_by_the_eye_is_crossed_out_and_named(written):
    """A look whose gripper LED camera 1 found but the eye rejected (here: camera 2 missed it)
    rang it like an accepted one: the video showed a look the controller never got. It is now
    crossed out in its colour (an 18 px tilted cross over the ring) and named in the corner;
    an accepted LED gets the ring alone."""
    raw = np.array([100.0, 120.0])
    dets = {"gripper": (Detection(True, raw, raw, 30.0),
                        Detection(False, np.full(2, np.nan), np.full(2, np.nan)))}
    colour = [255 * c for c in LED_RGB["gripper"][::-1]]
    for why in ("", "not found by cameras[1] (right)"):
        written.clear()
        video.VideoRecorder("unused").frame(_eye(dets, {"gripper": why}), np.full(3, np.nan))
        (frame,) = written
        diagonal = frame[120 + 5, 100 + 5].astype(int)  # on the cross, inside the ring
        assert (np.abs(diagonal - colour).max() < 80) == bool(why), (why, diagonal)
        corner = frame[28:46, 8:150].astype(int)  # 'missed: gripper' under the camera's name
        assert (np.abs(corner - BACKGROUND[0][::-1]).sum(axis=2) > 60).any() == bool(why)


def test_a_frame_rings_each_led_at_its_raw_pixel_the_panels_in_camera_order(written):
    """The panels side by side in camera order, each RGB turned to OpenCV's BGR; a found LED
    ringed (radius 9 px) in its colour about its raw (distorted) centroid, where the camera saw
    it, not its undistorted one."""
    raw, und = np.array([100.0, 120.0]), np.array([300.0, 300.0])
    eye = _eye({"gripper": (Detection(True, und, raw, 30.0),
                            Detection(False, np.full(2, np.nan), np.full(2, np.nan)))})
    video.VideoRecorder("unused").frame(eye, np.full(3, np.nan))
    (frame,) = written
    W, H = eye.estimate_rig.cameras[0].size
    assert frame.shape == (H, 2 * W, 3)
    assert frame[H - 1, 0].tolist() == list(BACKGROUND[0][::-1])
    assert frame[H - 1, W].tolist() == list(BACKGROUND[1][::-1])
    ring = frame[120, 109].astype(int)  # 9 px right of the raw centroid
    assert np.abs(ring - [255 * c for c in LED_RGB["gripper"][::-1]]).max() < 80, ring
    assert frame[300, 309].tolist() == list(BACKGROUND[0][::-1])  # nothing about the undistorted


def test_cameras_of_different_image_heights_make_one_frame_the_shorter_padded_below(written):
    """A rig of 1280 x 720 and 640 x 480 cameras (each valid in a rig file): --video ended the
    run with a traceback (numpy.hstack: 'along dimension 0, the array at index 0 has size 720
    and the array at index 1 has size 480'). Now one frame 720 px tall, 1280 + 640 wide: each
    panel at its own pixels, the shorter one filled below in grey."""
    import dataclasses

    rig = Rig.from_yaml(default_rig_path("two-link"))
    big = dataclasses.replace(rig.cameras[0], image_width=1280, image_height=720,
                              cx=639.5, cy=359.5)
    rig = dataclasses.replace(rig, cameras=(big, rig.cameras[1]))
    views = tuple(np.full((c.image_height, c.image_width, 3), b, np.uint8)
                  for c, b in zip(rig.cameras, BACKGROUND))
    eye = SimpleNamespace(arm=ArmSpec.from_args("two-link"), estimate_rig=rig,
                          last_observation=SimpleNamespace(frames=lambda: views, detections={},
                                                           reasons={}))
    video.VideoRecorder("unused").frame(eye, np.full(3, np.nan))
    (frame,) = written
    assert frame.shape == (720, 1280 + 640, 3)
    assert frame[719, 0].tolist() == list(BACKGROUND[0][::-1])
    assert frame[479, 1280].tolist() == list(BACKGROUND[1][::-1])
    assert frame[480, 1280].tolist() == list(video.PAD_BGR)
    assert frame[719, 1919].tolist() == list(video.PAD_BGR)


def test_an_odd_sized_frame_gets_a_row_and_a_column_more_and_reads_back_whole(tmp_path):
    """641 x 481 and 639 x 479 cameras make a 1280 x 481 frame, which the 4:2:0 encoders cut to
    1280 x 480 (read back one row short, unnoticed: the check counts frames). The frame is
    padded to 1280 x 482 (one grey row below, the panels' pixels where they were), and a video
    written through OpenCV reads back at that size, every frame."""
    a = np.full((481, 641, 3), 50, np.uint8)
    b = np.full((479, 639, 3), 150, np.uint8)
    frame = video.side_by_side([a, b])
    assert frame.shape == (482, 1280, 3)
    assert (frame[:481, :641] == 50).all() and (frame[:479, 641:] == 150).all()
    assert frame[481, 0].tolist() == list(video.PAD_BGR)
    three = video.side_by_side([a, a, np.full((480, 640, 3), 9, np.uint8)])  # 1922 x 481 -> 482
    assert three.shape == (482, 1922, 3)
    writer, path, _ = video.open_writer(tmp_path / "v", 20.0, frame.shape[1::-1])
    for _ in range(3):
        writer.write(frame)
    writer.release()
    cap = video.cv2.VideoCapture(str(path))
    sizes = []
    while True:
        ok, got = cap.read()
        if not ok:
            break
        sizes.append(got.shape)
    cap.release()
    assert sizes == [frame.shape] * 3


def test_the_ring_stays_outside_an_led_whose_image_is_larger_than_it(written):
    """The ring was 9 px whatever the LED's image: with a longer lens (f = 1000 px, 620 mm
    away: an LED 9.7 px in radius) it lay inside the LED's disc, drawn in the LED's colour,
    and no LED in that camera's panel looked circled. Now it clears the blob (area pi r^2) by
    3 px: 13 px for r = 9.7; 9 px, as before, for the shipped rigs' ~5.5 px LEDs."""
    raw = np.array([200.0, 150.0])
    dets = {"gripper": (Detection(True, raw, raw, float(np.pi * 9.7**2)),
                        Detection(False, np.full(2, np.nan), np.full(2, np.nan)))}
    video.VideoRecorder("unused").frame(_eye(dets), np.full(3, np.nan))
    (frame,) = written
    colour = [255 * c for c in LED_RGB["gripper"][::-1]]
    assert np.abs(frame[150, 213].astype(int) - colour).max() < 80  # the ring, 13 px right
    assert frame[150, 209].tolist() == list(BACKGROUND[0][::-1])  # not at 9 px
    assert video.ring_radius_px(np.pi * 5.5**2) == 9
    assert video.ring_radius_px(np.pi * 9.7**2) == 13
    assert video.ring_radius_px(0.0) == 9


def test_the_cross_marks_where_the_gripper_led_belongs_above_a_planar_set_point(written):
    """A planar set point lies in the joints' plane (z = 0); the gripper's LED, which the camera
    sees, is led_standoff_mm (12 mm) above it. The cross (its drawn pixels' centroid) is within
    1 px of the projection of that point in each camera (drawn at the nearest whole pixel: up to
    0.71 px), not of the set point itself (2-4 px off on the planar rig)."""
    eye = _eye({})
    set_point = np.array([60.0, 150.0, 0.0])
    video.VideoRecorder("unused").frame(eye, set_point)
    (frame,) = written
    W = eye.estimate_rig.cameras[0].size[0]
    for i, cam in enumerate(eye.estimate_rig.cameras):
        panel = frame[:, i * W:(i + 1) * W].astype(int)
        drawn = np.abs(panel - BACKGROUND[i][::-1]).sum(axis=2) > 60
        drawn[:30, :] = False  # the camera's name
        v, u = np.nonzero(drawn)
        centre = np.array([u.mean(), v.mean()])
        led = cam.project(set_point + [0, 0, eye.arm.led_standoff_mm]).ravel()
        assert np.linalg.norm(centre - led) < 1.0, (i, centre, led)  # drawn at a whole pixel
        assert np.linalg.norm(cam.project(set_point).ravel() - led) > 1.5


def test_a_video_one_frame_short_is_an_error(tmp_path):
    """The file is read back: one frame fewer than were written is a one-line error."""
    rng = np.random.default_rng(0)
    views = [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(2)]
    eye = _eye({})
    eye.last_observation = SimpleNamespace(frames=lambda: views, detections={}, reasons={})
    rec = video.VideoRecorder(tmp_path / "v")
    for _ in range(5):
        rec.frame(eye, np.full(3, np.nan))
    rec.frames += 1  # the recorder believes one frame more than the file holds
    with pytest.raises(UserError, match="only 5 of its 6 frames"):
        rec.close(check=True)


def test_each_frame_is_labelled_with_its_set_point_as_trace_csv_counts_them(written):
    """A frame carries its set point (trace.csv's k) at the first panel's foot, so that a
    moment of the video can be found in the trace; the loop hands the recorder k 0, k 1, ...
    (a frame had no index)."""
    from itg_vision.feedback import TruthFeedback
    from itg_vision.loop import simulate
    from itg_vision.world import World

    for label in ("", "k 12"):
        written.clear()
        video.VideoRecorder("unused").frame(_eye({}), np.full(3, np.nan), label=label)
        (frame,) = written
        H = frame.shape[0]
        foot = frame[H - 26:H - 4, 8:60].astype(int)
        assert (np.abs(foot - BACKGROUND[0][::-1]).sum(axis=2) > 60).any() == bool(label)

    class Labels:
        seen: list = []

        def frame(self, feedback, desired_mm, label=""):
            self.seen.append(label)

    class Hold:
        uses_encoders = False

        def step(self, desired_mm, markers, q_deg):
            from itg_vision.contracts import Step
            return Step(np.zeros(2))

    rec = Labels()
    with World(ArmSpec.from_args("two-link")) as world:
        trace = simulate(world, Hold(), TruthFeedback(), np.array([[100.0, 0.0, 0.0]] * 4),
                         iterations=2, recorder=rec)
    assert rec.seen == ["k 0", "k 1", "k 2", "k 3"] == [f"k {k}" for k in range(len(trace.records))]
