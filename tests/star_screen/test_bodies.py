"""Bright bodies: Sun/Moon flags with margin, bodies not listed are never computed, Earth chain."""

import math

import numpy as np
import pytest

from sim import ephemeris
from sim.constants import MU_EARTH, R_EARTH
from sim.frames import dcm_itrs_gcrs, dcm_lvlh_gcrs
from sim.rotations import compose, dcm, quat_from_dcm, quat_from_euler
from star_screen.attitude import q_SN_from_radec_roll
from star_screen.bodies import BrightBodies, earth_point_in_camera_chain
from star_screen.catalog import unit_to_radec
from star_screen.geometry import TrackerOptics, default_bench
from star_screen.render import Renderer


def _point_at(u):
    ra, dec = unit_to_radec(u)
    return q_SN_from_radec_roll(math.degrees(ra), math.degrees(dec), 0.0)


def _off(u, deg_north):
    ra, dec = unit_to_radec(u)
    return q_SN_from_radec_roll(math.degrees(ra), math.degrees(dec) + deg_north, 0.0)


def test_sun_in_field_and_in_margin(epoch):
    bb = BrightBodies(TrackerOptics(), bodies=("sun",), margins_deg={"sun": 30.0})
    u = ephemeris.sun_position_gcrs(epoch)
    u = u / np.linalg.norm(u)
    f = bb.evaluate(_point_at(u), epoch)
    assert f["sun"]["in_field"] and f["any_in_field"]
    assert np.allclose(f["sun"]["detector_xy"], [512, 384], atol=0.5)
    assert math.isclose(f["sun"]["angular_radius_deg"], 0.2705, abs_tol=0.01)  # 2 January: perihelion
    # 7.5 deg field half-height + 30 deg margin + 0.27 deg: in at 35 deg off, out at 40
    assert bb.evaluate(_off(u, 35.0), epoch)["sun"]["in_field"]
    assert not bb.evaluate(_off(u, 40.0), epoch)["sun"]["in_field"]
    assert "moon" not in f


def test_moon_flag_in_render_truth(epoch):
    t = TrackerOptics()
    u = ephemeris.moon_position_gcrs(epoch)
    u = u / np.linalg.norm(u)
    r = Renderer(default_bench(), bright_bodies=BrightBodies(t, bodies=("moon",), margins_deg={"moon": 5.0}))
    f = r.render(_point_at(u), epoch)
    assert f.bodies["moon"]["in_field"]
    assert 0.0 <= f.bodies["moon"]["illuminated_fraction"] <= 1.0
    far = r.render(_off(u, 60.0), epoch)
    assert not far.bodies["moon"]["in_field"] and not far.bodies["any_in_field"]


def test_moon_never_computed_when_not_listed(epoch, monkeypatch):
    def boom(*a, **k):
        raise AssertionError("the Moon was computed although no device cares about it")

    monkeypatch.setattr(ephemeris, "moon_position_gcrs", boom)
    r = Renderer(default_bench(), bright_bodies=BrightBodies(TrackerOptics(), bodies=("sun",)))
    f = r.render(q_SN_from_radec_roll(10.0, 10.0, 0.0), epoch)
    assert "moon" not in f.bodies and "sun" in f.bodies
    r0 = Renderer(default_bench(), r.catalog)
    assert r0.render(q_SN_from_radec_roll(10.0, 10.0, 0.0), epoch).bodies == {}


def _orbit(epoch):
    a = R_EARTH + 500e3
    i = math.radians(97.4)
    v = math.sqrt(MU_EARTH / a)
    r = np.array([a, 0.0, 0.0])
    vv = np.array([0.0, v * math.cos(i), v * math.sin(i)])
    return r, vv


def test_earth_chain_equals_direct_transform(epoch):
    r_sc, v_sc = _orbit(epoch)
    q_BO = quat_from_euler(np.radians([10.0, -20.0, 35.0]), "321")
    q_SB = quat_from_euler(np.radians([0.0, 30.0, 5.0]), "123")
    q_ON = quat_from_dcm(dcm_lvlh_gcrs(r_sc, v_sc))
    q_SN = compose(q_SB, compose(q_BO, q_ON))
    rng = np.random.default_rng(2)
    for lat, lon in zip(rng.uniform(-80, 80, 5), rng.uniform(-180, 180, 5), strict=True):
        la, lo = math.radians(lat), math.radians(lon)
        p_itrs = R_EARTH * np.array([math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)])
        chain = earth_point_in_camera_chain(p_itrs, epoch, r_sc, v_sc, q_BO, q_SB)
        direct = dcm(q_SN) @ (dcm_itrs_gcrs(epoch).T @ p_itrs - r_sc)
        assert np.allclose(chain, direct, rtol=0, atol=1e-6)


def test_nadir_camera_sees_sub_satellite_point_and_earth_on_boresight(epoch):
    r_sc, v_sc = _orbit(epoch)
    sub_itrs = dcm_itrs_gcrs(epoch) @ (r_sc / np.linalg.norm(r_sc) * R_EARTH)
    ident = np.array([1.0, 0.0, 0.0, 0.0])
    d = earth_point_in_camera_chain(sub_itrs, epoch, r_sc, v_sc, ident, ident)
    assert np.allclose(d / np.linalg.norm(d), [0, 0, 1], atol=1e-12)
    q_SN = quat_from_dcm(dcm_lvlh_gcrs(r_sc, v_sc))
    bb = BrightBodies(TrackerOptics(), bodies=("earth",))
    f = bb.evaluate(q_SN, epoch, r_sc_gcrs_m=r_sc)["earth"]
    assert f["in_field"] and f["off_boresight_deg"] < 1e-9
    assert math.isclose(f["angular_radius_deg"], math.degrees(math.asin(R_EARTH / np.linalg.norm(r_sc))))
    with pytest.raises(ValueError, match="r_sc_gcrs_m"):
        bb.evaluate(q_SN, epoch)
