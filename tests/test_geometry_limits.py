"""rig.geometry and rig.limits: hand-computable actuator motion, the report's runs pass,
crafted profiles over each limit are refused naming the actuator and the quantity."""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from rig import geometry as geo
from rig.config import RigConfig, load_config, parse_config
from rig.errors import LimitError, RigError
from rig.limits import QUANTITIES, check_all, check_plan, force_limit, plan_margins
from rig.paths import data_file
from rig.profile import (
    PEAK_ACCELERATION_FACTOR,
    PEAK_VELOCITY_FACTOR,
    Profile,
    Segment,
    load_profile,
)
from rig.units import INCH, POUND_FORCE, POUND_MASS

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

CONFIG = load_config()
MASS = 13_000 * POUND_MASS  # 7,000 lb platform + 6,000 lb payload
X_ACTUATORS = [1, 2, 3, 4]


def config_with(mutate: Callable[[dict], Any]) -> RigConfig:
    doc = tomllib.loads(data_file("rig.toml").read_text(encoding="utf-8"))
    mutate(doc)
    return parse_config(doc, "variant.toml")


def step(name: str, target: float, duration: float) -> Profile:
    """Rest 0.1 s, ramp to `target` (m) in `duration` (s), rest 1 s."""
    return Profile(name, (Segment(0.1), Segment(duration, target), Segment(1.0)))


# --- geometry ---------------------------------------------------------------------------

def test_extensions_are_the_projection_on_each_line_of_action() -> None:
    u = np.array([0.0, 0.1, -0.05])
    ext = geo.actuator_setpoints(CONFIG, u)
    assert ext.shape == (3, 6)
    # X1, X2 push from the −x edge, X3, X4 from the +x edge, Y1, Y2 are across the motion
    assert np.array_equal(ext[1], [0.1, 0.1, -0.1, -0.1, 0.0, 0.0])
    assert np.array_equal(ext[2], [-0.05, -0.05, 0.05, 0.05, 0.0, 0.0])
    assert np.array_equal(geo.actuator_velocity(CONFIG, u), ext)
    assert np.array_equal(geo.actuator_acceleration(CONFIG, u), ext)


def test_a_slanted_actuator_sees_its_cosine() -> None:
    def slant(doc: dict) -> None:
        doc["table"]["actuator"][0]["line_of_action"] = [0.6, 0.8]
    cfg = config_with(slant)
    ext = geo.actuator_setpoints(cfg, np.array([0.1]))
    assert ext[0] == pytest.approx([0.06, 0.1, -0.1, -0.1, 0.0, 0.0])


def test_forces_share_platform_and_payload_equally_on_the_x_actuators() -> None:
    f = geo.actuator_force(CONFIG, np.array([10.0, -5.0]))
    quarter = MASS * 10.0 / 4
    assert f[0] == pytest.approx([quarter, quarter, -quarter, -quarter, 0.0, 0.0])
    assert f[1] == pytest.approx(-0.5 * f[0])
    assert quarter == pytest.approx(14_741.75, abs=0.01)


@pytest.mark.parametrize("loa", [[0.6, 0.8], [0.0, -1.0], [-0.8, 0.6]])
def test_forces_balance_for_any_layout(loa: list[float]) -> None:
    def change(doc: dict) -> None:
        doc["table"]["actuator"][1]["line_of_action"] = loa
    cfg = config_with(change)
    f = geo.actuator_force(cfg, np.array([3.0]))[0]
    n, r = cfg.table.lines_of_action, cfg.table.positions
    assert f @ n == pytest.approx([MASS * 3.0, 0.0], abs=1e-6)  # x force, no y force
    assert f @ (r[:, 0] * n[:, 1] - r[:, 1] * n[:, 0]) == pytest.approx(0.0, abs=1e-6)  # no yaw


