"""Printable landmarks at true physical size: SVG and PDF (vector) and PNG (for the twin).

Geometry (all in units of the pattern size s, the outer side of the blue frame or the outer
diameter of the outer red ring; `pattern_layout` gives it in metres):

* object mark: a blue square frame of outer side s and band 0.12 s; the QR symbol, of side
  0.64 s, centred inside it (a quiet zone of 0.06 s, about 3-4 modules, between symbol and
  frame);
* signpost: two red rings, radii 0.40-0.50 s (outer) and 0.30-0.35 s (inner); the QR symbol, of
  side 0.38 s, centred (its corners 0.03 s inside the inner ring).

The page adds a white margin of 0.1 s around the pattern and a band of 0.2 s under it for the id
and the human label. The mark frame: origin at the pattern's centre, x along the symbol's rows
(to the right on the page), y up the page, z out of the printed face. Pure blue (0, 0, 255) and
pure red (255, 0, 0) are used for the frame and the rings and nowhere else; the symbol and the
label are black on white. The symbol is segno's QR code in byte mode, error correction M (or the
level asked), without error-correction boost, so its geometry is exactly the one the payload
needs.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np
import segno
from fpdf import FPDF
from numpy.typing import NDArray

from core.errors import InvalidInput
from core.landmarks.payload import ObjectMark, Record, Signpost, encode_payload

Kind = Literal["object", "signpost"]

BLUE_RGB = (0, 0, 255)
RED_RGB = (255, 0, 0)

FRAME_BAND = 0.12
OBJECT_QR = 0.64
RING_RADII = (0.50, 0.40, 0.35, 0.30)  # outer ring outer/inner edge, inner ring outer/inner edge
SIGNPOST_QR = 0.38
MARGIN = 0.10
LABEL_BAND = 0.20
ERROR_LEVELS = ("m", "q", "h")
DEFAULT_SIZE: dict[str, float] = {"object": 0.10, "signpost": 0.20}


@dataclass(frozen=True)
class PatternLayout:
    """Where things are on a landmark, metres, in the mark frame (origin at the centre).

    kind; size: outer side of the frame or outer diameter of the rings; qr_side: the symbol's
    side; frame_outer, frame_inner: half-sides of the frame's edges (object marks, else 0);
    ring_radii: the four ring edges (signposts, else ()), largest first.
    """

    kind: Kind
    size: float
    qr_side: float
    frame_outer: float
    frame_inner: float
    ring_radii: tuple[float, ...]


def pattern_layout(kind: str, size: float) -> PatternLayout:
    """Return the layout of a landmark of `kind` ("object" or "signpost") and `size` metres."""
    if kind not in DEFAULT_SIZE:
        raise InvalidInput(f"landmark kind must be 'object' or 'signpost', got {kind!r}")
    if not (np.isfinite(size) and 0.005 <= size <= 5.0):
        raise InvalidInput(f"landmark size must be 0.005-5 metres, got {size!r}")
    if kind == "object":
        return PatternLayout(
            "object", size, OBJECT_QR * size, size / 2, (0.5 - FRAME_BAND) * size, ()
        )
    return PatternLayout(
        "signpost", size, SIGNPOST_QR * size, 0.0, 0.0, tuple(r * size for r in RING_RADII)
    )


def qr_matrix(text: str, error: str = "m") -> NDArray[np.bool_]:
    """Return the QR symbol's module matrix (N, N) (True = dark), byte mode, no quiet zone."""
    if error not in ERROR_LEVELS:
        raise InvalidInput(f"error correction must be one of {ERROR_LEVELS}, got {error!r}")
    qr = segno.make(text, error=error, boost_error=False, mode="byte", micro=False)
    return np.array([list(row) for row in qr.matrix], dtype=bool)


@dataclass(frozen=True)
class Artwork:
    """A landmark's printable design, in millimetres on its page (origin top-left, y down).

    kind; size metres; record and text (the QR payload); label (printed under the pattern);
    modules: the symbol's module matrix; page_mm (width, height); centre_mm: the pattern's
    centre on the page; layout: the geometry in metres.
    """

    kind: Kind
    size: float
    text: str
    label: str
    modules: NDArray[np.bool_]
    page_mm: tuple[float, float]
    centre_mm: tuple[float, float]
    layout: PatternLayout

    @property
    def module_mm(self) -> float:
        """Return the side of one QR module, millimetres."""
        return 1000.0 * self.layout.qr_side / len(self.modules)

    def module_runs(self) -> list[tuple[float, float, float, float]]:
        """Return the dark modules as rectangles (x, y, w, h) mm, runs merged along rows."""
        n = len(self.modules)
        m = self.module_mm
        x0 = self.centre_mm[0] - n * m / 2
        y0 = self.centre_mm[1] - n * m / 2
        rects: list[tuple[float, float, float, float]] = []
        pad = np.zeros((n, 1), bool)
        row_edges = np.diff(np.hstack([pad, self.modules, pad]).astype(np.int8), axis=1)
        for r in range(n):
            starts = np.flatnonzero(row_edges[r] == 1)
            ends = np.flatnonzero(row_edges[r] == -1)
            for a, b in zip(starts, ends, strict=True):
                rects.append((float(x0 + a * m), float(y0 + r * m), float((b - a) * m), m))
        return rects


