"""--video: both camera views side by side, detected centroids and the projected desired point."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .errors import UserError
from .urdf import LED_RGB


class VideoRecorder:
    """Writes one frame per set point from a ``VisionFeedback``'s last images (MP4, mp4v)."""

    def __init__(self, path: str | Path, fps: float = 20.0):
        self.path = Path(path)
        self.fps = fps
        self._writer = None

    def frame(self, feedback, desired_mm: np.ndarray) -> None:
        images = getattr(feedback, "last_images", None)
        if not images:
            return
        views = next(iter(images.values()))
        panels = []
        for i, (img, cam) in enumerate(zip(views, feedback.estimate_rig.cameras)):
            bgr = np.ascontiguousarray(img[..., ::-1])
            for name, uvs in feedback.last_uv_raw.items():
                uv = uvs[i]
                if uv is not None:
                    colour = tuple(int(255 * c) for c in LED_RGB[name][::-1])
                    cv2.circle(bgr, (int(round(uv[0])), int(round(uv[1]))), 9, colour, 1, cv2.LINE_AA)
            d = cam.project(np.asarray(desired_mm, float)).reshape(-1)
            if np.all(np.isfinite(d)):
                cv2.drawMarker(bgr, (int(round(d[0])), int(round(d[1]))), (200, 0, 200),
                               cv2.MARKER_CROSS, 14, 1, cv2.LINE_AA)
            cv2.putText(bgr, cam.name, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
            panels.append(bgr)
        frame = np.hstack(panels)
        if self._writer is None:
            h, w = frame.shape[:2]
            self._writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps, (w, h))
            if not self._writer.isOpened():
                raise UserError(f"{self.path}: cannot open an MP4 writer (OpenCV built without a codec?)")
        self._writer.write(frame)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None

    def __enter__(self) -> "VideoRecorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
