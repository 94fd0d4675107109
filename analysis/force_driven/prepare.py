"""From a measured force and position to the regression's rows: derivatives, then decimation.

This is the inverse-dynamic-model procedure of the EMPS benchmark (Janot, Gautier
& Brunot 2019, reference script Script_IDIM_LS.m), kept step for step so that its
published figures can be reproduced exactly:

1. the position is low-passed by a 4th-order Butterworth run forwards and
   backwards (MATLAB `butter` + `filtfilt`, edge padding 3·(filter length − 1));
2. velocity and acceleration by central differences (`diffcent`, twice), and
   the first 49 samples dropped (their `n_border = 50`, 1-based);
3. every regressor column is computed at the full rate (sgn q̇ included), then
   each column and the force are low-passed by the same zero-phase Chebyshev I
   (order 8, 0.05 dB, cutoff 0.8 × the new Nyquist) and decimated (MATLAB
   `decimate`, which keeps the last sample). Filtering both sides of a force
   balance by one linear filter keeps it a force balance ("parallel
   filtering"): the high band, where the model is not meant to hold and the
   differentiated noise lives, is removed from both.

Central differences are biased at high frequency (the second derivative's gain
is (sin ωΔt / ωΔt)²): −2 % at fs/25. For records sampled close to their band
(Silverbox: 610 Hz with content to 200 Hz) the derivatives are taken in the
frequency domain instead (`spectral`): the even-extended record's FFT times
(iω)ᵏ and the same Butterworth's zero-phase magnitude, exact within the band;
its ends, where the extension bends the derivative, are dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from analysis.force_driven.loading import ForceRecord
from analysis.force_driven.model import term
from rig.errors import DataError

BUTTER_ORDER = 4
CHEBY = (8, 0.05)  # MATLAB decimate's default IIR: order, passband ripple (dB)
CHEBY_EDGE = 0.8  # its cutoff, as a share of the new Nyquist frequency
BORDER = 49  # samples dropped at the start after central differences (the EMPS script)
SPECTRAL_BORDER = 3.0  # cycles of the cutoff dropped at each end of a spectral derivative
CENTRAL_BAND = 1 / 25  # central differences only if the kept band is below fs/25
METHODS = ("auto", "central", "spectral")


@dataclass(frozen=True)
class Settings:
    """How a record was prepared; `cutoff_hz` is the Butterworth's, `factor` the decimation's.

    `band_hz` is the band the regression's rows keep, 0 to `band_hz`: the force error is
    measured there, so errors from preparations with different bands do not compare.
    """

    cutoff_hz: float
    factor: int
    method: str  # central or spectral
    band_hz: float

    def as_dict(self) -> dict[str, object]:
        return {"cutoff_hz": self.cutoff_hz, "decimation": self.factor,
                "derivatives": self.method, "band_hz": self.band_hz}


@dataclass
class Prepared:
    """A record ready for regression: full-rate states and force, columns decimated on demand."""

    record: ForceRecord
    settings: Settings
    q: np.ndarray  # filtered position, m (full rate, border dropped)
    qd: np.ndarray  # m/s
    qdd: np.ndarray  # m/s²
    force: np.ndarray  # measured, N (full rate, border dropped)
    start: int  # index of q[0] in the record
    _columns: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def name(self) -> str:
        return self.record.name

    def column(self, name: str) -> np.ndarray:
        """The term's regressor, low-passed and decimated like the force."""
        if name not in self._columns:
            self._columns[name] = decimate(term(name).regressor(self.q, self.qd, self.qdd),
                                           self.settings.factor)
        return self._columns[name]

    @property
    def y(self) -> np.ndarray:
        """The measured force, low-passed and decimated, N."""
        if "__force" not in self._columns:
            self._columns["__force"] = decimate(self.force, self.settings.factor)
        return self._columns["__force"]

    @property
    def rows(self) -> int:
        return self.y.size

    def record_index(self, row: int) -> int:
        """Index in the record of decimated row `row` (decimation keeps the last sample)."""
        r, n = self.settings.factor, self.q.size
        return self.start + (r - (r * -(-n // r) - n) - 1) + row * r


def prepare(record: ForceRecord, cutoff_hz: float | None = None, factor: int | None = None,
            method: str = "auto") -> Prepared:
    """Derivatives and decimation for `record`; defaults from the data (see `choose`)."""
    settings = choose(record, cutoff_hz, factor, method)
    if settings.method == "central":
        q, qd, qdd = central_derivatives(record.position, record.dt, settings.cutoff_hz)
        start, stop = BORDER, record.t.size
    else:
        q, qd, qdd = spectral_derivatives(record.position, record.dt, settings.cutoff_hz)
        border = int(np.ceil(SPECTRAL_BORDER / (settings.cutoff_hz * record.dt)))
        start, stop = border, record.t.size - border
    force = record.force
    if settings.method == "spectral":
        # no decimation filter follows at factor 1: low-pass the force by the same gain as
        # the position, so both sides of the balance carry one filter (parallel filtering)
        force = spectral_derivatives(force, record.dt, settings.cutoff_hz, orders=1)[0]
    s = slice(start, stop)
    if stop - start < 4 * max(settings.factor, 1) * CHEBY[0]:
        raise DataError(f"{record.path}: {stop - start} samples left after the filter "
                        "edges, too few to decimate")
    return Prepared(record, settings, q[s], qd[s], qdd[s], force[s], start)


def choose(record: ForceRecord, cutoff_hz: float | None, factor: int | None,
           method: str) -> Settings:
    """Fill in what was not given.

    The cutoff defaults to the one analysis.signals.differentiate chooses for the position
    (Mallows' Cp): about where the position's spectrum meets its noise floor. The decimation
    keeps 0.4 × the cutoff, the IDIM-LS ratio (Butterworth at 5 × the bandwidth of the
    dynamics, decimated to keep 2 × it). The EMPS recipe takes that bandwidth from its
    controller (20 Hz: 100 Hz, decimation 10); a force and a position alone do not show it,
    and no rule read off them (noise floor, power percentiles of q̈ or F) lands there
    without a constant tuned to land there (docs/datasets.md). So the band differs from a
    recipe's, and with it the force error: `Settings.band_hz` says which band it is.
    """
    if method not in METHODS:
        raise DataError(f"unknown derivative method {method!r} (known: {', '.join(METHODS)})")
    fs = 1.0 / record.dt
    if cutoff_hz is None:
        from analysis.signals.differentiate import differentiate

        cutoff_hz = float(differentiate(record.position, record.dt, "butter").settings["cutoff_hz"])
    if not (np.isfinite(cutoff_hz) and 0 < cutoff_hz < fs / 2):
        raise DataError(f"{record.path}: cutoff {cutoff_hz} Hz must be between 0 and the "
                        f"Nyquist frequency {fs / 2:.6g} Hz")
    if factor is None:
        factor = max(1, int(np.floor(CHEBY_EDGE * (fs / 2) / (0.4 * cutoff_hz))))
    if factor < 1:
        raise DataError(f"decimation factor must be >= 1, got {factor}")
    band = CHEBY_EDGE * (fs / 2) / factor if factor > 1 else min(cutoff_hz, fs / 2)
    if method == "auto":
        method = "central" if band <= CENTRAL_BAND * fs * (1 + 1e-9) else "spectral"
    return Settings(float(cutoff_hz), int(factor), method, kept_band(fs, cutoff_hz, factor, method))


def kept_band(fs: float, cutoff_hz: float, factor: int, method: str) -> float:
    """The upper edge (Hz) of what the force keeps: the decimation filter's cutoff, or the
    Nyquist frequency without one; spectral preparation also low-passes the force by the
    Butterworth (its half-amplitude point)."""
    band = CHEBY_EDGE * (fs / 2) / factor if factor > 1 else fs / 2
    return float(min(band, cutoff_hz) if method == "spectral" else band)


def central_derivatives(x: np.ndarray, dt: float, cutoff_hz: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EMPS's filtfilt(butter) then diffcent twice: x, ẋ, ẍ at the full rate."""
    b, a = signal.butter(BUTTER_ORDER, cutoff_hz * 2 * dt)
    xf = signal.filtfilt(b, a, x, padlen=3 * (max(len(a), len(b)) - 1))
    v = _diffcent(xf, dt)
    return xf, v, _diffcent(v, dt)


def _diffcent(y: np.ndarray, dt: float) -> np.ndarray:
    # central inside, one-sided at the two ends (M. Gautier's diffcent.m)
    return np.gradient(y, dt, edge_order=1)


def spectral_derivatives(x: np.ndarray, dt: float, cutoff_hz: float, orders: int = 3
                         ) -> list[np.ndarray]:
    """x, ẋ, ẍ from the even-extended FFT with the zero-phase Butterworth magnitude."""
    n = x.size
    ext = np.concatenate([x, x[::-1]])
    spectrum = np.fft.rfft(ext)
    f = np.fft.rfftfreq(ext.size, dt)
    gain = 1.0 / (1.0 + (f / cutoff_hz) ** (2 * BUTTER_ORDER))  # |H|² of filtfilt(butter)
    jw = 2j * np.pi * f
    if ext.size % 2 == 0:
        jw[-1] = 0.0  # the Nyquist bin has no defined derivative sign
    return [np.fft.irfft(spectrum * gain * jw**k, ext.size)[:n] for k in range(orders)]


def decimate(x: np.ndarray, factor: int) -> np.ndarray:
    """MATLAB `decimate(x, r)`: Chebyshev I zero-phase low-pass, then every r-th sample,
    aligned so that the last sample is kept."""
    if factor == 1:
        return np.asarray(x, float)
    b, a = signal.cheby1(CHEBY[0], CHEBY[1], CHEBY_EDGE / factor)
    y = signal.filtfilt(b, a, x, padlen=3 * (max(len(a), len(b)) - 1))
    n = x.size
    first = factor - (factor * int(np.ceil(n / factor)) - n) - 1
    return y[first::factor]
