"""Compiled hybrid RK4 integrator of the isolator model (numba).

State y = [z, ż, s_0 … s_{J-1}] (relative coordinates, one internal-state slot
per term). Three discrete modes are carried alongside and held fixed within a
step, so that RK4 always integrates a smooth right-hand side:

- `stuck`: static friction holds (ż ≡ 0, ẍ = ü);
- `outside`: |z| > δ, the gated terms act;
- the signs sz, szd that sgn(z), sgn(ż) terms use.

A mode changes only at an *event*: a step that ends with an event function
below zero is redone to the event's time, found by Illinois regula falsi on
the step length (each trial is a fresh RK4 step of the frozen-mode system), the
mode switches there and the rest of the step follows. This keeps fourth-order
convergence through dead-band entries, zero crossings and stick/slip, instead
of the first order a grid-aligned switch would give.

Base motion u(t) is a piecewise polynomial (scipy PPoly layout: `breaks` (K+1,),
`coefs` (degree+1, K)), held constant outside its breaks; analytic profiles are
exact in it and measured tables are a cubic spline.

The integrator stays one module, past the house's ~300 lines: its njit functions
call and inline into one another, and numba's cache (cache=True) is checked
against the source file of each compiled function only, so a callee edited in
another module would leave its callers' cached machine code stale.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from analysis.model.isolator import (
    N_GLOBAL,
    P_BREAKAWAY,
    P_DEAD_BAND,
    P_MASS,
    P_STOP_VELOCITY,
    TERM_WIDTH,
)
from analysis.model.terms import COULOMB, PRELOAD, basis, state_rate

MAX_EVENTS_PER_STEP = 16
ROOT_ITERATIONS = 60
LAND_PIECE = 4.0  # steps: a motion whose pieces are longer on average is stepped break to break
# of ε: the ε band's exit sits this far outside its entry. The located stop event leaves
# |ż| = ε to the last bit about as often as just inside it, and ε − |ż| = 0 does not arm
# the exit: the step then ran across the band in one RK4 step, where c2 tanh(βż) turns
# over (run B's return: x 11 µm off the converged solution; the step split at the exit,
# 1 µm). Which of the two happened flipped with the last bits of any constant: the
# breakaway force's cost had dips of 28 χ² at one value in ten (one campaign in 20 freed
# it at a third of the rig's).
LEAVE_MARGIN = 1e-9

# numba caches this module's compiled code against this file alone, and terms.basis
# and terms.state_rate are compiled into it: a change to them (the Bouc–Wen exponent)
# bumps this, or a cached kernel runs the old formula
TERMS_REVISION = 4

# numba's private switch (numba's own tests and its maintainers' benchmarks use it) for
# code that allocates nothing: no reference counts taken on the arrays it is handed
NO_REFCOUNT = {"_nrt": False}

# event slots
EV_BAND, EV_Z0, EV_ZD0, EV_STOP, EV_BREAKAWAY, EV_GRIP, EV_LEAVE = range(7)
N_EVENTS = 7


@njit(cache=True, inline="always")
def base_motion(breaks, coefs, t):
    """u, u̇, ü at time t from a piecewise polynomial held constant outside its breaks."""
    n = breaks.shape[0] - 1
    deg = coefs.shape[0] - 1
    if t <= breaks[0]:
        i = 0
        x = 0.0
        hold = True
    elif t >= breaks[n]:
        i = n - 1
        x = breaks[n] - breaks[n - 1]
        hold = True
    else:
        # a sampled table motion has a break at every sample, evenly spaced: the piece is
        # where t puts it, or one beside it (rounding); bisecting its thousands of breaks
        # at every RK4 stage took 11 % of a simulation. Any other profile (a few fitted
        # ramps) is bisected. Either way i is the one piece with
        # breaks[i] <= t < breaks[i + 1]: the same piece, so the same numbers, bit for bit
        i = int((t - breaks[0]) * (n / (breaks[n] - breaks[0])))
        i = min(max(i, 0), n - 1)
        if not (breaks[i] <= t < breaks[i + 1]):
            if i > 0 and breaks[i - 1] <= t < breaks[i]:
                i -= 1
            elif i < n - 1 and breaks[i + 1] <= t < breaks[i + 2]:
                i += 1
            else:
                lo = 0
                hi = n
                while hi - lo > 1:
                    mid = (lo + hi) // 2
                    if t >= breaks[mid]:
                        lo = mid
                    else:
                        hi = mid
                i = lo
        x = t - breaks[i]
        hold = False
    u = 0.0
    v = 0.0
    a = 0.0
    for m in range(deg + 1):  # Horner for the value and two derivatives
        a = a * x + 2.0 * v
        v = v * x + u
        u = u * x + coefs[m, i]
    if hold:
        return u, 0.0, 0.0
    return u, v, a


# term_forces, required_force, rhs and _slip_direction are inlined where they are called:
# a call per RK4 stage handing on a dozen arrays took a fifth of a simulation. rk4_step
# and event_values stay calls: inlined at their many call sites too, numba took over
# two minutes to compile the kernel (40 s as it is) for 5 % more, or was slower.
# rk4_step, event_values and simulate_one allocate nothing and are compiled without
# numba's reference counting (NO_REFCOUNT): with it, every call took and released each
# array it was handed, an atomic operation each that numba's pruning pass cannot remove
# across branches (numba issue 2350), and those were a third of a simulation (perf: 37 %
# of the samples on two instructions). Without: 3.42 -> 2.09 ms per row of a 4.7 s run,
# the same numbers to the last bit.
@njit(cache=True, inline="always")
def term_forces(kinds, gated, p, z, zd, sz, szd, outside, y, out):
    """Fill out[j] with each term's force (N); return their sum."""
    total = 0.0
    for j in range(kinds.shape[0]):
        o = N_GLOBAL + TERM_WIDTH * j
        if (gated[j] and not outside) or p[o] == 0.0:
            f = 0.0
        else:
            f = p[o] * basis(kinds[j], z, zd, sz, szd, y[2 + j], p[o + 1], p[o + 2], p[o + 3])
        out[j] = f
        total += f
    return total


