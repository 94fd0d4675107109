"""The integrator of the independent campaign generator's hybrid model.

Every dead-band entry/exit and every stick/slip transition is an event of
``scipy.integrate.solve_ivp``; the integration restarts at each one in the new mode,
and at each break of the table's motion. The segments' dense solutions together make
a ``Trajectory`` over the whole record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from bench.unseen.plant import BREAKAWAY_MARGIN, Plant


@dataclass
class Trajectory:
    """Dense solution over the whole record: piecewise solve_ivp segments."""

    starts: list[float]
    sols: list

    def __call__(self, t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        out = np.empty((5, t.size))
        idx = np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0, len(self.sols) - 1)
        for i in np.unique(idx):
            sel = idx == i
            out[:, sel] = self.sols[i](t[sel])
        return out


def simulate(plant: Plant, t_end: float, max_events: int = 20000,
             dwell: float = 5e-4) -> Trajectory:
    """Integrate the hybrid model from rest to t_end, restarting at every event.

    After a breakaway the mass slides for at least ``dwell`` seconds before it may stick
    again: with a stiff element in the load path (Bouc-Wen) the force otherwise sits on
    the breakaway threshold and stick/slip would alternate without time advancing.
    """
    opts = {"method": "RK45", "rtol": 1e-8, "atol": 1e-10, "max_step": 5e-4, "dense_output": True}
    k = plant.k
    y, edge, inside = plant.initial()
    y = np.asarray(y, dtype=float)
    stuck = True
    breaks = [b for b in plant.p.breaks if 0.0 < b < t_end] + [t_end]
    t = 0.0
    starts: list[float] = []
    sols: list = []
    stalled = 0
    no_stick_until = -1.0
    for _ in range(max_events):
        if t >= t_end:
            break
        t_stop = next(b for b in breaks if b > t + 1e-12)
        plant.piece = plant.p.piece_at(t + 1e-12)
        first: dict[str, float] = {}  # the solver's own first step
        if stuck:
            # at the start of a stuck segment: does the mass break away at once? (with a
            # small margin: a stick event leaves the force at the threshold to rounding)
            a, b = plant.hold_interval(t, y, edge, inside)
            fb = k["F_b"] * (1.0 + BREAKAWAY_MARGIN)
            if a > fb or b < -fb:
                stuck, inside = False, _region_after_breakaway(y[0], edge, inside, a > fb)
                edge, no_stick_until = 0, t + dwell
                continue
            on = max(a, -b) >= k["F_b"]  # left on or past F_b by the stick event
            fun = plant.rhs_stuck()
            events = [plant.ev_breakaway(edge, inside, BREAKAWAY_MARGIN if on else 0.0)]
            # A hold force on the breakaway threshold (where a stick event found the force,
            # rather than the velocity, coming into the window) may leave the window
            # [-F_b, F_b] through its other side within microseconds, as the table's
            # acceleration sweeps through the value that balances the spring: the
            # breakaway event is found only where a step ends on each side of the
            # crossing, so the first step is short. With the solver's own (0.5 ms) a mass
            # that stuck for 26 us just outside the dead band as the return ramp began
            # rode the whole ramp, at a 160 kN hold force against a 114 N breakaway.
            if min(fb - a, b + fb) < 1e-6 * fb:
                first = {"first_step": min(1e-6, 0.5 * (t_stop - t))}
        elif t < no_stick_until:
            t_stop = min(t_stop, no_stick_until)
            fun, events = plant.rhs_slip(inside), [plant.ev_deadband(inside)]
        else:
            fun = plant.rhs_slip(inside)
            events = [plant.ev_deadband(inside), plant.ev_stick(inside)]
        sol = solve_ivp(fun, (t, t_stop), y, events=events, **opts, **first)
        if sol.status == -1:
            raise RuntimeError(f"integration failed at t={t:.6f}: {sol.message}")
        starts.append(t)
        sols.append(sol.sol)
        t_new, y = float(sol.t[-1]), sol.y[:, -1].copy()
        stalled = stalled + 1 if t_new - t < 1e-10 else 0
        if stalled > 50:
            raise RuntimeError(f"no progress at t={t:.6f} (mode stuck={stuck}, inside={inside})")
        t = t_new
        if sol.status != 1:
            continue  # reached a breakpoint: same mode
        if stuck:  # breakaway
            a, b = plant.hold_interval(t, y, edge, inside)
            push_neg = (a - k["F_b"]) >= (-b - k["F_b"])
            inside = _region_after_breakaway(y[0], edge, inside, push_neg)
            stuck, edge, no_stick_until = False, 0, t + dwell
        elif sol.t_events[0].size:  # dead-band edge
            y[0] = math.copysign(k["delta"], y[0])
            sgn = 1 if y[0] > 0 else -1
            a, b = plant.hold_interval(t, y, sgn, inside)
            if abs(y[1]) < k["eps"] and a <= k["F_b"] and b >= -k["F_b"]:
                stuck, edge, y[1] = True, sgn, 0.0
            else:
                inside = not inside
        else:  # stick
            stuck, edge, y[1] = True, 0, 0.0
    else:
        raise RuntimeError(f"more than {max_events} events before t={t:.6f}")
    return Trajectory(starts, sols)


def _region_after_breakaway(z: float, edge: int, inside: bool, push_neg: bool) -> bool:
    """Which side of the dead band the mass moves into when it breaks away."""
    if not edge:
        return inside
    moving = -1 if push_neg else 1
    return moving * edge < 0  # towards the centre: inside
