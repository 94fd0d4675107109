"""The same hybrid model integrated by scipy's solve_ivp: the benchmark's baseline.

Written independently of the compiled kernel: modes are frozen per segment,
segments end on solve_ivp's terminal events, static friction is handled by a
root search on the required force. Slow by construction (Python right-hand
side), accurate to the tolerances given.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from analysis.model.isolator import IsolatorModel
from analysis.model.terms import kind


def _force(model: IsolatorModel, z: float, zd: float, sz: float, szd: float,
           outside: bool) -> float:
    total = 0.0
    for t in model.terms:
        if t.coef == 0.0 or (t.is_gated and not outside):
            continue
        k = kind(t.kind).name
        a = t.shape[0] if t.shape else 0.0
        total += t.coef * {"linear_spring": z, "tanh_spring": np.tanh(a * z),
                           "linear_damper": zd, "tanh_damper": np.tanh(a * zd),
                           "coulomb": np.tanh(zd / a) if a > 0 else szd, "preload": sz}[k]
    return total


def simulate_reference(model: IsolatorModel, motion, t_out: np.ndarray, rtol: float = 1e-9,
                       atol: float = 1e-12, method: str = "DOP853"):
    """z(t_out), ż(t_out) from rest; models without stateful terms."""
    ua = motion.derivative(2)
    t_end = float(t_out[-1])
    m, delta, fb, eps = model.mass, model.dead_band, model.breakaway, model.stop_velocity

    def udd(t):
        return (float(ua(np.clip(t, motion.x[0], motion.x[-1])))
                if motion.x[0] < t < motion.x[-1] else 0.0)

    def f_req(t, z, outside):
        return m * udd(t) + _force(model, z, 0.0, np.sign(z), 0.0, outside)

    z_out, zd_out = np.zeros_like(t_out), np.zeros_like(t_out)
    t, z, zd = float(t_out[0]), 0.0, 0.0
    outside = abs(z) > delta if delta > 0 else True
    stuck = fb > 0 and abs(f_req(t, z, outside)) <= fb
    szd = 1.0
    while t < t_end - 1e-12:
        if stuck:
            # scan for breakaway on a fine grid, then pin it down
            grid = np.arange(t, t_end + 1e-4, 1e-4)
            inside = (grid > motion.x[0]) & (grid < motion.x[-1])
            need = m * np.where(inside, ua(np.clip(grid, motion.x[0], motion.x[-1])), 0.0)
            over = np.abs(need + _force(model, z, 0.0, np.sign(z), 0.0, outside)) > fb
            hit = int(np.argmax(over)) if over.any() else None
            t_next = t_end if hit is None else brentq(
                lambda s, z=z, outside=outside: abs(f_req(s, z, outside)) - fb,
                grid[hit - 1], grid[hit], xtol=1e-14)
            sel = (t_out >= t) & (t_out <= t_next)
            z_out[sel], zd_out[sel] = z, 0.0
            if hit is None:
                break
            direction = -np.sign(f_req(t_next + 1e-9, z, outside))
            t, stuck, szd = t_next + 1e-12, False, direction
            continue
        sz = np.sign(z) if z != 0 else 1.0
        szd = np.sign(zd) if zd != 0 else szd
        armed = fb > 0 and abs(zd) > eps
        if fb > 0 and not armed and abs(f_req(t, z, outside)) <= fb:
            stuck, zd = True, 0.0  # appendix A: |ż| ≤ ε with the force within breakaway
            continue

        def rhs(s, y, sz=sz, szd=szd, outside=outside):
            return [y[1], -_force(model, y[0], y[1], sz, szd, outside) / m - udd(s)]

        events = []
        if delta > 0:
            band = (lambda s, y: abs(y[0]) - delta) if outside else (lambda s, y: delta - abs(y[0]))
            band.terminal, band.direction = True, -1
            events.append(band)
        if armed:
            def stop(s, y, szd=szd):
                return szd * y[1] - eps

            stop.terminal, stop.direction = True, -1
            events.append(stop)
        elif fb > 0:  # slow and slipping: stick when the force falls within breakaway,
            def grip(s, y, outside=outside):
                return fb - abs(f_req(s, y[0], outside))

            grip.terminal, grip.direction = True, 1

            def leave(s, y):  # or re-arm on leaving ε
                return eps - abs(y[1])

            leave.terminal, leave.direction = True, -1
            events += [grip, leave]
        t_start = t
        sol = solve_ivp(rhs, (t, t_end), [z, zd], method=method, rtol=rtol, atol=atol,
                        events=events or None, dense_output=True, max_step=2e-3)
        t_stop = sol.t[-1]
        sel = (t_out >= t) & (t_out <= t_stop)
        if sel.any():
            y = sol.sol(t_out[sel])
            z_out[sel], zd_out[sel] = y[0], y[1]
        t, z, zd = t_stop, sol.y[0, -1], sol.y[1, -1]
        if sol.status == 1 and t_stop - t_start < 1e-9:
            # sliding along a switching surface: events fire back to back; step over it
            # without events and re-derive the modes from the state, as the kernel does
            sol = solve_ivp(rhs, (t, min(t + 1e-5, t_end)), [z, zd], method=method,
                            rtol=rtol, atol=atol, dense_output=True)
            # a sample inside the step over is the step's (left at zero, one sample of a
            # lagged table's run read 0 against the kernel's −15.9 mm)
            sel = (t_out > t) & (t_out <= sol.t[-1])
            if sel.any():
                y = sol.sol(t_out[sel])
                z_out[sel], zd_out[sel] = y[0], y[1]
            t, z, zd = sol.t[-1], sol.y[0, -1], sol.y[1, -1]
            outside = abs(z) > delta if delta > 0 else True
            continue
        if sol.status == 1:  # an event ended the segment
            fired = [i for i, e in enumerate(sol.t_events) if e.size]
            ev = events[fired[0]]
            if delta > 0 and ev is events[0]:
                outside = not outside
            elif armed and abs(f_req(t, z, outside)) <= fb:
                stuck, zd = True, 0.0
            t += 1e-12
    return z_out, zd_out
