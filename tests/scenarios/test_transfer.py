"""The transfer experiment: the object's damping and friction scaled in the plant only, in both plants; the
sweep's runs; one short run in each plant; the side-by-side table."""

from __future__ import annotations

import numpy as np
import pytest

import sabre
from sabre.errors import InvalidValueError
from sabre.experiments import run_one, specs
from sabre.experiments.transfer import (
    SCALES,
    SIMULATORS,
    scaled_object_urdf,
    scaled_plant,
    transfer_configs,
    transfer_metrics,
    transfer_table,
)


@pytest.mark.parametrize("obj", sabre.OBJECTS)
def test_scaling_changes_the_joints_damping_and_friction_only(obj):
    scene = sabre.Scene.load(obj=obj)
    pose = scene.object_pose[:3, 3].tolist() + [0.0, 0.0, 0.0]
    scaled = sabre.Scene.from_urdf_strings(
        sabre.assets.urdf_text("royalpanda"), scaled_object_urdf(sabre.assets.urdf_text(obj), 2.5), pose
    )
    np.testing.assert_allclose(scaled.object_damping, 2.5 * scene.object_damping)
    np.testing.assert_allclose(scaled.object_friction, 2.5 * scene.object_friction)
    o = scene.o_upper / 2
    for frame in scene.object_frame_names:
        np.testing.assert_allclose(scaled.object_fk(o, frame), scene.object_fk(o, frame), atol=1e-12)
    np.testing.assert_array_equal(scaled.o_upper, scene.o_upper)


def test_both_plants_get_the_scaled_object_and_the_controllers_scene_keeps_its_own():
    pytest.importorskip("mujoco")
    scene = sabre.Scene.load(obj="drawer")
    for simulator in SIMULATORS:
        plant = scaled_plant(scene, simulator, 3.0)
        assert isinstance(plant, sabre.PlantInterface)
        np.testing.assert_allclose(plant.scene.object_damping, 3.0 * scene.object_damping)
        np.testing.assert_allclose(plant.scene.object_friction, 3.0 * scene.object_friction)
        np.testing.assert_allclose(plant.scene.object_pose, scene.object_pose)
    mujoco = scaled_plant(scene, "mujoco", 3.0)
    assert mujoco.model.dof_damping[-1] == pytest.approx(3.0 * scene.object_damping[0])
    assert mujoco.model.dof_frictionloss[-1] == pytest.approx(3.0 * scene.object_friction[0])
    with pytest.raises(InvalidValueError):
        scaled_plant(scene, "gazebo", 1.0)


def test_the_sweep_is_every_object_variant_plant_and_scale_at_every_seed():
    runs = specs("transfer", 10, short=False)
    assert len(runs) == len(sabre.OBJECTS) * 2 * len(SIMULATORS) * len(SCALES) * 10 == 480
    assert len({r.key for r in runs}) == len(runs)
    assert {r.options["plan_delay"] for r in runs} == {0.02}
    assert {r.options["variant"] for r in runs} == {"N", "IO"}
    # its runs name their own plants: a plant for every experiment (`experiment all --plant ...`) leaves them be
    assert specs("transfer", 1, short=True, plant="sabre.mujoco:MujocoPlant") == specs("transfer", 1, short=True)
    with pytest.raises(InvalidValueError, match="gazebo"):
        transfer_configs(simulators=("gazebo",))


def test_a_short_run_in_each_plant_and_the_table_side_by_side():
    pytest.importorskip("mujoco")
    configs = transfer_configs(objects=("drawer",), variants=("IO",), scales=(2.0,), duration=0.5)
    records = []
    for config in configs:
        spec = sabre.experiments.RunSpec("transfer", tuple(sorted(config.items())), 0)
        result = run_one(spec)
        assert set(result["metrics"]) >= {"success", "time_to_success", "mean_wrench", "tank_min", "failed"}
        assert result["metrics"]["failed"] == 0.0 and result["metrics"]["tank_min"] > 0.0
        records.append({"config": spec.options, "seed": 0, **result})
    failed = {"config": {**records[0]["config"], "scale": 3.0}, "seed": 1, "metrics": transfer_metrics(None)}
    table = transfer_table(records + [failed])
    lines = table.splitlines()
    assert lines[0].count("opened") == 2 and "sabre: tank min" in lines[0] and "mujoco: tank min" in lines[0]
    assert any(line.startswith("| drawer | IO | ×2 | 0/1 |") for line in lines)
    assert any("×3" in line and "(1 diverged)" in line for line in lines)
