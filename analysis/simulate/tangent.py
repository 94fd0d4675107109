"""Forward sensitivities of the simulated motion: the tangent of `kernel.simulate_one`.

The motion z(t; p) is a differentiable function of every constant, because every
mode switch happens at its located event time (tests/test_simulate_nonsmooth.py).
Its slopes d z / d p_c for n chosen constants come here from one integration of
the state together with its tangent Y = d y / d p (N × n), instead of n + 1
integrations of perturbed constants:

- within a step, the RK4 stages' tangent: K = (∂f/∂y) T + ∂f/∂p at each stage
  point, with the analytic partials of each term's basis and state rate;
- at a located event, the event time's own derivative from its function g,
  dτ = −(g_y · Y⁻ + g_p) / (g_y · f⁻ + g_t), and the state's tangent carried
  across the switch as Y⁺ = R (Y⁻ + f⁻ dτ) − f⁺ dτ, where R is the reset the
  switch makes (a stop sets ż = 0) and f⁻, f⁺ the rates before and after;
- discrete decisions the integrator takes at a step's start without locating
  them (a re-derived mode) carry the tangent unchanged.

The primal integration is the kernel's, call for call (`simulate_tangent` follows
`simulate_one`'s steps, events and mode decisions line for line), so the motion is
the kernel's to the last bit; tests/test_tangent.py checks both that and the slopes
against converged finite differences. Measured there: one integration with the
tangent of 9–11 constants costs about five plain ones, against n + 1 for a
finite-difference Jacobian. `runs_sensitivity` integrates several runs side by side on
the cores, from a start that may itself move with a constant (a sensor's gain); the
loop's refit takes its Jacobian from it on request (`refit._Evaluator`). The fits keep
their finite differences, whose path over the unseen benchmark ends in better valleys
(docs/loop.md, "Speed").

Where the two differ, the tangent is the exact flow's: the finite differences also
see where RK4's steps are split at events, an error of order h⁵ that moves with the
constant that places the split (the stop velocity, on runs that pass through its
band without sticking: its slope falls 35 × per halving of the step, to ~1e-8 of
k1's).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from numba import njit
from scipy.interpolate import PPoly

from analysis.model.isolator import (
    N_GLOBAL,
    P_BREAKAWAY,
    P_DEAD_BAND,
    P_MASS,
    P_STOP_VELOCITY,
    TERM_WIDTH,
    IsolatorModel,
)
from analysis.model.terms import (
    BOUC_WEN,
    COMPRESSION_SPRING,
    COULOMB,
    CUBIC_SPRING,
    EXTENSION_DAMPER,
    LINEAR_DAMPER,
    LINEAR_SPRING,
    PRELOAD,
    QUADRATIC_DAMPER,
    TANH_DAMPER,
    TANH_SPRING,
    THERMAL_DAMPER,
    basis,
)
from analysis.simulate import RunSetup, _check_step, _grid, kernel_coefs
from analysis.simulate.kernel import (
    EV_BAND,
    EV_BREAKAWAY,
    EV_GRIP,
    EV_LEAVE,
    EV_STOP,
    EV_Z0,
    EV_ZD0,
    LAND_PIECE,
    LEAVE_MARGIN,
    MAX_EVENTS_PER_STEP,
    N_EVENTS,
    ROOT_ITERATIONS,
    _sign,
    _slip_direction,
    base_motion,
    event_values,
    required_force,
    rhs,
    rk4_step,
    workspace,
)

NO_REFCOUNT = {"_nrt": False}  # as the kernel's calls: these allocate nothing

# numba caches this module's code against this file alone, and kernel.py's and terms.py's
# functions are compiled into it: their sources' hash (tests/test_tangent.py) is written
# here, so that a change there changes this file too, or a cached tangent runs old code
KERNEL_SOURCES = "93daa95a2b091a31"


@njit(cache=True, inline="always")
def basis_partials(kind, z, zd, s, a, b, c):
    """∂basis/∂(z, ż, s, a, b, c) of a term kind (sign switches held: their partials are 0)."""
    if kind == LINEAR_SPRING:
        return 1.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == TANH_SPRING:
        th = math.tanh(a * z)
        d = 1.0 - th * th
        return a * d, 0.0, 0.0, z * d, 0.0, 0.0
    if kind == LINEAR_DAMPER:
        return 0.0, 1.0, 0.0, 0.0, 0.0, 0.0
    if kind == TANH_DAMPER:
        th = math.tanh(a * zd)
        d = 1.0 - th * th
        return 0.0, a * d, 0.0, zd * d, 0.0, 0.0
    if kind == COULOMB:
        if a > 0.0:
            th = math.tanh(zd / a)
            d = 1.0 - th * th
            return 0.0, d / a, 0.0, -zd * d / (a * a), 0.0, 0.0
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == CUBIC_SPRING:
        return 3.0 * z * z, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == QUADRATIC_DAMPER:
        return 0.0, 2.0 * abs(zd), 0.0, 0.0, 0.0, 0.0
    if kind == BOUC_WEN:
        return 0.0, 0.0, 1.0, 0.0, 0.0, 0.0
    if kind == COMPRESSION_SPRING:
        return (1.0 if z > 0.0 else 0.0), 0.0, 0.0, 0.0, 0.0, 0.0
    if kind == EXTENSION_DAMPER:
        return 0.0, (1.0 if zd > 0.0 else 0.0), 0.0, 0.0, 0.0, 0.0
    if kind == THERMAL_DAMPER:
        if c > 0.0 and s > c:
            return 0.0, c, 0.0, 0.0, 0.0, zd
        return 0.0, s, zd, 0.0, 0.0, 0.0
    # PRELOAD, FORCE_OFFSET: constant between switches
    return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(cache=True, inline="always")
def rate_partials(kind, z, zd, s, a, b, c):
    """∂(state rate)/∂(z, ż, s, a, b, c) of a term kind."""
    if kind == BOUC_WEN:
        sg = 1.0 if s > 0.0 else (-1.0 if s < 0.0 else 0.0)
        szd = 1.0 if zd > 0.0 else (-1.0 if zd < 0.0 else 0.0)
        rs = abs(s)
        if c == 1.0:
            rn, drn = rs, 1.0
        else:
            rn = rs ** c
            drn = c * rs ** (c - 1.0) if rs > 0.0 else 0.0
        lg = math.log(rs) if rs > 0.0 else 0.0
        # r' = ż − a|ż| sg rⁿ − b ż rⁿ, with sg rⁿ = s at n = 1
        d_zd = 1.0 - a * szd * sg * rn - b * rn
        d_s = -a * abs(zd) * drn - b * zd * drn * sg
        return (0.0, d_zd, d_s, -abs(zd) * sg * rn, -zd * rn,
                -(a * abs(zd) * sg + b * zd) * rn * lg)
    if kind == THERMAL_DAMPER:
        if b > 0.0:
            return 0.0, 2.0 * a * zd, -1.0 / b, zd * zd, s / (b * b), 0.0
        return 0.0, 2.0 * a * zd, 0.0, zd * zd, 0.0, 0.0
    return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


@njit(cache=True, **NO_REFCOUNT)
def tangent_rhs(kinds, gated, p, t, y, Y, stuck, outside, sz, szd, col_term, col_slot,
                col_global, dY, acc):
    """dY/dt = (∂f/∂y) Y + ∂f/∂p at (t, y) for the frozen modes."""
    nt = kinds.shape[0]
    ns = Y.shape[1]
    z = y[0]
    zd = 0.0 if stuck else y[1]
    for j in range(nt):
        o = N_GLOBAL + TERM_WIDTH * j
        rz, rzd, rs, ra, rb, rc = rate_partials(kinds[j], z, zd, y[2 + j], p[o + 1], p[o + 2],
                                                p[o + 3])
        for c in range(ns):
            v = rz * Y[0, c] + rs * Y[2 + j, c]
            if not stuck:
                v += rzd * Y[1, c]
            if col_term[c] == j:
                slot = col_slot[c]
                v += ra if slot == 1 else (rb if slot == 2 else (rc if slot == 3 else 0.0))
            dY[2 + j, c] = v
    if stuck:
        for c in range(ns):
            dY[0, c] = 0.0
            dY[1, c] = 0.0
        return
    m = p[P_MASS]
    fz = 0.0
    fzd = 0.0
    ftot = 0.0
    for c in range(ns):
        acc[c] = 0.0
    for j in range(nt):
        if gated[j] and not outside:
            continue
        o = N_GLOBAL + TERM_WIDTH * j
        coef = p[o]
        a, b, cc = p[o + 1], p[o + 2], p[o + 3]
        bv = basis(kinds[j], z, zd, sz, szd, y[2 + j], a, b, cc)
        bz, bzd, bs, ba, bb, bc = basis_partials(kinds[j], z, zd, y[2 + j], a, b, cc)
        if coef != 0.0:
            ftot += coef * bv
        fz += coef * bz
        fzd += coef * bzd
        for c in range(ns):
            v = coef * bs * Y[2 + j, c]
            if col_term[c] == j:
                slot = col_slot[c]
                if slot == 0:
                    v += bv
                elif slot == 1:
                    v += coef * ba
                elif slot == 2:
                    v += coef * bb
                else:
                    v += coef * bc
            acc[c] += v
    for c in range(ns):
        dY[0, c] = Y[1, c]
        d = -(fz * Y[0, c] + fzd * Y[1, c] + acc[c]) / m
        if col_global[c] == P_MASS:
            d += ftot / (m * m)
        dY[1, c] = d


@njit(cache=True, **NO_REFCOUNT)
def tangent_step(kinds, gated, p, t, y, Y, h, stuck, outside, sz, szd, k1, k2, k3, tmp,
                 K1, K2, K3, K4, T, Yout, col_term, col_slot, col_global, acc):
    """The tangent of the RK4 step of length h from (t, y) whose stages k1, k2, k3 the
    kernel's `rk4_step` has just computed: Yout = d(step)/dp, h held."""
    n = y.shape[0]
    tangent_rhs(kinds, gated, p, t, y, Y, stuck, outside, sz, szd, col_term, col_slot,
                col_global, K1, acc)
    for i in range(n):
        tmp[i] = y[i] + 0.5 * h * k1[i]
    _axpy(Y, 0.5 * h, K1, T)
    tangent_rhs(kinds, gated, p, t + 0.5 * h, tmp, T, stuck, outside, sz, szd, col_term,
                col_slot, col_global, K2, acc)
    for i in range(n):
        tmp[i] = y[i] + 0.5 * h * k2[i]
    _axpy(Y, 0.5 * h, K2, T)
    tangent_rhs(kinds, gated, p, t + 0.5 * h, tmp, T, stuck, outside, sz, szd, col_term,
                col_slot, col_global, K3, acc)
    for i in range(n):
        tmp[i] = y[i] + h * k3[i]
    _axpy(Y, h, K3, T)
    tangent_rhs(kinds, gated, p, t + h, tmp, T, stuck, outside, sz, szd, col_term, col_slot,
                col_global, K4, acc)
    w = h / 6.0
    for i in range(Y.shape[0]):
        for c in range(Y.shape[1]):
            Yout[i, c] = Y[i, c] + w * (K1[i, c] + 2.0 * K2[i, c] + 2.0 * K3[i, c] + K4[i, c])


