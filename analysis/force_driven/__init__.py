"""Force-driven records (a measured force moves a mass): other rigs' CSV, the EMPS and
Silverbox benchmarks. Model and sign convention in `model`; the loop in `identify`."""

from analysis.force_driven.identify import ForceLoop, TermFit, close_force_loop, fit_terms
from analysis.force_driven.loading import ForceRecord, load_force_record
from analysis.force_driven.prepare import Prepared, prepare

__all__ = ["ForceLoop", "ForceRecord", "Prepared", "TermFit", "close_force_loop", "fit_terms",
           "load_force_record", "prepare"]
