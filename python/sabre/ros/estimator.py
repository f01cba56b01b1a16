"""The object-state estimator of the bridge, :class:`sabre.ObjectStateEstimator` (it lives in the core
package, :mod:`sabre.estimation`, so that a loop without ROS uses it too)."""

from __future__ import annotations

from ..estimation import ObjectEstimate, ObjectStateEstimator

__all__ = ["ObjectEstimate", "ObjectStateEstimator"]
