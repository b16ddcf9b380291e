"""Videos of trained policies: what minimum attention changes, seen side by side.

``render_runs(["runs/sac_alpha0", "runs/sac_alpha0.05"], "hopper.gif")`` rolls out each run's
deterministic policy (its latest checkpoint, no trainer) on one task in its own MJX environment,
renders every step's body with MuJoCo's offscreen renderer, and writes one video: the runs side by
side, and under each its control signals u(t) and the feedback norm ||du/dx||^2 along the
rollout, with a cursor at the current step. The frame where an episode ends (the hopper falls)
stays on screen, marked, until the longest rollout ends.

Offscreen rendering needs an OpenGL context without a display. ``MUJOCO_GL=egl`` (set here
unless the user set another) uses EGL: on a CPU-only Linux machine Mesa's software rasterizer
(``libegl1``, ``libgl1-mesa-dri``) provides it, on an NVIDIA machine the driver's EGL does;
on macOS leave ``MUJOCO_GL`` unset (CGL); ``MUJOCO_GL=osmesa`` is the fallback where EGL is
missing. GIFs are written with Pillow; MP4 needs ``imageio`` with ``imageio-ffmpeg``.
"""

from __future__ import annotations

import dataclasses
import io
import os
from typing import Any

import jax
import numpy as np

import minatt_jax.envs as envs
from minatt_jax import acting, checkpoint, gl
from minatt_jax.run_files import RunError, write_bytes_atomic

VIDEO_SUFFIXES = (".gif", ".mp4")


@dataclasses.dataclass
class Rollout:
    """One run's deterministic rollout: what a video shows of it."""

    label: str
    env: Any
    qpos: np.ndarray  # (T, nq) positions before each step
    action: np.ndarray  # (T, act_dim)
    feedback: np.ndarray  # (T,) ||du/dx||_F^2
    alive: np.ndarray  # (T,) 1 until the episode ends
    reward: np.ndarray  # (T,)

    @property
    def length(self) -> int:
        """Steps until the episode ended (or the whole rollout)."""
        return int(self.alive.sum())


def rollout(
    run_dir: str,
    variant: str | None = None,
    task_specs: tuple[str, ...] = (),
    steps: int | None = None,
    seed: int = 0,
    label: str | None = None,
) -> Rollout:
    """The deterministic rollout of ``run_dir``'s latest policy on the first task of ``variant``
    (default: the run's own task set) or of ``task_specs``, ``steps`` long (default: an episode).
    RunError (one line) for a run, task or length that does not fit."""
    try:
        policy = checkpoint.load_policy(run_dir)
    except checkpoint.CheckpointError as e:
        raise RunError(str(e)) from None
    config, env = policy.config, policy.env
    if not hasattr(env, "mj_model"):
        raise RunError(f"{config.env} has no MuJoCo model to render")
    steps = config.episode_limit if steps is None else steps
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= 100_000:
        raise RunError(f"steps must be an integer in [1, 100000], got {steps!r}")
    try:
        name = variant or config.task_set
        envs.check_task_set_name(name)
        tasks, _ = envs.resolve_tasks(env, name, task_specs)
    except (envs.UnknownNameError, envs.TaskSpecError) as e:
        raise RunError(str(e)) from None
    deterministic = policy.family.deterministic(policy.actor_params, policy.normalizer)

    @jax.jit
    def run(key: jax.Array) -> acting.Trajectory:
        state = env.reset(key, tasks[0])
        return acting.unroll(env, deterministic, state, steps, probe_feedback=True,
                             record_qpos=True)  # fmt: skip

    traj = jax.device_get(run(jax.random.PRNGKey(seed)))
    return Rollout(label or _label(config), env, np.asarray(traj.qpos), np.asarray(traj.action),
                   np.asarray(traj.feedback), np.asarray(traj.alive),
                   np.asarray(traj.reward))  # fmt: skip


def _label(config: Any) -> str:
    return f"{config.algo}, alpha {config.ma.alpha:g}, seed {config.seed}"


