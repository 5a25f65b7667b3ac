"""``swarm-phd record``: MP4 and GIF read back with the expected frames, refusals before
anything runs or is written, and the render contract Gymnasium's and PettingZoo's video
wrappers rely on (``metadata["render_fps"]``, fixed-size ``rgb_array`` frames)."""

from __future__ import annotations

import gymnasium as gym
import imageio.v2 as imageio
import imageio.v3 as iio
import numpy as np
import pytest

import swarm_env  # noqa: F401  (registers SwarmPHD-v0)
from swarm_phd import cli, record

SIZE = (928, 640)  # the renderer's frame: width, height


def _mp4_frames(path):
    reader = imageio.get_reader(path, format="FFMPEG")
    try:
        frames = [f for f in reader]
        return frames, reader.get_meta_data()
    finally:
        reader.close()


def test_mp4_has_one_frame_per_step_at_the_control_rate(tmp_path):
    out = tmp_path / "sub" / "wander.mp4"  # its directory is made
    rec = record.record(out, "scripted:wander", preset="lab-3m-4", duration_s=1.5, seed=2)
    assert rec.path == out and out.is_file()
    assert (rec.frames, rec.steps, rec.fps, rec.size_px) == (16, 15, 10.0, SIZE)
    frames, meta = _mp4_frames(out)
    assert len(frames) == 16  # the reset, then each of the 15 steps
    assert meta["fps"] == pytest.approx(10.0)
    assert tuple(meta["size"]) == SIZE
    assert frames[0].shape == (SIZE[1], SIZE[0], 3)
    assert not np.array_equal(frames[0], frames[-1])  # the swarm moved
    assert list(out.parent.iterdir()) == [out]  # no partial file left behind


def test_gif_from_the_cli_at_a_lower_fps_keeps_real_time(tmp_path, capsys):
    out = tmp_path / "formation.gif"
    argv = ["record", "--policy", "scripted:formation", "--task", "formation", "--preset"]
    argv += ["lab-3m-4", "--duration", "2", "--fps", "5", "--out", str(out), "--quiet"]
    assert cli.main(argv) == 0
    frames = iio.imread(out, index=None)
    assert frames.shape[0] == 11  # t = 0, 0.2, ..., 2.0 s
    assert frames.shape[1:3] == (SIZE[1], SIZE[0])
    assert iio.immeta(out)["duration"] == 200  # ms per frame: 5 fps
    printed = capsys.readouterr().out
    assert "11 frames of 928x640 px at 5 fps" in printed and "task formation" in printed


def test_frame_schedule():
    assert record.frame_steps(15, 0.1, 10.0) == list(range(16))
    assert record.frame_steps(20, 0.1, 5.0) == list(range(0, 21, 2))
    assert record.frame_steps(10, 0.1, 4.0) == [0, 3, 5, 8, 10]  # first step at or after k/4 s


