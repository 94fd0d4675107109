"""A device clock mapped onto host time: host ≈ offset + rate × device, from arrival times.

Every sample carries the device's own timestamp; the rig notes when it arrived
(host time). Arrival = sample time + delivery latency, and latency is never
negative but has a long tail (a busy core delays a frame by up to 100+ ms), so
the fit uses only the *fastest* deliveries:

- per `window_s` of device time keep the one sample with the smallest
  arrival − device time (the lower envelope);
- the line is the edge of their lower convex hull that spans the mean device
  time: of all lines under every sample, the one closest to them on average
  (the linear-programming skew estimate of Moon, Skelly & Towsley, 1999).
  Until `min_span_s` of device time is seen the rate is taken as exactly 1
  (40 ppm over 2 s is 80 µs) and the line touches the fastest sample.

A least-squares fit through all samples would be late by the mean latency and
tilted by any backlog (a starved sender catching up); the hull uses only the
fastest deliveries, so it is late only by the smallest latency seen.
Memory and refit cost grow with the run's duration / window_s, not its samples.
See docs/time_alignment.md for the measured error.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

WRAP_US = 1 << 32


@dataclass(frozen=True)
class ClockModel:
    """host = offset + rate × device (s); `samples` pairs behind it; `residual_rms` s."""

    offset: float
    rate: float
    samples: int
    residual_rms: float

    def to_host(self, device_s: float) -> float:
        return self.offset + self.rate * device_s


class ClockFit:
    """Accumulates (device s, host arrival s) pairs and keeps the current `model`."""

    def __init__(self, window_s: float = 0.1, min_span_s: float = 2.0,
                 refit_every: int = 100) -> None:
        self._window, self._min_span, self._refit_every = window_s, min_span_s, refit_every
        self._d: list[float] = []  # per window: device time of the fastest sample
        self._h: list[float] = []  # and its arrival
        self._wins: list[int] = []  # window index of each entry
        self._d0: float | None = None
        self._n = 0
        self._last_us: int | None = None
        self._wraps = 0
        self.model = ClockModel(0.0, 1.0, 0, 0.0)

    def device_seconds(self, timestamp_us: int) -> float:
        """A wrapping 32-bit µs timestamp as unwrapped device seconds (call in arrival order)."""
        if self._last_us is not None and timestamp_us < self._last_us - WRAP_US // 2:
            self._wraps += 1
        self._last_us = timestamp_us
        return (timestamp_us + self._wraps * WRAP_US) * 1e-6

    def add(self, device_s: float, host_s: float) -> float:
        """Record one pair; return the sample's host time on the current fit (s)."""
        if self._d0 is None:
            self._d0 = device_s
        w = int((device_s - self._d0) // self._window)
        if not self._wins or w > self._wins[-1]:  # a new window; empty windows stay out
            self._d.append(device_s)
            self._h.append(host_s)
            self._wins.append(w)
        elif w == self._wins[-1] and host_s - device_s < self._h[-1] - self._d[-1]:
            self._d[-1], self._h[-1] = device_s, host_s
        self._n += 1
        if self._n == 1 or self._n % self._refit_every == 0:
            self.refit()
        return self.model.to_host(device_s)

    def refit(self) -> ClockModel:
        """Fit the envelope so far; also returns the new model."""
        if not self._d:
            return self.model
        d0 = self._d[0]  # centre the regressor: device clocks read thousands of seconds
        d, h = np.asarray(self._d) - d0, np.asarray(self._h)
        rate = 1.0
        if d[-1] >= self._min_span and len(d) >= 5:
            rate = _hull_rate(d, h - d) + 1.0  # on latency (h − d): better conditioned
        base = float(np.min(h - rate * d))
        resid = h - (base + rate * d)
        self.model = ClockModel(base - rate * d0, rate, self._n, float(np.sqrt(np.mean(resid**2))))
        return self.model


def _hull_rate(x: np.ndarray, y: np.ndarray) -> float:
    """Slope of the lower convex hull's edge over mean(x); x increasing, (n ≥ 2,)."""
    hull: list[int] = []
    for i in range(len(x)):  # Andrew's monotone chain, lower half
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            if (x[b] - x[a]) * (y[i] - y[a]) - (y[b] - y[a]) * (x[i] - x[a]) <= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    mean = float(np.mean(x))
    for a, b in itertools.pairwise(hull):
        if x[b] >= mean:
            return float((y[b] - y[a]) / (x[b] - x[a]))
    return 0.0
