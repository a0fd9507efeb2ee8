"""--video: both camera views side by side, detected centroids and the projected desired point.

Codec: the first of these that this OpenCV build can encode (checked when the first frame
comes, with OpenCV's own log silenced while trying):

FFmpeg reports a failed encoder on stderr itself (not through OpenCV's log), so stderr's file
descriptor is pointed at /dev/null while trying.

1. H.264 (fourcc ``avc1``) in ``.mp4``: plays everywhere. The opencv-python wheels ship FFmpeg
   without an H.264 encoder (LGPL build), so this usually fails.
2. VP9 (``VP90``) in ``.webm``: plays in Chrome, Firefox, Edge and Safari 14.1+.
3. MPEG-4 Part 2 (``mp4v``) in ``.mp4``: most browsers do not play it (VLC, ffplay do); the
   note says so.

:attr:`VideoRecorder.path` is the file written (its suffix set by the codec) and
:attr:`VideoRecorder.codec_note` says which codec, for the summary.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np

from .errors import UserError
from .stdio import quiet_c_streams
from .urdf import LED_RGB


#: (fourcc, file suffix, note), in order of preference: see the module docstring.
CODECS = (("avc1", ".mp4", "H.264"),
          ("VP90", ".webm", "VP9; this OpenCV cannot encode H.264"),
          ("mp4v", ".mp4", "MPEG-4 Part 2, which most browsers do not play; this OpenCV can "
                           "encode neither H.264 nor VP9"))


def open_writer(path: Path, fps: float, size: tuple[int, int]):
    """The first codec of :data:`CODECS` this OpenCV can write: (writer, path, note)."""
    with quiet_c_streams("stderr"):
        for fourcc, suffix, note in CODECS:
            target = path.with_suffix(suffix)
            writer = cv2.VideoWriter(str(target), cv2.VideoWriter_fourcc(*fourcc), fps, size)
            if writer.isOpened():
                return writer, target, note
            writer.release()
            if target.exists() and target.stat().st_size == 0:
                target.unlink()
    raise UserError("video: this OpenCV can write none of H.264, VP9 or MPEG-4 video (no "
                    "FFmpeg backend, or one without those encoders)")


#: Radius (px) of the ring about a detected LED, at least: the LED's own image is smaller on
#: the shipped rigs (about 5.5 px at f = 600 px, 650 mm away).
RING_PX = 9
#: Pixels the ring keeps outside an LED's image when that is larger (a longer lens, a nearer
#: camera): a ring drawn in the LED's colour inside its disc cannot be seen.
RING_CLEARANCE_PX = 3


def ring_radius_px(area_px: float) -> int:
    """The ring's radius about an LED whose blob covers ``area_px`` (its disc's radius is
    sqrt(area / pi)): :data:`RING_PX`, or that radius + :data:`RING_CLEARANCE_PX` if larger."""
    r = math.sqrt(max(float(area_px), 0.0) / math.pi) if math.isfinite(area_px) else 0.0
    return max(RING_PX, math.ceil(r) + RING_CLEARANCE_PX)


#: Grey (BGR) below a panel shorter than the other (cameras of different image heights).
PAD_BGR = (96, 96, 96)


def side_by_side(panels: list[np.ndarray]) -> np.ndarray:
    """The panels (BGR images) left to right, each at its own pixels (the circles and crosses
    drawn on them stay where the eye saw them); a panel shorter than the tallest is filled
    below with :data:`PAD_BGR` (a rig's cameras may have different image heights), and an odd
    width or height gets one more column or row of it: the encoders store colour at half
    resolution (4:2:0) and cut an odd frame's last row (a 641 x 481 rig's video read back 480
    rows)."""
    h = max(p.shape[0] for p in panels)
    frame = np.hstack([p if p.shape[0] == h else cv2.copyMakeBorder(
        p, 0, h - p.shape[0], 0, 0, cv2.BORDER_CONSTANT, value=PAD_BGR) for p in panels])
    odd_h, odd_w = frame.shape[0] % 2, frame.shape[1] % 2
    if odd_h or odd_w:
        frame = cv2.copyMakeBorder(frame, 0, odd_h, 0, odd_w, cv2.BORDER_CONSTANT, value=PAD_BGR)
    return frame


class VideoRecorder:
    """Writes one frame per set point (the look of its last iteration; 20 fps by default) from
    a ``VisionFeedback``'s last observation: each LED the eye found ringed in its colour, one it
    then rejected (its triangulation's residual, or the other camera's miss) crossed out too and
    named in the panel's corner.

    ``path``: the file to write; its suffix is set by the codec found (see the module
    docstring), so read :attr:`path` after the first frame.
    """

    def __init__(self, path: str | Path, fps: float = 20.0):
        self.path = Path(path)
        self.fps = fps
        self.codec_note = ""
        self._writer = None
        self._written: Path | None = None  # where OpenCV writes (self.path, or a stand-in)
        self._stand_in: Path | None = None  # a temporary folder for a path OpenCV cannot take
        self.frames = 0  # frames written

    def frame(self, feedback, desired_mm: np.ndarray, label: str = "") -> None:
        """One frame from ``feedback.last_observation`` (whole frames: the run forces
        ``full_frame`` with ``--video``); nothing if it has none. ``label`` (the set point,
        ``k 12``: trace.csv's row) is written at the first panel's foot."""
        obs = feedback.last_observation
        views = obs.frames() if obs is not None else None
        if not views:
            return
        desired = feedback.arm.gripper_led_mm(desired_mm)  # the cross: where the LED belongs
        missed = [n for n, why in obs.reasons.items() if why]  # the eye's verdict at this look
        panels = []
        for i, (img, cam) in enumerate(zip(views, feedback.estimate_rig.cameras)):
            bgr = np.ascontiguousarray(img[..., ::-1])
            for name, dets in obs.detections.items():
                if dets[i].ok:
                    uv = dets[i].uv_raw_px
                    colour = tuple(int(255 * c) for c in LED_RGB[name][::-1])
                    at = (int(round(uv[0])), int(round(uv[1])))
                    ring = ring_radius_px(dets[i].area_px)
                    cv2.circle(bgr, at, ring, colour, 1, cv2.LINE_AA)
                    if name in missed:  # found here, but rejected: not what the controller got
                        cv2.drawMarker(bgr, at, colour, cv2.MARKER_TILTED_CROSS, 2 * ring, 1,
                                       cv2.LINE_AA)
            if missed:
                cv2.putText(bgr, "missed: " + ", ".join(missed), (8, 40), cv2.FONT_HERSHEY_SIMPLEX,
                            0.5, (0, 0, 200), 1, cv2.LINE_AA)
            d = cam.project(desired).reshape(-1)
            if np.all(np.isfinite(d)):
                cv2.drawMarker(bgr, (int(round(d[0])), int(round(d[1]))), (200, 0, 200),
                               cv2.MARKER_CROSS, 14, 1, cv2.LINE_AA)
            cv2.putText(bgr, cam.name, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
            panels.append(bgr)
        if label:
            h = panels[0].shape[0]
            cv2.putText(panels[0], label, (8, h - 10), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0),
                        1, cv2.LINE_AA)
        frame = side_by_side(panels)
        if self._writer is None:
            h, w = frame.shape[:2]
            target = self.path
            try:
                str(target).encode("utf-8")
            except UnicodeEncodeError:  # a name's bytes that are not UTF-8: OpenCV's FFmpeg
                # writer crashes the process on such a path; it writes under a plain one here
                self._stand_in = Path(tempfile.mkdtemp(prefix="itg_vision-video-"))
                target = self._stand_in / "video"
            self._writer, self._written, self.codec_note = open_writer(target, self.fps, (w, h))
            self.path = self.path.with_suffix(self._written.suffix)
        self._writer.write(frame)
        self.frames += 1

    def close(self, check: bool = False) -> None:
        """Finish the file. ``check``: read it back first, a `UserError` unless every frame
        written decodes (OpenCV's writer says nothing of a write the system refused: a full
        disk, a file size limit); read where OpenCV wrote it, since its FFmpeg crashes the
        process on a path whose bytes are not UTF-8."""
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        try:
            if check and self.frames:
                self._read_back(self._written)
            if self._stand_in is not None and self._written is not None and self._written.exists():
                shutil.move(self._written, self.path)  # the video to its place
        finally:
            if self._stand_in is not None:  # the stand-in folder gone
                shutil.rmtree(self._stand_in, ignore_errors=True)
                self._stand_in = None

    def _read_back(self, path: Path) -> None:
        read = 0
        with quiet_c_streams("stderr"):  # FFmpeg's own words on a cut file: said below
            cap = cv2.VideoCapture(str(path))
            try:
                while read < self.frames and cap.grab():
                    read += 1
            finally:
                cap.release()
        if read < self.frames:
            raise UserError(f"video: {self.path.name}: only {read} of its {self.frames} frames "
                            "could be read back (the disk full, or a file size limit?)")

    def __enter__(self) -> "VideoRecorder":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(check=exc_type is None)
