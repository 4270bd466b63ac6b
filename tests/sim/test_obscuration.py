"""Shadow tests on a plate: exact ray/body intersections and closed-form shadow geometry."""

import numpy as np
import pytest

from sim.obscuration import (
    Box,
    Frustum,
    HalfSpace,
    Occluder,
    Panel,
    SunDisk,
    mark_points,
    project_to_plate,
    straight_edge_hidden_fraction,
    visible_fraction,
)
from sim.rotations import dcm, quat_from_euler

FIXED = (np.zeros(3), np.eye(3))


def _inside_frustum(f, x):
    w = x - f.base_m
    z = w @ f.axis
    perp = np.linalg.norm(w - z[..., None] * f.axis, axis=-1)
    r = f.base_radius_m + (f.top_radius_m - f.base_radius_m) * z / f.length_m
    return (z >= 0) & (z <= f.length_m) & (perp <= r)


def _inside_box(b, x):
    return np.all(np.abs((x - b.center_m) @ b.dcm_XV.T) <= b.half_size_m, axis=-1)


def _first_inside(inside, p, d, lam):
    m = inside(p + lam[:, None] * d)
    return lam[m][0] if m.any() else np.inf


SHAPES = [
    (Frustum([0.2, -0.1, 0.3], [0.3, 0.2, 1.0], 2.0, 1.0, 0.3), _inside_frustum),
    (Frustum([0, 0, 0], [0, 0, 1], 2.0, 0.0, 1.0), _inside_frustum),  # cone, apex at the base
    (Frustum([0, 0, 0], [1, 0, 0], 2.0, 0.7, 0.7), _inside_frustum),  # cylinder
    (Box([0.1, 0.2, 0.3], [1.0, 0.5, 0.3], dcm(quat_from_euler([0.3, -0.2, 0.7], "321"))), _inside_box),
]


@pytest.mark.parametrize("shape, inside", SHAPES)
def test_entry_distance_matches_dense_marching(shape, inside):
    """The closed-form entry equals the first inside point of a 0.1 mm march along the ray."""
    rng = np.random.default_rng(7)
    P = rng.normal(size=(80, 3)) * 3.0
    aim = rng.normal(size=(80, 3)) * 0.6 + shape.bounding_sphere()[0]
    D = aim - P
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    E = shape.entry(P, D)
    lam = np.arange(1e-7, 12.0, 1e-4)
    ref = np.array([_first_inside(lambda x: inside(shape, x), p, d, lam) for p, d in zip(P, D, strict=True)])
    assert np.sum(np.isfinite(ref)) > 30  # the rays do test hits
    np.testing.assert_array_equal(np.isinf(E), np.isinf(ref))
    hit = np.isfinite(ref)
    assert np.all(np.abs(E[hit] - ref[hit]) <= 1e-4)


def test_panel_entry_matches_plane_crossing():
    pan = Panel([0, 0, 1], [2, 0, 0], [0, 1, 0.5])
    p = np.array([[0.5, 0.5, 0.0], [3.0, 0.5, 0.0], [0.5, 0.5, 3.0]])
    d = np.array([[0, 0, 1.0], [0, 0, 1.0], [0, 0, 1.0]])
    e = pan.entry(p, d)
    assert e[0] == pytest.approx(1.25)  # z of the panel at y = 0.5 is 1 + 0.25
    assert np.isinf(e[1]) and np.isinf(e[2])  # off the panel; panel behind the ray


def test_panel_above_plate_shadows_the_predicted_marks():
    """A 1 x 0.6 m panel 1.5 m above the plate, Sun 35 deg from the normal toward +x (azimuth 20 deg):
    the shadow is the panel shifted by -1.5 tan(35 deg) along the Sun's azimuth."""
    H, th, az = 1.5, np.radians(35.0), np.radians(20.0)
    s = np.array([[np.sin(th) * np.cos(az), np.sin(th) * np.sin(az), np.cos(th)]])
    panel = Occluder("panel", "chaser", Panel([-0.5, -0.3, H], [1.0, 0.0, 0.0], [0.0, 0.6, 0.0]))
    xs, ys = np.meshgrid(np.linspace(-2.5, 1.0, 36), np.linspace(-1.6, 1.0, 27))
    centres = np.stack((xs.ravel(), ys.ravel()), axis=-1)
    pts, w = mark_points(centres, 0.004, rings=0)
    lit = visible_fraction(pts.reshape(-1, 3), s, [panel], [FIXED], SunDisk(0.0))[0]
    shift = H * np.tan(th) * np.array([np.cos(az), np.sin(az)])
    q = centres + shift  # where the sunlight through each mark meets the panel's height
    predicted = (q[:, 0] >= -0.5) & (q[:, 0] <= 0.5) & (q[:, 1] >= -0.3) & (q[:, 1] <= 0.3)
    assert 20 < predicted.sum() < len(centres) - 20
    np.testing.assert_array_equal(lit == 0.0, predicted)
    np.testing.assert_array_equal(lit == 1.0, ~predicted)


