"""Tests of the episode files (Episode.save/load) and of the browser viewer, rendered in headless chromium."""

from __future__ import annotations

import os
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre.episode import pose_to_xyz_rpy

#: where the browser test also copies its screenshots (``SABRE_SCREENSHOTS=docs/img`` refreshes the README's)
SHOTS = os.environ.get("SABRE_SCREENSHOTS")


def short_episode(obj: str = "shelf", duration: float = 0.3) -> sabre.Episode:
    scene = sabre.Scene.load(obj=obj)
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=3, rollouts=8))
    return sabre.run_episode(scene, controller, duration, seed=3, x0=scene.default_state(), record_plans=True, progress=False)


def test_episode_save_load_round_trips_every_array_and_scalar(tmp_path):
    episode = short_episode("drawer")
    path = tmp_path / "episode.npz"
    episode.save(path)
    loaded = sabre.Episode.load(path)
    assert loaded.scene.object_name == "drawer" and loaded.scene.robot_name == episode.scene.robot_name
    np.testing.assert_array_equal(loaded.scene.object_pose, episode.scene.object_pose)
    for name in (
        "time",
        "state",
        "reference",
        "command",
        "wrench",
        "tau_ext",
        "contact",
        "cost",
        "phase",
        "tank_energy",
        "planning_times",
        "plan_time",
        "plan_hand_path",
        "contact_points",
        "contact_forces",
        "sample_hand_paths",
        "sample_weights",
    ):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(episode, name), err_msg=name)
    assert loaded.contact.dtype == bool
    assert (loaded.phases, loaded.success, loaded.time_to_success, loaded.variant) == (
        episode.phases,
        episode.success,
        episode.time_to_success,
        episode.variant,
    )
    assert loaded.dissipated_energy() == episode.dissipated_energy()


def test_recorded_nominal_hand_path_starts_at_the_grasp_frame_of_the_plan_state():
    episode = short_episode()
    scene = episode.scene
    assert episode.plan_hand_path.shape[0] == len(episode.plan_time) > 0
    assert episode.plan_hand_path.shape[2] == 3
    # the first plan starts from x0: its path's first point is the grasp frame there
    start = scene.fk(episode.state[0, : scene.nq] * 0 + scene.default_state()[: scene.nq], "grasp")[:3, 3]
    np.testing.assert_allclose(episode.plan_hand_path[0, 0], start, atol=1e-9)


def test_recorded_samples_are_the_heaviest_rollouts_with_their_invariant_weights():
    episode = short_episode()
    p, s, k1, _ = episode.sample_hand_paths.shape
    assert p == len(episode.plan_time) and s == 8 and k1 == episode.plan_hand_path.shape[1]
    w = episode.sample_weights
    # all 8 rollouts kept: their weights (55) sum to one, heaviest first
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=1e-12)
    assert (np.diff(w, axis=1) <= 0).all()
    # every sampled rollout starts where the plan starts
    np.testing.assert_allclose(episode.sample_hand_paths[:, :, 0], episode.plan_hand_path[:, None, 0].repeat(s, 1), atol=1e-9)


def test_recording_plans_does_not_change_the_episode():
    scene = sabre.Scene.load(obj="shelf")
    runs = []
    for record in (False, True):
        controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=3, rollouts=8))
        runs.append(
            sabre.run_episode(scene, controller, 0.3, seed=3, x0=scene.default_state(), record_plans=record, progress=False)
        )
    np.testing.assert_array_equal(runs[0].state, runs[1].state)


def test_recording_restores_the_controllers_own_choice_of_keeping_samples():
    scene = sabre.Scene.load(obj="shelf")
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=3, rollouts=8))
    for kept in (False, True):
        controller.keep_samples = kept
        episode = sabre.run_episode(scene, controller, 0.1, seed=3, x0=scene.default_state(), record_plans=True, progress=False)
        assert episode.sample_hand_paths is not None  # recording keeps the samples while it runs
        assert controller.keep_samples is kept


