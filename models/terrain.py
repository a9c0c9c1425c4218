"""Terrains: height maps ``z = h(x, y)`` shared by the MuJoCo scenes, placement code and tests.

A `Terrain` is a regular grid of heights over a rectangle of the world x-y plane, read the way
MuJoCo reads a height field: each grid cell, between columns ``j, j+1`` and rows ``i, i+1``, is
split into two triangles along the diagonal from ``(x_j, y_i)`` to ``(x_{j+1}, y_{i+1})``, and
the surface is linear on each triangle. `Terrain.height` and `Terrain.normal` evaluate exactly
that surface, so they agree with what MuJoCo collides against and ray-casts (up to its float32
storage of the heights; the tests check both). A terrain of constant height is built as a
MuJoCo plane.

Grid convention: ``heights[i, j]`` is the height at ``x_j = x_min + j dx``, ``y_i = y_min + i dy``
(row ``i`` along y, column ``j`` along x, row 0 at ``y_min``: the order of MuJoCo's
``hfield_data``). World frame: z up, gravity along -z; the machine starts at the origin heading
+x, and every terrain is defined far enough to drive 35 m in +x from there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from models.errors import TerrainError
from models.terrain_checks import (
    MAX_COORDINATE,
    MAX_NODES,
    MAX_SMOOTHING_WORK,
    MIN_SPACING,
    check_angle,
    check_finite,
    check_interval,
    check_points,
    check_positive,
    check_scalars,
)

__all__ = ["DEFAULT_X_RANGE", "DEFAULT_Y_RANGE", "Terrain", "flat", "ramp", "rough", "side_slope"]

DEFAULT_X_RANGE = (-10.0, 45.0)  # [m] 35 m drive in +x from the origin plus crane reach
DEFAULT_Y_RANGE = (-10.0, 10.0)  # [m] room for skid-steer drift and side slopes
_INSIDE_TOL = 1e-9  # [m] queries this far outside the grid are still accepted


@dataclass(frozen=True, eq=False)
class Terrain:
    """A height map, piecewise linear on MuJoCo's height-field triangles.

    Attributes:
        name: Short name, used for MuJoCo asset names and scene file names.
        heights: Heights [m], shape (n_y, n_x), n_y, n_x >= 2; ``heights[i, j]`` is at
            ``(x_j, y_i)`` (see the module docstring). Stored read-only.
        x_range: (x_min, x_max) covered by the grid [m].
        y_range: (y_min, y_max) covered by the grid [m].
        friction: Coulomb sliding friction coefficient of the ground [-].
    """

    name: str
    heights: np.ndarray
    x_range: tuple[float, float] = DEFAULT_X_RANGE
    y_range: tuple[float, float] = DEFAULT_Y_RANGE
    friction: float = 0.9

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.isidentifier():
            raise TerrainError(f"terrain name must be an identifier string, got {self.name!r}")
        try:
            if np.iscomplexobj(self.heights):
                raise TypeError("complex heights")
            heights = np.array(self.heights, dtype=float)
        except (TypeError, ValueError) as exc:
            raise TerrainError("terrain heights must be a 2-D array of numbers [m]") from exc
        if heights.ndim != 2 or min(heights.shape) < 2:
            raise TerrainError(f"terrain heights must have shape (n_y, n_x) with n_y, n_x >= 2, "
                               f"got {heights.shape}")
        if not np.all(np.isfinite(heights)):
            raise TerrainError("terrain heights contain NaN or inf")
        if np.abs(heights).max() > MAX_COORDINATE:
            raise TerrainError(f"terrain heights must lie in [-{MAX_COORDINATE:g}, "
                               f"{MAX_COORDINATE:g}] m, got up to {np.abs(heights).max():g}")
        heights.setflags(write=False)
        object.__setattr__(self, "heights", heights)
        object.__setattr__(self, "x_range", check_interval("x_range", self.x_range))
        object.__setattr__(self, "y_range", check_interval("y_range", self.y_range))
        object.__setattr__(self, "friction", check_positive("friction", self.friction))
        dx, dy = self.spacing
        if min(dx, dy) < MIN_SPACING:
            raise TerrainError(f"terrain grid spacing ({dx:g}, {dy:g}) m below the minimum "
                               f"{MIN_SPACING:g} m (ranges {self.x_range}, {self.y_range} m "
                               f"over {heights.shape[1]} x {heights.shape[0]} nodes)")

    # ------------------------------------------------------------------ geometry
    @property
    def shape(self) -> tuple[int, int]:
        """Grid shape (n_y, n_x)."""
        return self.heights.shape

    @property
    def spacing(self) -> tuple[float, float]:
        """Grid spacing (dx, dy) [m]."""
        n_y, n_x = self.heights.shape
        return ((self.x_range[1] - self.x_range[0]) / (n_x - 1),
                (self.y_range[1] - self.y_range[0]) / (n_y - 1))

    @property
    def center_xy(self) -> tuple[float, float]:
        """Centre of the grid rectangle in the world x-y plane [m]."""
        (x0, x1), (y0, y1) = self.x_range, self.y_range
        return 0.5 * (x0 + x1), 0.5 * (y0 + y1)

    @property
    def half_extent(self) -> tuple[float, float]:
        """Half sizes of the grid rectangle along x and y [m] (MuJoCo's hfield radius_x, _y)."""
        (x0, x1), (y0, y1) = self.x_range, self.y_range
        return 0.5 * (x1 - x0), 0.5 * (y1 - y0)

    @property
    def height_range(self) -> tuple[float, float]:
        """(lowest, highest) grid height [m]."""
        return float(self.heights.min()), float(self.heights.max())

    @property
    def is_flat(self) -> bool:
        """True when every height is the same: the terrain is a horizontal plane."""
        lo, hi = self.height_range
        return hi == lo

    def contains(self, x, y) -> np.ndarray | bool:
        """Whether world points (x, y) [m] lie on the grid (broadcast shapes)."""
        if np.ndim(x) == 0 and np.ndim(y) == 0:
            (x0, x1), (y0, y1) = self.x_range, self.y_range
            return bool(x0 - _INSIDE_TOL <= x <= x1 + _INSIDE_TOL
                        and y0 - _INSIDE_TOL <= y <= y1 + _INSIDE_TOL)
        x, y = np.asarray(x, float), np.asarray(y, float)
        inside = ((x >= self.x_range[0] - _INSIDE_TOL) & (x <= self.x_range[1] + _INSIDE_TOL)
                  & (y >= self.y_range[0] - _INSIDE_TOL) & (y <= self.y_range[1] + _INSIDE_TOL))
        return bool(inside) if inside.ndim == 0 else inside

    def _outside(self, x: float, y: float) -> TerrainError:
        return TerrainError(f"point ({x:.6g}, {y:.6g}) m outside terrain '{self.name}': "
                            f"x in [{self.x_range[0]:g}, {self.x_range[1]:g}] m, "
                            f"y in [{self.y_range[0]:g}, {self.y_range[1]:g}] m")

    def _triangle(self, x, y):
        """Height and gradient of the triangle under each point (broadcast shapes)."""
        xy = check_scalars(x, y)
        if xy is not None:
            z, gx, gy = self._triangle_at(*xy)
            return np.asarray(z), np.asarray(gx), np.asarray(gy)
        x, y = check_points(x, y)
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise TerrainError("terrain query points must be finite")
        inside = self.contains(x, y)
        if not np.all(inside):
            bad = ~np.asarray(inside)
            raise self._outside(float(x[bad].flat[0]), float(y[bad].flat[0]))
        dx, dy = self.spacing
        n_y, n_x = self.heights.shape
        fx = (x - self.x_range[0]) / dx
        fy = (y - self.y_range[0]) / dy
        j = np.clip(np.floor(fx).astype(int), 0, n_x - 2)
        i = np.clip(np.floor(fy).astype(int), 0, n_y - 2)
        u, v = fx - j, fy - i
        h = self.heights
        h00, h10, h01, h11 = h[i, j], h[i, j + 1], h[i + 1, j], h[i + 1, j + 1]
        # MuJoCo's split along (x_j, y_i)-(x_j+1, y_i+1): the triangle (00, 10, 11) below the
        # diagonal (u >= v), the triangle (00, 01, 11) above it.
        below = u >= v
        gx = np.where(below, h10 - h00, h11 - h01) / dx
        gy = np.where(below, h11 - h10, h01 - h00) / dy
        z = h00 + gx * dx * u + gy * dy * v
        return z, gx, gy

    def _triangle_at(self, x: float, y: float) -> tuple[float, float, float]:
        """`_triangle` for one point in plain Python (placement and contact code call it)."""
        if not (math.isfinite(x) and math.isfinite(y)):
            raise TerrainError("terrain query points must be finite")
        (x0, x1), (y0, y1) = self.x_range, self.y_range
        if not (x0 - _INSIDE_TOL <= x <= x1 + _INSIDE_TOL
                and y0 - _INSIDE_TOL <= y <= y1 + _INSIDE_TOL):
            raise self._outside(x, y)
        dx, dy = self.spacing
        n_y, n_x = self.heights.shape
        fx, fy = (x - x0) / dx, (y - y0) / dy
        j = min(max(int(math.floor(fx)), 0), n_x - 2)
        i = min(max(int(math.floor(fy)), 0), n_y - 2)
        u, v = fx - j, fy - i
        h = self.heights
        h00, h10, h01, h11 = (float(h[i, j]), float(h[i, j + 1]), float(h[i + 1, j]),
                              float(h[i + 1, j + 1]))
        if u >= v:
            gx, gy = (h10 - h00) / dx, (h11 - h10) / dy
        else:
            gx, gy = (h11 - h01) / dx, (h01 - h00) / dy
        return h00 + gx * dx * u + gy * dy * v, gx, gy

    def height(self, x, y) -> float | np.ndarray:
        """Terrain height h(x, y) [m] at world points (x, y) [m].

        Args:
            x: World x [m], scalar or array.
            y: World y [m], scalar or array (broadcast against ``x``).

        Returns:
            The height, a float for scalar input, else an array of the broadcast shape.

        Raises:
            TerrainError: A point is outside the grid or not finite.
        """
        xy = check_scalars(x, y)
        if xy is not None:
            return self._triangle_at(*xy)[0]
        z, _, _ = self._triangle(x, y)
        return z

    def gradient(self, x, y) -> np.ndarray:
        """Terrain gradient (dh/dx, dh/dy) [-] at world points, shape (..., 2).

        On a triangle edge the triangle that MuJoCo's split assigns the point to is used.
        """
        _, gx, gy = self._triangle(x, y)
        return np.stack([gx, gy], axis=-1)

    def normal(self, x, y) -> np.ndarray:
        """Upward unit terrain normal in world axes at world points, shape (..., 3).

        ``n = (-dh/dx, -dh/dy, 1) / |(-dh/dx, -dh/dy, 1)|``.
        """
        xy = check_scalars(x, y)
        if xy is not None:
            _, gx, gy = self._triangle_at(*xy)
            scale = 1.0 / math.sqrt(1.0 + gx * gx + gy * gy)
            return np.array([-gx * scale, -gy * scale, scale])
        _, gx, gy = self._triangle(x, y)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    @property
    def max_slope_deg(self) -> float:
        """Largest slope over all grid triangles [deg], from the grid's finite differences.

        Each triangle's slope is ``atan(|grad h|)`` with the gradient from forward differences
        along its two legs (the triangles MuJoCo collides against).
        """
        h = self.heights
        dx, dy = self.spacing
        below = np.hypot((h[:-1, 1:] - h[:-1, :-1]) / dx, (h[1:, 1:] - h[:-1, 1:]) / dy)
        above = np.hypot((h[1:, 1:] - h[1:, :-1]) / dx, (h[1:, :-1] - h[:-1, :-1]) / dy)
        return float(np.degrees(np.arctan(max(below.max(), above.max()))))


def _grid(x_range, y_range, spacing: float) -> tuple[np.ndarray, np.ndarray, tuple, tuple]:
    """Grid axes with about ``spacing`` between nodes that fit the ranges exactly."""
    x_range = check_interval("x_range", x_range)
    y_range = check_interval("y_range", y_range)
    spacing = check_positive("spacing", spacing)
    if spacing < MIN_SPACING:
        raise TerrainError(f"spacing {spacing:g} m below the minimum {MIN_SPACING:g} m")
    n_x = max(2, int(round((x_range[1] - x_range[0]) / spacing)) + 1)
    n_y = max(2, int(round((y_range[1] - y_range[0]) / spacing)) + 1)
    if n_x * n_y > MAX_NODES:
        raise TerrainError(f"spacing {spacing:g} m over x_range {x_range} m and y_range "
                           f"{y_range} m makes {n_x} x {n_y} grid nodes, more than "
                           f"{MAX_NODES:,}; use a coarser spacing or smaller ranges")
    return np.linspace(*x_range, n_x), np.linspace(*y_range, n_y), x_range, y_range


def flat(height: float = 0.0, x_range=DEFAULT_X_RANGE, y_range=DEFAULT_Y_RANGE,
         friction: float = 0.9) -> Terrain:
    """Horizontal ground at ``height`` [m] (built as a MuJoCo plane).

    Args:
        height: Ground height [m].
        x_range: Extent along world x [m].
        y_range: Extent along world y [m].
        friction: Sliding friction coefficient [-].
    """
    height = check_finite("height", height)
    return Terrain("flat", np.full((2, 2), height), x_range, y_range, friction)


def ramp(angle_deg: float, start_x: float = 4.0, transition_length: float = 2.0,
         spacing: float = 0.5, x_range=DEFAULT_X_RANGE, y_range=DEFAULT_Y_RANGE,
         friction: float = 0.9) -> Terrain:
    """Level ground that turns into a constant slope rising towards +x.

    ``h = 0`` for ``x <= start_x``; over ``transition_length`` the slope grows linearly (h is
    quadratic in x), then ``h`` rises at ``tan(angle)``. The maximum slope is ``angle_deg``.

    Args:
        angle_deg: Slope of the ramp [deg], in (-60, 60); negative goes downhill.
        start_x: Where the ramp begins [m]; the machine starts level at the origin.
        transition_length: Length of the rounded foot of the ramp [m], >= 0.
        spacing: Grid spacing [m].
        x_range: Extent along world x [m].
        y_range: Extent along world y [m].
        friction: Sliding friction coefficient [-].
    """
    angle_deg = check_angle("ramp angle", angle_deg)
    start_x = check_finite("start_x", start_x)
    transition_length = check_finite("transition_length", transition_length)
    if transition_length < 0:
        raise TerrainError(f"transition_length must be >= 0 m, got {transition_length}")
    xs, ys, x_range, y_range = _grid(x_range, y_range, spacing)
    slope = math.tan(math.radians(angle_deg))
    s = np.clip(xs - start_x, 0.0, None)
    if transition_length > 0:
        h = np.where(s < transition_length, 0.5 * slope * s * s / transition_length,
                     slope * (s - 0.5 * transition_length))
    else:
        h = slope * s
    return Terrain("ramp", np.tile(h, (ys.size, 1)), x_range, y_range, friction)


def side_slope(angle_deg: float, spacing: float = 1.0, x_range=DEFAULT_X_RANGE,
               y_range=DEFAULT_Y_RANGE, friction: float = 0.9) -> Terrain:
    """Plane through the origin tilted about the world x axis: ``h = y tan(angle)``.

    A positive angle raises the +y (left, for a machine heading +x) side.

    Args:
        angle_deg: Tilt [deg], in (-60, 60).
        spacing: Grid spacing [m] (the plane is exact at any spacing).
        x_range: Extent along world x [m].
        y_range: Extent along world y [m].
        friction: Sliding friction coefficient [-].
    """
    angle_deg = check_angle("side slope angle", angle_deg)
    xs, ys, x_range, y_range = _grid(x_range, y_range, spacing)
    h = np.outer(ys * math.tan(math.radians(angle_deg)), np.ones(xs.size))
    return Terrain("side_slope", h, x_range, y_range, friction)


def rough(seed: int, max_slope_deg: float = 26.7, feature_length: float = 1.0,
          spacing: float = 0.25, start_radius: float = 3.0, blend_length: float = 4.0,
          x_range=DEFAULT_X_RANGE, y_range=DEFAULT_Y_RANGE, friction: float = 0.9) -> Terrain:
    """Seeded smooth random terrain whose maximum slope is exactly ``max_slope_deg``.

    White noise on the grid is smoothed by a Gaussian kernel of standard deviation
    ``feature_length``, faded to level ground within ``start_radius`` of the origin (a smooth
    step over ``blend_length``) so the machine can be placed there, and scaled so that the
    largest finite-difference slope over the grid (`Terrain.max_slope_deg`) equals
    ``max_slope_deg``. The same seed gives the same terrain.

    Args:
        seed: Seed of the random generator (non-negative integer).
        max_slope_deg: Maximum slope [deg], in (0, 60). The paper's rough terrain has 26.7 deg.
        feature_length: Smoothing length [m]; bumps are a few times this long. Keep it well
            above the wheel radius and the spacing.
        spacing: Grid spacing [m].
        start_radius: Radius of the level start area around the origin [m].
        blend_length: Distance over which the level start area blends into the terrain [m].
        x_range: Extent along world x [m].
        y_range: Extent along world y [m].
        friction: Sliding friction coefficient [-].
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TerrainError(f"seed must be a non-negative integer, got {seed!r}")
    max_slope_deg = check_angle("max_slope_deg", max_slope_deg, allow_zero=False)
    feature_length = check_positive("feature_length", feature_length)
    start_radius = check_finite("start_radius", start_radius)
    blend_length = check_positive("blend_length", blend_length)
    if start_radius < 0:
        raise TerrainError(f"start_radius must be >= 0 m, got {start_radius}")
    xs, ys, x_range, y_range = _grid(x_range, y_range, spacing)
    dx, dy = xs[1] - xs[0], ys[1] - ys[0]
    if feature_length < 2 * max(dx, dy):
        raise TerrainError(f"feature_length {feature_length:g} m must be at least twice the grid "
                           f"spacing ({max(dx, dy):g} m) to be resolved")
    # The smoothing costs about 8 sigma operations per node and axis; bound it (a hang else).
    work = xs.size * ys.size * 8.0 * (feature_length / dx + feature_length / dy)
    if work > MAX_SMOOTHING_WORK:
        raise TerrainError(f"feature_length {feature_length:g} m is too long for a "
                           f"{xs.size} x {ys.size} grid of spacing {max(dx, dy):g} m (smoothing "
                           f"work {work:.3g} > {MAX_SMOOTHING_WORK:.0e}); use a shorter "
                           f"feature_length, a coarser spacing or smaller ranges")
    noise = np.random.default_rng(int(seed)).standard_normal((ys.size, xs.size))
    field = gaussian_filter(noise, sigma=(feature_length / dy, feature_length / dx),
                            mode="reflect")
    field -= field.mean()
    r = np.hypot(*np.meshgrid(xs, ys, indexing="xy"))
    t = np.clip((r - start_radius) / blend_length, 0.0, 1.0)
    heights = field * (t * t * (3.0 - 2.0 * t))  # smooth step: level at the start
    unscaled = Terrain("rough", heights, x_range, y_range, friction)
    grad_max = math.tan(math.radians(unscaled.max_slope_deg))
    if not grad_max > 0:
        raise TerrainError(f"start_radius {start_radius:g} m leaves no rough area in x_range "
                           f"{x_range} m and y_range {y_range} m")
    scale = math.tan(math.radians(max_slope_deg)) / grad_max
    return Terrain("rough", heights * scale, x_range, y_range, friction)