def test_cone_shadow_edges_are_the_tangent_lines_from_the_apex_shadow():
    """A cone standing on the plate (base radius R, height H): its shadow is the base disk plus the
    triangle to the apex's shadow A; its edges are the tangents from A to the base circle."""
    R, H, th = 0.3, 1.0, np.radians(40.0)
    s = np.array([[np.sin(th), 0.0, np.cos(th)]])
    cone = Occluder("cone", "target", Frustum([0, 0, 0], [0, 0, 1], H, R, 0.0))
    A = project_to_plate(np.array([0.0, 0.0, H]), s[0])[:2]
    dist = np.linalg.norm(A)
    assert dist > R
    phi = np.arccos(R / dist)  # tangent points at angle +-phi from the direction to A
    dirA = A / dist
    pts, inside = [], []
    for sign in (1.0, -1.0):
        rot = np.array([[np.cos(phi), -sign * np.sin(phi)], [sign * np.sin(phi), np.cos(phi)]])
        T = R * rot @ dirA
        along = (A - T) / np.linalg.norm(A - T)
        out = np.array([along[1], -along[0]])
        if out @ T < 0:
            out = -out  # normal pointing away from the shadow
        for f in (0.1, 0.3, 0.5, 0.7, 0.9):
            on = T + f * (A - T)
            for delta, is_in in ((1e-6, False), (-1e-6, True)):
                pts.append(np.append(on + delta * out, 0.0))
                inside.append(is_in)
    lit = visible_fraction(np.array(pts), s, [cone], [FIXED], SunDisk(0.0))[0]
    np.testing.assert_array_equal(lit == 0.0, np.array(inside))
    # Beyond the apex's shadow the plate is lit; just short of it, along the axis, it is dark.
    tip = visible_fraction(np.array([[*(A * (1 + 1e-6)), 0.0], [*(A * (1 - 1e-4)), 0.0]]), s, [cone], [FIXED],
                           SunDisk(0.0))[0]
    assert tip.tolist() == [1.0, 0.0]