@njit(cache=True, inline="always")
def _axpy(Y, a, K, out):
    for i in range(Y.shape[0]):
        for c in range(Y.shape[1]):
            out[i, c] = Y[i, c] + a * K[i, c]


@njit(cache=True, **NO_REFCOUNT)
def _jump(Yb, Y, fb, fa, dtau, reset):
    """Y = R (Yb + fb dτ) − fa dτ: the tangent across a switch at an event time that moves
    by dτ, with rates fb before and fa after it; R zeroes ż's row where the switch set ż = 0."""
    for c in range(Y.shape[1]):
        for i in range(Y.shape[0]):
            v = Yb[i, c] + fb[i] * dtau[c]
            if reset and i == 1:
                v = 0.0
            Y[i, c] = v - fa[i] * dtau[c]


@njit(cache=True)
def base_jerk(breaks, coefs, t):
    """d³u/dt³ of the piecewise polynomial at t (0 where it is held)."""
    n = breaks.shape[0] - 1
    if t <= breaks[0] or t >= breaks[n]:
        return 0.0
    lo = 0
    hi = n
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if t >= breaks[mid]:
            lo = mid
        else:
            hi = mid
    x = t - breaks[lo]
    deg = coefs.shape[0] - 1
    j = 0.0
    for m in range(deg + 1):
        pw = deg - m
        if pw >= 3:
            j += coefs[m, lo] * pw * (pw - 1) * (pw - 2) * x ** (pw - 3)
    return j


