"""Terrains: slopes as specified, start area, and agreement with what MuJoCo collides against."""

import math
import struct

import mujoco
import numpy as np
import pytest

from models import terrain as T
from models.errors import TerrainError


def _hfield_model(terrain: T.Terrain) -> mujoco.MjModel:
    """The terrain alone as a MuJoCo height field (independent of models.mujoco)."""
    lo, hi = terrain.height_range
    data = ((terrain.heights - lo) / (hi - lo)).astype("<f4")
    n_y, n_x = terrain.shape
    blob = struct.pack("<ii", n_y, n_x) + data.tobytes()
    (cx, cy), (hx, hy) = terrain.center_xy, terrain.half_extent
    xml = f"""<mujoco><asset><hfield name="t" file="t.bin" size="{hx} {hy} {hi - lo} 1"/></asset>
      <worldbody><geom type="hfield" hfield="t" pos="{cx} {cy} {lo}"/>
      <body><freejoint/><geom type="sphere" size="0.02"/></body></worldbody></mujoco>"""
    return mujoco.MjModel.from_xml_string(xml, {"t.bin": blob})


def _random_points(terrain: T.Terrain, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(*terrain.x_range, n), rng.uniform(*terrain.y_range, n)])


def _triangle_interior_points(terrain: T.Terrain, n: int, margin: float,
                              seed: int = 0) -> np.ndarray:
    """Points at least ``margin`` [cell fraction] from every edge of the grid triangles."""
    rng = np.random.default_rng(seed)
    (dx, dy), (n_y, n_x) = terrain.spacing, terrain.shape
    u, v = rng.uniform(margin, 1 - margin, (2, 4 * n))
    keep = np.abs(u - v) > margin * np.sqrt(2)
    u, v = u[keep][:n], v[keep][:n]
    j, i = rng.integers(0, n_x - 1, u.size), rng.integers(0, n_y - 1, u.size)
    return np.column_stack([terrain.x_range[0] + (j + u) * dx,
                            terrain.y_range[0] + (i + v) * dy])


@pytest.mark.parametrize("seed, slope", [(0, 26.7), (1, 26.7), (2, 15.0), (3, 40.0)])
def test_rough_max_slope_equals_parameter(seed, slope):
    terrain = T.rough(seed, max_slope_deg=slope)
    assert abs(terrain.max_slope_deg - slope) < 1e-9
    # Independent finite differences over every grid triangle.
    h, (dx, dy) = terrain.heights, terrain.spacing
    gx = np.concatenate([np.diff(h, axis=1)[:-1], np.diff(h, axis=1)[1:]]) / dx
    gy = np.concatenate([np.diff(h, axis=0)[:, 1:], np.diff(h, axis=0)[:, :-1]]) / dy
    assert abs(np.degrees(np.arctan(np.hypot(gx, gy).max())) - slope) < 1e-9


def test_rough_is_seeded():
    a, b, c = T.rough(5), T.rough(5), T.rough(6)
    np.testing.assert_array_equal(a.heights, b.heights)
    assert np.abs(a.heights - c.heights).max() > 0.05


def test_rough_start_area_is_level_and_terrain_is_rough_elsewhere():
    terrain = T.rough(0, start_radius=3.0)
    # A grid cell reaching beyond the level disc blends in: stay one cell diagonal inside.
    x, y = np.meshgrid(np.linspace(-2.6, 2.6, 30), np.linspace(-2.6, 2.6, 30))
    inside = np.hypot(x, y) < 3.0 - np.hypot(*terrain.spacing)
    assert np.abs(terrain.height(x[inside], y[inside])).max() < 1e-12
    assert np.ptp(terrain.heights) > 0.3  # bumps of tens of centimetres


@pytest.mark.parametrize("make", [T.flat, lambda: T.rough(0), lambda: T.ramp(20.0),
                                  lambda: T.side_slope(15.0)])
def test_extent_allows_a_35_m_drive(make):
    terrain = make()
    wheel_reach = 1.15 + 0.35 + 1.0  # half wheelbase, wheel radius, margin [m]
    assert terrain.contains(35.0 + wheel_reach, 0.0) and terrain.contains(-wheel_reach, 0.0)
    assert terrain.contains(35.0, 5.0) and terrain.contains(35.0, -5.0)


def test_ramp_profile_and_slope():
    terrain = T.ramp(20.0, start_x=4.0, transition_length=2.0)
    slope = math.tan(math.radians(20.0))
    assert terrain.height(3.0, 1.0) == 0.0
    assert terrain.height(20.0, -3.0) == pytest.approx(slope * (20.0 - 5.0), abs=1e-9)
    np.testing.assert_allclose(terrain.normal(20.0, 0.0),
                               [-math.sin(math.radians(20.0)), 0.0, math.cos(math.radians(20.0))],
                               atol=1e-12)
    assert terrain.max_slope_deg == pytest.approx(20.0, abs=1e-9)


def test_side_slope_is_a_plane_tilted_about_x():
    terrain = T.side_slope(15.0)
    pts = _random_points(terrain, 200)
    np.testing.assert_allclose(terrain.height(pts[:, 0], pts[:, 1]),
                               pts[:, 1] * math.tan(math.radians(15.0)), atol=1e-12)
    np.testing.assert_allclose(terrain.normal(pts[:, 0], pts[:, 1]),
                               np.tile([0.0, -math.sin(math.radians(15.0)),
                                        math.cos(math.radians(15.0))], (200, 1)), atol=1e-12)
    assert terrain.max_slope_deg == pytest.approx(15.0, abs=1e-9)


