"""The plant protocol: what the closed loop needs from a simulator or a robot (:class:`PlantInterface`), and
the check that an object provides it (:func:`as_plant`).

:class:`sabre.Plant` (Rapier) is one implementation; a wrapper around another simulator is another. The
closed loop (:func:`sabre.run_episode`, :meth:`sabre.LowLevelController.follow`) drives a ``"torque"`` plant
with the low-level controller's joint torques and a ``"velocity"`` plant with the filtered joint-velocity
command, which it tracks with a servo of its own as a robot's velocity interface does.
"""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from .errors import InvalidValueError

if TYPE_CHECKING:
    from .scene import Scene
    from .sim import ContactPoint

__all__ = ["PlantInterface", "COMMAND_INTERFACES", "PLANT_MEMBERS", "as_plant"]

#: What a plant's :meth:`PlantInterface.step` takes: joint torques, or joint velocity commands.
COMMAND_INTERFACES = ("torque", "velocity")

#: Every member a plant must have, in the order :func:`as_plant` names the missing ones.
PLANT_MEMBERS = (
    "scene",
    "dt",
    "time",
    "state",
    "command_interface",
    "step",
    "measured_tau_ext",
    "tau_ext",
    "wrench",
    "contact",
    "contacts",
    "reset",
    "hold_object",
    "object_held",
)


@runtime_checkable
class PlantInterface(Protocol):
    """A simulator or robot the closed loop can drive, one step of :attr:`dt` at a time.

    The state is sabre's (nx,) = [q, q̇, o, ȯ] of :attr:`scene` (:meth:`sabre.Scene.split_state`), in the
    scene's joint order and units (rad, m, rad/s, m/s). τ_ext is the torque the environment puts on the
    robot's joints (N·m, N for the base's translation), positive when it pushes the joint forwards.
    """

    @property
    def scene(self) -> Scene:
        """The robot and object the plant simulates (or the robot is)."""
        ...

    @property
    def dt(self) -> float:
        """The step (s) each :meth:`step` advances."""
        ...

    @property
    def time(self) -> float:
        """Time since the last :meth:`reset` (s)."""
        ...

    @property
    def state(self) -> np.ndarray:
        """(nx,) the current state [q, q̇, o, ȯ]."""
        ...

    @property
    def command_interface(self) -> str:
        """``"torque"``: :meth:`step` takes joint torques; ``"velocity"``: joint velocity commands."""
        ...

    def step(self, command: np.ndarray) -> None:
        """Advances one :attr:`dt` under ``command``: (nq,) joint torques (N·m, N) for a torque plant, (nu,)
        joint velocity commands (rad/s, m/s) for a velocity plant, which its own joint servo tracks."""
        ...

    @property
    def measured_tau_ext(self) -> np.ndarray:
        """(nq,) the plant's τ_ext reading after the last step, band-limited like a momentum observer or a
        filtered wrist sensor: the passivity row and the energy tank read it."""
        ...

    @property
    def tau_ext(self) -> np.ndarray:
        """(nq,) the true external joint torques of the last step (recorded, never fed back)."""
        ...

    @property
    def wrench(self) -> np.ndarray:
        """(6,) force (N) and torque (N·m) on the hand about the wrist flange, world frame, of the last step."""
        ...

    @property
    def contact(self) -> bool:
        """Whether any robot–object contact carried force in the last step."""
        ...

    def contacts(self) -> list[ContactPoint]:
        """Every robot–object contact point of the last step (:class:`sabre.ContactPoint`)."""
        ...

    def reset(self, x0: Sequence[float] | np.ndarray | None = None) -> None:
        """Puts the plant at x0 (nx,) (default: the scene's default state), time 0, object released."""
        ...

    def hold_object(self, flag: bool) -> None:
        """Fault injection: ``True`` holds the object's joint where it is (the stuck door); ``False`` releases it."""
        ...

    @property
    def object_held(self) -> bool:
        """Whether :meth:`hold_object` holds the object now."""
        ...


_MISSING = object()


def _has(plant: Any, name: str) -> bool:
    """Whether ``plant`` has the member: looked up without running a property, else through ``__getattr__``
    (a wrapper that delegates to the simulator it wraps)."""
    if inspect.getattr_static(plant, name, _MISSING) is not _MISSING:
        return True
    try:
        getattr(plant, name)
    except AttributeError:
        return False
    return True


def as_plant(plant: Any, scene: Scene | None = None) -> PlantInterface:
    """``plant`` itself once it provides every member of :class:`PlantInterface`, a known
    ``command_interface`` and, given ``scene``, that scene's dimensions.

    Raises:
        TypeError: members are missing (the message names them).
        InvalidValueError: an unknown command interface, or a plant of another robot than ``scene``'s.
    """
    missing = [name for name in PLANT_MEMBERS if not _has(plant, name)]
    if missing:
        raise TypeError(f"plant: a {type(plant).__name__} is not a sabre.PlantInterface; it lacks {', '.join(missing)}")
    if plant.command_interface not in COMMAND_INTERFACES:
        raise InvalidValueError(f"plant.command_interface must be one of {COMMAND_INTERFACES}, got {plant.command_interface!r}")
    if scene is not None and (plant.scene.nq != scene.nq or plant.scene.nx != scene.nx):
        raise InvalidValueError(
            f"plant: its scene (nq = {plant.scene.nq}, nx = {plant.scene.nx}) is not the controller's "
            f"(nq = {scene.nq}, nx = {scene.nx})"
        )
    return plant
