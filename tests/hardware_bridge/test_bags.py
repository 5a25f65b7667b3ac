"""Nothing recorded is lost: recordings survive SIGINT, SIGTERM, SIGHUP and exceptions (the bag is
closed and replays up to the last complete step), and every class of corrupted bag gives a
one-line error naming the file, or replays its valid part and reports what it skipped."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hardware_bridge.bag import BagError, ReplayWorld, replay_env
from hardware_bridge.faults import CORRUPTIONS, copy_bag
from swarm_phd.cli import main
from swarm_phd.export_bag import export_sim_episode
from tests.hardware_bridge.conftest import crash_in_step

ROOT = Path(__file__).resolve().parents[2]


def _markers_committed(bag: Path) -> int:
    db = bag / f"{bag.name}.db3"
    if not db.exists():
        return 0
    try:
        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=0.2)
        try:
            row = con.execute(
                "select count(*) from messages m join topics t on m.topic_id = t.id "
                "where t.name = '/bridge/step'"
            ).fetchone()
        finally:
            con.close()
        return int(row[0])
    except sqlite3.Error:
        return 0


def _run_until_recorded(cmd: list[str], bag: Path, n_markers: int, timeout_s: float):
    proc = subprocess.Popen(
        cmd,
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        if _markers_committed(bag) >= n_markers:
            break
        time.sleep(0.1)
    assert proc.poll() is None, proc.stderr.read().decode()
    return proc


# Subprocesses: generous limits, a cold numba cache compiles the kernels first (~1 min).
@pytest.mark.timeout(300)
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_bridge_recording_survives_a_signal(tmp_path, signum):
    bag = tmp_path / "rec"
    cmd = [sys.executable, "-m", "swarm_phd.cli", "bridge", "--loopback", "--steps", "100000"]
    proc = _run_until_recorded(cmd + ["--record", str(bag)], bag, 8, 200.0)
    seen = _markers_committed(bag)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=30)
    err = err.decode()
    assert proc.returncode == 128 + signum, err
    assert "Traceback" not in err
    assert signal.Signals(signum).name in err and "bag" in err
    assert (bag / "metadata.yaml").is_file()
    world = ReplayWorld(bag)
    assert world.n_steps() >= seen - 1  # the reset marker counts in ``seen``
    assert not world.skipped(), world.skipped()
    assert main(["replay", str(bag)]) == 0


@pytest.mark.timeout(300)
def test_export_bag_survives_sigterm(tmp_path):
    bag = tmp_path / "exp"
    cmd = [sys.executable, "-m", "swarm_phd.cli", "export-bag", "--out", str(bag)]
    proc = _run_until_recorded(cmd + ["--duration", "100000"], bag, 20, 200.0)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    # Twice (CI, 2026-12-03 and 12-05) this exited 1: SIGTERM's exception raised inside
    # numba's kernel loading came out as a SystemError. The command line now re-raises the
    # signal's exception (tests/test_cli.py); keep the stderr if it ever recurs.
    assert proc.returncode == 128 + signal.SIGTERM, err.decode()
    assert b"Traceback" not in err, err.decode()
    world = ReplayWorld(bag)
    assert world.n_steps() >= 19 and not world.skipped()


SIGNAL_PAIRS = [
    (signal.SIGINT, signal.SIGINT, 0.01),
    (signal.SIGINT, signal.SIGTERM, 0.04),
    (signal.SIGTERM, signal.SIGHUP, 0.1),
    (signal.SIGHUP, signal.SIGINT, 0.02),
]


def _second_signal_case(cmd: list[str], bag: Path, n_markers: int, first, second, gap_s):
    proc = _run_until_recorded(cmd, bag, n_markers, 200.0)
    seen = _markers_committed(bag)
    proc.send_signal(first)
    time.sleep(gap_s)
    proc.send_signal(second)
    _, err = proc.communicate(timeout=60)
    err = err.decode()
    # The status of the signal that ended it: the second, held until the bag was closed, or
    # the first when the second came after the clean-up (then ignored).
    assert proc.returncode in (128 + first, 128 + second), err
    assert "Traceback" not in err, err
    assert f"bag {bag} closed" in err, err  # what the message says is what the disk holds
    assert (bag / "metadata.yaml").is_file()
    world = ReplayWorld(bag)
    assert world.n_steps() >= seen - 1
    assert not world.skipped(), world.skipped()


@pytest.mark.timeout(300)
@pytest.mark.parametrize("first, second, gap_s", SIGNAL_PAIRS, ids=lambda x: str(x))
def test_a_second_signal_10_to_100_ms_later_still_leaves_a_closed_bag(
    tmp_path, first, second, gap_s
):
    bag = tmp_path / "rec"
    cmd = [sys.executable, "-m", "swarm_phd.cli", "bridge", "--loopback", "--steps", "100000"]
    _second_signal_case(cmd + ["--record", str(bag)], bag, 8, first, second, gap_s)
    assert main(["replay", str(bag)]) == 0


@pytest.mark.timeout(300)
@pytest.mark.parametrize("first, second, gap_s", SIGNAL_PAIRS[:2], ids=lambda x: str(x))
def test_export_bag_survives_two_signals(tmp_path, first, second, gap_s):
    bag = tmp_path / "exp"
    cmd = [sys.executable, "-m", "swarm_phd.cli", "export-bag", "--out", str(bag)]
    _second_signal_case(cmd + ["--duration", "100000"], bag, 20, first, second, gap_s)


@pytest.mark.timeout(60)
def test_recording_survives_an_exception_in_step(lab, tmp_path, monkeypatch):
    bag = tmp_path / "exc"
    _, env = lab(record=str(bag), max_steps=1000)
    for _ in range(5):
        env.step({a: np.array([0.1, 0.0]) for a in env.agents})
    crash_in_step(env, monkeypatch, env.world.limiter, "limit", v=0.1)
    env.close()  # the bag is complete
    world = ReplayWorld(bag)
    assert world.n_steps() == 5 and not world.skipped()


@pytest.mark.timeout(60)
def test_replay_judges_odometry_with_the_recorded_jump_factor(lab, tmp_path):
    """A bag remembers the bridge's ``odometry_jump_factor``: with a factor so tight that a
    spin at full turn rate looks like a jump, the replay refuses the same increments as the
    live run did (with the default 3.0 it would integrate them, and feed other odometry)."""
    bag = tmp_path / "spin"
    _, env = lab(record=str(bag), max_steps=1000, bridge={"odometry_jump_factor": 0.1})
    turn = env.config.robot.max_turn_rate_radps
    for _ in range(15):
        env.step({a: np.array([0.0, turn]) for a in env.agents})
    live = env.world.counters_snapshot().get("odometry.implausible", 0)
    env.close()  # the bag is complete
    assert live > 0
    replay = replay_env(bag)
    try:
        assert replay.world.assembler.jump_factor == 0.1
        replay.reset()
        while replay.agents:
            replay.step({a: np.zeros(2) for a in replay.agents})
        assert replay.world.counters.get("odometry.implausible") == live
    finally:
        replay.close()


# ---------------------------------------------------------------------------- corruption
@pytest.fixture(scope="module")
def good_bag(tmp_path_factory) -> Path:
    bag = tmp_path_factory.mktemp("good") / "sim"
    export_sim_episode(bag, preset="seed-lab", duration_s=1.0, seed=4)
    return bag


@pytest.mark.timeout(60)
@pytest.mark.parametrize("name,corrupt,expected", CORRUPTIONS, ids=[c[0] for c in CORRUPTIONS])
def test_corrupted_bags_give_one_line_errors_or_replay_the_valid_part(
    good_bag, tmp_path, capsys, name, corrupt, expected
):
    bag = copy_bag(good_bag, tmp_path / "bag")
    corrupt(bag)
    code = main(["replay", str(bag)])
    out, err = capsys.readouterr()
    assert "Traceback" not in err + out
    if expected == "error" or (expected == "any" and code != 0):
        assert code == 2, (name, out, err)
        lines = [line for line in err.splitlines() if line.strip()]
        assert len(lines) == 1, err
        assert str(bag) in lines[0], lines[0]
        if expected == "error":
            with pytest.raises(BagError):
                ReplayWorld(bag)
        return
    assert code == 0, (name, err)
    if expected != "any":
        world = ReplayWorld(bag)
        skipped = world.skipped()
        assert skipped.get(expected, 0) > 0, skipped
        assert "skipped" in err, err


def test_intact_bag_reports_no_skips(good_bag, capsys):
    assert main(["replay", str(good_bag)]) == 0
    _, err = capsys.readouterr()
    assert "skipped" not in err
    assert ReplayWorld(good_bag).skipped() == {}


def _delete_topic_rows(bag: Path, pattern: str) -> None:
    db = next(bag.glob("*.db3"))
    con = sqlite3.connect(db)
    try:
        con.execute(
            "delete from messages where topic_id in (select id from topics where name like ?)",
            (pattern,),
        )
        con.commit()
    finally:
        con.close()


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    "pattern, robot, word",
    [
        ("/ugv_1/odom%", "ugv_1", "odometry"),  # a sensor missing
        ("/ugv_2/%", "ugv_2", "odometry"),  # a robot missing altogether
        ("/mocap/ugv_0/%", "ugv_0", "motion capture"),
    ],
)
def test_a_bag_without_a_robots_odometry_or_truth_is_refused_naming_them(
    good_bag, tmp_path, capsys, pattern, robot, word
):
    bag = copy_bag(good_bag, tmp_path / "bag")
    _delete_topic_rows(bag, pattern)
    assert main(["replay", str(bag)]) == 2
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err and len(err.strip().splitlines()) == 1, err
    assert str(bag) in err and robot in err and word in err and "refused" in err, err


@pytest.mark.timeout(120)
def test_a_missing_camera_is_named_reported_stale_and_never_fed(good_bag, tmp_path, capsys):
    bag = copy_bag(good_bag, tmp_path / "bag")
    _delete_topic_rows(bag, "/ugv_3/camera/%")
    world = ReplayWorld(bag)
    assert world.missing == {"ugv_3": ("camera",)}
    step = world.reset()
    assert "camera" in step.stale["ugv_3"]
    assert main(["replay", str(bag), "--json"]) == 0
    out, err = capsys.readouterr()
    assert "ugv_3: camera" in err and "stale" in err, err
    import json

    result = json.loads(out)
    assert result["missing"] == {"ugv_3": ["camera"]}
    stale = result["episodes"][0]["stale_steps"]
    assert stale, result["episodes"][0]


@pytest.mark.timeout(60)
def test_a_fifo_in_the_bag_is_refused_at_once(good_bag, tmp_path, capsys):
    bag = copy_bag(good_bag, tmp_path / "bag")
    db = next(bag.glob("*.db3"))
    db.unlink()
    os.mkfifo(db)
    t0 = time.monotonic()
    assert main(["replay", str(bag)]) == 2
    assert time.monotonic() - t0 < 10.0
    err = capsys.readouterr().err
    assert "FIFO" in err and db.name in err, err


@pytest.mark.timeout(60)
def test_an_unopenable_database_with_an_absurd_count_ends_in_bounded_time(
    good_bag, tmp_path, capsys
):
    """rosbags refuses the database (a damaged header), and metadata.yaml claims 10^15
    messages: the salvage looks up no more rows than the file can hold and stops after a
    long run of empty ids."""
    bag = copy_bag(good_bag, tmp_path / "bag")
    meta = bag / "metadata.yaml"
    text = meta.read_text()
    import re

    meta.write_text(re.sub(r"message_count: \d+", "message_count: 1000000000000000", text))
    db = next(bag.glob("*.db3"))
    data = bytearray(db.read_bytes())
    data[28:32] = b"\xff\xff\xff\xff"  # an impossible page count: rosbags' sqlite refuses
    data[60:64] = b"\xff\xff\xff\xff"
    db.write_bytes(bytes(data))
    t0 = time.monotonic()
    code = main(["replay", str(bag)])
    elapsed = time.monotonic() - t0
    out, err = capsys.readouterr()
    assert elapsed < 30.0, elapsed
    assert "Traceback" not in out + err
    assert code == 0 and "database refused by rosbags" in err, err
    world = ReplayWorld(bag)
    assert world.skipped().get("bag.salvaged") == 1 and world.n_steps() >= 1