@njit(cache=True, **NO_REFCOUNT)
def event_partials(i, kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd,
                   direction, col_term, col_slot, col_global, gy, gp, scratch):
    """g_y (N,), g_p (n,) of event i at (t, y) for the modes it was armed in; returns g_t."""
    nt = kinds.shape[0]
    ns = gp.shape[0]
    gy[:] = 0.0
    gp[:] = 0.0
    gt = 0.0
    if i == EV_BAND:
        s = _sign(y[0]) if outside else -_sign(y[0])
        gy[0] = s
        for c in range(ns):
            if col_global[c] == P_DEAD_BAND:
                gp[c] = -1.0 if outside else 1.0
    elif i == EV_Z0:
        gy[0] = sz
    elif i == EV_ZD0:
        gy[1] = szd
    elif i == EV_STOP:
        gy[1] = direction
        for c in range(ns):
            if col_global[c] == P_STOP_VELOCITY:
                gp[c] = -1.0
    elif i == EV_LEAVE:
        gy[1] = -_sign(y[1])
        for c in range(ns):
            if col_global[c] == P_STOP_VELOCITY:
                gp[c] = 1.0 + LEAVE_MARGIN
    elif i == EV_BREAKAWAY or i == EV_GRIP:
        # g = ±(F_break − |m ü + F(z, 0, s)|): breakaway +, grip −
        ua = base_motion(breaks, coefs, t)[2]
        m = p[P_MASS]
        freq = required_force(kinds, gated, p, y, sz, outside, ua, scratch)
        sf = _sign(freq)
        w = 1.0 if i == EV_BREAKAWAY else -1.0  # g's sign
        gt = -w * sf * m * base_jerk(breaks, coefs, t)
        for c in range(ns):
            if col_global[c] == P_BREAKAWAY:
                gp[c] = w
            elif col_global[c] == P_MASS:
                gp[c] = -w * sf * ua
        for j in range(nt):
            if gated[j] and not outside:
                continue
            o = N_GLOBAL + TERM_WIDTH * j
            coef = p[o]
            bv = basis(kinds[j], y[0], 0.0, sz, 0.0, y[2 + j], p[o + 1], p[o + 2], p[o + 3])
            bz, bzd, bs, ba, bb, bc = basis_partials(kinds[j], y[0], 0.0, y[2 + j], p[o + 1],
                                                     p[o + 2], p[o + 3])
            gy[0] += -w * sf * coef * bz
            gy[2 + j] += -w * sf * coef * bs
            for c in range(ns):
                if col_term[c] == j:
                    slot = col_slot[c]
                    d = bv if slot == 0 else coef * (ba if slot == 1 else (bb if slot == 2
                                                                          else bc))
                    gp[c] += -w * sf * d
    return gt


