"""Bridge reliability figures: watchdog and guard latencies, stale commands after a frozen
server, link-loss detection, hostile inputs, bag corruptions, recording under signals, and a
soak. Regenerates ``docs/reference/reliability.md``.

    .venv/bin/python benchmarks/bench_bridge_faults.py                # full run, ~4 min
    .venv/bin/python benchmarks/bench_bridge_faults.py --quick        # fewer repetitions
    .venv/bin/python benchmarks/bench_bridge_faults.py --write docs/reference/reliability.md

Everything runs against the loopback robot server on 127.0.0.1 (ephemeral ports); the GIL and
kill experiments put the robots or the env in a separate process.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import logging
import os
import platform
import signal
import sqlite3
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hardware_bridge import real_env  # noqa: E402
from hardware_bridge.bag import BagError, ReplayWorld  # noqa: E402
from hardware_bridge.config import BridgeConfig  # noqa: E402
from hardware_bridge.faults import CORRUPTIONS, copy_bag  # noqa: E402
from hardware_bridge.loopback import (  # noqa: E402
    FaultConfig,
    LoopbackServer,
    hostile_inputs,
    read_twist_log,
    spawn,
    spawn_driving_env,
)
from hardware_bridge.world import TransportLostError  # noqa: E402
from swarm_core.atomic_files import write_text_atomically  # noqa: E402

ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _drive(env, steps: int, v: float = 0.2):
    infos = None
    for _ in range(steps):
        _, _, _, _, infos = env.step({a: np.array([v, 0.0], dtype=np.float32) for a in env.agents})
    return infos


@contextlib.contextmanager
def _seed_lab(**bridge):
    """A seed-lab loopback server (seed 0) and a real env on it with the ``bridge`` overrides,
    reset with seed 0; yields ``(server, env)`` and closes the env before the server."""
    with LoopbackServer("seed-lab", seed=0) as server:
        env = real_env(port=server.port, preset="seed-lab", max_steps=100_000, bridge=bridge)
        try:
            env.reset(seed=0)
            yield server, env
        finally:
            env.close()


def _first_zero(entries, after: float) -> dict[str, float]:
    out: dict[str, float] = {}
    for t, robot, v, w in entries:
        if t > after and v == 0.0 and w == 0.0 and robot not in out:
            out[robot] = t - after
    return out


def _wait(pred, timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def _stats(values: list[float]) -> str:
    if not values:
        return "n/a"
    return f"{min(values):.3f} / {statistics.median(values):.3f} / {max(values):.3f}"


# ---------------------------------------------------------------------------- experiments
def stall_latency(n: int) -> dict:
    """The in-process watchdog: the controller stops calling step()."""
    lat = []
    with _seed_lab() as (server, env):
        for _ in range(n):
            _drive(env, 3)
            t0 = time.monotonic()
            _wait(lambda t0=t0: len(_first_zero(server.twists(), t0)) == 4, 2.0)
            lat += list(_first_zero(server.twists(), t0).values())
    return {"n": len(lat), "latency_s": lat}


def _robot_process(log: Path) -> tuple[subprocess.Popen, int]:
    return spawn(log, cwd=ROOT, env=ENV)


def _log_entries(log: Path) -> list[tuple[float, str, float, float]]:
    return [(t, robot, v, w) for t, robot, v, w, applied in read_twist_log(log) if applied]


def gil_stall(n: int, guard: bool, stall_s: float = 2.0) -> dict:
    """A stall that holds the GIL in the env process, robots in another process."""
    lat = []
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "twists.log"
        proc, port = _robot_process(log)
        env = real_env(
            port=port,
            preset="seed-lab",
            max_steps=100_000,
            bridge={"guard_process": guard, "reset_timeout_s": 30.0},
        )
        try:
            env.reset(seed=0)
            for _ in range(n):
                _drive(env, 5)
                interval = sys.getswitchinterval()
                sys.setswitchinterval(10.0)
                try:
                    t0 = time.monotonic()
                    while time.monotonic() - t0 < stall_s:
                        pass
                finally:
                    sys.setswitchinterval(interval)
                time.sleep(0.3)
                lat += list(_first_zero(_log_entries(log), t0).values())
        finally:
            env.close()
            proc.stdin.close()
            proc.wait(10)
    return {"n": len(lat), "latency_s": lat, "stall_s": stall_s}


def killed_env(n: int) -> dict:
    """SIGKILL of the env process while it drives; the guard stops the robots."""
    lat = []
    with LoopbackServer("seed-lab", seed=0) as server:
        for _ in range(n):
            proc = spawn_driving_env(server.port, cwd=ROOT, env=ENV)
            time.sleep(1.0)
            t0 = time.monotonic()
            proc.kill()
            proc.wait(5)
            _wait(lambda t0=t0: len(_first_zero(server.twists(), t0)) == 4, 2.0)
            lat += list(_first_zero(server.twists(), t0).values())
    return {"n": len(lat), "latency_s": lat}


def frozen_server(stamped: bool, pause_s: float = 2.0) -> dict:
    """Freeze the server for ``pause_s`` while the client keeps commanding v = 0.2 m/s."""
    with LoopbackServer("seed-lab", seed=0, robot_cmd_timeout_s=0.5) as server:
        env = real_env(
            port=server.port,
            preset="seed-lab",
            max_steps=100_000,
            bridge={"stamped_commands": stamped, "transport_grace_s": 30.0},
        )
        try:
            env.reset(seed=0)
            _drive(env, 3)
            t0 = time.monotonic()
            server.pause(pause_s)
            lost_at = None
            while time.monotonic() < t0 + pause_s + 0.5:
                _drive(env, 1)
                if lost_at is None and env.world.counters.get("transport.lost"):
                    lost_at = time.monotonic() - t0
            _wait(lambda: env.world.client.connected, 5.0)
            if lost_at is None and env.world.counters.get("transport.lost"):
                lost_at = float("nan")
        finally:
            env.close()
        resume = t0 + pause_s
        log = [e for e in server.command_log() if e[0] > resume - 0.05]
        burst = [e for e in log if e[0] < resume + 0.1]  # what the freeze held back
        moving_applied = [e for e in burst if e[5] and e[2] > 0]
        applied_ages = [e[4] for e in log if e[5] and e[4] is not None]
        return {
            "stamped": stamped,
            "burst": len(burst),
            "moving_applied_in_burst": len(moving_applied),
            "refused_stale": server.counters.get("server.stale_commands"),
            "max_applied_age_s": max(applied_ages) if applied_ages else None,
            "link_lost_after_s": lost_at,
        }


def transport_grace(grace_s: float) -> dict:
    with _seed_lab(transport_grace_s=grace_s) as (server, env):
        _drive(env, 2)
        t0 = time.monotonic()
        server.stop()
        raised = None
        try:
            for _ in range(int(grace_s * 10) + 50):
                _drive(env, 1)
        except TransportLostError as exc:
            raised = (time.monotonic() - t0, str(exc))
    return {
        "grace_s": grace_s,
        "raised_after_s": raised[0] if raised else None,
        "message": raised[1] if raised else None,
    }


def hostile_classes() -> list[dict]:
    """Each hostile frame class, sent once per robot; what the bridge counted."""
    limit = 256 * 1024
    rows = []
    with _seed_lab(max_message_bytes=limit) as (server, env):
        _drive(env, 2, v=0.05)
        for name in hostile_inputs("ugv_0", time.time_ns(), limit):
            before = env.world.counters_snapshot()
            for robot in env.possible_agents:
                server.send_raw(hostile_inputs(robot, time.time_ns(), limit)[name])
            infos = _drive(env, 4, v=0.05)
            after = env.world.counters_snapshot()
            diff = {
                k: after.get(k, 0) - before.get(k, 0)
                for k in after
                if after.get(k, 0) != before.get(k, 0)
                and not k.endswith((".received", ".accepted", ".pre_command", "published"))
                and not k.startswith("safety.")
            }
            rows.append(
                {
                    "class": name,
                    "sent": len(env.possible_agents),
                    "counted": diff,
                    "link_up": env.world.client.connected
                    and not env.world.counters.get("transport.lost"),
                    "stale_after": sorted({s for i in infos.values() for s in i["stale"]}),
                }
            )
    return rows


def corruption_table() -> list[dict]:
    from swarm_phd.cli import main
    from swarm_phd.export_bag import export_sim_episode

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        good = Path(tmp) / "good"
        export_sim_episode(good, preset="seed-lab", duration_s=1.0, seed=4)
        for k, (name, corrupt, expected) in enumerate(CORRUPTIONS):
            bag = copy_bag(good, Path(tmp) / f"c{k}")
            corrupt(bag)
            import contextlib
            import io

            err = io.StringIO()
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                code = main(["replay", str(bag)])
            text = err.getvalue().strip().replace(str(bag), "BAG")
            try:
                world = ReplayWorld(bag)
                steps = sum(world.n_steps(e) for e in range(world.n_episodes))
                skipped = world.skipped()
            except BagError:
                steps, skipped = None, {}
            rows.append(
                {
                    "class": name,
                    "expected": expected,
                    "exit": code,
                    "stderr": text.splitlines()[0] if text else "",
                    "stderr_lines": len(text.splitlines()),
                    "steps": steps,
                    "skipped": skipped,
                    "traceback": "Traceback" in text,
                }
            )
    return rows


def signal_recording() -> list[dict]:
    rows = []
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        with tempfile.TemporaryDirectory() as tmp:
            bag = Path(tmp) / "rec"
            proc = subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "swarm_phd.cli",
                    "bridge",
                    "--loopback",
                    "--steps",
                    "100000",
                    "--record",
                    str(bag),
                ],
                cwd=ROOT,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                env=ENV,
            )
            db = bag / "rec.db3"
            seen = 0
            end = time.monotonic() + 90
            while time.monotonic() < end and seen < 30:
                time.sleep(0.2)
                if db.exists():
                    try:
                        con = sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=0.2)
                        seen = con.execute(
                            "select count(*) from messages m join topics t on m.topic_id=t.id "
                            "where t.name='/bridge/step'"
                        ).fetchone()[0]
                        con.close()
                    except sqlite3.Error:
                        pass
            proc.send_signal(signum)
            _, err = proc.communicate(timeout=30)
            try:
                world = ReplayWorld(bag)
                replayed, skipped = world.n_steps(), world.skipped()
            except BagError as exc:
                replayed, skipped = None, {"error": str(exc)}
            rows.append(
                {
                    "signal": signal.Signals(signum).name,
                    "exit": proc.returncode,
                    "steps_committed_before": seen - 1,
                    "steps_replayed": replayed,
                    "skipped": skipped,
                    "traceback": b"Traceback" in err,
                }
            )
    return rows


def soak(steps: int) -> dict:
    limit = 256 * 1024
    faults = FaultConfig(drop=0.03, delay=0.03, duplicate=0.03, malformed=0.03, seed=5)
    with LoopbackServer("seed-lab", seed=1, faults=faults) as server:
        env = real_env(
            port=server.port,
            preset="seed-lab",
            max_steps=10 * steps,
            bridge={"max_message_bytes": limit},
        )
        nonfinite = exceptions = sent = 0
        t0 = time.monotonic()
        try:
            env.reset(seed=1)
            rng = np.random.default_rng(0)
            for k in range(steps):
                if k % 10 == 5:
                    payloads = [
                        p
                        for robot in env.possible_agents
                        for p in hostile_inputs(robot, time.time_ns(), limit).values()
                    ]
                    sent += len(payloads)
                    # From another thread: the controller keeps its cadence (no stall trips).
                    threading.Thread(
                        target=lambda ps=payloads: [server.send_raw(p) for p in ps], daemon=True
                    ).start()
                try:
                    _, _, _, _, infos = env.step(
                        {a: rng.uniform([-0.3, -1.5], [0.3, 1.5]) for a in env.agents}
                    )
                except Exception:  # noqa: BLE001 - counted: the soak's figure
                    exceptions += 1
                    env.reset(seed=1)
                for loc in env.localizers:
                    if not (
                        np.all(np.isfinite(loc.mixture.means))
                        and np.all(np.isfinite(loc.mixture.weights))
                    ):
                        nonfinite += 1
            counters = env.world.counters_snapshot()
            trips = len(env.world.watchdog.trips)
        finally:
            env.close()
    return {
        "steps": steps,
        "wall_s": time.monotonic() - t0,
        "hostile_frames": sent,
        "injected": {
            k: v
            for k, v in server.counters.snapshot().items()
            if k.startswith("injected.") and k.count(".") == 1
        },
        "exceptions": exceptions,
        "nonfinite_mixtures": nonfinite,
        "watchdog_trips": trips,
        "counters": {
            k: v for k, v in counters.items() if not k.endswith((".received", ".accepted"))
        },
    }


# ---------------------------------------------------------------------------- report
PROSE = """# Reliability of the hardware bridge