def make_artwork(
    record: Record | str,
    kind: str | None = None,
    size: float | None = None,
    *,
    label: str | None = None,
    error: str = "m",
) -> Artwork:
    """Return the artwork of a landmark.

    record: an ObjectMark or Signpost (its payload is encoded and its kind and name used), or a
    raw payload text (then `kind` is required and `label` is printed as given). size: metres
    (default 0.10 for object marks, 0.20 for signposts).
    """
    if isinstance(record, ObjectMark | Signpost):
        text = encode_payload(record)
        rkind: str = record.kind
        if kind is not None and kind != rkind:
            raise InvalidInput(f"kind {kind!r} does not match the record's kind {rkind!r}")
        shown = label if label is not None else f"#{record.id} {record.name}"
    else:
        if kind is None:
            raise InvalidInput("a raw payload text needs its kind ('object' or 'signpost')")
        text, rkind, shown = str(record), kind, label or ""
    s = DEFAULT_SIZE.get(rkind, 0.1) if size is None else float(size)
    lay = pattern_layout(rkind, s)
    mm = 1000.0 * s
    page = ((1 + 2 * MARGIN) * mm, (1 + 2 * MARGIN + LABEL_BAND) * mm)
    centre = (page[0] / 2, (0.5 + MARGIN) * mm)
    return Artwork(
        kind=lay.kind,
        size=s,
        text=text,
        label=shown,
        modules=qr_matrix(text, error),
        page_mm=page,
        centre_mm=centre,
        layout=lay,
    )


def _f(x: float) -> str:
    return f"{x:.4f}".rstrip("0").rstrip(".")


def _label_font_mm(art: Artwork) -> float:
    return 0.08 * art.size * 1000.0


def _label_baseline_mm(art: Artwork) -> float:
    return art.centre_mm[1] + 1000.0 * art.size * (0.5 + 0.05) + _label_font_mm(art)


def to_svg(art: Artwork) -> str:
    """Return the artwork as SVG text; user units are millimetres and the page's width and
    height are given in mm, so the file prints at true size."""
    w, h = art.page_mm
    cx, cy = art.centre_mm
    parts = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{_f(w)}mm" height="{_f(h)}mm" '
        f'viewBox="0 0 {_f(w)} {_f(h)}">',
        f'<rect x="0" y="0" width="{_f(w)}" height="{_f(h)}" fill="#ffffff"/>',
    ]
    if art.kind == "object":
        o, i = art.layout.frame_outer * 1000, art.layout.frame_inner * 1000
        parts.append(
            f'<path id="frame" fill="#0000ff" fill-rule="evenodd" d="M{_f(cx - o)} {_f(cy - o)}'
            f"h{_f(2 * o)}v{_f(2 * o)}h{_f(-2 * o)}z M{_f(cx - i)} {_f(cy - i)}"
            f'h{_f(2 * i)}v{_f(2 * i)}h{_f(-2 * i)}z"/>'
        )
    else:
        for k, r in enumerate(art.layout.ring_radii):
            fill = "#ff0000" if k % 2 == 0 else "#ffffff"
            parts.append(f'<circle cx="{_f(cx)}" cy="{_f(cy)}" r="{_f(r * 1000)}" fill="{fill}"/>')
    d = "".join(
        f"M{_f(x)} {_f(y)}h{_f(rw)}v{_f(rh)}h{_f(-rw)}z" for x, y, rw, rh in art.module_runs()
    )
    parts.append(f'<path id="symbol" fill="#000000" d="{d}"/>')
    if art.label:
        label = art.label.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
        parts.append(
            f'<text x="{_f(cx)}" y="{_f(_label_baseline_mm(art))}" fill="#000000" '
            f'font-family="Helvetica, Arial, sans-serif" font-size="{_f(_label_font_mm(art))}" '
            f'text-anchor="middle">{label}</text>'
        )
    parts.append("</svg>")
    return "\n".join(parts) + "\n"


