"""Named recipes for the measured benchmarks in shared/datasets: EMPS and Silverbox.

Each recipe runs the force-driven loop the way its benchmark defines the task and
returns the figures to set beside the published ones (docs/datasets.md):

- EMPS (Janot, Gautier & Brunot 2019): identify on DATA_EMPS, cross-test on
  DATA_EMPS_PULSES; the benchmark's IDIM-LS preparation (Butterworth 100 Hz,
  central differences, decimation by 10) and error ‖F − F̂‖/‖F‖ in %. The loop
  starts from mass + viscous friction and validates on the pulse record.
  The benchmark's two published structures are also fitted with the same code,
  so the published 4.0834 % and 3.1117 % can be checked to the last digit.
- Silverbox (Wigren & Schoukens 2013): input V1 (the force), output V2 (the
  displacement), both in volts; train, test slices of the official loader;
  means of the training slice removed (a DC offset in V1 that the circuit does
  not pass would otherwise be the first "effect"). The loop starts from
  m, c, k and validates by simulation, by blocked cross-validation within the
  training slice; the simulation RMS error is reported on the test sections,
  before (linear) and after (the loop's model).
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from analysis.force_driven.identify import ForceLoop, TermFit, close_force_loop, fit_terms
from analysis.force_driven.identify import relative_error as cross_error
from analysis.force_driven.loading import ForceRecord, load_force_record
from analysis.force_driven.prepare import prepare
from analysis.force_driven.simulate import SKIP, initial_state, rms_error, simulate_position
from rig.errors import DataError

# where the datasets are looked for, after --data-dir: an environment variable, then
# shared/datasets beside the working directory or the source tree (the repository sits
# beside shared/). An installed package's own path leads into site-packages, so the
# working tree is looked at first.
DATA_ENV = "ISOLATOR_DATASETS"
SOURCE_TREE_DATA = Path(__file__).resolve().parents[3] / "shared" / "datasets"

EMPS_PUBLISHED = {  # benchmark description, IDIM-LS on DATA_EMPS (PROVENANCE.md)
    "symmetric": {"M": 95.1089, "Fv": 203.5034, "Fc": 20.3935, "offset": -3.1648,
                  "relerr_pct": 4.0834, "cross_test_pct": 5.9824},
    "direction_dependent": {"M": 95.1540, "Fv+": 166.7061, "Fc+": 20.1440, "Fv-": 240.4236,
                            "Fc-": 20.6277, "relerr_pct": 3.1117},
}
EMPS_SYMMETRIC = ["mass", "viscous", "coulomb_friction", "force_offset"]
EMPS_DIRECTIONAL = EMPS_SYMMETRIC + ["asymmetric_damping"]
EMPS_CUTOFF, EMPS_FACTOR = 100.0, 10  # Script_IDIM_LS.m: 5 × 20 Hz; round(0.8·500/40)

SILVERBOX_TRAIN = (40650, 105712)
SILVERBOX_TESTS = {"arrow (full)": (100, 40575), "arrow (no extrapolation)": (100, 32100),
                   "multisine": (105712, 127400)}
# above the excitation's 200 Hz, below Nyquist (305 Hz): both sides of the balance are
# filtered by it, so it only trims noise and the sampled derivatives' top band
SILVERBOX_CUTOFF = 250.0


def data_dir(given: Path | None = None) -> Path:
    """The datasets directory: `given`, else the first of `candidate_dirs()` that exists."""
    if given is not None:
        if not Path(given).is_dir():
            raise DataError(f"{given}: no datasets directory (--data-dir)")
        return Path(given)
    looked = candidate_dirs()
    found = next((p for p in looked if p.is_dir()), None)
    if found is None:
        raise DataError("no datasets directory; looked in " + ", ".join(map(str, looked))
                        + f": give --data-dir DIR or set {DATA_ENV}")
    return found


def candidate_dirs() -> list[Path]:
    """Where the datasets may be, in the order they are looked for."""
    env = os.environ.get(DATA_ENV)
    cwd = Path.cwd()
    out = [Path(env)] if env else []
    out += [cwd / "shared" / "datasets", cwd.parent / "shared" / "datasets", SOURCE_TREE_DATA]
    return list(dict.fromkeys(p.resolve() for p in out))


@dataclass
class EmpsResult:
    loop: ForceLoop
    symmetric: TermFit
    directional: TermFit
    cross_test: dict[str, float]  # relative error on the pulse record, fraction
    published: dict = field(default_factory=lambda: EMPS_PUBLISHED)

    def directional_as_published(self) -> dict[str, float]:
        """Our direction-dependent fit in the benchmark's parameters (M, Fv±, Fc±).

        For q̇ > 0 the friction is (c + c_ext) q̇ + Fc + F0, for q̇ < 0 c q̇ − Fc + F0,
        i.e. Fv+ = c + c_ext, Fv− = c, Fc+ = Fc + F0, Fc− = Fc − F0.
        """
        p = self.directional.parameters()
        return {"M": p["mass"], "Fv+": p["viscous"] + p["asymmetric_damping"],
                "Fc+": p["coulomb_friction"] + p["force_offset"], "Fv-": p["viscous"],
                "Fc-": p["coulomb_friction"] - p["force_offset"]}


def emps(directory: Path | None = None) -> EmpsResult:
    """The EMPS recipe (module doc)."""
    d = data_dir(directory) / "emps"
    train = prepare(load_force_record(d / "emps_train_DATA_EMPS.csv.gz", "force_N", "qm_m"),
                    EMPS_CUTOFF, EMPS_FACTOR, "central")
    test = prepare(load_force_record(d / "emps_test_DATA_EMPS_PULSES.csv.gz", "force_N",
                                     "qm_m"), EMPS_CUTOFF, EMPS_FACTOR, "central")
    loop = close_force_loop([train], ["mass", "viscous"], heldout=[test])
    symmetric = fit_terms([train], EMPS_SYMMETRIC)
    directional = fit_terms([train], EMPS_DIRECTIONAL)
    cross = {"symmetric": cross_error(symmetric, [test]),
             "direction_dependent": cross_error(directional, [test]),
             "loop_base": cross_error(loop.base, [test]),
             "loop_final": cross_error(loop.final, [test])}
    return EmpsResult(loop, symmetric, directional, cross)


@dataclass
class SilverboxResult:
    loop: ForceLoop
    simulation_before: dict[str, float]  # test section -> RMS error, V
    simulation_after: dict[str, float]
    offsets: dict[str, float]  # removed means, V


def silverbox(directory: Path | None = None) -> SilverboxResult:
    """The Silverbox recipe (module doc)."""
    path = data_dir(directory) / "silverbox" / "silverbox_SNLS80mV.csv.gz"
    raw = load_force_record(path, "V1_V", "V2_V")
    a, b = SILVERBOX_TRAIN
    u0, y0 = float(raw.force[a:b].mean()), float(raw.position[a:b].mean())
    rec = ForceRecord(raw.name, raw.path, raw.t, raw.force - u0, raw.position - y0,
                      raw.force_column, raw.position_column)
    train = prepare(rec.section(a, b, "train"), SILVERBOX_CUTOFF, 1, "spectral")
    loop = close_force_loop([train], ["mass", "viscous", "stiffness"], validation="simulation")
    return SilverboxResult(loop, simulation_errors(loop.base, rec),
                           simulation_errors(loop.final, rec), {"V1_V": u0, "V2_V": y0})


def simulation_errors(fit: TermFit, rec: ForceRecord) -> dict[str, float]:
    """RMS of simulated − measured output on each test section, after SKIP samples."""
    out = {}
    for name, (a, b) in SILVERBOX_TESTS.items():
        y = rec.position[a:b]
        q0, v0 = initial_state(y, rec.dt)
        out[name] = rms_error(simulate_position(fit.parameters(), rec.force[a:b], rec.dt, q0,
                                                v0), y, SKIP)
    return out


# ---------------------------------------------------------------- report


def emps_table(r: EmpsResult) -> str:
    """Markdown: published vs ours, the loop's steps, the direction-dependent parameters."""
    pub = r.published
    sym, dd = r.symmetric, r.directional
    lines = [("| model (DATA_EMPS, IDIM-LS) | published relerr | ours | cross-test on PULSES "
             "(published / ours) |"), "|---|---:|---:|---:|",
             (f"| symmetric: M, Fv, Fc, offset | {pub['symmetric']['relerr_pct']:.4f} % | "
             f"{100 * sym.relative_error:.4f} % | {pub['symmetric']['cross_test_pct']:.4f} % / "
             f"{100 * r.cross_test['symmetric']:.4f} % |"),
             (f"| direction-dependent: M, Fv±, Fc± | {pub['direction_dependent']['relerr_pct']:.4f}"
             f" % | {100 * dd.relative_error:.4f} % | — / "
             f"{100 * r.cross_test['direction_dependent']:.4f} % |"),
             (f"| loop, before: M, Fv | — | {100 * r.loop.base.relative_error:.4f} % | — / "
             f"{100 * r.cross_test['loop_base']:.4f} % |")]
    for s in r.loop.steps:
        lines.append(f"| loop, + {s.added} ({s.parameter} = {s.value:.4g} ± {s.std:.2g} "
                     f"{s.unit}) | — | {100 * s.error_after:.4f} % | — / "
                     f"{100 * s.heldout_after:.4f} % |")
    lines += ["", "| parameter | published | ours |", "|---|---:|---:|"]
    p_sym = sym.parameters()
    for key, name in (("M", "mass"), ("Fv", "viscous"), ("Fc", "coulomb_friction"),
                      ("offset", "force_offset")):
        lines.append(f"| symmetric {key} | {pub['symmetric'][key]:.4f} | {p_sym[name]:.4f} |")
    for key, value in r.directional_as_published().items():
        lines.append(f"| direction-dependent {key} | {pub['direction_dependent'][key]:.4f} | "
                     f"{value:.4f} |")
    return "\n".join(lines)


