"""Catalogs of hostile inputs, shared by the tests and ``benchmarks/bench_bridge_faults.py``:
bag corruptions (this module) and hostile rosbridge frames
(:func:`hardware_bridge.loopback.hostile_inputs`).

Each corruption is ``(name, apply(bag_dir), expected)``; the bag directory holds ``bag.db3``
(see :func:`copy_bag`). ``expected`` is ``"error"`` (replay must refuse with a one-line
:class:`~hardware_bridge.bag.BagError` naming the file), a skip counter key (replay must replay
the valid part and report that skip) or ``"any"`` (either, depending on where the damage lands).
"""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np


def copy_bag(good: Path, dest: Path) -> Path:
    """Copy a bag directory to ``dest`` with its database renamed ``bag.db3``."""
    shutil.copytree(good, dest)
    (dest / f"{good.name}.db3").rename(dest / "bag.db3")
    meta = (dest / "metadata.yaml").read_text().replace(f"{good.name}.db3", "bag.db3")
    (dest / "metadata.yaml").write_text(meta)
    return dest


def _sql(bag: Path, statement: str, params=()) -> None:
    con = sqlite3.connect(bag / "bag.db3")
    con.execute(statement, params)
    con.commit()
    con.close()


def _truncate(fraction):
    def apply(bag):
        db = bag / "bag.db3"
        data = db.read_bytes()
        db.write_bytes(data[: int(len(data) * fraction)])

    return apply


def _garbage(offset_fraction, n=4096):
    def apply(bag):
        db = bag / "bag.db3"
        data = bytearray(db.read_bytes())
        start = int(len(data) * offset_fraction)
        rng = np.random.default_rng(0)
        data[start : start + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        db.write_bytes(bytes(data))

    return apply


def _meta(old, new):
    def apply(bag):
        path = bag / "metadata.yaml"
        text = path.read_text()
        if old not in text:
            raise ValueError(f"metadata.yaml has no {old!r} to corrupt")
        path.write_text(text.replace(old, new, 1))

    return apply


def _custom(text):
    def apply(bag):
        from ruamel.yaml import YAML

        yaml = YAML(typ="safe")
        path = bag / "metadata.yaml"
        info = yaml.load(path.read_text())
        info["rosbag2_bagfile_information"]["custom_data"]["swarm_phd"] = text
        with path.open("w") as f:
            yaml.dump(info, f)

    return apply


# (name, corruption, expected): "error" = one-line BagError naming the file; a key = replays
# its valid part and reports that skip.
CORRUPTIONS = [
    ("missing_dir", lambda bag: shutil.rmtree(bag), "error"),
    ("a_file_not_a_dir", lambda bag: (shutil.rmtree(bag), bag.write_text("x")), "error"),
    ("missing_metadata", lambda bag: (bag / "metadata.yaml").unlink(), "error"),
    ("missing_db3", lambda bag: (bag / "bag.db3").unlink(), "error"),
    ("empty_db3", _truncate(0.0), "error"),
    ("truncated_db3_10pct", _truncate(0.1), "error"),
    ("truncated_db3_60pct", _truncate(0.6), "bag.salvaged"),
    ("garbage_db3_header", _garbage(0.0, 100), "error"),
    ("garbage_db3_middle", _garbage(0.5), "any"),
    ("truncated_db3_90pct", _truncate(0.9), "bag.read_error"),
    (
        "metadata_not_yaml",
        lambda bag: (bag / "metadata.yaml").write_bytes(b"\x00\xff: [{"),
        "error",
    ),
    ("metadata_wrong_root", lambda bag: (bag / "metadata.yaml").write_text("- 1\n- 2\n"), "error"),
    ("metadata_no_custom_data", _meta("swarm_phd:", "other_tool:"), "error"),
    ("custom_data_not_json", _custom("{not json"), "error"),
    ("custom_data_not_object", _custom("[1, 2]"), "error"),
    ("robots_wrong_type", _custom('{"robots": 5, "config": {}}'), "error"),
    ("robot_id_invalid", _custom('{"robots": ["a b"], "config": {}}'), "error"),
    (
        "config_wrong_type",
        _custom('{"robots": ["ugv_0"], "config": {"n_robots": "four"}}'),
        "error",
    ),
    ("config_unknown_key", _custom('{"robots": ["ugv_0"], "config": {"warp": 9}}'), "error"),
    (
        "stale_mocap_nan",
        _custom('{"robots": ["ugv_0"], "config": {}, "stale_mocap_s": NaN}'),
        "error",
    ),
    (
        "jump_factor_negative",
        _custom('{"robots": ["ugv_0"], "config": {}, "odometry_jump_factor": -1}'),
        "error",
    ),
    ("metadata_version_wrong_type", _meta("version: 8", "version: eight"), "error"),
    (
        "metadata_topics_wrong_type",
        _meta("topics_with_message_count:", "topics_with_message_count: 3\n  x:"),
        "error",
    ),
    (
        "wrong_type_for_scan",
        _meta(
            "name: /ugv_0/scan\n      offered_qos_profiles: ''\n      serialization_format: cdr\n"
            "      type: sensor_msgs/msg/LaserScan",
            "name: /ugv_0/scan\n      offered_qos_profiles: ''\n      serialization_format: cdr\n"
            "      type: std_msgs/msg/String",
        ),
        "bag.wrong_type",
    ),
    (
        "garbage_message_row",
        lambda bag: _sql(
            bag,
            "update messages set data = x'00010203' where id = (select min(id) from messages "
            "where topic_id = (select id from topics where name = '/ugv_1/scan'))",
        ),
        "bag.undecodable",
    ),
    (
        "duplicated_rows",
        lambda bag: _sql(
            bag,
            "insert into messages (topic_id, timestamp, data) select topic_id, timestamp, data "
            "from messages where id % 7 = 0",
        ),
        "bag.duplicate_rows",
    ),
    (
        "deleted_marker",
        lambda bag: _sql(
            bag,
            "delete from messages where id = (select id from messages where topic_id = (select "
            "id from topics where name = '/bridge/step') order by timestamp limit 1 offset 4)",
        ),
        "bag.missing_steps",
    ),
    (
        "garbage_marker",
        lambda bag: _sql(
            bag,
            "update messages set data = x'000100000500000068656c6c6f000000' where id = (select "
            "id from messages where topic_id = (select id from topics where name = "
            "'/bridge/step') order by timestamp limit 1 offset 3)",
        ),
        "bag.bad_marker",
    ),
    (
        "shifted_message_time",
        lambda bag: _sql(
            bag,
            "update messages set timestamp = timestamp - 1000 where id = (select min(id) from "
            "messages where topic_id = (select id from topics where name = '/ugv_2/odom'))",
        ),
        "bag.stamp_mismatch",
    ),
    (
        "all_markers_deleted",
        lambda bag: _sql(
            bag,
            "delete from messages where topic_id = (select id from topics where name = "
            "'/bridge/step')",
        ),
        "error",
    ),
]