def test_plan_at_gives_the_plan_running_at_a_time():
    episode = short_episode()
    times = episode.plan_time
    assert len(times) == 6  # 0.3 s at 20 Hz
    for j, t in enumerate(times):
        for at in (t, t + 0.5 * (times[1] - times[0])):
            plan = episode.plan_at(at)
            assert plan.time == t
            np.testing.assert_array_equal(plan.hand_path, episode.plan_hand_path[j])
            np.testing.assert_array_equal(plan.sample_hand_paths, episode.sample_hand_paths[j])
            np.testing.assert_array_equal(plan.sample_weights, episode.sample_weights[j])
            np.testing.assert_array_equal(plan.contact_points, episode.contact_points[j])
            np.testing.assert_array_equal(plan.obstacles, episode.obstacles[j])
    assert episode.plan_at(-1.0).time == times[0]
    unrecorded = sabre.run_episode(
        episode.scene,
        sabre.Controller(episode.scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=3, rollouts=8)),
        0.1,
        x0=episode.scene.default_state(),
        progress=False,
    )
    assert unrecorded.plan_at(0.0) is None


def test_plan_recorder_keeps_the_heaviest_samples_and_pads_only_the_episode_arrays():
    from sabre.episode import PlanRecorder

    scene = sabre.Scene.load(obj="drawer")
    recorder = PlanRecorder(scene)
    with pytest.raises(sabre.InvalidValueError):
        recorder.latest()
    x = scene.default_state()
    states = np.repeat(x[None], 4, axis=0)  # a plan of K = 3 steps that stays at x
    grasp = scene.fk(x[: scene.nq], "grasp")[:3, 3]
    samples = np.repeat(states[None], PlanRecorder.SAMPLES + 4, axis=0)
    weights = np.arange(PlanRecorder.SAMPLES + 4, dtype=float)
    weights /= weights.sum()
    recorder.append(0.0, states, np.zeros((0, 3)), np.zeros((0, 3)), sample_states=samples, sample_weights=weights)
    recorder.append(
        0.05,
        states,
        [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
        [[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]],
        sample_states=samples,
        sample_weights=weights,
        obstacles=[[0.1, 0.2, 0.3, 0.4]],
    )
    latest = recorder.latest()
    assert latest.time == 0.05 and len(recorder) == 2
    np.testing.assert_allclose(latest.hand_path, np.repeat(grasp[None], 4, axis=0), atol=1e-12)
    np.testing.assert_array_equal(latest.contact_points, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    np.testing.assert_array_equal(latest.obstacles, [[0.1, 0.2, 0.3, 0.4]])
    np.testing.assert_array_equal(latest.sample_weights, weights[::-1][: PlanRecorder.SAMPLES])
    assert latest.sample_hand_paths.shape == (PlanRecorder.SAMPLES, 4, 3)
    arrays = recorder.arrays()
    assert arrays["contact_points"].shape == (2, 2, 3) and np.isnan(arrays["contact_points"][0]).all()
    assert arrays["obstacles"].shape == (2, 1, 4) and np.isnan(arrays["obstacles"][0]).all()
    np.testing.assert_array_equal(arrays["contact_forces"][1], [[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]])
    np.testing.assert_array_equal(arrays["plan_time"], [0.0, 0.05])
    assert arrays["sample_hand_paths"].shape == (2, PlanRecorder.SAMPLES, 4, 3)


def test_pose_to_xyz_rpy_inverts_the_scene_object_placement():
    pose = [0.3, -1.2, 0.1, 0.2, -0.4, 2.5]
    scene = sabre.Scene.load(obj="microwave", obj_pose=pose)
    np.testing.assert_allclose(pose_to_xyz_rpy(scene.object_pose), pose, atol=1e-12)


def test_load_rejects_a_file_that_is_not_an_episode(tmp_path):
    path = tmp_path / "other.npz"
    np.savez(path, a=np.zeros(3))
    with pytest.raises(sabre.InvalidValueError):
        sabre.Episode.load(path)


def test_urdf_visuals_read_the_robot_primitives_with_their_colours():
    from sabre.viz.viewer import asset_path, urdf_visuals

    shapes = urdf_visuals(asset_path("robots", "royalpanda"))
    links = {s.link for s in shapes}
    assert {"base_link", "panda_link4", "hook_finger"} <= links
    footprint = next(s for s in shapes if s.link == "base_link" and s.kind == "cylinder")
    assert footprint.size == (0.53, 0.35)
    np.testing.assert_allclose(footprint.origin[:3, 3], [0.0, 0.0, 0.225])


def test_viewer_without_viser_raises_missing_extra(monkeypatch):
    # None in sys.modules makes every import of the module fail, as when the extra is not installed
    monkeypatch.setitem(sys.modules, "viser", None)
    from sabre.viz.viewer import Viewer

    with pytest.raises(sabre.MissingExtraError, match=r"sabre-mpc\[viewer\]' \(missing: viser\)"):
        Viewer(sabre.Scene.load())


def opening_episode() -> sabre.Episode:
    """The controller opening the shelf from the hooked state: the door swings open and the robot
    follows it, so both are drawn in different places at the start and at the end."""
    scene = sabre.Scene.load(obj="shelf")
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=0))
    episode = sabre.run_episode(
        scene, controller, 5.0, seed=0, x0=sabre.paper.scenarios.hooked_state(scene), record_plans=True, progress=False
    )
    assert episode.opening[-1] - episode.opening[0] > 0.3, "the recorded door must swing for this test"
    return episode


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(_chromium() is None, reason="Debian's chromium is not installed (make test-setup installs it)")
def test_browser_draws_robot_and_door_and_both_move_along_the_timeline(tmp_path):
    pytest.importorskip("viser")
    playwright = pytest.importorskip("playwright.sync_api")
    from sabre.viz.viewer import Viewer

    episode = opening_episode()
    viewer = Viewer(episode.scene, port=0)
    try:
        timeline = viewer.load_episode(episode)
        with playwright.sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=_chromium(),
                headless=True,
                args=[
                    "--use-gl=angle",
                    "--use-angle=swiftshader",
                    "--enable-unsafe-swiftshader",
                    "--ignore-gpu-blocklist",
                    "--no-sandbox",
                ],
            )
            page = browser.new_page(viewport={"width": 900, "height": 560})
            page.goto(f"http://127.0.0.1:{viewer.port}/")
            page.wait_for_selector("canvas", timeout=60_000)
            start = _settled_screenshot(page, tmp_path / "start.png")
            timeline.seek(float(episode.time[-1]))
            end = _settled_screenshot(page, tmp_path / "end.png")
            browser.close()
    finally:
        viewer.close()
    if SHOTS:
        from PIL import Image

        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        for name in ("start", "end"):  # a 256-colour palette keeps the README's images small
            Image.open(tmp_path / f"{name}.png").quantize(256).save(Path(SHOTS) / f"viewer_{name}.png", optimize=True)

    a, b = _pixels(start), _pixels(end)
    background = np.median(a.reshape(-1, 3), axis=0)
    drawn = np.abs(a - background).sum(axis=2) > 60
    # robot (grey links) and shelf (wood colour) cover a real part of the 3D view
    assert drawn.mean() > 0.02
    door = _brown(a)  # the shelf door's URDF colour is wood brown; nothing else in the scene is
    assert door.mean() > 0.002, "the shelf door is not drawn"
    assert (_brown(b) != door).mean() > 0.001, "the door did not swing"
    changed = np.abs(a - b).sum(axis=2) > 60
    assert changed.mean() > 0.005, "nothing moved between the start and the end of the timeline"