@pytest.fixture
def no_env(monkeypatch):
    """Fails the test if an env is built (the refusal must come first)."""

    def refuse(*args, **kwargs):
        raise AssertionError("an env was built before the input was checked")

    monkeypatch.setattr("agents.policies.policy_env", refuse)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--out", "{tmp}/video.avi"], "unknown video format '.avi'; end the name with one of"),
        (["--out", "{tmp}/video"], "unknown video format '(no extension)'"),
        (["--out", "{tmp}/afile/video.mp4"], "is not a directory"),
        (["--policy", "scripted:dance"], "unknown policy 'scripted:dance'; known: random, "),
        (["--policy", "greedy"], "scripted:formation"),
        (["--policy", "{tmp}/missing.zip"], "does not exist"),
        (["--policy", "pretrained:dance"], "unknown pretrained policy 'pretrained:dance'; known"),
        (["--duration", "0"], "--duration"),
        (["--fps", "-1"], "--fps must be a finite number > 0.0, got -1.0"),
        (["--seed", "-3"], "--seed must be an integer >= 0, got -3"),
    ],
)
def test_bad_input_is_refused_before_anything_runs(tmp_path, capsys, no_env, argv, message):
    (tmp_path / "afile").write_text("not a directory")
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "v.mp4")]
    before = sorted(tmp_path.iterdir())
    assert cli.main(["record", "--preset", "lab-3m-4", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("swarm-phd record: error: ") and message in err, err
    assert sorted(tmp_path.iterdir()) == before  # nothing written


def test_fps_above_the_control_rate_and_a_policy_that_cannot_act_are_refused(tmp_path):
    out = tmp_path / "v.mp4"
    with pytest.raises(ValueError, match=r"--fps must be at most the control rate, 10 frames/s"):
        record.record(out, preset="lab-3m-4", duration_s=1.0, fps=12)
    with pytest.raises(ValueError, match="render_agent 'ugv_9' is not one of the agents"):
        record.record(out, preset="lab-3m-4", duration_s=1.0, render_agent="ugv_9")
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_recording_leaves_no_file(tmp_path, monkeypatch):
    from agents import policies

    real = policies.load_policy

    def failing_after_three_steps(spec, env):
        act, calls = real(spec, env), []

        def policy(obs, infos):
            calls.append(1)
            if len(calls) > 3:
                raise KeyboardInterrupt
            return act(obs, infos)

        return policy

    monkeypatch.setattr(policies, "load_policy", failing_after_three_steps)
    out = tmp_path / "v.gif"
    with pytest.raises(KeyboardInterrupt):
        record.record(out, "random", preset="lab-3m-4", duration_s=2.0)
    assert list(tmp_path.iterdir()) == []  # neither the video nor its partial file


def test_render_contract_of_the_video_wrappers():
    """What gymnasium.wrappers.RecordVideo and PettingZoo's video tools read: the render fps
    matches the control rate, and every frame is uint8 RGB of one size."""
    env = gym.make("SwarmPHD-v0", render_mode="rgb_array", preset="lab-3m-4", max_steps=30)
    period = env.unwrapped.env.config.control_period_s
    assert env.metadata["render_fps"] == pytest.approx(1.0 / period)
    env.reset(seed=0)
    shapes = set()
    for _ in range(12):
        frame = env.render()
        assert frame.dtype == np.uint8
        shapes.add(frame.shape)
        env.step(env.action_space.sample())
    assert shapes == {(SIZE[1], SIZE[0], 3)}
    par = swarm_env.parallel_env("lab-3m-4", render_mode="rgb_array")
    assert par.metadata["render_fps"] == pytest.approx(10.0)
    fast = gym.make("SwarmPHD-v0", render_mode="rgb_array", control_period_s=0.05)
    assert fast.metadata["render_fps"] == pytest.approx(20.0)  # follows the control rate
    assert swarm_env.SwarmEnv.metadata["render_fps"] == 10  # the class's own is untouched
    for e in (env, par, fast):
        e.close()


def test_gymnasium_record_video(tmp_path):
    pytest.importorskip("moviepy", reason="Gymnasium's RecordVideo encodes with moviepy")
    env = gym.make("SwarmPHD-v0", render_mode="rgb_array", preset="lab-3m-4", max_steps=10)
    folder = tmp_path / "videos"
    env = gym.wrappers.RecordVideo(env, str(folder), episode_trigger=lambda e: True)
    env.reset(seed=0)
    done = False
    while not done:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        done = term or trunc
    env.close()
    (video,) = folder.glob("*.mp4")
    frames, meta = _mp4_frames(video)
    assert len(frames) == 11  # the reset and 10 steps
    assert meta["fps"] == pytest.approx(10.0) and tuple(meta["size"]) == SIZE


@pytest.mark.slow
def test_a_trained_model_is_recorded_in_its_own_env(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    run = tmp_path / "run"
    train = ["train", "--preset", "lab-3m-4", "--task", "formation", "--observation", "phd"]
    train += ["--timesteps", "128", "--n-copies", "1", "--n-steps", "32", "--batch-size", "32"]
    train += ["--n-epochs", "1", "--max-steps", "20", "--no-progress-bar", "--quiet"]
    assert cli.main([*train, "--out", str(run)]) == 0
    out = tmp_path / "model.mp4"
    # No --preset or --task: the model's own (lab-3m-4, formation); its 20-step episode ends
    # the video before the 3 s asked for.
    argv = ["record", "--policy", str(run / "model.zip"), "--duration", "3", "--out", str(out)]
    assert cli.main([*argv, "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "task formation, 4 UGVs" in printed and "(the episode ended there)" in printed
    frames, _ = _mp4_frames(out)
    assert len(frames) == 21
