"""Ephemeris adapter: range errors, unknown bodies, pickling, batch vs scalar, velocity vs
central finite differences of position."""

import functools
import pickle

import numpy as np
import pytest

from skynav.infra.errors import SkynavError
from skynav.scenes.ephemeris_jpl import BODIES, BODY_NAIF_IDS, BODY_RADII_KM, Ephemeris, default_ephemeris
from skynav.scenes.errors import EphemerisRangeError, UnknownBodyError

YEAR_S = 365.25 * 86400.0


def test_tables_cover_bodies():
    assert set(BODY_RADII_KM) == set(BODIES) == set(BODY_NAIF_IDS)


def test_kernel_not_opened_by_constructor():
    eph = Ephemeris(path="/nonexistent/de421.bsp")  # would fail if opened here
    assert eph._kernel is None


def test_out_of_range_epochs_raise_with_mask_and_message():
    eph = Ephemeris()
    t = np.linspace(-10.0, 10.0, 100) * YEAR_S
    t[[3, 50, 97]] = [-120 * YEAR_S, 60 * YEAR_S, np.nan]  # 1880, 2060, NaN
    with pytest.raises(EphemerisRangeError) as info:
        eph.position_velocity("mars", t)
    err = info.value
    assert isinstance(err, ValueError) and isinstance(err, SkynavError)
    assert str(err) == "de421.bsp covers 1899-07-29..2053-10-09 TDB; 3 of 100 epochs outside (see .time_mask)"
    assert np.flatnonzero(err.time_mask).tolist() == [3, 50, 97]
    start, end = eph.span_tdb_s
    # DE421 span: JD 2414864.5 .. 2471184.5 (skyfield-data's de421.bsp)
    assert start == (2414864.5 - 2451545.0) * 86400.0 and end == (2471184.5 - 2451545.0) * 86400.0
    eph.position("sun", end)  # the end point itself is inside
    with pytest.raises(EphemerisRangeError):
        eph.position("sun", end + 1.0)


def test_unknown_body():
    with pytest.raises(UnknownBodyError) as info:
        Ephemeris().position("pluto", 0.0)
    assert isinstance(info.value, KeyError)
    assert "pluto" in str(info.value) and "neptune" in str(info.value)


def test_pickle_round_trip_reopens_lazily():
    eph = Ephemeris()
    before = eph.position("moon", 1.0e8)
    clone = pickle.loads(pickle.dumps(eph))
    assert clone._kernel is None
    np.testing.assert_array_equal(clone.position("moon", 1.0e8), before)
    assert clone == eph and hash(clone) == hash(eph) and eval(repr(eph)) == eph
    assert Ephemeris(path="/x/de430.bsp") != eph
    assert default_ephemeris() is default_ephemeris()


@pytest.mark.parametrize("body", BODIES)
def test_batch_equals_scalar_loop(body, rng):
    # one epoch goes through the fast path (one_epoch_state), an array of epochs through
    # jplephem: two implementations, so within 2 ulps (_assert_state_close)
    eph = default_ephemeris()
    t = rng.uniform(-50, 50, 7) * YEAR_S
    r, v = eph.position_velocity(body, t)
    assert r.shape == v.shape == (7, 3)
    for k, tk in enumerate(t):
        rk, vk = eph.position_velocity(body, tk)
        assert rk.shape == vk.shape == eph.position(body, tk).shape == (3,)
        _assert_state_close(rk, vk, r[k], v[k], (body, tk))


@functools.lru_cache(maxsize=2)
def _kernel(path):
    from jplephem.spk import SPK

    return SPK.open(path)


def _jplephem(eph, body, t, offset_s=0.0):
    """The reference, straight from jplephem (not through :class:`Ephemeris`): its
    ``Segment.compute_and_differentiate`` summed over the body's chain of segments, at the
    two-part Julian date of ``t + offset_s`` (TDB s past J2000), for one epoch; km, km/s."""
    from skynav.scenes.ephemeris_jpl import _CHAINS

    kernel = _kernel(eph.path)
    day = np.floor(t / 86400.0)
    jd1, jd2 = 2451545.0 + day, ((t - day * 86400.0) + offset_s) / 86400.0
    r, v = np.zeros(3), np.zeros(3)
    for pair in _CHAINS[body]:
        p, dv = kernel[pair].compute_and_differentiate(jd1, jd2)
        r, v = r + p, v + dv
    return r, v / 86400.0


def test_one_epoch_fast_path_repeats_jplephem():
    """One epoch at a time (the light-time iterations' reads) goes through the fast path
    (:func:`one_epoch_state`): it gives jplephem's evaluation, its reference, within 2 ulps
    (:func:`_assert_state_close`) for every body, at random epochs across DE421, with two-part
    offsets, at interval boundaries and at the kernel's ends, and its position equals its own
    position-and-velocity's (the same code); past the kernel's end it leaves the error to the
    reference."""
    eph = Ephemeris()
    lo, hi = eph.span_tdb_s
    rng = np.random.default_rng(13)
    epochs = np.concatenate([rng.uniform(lo + 1.0, hi - 1.0, 40), [0.0, 86400.0 * 32, -86400.0 * 16.5, lo, hi]])
    for t in epochs.tolist():
        for off in (0.0, -1234.5678, 1e-7):
            if not lo <= t + off <= hi:
                continue
            for b in BODIES:
                r, v = eph.position_velocity(b, t, offset_s=off)
                assert np.array_equal(eph.position(b, t, offset_s=off), r)  # same code
                _assert_state_close(r, v, *_jplephem(eph, b, t, off), (b, t, off))
    assert len(eph._intervals) > 0  # the fast path answered (it keeps the intervals it read)
    with pytest.raises(EphemerisRangeError):
        eph.position_velocity("moon", hi + 1.0)


