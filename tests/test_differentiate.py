"""Each differentiation method against exact derivatives, at an optical sensor's noise.

Signal: profile C's table motion (peaks 2.18 m/s, 56 m/s², the sharpest of the
three), 1 kHz, white noise 25.4 µm. Limits are 1.3× the RMS errors measured on
seeds 0–2 (away from 50 samples at each end), e.g. butter: v 1.5–1.6 mm/s,
a 0.47–0.50 m/s²; spline a 0.90–0.93 m/s² (its Cp rule picks a higher cutoff).
"""

from __future__ import annotations

import numpy as np
import pytest

from analysis.signals.differentiate import METHODS, differentiate, estimate_noise
from rig.profile import load_profile

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

SIGMA = 2.54e-5
LIMITS = {"savgol": (2.6e-3, 0.73), "butter": (2.1e-3, 0.65), "spline": (2.8e-3, 1.21),
          "rts": (2.2e-3, 0.68)}  # m/s, m/s²


@pytest.fixture(scope="module")
def signal():
    motion = load_profile("C").motion()
    t = np.arange(3001) * 1e-3
    exact = motion(t), motion.derivative()(t), motion.derivative(2)(t)
    noisy = exact[0] + SIGMA * np.random.default_rng(7).standard_normal(t.size)
    return noisy, exact


@pytest.mark.parametrize("method", METHODS)
def test_error_within_limits(signal, method: str) -> None:
    y, (x, v, a) = signal
    d = differentiate(y, 1e-3, method)
    inner = slice(50, -50)
    assert np.sqrt(np.mean((d.v - v)[inner] ** 2)) < LIMITS[method][0]
    assert np.sqrt(np.mean((d.a - a)[inner] ** 2)) < LIMITS[method][1]
    assert np.sqrt(np.mean((d.x - x) ** 2)) < 0.5 * SIGMA  # smoothing removes most noise
    assert d.method == method and d.settings["cutoff_hz"] > 0


def test_auto_is_butter_and_settings_repeat_exactly(signal) -> None:
    y, _ = signal
    d = differentiate(y, 1e-3)
    assert d.method == "butter" and d.settings["requested"] == "auto"
    again = differentiate(y, 1e-3, "butter", settings={"cutoff_hz": d.settings["cutoff_hz"]})
    np.testing.assert_array_equal(again.a, d.a)


def test_noise_estimate(signal) -> None:
    y, _ = signal
    assert estimate_noise(y, 1e-3) == pytest.approx(SIGMA, rel=0.1)
    # a quantised noise-free ramp: third differences are mostly 0, the floor is step/√12
    steps = np.round(np.linspace(0, 1e-3, 500) / 1e-6) * 1e-6
    assert 0 < estimate_noise(steps, 1e-3) <= 2e-6 / np.sqrt(12)


@pytest.mark.parametrize(("x", "dt", "message"), [
    (np.ones(5), 1e-3, "at least"), (np.r_[np.zeros(20), np.nan], 1e-3, "not finite"),
    (np.zeros(20), 0.0, "dt must be"),
])
def test_bad_input(x, dt, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        differentiate(x, dt)


def test_unknown_method() -> None:
    with pytest.raises(ValueError, match="unknown method 'fft'"):
        differentiate(np.zeros(50), 1e-3, "fft")
