"""The sampler's update, by formula: one planning iteration against a NumPy re-implementation.

A task whose cost is a single ``costs.PythonTerm`` lets the test choose every rollout's cost while
the controller runs its real sample → roll out → update path. The expected new nominal is computed
here, independently of sabre, from the batch the term saw: the cost-scale-invariant weights (55),
the clipped step μ += α clip(Σ_l w_l (u_l − μ), ±g_max) (14), (54), Savitzky–Golay smoothing and
the projection onto the input bounds. A second iteration checks the batch layout: shifted nominal,
zero sequence, then the best previous samples by weight, in order, shifted by the elapsed time.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

import sabre
from sabre import costs, tasks

ROLLOUTS = 20
DT = 0.015
HORIZON = 0.6  # K = 40 steps: longer than the smoothing window, so interior and end windows both occur
WINDOW = 30
ORDER = 3
LIMIT = 0.8  # below every joint velocity limit of the RoyalPanda, so it is the projection bound


class ChosenCosts(tasks.Task):
    """One phase whose only cost term returns ``choose(inputs)``; records every batch it sees."""

    phases = ("main",)

    def __init__(self, choose: Callable[[np.ndarray], np.ndarray]) -> None:
        self.choose = choose
        self.batches: list[np.ndarray] = []

    def _evaluate(self, batch: costs.Batch) -> np.ndarray:
        self.batches.append(batch.inputs.copy())
        return self.choose(batch.inputs)

    def cost(self, scene: sabre.Scene, phase: str) -> costs.Cost:
        return costs.Cost([costs.PythonTerm(function=self._evaluate)])


def invariant_weights(c: np.ndarray, h: float) -> np.ndarray:
    """(55): exp(−h (J − J_min)/(J_max − J_min)) over the finite costs, normalised; others zero."""
    finite = np.isfinite(c)
    w = np.zeros_like(c)
    if not finite.any():
        return w
    lo, hi = c[finite].min(), c[finite].max()
    span = hi - lo
    w[finite] = np.exp(-h * (c[finite] - lo) / span) if span > 0 else 1.0
    return w / w.sum()


def savitzky_golay(seq: np.ndarray, window: int, order: int) -> np.ndarray:
    """Local least-squares cubic fits, one per step; the window is shifted, not shrunk, at the ends."""
    k = seq.shape[0]
    window = min(window, k)
    out = np.empty_like(seq)
    for i in range(k):
        start = min(max(i - window // 2, 0), k - window)
        s = np.arange(start, start + window) - i
        vander = np.vander(s, order + 1, increasing=True)
        coef, *_ = np.linalg.lstsq(vander, seq[start : start + window], rcond=None)
        out[i] = coef[0]
    return out


def shifted(seq: np.ndarray, steps: float) -> np.ndarray:
    """seq moved forward by `steps` (fractional) steps: linear interpolation, padded with the last row."""
    k = seq.shape[0]
    s = np.clip(np.arange(k) + steps, 0, k - 1)
    return np.stack([np.interp(s, np.arange(k), seq[:, d]) for d in range(seq.shape[1])], axis=1)


def expected_update(
    nominal: np.ndarray, inputs: np.ndarray, c: np.ndarray, config: sabre.ControllerConfig
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The updated nominal, the unclipped gradient estimate Σ_l w_l (u_l − μ) and the smoothed
    nominal before its projection onto the bounds."""
    w = invariant_weights(c, config.h)
    if w.sum() == 0.0:
        return nominal.copy(), np.zeros_like(nominal), nominal.copy()
    gradient = np.einsum("l,lkd->kd", w, inputs - nominal)
    stepped = nominal + config.step_size * np.clip(gradient, -config.gradient_clip, config.gradient_clip)
    smoothed = savitzky_golay(stepped, config.smoothing_window, config.smoothing_order)
    return np.clip(smoothed, -LIMIT, LIMIT), gradient, smoothed


