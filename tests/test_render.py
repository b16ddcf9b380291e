"""Videos of policies: frames that show a body, moving, side by side, with the controls beneath."""

from __future__ import annotations

import os

import numpy as np
import pytest
from conftest import run_cli, untrained_run

from minatt_jax import api, render
from minatt_jax.config import PRESETS, resolve, with_overrides

CONFIG = resolve(with_overrides(PRESETS["smoke"], total_steps=300))
WIDTH, HEIGHT, STEPS = 96, 72, 12


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("render") / "run")
    untrained_run(path, CONFIG, 300)
    return path


def _frames(path):
    from PIL import Image, ImageSequence

    with Image.open(path) as im:
        return np.stack([np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(im)])


def test_a_rollout_renders_a_moving_body_with_its_controls(run, tmp_path):
    r = render.rollout(run, steps=STEPS)
    assert r.qpos.shape == (STEPS, r.env.mj_model.nq) and r.action.shape[0] == STEPS
    body = render.body_frames(r, WIDTH, HEIGHT)
    assert body.shape == (r.length, HEIGHT, WIDTH, 3)
    assert body[0].std() > 10  # a scene (floor, body, sky), not one flat colour
    # the body moves: the hopper falls and sways under its untrained policy
    assert np.abs(body[-1].astype(int) - body[0].astype(int)).mean() > 0.5
    strip = render.signal_strip(r, frames=3, stride=1, width=WIDTH)
    assert len(strip) == 3 and strip[0].shape[1] == WIDTH
    assert not np.array_equal(strip[0], strip[2])  # the cursor moved


def test_runs_side_by_side_through_the_cli_and_the_api(run, tmp_path, capsys):
    out = str(tmp_path / "side.gif")
    size = ["--width", str(WIDTH), "--height", str(HEIGHT)]
    argv = ["render", run, run, "--out", out, "--steps", str(STEPS), "--stride", "3", *size,
            "--label", "a", "--label", "b"]  # fmt: skip
    status, io = run_cli(argv, capsys)
    assert status == 0, io.err
    frames = _frames(out)
    assert frames.shape[2] == 2 * WIDTH and frames.shape[1] > HEIGHT  # two columns, panels
    left, right = frames[:, :HEIGHT, :WIDTH], frames[:, :HEIGHT, WIDTH:]
    assert np.abs(left.astype(int) - right.astype(int)).mean() < 5  # the same run twice
    assert "wrote" in io.out and "frames" in io.out
    info = api.load_run(run).render(str(tmp_path / "one.gif"), steps=STEPS, stride=3,
                                    width=WIDTH, height=HEIGHT)  # fmt: skip
    assert info["size"][0] == WIDTH and info["runs"][0]["length"] <= STEPS
    assert os.path.getsize(tmp_path / "one.gif") > 0


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--out", "{tmp}/v.avi"], "end it in .gif or .mp4"),
        (["--out", "{tmp}/v.gif", "--label", "only-one"], "--label once per run"),
        (["--out", "{tmp}/v.gif", "--variant", "icy"], "unknown variant 'icy'"),
        (["--out", "{run}/policy_snapshots/v.gif"], "the run's own file"),
    ],
)
def test_bad_render_input_is_one_line(run, tmp_path, capsys, argv, message):
    argv = [a.format(tmp=tmp_path, run=run) for a in argv]
    status, io = run_cli(["render", run, run, "--steps", "2", *argv], capsys)
    assert status == 2 and len(io.err.strip().splitlines()) == 1 and message in io.err