def _settled_screenshot(page, path: Path) -> bytes:
    """Screenshots until two consecutive ones agree (the scene has streamed in and rendered), with
    the page's notices (headless Chromium renders WebGL in software, which viser points out) closed."""
    previous = None
    for _ in range(40):
        page.wait_for_timeout(500)
        for close in page.locator("button.mantine-Notification-closeButton").all():
            close.click()
        shot = page.screenshot(path=str(path))
        if previous is not None and shot == previous:
            return shot
        previous = shot
    return previous


def _pixels(png: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int32)


def _brown(pixels: np.ndarray) -> np.ndarray:
    r, g, b = pixels[..., 0], pixels[..., 1], pixels[..., 2]
    return (r - b > 30) & (r > g) & (g > b)


def test_run_episode_with_a_live_viewer_leaves_it_showing_the_final_state():
    pytest.importorskip("viser")
    from sabre.viz.viewer import Viewer

    scene = sabre.Scene.load(obj="shelf")
    viewer = Viewer(scene, port=0)
    try:
        controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=1, rollouts=8))
        plant = sabre.Plant(scene)
        episode = sabre.run_episode(
            scene, controller, 0.2, seed=1, x0=scene.default_state(), viewer=viewer, plant=plant, progress=False
        )
        final = plant.state
        hand = viewer._robot_links["panda_link7"]
        np.testing.assert_allclose(hand.position, scene.fk(final[: scene.nq], "panda_link7")[:3, 3], atol=1e-6)
        assert viewer._time.value == pytest.approx(plant.time, abs=1e-3)
        assert viewer._tank.value == pytest.approx(controller.tank.energy, abs=1e-3)
        assert episode.plan_hand_path is not None and len(episode.plan_time) == 4
    finally:
        viewer.close()


