"""Landmark artwork: true physical size in SVG and PDF, the symbol readable, colours exclusive."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
import zlib

import cv2
import numpy as np
import pytest
import zxingcpp

from core.errors import InvalidInput
from core.landmarks import ObjectMark, Signpost, decode_payload
from core.landmarks.artwork import make_artwork, to_pdf, to_png, to_png_image, to_svg

CUP = ObjectMark(7, "cup", "blue cup", "kitchen", (0.08, 0.08, 0.1), hints=("fragile",))
DOOR = Signpost(3, "kitchen door", "kitchen", (1.0, 2.0, 1.2, 0, 0, 0.7071, 0.7071), (1, 2))
PT_PER_MM = 72 / 25.4


def _svg_frame_mm(svg: str) -> float:
    root = ET.fromstring(svg)
    ns = "{http://www.w3.org/2000/svg}"
    w_mm = float(root.get("width", "").removesuffix("mm"))
    vb = [float(v) for v in root.get("viewBox", "").split()]
    unit = w_mm / vb[2]  # millimetres per user unit
    frame = next(p for p in root.iter(f"{ns}path") if p.get("id") == "frame")
    # The outer square is the first sub-path: "M x y h W v W h -W z".
    side = float(re.match(r"M\S+ \S+h([0-9.]+)", frame.get("d", "")).group(1))  # type: ignore[union-attr]
    return side * unit


def _pdf_rects_mm(pdf: bytes) -> list[tuple[float, float]]:
    """Return (w, h) in mm of every filled rectangle in the PDF's content streams."""
    out = []
    for m in re.finditer(rb"stream\r?\n(.*?)\r?\nendstream", pdf, re.S):
        data = m.group(1)
        try:
            data = zlib.decompress(data)
        except zlib.error:
            pass
        for r in re.finditer(rb"(-?[0-9.]+) (-?[0-9.]+) (-?[0-9.]+) (-?[0-9.]+) re", data):
            w, h = float(r.group(3)), float(r.group(4))
            out.append((abs(w) / PT_PER_MM, abs(h) / PT_PER_MM))
    return out


def test_a_100_mm_frame_measures_100_mm_in_svg_and_pdf() -> None:
    art = make_artwork(CUP, size=0.100)
    assert _svg_frame_mm(to_svg(art)) == pytest.approx(100.0, abs=1e-3)
    rects = _pdf_rects_mm(to_pdf(art))
    # The blue frame is the largest filled square after the page background; fpdf2 writes
    # coordinates with 2 decimals in points (0.0035 mm).
    squares = sorted(w for w, h in rects if abs(w - h) < 1e-6)
    assert any(abs(w - 100.0) < 0.005 for w in squares), squares
    # The page is the artwork's size: 120 mm wide (pattern plus two 10 mm margins).
    box = re.search(rb"/MediaBox \[0 0 ([0-9.]+) ([0-9.]+)\]", to_pdf(art))
    assert box is not None and float(box.group(1)) / PT_PER_MM == pytest.approx(120.0, abs=0.01)


def test_ring_radii_at_true_size_in_svg() -> None:
    art = make_artwork(DOOR, size=0.200)
    root = ET.fromstring(to_svg(art))
    radii = [float(c.get("r", "")) for c in root.iter("{http://www.w3.org/2000/svg}circle")]
    assert radii[0] == pytest.approx(100.0)  # outer diameter 200 mm
    assert sorted(radii, reverse=True) == radii and len(radii) == 4


@pytest.mark.parametrize("record", [CUP, DOOR])
def test_png_symbol_decodes_and_colours_are_exclusive(record: ObjectMark | Signpost) -> None:
    art = make_artwork(record)
    img = to_png_image(art, 4000)
    read = zxingcpp.read_barcodes(img)
    assert [decode_payload(r.text) for r in read] == [record]
    hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
    saturated = hsv[..., 1] > 60
    hue = hsv[..., 0][saturated].astype(int)
    # Only one hue is present among saturated pixels: blue (OpenCV hue 120) or red (0/180).
    target = 120 if record.kind == "object" else 0
    assert np.all(np.minimum(np.abs(hue - target), 180 - np.abs(hue - target)) <= 2)
    # The coloured pattern has the layout's size: the saturated pixels' extent, 5 % margin
    # for anti-aliased edge pixels (one pixel at 4 px/mm is 0.25 mm of 100-200 mm).
    _, xs = np.nonzero(saturated)
    width_mm = (xs.max() - xs.min() + 1) / 4.0
    assert width_mm == pytest.approx(art.size * 1000, rel=0.01)
    png = to_png(art, 4000)
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and b"pHYs" in png[:64]


def test_module_grid_matches_segno_and_error_level() -> None:
    art = make_artwork(CUP)
    n = len(art.modules)
    assert (n - 17) % 4 == 0  # a QR symbol of version v has 17 + 4 v modules
    with pytest.raises(InvalidInput):
        make_artwork(CUP, error="l")
    with pytest.raises(InvalidInput):
        make_artwork(CUP, kind="signpost")
    with pytest.raises(InvalidInput):
        make_artwork(CUP, size=-1.0)
