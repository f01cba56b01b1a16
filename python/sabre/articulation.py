"""The articulation of an object that has no model, estimated from the hand's path while it pulls the
handle: door or drawer, the hinge's axis and position or the slide's direction, each with its
uncertainty, and the opening along the estimate (the core's ``_core.ArticulationEstimator``).

The method is Sturm, Stachniss and Burgard's (JAIR 2011) for the two joint types a handle is on: a
circle and a line are fitted to the hand's path by least squares (the circle by Levenberg–Marquardt
on the geometric distance, with a Gaussian prior that the hinge runs along the handle's bar), and
the Bayesian information criterion chooses between them, starting from the user's prior. Samples
are averaged in bins a few millimetres of path apart; the geometry is refitted when a bin closes,
the opening and its rate follow every sample.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from . import _core
from ._validate import as_float_array, core_config
from .errors import InvalidValueError

__all__ = ["ArticulationConfig", "ArticulationEstimate", "ArticulationEstimator", "PRIORS"]

_DEFAULTS = _core.ArticulationConfig()

#: What a user may say of a handle before pulling it, and the probability of a door each gives.
PRIORS: dict[str, float] = {"door": 0.8, "drawer": 0.2, "unknown": 0.5}


@dataclass(frozen=True)
class ArticulationConfig:
    """How the estimator weighs the hand's path and decides (defaults: the core's).

    - position_noise: σ (m) of one measured hand position; noise_floor: σ (m) that no averaging goes
      below (the hook's play in the handle, the arm's compliance); bin_length: path (m) one bin spans;
      max_bins: most bins kept (neighbours merge beyond).
    - axis_std: σ (rad) of the hinge's tilt from the handle's bar before the data. gravity_aligned:
      hinges are vertical or horizontal and slides level, as furniture and appliances have them: a bar
      within ``aligned_within`` rad of the vertical puts the hinge's prior on the vertical, one within
      it of the horizontal in the horizontal plane, with σ ``aligned_std`` rad for the tilt gravity
      fixes (off: the bar's direction alone).
    - radius: (lower, upper) hinge-to-handle distances (m) a door may have; min_path: path (m) before
      the data are weighed; decide: posterior at which a type is decided.
    - rate_cutoff: cutoff (Hz) of the low-passes on the opening and its rate; rehook_time: a hook let
      go for longer (s) may go in again elsewhere along the bar (the path after it may sit beside the
      last along the bar); shorter gaps continue the stretch.
    """

    position_noise: float = _DEFAULTS.position_noise
    noise_floor: float = _DEFAULTS.noise_floor
    bin_length: float = _DEFAULTS.bin_length
    max_bins: int = _DEFAULTS.max_bins
    axis_std: float = _DEFAULTS.axis_std
    gravity_aligned: bool = _DEFAULTS.gravity_aligned
    aligned_within: float = _DEFAULTS.aligned_within
    aligned_std: float = _DEFAULTS.aligned_std
    radius: tuple[float, float] = field(default=tuple(_DEFAULTS.radius))  # type: ignore[assignment]
    min_path: float = _DEFAULTS.min_path
    decide: float = _DEFAULTS.decide
    rate_cutoff: float = _DEFAULTS.rate_cutoff
    rehook_time: float = _DEFAULTS.rehook_time

    def __post_init__(self) -> None:
        # the core checks; an estimator for an identity handle is the cheapest way to ask it
        _core.ArticulationEstimator(np.eye(4), 0.5, self._core_config())

    def _core_config(self) -> Any:
        radius = tuple(float(r) for r in self.radius)
        if len(radius) != 2:
            raise InvalidValueError(f"radius must be (lower, upper), got {self.radius!r}")
        return core_config(
            _core.ArticulationConfig,
            position_noise=float(self.position_noise),
            noise_floor=float(self.noise_floor),
            bin_length=float(self.bin_length),
            max_bins=int(self.max_bins),
            axis_std=float(self.axis_std),
            gravity_aligned=bool(self.gravity_aligned),
            aligned_within=float(self.aligned_within),
            aligned_std=float(self.aligned_std),
            radius=radius,
            min_path=float(self.min_path),
            decide=float(self.decide),
            rate_cutoff=float(self.rate_cutoff),
            rehook_time=float(self.rehook_time),
        )


Kind = Literal["revolute", "prismatic"]


@dataclass(frozen=True)
class ArticulationEstimate:
    """The estimate after the last sample.

    kind: "revolute" (a door), "prismatic" (a drawer), or None while the evidence is short of
    :attr:`ArticulationConfig.decide`; p_revolute: the posterior probability of a door. The geometry
    is of type ``geometry`` (the decided kind, else prismatic: the first pull goes along the handle's
    outward normal, then along the path's line). axis (3,): the hinge's axis, the opening right-handed
    about it, or the slide's direction; point (3,): the hinge's point in the plane of the hand's path,
    or where the path began; radius (m): the handle's distance from the hinge (NaN for a slide).
    axis_std (rad), point_std (m), radius_std (m): standard deviations (inf before the data).
    opening (rad or m) and rate: along the geometry, low-passed; path_length (m) hooked; samples seen;
    hooked: whether the last sample was.
    """

    kind: Kind | None
    geometry: Kind
    p_revolute: float
    axis: np.ndarray
    point: np.ndarray
    radius: float
    axis_std: float
    point_std: float
    radius_std: float
    opening: float
    rate: float
    path_length: float
    samples: int
    hooked: bool

    @classmethod
    def _from_core(cls, d: dict[str, Any]) -> ArticulationEstimate:
        d = dict(d)
        d["axis"] = np.asarray(d["axis"], dtype=np.float64)
        d["point"] = np.asarray(d["point"], dtype=np.float64)
        return cls(**d)


class ArticulationEstimator:
    """Estimates the articulation of the handle at ``handle`` ((4, 4) world pose of its frame: origin at
    the bar's centre, x along the bar, z into the panel, as :mod:`sabre.handles` defines it) from the
    hand's measured positions. ``prior``: "door", "drawer" or "unknown" (:data:`PRIORS`), or the
    probability of a door; a wrong prior delays the decision, the path overrules it.

    Raises:
        InvalidValueError: an unknown prior, a probability outside [0, 1], a bad config.
        ShapeError: a handle pose that is not (4, 4).
    """

    def __init__(self, handle: np.ndarray, prior: str | float = "unknown", config: ArticulationConfig | None = None) -> None:
        self.handle = as_float_array("handle", handle, (4, 4))
        if isinstance(prior, str):
            if prior not in PRIORS:
                raise InvalidValueError(f"prior must be one of {tuple(PRIORS)} or a probability, got {prior!r}")
            p = PRIORS[prior]
        else:
            p = float(prior)
        self.prior = prior
        self.config = config or ArticulationConfig()
        self._core = _core.ArticulationEstimator(np.ascontiguousarray(self.handle), p, self.config._core_config())

    def update(
        self,
        t: float | Sequence[float] | np.ndarray,
        hand: Sequence[float] | np.ndarray,
        hooked: bool | Sequence[bool] | np.ndarray = True,
        record: bool | Sequence[bool] | np.ndarray | None = None,
    ) -> ArticulationEstimate:
        """Takes one hand position (3,) at time t (s), or T of them (T, 3) at times (T,). ``hooked`` (bool
        or (T,)): the hand holds the handle, and the opening follows it (while not hooked it holds at
        rest). ``record`` (default: as hooked): the seated hook pulls, and its path is the handle's (a
        hook still seating itself moves across the bar). Returns the estimate after the last.

        Raises:
            ShapeError, InvalidValueError: mismatched shapes, non-finite values (the batch is refused
                whole, the estimate left as it was).
        """
        times = np.atleast_1d(np.asarray(t, dtype=np.float64))
        n = times.shape[0]
        points = as_float_array("hand", np.asarray(hand, dtype=np.float64).reshape(-1, 3) if np.size(hand) else hand, (n, 3))
        flags = np.broadcast_to(np.asarray(hooked, dtype=bool), (n,))
        records = flags if record is None else np.broadcast_to(np.asarray(record, dtype=bool), (n,))
        return ArticulationEstimate._from_core(
            self._core.update(
                np.ascontiguousarray(times), np.ascontiguousarray(points), [bool(f) for f in flags], [bool(r) for r in records]
            )
        )

    @property
    def reference(self) -> np.ndarray:
        """(3,) where the hand holds the handle with the object closed (world): the opening's zero
        (default: the handle frame's origin)."""
        return np.asarray(self._core.reference, dtype=np.float64)

    @reference.setter
    def reference(self, point: Sequence[float] | np.ndarray) -> None:
        self._core.set_reference([float(v) for v in as_float_array("reference", point, (3,))])

    @property
    def estimate(self) -> ArticulationEstimate:
        return ArticulationEstimate._from_core(self._core.estimate())

    @property
    def points(self) -> np.ndarray:
        """(M, 5) the binned path the fits see: position (3), weight 1/σ² (1/m²), hooked stretch."""
        return np.asarray(self._core.points())

    def opening_at(self, hand: Sequence[float] | np.ndarray) -> float:
        """The opening the hand at ``hand`` (3,) puts along the current estimate (≥ 0)."""
        return float(self._core.opening_at([float(v) for v in as_float_array("hand", hand, (3,))]))

    def reset(self) -> None:
        """Forgets the path and the estimate."""
        self._core.reset()