def _mujoco_for_rendering() -> Any:
    """mujoco with an offscreen OpenGL backend (``gl.choose_for_rendering``), or RunError."""
    why = gl.choose_for_rendering()
    if why is not None:
        raise RunError(why)
    import mujoco

    return mujoco


def body_frames(r: Rollout, width: int = 320, height: int = 240, distance: float = 3.5,
                stride: int = 1) -> np.ndarray:  # fmt: skip
    """(frames, height, width, 3) uint8 renders of the rollout's bodies, every ``stride``-th
    step up to its end, by a camera that follows the root body from the side."""
    mujoco = _mujoco_for_rendering()

    model = r.env.mj_model
    data = mujoco.MjData(model)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    camera.trackbodyid = 1 if model.nbody > 1 else 0
    camera.distance, camera.elevation, camera.azimuth = distance, -15.0, 90.0
    try:
        renderer = mujoco.Renderer(model, height, width)
    except Exception as e:  # noqa: BLE001 - the GL backends raise many types
        raise RunError(f"offscreen rendering is not available ({e}); on Linux install EGL "
                       "(libegl1, libgl1-mesa-dri) or set MUJOCO_GL=osmesa") from None  # fmt: skip
    frames = []
    with renderer:
        for t in range(0, max(r.length, 1), stride):
            data.qpos[:] = r.qpos[t]
            mujoco.mj_forward(model, data)
            renderer.update_scene(data, camera=camera)
            frames.append(renderer.render().copy())
    return np.stack(frames)


def signal_strip(r: Rollout, frames: int, stride: int, width: int, height: int = 150,
                 feedback_top: float | None = None) -> list:  # fmt: skip
    """The panel under a run's frames, one image per frame: u(t) (one line per action) and the
    feedback norm over the rollout (up to ``feedback_top``: one scale for runs side by side),
    a cursor at the frame's step."""
    from minatt_jax.analysis.plots import _pyplot

    plt = _pyplot()
    dpi = 100
    fig, (ax_u, ax_f) = plt.subplots(2, 1, figsize=(width / dpi, height / dpi), dpi=dpi,
                                     sharex=True, layout="constrained")  # fmt: skip
    t = np.arange(r.length)
    ax_u.plot(t, r.action[: r.length], lw=0.8)
    ax_u.set_ylim(-1.05, 1.05)
    ax_u.set_ylabel("u(t)", fontsize=7)
    ax_f.plot(t, r.feedback[: r.length], lw=0.8, color="black")
    ax_f.set_yscale("symlog", linthresh=1e-2)
    if feedback_top is not None:
        ax_f.set_ylim(0, feedback_top)
    ax_f.set_ylabel("|du/dx|^2", fontsize=7)
    ax_f.set_xlabel("step", fontsize=7)
    for ax in (ax_u, ax_f):
        ax.tick_params(labelsize=6)
        ax.set_xlim(0, max(r.length - 1, 1))
    fig.canvas.draw()
    base = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    # the data-to-pixel map of the step axis, to draw each frame's cursor
    x0 = ax_f.transData.transform((0, 0))[0]
    x1 = ax_f.transData.transform((max(r.length - 1, 1), 0))[0]
    plt.close(fig)
    strips = []
    for i in range(frames):
        step = min(i * stride, r.length - 1)
        img = base.copy()
        col = int(round(x0 + (x1 - x0) * step / max(r.length - 1, 1)))
        img[:, max(col - 1, 0) : col + 1] = (220, 40, 40)
        strips.append(img)
    return strips


