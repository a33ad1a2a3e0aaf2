"""Nothing in the ephemeris, apparent-direction or time path touches the network."""

import socket

import numpy as np
import pytest


class NetworkUsed(AssertionError):
    pass


@pytest.fixture
def no_network(monkeypatch):
    def refuse(*args, **kwargs):
        raise NetworkUsed(f"network access attempted: {args[1:] or kwargs}")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket.socket, "connect_ex", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    monkeypatch.setattr(socket, "getaddrinfo", refuse)


def test_guard_really_blocks(no_network):
    """The guard itself works (otherwise the test below could not fail)."""
    with pytest.raises(NetworkUsed):
        socket.create_connection(("example.org", 80), timeout=1)
    with pytest.raises(NetworkUsed):
        socket.socket().connect(("127.0.0.1", 9))


def test_ephemeris_apparent_and_time_conversion_offline(no_network):
    from astropy.time import Time
    from astropy.utils import iers

    from skynav.scenes import timescales
    from skynav.scenes.apparent import apparent_body
    from skynav.scenes.ephemeris_jpl import Ephemeris

    # UTC -> TDB needs leap seconds (bundled) and TDB-TT (analytic); no IERS download
    t = Time("2024-05-15T12:00:00", scale="utc")
    t_tdb_s = timescales.tdb_seconds(t)
    assert iers.conf.auto_download is False  # set by the first conversion (timescales loads astropy then)
    # 2024: TT - UTC = 69.184 s; |TDB - TT| < 2 ms (Fairhead & Bretagnon 1990)
    expected = (Time("2024-05-15T12:00:00", scale="tt").jd - 2451545.0) * 86400.0 + 69.184
    assert abs(t_tdb_s - expected) < 2e-3

    eph = Ephemeris()  # fresh instance: the kernel is opened under the guard
    r, v = eph.position_velocity("earth", t_tdb_s)
    d = apparent_body(eph, "mars", r + 1e6, v, t_tdb_s)
    assert np.isclose(np.linalg.norm(d.u_apparent), 1.0)
    assert 0 < d.light_time_s < 1500.0
