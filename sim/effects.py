"""Physical effects the simulated rig can add to the isolator or its sensors, undeclared.

The identification's loop must find these from the data alone, so nothing here
is written to a run file or a CSV: the simulated rig only changes what it
measures. The names are the loop's candidate names (issue 6), so a test can
check that the loop named the effect that was injected.

An effect is either a force term added to the isolator model (same registry as
the fitted model, `analysis.model.terms`) or a distortion of the mass sensor.
Magnitudes are SI; `spec` strings look like ``coulomb_friction=150`` or
``thermal_damping_drift=-400,0.8,600,0.5`` (value, then the shape constants; those
at the end a term may leave out take their defaults).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.model.isolator import IsolatorModel, Term
from analysis.model.terms import kind as term_kind
from rig.errors import ConfigError


@dataclass(frozen=True)
class EffectKind:
    """One injectable effect: how its magnitude enters, and what it means."""

    name: str
    unit: str
    meaning: str
    term_kind: str = ""  # force term added to the model; "" for a sensor effect
    term_name: str = ""
    shape_defaults: tuple[float, ...] = ()


EFFECTS: dict[str, EffectKind] = {
    e.name: e
    for e in (
        # v_s 0: the report's step at ż = 0; a seal whose friction builds up over a few
        # mm/s takes v_s
        EffectKind("coulomb_friction", "N", "dry friction of the rod seals, F tanh(ż/v_s) "
                   "(F sgn(ż) at v_s = 0)", "coulomb", "c3", (0.0,)),
        EffectKind("asymmetric_damping", "N/(m/s)", "extra damping when the isolator extends",
                   "extension_damper", "c_ext"),
        EffectKind("quadratic_damping", "N/(m/s)^2", "turbulent orifice flow, c ż|ż|",
                   "quadratic_damper", "c_q"),
        EffectKind("cubic_stiffness", "N/m^3", "hardening spring, k z³", "cubic_spring", "k3"),
        EffectKind("asymmetric_stiffness", "N/m", "extra stiffness in compression (z > 0)",
                   "compression_spring", "k_comp"),
        EffectKind("preload", "N", "fluid preload, γ sgn(z) outside the dead band",
                   "preload", "gamma"),
        EffectKind("force_offset", "N", "a constant force: a tilted track or a load-cell zero",
                   "force_offset", "F0"),
        # heating 0.8 K s/m²: c1 ≈ 6 kN/(m/s) into ~7.5 kJ/K of fluid and casing;
        # 600 s: a warm casing cools over minutes (the report's run C); no θ_max (0): the
        # drift does not stop within a campaign
        EffectKind("thermal_damping_drift", "N/(m/s)/K",
                   "viscosity falls as the fluid heats from the energy the damper dissipates",
                   "thermal_damper", "c_T", (0.8, 600.0, 0.0)),
        EffectKind("hysteresis", "N/m", "Bouc–Wen rate-independent hysteresis of the seals",
                   "bouc_wen", "k_h", (60.0, 20.0, 1.0)),
        EffectKind("sensor_delay", "s", "the mass sensor lags the table sensor"),
        EffectKind("sensor_gain", "1", "scale error of the mass sensor: x_meas = (1 + g) x"),
    )
}


@dataclass(frozen=True)
class Effect:
    """An effect at a magnitude (SI), with its shape constants."""

    name: str
    value: float
    shape: tuple[float, ...] = ()

    @property
    def kind(self) -> EffectKind:
        return EFFECTS[self.name]


def parse_effect(spec: str) -> Effect:
    """``name=value[,shape...]`` → Effect; ConfigError names what is wrong."""
    name, sep, rest = spec.partition("=")
    name = name.strip()
    if name not in EFFECTS:
        raise ConfigError("--effect", name or spec, f"unknown effect (known: {', '.join(EFFECTS)})")
    if not sep or not rest.strip():
        raise ConfigError("--effect", name, f"needs a magnitude in {EFFECTS[name].unit}: "
                                             f"{name}=VALUE")
    try:
        numbers = [float(v) for v in rest.split(",")]
    except ValueError:
        raise ConfigError("--effect", name, f"not a number: {rest!r}") from None
    if not all(np.isfinite(numbers)):
        raise ConfigError("--effect", name, f"must be finite, got {rest!r}")
    kind = EFFECTS[name]
    shape = tuple(numbers[1:]) or kind.shape_defaults
    if kind.term_kind and len(shape) < len(kind.shape_defaults):
        # a spec written before a shape constant existed (a Bouc–Wen a, b without n)
        k = term_kind(kind.term_kind)
        full = k.completed_shape(dict(zip(k.shape_names, shape)))
        if len(full) == len(k.shape_names):
            shape = tuple(full[n] for n in k.shape_names)
    if len(shape) != len(kind.shape_defaults):
        raise ConfigError("--effect", name, f"takes {len(kind.shape_defaults)} shape constants "
                                            f"after the value, got {len(numbers) - 1}")
    return Effect(name, numbers[0], shape)


def with_effects(model: IsolatorModel, effects: tuple[Effect, ...]) -> IsolatorModel:
    """The model with every force-term effect added (sensor effects are not the model's).

    Where the model already has the term (the report's model carries c3 and γ at
    zero), the effect adds to its coefficient.
    """
    for e in effects:
        k = e.kind
        if not k.term_kind:
            continue
        have = {t.name: t for t in model.terms}
        if k.term_name in have and have[k.term_name].kind == k.term_kind:
            t = have[k.term_name]
            model = model.with_parameters(**{k.term_name: t.coef + e.value,
                                             **dict(zip(t.shape_names(), e.shape))})
        else:
            model = model.with_terms(Term(k.term_kind, k.term_name, e.value, e.shape))
    return model


def distort_mass_sensor(t: np.ndarray, x: np.ndarray, effects: tuple[Effect, ...]) -> np.ndarray:
    """What the mass sensor reports for true x(t): delayed and scaled as the effects say."""
    out = np.asarray(x, float)
    for e in effects:
        if e.name == "sensor_delay":
            # the sensor reports x(t − d): interpolate the true signal, held before t0
            out = np.interp(t - e.value, t, out)
        elif e.name == "sensor_gain":
            out = (1.0 + e.value) * out
    return out
