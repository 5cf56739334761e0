"""A local MJPEG server, the camera node tests' stand-in for an IP camera (or the twin's
stream.mjpg), with the ways a real one fails: a hung sensor, a camera gone away, a stream that
ends."""

from __future__ import annotations

import http.server
import threading
import time

import cv2
import numpy as np


def flat_jpeg() -> bytes:
    """Return a small uniform grey JPEG (32 x 24 pixels)."""
    ok, jpg = cv2.imencode(".jpg", np.full((24, 32, 3), 90, np.uint8))
    assert ok
    return jpg.tobytes()


class MjpegStream:
    """An MJPEG server cycling through `frames` (JPEG bytes) at `fps`, each part stamped with
    X-Timestamp (Unix seconds). While `paused` is set it holds its connections open and sends
    nothing (as the twin's stream while the twin is paused, or a camera whose sensor hung);
    while `down` is set it answers 503 (a camera gone away); with `per_connection` it ends each
    connection after that many parts."""

    def __init__(
        self, frames: list[bytes], fps: float = 8.0, per_connection: int | None = None
    ) -> None:
        self.paused = threading.Event()
        self.down = threading.Event()
        owner = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:
                pass

            def do_GET(self) -> None:
                if owner.down.is_set():
                    self.send_error(503)
                    return
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=b")
                self.end_headers()
                k = 0
                while per_connection is None or k < per_connection:
                    if owner.paused.is_set():
                        time.sleep(0.02)
                        continue
                    body = frames[k % len(frames)]
                    head = (
                        f"--b\r\nContent-Type: image/jpeg\r\nContent-Length: {len(body)}\r\n"
                        f"X-Timestamp: {time.time():.6f}\r\n\r\n"
                    )
                    try:
                        self.wfile.write(head.encode() + body + b"\r\n")
                        self.wfile.flush()
                    except (BrokenPipeError, ConnectionResetError):
                        return  # the reader left
                    k += 1
                    time.sleep(1.0 / fps)

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/stream.mjpg"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
