"""The isolator's hybrid model for the independent campaign generator (after CERL TR
M-226, Eq 10).

Model, in relative coordinates z = x - u (u table, x mass, both absolute)::

    m z'' = -m u'' - F(z, z')
    F = c1 z'                                                    (|z| <= delta)
    F = k1 z + k2 tanh(alpha z) + c1 z' + c2 tanh(beta z')       (|z| >  delta)

plus static friction: while stuck (z' = 0) the mass moves with the table until
|m u'' + F(z, 0)| exceeds the breakaway force F_b; sliding stops when |z'| < eps and
the force is within breakaway. At a dead-band edge the spring force jumps; a mass
resting against the edge is held there (the force is set-valued at the edge) the same
way as by friction, which keeps the integration free of chattering.

``Plant`` gives the right-hand sides of the sliding and the stuck modes, the event
functions of their transitions (dead-band entry/exit, stick, breakaway) and the
initial state; ``bench.unseen.integrate`` runs them. F and its effects' terms are in
``bench.unseen.effects``.
"""

from __future__ import annotations

from scipy.optimize import brentq

from bench.unseen import effects as _effects
from bench.unseen.motion import Profile

MASS = 2721.55  # kg (6000 lb)
# A stick event leaves the hold force on F_b to rounding, on either side of it: a held
# mass breaks away at once only past F_b (1 + BREAKAWAY_MARGIN), and the breakaway event
# looks for that threshold where the force starts on or past F_b itself
BREAKAWAY_MARGIN = 1e-7


class Plant:
    """Eq 10 with a dead band, static friction and the drawn effects.

    State y = [z, z', u_lag, T, w]: relative displacement and velocity, the lagged
    table (servo lag only), the thermal state (thermal only), Bouc-Wen w (bouc_wen only).
    """

    def __init__(self, k: dict, effects: dict[str, dict], profile: Profile):
        self.k = k
        self.e = effects
        self.p = profile
        self.m = MASS
        lag = effects.get("servo_lag")
        self.tau_lag = lag["tau"] if lag else 0.0
        self.piece = 0  # the profile piece of the current integration segment

    # table motion -------------------------------------------------------------
    def table(self, t: float, y) -> tuple[float, float, float]:
        """(u, u', u'') of the table itself (the command, or its first-order lag)."""
        if self.tau_lag:
            uc, ucd, _ = self.p(t, self.piece)
            ul = y[2]
            uld = (uc - ul) / self.tau_lag
            return ul, uld, (ucd - uld) / self.tau_lag
        return self.p(t, self.piece)

    # forces -------------------------------------------------------------------
    def spring(self, z: float) -> float:
        """Spring terms acting outside the dead band."""
        return _effects.spring(self.k, self.e, z)

    def force(self, z: float, zd: float, inside: bool, T: float, w: float) -> float:
        return _effects.force(self.k, self.e, z, zd, inside, T, w)

    # right-hand sides ----------------------------------------------------------
    def rhs_slip(self, inside: bool):
        e, m, k = self.e, self.m, self.k
        th = e.get("thermal")
        bw = e.get("bouc_wen")

        def f(t, y):
            z, zd, _, T, w = y
            _, uld, udd = self.table(t, y)
            F = self.force(z, zd, inside, T, w)
            Td = (k["c1"] * zd * zd / th["C"] - T) / th["tau_T"] if th else 0.0
            if bw:
                aw = abs(w)
                wn1 = aw ** (bw["n"] - 1.0) if aw > 0.0 else (1.0 if bw["n"] == 1.0 else 0.0)
                wd = zd - bw["beta_h"] * abs(zd) * wn1 * w - bw["gamma_h"] * zd * wn1 * aw
            else:
                wd = 0.0
            return [zd, -udd - F / m, uld, Td, wd]

        return f

    def rhs_stuck(self):
        th = self.e.get("thermal")

        def f(t, y):
            _, uld, _ = self.table(t, y)
            Td = -y[3] / th["tau_T"] if th else 0.0
            return [0.0, 0.0, uld, Td, 0.0]

        return f

    def hold_interval(self, t: float, y, edge: int, inside: bool) -> tuple[float, float]:
        """The range of the force the table must supply to hold the mass (z' = 0)."""
        z, _, _, T, w = y
        _, _, udd = self.table(t, y)
        mu = self.m * udd
        if edge:
            a = mu + self.force(z, 0.0, True, T, w)
            b = mu + self.force(z, 0.0, False, T, w)
            return (a, b) if a <= b else (b, a)
        a = mu + self.force(z, 0.0, inside, T, w)
        return a, a

    # events ------------------------------------------------------------------
    def ev_deadband(self, inside: bool):
        d = self.k["delta"]

        def g(t, y):
            return abs(y[0]) - d

        g.terminal = True
        g.direction = 1.0 if inside else -1.0
        return g

    def ev_stick(self, inside: bool):
        k, m = self.k, self.m

        def g(t, y):
            z, zd, _, T, w = y
            _, _, udd = self.table(t, y)
            return max(abs(zd) - k["eps"],
                       abs(m * udd + self.force(z, 0.0, inside, T, w)) - k["F_b"])

        g.terminal = True
        g.direction = -1.0
        return g

    def ev_breakaway(self, edge: int, inside: bool, margin: float = 0.0):
        """The hold force rising through F_b (1 + margin). The margin where the force
        starts on or past F_b: a rounding error above it, left by the stick event as a
        Bouc-Wen loop's force settled onto the threshold, made the event positive from the
        start, it never crossed, and seed 810's mass rode run C's whole second pulse held
        to the table against a 75 N breakaway. Elsewhere none, so that every other
        campaign is integrated as before to the bit."""
        fb = self.k["F_b"] * (1.0 + margin)

        def g(t, y):
            a, b = self.hold_interval(t, y, edge, inside)
            return max(a - fb, -b - fb)

        g.terminal = True
        g.direction = 1.0
        return g

    # initial state -------------------------------------------------------------
    def initial(self) -> tuple[list[float], int, bool]:
        """Rest: z = 0 unless a force offset pushes the mass to an edge or beyond."""
        d, fb = self.k["delta"], self.k["F_b"]
        F0 = self.e.get("force_offset", {}).get("F0", 0.0)
        if abs(F0) <= fb:
            return [0.0, 0.0, 0.0, 0.0, 0.0], 0, True
        sgn = -1.0 if F0 > 0 else 1.0
        z_edge = sgn * d
        if abs(self.spring(z_edge)) >= abs(F0):
            return [z_edge, 0.0, 0.0, 0.0, 0.0], int(sgn), True
        hi = z_edge
        while abs(self.spring(hi)) < abs(F0):
            hi *= 2.0
        z = brentq(lambda v: self.spring(v) + F0, z_edge, hi, xtol=1e-14)
        return [z, 0.0, 0.0, 0.0, 0.0], 0, False
