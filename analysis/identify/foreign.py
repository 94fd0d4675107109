"""Base-excited runs from other tools' measurement files: ASAM MDF (asammdf), LabVIEW TDMS (nptdms).

Channels are found by name: `channels` = (U, X) when given (`analysis fit
--channels U,X`), else `u` and `x`, else the run file's `table_u` and `mass_x` (an
MDF written by `rig export`). In TDMS a name may be GROUP/CHANNEL, and must be
when the channel is in more than one group; an MDF channel in more than one group
is refused.

Units come from the file: the MDF channel's unit, the TDMS channel's `unit_string`
property. They are converted to metres by rig.units; a unit that is not a length
there is refused, naming it. A channel without a unit takes `units` (fit's
--units), else metres, and is then marked assumed so that loading's span check
refuses a file in inches read as metres, as for CSV. A unit in the file that
disagrees with `units` is refused.

Time (s): in MDF each channel's own master; in TDMS a channel `t` or `time` of the
channel's group, else its waveform properties (wf_start_offset + k wf_increment).
When u and x do not share one time base (an MDF from `rig export` gives each
channel its own group: the sensors sample on their own clocks), both are put on
one grid at the slower channel's step over the time they share, starting on a
sample of x, as loading does for run files, and a warning says so.

asammdf and nptdms are imported only when such a file is read. Anything unusable
raises DataError naming the file and the reason.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from rig.convert.failed_open import release
from rig.errors import DataError
from rig.units import UnitError, factor, to_si

MDF_SUFFIXES = (".mf4", ".mdf")
TDMS_SUFFIXES = (".tdms",)
FOREIGN_SUFFIXES = MDF_SUFFIXES + TDMS_SUFFIXES
DEFAULT_CHANNELS = (("u", "x"), ("table_u", "mass_x"))
LENGTH_UNITS = ("m", "mm", "in", "in.", "ft")  # rig.units names of a length
TIME_CHANNELS = ("t", "time")

Series = tuple[np.ndarray, np.ndarray, str]  # time (s), values, unit as in the file


def parse_channels(text: str) -> tuple[str, str]:
    """`U,X` from the command line as (U, X); for argparse's `type=`."""
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 2 or not all(parts):
        raise argparse.ArgumentTypeError(f"give two channel names U,X, got {text!r}")
    return parts[0], parts[1]


