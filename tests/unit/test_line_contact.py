"""controller_node.line_contact without a controller: a sole resting on a round rung that is
not where the plan put it under the sole, located from synthetic ankle F/T readings (the foot's
own weight in them, sensor noise), and the controller's contact moved there."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from controller_node.line_contact import GRAVITY, LineContactLocator
from controller_node.params import load_controller_params

FOOT_MASS = 0.6  # [kg]
FOOT_COM = np.array([0.03, 0.0, -0.02])  # [m] sensor frame
# the planned line: 2 points 6 cm apart across the sole, 4 cm ahead of and 3.5 cm below the sensor
POINTS = np.array([[0.04, -0.03, -0.035], [0.04, 0.03, -0.035]])


def model_with_a_foot() -> tuple[pin.Model, int]:
    model = pin.Model()
    jid = model.addJoint(0, pin.JointModelRY(), pin.SE3.Identity(), "ankle")
    model.appendBodyToJoint(jid, pin.Inertia(FOOT_MASS, FOOT_COM, np.eye(3) * 1e-3), pin.SE3.Identity())
    fid = model.addFrame(pin.Frame("foot", jid, 0, pin.SE3.Identity(), pin.FrameType.BODY))
    return model, fid


def reading(R: np.ndarray, line_x: float, normal_force: float, tangential: float, rng, sigma_f=0.0, sigma_m=0.0):
    """The sensor's wrench (sensor frame) of the rung pushing on a line at ``line_x`` (sensor
    frame x) with the given force (world up + world x), plus the foot's weight."""
    force_world = np.array([tangential, 0.0, normal_force])
    F = R.T @ force_world
    g = FOOT_MASS * (R.T @ GRAVITY)
    r = np.array([line_x, 0.0, POINTS[0, 2]])
    wrench = np.concatenate([F + g, np.cross(r, F) + np.cross(FOOT_COM, g)])
    return wrench + np.concatenate([rng.normal(0, sigma_f, 3), rng.normal(0, sigma_m, 3)])


@pytest.mark.parametrize("shift", [0.02, -0.03, 0.0])
@pytest.mark.parametrize("pitch", [0.0, -0.15])
def test_the_line_is_found_where_the_rung_pushes(shift, pitch):
    params = load_controller_params().line_contact
    model, fid = model_with_a_foot()
    R = pin.utils.rotate("y", pitch)
    oMf = {fid: pin.SE3(R, np.array([0.5, 0.12, 0.5]))}
    locator = LineContactLocator(model, {"left_foot": ("ankle", fid)}, params)
    assert locator.start("left_foot", fid, POINTS, np.array([0.0, 0.0, 1.0]), oMf)
    rng = np.random.default_rng(1)
    # the engage ramp: readings below locate_force do not count
    t = 0.0
    for force in (2.0, 8.0, 15.0):
        t += 0.005
        assert locator.update(t, oMf, {"ankle": reading(R, 0.04 + shift, force, 0.0, rng)}) == []
    estimates = []
    for force in np.linspace(40.0, 120.0, 10):  # 50 ms of the engage ramp
        t += 0.005
        # 0.5 % of the ankle's 1 kN / 50 N m ranges as noise, a tangential push of 10 % of the load
        estimates += locator.update(t, oMf, {"ankle": reading(R, 0.04 + shift, force, 0.1 * force, rng, 5.0, 0.25)})
    if shift == 0.0:
        assert estimates == []  # within min_shift of the plan: the contact stays as it is
        return
    estimate = estimates[0]
    assert estimate.samples >= params.samples
    assert sum(e.shift for e in estimates) == pytest.approx(estimates[-1].total)
    assert estimates[-1].total == pytest.approx(shift, abs=0.004) and estimate.total == estimate.shift
    # the shift is along the sole's forward axis, across the line (the limb frame is the sensor's)
    assert estimate.shift_in_frame == pytest.approx([estimate.shift, 0.0, 0.0], abs=1e-9)
    assert estimate.normal_world == pytest.approx([0.0, 0.0, 1.0])  # the sole's normal, as planned
    # tracking goes on: more readings of the same line move nothing
    for _ in range(40):
        t += 0.005
        assert locator.update(t, oMf, {"ankle": reading(R, 0.04 + shift, 100.0, 0.0, rng, 5.0, 0.25)}) == []
    assert locator.pending == ("left_foot",)  # followed while the contact lasts (track_s 0)
    locator.cancel("left_foot")  # its release
    assert locator.pending == ()


@pytest.mark.parametrize("noise_percent", [0.5, 2.0])
def test_noise_and_bias_do_not_move_a_line_that_is_where_planned(noise_percent):
    """A foot where the plan put it, 0.5 s of readings with F/T noise of sigma noise_percent of
    the ankle's 1 kN / 50 N m ranges and a bias of half that: the fit is only acted on when it is
    significant, and the bias measured while the foot was in the air is taken out. (Acting on
    every window of three readings walked the line 2 cm off in 0.5 s at 0.5 %, measured in a
    climb.)"""
    params = load_controller_params().line_contact
    model, fid = model_with_a_foot()
    R = pin.utils.rotate("y", -0.05)
    oMf = {fid: pin.SE3(R, np.zeros(3))}
    locator = LineContactLocator(model, {"left_foot": ("ankle", fid)}, params)
    rng = np.random.default_rng(3)
    sigma_f, sigma_m = 10.0 * noise_percent, 0.5 * noise_percent
    bias = np.concatenate([rng.normal(0, 0.5 * sigma_f, 3), [0.0, 0.5 * sigma_m, 0.0]])
    t = 0.0
    for _ in range(60):  # 0.3 s in the air before the approach
        t += 0.005
        locator.observe({"ankle": reading(R, 0.04, 0.0, 0.0, rng, sigma_f, sigma_m) + bias}, ["left_foot"])
    locator.tare("left_foot", oMf)
    assert locator.start("left_foot", fid, POINTS, np.array([0.0, 0.0, 1.0]), oMf)
    moves = []
    while t < 0.6:
        t += 0.005
        moves += locator.update(t, oMf, {"ankle": reading(R, 0.04, 70.0, 3.0, rng, sigma_f, sigma_m) + bias})
    assert sum(m.shift for m in moves) == pytest.approx(0.0, abs=params.min_shift), moves
    assert len(moves) <= 1