def silverbox_table(r: SilverboxResult) -> str:
    """Markdown: the loop's steps and the simulation errors on the test sections."""
    loop = r.loop
    model_after = "linear + " + " + ".join(loop.effects_added) if loop.effects_added else "linear"
    lines = [("| test section (samples, SNLS80mV) | before: linear m, c, k | after: "
             f"{model_after} | ratio |"), "|---|---:|---:|---:|"]
    for name, (a, b) in SILVERBOX_TESTS.items():
        before, after = r.simulation_before[name], r.simulation_after[name]
        lines.append(f"| {name} [{a}, {b}) | {1e3 * before:.3f} mV | {1e3 * after:.3f} mV | "
                     f"{before / after:.1f} |")
    lines += ["", ("| step | parameter | relative equation error (train) | held-out simulation "
              "RMS |"), "|---|---|---:|---:|",
              (f"| base m, c, k | — | {100 * loop.base.relative_error:.3f} % | "
              f"{1e3 * loop.heldout_before:.3f} mV |")]
    for s in loop.steps:
        lines.append(f"| + {s.added} | {s.parameter} = {s.value:.4g} ± {s.std:.2g} | "
                     f"{100 * s.error_after:.3f} % | {1e3 * s.heldout_after:.3f} mV |")
    return "\n".join(lines)


