"""Cost terms of the sampling-based controller (paper Sec. IV-A), composed with ``+`` and compiled to Rust.

Each built-in term is a small frozen dataclass holding its weights (defaults: the paper's Table I).
Terms add up into a :class:`Cost`; :meth:`Cost.compile` turns the built-in terms into one Rust object
that the rollout workers evaluate at every step with no Python call. A user-defined term is a
:class:`PythonTerm`: a callable that receives the whole batch once per planning iteration and
returns one cost per rollout, added to the Rust costs::

    import numpy as np
    import sabre
    from sabre import costs

    def keep_hand_high(batch: costs.Batch) -> np.ndarray:
        z = batch.frames["grasp"][..., 2, 3]          # (N, K+1) height of the grasp frame
        return 50.0 * np.maximum(0.0, 0.8 - z).sum(axis=1)

    cost = costs.TargetPose(target=np.eye(4)) + costs.JointLimits() + costs.PythonTerm(keep_hand_high, frames=("grasp",))
"""

from __future__ import annotations

import abc
import warnings
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from . import _core
from ._validate import as_array, as_float_array, as_non_negative, as_pose
from .errors import InvalidValueError
from .scene import Scene

__all__ = [
    "Term",
    "Cost",
    "Batch",
    "TargetPose",
    "Contact",
    "JointLimits",
    "ArmReach",
    "SelfCollision",
    "Posture",
    "ObjectState",
    "Power",
    "BaseBox",
    "Obstacles",
    "BaseClearance",
    "PythonTerm",
    "CompiledCost",
]


class Term(abc.ABC):
    """Base class of cost terms; ``a + b`` gives a :class:`Cost`."""

    @abc.abstractmethod
    def spec(self, scene: Scene) -> dict | None:
        """The Rust specification of this term (None for Python-evaluated terms)."""

    def __add__(self, other: Term | Cost) -> Cost:
        return Cost([self]) + other

    def compile(self, scene: Scene) -> CompiledCost:
        """This term alone, compiled (see :meth:`Cost.compile`)."""
        return Cost([self]).compile(scene)

    def __radd__(self, other: Term | Cost | int) -> Cost:
        if other == 0:  # sum([...]) starts from 0
            return Cost([self])
        return Cost([other]) + self if isinstance(other, Term) else other + self


def _ordered_bounds(lower: np.ndarray, upper: np.ndarray) -> None:
    if lower.shape != upper.shape:
        raise InvalidValueError(f"lower and upper must have the same length, got {lower.shape} and {upper.shape}")
    if np.any(lower > upper):
        raise InvalidValueError(f"bounds inverted: lower {lower.tolist()} exceeds upper {upper.tolist()}")


def _weight(name: str, value: float) -> float:
    return as_non_negative(name, value)


@dataclass(frozen=True)
class TargetPose(Term):
    """(29) ‖log(T⁻¹ T*)‖²_W of robot frame ``frame`` (None: the scene's tool frame).

    The target is ``target`` (4, 4) in the world, or, with ``object_frame``, the pose
    ``object_frame ∘ target`` that moves with the object (e.g. a grasp pose on the handle).
    W = diag(linear_weight × 3, angular_weight × 3); Table I: W_t = 100 I. ``weights`` (6,) sets
    the diagonal of W per axis instead (translation x, y, z then rotation x, y, z, all in the
    frame's own axes), e.g. to let a hand slide along a handle but not off it. With
    ``object_frame``, ``lead`` takes that frame at the object configuration ``lead`` ahead of the
    current one (capped at ``lead_limit``): a target that runs ahead along the opening path.
    """

    target: np.ndarray = field(default_factory=lambda: np.eye(4))
    frame: str | None = None
    object_frame: str | None = None
    linear_weight: float = 100.0
    angular_weight: float = 100.0
    weights: tuple[float, ...] | None = None
    lead: float = 0.0
    lead_limit: float = float("inf")

    def __post_init__(self) -> None:
        object.__setattr__(self, "target", as_pose("target", self.target))

    def spec(self, scene: Scene) -> dict:
        target = self.target
        if not np.isfinite(self.lead) or np.isnan(self.lead_limit):
            raise InvalidValueError("lead must be finite and lead_limit a number")
        if self.lead != 0.0 and self.object_frame is None:
            raise InvalidValueError("lead needs an object_frame to run ahead on")
        if self.weights is not None:
            if len(self.weights) != 6:
                raise InvalidValueError(f"weights must have 6 entries (x, y, z, rx, ry, rz), got {len(self.weights)}")
            weights = [_weight(f"weights[{i}]", w) for i, w in enumerate(self.weights)]
        else:
            weights = [_weight("linear_weight", self.linear_weight)] * 3 + [_weight("angular_weight", self.angular_weight)] * 3
        return {
            "kind": "pose",
            "frame": self.frame if self.frame is not None else scene.require_tool_frame("TargetPose"),
            "target": target.ravel().tolist(),
            "object_frame": self.object_frame,
            "weights": weights,
            "lead": float(self.lead),
            "lead_limit": float(self.lead_limit),
        }


