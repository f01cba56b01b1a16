"""The records the safety filter returns: one FILTER-QP call, a sequence of them, the filter's
counters, its constraint rows and its QP's matrices."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

__all__ = ["FilterResult", "SequenceResult", "FilterStats", "ConstraintRows", "QPMatrices"]


@dataclass(frozen=True)
class FilterResult:
    """One FILTER-QP call.

    Attributes:
        u: (nq,) filtered command, within the joint velocity limits.
        slack: (R,) slack δ ≥ 0 of each row (order of :attr:`SafetyFilter.row_names`).
        class_slack: largest slack per class.
        barrier: (R,) barrier value h of each row (without the margin); NaN for rows off in this
            call (empty obstacle slots, passivity without a tank).
        active: names of the active constraints (tight or relaxed rows, input limits at a bound),
            e.g. ``joint_limit:panda_joint4``, ``self_collision:panda_link1-panda_link7``,
            ``arm_reach``, ``base_box:x``, ``obstacle:<id>:<link>``, ``passivity``,
            ``input_limit:<joint>``.
        status: ``"solved"``, ``"almost_solved"`` or ``"fallback"`` (the solver failed; u is the safe stop 0).
        solver_status: Clarabel's verdict.
        solve_time: wall time of the call in the core (s).
        iterations: interior-point iterations (0 without Clarabel).
        qp_rows: rows in the QP that was solved (0: no solver ran; active rows for ``active_set``).
        method: how the command was found: ``"projection"`` (the command clipped to the input
            limits met every row), ``"active_set"`` (the previous call's active set, re-solved and
            verified against every optimality condition) or ``"interior_point"`` (Clarabel).
    """

    u: np.ndarray
    slack: np.ndarray
    class_slack: Mapping[str, float]
    barrier: np.ndarray
    active: tuple[str, ...]
    status: str
    solver_status: str
    solve_time: float
    iterations: int
    qp_rows: int
    method: str

    @property
    def fallback(self) -> bool:
        """Whether the solver failed and u is the safe stop 0."""
        return self.status == "fallback"


@dataclass(frozen=True)
class SequenceResult:
    """Sequential FILTER-QP (Algorithm 1): the filtered sequence U (K, nq), the rollout states
    (K+1, nx) it produces in the rollout model, each step's filter status and the fallback count."""

    U: np.ndarray
    states: np.ndarray
    status: tuple[str, ...]
    fallbacks: int


@dataclass(frozen=True)
class FilterStats:
    """Counters of a :class:`SafetyFilter` since it was built or :meth:`SafetyFilter.reset_stats`.

    Attributes:
        calls: FILTER-QP calls (each step of :meth:`SafetyFilter.filter_sequence` counts).
        fallbacks: calls whose solver failed and returned the safe stop u = 0.
        mean_solve_time: mean wall time per call in the core (s; 0 without calls).
        max_solve_time: longest call (s).
        total_iterations: interior-point iterations summed over the calls.
        interior_point_calls: calls that ran Clarabel (the others took an exact shortcut).
        hard_limit_holds: calls whose command the hard-limit guard changed: a joint at or beyond
            its URDF limit was commanded further out and that component was zeroed, or, in the
            inner loop's cascade, a component was clipped to the joint-limit bound.
    """

    calls: int
    fallbacks: int
    mean_solve_time: float
    max_solve_time: float
    total_iterations: int
    interior_point_calls: int
    hard_limit_holds: int


@dataclass(frozen=True)
class ConstraintRows:
    """The affine rows of FILTER-QP at one state: row i requires ``a[i] @ u + δ_i ≥ b[i]``.

    Attributes:
        a: (R, nq) gradient ∂h/∂q of each row's barrier (for passivity: τ_extᵀ).
        b: (R,) right-hand side −γ (h − Δ) (19), in the units of ``a @ u``.
        h: (R,) barrier value of each row without the margin; NaN for rows off at this call.
    """

    a: np.ndarray
    b: np.ndarray
    h: np.ndarray


@dataclass(frozen=True)
class QPMatrices:
    """The whole FILTER-QP (41) as dense arrays: minimise ½ zᵀPz + qᵀz subject to A z ≤ b, over
    z = [u (nu); δ (R)], the command and one slack per row; the input bounds are rows of A too.

    Attributes:
        P: (nu + R, nu + R) quadratic cost (identity on u, the class penalty Γ on each slack).
        q: (nu + R,) linear cost (−u_ref on u).
        A: (m, nu + R) inequality rows. b: (m,) their bounds.
        nu: the number of command entries at the front of z.
    """

    P: np.ndarray
    q: np.ndarray
    A: np.ndarray
    b: np.ndarray
    nu: int