@pytest.mark.parametrize("rings, frac_tol", [(2, 0.07), (4, 0.03), (6, 0.016), (10, 0.0095)])
@pytest.mark.parametrize("th_deg", [0.0, 25.0])
def test_umbra_and_penumbra_widths_and_profile_match_geometry(rings, frac_tol, th_deg):
    """A long strip of width W at height H under a Sun of angular radius a (exaggerated to 0.05 rad):
    umbra from x0 - H tan(th - a) to x0 + W - H tan(th + a), penumbra out to x0 - H tan(th + a) and
    x0 + W - H tan(th - a); inside the penumbra the hidden fraction follows the circular segments cut
    by the two edges' great circles."""
    H, W, x0, a = 2.0, 1.0, -0.5, 0.05
    th = np.radians(th_deg)
    s = np.array([[np.sin(th), 0.0, np.cos(th)]])
    strip = Occluder("strip", "chaser", Panel([x0, -500.0, H], [W, 0, 0], [0, 1000.0, 0]))
    dx = 2.5e-4
    x = np.arange(-3.0, 2.0, dx)
    pts = np.stack((x, 0 * x, 0 * x), axis=-1)
    hidden = 1.0 - visible_fraction(pts, s, [strip], [FIXED], SunDisk(a, rings))[0]
    t = np.tan
    umbra = x[hidden >= 1.0 - 1e-12]
    pen = x[hidden > 0.0]
    limb = H * (t(th + a) - t(th + a * np.cos(np.pi / (6 * rings)))) + dx
    assert umbra.min() == pytest.approx(x0 - H * t(th - a), abs=limb)
    assert umbra.max() == pytest.approx(x0 + W - H * t(th + a), abs=limb)
    assert pen.min() == pytest.approx(x0 - H * t(th + a), abs=limb)
    assert pen.max() == pytest.approx(x0 + W - H * t(th - a), abs=limb)
    # Umbra and penumbra widths as such.
    assert umbra.max() - umbra.min() == pytest.approx(W - H * (t(th + a) - t(th - a)), abs=2 * limb)
    assert umbra.min() - pen.min() == pytest.approx(H * (t(th + a) - t(th - a)), abs=2 * limb)

    def offset(edge_x):  # signed angle of the Sun's centre from the plane through the point and the edge
        n = np.cross(np.array([edge_x, 0.0, H]) - pts, [0.0, 1.0, 0.0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return np.arcsin(n @ s[0])

    exact = straight_edge_hidden_fraction(offset(x0), a) - straight_edge_hidden_fraction(offset(x0 + W), a)
    assert np.max(np.abs(hidden - np.abs(exact))) < frac_tol


def test_plate_horizon_hides_the_segment_of_the_sun_below_it():
    a = 0.01
    plate = Occluder("plate", "target", HalfSpace([0, 0, 0], [0, 0, 1]))
    elev = np.array([-0.02, -0.005, 0.0, 0.004, 0.02])
    s = np.stack((np.cos(elev), 0 * elev, np.sin(elev)), axis=-1)
    lit = visible_fraction(np.zeros((1, 3)), s, [plate], [FIXED], SunDisk(a, 10))[:, 0]
    exact = 1.0 - straight_edge_hidden_fraction(elev, a)
    assert lit[0] == 0.0 and lit[-1] == 1.0
    np.testing.assert_allclose(lit, exact, atol=0.01)


def test_moving_occluder_poses_per_time():
    """A panel carried by a vehicle moving along +x: it shadows the origin only while over it."""
    pan = Occluder("p", "chaser", Panel([-0.5, -0.5, 0.0], [1, 0, 0], [0, 1, 0]))
    x = np.linspace(-3, 3, 13)
    r_VP_P = np.stack((x, 0 * x, np.full_like(x, 2.0)), axis=-1)
    dcm_VP = np.broadcast_to(np.eye(3), (13, 3, 3))
    s = np.broadcast_to([0.0, 0.0, 1.0], (13, 3))
    lit = visible_fraction(np.zeros((1, 3)), s, [pan], [(r_VP_P, dcm_VP)], SunDisk(0.0))[:, 0]
    np.testing.assert_array_equal(lit == 0.0, np.abs(x) <= 0.5)


def test_culling_never_changes_the_answer():
    """The bounding-sphere skip is conservative: same result as evaluating every time."""
    rng = np.random.default_rng(3)
    occ = [Occluder("c", "t", Frustum([0, 0, 0.1], [0.2, 0.1, 1], 0.8, 0.3, 0.1)),
           Occluder("b", "t", Box([0.4, 0.3, 0.5], [0.1, 0.2, 0.3]))]
    s = rng.normal(size=(200, 3))
    s[:, 2] = np.abs(s[:, 2]) + 0.2
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    pts = np.concatenate((rng.uniform(-0.8, 0.8, size=(60, 2)), np.zeros((60, 1))), axis=1)
    disk = SunDisk(0.02, 3)
    got = visible_fraction(pts, s, occ, [FIXED, FIXED], disk)
    dirs, w = disk.directions(s)
    blocked = np.zeros((200, len(w), 60), dtype=bool)
    for o in occ:
        blocked |= np.isfinite(o.shape.entry(pts[None, None], dirs[:, :, None, :]))
    np.testing.assert_allclose(got, 1.0 - np.einsum("tkm,k->tm", blocked, w), atol=1e-12)
    assert 0.0 < got.mean() < 1.0


def test_disk_and_mark_quadratures():
    rho, phi, w = SunDisk(0.004, 5).offsets()
    assert len(w) == 1 + 3 * 5 * 6 and w.sum() == pytest.approx(1.0)
    assert rho.max() == pytest.approx(0.004)  # the last ring is on the limb
    # Second moment of a uniform disk, a^2 / 2 (the quadrature is 2.0 % high at 5 rings).
    assert np.sum(w * rho ** 2) == pytest.approx(0.004 ** 2 / 2, rel=0.025)
    dirs, _ = SunDisk(0.004, 5).directions(np.array([[0.0, 0.6, 0.8]]))
    ang = np.arccos(np.clip(dirs[0] @ [0.0, 0.6, 0.8], -1, 1))
    np.testing.assert_allclose(ang, rho, atol=1e-9)
    pts, wm = mark_points([[0.1, 0.2], [0.3, -0.1]], 0.05, rings=3)
    assert pts.shape == (2, 37, 3) and wm.sum() == pytest.approx(1.0)
    assert np.max(np.linalg.norm(pts[1, :, :2] - [0.3, -0.1], axis=1)) == pytest.approx(0.05)


@pytest.mark.parametrize("make, message", [
    (lambda: Frustum([0, 0, 0], [0, 0, 0], 1.0, 0.1, 0.1), "axis"),
    (lambda: Frustum([0, 0, 0], [0, 0, 1], -1.0, 0.1, 0.1), "length_m"),
    (lambda: Panel([0, 0, 0], [1, 0, 0], [2, 0, 0]), "not parallel"),
    (lambda: Box([0, 0, 0], [1, 0, 1]), "half_size_m"),
    (lambda: SunDisk(0.2), "angular_radius_rad"),
])
def test_bad_shapes_are_refused_with_their_field(make, message):
    with pytest.raises(ValueError, match=message):
        make()
