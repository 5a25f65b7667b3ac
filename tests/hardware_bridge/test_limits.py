"""Limits: every safety field of BridgeConfig is bounded (a clear error naming the field and the
value, before anything connects), actions must be real numbers, one bridge process per robot,
and ``evaluate --out`` never silently replaces earlier results."""

from __future__ import annotations

import dataclasses
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hardware_bridge import real_env
from hardware_bridge.claim import RobotClaim, RobotClaimedError, lock_path
from hardware_bridge.config import BOUNDS, INT_FIELDS, BridgeConfig
from swarm_phd.cli import main

ROOT = Path(__file__).resolve().parents[2]

#: Hostile values: (field, value). Every one must be refused with the field and value named.
HOSTILE = [
    ("watchdog_timeout_s", 1e9),
    ("watchdog_timeout_s", 0.0),
    ("watchdog_timeout_s", math.nan),
    ("watchdog_timeout_s", math.inf),
    ("watchdog_timeout_s", -0.5),
    ("watchdog_timeout_s", "0.5"),
    ("watchdog_timeout_s", True),
    ("watchdog_poll_s", 10.0),
    ("watchdog_poll_s", 0.0),
    ("watchdog_repeat_s", 1e6),
    ("step_overrun_s", 1e9),
    ("step_overrun_s", 0.0),
    ("robot_cmd_timeout_s", 3600.0),
    ("max_future_s", 1e9),
    ("max_past_s", 1e12),
    ("max_speed_mps", 1e9),
    ("max_speed_mps", -1.0),
    ("max_turn_rate_radps", 1e6),
    ("max_accel_mps2", math.inf),
    ("max_turn_accel_radps2", 1e9),
    ("stale_odometry_s", 1e9),
    ("stale_lidar_s", -1.0),
    ("stale_camera_s", 1e9),
    ("stale_mocap_s", math.nan),
    ("stale_uav_s", 1e9),
    ("transport_grace_s", 1e9),
    ("ping_interval_s", 1e9),
    ("ping_timeout_s", 0.0),
    ("connect_timeout_s", 1e9),
    ("reset_timeout_s", 1e9),
    ("reconnect_initial_delay_s", 1e9),
    ("reconnect_max_delay_s", 1e9),
    ("duplicate_window_s", 1e9),
    ("max_position_m", 1e300),
    ("odometry_jump_factor", 1e9),
    ("queue_length", 10**9),
    ("queue_length", 1.5),
    ("throttle_rate_ms", -1),
    ("throttle_rate_ms", 10**9),
    ("buffer_length", 10**12),
    ("max_beams", 10**9),
    ("max_bearings", 0),
    ("max_message_bytes", 10**15),
    ("hard_max_message_bytes", 10**15),
    ("use_mocap", "yes"),
    ("guard_process", 0),
    ("stamped_commands", None),
    ("required_sensors", "odometry"),
    ("required_sensors", ("sonar",)),
    ("unstamped_bearings", "ugv_0"),
    ("unstamped_bearings", 7),
    ("geofence_m", (0.0, math.inf, 0.0, 1.0)),
    ("geofence_m", (1.0, 0.0, 0.0, 1.0)),
    ("uav_id", "0bad"),
]


@pytest.mark.parametrize("field, value", HOSTILE, ids=lambda x: repr(x)[:30])
def test_hostile_bridge_config_values_are_refused_naming_field_and_value(field, value):
    with pytest.raises(ValueError) as info:
        BridgeConfig(**{field: value})
    text = str(info.value)
    assert f"BridgeConfig.{field}" in text, text
    shown = repr(value) if not isinstance(value, tuple) else repr(value[0])
    assert shown in text or repr(tuple(value) if isinstance(value, tuple) else value) in text, text


def test_every_numeric_field_is_bounded_and_the_defaults_are_inside():
    numeric = {
        f.name
        for f in dataclasses.fields(BridgeConfig)
        if isinstance(f.default, (int, float)) and not isinstance(f.default, bool)
    } | {"max_speed_mps", "max_turn_rate_radps", "max_accel_mps2", "max_turn_accel_radps2"}
    assert numeric == set(BOUNDS), numeric ^ set(BOUNDS)
    config = BridgeConfig()
    for name, (low, high, _) in BOUNDS.items():
        value = getattr(config, name)
        if value is not None:
            assert low <= value <= high, (name, value)
    assert set(INT_FIELDS) <= set(BOUNDS)
    # The bounds themselves are accepted (edges are usable values).
    BridgeConfig(watchdog_timeout_s=1.0, step_overrun_s=1.0, max_future_s=5.0, queue_length=1000)


def test_the_watchdog_must_tick_inside_its_timeout():
    with pytest.raises(ValueError, match="watchdog_poll_s must be < watchdog_timeout_s"):
        BridgeConfig(watchdog_timeout_s=0.02, watchdog_poll_s=0.05)