def test_flat_terrain():
    terrain = T.flat(0.25)
    assert terrain.is_flat and terrain.max_slope_deg == 0.0
    assert terrain.height(3.0, -2.0) == 0.25
    np.testing.assert_array_equal(terrain.normal(3.0, -2.0), [0.0, 0.0, 1.0])


def test_normal_matches_finite_differences_of_height():
    terrain = T.rough(4)
    pts = _triangle_interior_points(terrain, 300, margin=0.01)
    eps = 1e-6
    n = terrain.normal(pts[:, 0], pts[:, 1])
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    # Inside one triangle the height is linear: central differences give its gradient.
    gx = (terrain.height(pts[:, 0] + eps, pts[:, 1]) - terrain.height(pts[:, 0] - eps,
                                                                      pts[:, 1])) / (2 * eps)
    gy = (terrain.height(pts[:, 0], pts[:, 1] + eps) - terrain.height(pts[:, 0],
                                                                      pts[:, 1] - eps)) / (2 * eps)
    expected = np.column_stack([-gx, -gy, np.ones_like(gx)])
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(n, expected, atol=1e-6)


@pytest.mark.parametrize("make", [lambda: T.rough(3), lambda: T.ramp(25.0)])
def test_height_matches_mujoco_ray_casts(make):
    terrain = make()
    model = _hfield_model(terrain)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geom = np.zeros(1, np.int32)
    top = terrain.height_range[1] + 10.0
    pts = _random_points(terrain, 500)
    hit = np.array([top - mujoco.mj_ray(model, data, np.array([x, y, top]),
                                        np.array([0.0, 0.0, -1.0]),
                                        np.array([1, 0, 0, 0, 0, 0], np.uint8), 1, -1, geom)
                    for x, y in pts])
    np.testing.assert_allclose(hit, terrain.height(pts[:, 0], pts[:, 1]), atol=1e-6)


def test_height_and_normal_match_mujoco_collisions():
    terrain = T.rough(3)
    model = _hfield_model(terrain)
    data = mujoco.MjData(model)
    radius = model.geom_size[1, 0]
    checked = 0
    for x, y in _triangle_interior_points(terrain, 300, margin=0.2):
        data.qpos[:3] = [x, y, terrain.height(x, y) + radius - 0.005]  # 5 mm into the ground
        data.qpos[3:7] = [1.0, 0.0, 0.0, 0.0]
        mujoco.mj_forward(model, data)
        if data.ncon != 1:  # on a steep triangle the sphere may still touch a neighbour
            continue
        contact = data.contact[0]
        normal = contact.frame[:3]  # from the height field (geom 0) to the sphere
        surface = data.qpos[:3] - (radius + contact.dist) * normal
        assert surface[2] == pytest.approx(terrain.height(surface[0], surface[1]), abs=1e-6)
        np.testing.assert_allclose(normal, terrain.normal(surface[0], surface[1]), atol=1e-5)
        checked += 1
    assert checked > 250


@pytest.mark.parametrize("call", [
    lambda: T.rough(-1),
    lambda: T.rough(1.5),
    lambda: T.rough(True),
    lambda: T.rough(0, max_slope_deg=0.0),
    lambda: T.rough(0, max_slope_deg=75.0),
    lambda: T.rough(0, max_slope_deg=float("nan")),
    lambda: T.rough(0, feature_length=0.1),
    lambda: T.rough(0, spacing=-0.25),
    lambda: T.ramp(61.0),
    lambda: T.ramp(10.0, transition_length=-1.0),
    lambda: T.side_slope("steep"),
    lambda: T.flat(x_range=(5.0, -5.0)),
    lambda: T.Terrain("bad", np.zeros(5)),
    lambda: T.Terrain("bad", np.full((3, 3), np.inf)),
    lambda: T.Terrain("bad name", np.zeros((3, 3))),
    lambda: T.Terrain("bad", np.zeros((3, 3)), friction=0.0),
    lambda: T.flat().height(100.0, 0.0),
    lambda: T.rough(0).normal(0.0, float("nan")),
])
def test_bad_input_raises_terrain_error(call):
    with pytest.raises(TerrainError):
        call()


def test_out_of_range_message_names_the_valid_extent():
    with pytest.raises(TerrainError, match=r"x in \[-10, 45\] m"):
        T.rough(0).height(50.0, 0.0)


@pytest.mark.parametrize("make", [
    lambda: T.ramp(10.0, spacing=1e-5),  # billions of grid nodes
    lambda: T.Terrain("t", np.array([[0.0, 1e300], [0.0, 0.0]])),  # slopes overflow
    lambda: T.Terrain("t", np.zeros((2, 2)), x_range=(0.0, 1e-9)),  # spacing too small
    lambda: T.flat().height("a", 0.0),
    lambda: T.flat().normal([[0.0, 1.0], [2.0]], 0.0),
])
def test_extreme_terrains_and_queries_are_refused(make):
    with pytest.raises(TerrainError):
        make()
