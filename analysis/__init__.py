"""Identification of nonlinear shock isolators from logged runs (after CERL TR M-226)."""