@pytest.mark.timeout(60)
def test_a_bad_bridge_config_is_refused_before_anything_connects(loopback):
    server = loopback()
    with pytest.raises(ValueError, match=r"BridgeConfig.watchdog_timeout_s.*1000000000.0"):
        real_env(port=server.port, preset="seed-lab", bridge={"watchdog_timeout_s": 1e9})
    time.sleep(0.2)
    assert server.n_clients == 0
    claim = RobotClaim("127.0.0.1", server.port, ("ugv_0",))  # nothing was left claimed
    claim.release()


@pytest.mark.timeout(60)
@pytest.mark.parametrize("kind", ["bool", "complex", "object"])
def test_a_non_real_action_is_refused_and_drives_nothing(loopback, kind):
    torch = pytest.importorskip("torch")
    server = loopback()
    env = real_env(port=server.port, preset="seed-lab")
    try:
        env.reset(seed=0)
        bad = {
            "bool": torch.tensor([True, False]),
            "complex": torch.tensor([0.3 + 0j, 0j]),
            "object": np.array([0.3, 0.0], dtype=object),
        }[kind]
        actions = {a: np.zeros(2) for a in env.agents}
        actions["ugv_1"] = bad
        t0 = time.monotonic()
        with pytest.raises(ValueError, match="ugv_1.*real numbers"):
            env.step(actions)
        time.sleep(0.2)
        moving = [(t, r, v) for t, r, v, _ in server.twists() if t > t0 and v != 0.0]
        assert moving == []
    finally:
        env.close()


_HOLDER = """
import sys, time
from hardware_bridge.claim import RobotClaim
claim = RobotClaim("localhost", int(sys.argv[1]), ("ugv_0", "ugv_2"))
print("held", flush=True)
time.sleep(120)
"""


@pytest.mark.timeout(60)
def test_a_second_bridge_process_on_the_same_robots_is_refused(loopback):
    server = loopback()
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(server.port)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
    )
    try:
        assert holder.stdout.readline().strip() == b"held"
        # 127.0.0.1 and localhost are the same server: ugv_0 is taken, named with the holder.
        with pytest.raises(RobotClaimedError, match=rf"'ugv_0'.*pid {holder.pid}"):
            real_env(port=server.port, preset="seed-lab")
        assert server.n_clients == 0
        # A robot set without them is free.
        env = real_env(robots=["ugv_1", "ugv_3"], port=server.port, preset="seed-lab")
        env.close()
        # The kernel drops the claim when the holder dies, however it dies.
        holder.send_signal(signal.SIGKILL)
        holder.wait(10)
        env = real_env(port=server.port, preset="seed-lab")
        env.close()
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait(10)
        holder.stdout.close()


def test_claims_are_exclusive_within_a_process_too_and_released():
    port = 1  # no server needed: the claim is a lock file
    first = RobotClaim("127.0.0.1", port, ("ugv_0",))
    try:
        with pytest.raises(RobotClaimedError, match=f"pid {os.getpid()}"):
            RobotClaim("::1", port, ("ugv_0",))
        assert lock_path("127.0.0.1", port, "ugv_0") == lock_path("localhost", port, "ugv_0")
    finally:
        first.release()
    RobotClaim("127.0.0.1", port, ("ugv_0",)).release()


TINY = ["--preset", "lab-3m-4", "--duration", "0.2", "--localizer", "phd-lc", "--seeds", "0"]


def test_evaluate_refuses_an_out_holding_earlier_results(tmp_path, capsys):
    out = tmp_path / "eval"
    out.mkdir()
    (out / "metrics.json").write_text("{}")
    assert main(["evaluate", *TINY, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "holds earlier results (metrics.json)" in err
    assert "pass --overwrite to write into it anyway" in err
    assert (out / "metrics.json").read_text() == "{}"  # untouched


class _Payload:
    """Unpickling this touches a file: what a hostile model zip would do with a shell."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def _evil_zip(path: Path, marker: Path) -> Path:
    import base64
    import json
    import pickle
    import zipfile

    blob = base64.b64encode(pickle.dumps(_Payload(marker))).decode()
    data = {"policy_class": {":type:": "<class 'abc.ABCMeta'>", ":serialized:": blob}}
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("data", json.dumps(data))
        z.writestr("swarm_phd.json", json.dumps({"env_kwargs": {"preset": "lab-3m-4"}}))
    return path


def test_a_model_zip_is_refused_on_robots_without_trust_policy(tmp_path, capsys):
    marker = tmp_path / "pwned"
    model = _evil_zip(tmp_path / "model.zip", marker)
    # The payload is real: unpickling the zip's data runs it.
    import base64
    import json
    import pickle
    import zipfile

    with zipfile.ZipFile(model) as z:
        blob = json.loads(z.read("data"))["policy_class"][":serialized:"]
    pickle.loads(base64.b64decode(blob))
    assert marker.exists()
    marker.unlink()
    code = main(["bridge", "--loopback", "--policy", str(model), "--steps", "5"])
    err = capsys.readouterr().err
    assert code == 2
    assert "--trust-policy" in err and "unpickles" in err and str(model) in err
    assert not marker.exists()
