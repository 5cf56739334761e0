"""A local MJPEG server, the camera node tests' stand-in for an IP camera."""

from __future__ import annotations

import http.server
import threading
import time


class MjpegStream:
    """An MJPEG server cycling through `frames` at `fps`, each part stamped with X-Timestamp."""

    def __init__(self, frames: list[bytes], fps: float = 8.0) -> None:
        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args) -> None:
                pass

            def do_GET(self) -> None:
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=b")
                self.end_headers()
                k = 0
                while True:
                    body = frames[k % len(frames)]
                    head = (
                        f"--b\r\nContent-Type: image/jpeg\r\nContent-Length: {len(body)}\r\n"
                        f"X-Timestamp: {time.time():.6f}\r\n\r\n"
                    )
                    try:
                        self.wfile.write(head.encode() + body + b"\r\n")
                        self.wfile.flush()
                    except (BrokenPipeError, ConnectionResetError):
                        return
                    k += 1
                    time.sleep(1.0 / fps)

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/stream.mjpg"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()
