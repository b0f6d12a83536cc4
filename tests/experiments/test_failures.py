"""`nerf-transporter failures`: each failed test episode of a cell, judged from its replayed scene."""

import json
from pathlib import Path

import numpy as np
import pytest

from nerf_transporter import geometry
from nerf_transporter.cli import main as cli_main
from nerf_transporter.evaluation.metrics import summarize
from nerf_transporter.evaluation.rollout import NOT_ACHIEVED
from nerf_transporter.experiments.failures import (
    AIMED_OFF,
    AIMED_WITHIN_TOLERANCE,
    PICKED_ANOTHER_BODY,
    aim,
    carried_pose,
    diagnose_cell,
    paired_table,
)
from nerf_transporter.sim import make_env
from nerf_transporter.sim.fingerprint import world_fingerprint

SEED = 3  # a block-insertion test seed whose fixture is tilted by more than the 15 deg tolerance


@pytest.fixture(scope="module")
def scene():
    env = make_env("block-insertion")
    env.reset(seed=SEED)
    oracle = env.task.oracle(env)
    yield env, oracle
    env.close()


def _record(pose_pair):
    return [float(v) for v in np.concatenate([pose_pair[0], pose_pair[1]])]


def _shift_place(action, offset):
    place = (np.asarray(action["place"][0]) + np.asarray(offset), action["place"][1])
    return {"pick": action["pick"], "place": place}


def test_the_oracle_carries_the_object_onto_its_target(scene):
    env, oracle = scene
    carried = carried_pose(env.task.object_pose(env), oracle)
    target = env.task.target_poses[0]
    np.testing.assert_allclose(carried[0], target[0], atol=1e-9)
    assert geometry.rotation_angle(
        geometry.quat_to_matrix(carried[1]), geometry.quat_to_matrix(target[1])
    ) == pytest.approx(0.0, abs=1e-6)
    aimed = aim(env.task, env.task.object_pose(env), oracle)
    assert aimed["missed"] == [] and aimed["errors"]["position"] < 1e-9


def test_an_offset_along_the_approach_is_forgiven_and_one_across_it_is_not(scene):
    env, oracle = scene
    axes = geometry.quat_to_matrix(oracle["place"][1])
    along = aim(env.task, env.task.object_pose(env), _shift_place(oracle, 0.05 * axes[:, 2]))
    across = aim(env.task, env.task.object_pose(env), _shift_place(oracle, 0.03 * axes[:, 0]))
    assert along["missed"] == []
    assert across["missed"] == ["position"]
    assert across["errors"]["position"] == pytest.approx(0.03)


def test_a_flat_place_at_a_steep_stand_misses_in_tilt():
    """hanging-disks' check (the anchor's `match_rp`) judges roll and pitch: a disk carried flat
    to a stand tilted beyond 22.5 deg misses in tilt, not in position."""
    env = make_env("hanging-disks")
    for seed in range(1, 40, 2):
        env.reset(seed=seed)
        roll, pitch, _ = geometry.quat_to_euler(env.task.target_poses[0][1])
        if max(abs(roll), abs(pitch)) > np.radians(25):
            break
    oracle = env.task.oracle(env)
    _, _, yaw = geometry.quat_to_euler(oracle["place"][1])
    flat = {
        "pick": oracle["pick"],
        "place": (oracle["place"][0], geometry.euler_to_quat(0, 0, yaw)),
    }
    aimed = aim(env.task, env.task.object_pose(env), flat)
    env.close()
    assert "tilt" in aimed["missed"] and "position" not in aimed["missed"]


def _cell(tmp_path, episodes, world=None):
    identity = {"task": "block-insertion", "setting": "normal", "method": "mira", "imagery": "nerf"}
    record = {
        "protocol": identity,
        **identity,
        **summarize(episodes),
        "checkpoint": {"step": 2000},
        "world": world or world_fingerprint(),
        "git": {"commit": "abc"},
        "episode_results": episodes,
    }
    path = tmp_path / "results" / "block-insertion" / "mira.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record))
    return record | {"path": str(path)}