def compose(rollouts: list[Rollout], width: int = 320, height: int = 240,
            stride: int = 1) -> np.ndarray:  # fmt: skip
    """The video's frames: each run's body over its signal panel, runs side by side; a run
    whose episode ended holds its last frame with a red border."""
    from PIL import Image, ImageDraw

    bodies = [body_frames(r, width, height, stride=stride) for r in rollouts]
    count = max(len(b) for b in bodies)
    highest = 1.2 * max(float(np.max(r.feedback[: max(r.length, 1)])) for r in rollouts) + 1e-6
    strips = [signal_strip(r, count, stride, width, feedback_top=highest) for r in rollouts]
    frames = []
    for i in range(count):
        columns = []
        for r, body, strip in zip(rollouts, bodies, strips, strict=True):
            ended = i >= len(body)
            top = Image.fromarray(body[min(i, len(body) - 1)])
            draw = ImageDraw.Draw(top)
            step = min(i * stride, r.length - 1)
            note = f" | ended at step {r.length}" if ended else ""
            draw.text((6, 4), f"{r.label}\nstep {step}{note}", fill=(255, 255, 255))
            if ended:
                draw.rectangle((0, 0, width - 1, height - 1), outline=(220, 40, 40), width=4)
            columns.append(np.concatenate([np.asarray(top), strip[i]], axis=0))
        frames.append(np.concatenate(columns, axis=1))
    return np.stack(frames)


def write_video(frames: np.ndarray, path: str, fps: float) -> None:
    """Writes ``frames`` as a GIF (Pillow) or an MP4 (imageio-ffmpeg), atomically."""
    suffix = os.path.splitext(path)[1].lower()
    if suffix == ".gif":
        from PIL import Image

        images = [Image.fromarray(f) for f in frames]
        buffer = io.BytesIO()
        images[0].save(buffer, format="GIF", save_all=True, append_images=images[1:],
                       duration=int(round(1000 / fps)), loop=0, optimize=True)  # fmt: skip
        write_bytes_atomic(path, buffer.getvalue())
    elif suffix == ".mp4":
        try:
            import imageio.v3 as iio

            data = iio.imwrite("<bytes>", frames, extension=".mp4", fps=fps)
        except (ImportError, OSError, ValueError, RuntimeError) as e:
            raise RunError(f"MP4 needs imageio with imageio-ffmpeg ({e}); pip install "
                           "imageio-ffmpeg, or write a .gif") from None  # fmt: skip
        write_bytes_atomic(path, data)
    else:
        raise RunError(f"cannot tell the video format of {path}: end it in .gif or .mp4")


def render_runs(
    run_dirs: list[str],
    out: str,
    variant: str | None = None,
    task_specs: tuple[str, ...] = (),
    steps: int | None = None,
    seed: int = 0,
    width: int = 320,
    height: int = 240,
    stride: int = 2,
    labels: list[str] | None = None,
) -> dict[str, Any]:
    """Renders the runs' deterministic policies side by side on one task into ``out`` (.gif or
    .mp4); returns what it showed: each run's label, episode length, return and mean feedback
    norm, and the video's frame count and size. ``stride`` renders every stride-th step (the
    video plays at the environment's real time)."""
    if os.path.splitext(out)[1].lower() not in VIDEO_SUFFIXES:
        raise RunError(f"cannot tell the video format of {out}: end it in .gif or .mp4")
    if not run_dirs:
        raise RunError("render needs at least one run directory")
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise RunError(f"stride must be a positive integer, got {stride!r}")
    names = labels or [None] * len(run_dirs)
    rollouts = [rollout(d, variant, task_specs, steps, seed, n)
                for d, n in zip(run_dirs, names, strict=True)]  # fmt: skip
    frames = compose(rollouts, width, height, stride)
    fps = 1.0 / (rollouts[0].env.dt * stride)
    write_video(frames, out, fps)
    return {
        "out": out,
        "frames": int(frames.shape[0]),
        "size": [int(frames.shape[2]), int(frames.shape[1])],
        "fps": fps,
        "runs": [
            {
                "run_dir": d,
                "label": r.label,
                "length": r.length,
                "return": float(np.sum(r.reward * r.alive)),
                "feedback_norm": float(np.sum(r.feedback * r.alive) / max(r.length, 1)),
            }
            for d, r in zip(run_dirs, rollouts, strict=True)
        ],  # fmt: skip
    }
