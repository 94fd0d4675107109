"""Signals from sampled displacement: velocity and acceleration, and which samples rest."""