def expected_nominal(
    nominal: np.ndarray, inputs: np.ndarray, c: np.ndarray, config: sabre.ControllerConfig
) -> tuple[np.ndarray, np.ndarray]:
    """The updated nominal and the unclipped gradient estimate."""
    return expected_update(nominal, inputs, c, config)[:2]


def make_controller(scene: sabre.Scene, choose, **overrides) -> tuple[sabre.Controller, ChosenCosts]:
    settings = dict(
        rollouts=ROLLOUTS,
        horizon=HORIZON,
        dt=DT,
        step_size=0.7,
        gradient_clip=0.2,
        keep_fraction=0.3,
        smoothing_window=WINDOW,
        smoothing_order=ORDER,
        input_limit=(LIMIT,) * scene.nu,
        seed=3,
        threads=1,
    )
    settings.update(overrides)
    task = ChosenCosts(choose)
    return sabre.Controller(scene, task, sabre.ControllerConfig(**settings)), task


def against_ramp(inputs: np.ndarray) -> np.ndarray:
    """A cost with a wide spread that fresh samples can beat the zero sequence on: minus the
    alignment of each sequence with a fixed ramp."""
    k, nu = inputs.shape[1:]
    target = np.linspace(-1.0, 1.0, k)[:, None] * np.linspace(1.0, -1.0, nu)[None, :]
    return -np.sum(inputs * target, axis=(1, 2))


def with_non_finite(inputs: np.ndarray) -> np.ndarray:
    c = against_ramp(inputs)
    c[[3, 7]] = np.inf
    c[[5, 11]] = np.nan
    c[4] = -np.inf
    return c


def test_scene_limits_exceed_the_test_bound(scene):
    # the projection bound is min(dq_limit, input_limit); the formulas below use LIMIT alone
    assert np.all(scene.dq_limit > LIMIT)


def test_first_update_matches_numpy_with_clipping_active(scene):
    # a sharp mapping lets the best sample dominate, so the step is about a whole sample deviation
    controller, task = make_controller(scene, against_ramp, h=60.0)
    controller.update(scene.default_state(), 0.0)
    (inputs,) = task.batches
    zero = np.zeros((controller.config.horizon_steps, scene.nu))
    expected, gradient = expected_nominal(zero, inputs, against_ramp(inputs), controller.config)
    # the case is meant to clip: a sizeable share of the gradient exceeds g_max
    assert np.mean(np.abs(gradient) > controller.config.gradient_clip) > 0.1
    np.testing.assert_allclose(controller.nominal, expected, rtol=0, atol=1e-10)


def test_first_update_matches_numpy_with_clipping_inactive(scene):
    controller, task = make_controller(scene, against_ramp, gradient_clip=50.0, step_size=0.4)
    controller.update(scene.default_state(), 0.0)
    (inputs,) = task.batches
    zero = np.zeros((controller.config.horizon_steps, scene.nu))
    expected, gradient = expected_nominal(zero, inputs, against_ramp(inputs), controller.config)
    assert np.all(np.abs(gradient) < controller.config.gradient_clip)
    np.testing.assert_allclose(controller.nominal, expected, rtol=0, atol=1e-10)


def test_smoothed_nominal_is_projected_onto_the_input_bounds(scene):
    # no clipping, a full step and a sharp mapping: the nominal jumps to about the best sample;
    # wide noise drawn every 8 steps keeps that sample on the bounds in plateaus, at whose corners
    # the smoothed curve overshoots them
    controller, task = make_controller(
        scene, against_ramp, h=60.0, step_size=1.0, gradient_clip=50.0, sigma=(4.0,) * scene.nu, noise_interval=8
    )
    controller.update(scene.default_state(), 0.0)
    (inputs,) = task.batches
    zero = np.zeros((controller.config.horizon_steps, scene.nu))
    expected, _, smoothed = expected_update(zero, inputs, against_ramp(inputs), controller.config)
    assert np.max(np.abs(smoothed)) > LIMIT + 1e-3
    np.testing.assert_allclose(controller.nominal, expected, rtol=0, atol=1e-10)
    assert np.max(np.abs(controller.nominal)) <= LIMIT


