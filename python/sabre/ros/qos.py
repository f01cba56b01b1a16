"""QoS profiles of the bridge's endpoints from their ``<name>_qos`` parameters.

A parameter names a profile and optionally a depth, ``"sensor"`` or ``"reliable:1"``:

- ``sensor``: best effort, volatile, depth 10. A best-effort subscription matches reliable and
  best-effort publishers alike (franka_ros2 publishes its external wrench and torques best effort,
  most drivers their joint states reliable), so every sensor input defaults to it.
- ``reliable``: reliable, volatile, depth 10 (what ros2_control's command subscriptions offer and
  need: a best-effort publisher does not match a reliable subscription).
- ``latched``: reliable, transient local, depth 1 (``robot_description`` as robot_state_publisher
  offers it, an object pose a perception node sends once).
"""

from __future__ import annotations

from typing import Any

from ..errors import InvalidValueError

__all__ = ["PROFILES", "parse", "profile"]

#: profile name → (reliable, transient local, default depth)
PROFILES: dict[str, tuple[bool, bool, int]] = {
    "sensor": (False, False, 10),
    "reliable": (True, False, 10),
    "latched": (True, True, 1),
}


def parse(text: str) -> tuple[bool, bool, int]:
    """(reliable, transient local, depth) of a QoS parameter's value."""
    name, _, depth = str(text).strip().partition(":")
    if name not in PROFILES:
        raise InvalidValueError(f"QoS {text!r}: the profile must be one of {', '.join(PROFILES)} (optionally ':depth')")
    reliable, latched, default_depth = PROFILES[name]
    try:
        n = int(depth) if depth else default_depth
    except ValueError:
        raise InvalidValueError(f"QoS {text!r}: the depth after ':' must be an integer") from None
    if n < 1:
        raise InvalidValueError(f"QoS {text!r}: the depth must be at least 1")
    return reliable, latched, n


def profile(text: str) -> Any:
    """The rclpy ``QoSProfile`` of a QoS parameter's value (keep last, the parsed depth)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    reliable, latched, depth = parse(text)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )
