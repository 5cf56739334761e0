"""A local RTSP camera for the tests: serves a video file as H.264 over RTSP (RTP over UDP or
TCP, as the client asks) with GStreamer's RTSP server, the way an IP camera serves its stream.

Run with the system Python that has PyGObject and the GStreamer RTSP server's introspection
data (Debian: python3-gi, gir1.2-gst-rtsp-server-1.0, gstreamer1.0-plugins-good for the AVI
demuxer and RTP payloader, gstreamer1.0-plugins-ugly for x264enc):

    /usr/bin/python3 tests/support/rtsp_server.py --port 8554 --mount /cam clip.avi

Each client gets its own pipeline that plays the file from its start at the file's frame rate
and ends the stream at the file's end (a client that reconnects plays it again). Prints
`ready rtsp://127.0.0.1:PORT/MOUNT` on stdout once it listens; runs until SIGTERM or SIGINT.
`--check` only imports what it needs and exits 0 (or 1 saying what is missing).
"""

from __future__ import annotations

import argparse
import signal
import sys

NEEDED = ("avidemux", "jpegdec", "videoconvert", "x264enc", "rtph264pay")


def _import() -> tuple[object, object, object]:
    """Return the Gst, GstRtspServer and GLib modules. Raises ImportError or ValueError with
    what is missing."""
    import gi

    gi.require_version("Gst", "1.0")
    gi.require_version("GstRtspServer", "1.0")
    from gi.repository import GLib, Gst, GstRtspServer

    Gst.init(None)
    missing = [name for name in NEEDED if Gst.ElementFactory.find(name) is None]
    if missing:
        raise ImportError(
            f"GStreamer elements {missing} are missing (gstreamer1.0-plugins-good, "
            "gstreamer1.0-plugins-ugly)"
        )
    return Gst, GstRtspServer, GLib


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Serve a video file over RTSP (H.264).")
    parser.add_argument("file", nargs="?", help="an AVI file of JPEG frames (OpenCV's MJPG)")
    parser.add_argument("--port", type=int, default=8554)
    parser.add_argument("--mount", default="/cam")
    parser.add_argument("--check", action="store_true", help="check the imports and exit")
    args = parser.parse_args(argv)
    try:
        _, GstRtspServer, GLib = _import()
    except (ImportError, ValueError) as exc:
        print(f"rtsp_server: {exc}", file=sys.stderr)
        return 1
    if args.check:
        return 0
    if not args.file:
        parser.error("give the video file to serve")
    server = GstRtspServer.RTSPServer()  # type: ignore[attr-defined]
    server.set_address("127.0.0.1")
    server.set_service(str(args.port))
    factory = GstRtspServer.RTSPMediaFactory()  # type: ignore[attr-defined]
    # A key frame every 5 frames and no B-frames: a client that joins decodes at once, and a
    # frame leaves the encoder as soon as it is in (what an IP camera's low-latency mode does).
    location = args.file.replace("\\", "\\\\").replace('"', '\\"')
    factory.set_launch(
        f'( filesrc location="{location}" ! avidemux ! jpegdec ! videoconvert ! '
        "video/x-raw,format=I420 ! x264enc tune=zerolatency speed-preset=ultrafast "
        "key-int-max=5 bframes=0 ! rtph264pay name=pay0 pt=96 config-interval=1 )"
    )
    factory.set_shared(False)
    server.get_mount_points().add_factory(args.mount, factory)
    if server.attach(None) == 0:
        print(f"rtsp_server: cannot listen on 127.0.0.1:{args.port}", file=sys.stderr)
        return 1
    loop = GLib.MainLoop()  # type: ignore[attr-defined]
    for signum in (signal.SIGTERM, signal.SIGINT):
        GLib.unix_signal_add(GLib.PRIORITY_DEFAULT, signum, loop.quit)  # type: ignore[attr-defined]
    print(f"ready rtsp://127.0.0.1:{args.port}{args.mount}", flush=True)
    loop.run()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