@njit(cache=True, nogil=True)
def simulate_tangent(kinds, gated, p, breaks, coefs, t0, dt, n_out, substeps, z0, zd0, s0,
                     dz0, dzd0, col_term, col_slot, col_global, out_z, out_dz):
    """`kernel.simulate_one`'s integration (the same calls, so the same z to the last bit)
    with the tangent of the state carried along; out_dz (n, n_out): d z / d p_c.
    dz0, dzd0 (n,): the start's own slopes d z0 / d p_c, d ż0 / d p_c (a start read from
    the data moves with the sensor's gain, one at the dead band's edge with δ); a column
    whose col_term and col_global are both −1 has no constant of its own, only that start."""
    nt = kinds.shape[0]
    n = 2 + nt
    ns = col_term.shape[0]
    work, scratch, events = workspace(nt)
    y, y1, ytry = work[0], work[1], work[2]
    k1, k2, k3, k4 = work[3], work[4], work[5], work[6]
    tmp = work[7]
    fm, fp, gy = np.zeros(n), np.zeros(n), np.zeros(n)  # rates across a switch, g_y
    g0, g1, gt = events[0], events[1], events[2]
    Y = np.zeros((n, ns))
    Y1 = np.zeros((n, ns))
    K1 = np.zeros((n, ns))
    K2 = np.zeros((n, ns))
    K3 = np.zeros((n, ns))
    K4 = np.zeros((n, ns))
    T = np.zeros((n, ns))
    for c in range(ns):
        Y[0, c] = dz0[c]
        Y[1, c] = dzd0[c]
    acc = np.zeros(ns)
    gp = np.zeros(ns)
    dtau_ev = np.zeros(ns)  # d τ / d p of the last located event, at time ev_t
    ev_t = -math.inf

    uses_sz = False
    uses_szd = False
    for j in range(nt):
        coef = p[N_GLOBAL + TERM_WIDTH * j]
        if kinds[j] == PRELOAD and coef != 0.0:
            uses_sz = True
        if kinds[j] == COULOMB and coef != 0.0:
            uses_szd = True
    delta = p[P_DEAD_BAND]
    fbreak = p[P_BREAKAWAY]
    eps = p[P_STOP_VELOCITY]
    friction = fbreak > 0.0

    y[0] = z0
    y[1] = zd0
    for j in range(nt):
        y[2 + j] = s0[j]
    outside = (abs(z0) > delta) if delta > 0.0 else True
    sz = _sign(z0)
    szd = _sign(zd0)
    stuck = False
    if friction and zd0 == 0.0:
        ua = base_motion(breaks, coefs, t0)[2]
        stuck = abs(required_force(kinds, gated, p, y, sz, outside, ua, scratch)) <= fbreak

    h = dt / substeps
    nb = breaks.shape[0]
    land = nb > 1 and breaks[nb - 1] - breaks[0] > LAND_PIECE * h * (nb - 1)
    ib = 0
    t = t0
    for k in range(n_out):
        if k > 0:
            for _ in range(substeps):
                t_end = t + h
                nev = 0
                while t_end - t > 1e-12 * h:
                    t_stop = t_end
                    if land:
                        while ib < nb and breaks[ib] <= t + 1e-9 * h:
                            ib += 1
                        if ib < nb and breaks[ib] < t_end - 1e-9 * h:
                            t_stop = breaks[ib]
                        if 0 < ib < nb:
                            t_stop = min(t_stop, t + (breaks[ib] - breaks[ib - 1]) / LAND_PIECE)
                    hrem = t_stop - t
                    # a mode the step's start re-derives right after a located event switches
                    # at that event's time, and carries its dτ (a mass that enters the dead
                    # band slowly sticks at the edge: its z there is −δ, whatever k1)
                    st_b, out_b, sz_b, szd_b, zd_b = stuck, outside, sz, szd, y[1]
                    if delta > 0.0 and outside and abs(y[0]) < delta:
                        outside = False
                    elif delta > 0.0 and not outside and abs(y[0]) > delta:
                        outside = True
                    if stuck and friction:
                        slip = _slip_direction(kinds, gated, p, breaks, coefs, t, y, sz,
                                               outside, scratch)
                        if slip != 0.0:
                            stuck = False
                            szd = slip
                    if sz == 0.0 and y[0] != 0.0:
                        sz = _sign(y[0])
                    if not stuck and szd == 0.0 and y[1] != 0.0:
                        szd = _sign(y[1])
                    direction = 0.0
                    if not stuck and friction:
                        if abs(y[1]) > eps:
                            direction = _sign(y[1])
                        else:
                            ua = base_motion(breaks, coefs, t)[2]
                            if abs(required_force(kinds, gated, p, y, sz, outside, ua,
                                                  scratch)) <= fbreak:
                                stuck = True
                                y[1] = 0.0
                                Y[1, :] = 0.0
                    if t == ev_t and (stuck != st_b or outside != out_b or sz != sz_b
                                      or szd != szd_b or y[1] != zd_b):
                        for i in range(n):
                            tmp[i] = y[i]
                        tmp[1] = zd_b
                        rhs(kinds, gated, p, breaks, coefs, t, tmp, st_b, out_b, sz_b, szd_b,
                            fm, scratch)
                        rhs(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd, fp,
                            scratch)
                        _jump(Y, Y, fm, fp, dtau_ev, y[1] != zd_b)
                    event_values(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd,
                                 direction, uses_sz, uses_szd, g0, scratch)
                    rhs(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd, k1,
                        scratch)
                    rk4_step(kinds, gated, p, breaks, coefs, t, y, hrem, stuck, outside, sz, szd,
                             y1, k1, k2, k3, k4, tmp, scratch, True)
                    event_values(kinds, gated, p, breaks, coefs, t + hrem, y1, stuck, outside,
                                 sz, szd, direction, uses_sz, uses_szd, g1, scratch)
                    fired = False
                    for i in range(N_EVENTS):
                        if g0[i] > 0.0 and g1[i] <= 0.0:
                            fired = True
                    if not fired or nev >= MAX_EVENTS_PER_STEP:
                        tangent_step(kinds, gated, p, t, y, Y, hrem, stuck, outside, sz, szd,
                                     k1, k2, k3, tmp, K1, K2, K3, K4, T, Y1, col_term,
                                     col_slot, col_global, acc)
                        for i in range(n):
                            for c in range(ns):
                                Y[i, c] = Y1[i, c]
                        for i in range(n):
                            y[i] = y1[i]
                        t = t_stop
                        if fired:
                            outside = (abs(y[0]) > delta) if delta > 0.0 else True
                            sz = _sign(y[0])
                            szd = _sign(y[1])
                        continue
                    theta_best = 1.0
                    i_best = -1
                    for i in range(N_EVENTS):
                        if not (g0[i] > 0.0 and g1[i] <= 0.0):
                            continue
                        lo = 0.0
                        hi = 1.0
                        glo = g0[i]
                        ghi = g1[i]
                        side = 0
                        for _it in range(ROOT_ITERATIONS):
                            if (hi - lo) * hrem <= 1e-13 + 1e-13 * abs(t):
                                break
                            th = (lo * ghi - hi * glo) / (ghi - glo)
                            if not (lo < th < hi):
                                th = 0.5 * (lo + hi)
                            rk4_step(kinds, gated, p, breaks, coefs, t, y, th * hrem, stuck,
                                     outside, sz, szd, ytry, k1, k2, k3, k4, tmp, scratch,
                                     True)
                            event_values(kinds, gated, p, breaks, coefs, t + th * hrem, ytry,
                                         stuck, outside, sz, szd, direction, uses_sz, uses_szd,
                                         gt, scratch)
                            gv = gt[i]
                            if gv > 0.0:
                                lo = th
                                glo = gv
                                if side == -1:
                                    ghi *= 0.5
                                side = -1
                            else:
                                hi = th
                                ghi = gv
                                if side == 1:
                                    glo *= 0.5
                                side = 1
                        if hi < theta_best or i_best < 0:
                            i_best = i
                        theta_best = min(theta_best, hi)
                    hs = theta_best * hrem
                    rk4_step(kinds, gated, p, breaks, coefs, t, y, hs, stuck, outside, sz, szd,
                             ytry, k1, k2, k3, k4, tmp, scratch, True)
                    # the tangent of the step to the event at fixed length, then the event
                    # time's own derivative and the switch (module docstring)
                    tangent_step(kinds, gated, p, t, y, Y, hs, stuck, outside, sz, szd, k1, k2,
                                 k3, tmp, K1, K2, K3, K4, T, Y1, col_term, col_slot,
                                 col_global, acc)
                    stuck0, outside0, sz0, szd0 = stuck, outside, sz, szd
                    t = t + hs
                    for i in range(n):
                        y[i] = ytry[i]
                    rhs(kinds, gated, p, breaks, coefs, t, y, stuck0, outside0, sz0, szd0, fm,
                        scratch)
                    gtime = event_partials(i_best, kinds, gated, p, breaks, coefs, t, y, stuck0,
                                           outside0, sz0, szd0, direction, col_term, col_slot,
                                           col_global, gy, gp, scratch)
                    event_values(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd,
                                 direction, uses_sz, uses_szd, gt, scratch)
                    nev += 1
                    if g0[EV_BAND] > 0.0 and gt[EV_BAND] <= 0.0:
                        outside = not outside
                    if g0[EV_Z0] > 0.0 and gt[EV_Z0] <= 0.0:
                        sz = -sz
                    if g0[EV_ZD0] > 0.0 and gt[EV_ZD0] <= 0.0:
                        szd = -szd
                    if g0[EV_BREAKAWAY] > 0.0 and gt[EV_BREAKAWAY] <= 0.0:
                        ua = base_motion(breaks, coefs, t)[2]
                        freq = required_force(kinds, gated, p, y, sz, outside, ua, scratch)
                        stuck = False
                        szd = -_sign(freq)
                    elif g0[EV_GRIP] > 0.0 and gt[EV_GRIP] <= 0.0:
                        stuck = True
                        y[1] = 0.0
                    elif g0[EV_STOP] > 0.0 and gt[EV_STOP] <= 0.0:
                        ua = base_motion(breaks, coefs, t)[2]
                        if abs(required_force(kinds, gated, p, y, sz, outside, ua,
                                              scratch)) <= fbreak:
                            stuck = True
                            y[1] = 0.0
                    rhs(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd, fp,
                        scratch)
                    rate = 0.0
                    for i in range(n):
                        rate += gy[i] * fm[i]
                    rate += gtime
                    for c in range(ns):
                        num = gp[c]
                        for i in range(n):
                            num += gy[i] * Y1[i, c]
                        dtau_ev[c] = -num / rate if rate != 0.0 else 0.0
                    ev_t = t
                    _jump(Y1, Y, fm, fp, dtau_ev, stuck and not stuck0)
            t = t0 + k * dt
        if stuck and friction:
            slip = _slip_direction(kinds, gated, p, breaks, coefs, t, y, sz, outside, scratch)
            if slip != 0.0:
                stuck = False
                szd = slip
        out_z[k] = y[0]
        for c in range(ns):
            out_dz[c, k] = Y[0, c]


