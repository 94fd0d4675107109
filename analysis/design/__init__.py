"""Isolator design: the constants that protect a given equipment best (docs/design.md).

threat (the base motions), quantity (limits with units), space (free constants and
their box), objective (peaks over the threats), search (global sample and local
search), ideal (Figure 1's isolator), pareto, sensitivity (tolerances), design (the
whole), report and figure (output), cli (`analysis design`).
"""