What the bridge does when something fails, and the measured figures. The design is described
in [Real robots](../how-to/real-robots.md) (safety) and [Bags](../how-to/bags.md) (recording
and replay). Everything runs against the loopback robot server on 127.0.0.1, which speaks the
rosbridge protocol. Every failure class, with its cases, outcomes, worst stop time and the test
that produces it, is in one table: [Failure classes at a glance](#failure-classes-at-a-glance).
The latency, frozen-server, hostile-frame, corrupted-bag, signal and soak tables below are
regenerated by `python benchmarks/bench_bridge_faults.py --write docs/reference/reliability.md`
(command, machine and date with them).

## What stops the robots

1. `World.halt()`, in the env process: the env calls it on any exception in its `step()`,
   `reset()` or `close()`; `RealWorld.step()` calls it before raising `TransportLostError`.
2. The watchdog thread, in the env process: `step()` not called for `watchdog_timeout_s`
   (0.3 s) after the previous one returned; a `step()` still running `step_overrun_s` (0.2 s)
   after its control period ended (a hung step); SIGINT / SIGTERM / SIGHUP; `close()`; link
   loss. Every tick it also checks that the guard process is alive, and restarts a dead one
   (logged with its exit status, counted as `guard.restarts`).
3. The guard process, with its own websocket: the same deadlines, fed over a pipe; it also
   fires when the env process holds the GIL, is frozen (SIGSTOP, Ctrl-Z: the guard runs in its
   own session and is not frozen with it) or dies (SIGKILL closes the pipe).
4. The robot's own command timeout (ros2_control `diff_drive_controller`,
   `use_stamped_vel: true`, `cmd_vel_timeout: 0.5`): no command for 0.5 s, and a
   `TwistStamped` older than 0.5 s on arrival is never executed.