def _columns(model: IsolatorModel, names: Sequence[str | None]
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernel's column maps (col_term, col_slot, col_global) of the named constants;
    None: a column with no constant of its own."""
    idx = model.vector_index()
    cols = [-1 if name is None else idx[name] for name in names]
    col_global = np.array([c if 0 <= c < N_GLOBAL else -1 for c in cols], np.int64)
    col_term = np.array([(c - N_GLOBAL) // TERM_WIDTH if c >= N_GLOBAL else -1 for c in cols],
                        np.int64)
    col_slot = np.array([(c - N_GLOBAL) % TERM_WIDTH if c >= N_GLOBAL else -1 for c in cols],
                        np.int64)
    return col_term, col_slot, col_global


def motion_sensitivity(model: IsolatorModel, motion: PPoly, names: Sequence[str],
                       duration: float | None = None, dt: float = 1e-3,
                       t0: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """z (n,) of `model` driven by `motion` from rest, as `simulate` gives it, and
    d z / d p (len(names), n) of the named constants (SI: m per unit of each)."""
    return runs_sensitivity(model, [RunSetup(motion, duration, dt, t0)], names)[0]


def runs_sensitivity(model: IsolatorModel, setups: Sequence[RunSetup],
                     names: Sequence[str | None],
                     start_slopes: Sequence[np.ndarray] | None = None
                     ) -> list[tuple[np.ndarray, np.ndarray]]:
    """z (n_k,) and d z / d p (len(names), n_k) of each run, its terms' internal states
    starting at zero; the runs share the cores, one thread each.

    names: the constants (None: a column with no constant, moved by its start only);
    start_slopes[k] (len(names), 2): d (z0, ż0) / d p of run k's start, default zero.
    """
    col_term, col_slot, col_global = _columns(model, names)
    kinds, gated = model.structure()
    p = model.vector()
    s0 = np.zeros(len(model.terms))

    def one(k: int) -> tuple[np.ndarray, np.ndarray]:
        s = setups[k]
        _check_step(s.dt, 1)
        start, n = _grid(s.motion, s.duration, s.dt, s.t0)
        d0 = (np.zeros((len(names), 2)) if start_slopes is None
              else np.asarray(start_slopes[k], float).reshape(len(names), 2))
        z = np.empty(n)
        dz = np.empty((len(names), n))
        simulate_tangent(kinds, gated, p, np.ascontiguousarray(s.motion.x, float),
                         kernel_coefs(s.motion), start, s.dt, n, 1, s.z0, s.zd0, s0,
                         np.ascontiguousarray(d0[:, 0]), np.ascontiguousarray(d0[:, 1]),
                         col_term, col_slot, col_global, z, dz)
        return z, dz

    workers = min(len(setups), max(numba.get_num_threads(), 1))
    if workers <= 1:
        return [one(k) for k in range(len(setups))]
    with ThreadPoolExecutor(workers) as pool:  # simulate_tangent releases the GIL
        return list(pool.map(one, range(len(setups))))