def test_non_finite_costs_get_zero_weight_in_the_update(scene):
    controller, task = make_controller(scene, with_non_finite)
    controller.update(scene.default_state(), 0.0)
    (inputs,) = task.batches
    zero = np.zeros((controller.config.horizon_steps, scene.nu))
    expected, _ = expected_nominal(zero, inputs, with_non_finite(inputs), controller.config)
    np.testing.assert_allclose(controller.nominal, expected, rtol=0, atol=1e-10)
    assert controller.stats.failed_rollouts == 5
    # and a NumPy update that let the poisoned rows in as the best samples would differ
    leaked = with_non_finite(inputs)
    leaked[~np.isfinite(leaked)] = np.nanmin(leaked[np.isfinite(leaked)])
    wrong, _ = expected_nominal(zero, inputs, leaked, controller.config)
    assert np.max(np.abs(wrong - expected)) > 1e-3


def test_equal_costs_step_along_the_mean_deviation(scene):
    controller, task = make_controller(scene, lambda u: np.full(u.shape[0], 2.5), gradient_clip=50.0)
    controller.update(scene.default_state(), 0.0)
    (inputs,) = task.batches
    mean_step = controller.config.step_size * inputs.mean(axis=0)
    expected = np.clip(savitzky_golay(mean_step, WINDOW, ORDER), -LIMIT, LIMIT)
    np.testing.assert_allclose(controller.nominal, expected, rtol=0, atol=1e-10)
    assert controller.stats.effective_sample_size == pytest.approx(ROLLOUTS)


def test_all_costs_non_finite_leave_the_nominal_unchanged(scene):
    controller, task = make_controller(scene, against_ramp)
    x = scene.default_state()
    controller.update(x, 0.0)
    before = controller.nominal.copy()
    task.choose = lambda u: np.full(u.shape[0], np.inf)
    controller.update(x, 0.0)
    np.testing.assert_array_equal(controller.nominal, before)
    assert controller.stats.failed_rollouts == ROLLOUTS


def test_second_batch_holds_shifted_nominal_zero_and_best_previous_samples(scene):
    controller, task = make_controller(scene, with_non_finite)
    x = scene.default_state()
    controller.update(x, 0.0)
    first_nominal = controller.nominal.copy()
    elapsed = 2.5 * DT  # a fractional shift exercises the interpolation
    controller.update(x, elapsed)
    first, second = task.batches
    steps = elapsed / DT

    np.testing.assert_allclose(second[0], shifted(first_nominal, steps), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(second[1], 0.0)
    w = invariant_weights(with_non_finite(first), controller.config.h)
    keep = int(np.floor(controller.config.keep_fraction * ROLLOUTS))
    order = sorted(np.flatnonzero(w > 0), key=lambda i: (-w[i], i))[:keep]
    assert len(order) == keep == 6
    for slot, i in enumerate(order):
        np.testing.assert_allclose(
            second[2 + slot],
            shifted(first[i], steps),
            rtol=0,
            atol=1e-12,
            err_msg=f"slot {2 + slot} should hold previous sample {i}",
        )
    # the rest are fresh draws around the shifted nominal, inside the bounds
    fresh = second[2 + keep :]
    assert np.all(np.abs(fresh) <= LIMIT)
    assert not any(np.allclose(f, shifted(p, steps)) for f in fresh for p in first)
    # and the second update follows the same formula on the new batch
    expected, _ = expected_nominal(shifted(first_nominal, steps), second, with_non_finite(second), controller.config)
    np.testing.assert_allclose(controller.nominal, expected, rtol=0, atol=1e-10)
    assert controller.nominal_t0 == pytest.approx(elapsed)


def test_keep_fraction_zero_reuses_no_previous_sample(scene):
    controller, task = make_controller(scene, against_ramp, keep_fraction=0.0)
    x = scene.default_state()
    controller.update(x, 0.0)
    controller.update(x, DT)
    first, second = task.batches
    assert not any(np.allclose(s, shifted(p, 1.0)) for s in second[2:] for p in first)