With the defaults at 10 Hz, a hung step is stopped at most `period + step_overrun_s +
watchdog_poll_s` = 0.31 s after its command went out, and a stall between steps at most
`period + watchdog_timeout_s + watchdog_poll_s` = 0.41 s after the last command: both inside
the robots' own 0.5 s timeout. Both limits are `BridgeConfig` fields with bounds
(`watchdog_timeout_s` <= 1 s, `step_overrun_s` <= 1 s).

"""


def _row(*cells) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _table(header: list[str], rows: list[list]) -> list[str]:
    return [_row(*header), _row(*["---"] * len(header))] + [_row(*r) for r in rows] + [""]


def _kv(d: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in sorted(d.items())) or "-"


def report(results: dict, command: str) -> str:
    load = ", ".join(f"{x:.1f}" for x in results["load"])
    lines = [
        PROSE,
        f"Measured {results['date']} on {results['machine']} with `{command}` "
        f"(load average {load} at the start).\n",
    ]
    s, g, ng, k = (results[x] for x in ("stall", "gil_guard", "gil_no_guard", "killed"))
    lines.append("## Watchdog and guard latencies (seconds, min / median / max)\n")
    lines.append(
        "From the return of the last `env.step()` (stall, GIL) or the kill, to the zero command's "
        "arrival at the robot; 4 robots per event.\n"
    )
    lines += _table(
        ["Case", "Samples (robot stops)", "Latency to the zero Twist"],
        [
            [
                "controller stops calling `step()` "
                f"(`watchdog_timeout_s={BridgeConfig().watchdog_timeout_s}`)",
                s["n"],
                _stats(s["latency_s"]),
            ],
            [
                f"env holds the GIL for {g['stall_s']:.0f} s, guard process on",
                g["n"],
                _stats(g["latency_s"]),
            ],
            [
                f"env holds the GIL for {ng['stall_s']:.0f} s, guard process off",
                ng["n"],
                _stats(ng["latency_s"]),
            ],
            ["env process killed (SIGKILL) while driving", k["n"], _stats(k["latency_s"])],
        ],
    )
    lines.append("## Frozen server (rosbridge paused 2 s while the client commands 0.2 m/s)\n")
    rows = []
    for r in (results["frozen_stamped"], results["frozen_twist"]):
        age = r["max_applied_age_s"]
        lost = r["link_lost_after_s"]
        rows.append(
            [
                "TwistStamped" if r["stamped"] else "Twist (legacy)",
                r["burst"],
                r["moving_applied_in_burst"],
                r["refused_stale"],
                "unknown (no stamp)" if age is None else f"{age:.3f}",
                "not lost" if lost is None else f"{lost:.2f}",
            ]
        )
    lines += _table(
        [
            "Commands",
            "Delivered in the burst at resume",
            "Moving commands executed from it",
            "Refused as stale",
            "Oldest executed (s)",
            "Link loss noticed after (s)",
        ],
        rows,
    )
    t = results["grace"]
    lines.append(
        f"Transport loss: with `transport_grace_s={t['grace_s']}`, `step()` raised "
        f"`TransportLostError` {t['raised_after_s']:.2f} s after the server went down: "
        f'"{t["message"]}"\n'
    )
    lines.append("## Hostile frames (one per robot, 4 robots; then 4 steps)\n")
    lines += _table(
        ["Class", "Sent", "Counted by the bridge", "Link up", "Stale sensors after"],
        [
            [
                f"`{r['class']}`",
                r["sent"],
                _kv(r["counted"]),
                r["link_up"],
                ", ".join(r["stale_after"]) or "none",
            ]
            for r in results["hostile"]
        ],
    )
    lines.append("## Corrupted bags (`swarm-phd replay BAG`)\n")
    lines.append(
        "A 1 s exported episode (10 steps), corrupted one way at a time. Exit 2 = one line on "
        "stderr naming the file; exit 0 = the valid part replayed, skips reported.\n"
    )
    lines += _table(
        ["Class", "Exit", "Steps replayed", "Skipped", "stderr (first line)"],
        [
            [
                f"`{r['class']}`",
                f"{r['exit']}{' **TRACEBACK**' if r['traceback'] else ''}",
                "-" if r["steps"] is None else r["steps"],
                _kv(r["skipped"]),
                # code span: a message may hold brackets that Markdown would read as a link
                "`" + r["stderr"].replace("`", "'").replace("|", "\\|")[:160] + "`",
            ]
            for r in results["corruption"]
        ],
    )
    lines.append("## Recording under signals (`swarm-phd bridge --loopback --record`)\n")
    lines += _table(
        [
            "Signal",
            "Exit status",
            "Steps committed before",
            "Steps replayed",
            "Skipped",
            "Traceback",
        ],
        [
            [
                r["signal"],
                r["exit"],
                r["steps_committed_before"],
                r["steps_replayed"],
                _kv(r["skipped"]),
                r["traceback"],
            ]
            for r in results["signals"]
        ],
    )
    so = results["soak"]
    lines.append("## Soak\n")
    lines.append(
        f"{so['steps']} steps ({so['wall_s']:.0f} s) with 3 % each of dropped, delayed, "
        f"duplicated and malformed sensor messages (injected: {_kv(so['injected'])}) and "
        f"{so['hostile_frames']} hostile frames: {so['exceptions']} exceptions, "
        f"{so['nonfinite_mixtures']} non-finite mixtures, {so['watchdog_trips']} watchdog "
        "trips.\n"
    )
    lines.append("Bridge counters: " + _kv(so["counters"]) + "\n")
    lines.append("## Limits\n")
    lines.append(LIMITS)
    return "\n".join(lines)


LIMITS = """- A frame above `hard_max_message_bytes` (64 MB) cannot be received by the websocket
  library and drops the link (counted as a transport loss, the robots stop, the link comes back).