def result_json(r: EmpsResult | SilverboxResult) -> dict:
    from analysis.force_driven.report import force_loop_json

    doc = force_loop_json(r.loop, [])
    doc.pop("records")
    doc.pop("error_band_hz")  # of the records, which the recipes do not keep
    if isinstance(r, EmpsResult):
        doc["published"] = r.published
        doc["published_structures"] = {
            "symmetric": {"parameters": r.symmetric.parameters(),
                          "error": r.symmetric.relative_error},
            "direction_dependent": {"parameters": r.directional_as_published(),
                                    "error": r.directional.relative_error}}
        doc["cross_test"] = r.cross_test
    else:
        doc["simulation_rms_before_V"] = r.simulation_before
        doc["simulation_rms_after_V"] = r.simulation_after
        doc["offsets_removed_V"] = r.offsets
    return json.loads(json.dumps(doc, default=_plain))


def _plain(x: object) -> object:
    if isinstance(x, np.generic):
        return x.item()
    if hasattr(x, "__dataclass_fields__"):
        return asdict(x)  # type: ignore[arg-type]
    raise TypeError(f"not JSON: {type(x).__name__}")


# ---------------------------------------------------------------- command

NAMES = ("emps", "silverbox")


def add_datasets_parser(sub) -> None:  # argparse._SubParsersAction
    p = sub.add_parser("datasets", help="the force-driven loop on the EMPS and Silverbox "
                                        "benchmarks, beside their published figures")
    p.add_argument("name", choices=(*NAMES, "all"), help="which benchmark")
    p.add_argument("--data-dir", type=Path, metavar="DIR",
                   help=f"the datasets directory (default: ${DATA_ENV}, else shared/datasets "
                        "beside the working directory or the source tree)")
    p.add_argument("--json", type=Path, metavar="FILE", help="write the results as JSON")


def run_datasets(args) -> int:
    """Run the recipes asked for; print each loop, then the markdown tables of docs/datasets.md."""
    from analysis.force_driven.report import format_force_loop

    names = NAMES if args.name == "all" else (args.name,)
    doc = {}
    for name in names:
        result = emps(args.data_dir) if name == "emps" else silverbox(args.data_dir)
        print(f"== {name}")
        print(format_force_loop(result.loop, []))
        print()
        print(emps_table(result) if name == "emps" else silverbox_table(result))
        print()
        doc[name] = result_json(result)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=2), encoding="utf-8")
        print(f"wrote {args.json}")
    return 0