def test_a_line_two_centimetres_off_is_found_within_its_tracking_time_under_two_percent_noise():
    params = load_controller_params().line_contact
    model, fid = model_with_a_foot()
    R = np.eye(3)
    oMf = {fid: pin.SE3(R, np.zeros(3))}
    locator = LineContactLocator(model, {"left_foot": ("ankle", fid)}, params)
    rng = np.random.default_rng(4)
    locator.start("left_foot", fid, POINTS, np.array([0.0, 0.0, 1.0]), oMf)
    t, moves = 0.0, []
    while not moves:
        t += 0.005
        moves += locator.update(t, oMf, {"ankle": reading(R, 0.06, 100.0, 0.0, rng, 20.0, 1.0)})
    assert t <= 0.3  # [s] (a 100 N load; at 0.5 % noise the sweep of 200 seeds: 25 ms median)
    assert moves[0].total == pytest.approx(0.02, abs=0.008)


def test_the_foot_weight_is_taken_out_of_the_reading():
    """A light load on a pitched foot: the foot's own weight in the reading would move the line
    by millimetres (a locator whose model has a weightless foot moves it)."""
    params = load_controller_params().line_contact
    R = pin.utils.rotate("y", -0.3)
    shifts = {}
    for name, mass in (("weighed", FOOT_MASS), ("weightless", 1e-9)):
        model, fid = model_with_a_foot()
        model.inertias[1] = pin.Inertia(mass, FOOT_COM, np.eye(3) * 1e-3)
        oMf = {fid: pin.SE3(R, np.zeros(3))}
        locator = LineContactLocator(model, {"left_foot": ("ankle", fid)}, params)
        locator.start("left_foot", fid, POINTS, np.array([0.0, 0.0, 1.0]), oMf)
        rng = np.random.default_rng(0)
        out, t = [], 0.0
        for _ in range(params.samples):
            out += locator.update(t, oMf, {"ankle": reading(R, 0.04, params.locate_force + 8.0, 0.0, rng)})
        shifts[name] = out[0].shift if out else 0.0
    assert shifts["weighed"] == 0.0  # no move: the line is where planned
    assert abs(shifts["weightless"]) > params.min_shift


def test_a_limb_without_a_sensor_or_a_line_is_not_located():
    params = load_controller_params().line_contact
    model, fid = model_with_a_foot()
    oMf = {fid: pin.SE3.Identity()}
    locator = LineContactLocator(model, {"left_foot": ("ankle", fid)}, params)
    assert not locator.start("right_foot", fid, POINTS, np.array([0.0, 0.0, 1.0]), oMf)
    assert not locator.start("left_foot", fid, POINTS[:1], np.array([0.0, 0.0, 1.0]), oMf)
    assert locator.start("left_foot", fid, POINTS, np.array([0.0, 0.0, 1.0]), oMf)
    locator.cancel("left_foot")  # the foot lifted before the estimate
    assert locator.pending == ()


def test_the_controller_moves_its_contact_to_the_located_line():
    """ContactSet.shift: the QP contact's points and reference move in the limb frame, the
    hold's in the world; the force ramp under way is kept."""
    from climb_core.contact import ContactPoint, Hold
    from controller_node.constraints import contact_from_hold
    from controller_node.contact_set import ContactSet

    up = np.array([0.0, 0.0, 1.0])
    hold = Hold("left_foot", "sole", "rung_2", tuple(ContactPoint(p, up) for p in POINTS), 0.25, False, 0.0)
    contact = contact_from_hold(hold, 0, pin.SE3.Identity(), np.eye(4), force_limit=800.0)
    cs = ContactSet()
    cs.put("left_foot", hold, contact, now=0.0, engage_s=0.2)
    cs.shift("left_foot", np.array([0.02, 0.0, 0.0]), np.array([0.02, 0.0, 0.0]), 0.8, 4)
    c = cs.active["left_foot"]
    assert c is not contact  # a new object (the QP's workspace caches contacts by identity)
    assert c.scale == contact.scale and c.limb == "left_foot"
    assert c.points_in_frame[:, 0] == pytest.approx([0.06, 0.06])
    assert c.reference_in_frame == pytest.approx([0.06, 0.0, -0.035])
    assert cs.holds["left_foot"].positions[:, 0] == pytest.approx([0.06, 0.06])
    assert "left_foot" in cs.ramps  # still engaging
    # the moment map follows: a unit normal force at the points has the new lever arm
    phi = c.wrench_map(np.eye(3))
    assert phi.shape[0] == 6