def _help_sections(text: str) -> tuple[str, dict[str, str]]:
    """argparse's help text read back: the usage (on one line) and {argument as listed: its help}."""
    usage, *_ = text.split("\n\n")
    entries: dict[str, str] = {}
    name = None
    for line in text.splitlines():
        if re.match(r"^  \S", line):  # an argument: its name, then its help after two spaces or more
            name, _, help_text = line.strip().partition("  ")
            entries[name] = help_text.strip()
        elif name is not None and line.startswith("   "):  # its help, wrapped
            entries[name] = f"{entries[name]} {line.strip()}".strip()
        else:
            name = None
    return " ".join(usage.split()), entries


def test_view_help_lists_the_options_the_parser_declares_which_are_replays_arguments(capsys):
    """``view --help`` exits 0 with the usage, the description and the argument list of exactly the
    arguments the parser declares, each with its help; those are the episode's path and replay()'s
    keyword arguments, with replay()'s defaults."""
    import argparse
    import inspect

    from sabre.cli import main
    from sabre.cli.main import build_parser
    from sabre.viz.viewer import replay

    with pytest.raises(SystemExit) as exit_:
        main(["view", "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    usage, entries = _help_sections(text)

    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    view = commands.choices["view"]
    expected_usage, expected_entries = ["usage: python -m sabre view"], {}
    for action in view._actions:
        if action.option_strings:
            metavar = "" if action.nargs == 0 else f" {action.metavar or action.dest.upper()}"
            expected_usage.append(f"[{action.option_strings[0]}{metavar}]")
            expected_entries[", ".join(f"{o}{metavar}" for o in action.option_strings)] = action.help
        else:
            expected_entries[action.dest] = action.help
    expected_usage += [a.dest for a in view._actions if not a.option_strings]  # positionals last
    assert usage == " ".join(expected_usage)
    assert entries == expected_entries
    assert " ".join(view.description.split()) in " ".join(text.split())

    keywords = {k: p.default for k, p in inspect.signature(replay).parameters.items() if p.kind is p.KEYWORD_ONLY}
    options = {a.dest: a.default for a in view._actions if a.option_strings and a.dest != "help"}
    assert options == keywords  # every server setting of replay(), its default unchanged
    assert [a.dest for a in view._actions if not a.option_strings] == ["episode"]


def test_viewer_shows_the_filters_obstacles_and_the_constraints_near_their_bound():
    pytest.importorskip("viser")
    from sabre.viz.viewer import Viewer

    scene = sabre.Scene.load(obj="shelf")
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=2, rollouts=8, variant="IO"))
    controller.add_obstacle([0.2, -2.0, 0.5], 0.1)
    viewer = Viewer(scene, port=0)
    try:
        x0 = sabre.paper.paper_start_state(scene)  # elbow 0.12 rad from its limit
        episode = sabre.run_episode(scene, controller, 0.1, seed=2, x0=x0, viewer=viewer, progress=False)
        np.testing.assert_allclose(episode.obstacles[0, 0], [0.2, -2.0, 0.5, 0.1])
        assert viewer._shown_obstacles == 1
        h = sabre.SafetyFilter(scene).constraint_rows(x0).h
        names = sabre.SafetyFilter(scene).row_names
        expected = [n for n, v in zip(names, h) if np.isfinite(v) and v < 0.05]
        assert expected, "the paper's start has rows near their bound"
        timeline = viewer.load_episode(episode)
        timeline.seek(0.0)
        assert viewer._active.value.split(", ")[: len(expected[:6])] == expected[:6]
    finally:
        viewer.close()