def test_setpoint_times_include_both_ends() -> None:
    assert np.allclose(geo.setpoint_times(0.01, 400), [0, 0.0025, 0.005, 0.0075, 0.01])
    t = geo.setpoint_times(3.0, 400)
    assert len(t) == 1201 and t[-1] == 3.0


def test_plan_of_run_a() -> None:
    profile = load_profile("A")
    plan = geo.actuator_plan(CONFIG, profile)
    u, _, u_ddot = profile.sample(plan.t)
    assert plan.extension.shape == plan.force.shape == (1201, 6)
    assert np.array_equal(plan.extension[:, 0], u)
    assert np.array_equal(plan.extension[:, 3], -u)
    assert np.allclose(plan.force[:, 1], MASS * u_ddot / 4)
    with pytest.raises(ValueError):
        plan.extension[0, 0] = 1.0  # read-only: the plan that was checked is the plan sent


def test_motion_must_be_one_dimensional() -> None:
    with pytest.raises(ValueError, match="1-D"):
        geo.actuator_setpoints(CONFIG, np.zeros((3, 2)))


# --- limits: the report's runs ----------------------------------------------------------

@pytest.mark.parametrize("run", ["A", "B", "C"])
def test_report_runs_pass_with_honest_margins(run: str) -> None:
    margins = check_all(CONFIG, load_profile(run))
    assert not margins.violations
    assert len(margins.items) == 6 * len(QUANTITIES)
    assert 0.15 < margins.worst.fraction < 0.5  # room to spare, but not an idle limit
    stroke = margins.get(1, "stroke")
    assert stroke.peak == pytest.approx(5.5 * INCH)
    assert stroke.fraction == pytest.approx(1 - 5.5 / 7)
    # every run has a 5.5 in move in 0.12 s; its midpoint falls on a setpoint
    velocity = margins.get(3, "velocity")
    assert velocity.peak == pytest.approx(PEAK_VELOCITY_FACTOR * 5.5 * INCH / 0.12, rel=1e-9)
    acceleration = margins.get(2, "acceleration").peak
    exact = PEAK_ACCELERATION_FACTOR * 5.5 * INCH / 0.12**2
    assert exact * 0.995 < acceleration <= exact
    assert margins.get(4, "force").peak == pytest.approx(MASS * acceleration / 4)
    assert margins.get(5, "force").peak == 0.0


def test_check_is_pure() -> None:
    profile = load_profile("C")
    assert check_all(CONFIG, profile) == check_all(CONFIG, profile)
    assert profile == load_profile("C")


# --- limits: crafted violations ---------------------------------------------------------

@pytest.mark.parametrize(("profile", "quantity", "rule"), [
    (step("S", 0.20, 1.0), "stroke", "stroke limit"),  # 0.2 m > 7 in
    (step("V", 0.16, 0.11), "velocity", "servovalve limit"),  # 2.73 m/s > 2.69 m/s
    (step("G", 0.05, 0.055), "acceleration", "acceleration limit"),  # 95 m/s² > 78.5 m/s²
])
def test_each_limit_is_enforced_alone(profile: Profile, quantity: str, rule: str) -> None:
    with pytest.raises(LimitError) as info:
        check_all(CONFIG, profile)
    first, *lines = str(info.value).splitlines()
    assert first == (f"profile {profile.name}: 4 limit violations on actuators 1, 2, 3, 4; "
                     "nothing has moved")
    assert len(lines) == 4
    for actuator, line in zip(X_ACTUATORS, lines):
        assert line.startswith(f"actuator {actuator} {quantity} ")
        assert f" exceeds {rule} " in line and f"(profile {profile.name}, t = " in line
    margins = info.value.margins
    assert {(m.actuator, m.quantity) for m in margins.violations} == {
        (a, quantity) for a in X_ACTUATORS}