@njit(cache=True, inline="always")
def required_force(kinds, gated, p, y, sz, outside, ua, scratch):
    """Force static friction must supply to keep ż = 0 (N): m ü + F(z, 0)."""
    return p[P_MASS] * ua + term_forces(kinds, gated, p, y[0], 0.0, sz, 0.0, outside, y, scratch)


@njit(cache=True, inline="always")
def rhs(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd, dy, scratch):
    """dy/dt for the frozen modes; returns ẍ (m/s²)."""
    ua = base_motion(breaks, coefs, t)[2]
    z = y[0]
    zd = 0.0 if stuck else y[1]
    for j in range(kinds.shape[0]):
        o = N_GLOBAL + TERM_WIDTH * j
        dy[2 + j] = state_rate(kinds[j], z, zd, y[2 + j], p[o], p[o + 1], p[o + 2], p[o + 3])
    if stuck:
        dy[0] = 0.0
        dy[1] = 0.0
        return ua
    f = term_forces(kinds, gated, p, z, zd, sz, szd, outside, y, scratch)
    xdd = -f / p[P_MASS]
    dy[0] = zd
    dy[1] = xdd - ua
    return xdd


@njit(cache=True, **NO_REFCOUNT)
def rk4_step(kinds, gated, p, breaks, coefs, t, y, h, stuck, outside, sz, szd,
             out, k1, k2, k3, k4, tmp, scratch, k1_ready=False):
    """One classical RK4 step of length h with the modes frozen; result in `out`.

    k1_ready: k1 already holds dy/dt at (t, y) for these modes (a sample's recorded
    rate, or an earlier trial step from the same point while an event is located).
    """
    n = y.shape[0]
    if not k1_ready:
        rhs(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd, k1, scratch)
    for i in range(n):
        tmp[i] = y[i] + 0.5 * h * k1[i]
    rhs(kinds, gated, p, breaks, coefs, t + 0.5 * h, tmp, stuck, outside, sz, szd, k2, scratch)
    for i in range(n):
        tmp[i] = y[i] + 0.5 * h * k2[i]
    rhs(kinds, gated, p, breaks, coefs, t + 0.5 * h, tmp, stuck, outside, sz, szd, k3, scratch)
    for i in range(n):
        tmp[i] = y[i] + h * k3[i]
    rhs(kinds, gated, p, breaks, coefs, t + h, tmp, stuck, outside, sz, szd, k4, scratch)
    for i in range(n):
        out[i] = y[i] + h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])