@dataclass(frozen=True)
class Contact(Term):
    """(30) w_γ for every step in which the robot touches the object (used while approaching)."""

    weight: float = 100.0

    def spec(self, scene: Scene) -> dict:
        return {"kind": "contact", "weight": _weight("weight", self.weight)}


@dataclass(frozen=True)
class JointLimits(Term):
    """(31) per violated joint limit w_j + W_js · violation² (limits default to the scene's)."""

    weight: float = 1000.0
    weight_slope: float = 100.0
    lower: Sequence[float] | None = None
    upper: Sequence[float] | None = None

    def __post_init__(self) -> None:
        if self.lower is not None and self.upper is not None:
            _ordered_bounds(as_float_array("lower", self.lower, (None,)), as_float_array("upper", self.upper, (None,)))

    def spec(self, scene: Scene) -> dict:
        lower = scene.q_lower if self.lower is None else as_float_array("lower", self.lower, (scene.nq,))
        upper = scene.q_upper if self.upper is None else as_float_array("upper", self.upper, (scene.nq,))
        return {
            "kind": "joint_limits",
            "weight": _weight("weight", self.weight),
            "weight_slope": _weight("weight_slope", self.weight_slope),
            "lower": np.maximum(lower, -1e6).tolist(),
            "upper": np.minimum(upper, 1e6).tolist(),
        }


@dataclass(frozen=True)
class ArmReach(Term):
    """(32) if the planar distance r of the end effector from the arm base exceeds r_max: w_r + w_rs (r − r_max)².

    ``r_max``, the base and the frame default to the robot's ``<sabre><arm_reach>`` declaration.
    """

    r_max: float | None = None
    weight: float = 1000.0
    weight_slope: float = 100.0
    base: str | None = None
    frame: str | None = None

    def spec(self, scene: Scene) -> dict:
        declared = scene.arm_reach
        if declared is None and (self.base is None or self.frame is None or self.r_max is None):
            raise InvalidValueError("ArmReach: the robot declares no arm reach; give base, frame and r_max")
        if declared is None:
            # Narrowed by the check above: with no declared reach, base, frame and r_max are all given.
            assert self.base is not None and self.frame is not None and self.r_max is not None
            base, frame, r_max = self.base, self.frame, self.r_max
        else:
            base = self.base or declared[0]
            frame = self.frame or declared[1]
            r_max = self.r_max if self.r_max is not None else declared[2]
        return {
            "kind": "arm_reach",
            "base": base,
            "frame": frame,
            "r_max": as_non_negative("r_max", r_max),
            "weight": _weight("weight", self.weight),
            "weight_slope": _weight("weight_slope", self.weight_slope),
        }


@dataclass(frozen=True)
class SelfCollision(Term):
    """(33) per declared sphere pair closer than the sum of radii: w + w_s (d_min − d)²."""

    weight: float = 1000.0
    weight_slope: float = 100.0

    def spec(self, scene: Scene) -> dict:
        return {
            "kind": "self_collision",
            "weight": _weight("weight", self.weight),
            "weight_slope": _weight("weight_slope", self.weight_slope),
        }


@dataclass(frozen=True)
class Posture(Term):
    """Σ_i w_i (q_i − q*_i)²: a preferred robot posture (weights of 0 leave joints free)."""

    target: Sequence[float] | np.ndarray = ()
    weights: Sequence[float] | np.ndarray = ()

    def spec(self, scene: Scene) -> dict:
        target = as_float_array("target", self.target, (scene.nq,))
        weights = as_float_array("weights", self.weights, (scene.nq,))
        if np.any(weights < 0):
            raise InvalidValueError("Posture: weights must be non-negative")
        return {"kind": "posture", "target": target.tolist(), "weights": weights.tolist()}