def test_force_over_the_pressure_limit() -> None:
    def heavy(doc: dict) -> None:
        doc["table"]["payload_mass"]["value"] = 30_000  # lbm
    cfg = config_with(heavy)
    with pytest.raises(LimitError) as info:
        check_all(cfg, load_profile("C"))
    lines = str(info.value).splitlines()[1:]
    assert len(lines) == 4
    assert all(re.fullmatch(r"actuator [1-4] force [\d,]+ N exceeds pressure x area limit "
                            r"160,136 N \(profile C, t = 0\.\d{3} s\)", x) for x in lines), lines
    peak = info.value.margins.get(1, "force").peak
    assert peak == pytest.approx((37_000 * POUND_MASS) * info.value.margins.get(
        1, "acceleration").peak / 4)


def test_one_violation_is_one_line_naming_actuator_value_and_limit() -> None:
    def slow_valve(doc: dict) -> None:
        doc["table"]["actuator"][1]["servovalve_flow"]["value"] = 200  # gpm: 1.63 m/s
    with pytest.raises(LimitError) as info:
        check_all(config_with(slow_valve), load_profile("A"))
    assert str(info.value) == ("actuator 2 velocity 2.18 m/s exceeds servovalve limit 1.63 m/s "
                               "(profile A, t = 2.360 s)")
    assert isinstance(info.value, ValueError) and isinstance(info.value, RigError)


def test_a_short_stroke_on_one_actuator() -> None:
    def short(doc: dict) -> None:
        doc["table"]["actuator"][2]["stroke"]["value"] = 5.0  # in
    with pytest.raises(LimitError, match=r"^actuator 3 stroke 0\.1397 m exceeds stroke limit "
                                         r"0\.1270 m \(profile B, t = 0\.3\d\d s\)$"):
        check_all(config_with(short), load_profile("B"))


def test_rated_capacity_binds_when_pressure_is_ample() -> None:
    def high(doc: dict) -> None:
        doc["table"]["supply_pressure"]["value"] = 10_000  # psi: 120,000 lb > 75,000 lb rated
    cfg = config_with(high)
    limit, rule = force_limit(cfg, cfg.table.actuators[0])
    assert (limit, rule) == (pytest.approx(75_000 * POUND_FORCE), "force capacity")
    limit, rule = force_limit(CONFIG, CONFIG.table.actuators[0])
    assert (limit, rule) == (pytest.approx(36_000 * POUND_FORCE), "pressure x area limit")


def test_margins_without_raising() -> None:
    plan = geo.actuator_plan(CONFIG, step("S", 0.20, 1.0))
    margins = plan_margins(CONFIG, plan)
    assert margins.get(1, "stroke").fraction == pytest.approx(1 - 0.20 / (7 * INCH))
    assert margins.get(1, "stroke").fraction < 0
    with pytest.raises(LimitError):
        check_plan(CONFIG, plan)
    with pytest.raises(KeyError):
        margins.get(7, "stroke")


# --- margins formatting -----------------------------------------------------------------

def test_margins_format_in_si_and_us_units() -> None:
    margins = check_all(CONFIG, load_profile("C"))
    si = margins.format()
    for fragment in ("profile C", "400 Hz", "0.1397 m", "0.1778 m", "2.18 m/s", "2.69 m/s",
                     "m/s^2", "160,136 N", "servovalve limit", "18.8%", "smallest margin"):
        assert fragment in si, fragment
    us = margins.format(units="us")
    for fragment in ("5.50 in", "7.00 in", "85.9 in/s", "in/s^2", "36,000 lb", "18.8%"):
        assert fragment in us, fragment
    assert len(si.splitlines()) == 2 + 24 + 1
    assert "OVER" not in si
    with pytest.raises(ValueError):
        margins.format(units="imperial")


def test_over_limit_rows_are_flagged_in_the_table() -> None:
    margins = plan_margins(CONFIG, geo.actuator_plan(CONFIG, step("S", 0.20, 1.0)))
    flagged = [line for line in margins.format().splitlines() if "<< OVER" in line]
    assert len(flagged) == 4 and all(" stroke " in line for line in flagged)
    assert math.isclose(margins.worst.peak, 0.20)