@njit(cache=True, **NO_REFCOUNT)
def event_values(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd, direction,
                 uses_sz, uses_szd, g, scratch):
    """Event functions at (t, y) for the current modes; an event is armed while g > 0.

    `direction` is sgn(ż) at the step start, or 0 when |ż| ≤ ε then (the stop
    event is armed only once the motion has left the ε band).
    """
    for i in range(N_EVENTS):
        g[i] = math.inf
    delta = p[P_DEAD_BAND]
    friction = p[P_BREAKAWAY] > 0.0
    if stuck:
        if friction:
            ua = base_motion(breaks, coefs, t)[2]
            g[EV_BREAKAWAY] = p[P_BREAKAWAY] - abs(
                required_force(kinds, gated, p, y, sz, outside, ua, scratch))
        return
    if delta > 0.0:
        g[EV_BAND] = abs(y[0]) - delta if outside else delta - abs(y[0])
    if uses_sz and sz != 0.0:
        g[EV_Z0] = sz * y[0]
    if uses_szd and szd != 0.0:
        g[EV_ZD0] = szd * y[1]
    if friction and direction != 0.0:
        g[EV_STOP] = direction * y[1] - p[P_STOP_VELOCITY]
    elif friction:
        # slow and slipping (|ż| ≤ ε, the stop event not armed): static friction grips
        # as soon as the force falls within breakaway, unless |ż| leaves the band first
        ua = base_motion(breaks, coefs, t)[2]
        g[EV_GRIP] = abs(required_force(kinds, gated, p, y, sz, outside, ua, scratch)) - p[
            P_BREAKAWAY]
        g[EV_LEAVE] = p[P_STOP_VELOCITY] * (1.0 + LEAVE_MARGIN) - abs(y[1])


@njit(cache=True, inline="always")
def _slip_direction(kinds, gated, p, breaks, coefs, t, y, sz, outside, scratch):
    """sgn(ż) a held mass starts slipping with, or 0 while static friction can hold it.

    The force it must transmit beyond breakaway pushes it the other way.
    """
    ua = base_motion(breaks, coefs, t)[2]
    freq = required_force(kinds, gated, p, y, sz, outside, ua, scratch)
    return -_sign(freq) if abs(freq) > p[P_BREAKAWAY] else 0.0


@njit(cache=True, inline="always")
def _sign(x):
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


@njit(cache=True)
def workspace(n_terms):
    """The arrays one `simulate_one` works in: (state rows (9, 2 + J), scratch (J or 1,),
    event rows (3, N_EVENTS)), zeroed."""
    return (np.zeros((9, 2 + n_terms)), np.zeros(max(n_terms, 1)),
            np.zeros((3, N_EVENTS)))


