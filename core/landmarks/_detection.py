"""What the detector reports of one landmark: `LandmarkDetection`, made from its pose and its
symbol's read (the record decoded from the symbol's text, or the reason it is not there)."""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from core.landmarks._symbol import SymbolRead, why_unread
from core.landmarks._view import ImageView
from core.landmarks.ambiguity import PoseHypothesis, is_decided
from core.landmarks.payload import PayloadError, Record, decode_payload

Array = NDArray[np.float64]


@dataclass(frozen=True)
class LandmarkDetection:
    """One landmark found in an image.

    kind: "object" (blue frame) or "signpost" (red rings); outline (N, 2) distorted pixels: the
    frame's four outer corners, or 36 points of the outer ring's edge; T_cam_mark (4, 4): the
    mark frame (origin at the pattern's centre, z out of the face, x along the symbol's rows)
    in camera coordinates, metres; cov (6, 6): covariance of (rotation vector, translation) of
    T_cam_mark (radians, metres); record: the decoded payload or None; reason: why it was not
    decoded ("too small", "too oblique", "blurred", "damaged", "foreign payload"), None when
    decoded; text: the symbol's raw text when one was read; orientation_known: whether the
    rotation about the normal was fixed by the symbol (else its variance is that of a uniform
    angle); rms: edge fit RMS, pixels; hypotheses: for rings, both poses of their two-fold
    ambiguity (core.landmarks.ambiguity), best first, each with its covariance of (rvec, t)
    and its probability given the image (the rings' centre, the symbol, the mounting prior);
    () for frames. The first is T_cam_mark. When the image cannot decide (`decided` False),
    cov is the two poses' covering covariance (a good pose's confidence is never claimed);
    when it decides, cov is the chosen pose's own.
    """

    kind: str
    outline: Array
    T_cam_mark: Array
    cov: Array = field(repr=False)
    record: Record | None
    reason: str | None
    text: str | None = None
    orientation_known: bool = False
    rms: float = 0.0
    hypotheses: tuple[PoseHypothesis, ...] = field(default=(), repr=False)

    @property
    def position(self) -> Array:
        """Return the pattern centre (3,) in camera coordinates, metres."""
        return self.T_cam_mark[:3, 3]

    @property
    def normal(self) -> Array:
        """Return the unit normal (3,) out of the printed face, camera coordinates."""
        return self.T_cam_mark[:3, 2]

    @property
    def decided(self) -> bool:
        """Return whether the image decides the pose (one hypothesis, or the first at least
        core.landmarks.ambiguity.DECIDED_PROBABILITY)."""
        return is_decided(self.hypotheses)

    @property
    def probability(self) -> float:
        """Return the reported pose's probability given the image (1 for frames)."""
        return self.hypotheses[0].probability if self.hypotheses else 1.0


def make_detection(
    ctx: ImageView,
    kind: str,
    R: Array,
    t: Array,
    cov: Array,
    outline: Array,
    qr_side: float,
    read: SymbolRead | None,
    known: bool,
    rms: float,
    hypotheses: tuple[PoseHypothesis, ...],
) -> LandmarkDetection:
    """Return the detection of a mark of `kind` at pose (R, t) (cov of (rvec, t)) with its
    symbol's read: the record decoded from its text, or why there is none."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    record: Record | None = None
    reason: str | None = None
    text = read.text if read is not None else None
    if text is not None:
        try:
            record = _decode_record(text)
        except PayloadError as exc:
            reason = "foreign payload" if exc.reason in ("foreign", "version") else "damaged"
        if record is not None and record.kind != kind:
            # A valid payload in the other kind's pattern: not a landmark this map can use.
            record, reason = None, "foreign payload"
    else:
        reason = why_unread(ctx, R, t, qr_side) if ctx.decode else "not attempted"
    return LandmarkDetection(
        kind=kind,
        outline=outline,
        T_cam_mark=T,
        cov=cov,
        record=record,
        reason=reason,
        text=text,
        orientation_known=known,
        rms=rms,
        hypotheses=hypotheses,
    )


# A camera sees the same landmarks frame after frame: their texts' records (immutable) are kept.
_decode_record = functools.lru_cache(maxsize=256)(decode_payload)