- The robot-side command timeout is a robot setting (`diff_drive_controller`); the bridge sends
  `TwistStamped` and documents the setting, it cannot verify it over rosbridge. A robot on a
  legacy `Twist` base driver executes a held-back burst (see the table): run `twist_mux` or the
  driver's timeout there.
- A bag whose recorder was killed with SIGKILL has whole committed steps but no `metadata.yaml`;
  replay refuses it with a one-line error that says so (`ros2 bag reindex` rebuilds the rosbag2
  metadata, not the swarm-phd config stored in it).
- A database that rosbags refuses (truncated, damaged pages) is salvaged row by row: rows on
  readable pages replay, rows on damaged pages are counted as lost (`bag.read_error`). Damage
  to the first page or the schema refuses the bag. Damage inside a row's bytes that still
  decodes as the right type (a changed float) cannot be detected: the bag format has no
  checksums.
- Figures on a shared 2-core machine: the load average is printed with them. The soak's
  watchdog trips and stale sensor-steps are the controller or the loopback's real-time sim being
  starved by other processes, not the inputs.
"""


#: The first heading of docs/reference/reliability.md that this script does not generate.
KEPT_SECTION = "## Failure classes at a glance"


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--write", default=None, help="write the report to this markdown file")
    args = parser.parse_args()
    logging.getLogger("hardware_bridge").setLevel(logging.ERROR)
    n = 3 if args.quick else 10
    results = {
        "date": datetime.date.today().isoformat(),
        "machine": (
            f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
        ),
    }
    results["load"] = os.getloadavg()
    steps = [
        ("stall", lambda: stall_latency(n)),
        ("gil_guard", lambda: gil_stall(max(2, n // 3), guard=True)),
        ("gil_no_guard", lambda: gil_stall(2, guard=False)),
        ("killed", lambda: killed_env(max(2, n // 3))),
        ("frozen_stamped", lambda: frozen_server(True)),
        ("frozen_twist", lambda: frozen_server(False)),
        ("grace", lambda: transport_grace(1.0)),
        ("hostile", hostile_classes),
        ("corruption", corruption_table),
        ("signals", signal_recording),
        ("soak", lambda: soak(150 if args.quick else 600)),
    ]
    for name, fn in steps:
        t0 = time.monotonic()
        results[name] = fn()
        print(f"{name}: {time.monotonic() - t0:.1f} s", file=sys.stderr, flush=True)
    command = "python benchmarks/bench_bridge_faults.py" + (" --quick" if args.quick else "")
    text = report(results, command)
    if args.write:
        path = Path(args.write)
        # The page's sections from KEPT_SECTION on are maintained by hand from the tests
        # (tests/hardware_bridge/, tests/swarm_env/test_invalid_inputs_property.py): keep them.
        kept = ""
        if path.is_file():
            old = path.read_text()
            at = old.find(KEPT_SECTION)
            kept = old[at:] if at >= 0 else ""
        write_text_atomically(path, text.rstrip("\n") + ("\n\n" + kept if kept else "\n"))
        print(f"wrote {args.write}", file=sys.stderr)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