def read_foreign(path: Path, channels: tuple[str, str] | None = None,
                 units: str | None = None, warnings: list[str] | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """t (s), u, x (m) on one time base, and whether their unit was assumed (named nowhere).

    path: a .mf4/.mdf or .tdms file. channels: (U, X) names, default module doc.
    units: the unit of channels that name none ("m", "in"); warnings gets a line
    when u and x had to be put on one grid.
    """
    path = Path(path)
    read = _mdf_series if path.suffix.lower() in MDF_SUFFIXES else _tdms_series
    (tu, u, unit_u), (tx, x, unit_x), (name_u, name_x) = read(path, channels)
    u, assumed_u = _metres(path, name_u, u, unit_u, units)
    x, assumed_x = _metres(path, name_x, x, unit_x, units)
    for name, t, v in ((name_u, tu, u), (name_x, tx, x)):
        _check(path, name, t, v)
    if tu.shape == tx.shape and np.array_equal(tu, tx):
        return tx, u, x, assumed_u and assumed_x
    t, u, x = _one_grid(path, (name_u, tu, u), (name_x, tx, x), warnings)
    return t, u, x, assumed_u and assumed_x


def _pick(path: Path, channels: tuple[str, str] | None, have: set[str], kind: str,
          hint: str = "") -> tuple[str, str]:
    """The (U, X) names to read: the given ones, else the first default pair present."""
    if channels is not None:
        missing = [c for c in channels if c not in have]
        if not missing:
            return channels
        what = f"no channel {', '.join(repr(c) for c in missing)}"
    else:
        for pair in DEFAULT_CHANNELS:
            if all(c in have for c in pair):
                return pair
        what = "no channels u and x (nor table_u and mass_x); name them with --channels U,X"
    shown = ", ".join(sorted(have)[:12]) + (" …" if len(have) > 12 else "")
    raise DataError(f"{path}: {what} (this {kind} file has: {shown or 'no channels'}){hint}")


# --- MDF -------------------------------------------------------------------------------

def _mdf_series(path: Path, channels: tuple[str, str] | None
                ) -> tuple[Series, Series, tuple[str, str]]:
    from asammdf import MDF  # heavy: imported for such files only

    try:
        mdf = MDF(path)
    except Exception as e:  # noqa: BLE001 - asammdf raises MdfException, struct, OS errors
        release(e)  # asammdf's half-built reader (rig.convert.failed_open)
        raise DataError(f"{path}: not a readable MDF file: {type(e).__name__}: {e}") from None
    try:
        have = set(mdf.channels_db)
        bus_log = any(name.startswith("CAN_DataFrame") for name in have)
        hint = "; a CAN bus log: `rig import` it with the DBC" if bus_log else ""
        names = _pick(path, channels, have, "MDF", hint)
        return _mdf_get(path, mdf, names[0]), _mdf_get(path, mdf, names[1]), names
    finally:
        mdf.close()


def _mdf_get(path: Path, mdf, name: str) -> Series:
    where = mdf.channels_db[name]
    groups = sorted({g for g, _ in where})
    if len(groups) > 1:
        raise DataError(f"{path}: channel {name!r} is in {len(groups)} channel groups "
                        f"({', '.join(map(str, groups))}); one is needed")
    group, index = where[0]
    try:
        sig = mdf.get(name, group, index)
    except Exception as e:  # noqa: BLE001 - a damaged data block: any of asammdf's errors
        raise DataError(f"{path}: channel {name!r}: {type(e).__name__}: {e}") from None
    return np.asarray(sig.timestamps, float), _numbers(path, name, sig.samples), str(sig.unit)


# --- TDMS ------------------------------------------------------------------------------

def _tdms_series(path: Path, channels: tuple[str, str] | None
                 ) -> tuple[Series, Series, tuple[str, str]]:
    from nptdms import TdmsFile  # imported for such files only

    try:
        tdms = TdmsFile.read(path)
    except Exception as e:  # noqa: BLE001 - nptdms raises ValueError, struct, OS errors
        raise DataError(f"{path}: not a readable TDMS file: {type(e).__name__}: {e}") from None
    found: dict[str, list] = {}
    for group in tdms.groups():
        for ch in group.channels():
            found.setdefault(ch.name, []).append(ch)
            found.setdefault(f"{group.name}/{ch.name}", []).append(ch)
    names = _pick(path, channels, set(found), "TDMS")
    return _tdms_get(path, tdms, found, names[0]), _tdms_get(path, tdms, found, names[1]), names


def _tdms_get(path: Path, tdms, found: dict[str, list], name: str) -> Series:
    if len(found[name]) > 1:
        groups = ", ".join(ch.group_name for ch in found[name])
        raise DataError(f"{path}: channel {name!r} is in groups {groups}; name it GROUP/{name}")
    ch = found[name][0]
    values = _numbers(path, name, ch[:])
    unit = str(ch.properties.get("unit_string", ""))
    group = tdms[ch.group_name]
    clock = next((c for c in group.channels() if c.name.lower() in TIME_CHANNELS
                  and c.name != ch.name), None)
    if clock is not None:
        t_unit = str(clock.properties.get("unit_string", "s")) or "s"
        if t_unit != "s":
            raise DataError(f"{path}: time channel {ch.group_name}/{clock.name} in {t_unit!r}, "
                            "expected s")
        t = _numbers(path, clock.name, clock[:])
    else:
        try:
            t = np.asarray(ch.time_track(), float)
        except (KeyError, ValueError) as e:
            raise DataError(f"{path}: channel {name!r} has no time: no channel "
                            f"{' or '.join(TIME_CHANNELS)} in group {ch.group_name} and no "
                            f"waveform timing ({e})") from None
    return t, values, unit


# --- shared ------------------------------------------------------------------------------

def _numbers(path: Path, name: str, values) -> np.ndarray:
    a = np.asarray(values)
    if a.ndim != 1 or a.dtype.kind not in "iuf":
        raise DataError(f"{path}: channel {name!r} holds {a.dtype} of shape {a.shape}, "
                        "not one number per sample")
    return a.astype(float)


def _metres(path: Path, name: str, values: np.ndarray, unit: str, given: str | None
            ) -> tuple[np.ndarray, bool]:
    """Values in m, and whether their unit was assumed; DataError for a unit not a length."""
    unit = unit.strip()
    if unit and given is not None and unit != given:
        raise DataError(f"{path}: channel {name!r} is in {unit} but --units says {given}")
    use = unit or given or "m"
    if use not in LENGTH_UNITS:
        try:
            factor(use)
            problem = "not a length"
        except UnitError:
            problem = "an unknown unit"
        raise DataError(f"{path}: channel {name!r} in {use!r}, {problem} (lengths known: "
                        f"{', '.join(LENGTH_UNITS)})")
    return np.asarray(to_si(values, use), float), not unit and given is None


def _check(path: Path, name: str, t: np.ndarray, v: np.ndarray) -> None:
    if t.shape != v.shape:
        raise DataError(f"{path}: channel {name!r} has {v.size} values for {t.size} times")
    bad = np.flatnonzero(~(np.isfinite(t) & np.isfinite(v)))
    if bad.size:
        raise DataError(f"{path}: channel {name!r}: sample {bad[0]} is not finite "
                        f"({bad.size} such samples)")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0])
        raise DataError(f"{path}: channel {name!r}: time does not increase at sample {k + 1} "
                        f"(t = {t[k + 1]:.6g} s after {t[k]:.6g} s)")


def _one_grid(path: Path, u: tuple[str, np.ndarray, np.ndarray],
              x: tuple[str, np.ndarray, np.ndarray], warnings: list[str] | None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u and x on one grid: the slower step, over their common span, from a sample of x."""
    (name_u, tu, vu), (name_x, tx, vx) = u, x
    if tu.size < 2 or tx.size < 2:
        raise DataError(f"{path}: {name_u} has {tu.size} samples and {name_x} {tx.size}; "
                        "need at least 2 each")
    dt = max(float(np.median(np.diff(tu))), float(np.median(np.diff(tx))))
    t0, t1 = max(tu[0], tx[0]), min(tu[-1], tx[-1])
    if t1 <= t0:
        raise DataError(f"{path}: {name_u} ({tu[0]:.6g}–{tu[-1]:.6g} s) and {name_x} "
                        f"({tx[0]:.6g}–{tx[-1]:.6g} s) do not overlap in time")
    first = int(np.searchsorted(tx, t0 - 1e-9 * dt))
    t0 = float(tx[first]) if first < tx.size and tx[first] <= t1 else t0
    t = t0 + dt * np.arange(int(np.floor((t1 - t0) / dt + 1e-9)) + 1)
    if warnings is not None:
        warnings.append(f"{path}: {name_u} ({tu.size} samples) and {name_x} ({tx.size}) have "
                        f"their own times; both interpolated onto one {dt * 1e3:.4g} ms grid "
                        f"over the {t[-1] - t[0]:.3f} s they share")
    return t, np.interp(t, tu, vu), np.interp(t, tx, vx)
