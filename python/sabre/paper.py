"""What exists only to reproduce the paper (Rizzi et al., T-RO 2023), re-exported from where it lives.

- :func:`paper_start_state`: the paper's starting condition (base at (−3, −3), arm folded near its limits).
  For the RoyalPanda it is :meth:`sabre.Scene.start_state`, which is the name for any robot.
- :mod:`scenarios`: the evaluation scenarios of Sec. VI-A (the stuck door, the tank's chattering, the
  obstacle corridor, opening from the paper's start), each a function returning a small frozen result.
- :func:`likelihood_weights`: the sample weights of the three mappings Fig. 3 compares (naive,
  baseline, and the scale-invariant (55) that the controller applies itself).

The runner over seeds and the figures are :mod:`sabre.experiments` (``python -m sabre experiment``).
"""

from __future__ import annotations

from .closed_loop import paper_start_state
from .experiments import scenarios
from .planner import likelihood_weights

__all__ = ["paper_start_state", "scenarios", "likelihood_weights"]
