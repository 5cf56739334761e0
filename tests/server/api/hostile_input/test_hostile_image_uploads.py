"""Image uploads: the size from the header, before any decoding; an image declaring too many
pixels is refused before it is decoded."""

from __future__ import annotations

import json
import struct
import zlib

import pytest

from tests.support.hostile_requests import RSS_BOUND_MB


def _encoded(ext: str, shape: tuple[int, ...], seed: int = 0) -> bytes:
    import cv2
    import numpy as np

    image = np.random.default_rng(seed).integers(0, 255, shape, dtype=np.uint8)
    ok, data = cv2.imencode(ext, image)
    assert ok
    return data.tobytes()


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    crc = struct.pack(">I", zlib.crc32(kind + body))
    return struct.pack(">I", len(body)) + kind + body + crc


def _png_declaring(width: int, height: int) -> bytes:
    """Return a PNG of a few bytes whose header declares width x height grey pixels (8 bit) and
    that holds none of them."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr) + _png_chunk(b"IEND", b"")


@pytest.mark.parametrize("ext", [".png", ".jpg", ".bmp", ".tiff", ".webp", ".gif", ".ppm"])
@pytest.mark.parametrize("shape", [(37, 53, 3), (300, 17, 3)])
def test_image_headers_give_the_size_opencv_decodes(ext, shape):
    import cv2
    import numpy as np

    from server.api.limits import read_image_header

    data = _encoded(ext, shape)
    header = read_image_header(data)
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert header is not None
    assert (header.height, header.width) == decoded.shape[:2]


def test_an_image_declaring_too_many_pixels_is_refused_before_decoding():
    from server.api.errors import FieldProblem
    from server.api.limits import check_image_size

    # A 1 kB PNG that declares 20000 x 20000 grey pixels (760 MB to decode).
    png = _png_declaring(20000, 20000)
    with pytest.raises(FieldProblem) as refused:
        check_image_size(png, 12_000_000, "files.0", "big.png")
    assert refused.value.status == 413
    reason = refused.value.errors[0].reason
    assert "20000x20000" in reason and "limit of 12000000 pixels" in reason
    with pytest.raises(FieldProblem) as unknown:
        check_image_size(b"hello", 12_000_000, "files.0", "a.png")
    assert unknown.value.status == 415
    assert check_image_size(_encoded(".png", (48, 64)), 12_000_000, "f", "ok.png").pixels == 3072


def test_an_upload_declaring_too_many_pixels_is_refused_by_the_service(case, home):
    # The same end to end: a few-byte PNG declaring 20000 x 20000 pixels cost the old
    # service ~760 MB to decode before its 415.
    png = _png_declaring(20000, 20000)
    boundary = "hostileboundary"
    camera = home["cameras"][0]["id"]
    parts = [
        (f'--{boundary}\r\nContent-Disposition: form-data; name="{k}"\r\n\r\n{v}\r\n').encode()
        for k, v in (("camera_id", camera), ("board", "9x6"), ("square", "0.025"))
    ]
    parts.append(
        (
            f'--{boundary}\r\nContent-Disposition: form-data; name="files"; '
            'filename="big.png"\r\nContent-Type: image/png\r\n\r\n'
        ).encode()
        + png
        + b"\r\n"
    )
    body = b"".join(parts) + f"--{boundary}--\r\n".encode()
    status, _, problem, growth, _ = case.send(
        "POST",
        "/api/v1/calibration-runs/upload",
        body,
        **{"Content-Type": f"multipart/form-data; boundary={boundary}"},
    )
    assert status == 413, problem
    assert "20000x20000" in json.dumps(problem) and "pixels" in json.dumps(problem)
    assert growth < RSS_BOUND_MB
    case.next_request_answered()