@dataclass(frozen=True)
class ObjectState(Term):
    """(34) ‖o − o*‖²_{W_o}; Table I: W_o = 100."""

    target: Sequence[float] = (0.0,)
    weight: float = 100.0

    def spec(self, scene: Scene) -> dict:
        target = as_float_array("target", np.atleast_1d(self.target), (scene.no,))
        return {"kind": "object", "target": target.tolist(), "weights": [_weight("weight", self.weight)] * scene.no}


@dataclass(frozen=True)
class Power(Term):
    """(36) w_p · max(0, −τ_extᵀ u − p_max): penalises power dissipated against the environment."""

    weight: float = 10.0
    p_max: float = 0.0

    def spec(self, scene: Scene) -> dict:
        return {"kind": "power", "weight": _weight("weight", self.weight), "p_max": float(self.p_max)}


@dataclass(frozen=True)
class BaseBox(Term):
    """Base position limits [x_min, x_max] × [y_min, y_max] (experiments use ±2 m): w + w_s · excess²,
    on the coordinates of the scene's holonomic base (:attr:`~sabre.Scene.base_indices`); a robot
    with a fixed base has none, and compiling the term for it raises :class:`InvalidValueError`."""

    lower: Sequence[float] = (-2.0, -2.0)
    upper: Sequence[float] = (2.0, 2.0)
    weight: float = 100.0
    weight_slope: float = 100.0

    def __post_init__(self) -> None:
        _ordered_bounds(as_float_array("lower", self.lower, (2,)), as_float_array("upper", self.upper, (2,)))

    def spec(self, scene: Scene) -> dict:
        return {
            "kind": "base_box",
            "lower": as_float_array("lower", self.lower, (2,)).tolist(),
            "upper": as_float_array("upper", self.upper, (2,)).tolist(),
            "weight": _weight("weight", self.weight),
            "weight_slope": _weight("weight_slope", self.weight_slope),
        }


@dataclass(frozen=True)
class Obstacles(Term):
    """Sphere obstacles (centres (M, 3), radii (M,)) against the robot's collision spheres."""

    centers: Sequence[Sequence[float]] = ()
    radii: Sequence[float] = ()
    weight: float = 100.0
    weight_slope: float = 100.0

    def __post_init__(self) -> None:
        radii = as_float_array("radii", as_array("radii", self.radii).reshape(-1), (None,))
        as_float_array("centers", as_array("centers", self.centers).reshape(-1, 3), (len(radii), 3))
        if np.any(radii < 0.0):
            raise InvalidValueError(f"radii: an obstacle's radius must be non-negative, got {radii.tolist()}")

    def spec(self, scene: Scene) -> dict:
        radii = as_float_array("radii", np.asarray(self.radii, dtype=float).reshape(-1), (None,))
        centers = as_float_array("centers", np.asarray(self.centers, dtype=float).reshape(-1, 3), (len(radii), 3))
        return {
            "kind": "obstacles",
            "centers": centers.ravel().tolist(),
            "radii": radii.tolist(),
            "weight": _weight("weight", self.weight),
            "weight_slope": _weight("weight_slope", self.weight_slope),
        }


@dataclass(frozen=True)
class BaseClearance(Term):
    """Keeps the robot base's footprint clear of the object's moving parts: w + w_s · p².

    The footprint is a vertical cylinder about ``link``'s origin (None: the scene's
    :attr:`~sabre.Scene.base_link`), (radius, bottom, top) in metres
    with heights relative to the link origin; by default the cylinder that bounds the link's URDF
    collision primitives. It is grown by ``margin`` on every side. The moving parts are points
    spread at most ``spacing`` apart over the collision primitives of the object's moving links; p
    is the deepest planar penetration of a point that lies within the footprint's height band.
    A dishwasher door falls toward the robot; the rollout model gives the base no collider, so
    without this term the sampler cannot see the door landing on the base.
    """

    link: str | None = None
    footprint: Sequence[float] | None = None
    margin: float = 0.05
    spacing: float = 0.1
    weight: float = 100.0
    weight_slope: float = 10000.0

    def spec(self, scene: Scene) -> dict:
        footprint = None
        if self.footprint is not None:
            footprint = as_float_array("footprint", self.footprint, (3,)).tolist()
            if footprint[0] < 0.0 or footprint[1] > footprint[2]:
                raise InvalidValueError(f"footprint: expected (radius >= 0, bottom, top >= bottom), got {footprint}")
        if not (np.isfinite(self.spacing) and self.spacing > 0.0):
            raise InvalidValueError(f"spacing must be positive and finite, got {self.spacing}")
        return {
            "kind": "base_clearance",
            "link": str(self.link) if self.link is not None else scene.base_link,
            "footprint": footprint,
            "margin": _weight("margin", self.margin),
            "spacing": float(self.spacing),
            "weight": _weight("weight", self.weight),
            "weight_slope": _weight("weight_slope", self.weight_slope),
        }


