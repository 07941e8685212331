"""Judging detectors against the simulator: ground-truth energy exchanges, the evaluation grid, scoring.

Issue 6 ("Must show"): internal-resonance events are scored against *major exchanges* read from the
simulator's exact modal coordinates, over a grid of beam_ch4_exp hits (force x damping, nonlinear and
linear). ``truth`` defines the exchanges, ``grid`` simulates the cases, ``score`` matches events.
See ``docs/evaluation.md``.
"""
