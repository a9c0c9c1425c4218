"""`models.mujoco.ContactMerge`: one contact per wheel and terrain face on a height field.

Oracles: MuJoCo's own step (the two-half step with the constraints rebuilt is bit for bit
`mj_step`), and a sphere on a MuJoCo plane geom (one contact, the reference stiffness).
"""

import math

import mujoco
import numpy as np
import pytest

from models.errors import ModelError
from models.mujoco import ContactMerge

RADIUS = 0.35  # [m], the reference machine's wheel sphere
MASS = 3000.0  # [kg], about a wheel's share of the machine
N = 21  # grid points per side
HALF = 2.5  # [m] half extent: spacing 0.25 m, as the scenario terrains
_GROUND = ('priority="1" solref="0.01 1" solimp="0.9 0.95 0.001 0.5 2" '
           'friction="0.9 0.005 0.0001"')


def _scene(heights: np.ndarray | None, pos, on_rails: bool = False):
    """A sphere over a height field (``heights`` [m], N x N, rows along y) or a plane; free,
    or ``on_rails`` (sliding in x and z, rolling about y)."""
    if heights is None:
        ground = f'<geom name="ground" type="plane" size="{HALF} {HALF} 0.1" {_GROUND}/>'
        asset = ""
        top = 1.0
    else:
        top = max(float(np.ptp(heights)), 1e-3)
        base = float(heights.min())
        asset = (f'<asset><hfield name="h" nrow="{N}" ncol="{N}" '
                 f'size="{HALF} {HALF} {top} 0.5"/></asset>')
        ground = f'<geom name="ground" type="hfield" hfield="h" pos="0 0 {base}" {_GROUND}/>'
    joints = ('<joint type="slide" axis="1 0 0"/><joint type="slide" axis="0 0 1"/>'
              '<joint type="hinge" axis="0 1 0"/>') if on_rails else "<freejoint/>"
    xml = f"""
<mujoco>
  <option timestep="0.002" integrator="implicitfast" cone="elliptic" tolerance="1e-10"/>
  {asset}
  <worldbody>
    {ground}
    <body name="wheel" pos="{pos[0]} {pos[1]} {pos[2]}">
      {joints}
      <geom name="tyre" type="sphere" size="{RADIUS}" mass="{MASS}"/>
    </body>
  </worldbody>
</mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    if heights is not None:
        model.hfield_data[:] = ((heights - base) / top).ravel()
    return model, mujoco.MjData(model), model.geom("tyre").id


def _settle(model, data, step, seconds: float = 1.0) -> list[int]:
    """Steps for ``seconds``; returns the number of force-carrying contacts at each step."""
    counts = []
    for _ in range(int(round(seconds / model.opt.timestep))):
        step(data)
        counts.append(int(sum(1 for i in range(data.ncon) if data.contact.efc_address[i] >= 0)))
    return counts


def _normal_force(model, data) -> float:
    f, total = np.zeros(6), 0.0
    for i in range(data.ncon):
        if data.contact.efc_address[i] >= 0:
            mujoco.mj_contactForce(model, data, i, f)
            total += f[0]
    return total


def _grid():
    x = np.linspace(-HALF, HALF, N)
    return np.meshgrid(x, x)  # X[row, col], Y[row, col]: rows along y


def test_the_two_half_step_with_rebuilt_constraints_is_mujocos_step():
    rng = np.random.default_rng(3)
    heights = 0.05 * rng.standard_normal((N, N))
    model, d1, tyre = _scene(heights, (0.1, 0.2, heights.max() + RADIUS + 0.02))
    d2 = mujoco.MjData(model)
    merge = ContactMerge(model, [tyre])
    for _ in range(300):
        mujoco.mj_step(model, d1)
        mujoco.mj_step1(model, d2)
        merge._rebuild(d2)  # the constraint stage again, nothing excluded
        mujoco.mj_step2(model, d2)
    assert d1.ncon > 0
    np.testing.assert_array_equal(d1.qpos, d2.qpos)
    np.testing.assert_array_equal(d1.qvel, d2.qvel)


@pytest.mark.parametrize("where", ["vertex", "ridge"])
def test_a_sphere_on_a_height_field_rests_like_on_a_plane(where):
    """On a flat patch (at a grid vertex six triangles meet) and on a ridge between two faces
    MuJoCo reports several coincident contacts; merged there is one, and the sphere sinks in
    as far as on a level MuJoCo plane (on the ridge it rests on the crest)."""
    X, Y = _grid()
    slope = math.radians(4.0) if where == "ridge" else 0.0
    heights = -math.tan(slope) * np.abs(Y)  # a roof along x for the ridge, flat otherwise
    centre = (0.0, 0.0, 1.0 + RADIUS + 0.01)
    runs = {}
    for merged in (False, True):
        model, data, tyre = _scene(heights + 1.0, centre)
        merge = ContactMerge(model, [tyre])
        step = merge.step if merged else (lambda d, m=model: mujoco.mj_step(m, d))
        counts = _settle(model, data, step)
        runs[merged] = (counts[-1], data.qpos[2], _normal_force(model, data))
    plane, pdata, _ = _scene(None, (0.0, 0.0, RADIUS + 0.01))
    _settle(plane, pdata, lambda d: mujoco.mj_step(plane, d))
    sink_plane = RADIUS - pdata.qpos[2]
    assert runs[False][0] >= 2  # the duplicates this class is for
    count, z, force = runs[True]
    assert count == 1
    # on the ridge the sphere touches the edge: the sphere's sink is measured along z
    assert RADIUS - (z - 1.0) == pytest.approx(sink_plane, rel=0.05)
    assert force == pytest.approx(MASS * 9.81, rel=0.02)
    sink_unmerged = RADIUS - (runs[False][1] - 1.0)
    assert sink_unmerged < 0.8 * sink_plane  # stiffer with the duplicates


def test_a_loaded_sphere_rolling_along_a_ridge_carries_its_weight_at_every_step():
    """The failure seen in the scenarios: on a ridge the number of coincident contacts changes
    as the wheel rolls over the triangles' edges, and its force jumps from step to step (to
    0 N and 40 kN at 1 m/s here); merged it carries its weight at every step. The wheel runs
    on rails along the ridge (as a wheel on its axle)."""
    X, Y = _grid()
    heights = 1.0 - math.tan(math.radians(6.0)) * np.abs(Y)
    weight = MASS * 9.81
    spread = {}
    for merged in (False, True):
        model, data, tyre = _scene(heights, (-1.5, 0.0, 1.0 + RADIUS + 0.002), on_rails=True)
        data.qvel[0] = 1.0  # rolling along the ridge (x)
        data.qvel[2] = 1.0 / RADIUS
        merge = ContactMerge(model, [tyre])
        step = merge.step if merged else (lambda d, m=model: mujoco.mj_step(m, d))
        _settle(model, data, step, 0.2)
        force = []
        for _ in range(1000):
            step(data)
            force.append(_normal_force(model, data))
        spread[merged] = (min(force) / weight, max(force) / weight)
    assert spread[False][1] - spread[False][0] > 0.2  # what the merging is for
    assert 0.98 < spread[True][0] <= spread[True][1] < 1.02


def test_a_sphere_in_a_valley_keeps_a_contact_on_each_flank():
    X, Y = _grid()
    heights = 1.0 + math.tan(math.radians(20.0)) * np.abs(Y)
    model, data, tyre = _scene(heights, (0.0, 0.0, 1.0 + RADIUS / math.cos(math.radians(20))))
    merge = ContactMerge(model, [tyre])
    counts = _settle(model, data, merge.step)
    assert counts[-1] == 2
    normals = [data.contact.frame[i, :3] for i in range(data.ncon)
               if data.contact.efc_address[i] >= 0]
    tilt = sorted(math.degrees(math.atan2(n[1], n[2])) for n in normals)
    np.testing.assert_allclose(tilt, [-20.0, 20.0], atol=0.5)
    assert _normal_force(model, data) * math.cos(math.radians(20)) == pytest.approx(
        MASS * 9.81, rel=0.02)


@pytest.mark.parametrize("kwargs, match", [
    ({"angle": -0.1}, "angle"), ({"angle": 2.0}, "angle"), ({"distance": math.nan}, "distance"),
    ({"wheel_geoms": [7]}, "wheel_geoms"), ({"wheel_geoms": []}, "wheel_geoms")])
def test_bad_arguments_raise_model_errors(kwargs, match):
    model, _, tyre = _scene(None, (0.0, 0.0, 1.0))
    args = {"wheel_geoms": [tyre], **kwargs}
    with pytest.raises(ModelError, match=match):
        ContactMerge(model, **args)


def test_the_compiled_merge_excludes_what_the_numpy_rule_does():
    """The machine driving on rough ground, every step merged both ways: the same contacts.

    Oracle: `ContactMerge.merge_reference` (numpy) on a copy of each step's collision.
    """
    from models import build_reference_machine
    from models import terrain as T
    from scenarios.simulator import Simulator

    sim = Simulator(build_reference_machine(), T.rough(5, max_slope_deg=20))
    merge = sim._contact_merge
    if not merge.compiled:
        pytest.skip("no C compiler: the numpy rule runs")
    sim.reset()
    m, d = sim.model, sim.data
    rng = np.random.default_rng(0)
    check = mujoco.MjData(m)
    excluded = 0
    for k in range(60):
        sim.set_command(rng.uniform(-0.05, 0.05, 6), rng.uniform(-0.2, 0.2, 3),
                        rng.uniform(-1, 2, 2))
        sim.step(10)
        mujoco.mj_copyData(check, m, d)
        mujoco.mj_step1(m, d)
        mujoco.mj_step1(m, check)
        assert merge.merge(d) == merge.merge_reference(check)
        np.testing.assert_array_equal(d.contact.exclude[:d.ncon], check.contact.exclude[:d.ncon])
        np.testing.assert_array_equal(d.contact.efc_address[:d.ncon],
                                      check.contact.efc_address[:d.ncon])
        excluded += int(d.contact.exclude[:d.ncon].sum())
    assert excluded > 0  # the ground made coincident contacts to merge
