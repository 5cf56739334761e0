"""The landmark payload: round trips, and every corrupt or foreign text rejected by reason."""

from __future__ import annotations

import zlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core.errors import InvalidInput
from core.landmarks import ObjectMark, PayloadError, Signpost, decode_payload, encode_payload

texts = st.text(
    alphabet=st.characters(blacklist_categories=("Cs", "Cc", "Cf", "Zl", "Zp", "Co", "Cn")),
    min_size=1,
    max_size=20,
).filter(str.isprintable)
lengths = st.floats(-50, 50, allow_nan=False)
quats = st.tuples(*[st.floats(-1, 1, allow_nan=False)] * 4).filter(
    lambda q: sum(v * v for v in q) > 0.01
)
ids = st.integers(0, 999_999_999)

object_marks = st.builds(
    ObjectMark,
    id=ids,
    object_class=texts,
    name=texts,
    room=texts,
    size=st.tuples(*[st.floats(0, 5, allow_nan=False)] * 3),
    grasp=st.tuples(lengths, lengths, lengths).flatmap(lambda p: quats.map(lambda q: p + q)),
    hints=st.lists(texts, max_size=3).map(tuple),
)
signposts = st.builds(
    lambda i, n, r, p, q, nb: Signpost(i, n, r, p + q, tuple(x for x in nb if x != i)),
    ids,
    texts,
    texts,
    st.tuples(lengths, lengths, lengths),
    quats,
    st.lists(ids, max_size=4),
)


@settings(max_examples=200, deadline=None)
@given(st.one_of(object_marks, signposts))
def test_random_records_round_trip(record: ObjectMark | Signpost) -> None:
    text = encode_payload(record)
    assert decode_payload(text) == record
    assert decode_payload(text.encode()) == record


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_never_decode(data: bytes) -> None:
    with pytest.raises(PayloadError):
        decode_payload(data)


def _sample() -> str:
    return encode_payload(
        ObjectMark(7, "cup", "blue cup | 1,2", "kitchen", (0.08, 0.08, 0.1), hints=("fragile",))
    )


def test_separators_inside_text_fields_survive() -> None:
    assert decode_payload(_sample()).name == "blue cup | 1,2"  # type: ignore[union-attr]


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_any_single_character_change_is_caught(data: st.DataObject) -> None:
    text = _sample()
    i = data.draw(st.integers(0, len(text) - 1))
    c = data.draw(st.characters(min_codepoint=32, max_codepoint=126))
    changed = text[:i] + c + text[i + 1 :]
    if changed == text:
        return
    # CRC-32 detects every single-symbol error (all burst errors up to 32 bits).
    with pytest.raises(PayloadError):
        decode_payload(changed)


def test_reasons_name_the_problem() -> None:
    text = _sample()
    cases = {
        "foreign": "https://example.com/product/42",
        "version": text.replace("ISL1", "ISL2", 1),
        "truncated": text[:30],
        "checksum": text[:-1] + ("0" if text[-1] != "0" else "1"),
    }
    for reason, bad in cases.items():
        with pytest.raises(PayloadError) as err:
            decode_payload(bad)
        assert err.value.reason == reason, (reason, str(err.value))
    # A well-formed text with a valid checksum but a bad field is "malformed".
    body = "ISL1|S|3|door|hall|1,2,x,0,0,0,1|"
    with pytest.raises(PayloadError) as err:
        decode_payload(f"{body}|{zlib.crc32(body.encode()):08X}")
    assert err.value.reason in ("malformed", "truncated")
    body = "ISL1|S|3|door|hall|1,2,3,0,0,0,1|4,x"
    with pytest.raises(PayloadError) as err:
        decode_payload(f"{body}|{zlib.crc32(body.encode()):08X}")
    assert err.value.reason == "malformed"


def test_records_check_their_fields() -> None:
    with pytest.raises(InvalidInput):
        ObjectMark(-1, "cup", "cup", "kitchen")
    with pytest.raises(InvalidInput):
        ObjectMark(1, "", "cup", "kitchen")
    with pytest.raises(InvalidInput):
        Signpost(1, "door", "hall", (0, 0, 0, 0, 0, 0, 0))
    with pytest.raises(InvalidInput):
        Signpost(1, "door", "hall", neighbours=(1,))
    # Quaternions are normalised with w >= 0; lengths quantised to 0.1 mm.
    s = Signpost(1, "door", "hall", (1.23456, 0, 0, 0, 0, 0, -2))
    assert s.pose == (1.2346, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