def to_pdf(art: Artwork) -> bytes:
    """Return the artwork as a one-page PDF whose page is the artwork's size in mm (fpdf2)."""
    w, h = art.page_mm
    cx, cy = art.centre_mm
    pdf = FPDF(unit="mm", format=(w, h))
    pdf.set_margin(0)
    pdf.set_auto_page_break(False)
    pdf.add_page()
    if art.kind == "object":
        o, i = art.layout.frame_outer * 1000, art.layout.frame_inner * 1000
        pdf.set_fill_color(*BLUE_RGB)
        pdf.rect(cx - o, cy - o, 2 * o, 2 * o, style="F")
        pdf.set_fill_color(255, 255, 255)
        pdf.rect(cx - i, cy - i, 2 * i, 2 * i, style="F")
    else:
        for k, r in enumerate(art.layout.ring_radii):
            pdf.set_fill_color(*(RED_RGB if k % 2 == 0 else (255, 255, 255)))
            pdf.circle(cx, cy, r * 1000, style="F")
    pdf.set_fill_color(0, 0, 0)
    for x, y, rw, rh in art.module_runs():
        pdf.rect(x, y, rw, rh, style="F")
    if art.label:
        pdf.set_text_color(0, 0, 0)
        pdf.set_font("helvetica", size=_label_font_mm(art) * 72 / 25.4)
        text = art.label.encode("latin-1", "replace").decode("latin-1")
        pdf.set_xy(0, _label_baseline_mm(art) - _label_font_mm(art))
        pdf.cell(w, _label_font_mm(art), text, align="C")
    return bytes(pdf.output())


def to_png_image(art: Artwork, pixels_per_metre: float = 5000.0) -> NDArray[Any]:
    """Return the artwork as a BGR uint8 image at `pixels_per_metre` (default 5 px/mm).

    Drawn at 4x and reduced by area averaging, so edges are anti-aliased and sit where the
    vector artwork puts them (pixel centres at (i + 0.5) / pixels_per_metre metres from the
    page's top-left corner).
    """
    if not (np.isfinite(pixels_per_metre) and pixels_per_metre > 0):
        raise InvalidInput(f"pixels_per_metre must be positive, got {pixels_per_metre}")
    ss = 4
    ppmm = pixels_per_metre / 1000.0
    W = round(art.page_mm[0] * ppmm)
    H = round(art.page_mm[1] * ppmm)
    if W * H > 64e6:
        raise InvalidInput(f"a {W} x {H} px PNG is too large; lower pixels_per_metre")
    scale = ppmm * ss
    img = np.full((H * ss, W * ss, 3), 255, np.uint8)
    shift = 4
    one = 1 << shift

    def pt(x: float, y: float) -> tuple[int, int]:
        return round(x * scale * one), round(y * scale * one)

    cx, cy = art.centre_mm
    blue = BLUE_RGB[::-1]
    red = RED_RGB[::-1]
    if art.kind == "object":
        for half, colour in ((art.layout.frame_outer, blue), (art.layout.frame_inner, (255,) * 3)):
            o = half * 1000
            poly = np.array(
                [pt(cx - o, cy - o), pt(cx + o, cy - o), pt(cx + o, cy + o), pt(cx - o, cy + o)]
            )
            cv2.fillPoly(img, [poly], colour, cv2.LINE_8, shift)
    else:
        for k, r in enumerate(art.layout.ring_radii):
            c = red if k % 2 == 0 else (255, 255, 255)
            cv2.circle(img, pt(cx, cy), round(r * 1000 * scale * one), c, -1, cv2.LINE_8, shift)
    for x, y, rw, rh in art.module_runs():
        poly = np.array([pt(x, y), pt(x + rw, y), pt(x + rw, y + rh), pt(x, y + rh)])
        cv2.fillPoly(img, [poly], (0, 0, 0), cv2.LINE_8, shift)
    if art.label:
        font = cv2.FONT_HERSHEY_SIMPLEX
        height = _label_font_mm(art) * scale
        fs = cv2.getFontScaleFromHeight(font, max(1, round(height * 0.75)), 2)
        thick = max(1, round(height / 12))
        (tw, _), _ = cv2.getTextSize(art.label, font, fs, thick)
        org = (round(cx * scale - tw / 2), round(_label_baseline_mm(art) * scale))
        cv2.putText(img, art.label, org, font, fs, (0, 0, 0), thick, cv2.LINE_AA)
    return cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)


def to_png(art: Artwork, pixels_per_metre: float = 5000.0) -> bytes:
    """Return the artwork as PNG bytes at `pixels_per_metre` (with its resolution recorded in
    the file's pHYs chunk, so it prints at true size)."""
    ok, buf = cv2.imencode(".png", to_png_image(art, pixels_per_metre))
    if not ok:
        raise InvalidInput("the PNG could not be encoded")
    data = bytes(buf)
    return _with_phys(data, pixels_per_metre)


def _with_phys(png: bytes, pixels_per_metre: float) -> bytes:
    ppm = round(pixels_per_metre)
    payload = struct.pack(">IIB", ppm, ppm, 1)
    chunk = struct.pack(">I", len(payload)) + b"pHYs" + payload
    chunk += struct.pack(">I", zlib.crc32(b"pHYs" + payload) & 0xFFFFFFFF)
    # The pHYs chunk goes right after IHDR (8-byte signature + 25-byte IHDR chunk).
    return png[:33] + chunk + png[33:]