# allocates nothing (its caller hands it a `workspace`): no reference counting, as rk4_step
@njit(cache=True, **NO_REFCOUNT)
def simulate_one(kinds, gated, p, breaks, coefs, t0, dt, n_out, substeps, z0, zd0, s0,
                 out_z, out_zd, out_xdd, out_f, out_s, out_stuck, work, scratch, events):
    """Integrate one parameter set; write n_out samples spaced dt from t0.

    out_f (J+1, n_out): each term's force and, last, the static-friction force;
    out_s (J, n_out): internal states; out_stuck (n_out,): 1 while stuck.
    These three are written only when out_stuck has room for the samples (a batch
    hands empty ones). work, scratch, events: a `workspace(J)`.
    Returns the RK4 steps it took, an event's trial steps included.
    """
    # whether to record follows from the arrays, not from a flag: a literal False from
    # simulate_jobs and a bool from Python are two numba signatures, each compiled in full
    # (70-100 s cold on a 2-core machine), where the batch and the recorded run share one
    record = out_stuck.shape[0] >= n_out
    nt = kinds.shape[0]
    n = 2 + nt
    y, y1, ytry = work[0], work[1], work[2]
    k1, k2, k3, k4 = work[3], work[4], work[5], work[6]
    tmp, dy = work[7], work[8]
    g0, g1, gt = events[0], events[1], events[2]

    uses_sz = False
    uses_szd = False
    for j in range(nt):  # a sign switch matters only where its term has a force
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
    for j in range(nt):  # internal states start where the caller says (a warm fluid, …)
        y[2 + j] = s0[j]
    outside = (abs(z0) > delta) if delta > 0.0 else True
    sz = _sign(z0)
    szd = _sign(zd0)
    stuck = False
    if friction and zd0 == 0.0:
        ua = base_motion(breaks, coefs, t0)[2]
        stuck = abs(required_force(kinds, gated, p, y, sz, outside, ua, scratch)) <= fbreak

    h = dt / substeps
    # a fitted profile (a few ramps, pieces many steps long) is stepped break to break, and
    # a piece shorter than LAND_PIECE steps is crossed in that many: a ramp shorter than
    # a step falls between RK4's stages otherwise (a 0.7 ms tail ramp of a lagged table,
    # ±1800 m/s², kicked ż by 0.9 m/s and left run C 900 x noise off at the true
    # constants; landed on but crossed in one step, 96 µm). A sampled spline's knots are
    # about a step apart and C², and landing on them would double the work for nothing.
    nb = breaks.shape[0]
    land = nb > 1 and breaks[nb - 1] - breaks[0] > LAND_PIECE * h * (nb - 1)
    ib = 0  # the first break after t, where landing
    t = t0
    steps = 0  # RK4 steps taken, trial steps of an event's location included: the work done
    recorded = False  # dy holds the rate at the last recorded sample (t_rec and modes)
    t_rec = t0
    zd_rec = 0.0
    stuck_rec = False
    outside_rec = False
    sz_rec = 0.0
    szd_rec = 0.0
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
                        # a piece shorter than LAND_PIECE steps: that many across it
                        if 0 < ib < nb:
                            t_stop = min(t_stop, t + (breaks[ib] - breaks[ib - 1]) / LAND_PIECE)
                    hrem = t_stop - t
                    # a dead-band mode the state contradicts (|z| < δ yet "outside"): an
                    # exit missed because the entry left z exactly on the edge, where the
                    # exit's event function is not armed (g = 0). Where the spring's jump
                    # at the edge pushes back harder than the other forces push out, the
                    # mass slides along the edge (a Filippov sliding mode); re-deriving the
                    # mode each step keeps it there instead of leaving the springs on
                    # inside the band.
                    if delta > 0.0 and outside and abs(y[0]) < delta:
                        outside = False
                    elif delta > 0.0 and not outside and abs(y[0]) > delta:
                        outside = True
                    # the same for static friction: a mass held while the force it needs
                    # already exceeds breakaway lets go now. The breakaway event can be
                    # lost when it falls microseconds after a break of the table's
                    # polynomial (a ramp's start); measured: the mass then rode the
                    # table through a whole ramp with 49 kN of "static friction".
                    if stuck and friction:
                        slip = _slip_direction(kinds, gated, p, breaks, coefs, t, y, sz,
                                               outside, scratch)
                        if slip != 0.0:
                            stuck = False
                            szd = slip
                    # signs start when the motion does: a state at rest has no sign yet
                    if sz == 0.0 and y[0] != 0.0:
                        sz = _sign(y[0])
                    if not stuck and szd == 0.0 and y[1] != 0.0:
                        szd = _sign(y[1])
                    direction = 0.0
                    if not stuck and friction:
                        if abs(y[1]) > eps:
                            direction = _sign(y[1])
                        else:
                            # inside the ε band and not armed: stick as soon as the force allows
                            ua = base_motion(breaks, coefs, t)[2]
                            if abs(required_force(kinds, gated, p, y, sz, outside, ua,
                                                  scratch)) <= fbreak:
                                stuck = True
                                y[1] = 0.0
                    event_values(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd,
                                 direction, uses_sz, uses_szd, g0, scratch)
                    # the rate recorded with the sample is this step's first stage when
                    # nothing has changed since: same time, state and modes
                    if (recorded and t == t_rec and y[1] == zd_rec and stuck == stuck_rec
                            and outside == outside_rec and sz == sz_rec and szd == szd_rec):
                        for i in range(n):
                            k1[i] = dy[i]
                    else:
                        rhs(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd, k1,
                            scratch)
                    recorded = False
                    steps += 1
                    rk4_step(kinds, gated, p, breaks, coefs, t, y, hrem, stuck, outside, sz, szd,
                             y1, k1, k2, k3, k4, tmp, scratch, True)
                    event_values(kinds, gated, p, breaks, coefs, t + hrem, y1, stuck, outside,
                                 sz, szd, direction, uses_sz, uses_szd, g1, scratch)
                    fired = False
                    for i in range(N_EVENTS):
                        if g0[i] > 0.0 and g1[i] <= 0.0:
                            fired = True
                    if not fired or nev >= MAX_EVENTS_PER_STEP:
                        for i in range(n):
                            y[i] = y1[i]
                        t = t_stop
                        if fired:  # too many switches in one step: re-derive modes from the state
                            outside = (abs(y[0]) > delta) if delta > 0.0 else True
                            sz = _sign(y[0])
                            szd = _sign(y[1])
                        continue  # to t_end, or on from a break landed on
                    # earliest event: Illinois regula falsi on the fraction θ of the step
                    theta_best = 1.0
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
                            steps += 1
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
                        theta_best = min(theta_best, hi)
                    # step to just past the event, then switch every mode whose event has fired
                    hs = theta_best * hrem
                    steps += 1
                    rk4_step(kinds, gated, p, breaks, coefs, t, y, hs, stuck, outside, sz, szd,
                             ytry, k1, k2, k3, k4, tmp, scratch, True)
                    t = t + hs
                    for i in range(n):
                        y[i] = ytry[i]
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
                        szd = -_sign(freq)  # the mass slips the way the unbalanced force pushes
                    elif g0[EV_GRIP] > 0.0 and gt[EV_GRIP] <= 0.0:
                        stuck = True
                        y[1] = 0.0
                    elif g0[EV_STOP] > 0.0 and gt[EV_STOP] <= 0.0:
                        ua = base_motion(breaks, coefs, t)[2]
                        if abs(required_force(kinds, gated, p, y, sz, outside, ua,
                                              scratch)) <= fbreak:
                            stuck = True
                            y[1] = 0.0
            t = t0 + k * dt  # snap to the output grid: no drift from summing h
        if stuck and friction:  # as at a step's start: never record a held mass past breakaway
            slip = _slip_direction(kinds, gated, p, breaks, coefs, t, y, sz, outside, scratch)
            if slip != 0.0:
                stuck = False
                szd = slip
        # record the sample at t
        xdd = rhs(kinds, gated, p, breaks, coefs, t, y, stuck, outside, sz, szd, dy, scratch)
        recorded = True
        t_rec = t
        zd_rec = y[1]
        stuck_rec = stuck
        outside_rec = outside
        sz_rec = sz
        szd_rec = szd
        out_z[k] = y[0]
        out_zd[k] = 0.0 if stuck else y[1]
        out_xdd[k] = xdd
        if record:
            record_sample(kinds, gated, p, breaks, coefs, t, y, k, out_zd[k], stuck, outside,
                          sz, szd, out_f, out_s, out_stuck, scratch)
    return steps


