"""The tracker's appearance cue: two people who meet face to face and walk back the way they
came keep their identities when their detections carry descriptors of their looks, and a
person whose look changes is still followed by position."""

from __future__ import annotations

import numpy as np
from localization_scene import ROOM, make_cameras

from core.localization.appearance import APPEARANCE_SIZE
from core.localization.tracking import Tracker, TrackerConfig, TrackState

RATE = 7.0  # frames a second, a CCTV camera's
SIGMA = 5.0  # px: a detector's box foot on a small, far person
SEEDS = range(100, 120)


def _look(bins, rng, spread=0.3):
    """Return a noisy descriptor: most of its mass in `bins`, `spread` of it anywhere (the
    background and the pixel noise in a box)."""
    v = np.zeros(APPEARANCE_SIZE)
    v[list(bins)] = 1.0 / len(bins)
    v = (1.0 - spread) * v + spread * rng.dirichlet(np.ones(APPEARANCE_SIZE))
    return v / v.sum()


def _meet_and_return(rng):
    """Times (K,) and floor positions (K, 2) of two people who walk towards each other at
    0.9 m/s, stop 0.2 m apart (0.25 m to the side) for 1.5 s and walk back: a constant-velocity
    prediction carries each through the other's place."""
    t = np.arange(0.0, 10.0, 1.0 / RATE) + rng.uniform(0.0, 1.0 / RATE)
    centre = np.array(ROOM) / 2
    walked = 0.9 * (np.clip(t, 0.0, 3.0) - np.clip(t - 4.5, 0.0, None))

    def side(sign, lateral):
        return np.column_stack(
            [centre[0] + sign * (2.9 - walked - 0.1), np.full(t.size, centre[1] + lateral)]
        )

    return t, side(-1.0, 0.0), side(1.0, 0.25)


def _swapped(seed, config, looks=True):
    """Return whether a track of the two people ever followed the other person (nearer them by
    more than 0.3 m); one camera, detections in random order."""
    rng = np.random.default_rng(seed)
    cam = make_cameras(1)
    trk = Tracker(cam, config)
    t, a, b = _meet_and_return(rng)
    owner: dict[int, int] = {}
    for k in range(t.size):
        X = np.column_stack([np.stack([a[k], b[k]]), np.zeros(2)])
        px = cam[0].project(X) + rng.normal(0.0, SIGMA, (2, 2))
        order = rng.permutation(2)
        desc = np.stack([_look((3, 40), rng), _look((12, 50), rng)])
        r = trk.update(
            0,
            t[k],
            px[order],
            pixel_sigma=SIGMA,
            heights=0.0,
            kinds="person",
            appearances=desc[order] if looks else None,
        )
        for snap in r.updated:
            if snap.state is TrackState.TENTATIVE:
                continue
            d = np.linalg.norm(snap.xy - np.stack([a[k], b[k]]), axis=1)
            own = owner.setdefault(snap.id, int(np.argmin(d)))
            if d[1 - own] + 0.3 < d[own]:
                return True
    return False


def test_people_who_meet_and_turn_back_keep_their_identities():
    with_looks = [_swapped(s, TrackerConfig()) for s in SEEDS]
    by_position = [_swapped(s, TrackerConfig(), looks=False) for s in SEEDS]
    assert not any(with_looks), [s for s, w in zip(SEEDS, with_looks, strict=True) if w]
    # Position alone cannot tell them apart where they turn: the case needs the cue (the
    # tracker swaps about half of these meetings without it).
    assert sum(by_position) >= 3, by_position
    # A weight of 0 turns the cue off in association (recognition after a loss stays).
    off = [_swapped(s, TrackerConfig(appearance_weight=0.0)) for s in SEEDS]
    assert off == by_position


def test_a_person_whose_look_changes_is_followed_by_position():
    """One person walks across the room; half way their look changes completely (a coat taken
    off, the light of another room): one track throughout."""
    rng = np.random.default_rng(7)
    cam = make_cameras(1)
    trk = Tracker(cam)
    t = np.arange(0.0, 8.0, 1.0 / RATE)
    xy = np.column_stack([1.0 + 0.8 * t, np.full(t.size, ROOM[1] / 2)])
    ids = set()
    for k in range(t.size):
        px = cam[0].project(np.array([[*xy[k], 0.0]])) + rng.normal(0.0, SIGMA, (1, 2))
        desc = _look((3, 40) if t[k] < 4.0 else (20, 60), rng)[None]
        r = trk.update(0, t[k], px, pixel_sigma=SIGMA, heights=0.0, appearances=desc)
        ids |= {s.id for s in r.updated if s.state is not TrackState.TENTATIVE}
    assert len(ids) == 1 and len(trk) == 1


def _walk_behind_a_pillar(seed, first_look, second_look, looks=True):
    """Return the confirmed track ids of a walker crossing the room at 0.9 m/s, unseen for
    3 s in the middle (behind a pillar), in their look `first_look` before and `second_look`
    after."""
    rng = np.random.default_rng(seed)
    cam = make_cameras(1)
    trk = Tracker(cam)
    t = np.arange(0.0, 9.0, 1.0 / RATE)
    xy = np.column_stack([0.8 + 0.9 * t, np.full(t.size, ROOM[1] / 2)])
    ids = []
    for k in range(t.size):
        hidden = 3.0 <= t[k] < 6.0
        if hidden:
            trk.update(0, t[k], np.zeros((0, 2)))
            continue
        px = cam[0].project(np.array([[*xy[k], 0.0]])) + rng.normal(0.0, SIGMA, (1, 2))
        desc = _look(first_look if t[k] < 3.0 else second_look, rng)[None]
        r = trk.update(
            0, t[k], px, pixel_sigma=SIGMA, heights=0.0, appearances=desc if looks else None
        )
        ids += [s.id for s in r.updated if s.state is not TrackState.TENTATIVE]
    return list(dict.fromkeys(ids))


def test_a_person_lost_behind_a_pillar_is_recognised_by_their_look():
    # Out of sight for 3 s the track grows vaguer than max_position_std (2 m): by position it
    # ends, and the person comes back as a new target.
    assert len(_walk_behind_a_pillar(1, (3, 40), (3, 40), looks=False)) == 2
    for seed in range(3):
        # The same clothes on the other side of the pillar: the same target.
        assert len(_walk_behind_a_pillar(seed, (3, 40), (3, 40))) == 1, seed
        # Someone else comes out (other clothes): a new target.
        assert len(_walk_behind_a_pillar(seed, (3, 40), (20, 60))) == 2, seed