def _episode(action, success, failure=None, seed=SEED):
    return {
        "seed": seed,
        "success": success,
        "failure": failure,
        "error": None,
        "action": {key: _record(pose) for key, pose in action.items()},
    }


def _oracle(seed):
    """The oracle action of block-insertion's scene of `seed`."""
    env = make_env("block-insertion")
    env.reset(seed=seed)
    oracle = env.task.oracle(env)
    env.close()
    return oracle


def test_failed_episodes_are_classed_by_pick_aim_and_settling(scene, tmp_path, capsys):
    """One episode a seed (a cell repeats none); each fixture is tilted by 20-30 deg, as SEED's."""
    env, oracle = scene
    oracles = {seed: _oracle(seed) for seed in (5, 7, 9, 13)}
    corner = geometry.BOUNDS[:2, 1] - geometry.PIXEL_SIZE  # the image's last row and column
    table_pick = (np.array([*corner, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))
    # the empty table 20 px inside the other corner, where a pick that scores no object above
    # the table lands (docs/failures.md, "stacking-kits' mira refit on the default imagery")
    inside_corner = geometry.BOUNDS[:2, 0] + 20 * geometry.PIXEL_SIZE
    inner_table_pick = (np.array([*inside_corner, 0.0]), np.array([0.0, 0.0, 0.0, 1.0]))
    episodes = [
        _episode(oracle, True),
        _episode(oracles[5], False, NOT_ACHIEVED, 5) | {"pose_error": {"position_error": 0.2}},
        _episode({"pick": table_pick, "place": oracles[7]["place"]}, False, NOT_ACHIEVED, 7),
        _episode(_shift_place(oracles[9], (0.05, 0.0, 0.0)), False, NOT_ACHIEVED, 9),
        _episode(oracles[13], False, "unreachable: pre-place pose", 13),
        _episode({"pick": inner_table_pick, "place": oracles[5]["place"]}, False, NOT_ACHIEVED, 21),
        {"seed": 15, "success": False, "failure": None, "error": "reset raised", "action": None},
    ]
    record = _cell(tmp_path, episodes)
    classes = [d["class"] for d in diagnose_cell(record, progress=False)]
    assert classes == [
        "success",
        AIMED_WITHIN_TOLERANCE,
        PICKED_ANOTHER_BODY,
        AIMED_OFF,
        "unreachable: pre-place pose",
        PICKED_ANOTHER_BODY,
        "erred",
    ]
    out = tmp_path / "diagnoses.json"
    assert (
        cli_main(["failures", str(tmp_path / "results"), "--json", str(out), "--no-progress"]) == 0
    )
    rows = [line for line in capsys.readouterr().out.splitlines() if "| mira (ours) |" in line]
    assert rows[0].startswith(
        "| block-insertion | mira (ours) | 7 | 1 (0) | 2 | 1: 1 / 0 / 0 | 1 (1) |"
    )
    # both picks of the table counted, one of them on the image's corner
    assert "| 1 unreachable: pre-place pose | 2 (1) | 1 |" in rows[0]
    assert (
        rows[1] == "| block-insertion | mira (ours) | 0/0 | 0/0 | 1/6 | 0/0 |"
    )  # erred: not counted
    # the aims that carried the object all lie in their target's tilt; the pick of the table
    # is left out
    assert rows[2] == "| block-insertion | mira (ours) | 1/4 | 0/0 | 0/0 | 0/0 | 0/0 | 0/0 |"
    stored = json.loads(out.read_text())[0]
    assert [d["class"] for d in stored["episodes_diagnosed"]] == classes
    cell_file = tmp_path / "results" / "block-insertion" / "mira.json"
    assert cli_main(["failures", str(cell_file), "--no-progress"]) == 0  # one cell file
    assert capsys.readouterr().out.count("| mira (ours) |") == 3


def test_a_cell_of_another_world_or_without_episodes_is_refused(scene, tmp_path, capsys):
    _cell(tmp_path, [_episode(scene[1], True)], world="0" * 16)
    assert cli_main(["failures", str(tmp_path / "results"), "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert "measured in world 0000000000000000" in error and "abc" in error
    _cell(tmp_path, [])
    assert cli_main(["failures", str(tmp_path / "results"), "--no-progress"]) == 2
    assert "no episode results" in capsys.readouterr().err
    (tmp_path / "other.json").write_text("{}")
    assert cli_main(["failures", str(tmp_path / "other.json")]) == 2
    assert "other.json lacks method" in capsys.readouterr().err
    assert cli_main(["failures", str(tmp_path / "nothing")]) == 2
    assert "no such directory" in capsys.readouterr().err


def test_two_cell_files_of_one_row_and_column_are_refused_not_one_dropped(scene, tmp_path, capsys):
    """Two sweeps' cells of one row (a recipe beside the table's): the table keeps one cell a
    row and column, so naming both is an error that names them, never a silently shorter table."""
    record = _cell(tmp_path, [_episode(scene[1], True)])
    sweep = tmp_path / "sweep" / "block-insertion" / "mira.json"
    sweep.parent.mkdir(parents=True)
    sweep.write_text(Path(record["path"]).read_text())
    assert cli_main(["failures", record["path"], str(sweep), "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert "are both the mira cell of block-insertion" in error
    assert str(sweep) in error and record["path"] in error
    assert cli_main(["failures", record["path"], record["path"], "--no-progress"]) == 0


def test_a_test_record_is_analysed_after_the_cells_named_by_its_file_and_not_paired(
    scene, tmp_path, capsys
):
    env, oracle = scene
    _cell(tmp_path, [_episode(oracle, True)])
    episodes = [_episode(_shift_place(oracle, (0.05, 0.0, 0.0)), False, NOT_ACHIEVED)]
    tested = {"task": "block-insertion", "setting": "normal", "method": "mira", "imagery": "oracle"}
    record = tested | summarize(episodes) | {"split": "test", "global_step": 2000}
    path = tmp_path / "mira-on-oracle-imagery.json"
    path.write_text(
        json.dumps(record | {"world": world_fingerprint(), "episode_results": episodes})
    )
    assert cli_main(["failures", str(path), str(tmp_path / "results"), "--no-progress"]) == 0
    rows = [line for line in capsys.readouterr().out.splitlines() if "| block-insertion |" in line]
    assert rows[0].startswith("| block-insertion | mira (ours) | 1 | 1 (0) |")
    assert rows[1].startswith(
        "| block-insertion | mira, oracle imagery (mira-on-oracle-imagery.json) | 1 | 0 (0) | 0 "
        "| 1: 1 / 0 / 0 |"
    )
    assert len(rows) == 6  # the summary and two binned tables; no pair of the cell with the record


def test_mira_is_paired_with_every_other_row_of_its_column_on_common_seeds():
    def cell(method, imagery, outcomes, task="block-insertion"):
        episodes = [
            {"seed": seed, "success": success, "error": None} for seed, success in outcomes.items()
        ]
        episodes.append({"seed": 99, "success": False, "error": "reset raised"})  # left out
        return {"task": task, "setting": "normal", "method": method, "imagery": imagery} | {
            "episode_results": episodes
        }

    records = [
        cell("mira", "nerf", {1: True, 3: True, 5: False, 7: False}),
        cell("mira", "oracle", {1: True, 3: False, 5: True, 7: False}),
        cell("transporter_se2", None, {1: False, 3: False, 5: False}),
        cell("form2fit", None, {1: True}, task="hanging-disks"),  # no mira in its column
    ]
    header, rows = paired_table(records)
    assert header[:3] == ["column", "mira against", "seeds"]
    assert rows == [
        ["block-insertion", "mira, oracle imagery", "4", "1", "1", "1", "1", "1"],
        ["block-insertion", "Transporter-SE(2)", "3", "0", "2", "0", "1", "0.5"],
    ]