# a call, not inlined: inlined behind a flag known only at run time, this made every
# simulation of a batch (which records nothing) 5-8 % slower
@njit(cache=True, **NO_REFCOUNT)
def record_sample(kinds, gated, p, breaks, coefs, t, y, k, zd, stuck, outside, sz, szd,
                  out_f, out_s, out_stuck, scratch):
    """Column k of out_f (each term's force, then static friction's), out_s and out_stuck."""
    nt = kinds.shape[0]
    ftot = term_forces(kinds, gated, p, y[0], zd, sz, 0.0 if stuck else szd, outside, y,
                       scratch)
    for j in range(nt):
        out_f[j, k] = scratch[j]
        out_s[j, k] = y[2 + j]
    if stuck:
        ua = base_motion(breaks, coefs, t)[2]
        out_f[nt, k] = -(p[P_MASS] * ua + ftot)
    else:
        out_f[nt, k] = 0.0
    out_stuck[k] = 1.0 if stuck else 0.0


@njit(cache=True, parallel=True)
def simulate_jobs(kinds, gated, P, job_run, breaks, n_breaks, coefs, t0, dt, n_out, substeps,
                  z0, zd0, S0, out_z, out_zd, out_xdd, out_steps):
    """simulate_one for each job in parallel: parameter row P[r] on run job_run[r].

    Runs differ in table motion (row m of `breaks` (M, B) and `coefs` (M, deg+1, B−1),
    the first n_breaks[m] breaks used; a lower degree padded with leading zeros,
    which Horner's rule carries as exact zeros), start time, step, length and
    start state. One call spreads every run's rows over the cores, where a
    batch per run leaves a core idle whenever its row count is odd.
    out_steps[r]: the RK4 steps row r took (`simulate_one`).
    """
    nt = kinds.shape[0]
    for r in prange(P.shape[0]):
        m = job_run[r]
        nb = n_breaks[m]
        f = np.empty((nt + 1, 0))
        s = np.empty((nt, 0))
        st = np.empty(0)
        work, scratch, events = workspace(nt)
        # a strided view (numba's layout "A"), which `simulate` hands over too: another
        # layout would be another full compile of simulate_one, and a contiguous copy per
        # row made every simulation 8 % slower (a fresh mapping of its pages each time)
        out_steps[r] = simulate_one(kinds, gated, P[r], breaks[m, :nb], coefs[m, :, :nb - 1],
                                    t0[m], dt[m], n_out[m], substeps, z0[m], zd0[m], S0[r],
                                    out_z[r], out_zd[r], out_xdd[r], f, s, st, work, scratch,
                                    events)