@dataclass(frozen=True)
class Batch:
    """What a :class:`PythonTerm` sees of one planning iteration.

    Attributes:
        states: (N, K+1, nx) rollout states. inputs: (N, K, nu) sampled commands.
        tau_ext: (N, K, nq). contact: (N, K) bool. dt: rollout step (s).
        frames: name → (N, K+1, 4, 4) world poses of the frames the term asked for.
    """

    states: np.ndarray
    inputs: np.ndarray
    tau_ext: np.ndarray
    contact: np.ndarray
    dt: float
    frames: dict[str, np.ndarray]


@dataclass(frozen=True)
class PythonTerm(Term):
    """A user-defined term: ``function(batch: Batch) -> (N,)`` called once per planning iteration.

    ``frames`` lists the robot frames whose poses the function needs (computed in Rust).
    """

    function: Callable[[Batch], np.ndarray] = None  # type: ignore[assignment]
    frames: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not callable(self.function):
            raise InvalidValueError("PythonTerm: function must be callable")

    def spec(self, scene: Scene) -> None:
        return None

    def evaluate(self, scene: Scene, batch: Batch) -> np.ndarray:
        n = batch.states.shape[0]
        name = getattr(self.function, "__name__", "?")
        raw = as_array(f"PythonTerm {name}", self.function(batch))
        if raw.dtype.kind not in "fiu":
            # complex costs have no order: never drop the imaginary part silently
            raise InvalidValueError(f"PythonTerm {name}: returned dtype {raw.dtype}, expected real numbers")
        values = raw.astype(np.float64)
        if values.shape != (n,):
            raise InvalidValueError(f"PythonTerm {name}: returned shape {values.shape}, expected ({n},)")
        nan = np.isnan(values)
        if nan.any():
            warnings.warn(
                f"PythonTerm {name}: {int(nan.sum())} of {n} costs are NaN; those rollouts weigh zero",
                RuntimeWarning,
                stacklevel=2,
            )
        # NaN or inf removes that rollout from the weighted average.
        return np.where(nan, np.inf, values)


@dataclass(frozen=True)
class CompiledCost:
    """A cost ready for the planner: the Rust part and the Python terms."""

    core: _core.Cost
    python_terms: tuple[PythonTerm, ...]

    @property
    def frames_needed(self) -> tuple[str, ...]:
        return tuple(sorted({f for t in self.python_terms for f in t.frames}))


class Cost:
    """A sum of terms."""

    def __init__(self, terms: Iterable[Term] = ()) -> None:
        self.terms: tuple[Term, ...] = tuple(terms)
        for t in self.terms:
            if not isinstance(t, Term):
                raise InvalidValueError(f"a cost is made of sabre.costs terms, got {type(t).__name__}")

    def __add__(self, other: Term | Cost) -> Cost:
        if isinstance(other, Term):
            return Cost(self.terms + (other,))
        if isinstance(other, Cost):
            return Cost(self.terms + other.terms)
        return NotImplemented

    __radd__ = __add__

    def compile(self, scene: Scene) -> CompiledCost:
        specs = [t.spec(scene) for t in self.terms]
        python_terms = tuple(t for t in self.terms if isinstance(t, PythonTerm))
        return CompiledCost(core=_core.Cost(scene._core, [s for s in specs if s is not None]), python_terms=python_terms)

    def __repr__(self) -> str:
        return " + ".join(type(t).__name__ for t in self.terms) or "Cost()"