@pytest.mark.parametrize("body", BODIES)
def test_velocity_matches_central_difference(body, rng):
    eph = default_ephemeris()
    t = rng.uniform(-50, 50, 5) * YEAR_S
    h = 60.0  # s; O(h^2 a') truncation: Moon |da/dt| ~ 2e-11 km/s^3 -> ~1e-8 km/s
    _, v = eph.position_velocity(body, t)
    fd = (eph.position(body, t, offset_s=h) - eph.position(body, t, offset_s=-h)) / (2 * h)
    # 1e-7 km/s = 0.1 mm/s: covers truncation and the ~1e-9 km rounding of 1e9 km positions / 120 s
    np.testing.assert_allclose(fd, v, rtol=0, atol=1e-7)


def test_offset_is_exact_two_part_time():
    eph = default_ephemeris()
    t = 1.5e9  # float resolution here is 2.4e-7 s: t + 1e-7 rounds to t or t + 2.4e-7
    r1 = eph.position("moon", t, offset_s=1e-7)
    r0 = eph.position("moon", t)
    _, v = eph.position_velocity("moon", t)
    # a 0.1 us offset must move the Moon by v * 1e-7 s (~3e-6 km), not by 0 or v * 2.4e-7 s;
    # 6e-8 km = two ulps of a 1.5e8 km coordinate
    assert np.all(np.abs((r1 - r0) - v * 1e-7) <= 6e-8)


@pytest.mark.parametrize("body", BODIES)
def test_position_equals_position_velocity_bit_for_bit(body, rng):
    """Exact: the same code (jplephem's one ``Segment.generate``, stopped after the position)."""
    eph = default_ephemeris()
    t = rng.uniform(-50, 50, 5) * YEAR_S
    np.testing.assert_array_equal(eph.position(body, t), eph.position_velocity(body, t)[0])
    np.testing.assert_array_equal(eph.position(body, t[0], offset_s=-123.4), eph.position_velocity(body, t[0], offset_s=-123.4)[0])


def _assert_state_close(got_r, got_v, r, v, what):
    """Two implementations of one Chebyshev sum (ours against jplephem's): within 2 ulps of
    each vector's largest coordinate (60 um on a 1 au position, 2e-15 km/s on 30 km/s; a wrong
    interval or coefficient is off by kilometres). They use the same IEEE operations in the
    same order, so they agree exactly today (measured), but that is not the contract."""
    assert np.all(np.abs(got_r - r) <= 2 * np.spacing(np.abs(r).max())), (what, got_r, r)
    assert np.all(np.abs(got_v - v) <= 2 * np.spacing(np.abs(v).max())), (what, got_v, v)


def test_states_at_and_epoch_states_are_position_velocity():
    """Several bodies at one epoch are each body's :meth:`position_velocity` at that epoch
    (exact: the same code), in the order asked, for all bodies and for a subset."""
    from skynav.scenes.ephemeris_jpl import BODIES, default_ephemeris

    eph = default_ephemeris()
    lo, hi = eph.span_tdb_s
    epochs = np.concatenate([np.random.default_rng(11).uniform(lo + 1.0, hi - 1.0, 10), [0.0, 86400.0 * 32]])
    for bodies in (BODIES, ("moon", "sun", "saturn", "mercury")):
        for t in epochs:
            got, st = eph.states_at(t, bodies), eph.epoch_states(t, bodies)
            assert list(got) == list(bodies) and st.positions.shape == st.velocities.shape == (len(bodies), 3)
            for j, b in enumerate(bodies):
                r, v = eph.position_velocity(b, float(t))
                assert np.array_equal(got[b][0], r) and np.array_equal(got[b][1], v)
                assert np.array_equal(st.position(b), r) and np.array_equal(st.positions[j], r)
                assert np.array_equal(st.velocity(b), v) and np.array_equal(st.velocities[j], v)


def test_states_at_refuses_epochs_outside_the_kernel_and_unknown_bodies():
    import pytest

    from skynav.scenes.ephemeris_jpl import default_ephemeris
    from skynav.scenes.errors import EphemerisRangeError, UnknownBodyError

    eph = default_ephemeris()
    with pytest.raises(EphemerisRangeError):
        eph.states_at(eph.span_tdb_s[1] + 86400.0 * 400)
    with pytest.raises(UnknownBodyError):
        eph.states_at(0.0, ("pluto",))


def test_positions_at_is_position():
    """Several bodies at several epochs are each body's :meth:`position` at those epochs (exact:
    the same code), in the order asked, for all bodies and a subset; an epoch outside the
    kernel is refused as position() refuses it."""
    eph = Ephemeris()
    lo, hi = eph.span_tdb_s
    t = np.concatenate([np.random.default_rng(14).uniform(lo + 1.0, hi - 1.0, 30), [0.0, 86400.0 * 32, lo, hi]])
    for bodies in (BODIES, ("moon", "sun", "saturn", "earth")):
        got = eph.positions_at(t, bodies)
        assert got.shape == (t.size, len(bodies), 3)
        for j, b in enumerate(bodies):
            assert np.array_equal(got[:, j], eph.position(b, t)), b
    with pytest.raises(EphemerisRangeError) as info:
        eph.positions_at(np.array([0.0, hi + 86400.0]), ("mars",))
    assert info.value.time_mask.tolist() == [False, True]
    with pytest.raises(UnknownBodyError):
        eph.positions_at(np.array([0.0]), ("pluto",))
