"""Closing the loop: find what the fitted model lacks from its residual, add it, refit."""

from analysis.loop.candidates import CANDIDATES, Candidate
from analysis.loop.close import close_identified, close_loop
from analysis.loop.evidence import Diagnosis, diagnose
from analysis.loop.refit import Fit, Hypothesis, predict, refit
from analysis.loop.result import LoopResult, Step
from analysis.loop.runs import LoopRun

__all__ = ["CANDIDATES", "Candidate", "Diagnosis", "Fit", "Hypothesis", "LoopResult", "LoopRun",
           "Step", "close_identified", "close_loop", "diagnose", "predict", "refit"]
