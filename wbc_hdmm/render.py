"""``wbc render``: an mp4 of a run, replayed from its log.

The machine on its terrain (the same MuJoCo model, ``qpos`` replayed sample by sample), seen
by a chase camera; each wheel's ground-truth normal force drawn as an arrow along the terrain
normal above its contact point (clear of the tyre), 1 m per `FORCE_SCALE`, coloured by its
margin to the threshold (green above threshold + `MARGIN_WARN`, amber above the threshold, red
below); the frame gets a red border while any wheel is below the threshold; beside it, the
four forces over the run with the threshold and a cursor at the current time. Headless:
MuJoCo's EGL context (``MUJOCO_GL=egl``), imageio with its bundled ffmpeg.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from models.description import WHEEL_ORDER
from wbc_hdmm.replay import replay_scene

__all__ = ["FORCE_SCALE", "MARGIN_WARN", "RenderError", "check_out", "frame_at",
           "render_run"]

FORCE_SCALE = 10e3  # [N] per metre of arrow
MARGIN_WARN = 1.5e3  # [N] above the threshold: amber below this margin
_COLORS = {"ok": (0.2, 0.8, 0.3, 1.0), "warn": (1.0, 0.65, 0.0, 1.0),
           "low": (0.95, 0.1, 0.1, 1.0)}
_WHEEL_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red")


class RenderError(ValueError):
    """Bad render settings, or no GL context to render with."""


def _check(name: str, value, lower: int, upper: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lower <= value <= upper:
        raise RenderError(f"{name} {value!r} outside [{lower}, {upper}] (an integer)")
    return value


def _plot_panel(log: dict, threshold: float | None, width: int, height: int):
    """The force plot as an RGB image (height, width, 3) and the map time -> pixel column."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(width / 100, height / 100), dpi=100)
    ax = fig.add_axes((0.2, 0.12, 0.75, 0.8))
    t = np.asarray(log["time"], float)
    f = np.asarray(log["normal_force"], float) / 1e3
    for k, name in enumerate(WHEEL_ORDER):
        ax.plot(t, f[:, k], color=_WHEEL_COLORS[k], lw=0.8, label=name)
    if threshold is not None:
        ax.axhline(threshold / 1e3, color="k", ls="--", lw=0.8)
    ax.set_xlim(t[0], t[-1])
    ax.set_xlabel("time [s]", fontsize=7)
    ax.set_ylabel("normal force [kN]", fontsize=7)
    ax.tick_params(labelsize=6)
    ax.legend(fontsize=6, ncol=2, loc="upper right")
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    (x0, y0), (x1, y1) = ax.transData.transform([(t[0], 0.0), (t[-1], 0.0)])
    plt.close(fig)
    top = int(height * (1 - 0.92))
    bottom = int(height * (1 - 0.12))

    def column(time: float) -> int:
        return int(round(x0 + (x1 - x0) * (time - t[0]) / max(t[-1] - t[0], 1e-9)))

    return image, column, (top, bottom)


def _arrow(scene, start, end, rgba) -> None:
    import mujoco

    if scene.ngeom >= scene.maxgeom:
        return
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_ARROW, np.zeros(3), np.zeros(3), np.zeros(9),
                        np.asarray(rgba, np.float32))
    mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_ARROW, 0.07, np.asarray(start, float),
                         np.asarray(end, float))
    scene.ngeom += 1


class _Replayer:
    """The 3-D view of a logged run, one sample at a time (see the module docstring)."""

    def __init__(self, run_dir, width: int, height: int):
        os.environ.setdefault("MUJOCO_GL", "egl")
        import mujoco

        from models.mujoco import build_model

        self.log, machine, terrain, self.threshold = replay_scene(run_dir)
        self.model = build_model(machine, terrain)
        if self.log["qpos"].shape[1] != self.model.nq:
            raise RenderError(f"the log's qpos has {self.log['qpos'].shape[1]} entries, the "
                              f"rebuilt model {self.model.nq}: another model version")
        self.data = mujoco.MjData(self.model)
        try:
            self.renderer = mujoco.Renderer(self.model, height=height, width=width)
        except (RuntimeError, ImportError, OSError, mujoco.FatalError) as exc:
            raise RenderError(f"no OpenGL context for rendering ({exc}); headless, set "
                              f"MUJOCO_GL=egl") from exc
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.camera.distance, self.camera.elevation = 8.0, -18.0
        self.time = np.asarray(self.log["time"], float)
        self.forces = np.asarray(self.log["normal_force"], float)
        self.lift = 2.0 * machine.wheel_radius + 0.05  # [m] arrows start above the tyre

    def frame(self, i: int) -> np.ndarray:
        """The view of sample ``i``, (height, width, 3) uint8, red-bordered below threshold."""
        import mujoco

        log = self.log
        self.data.qpos[:] = log["qpos"][i]
        mujoco.mj_kinematics(self.model, self.data)
        rot, pos = log["base_rotation"][i], log["base_position"][i]
        self.camera.lookat[:] = pos
        self.camera.azimuth = float(np.degrees(np.arctan2(rot[1, 0], rot[0, 0]))) + 30.0
        self.renderer.update_scene(self.data, camera=self.camera)
        low = False
        for k in range(4):
            f = self.forces[i, k]
            normal = rot @ log["normal_in_fb"][i, k]
            start = pos + rot @ log["point_in_fb"][i, k] + normal * self.lift
            kind = "ok"
            if self.threshold is not None and f < self.threshold + MARGIN_WARN:
                kind = "warn" if f >= self.threshold else "low"
                low |= kind == "low"
            if f > 0:
                _arrow(self.renderer.scene, start, start + normal * f / FORCE_SCALE,
                       _COLORS[kind])
        image = self.renderer.render().copy()
        if low:
            image[:6], image[-6:], image[:, :6], image[:, -6:] = 230, 230, 230, 230
            image[:6, :, 1:] = image[-6:, :, 1:] = 30
            image[:, :6, 1:] = image[:, -6:, 1:] = 30
        return image

    def close(self) -> None:
        """Release the GL context."""
        self.renderer.close()


def frame_at(run_dir, time: float, width: int = 640, height: int = 360) -> np.ndarray:
    """The 3-D view of a run at ``time`` [s] (the nearest logged sample), (h, w, 3) uint8.

    Raises:
        RenderError: A size out of range, or no GL context.
        LogError: The log cannot be read or replayed.
    """
    width = _check("width", width, 160, 1920) // 8 * 8
    height = _check("height", height, 120, 1080) // 8 * 8
    replay = _Replayer(run_dir, width, height)
    try:
        i = min(int(np.searchsorted(replay.time, time)), len(replay.time) - 1)
        return replay.frame(i)
    finally:
        replay.close()


def check_out(out) -> Path:
    """The mp4 path ``out``, checked before any rendering.

    It must end in .mp4, not be a folder, and lie in a folder that exists or can be made and
    is writable.
    """
    if not isinstance(out, (str, os.PathLike)):
        raise RenderError(f"out must be an .mp4 file path (str or os.PathLike), got "
                          f"{type(out).__name__}")
    out = Path(out)
    if out.suffix.lower() != ".mp4":
        raise RenderError(f"out '{out}' must end in .mp4")
    if out.is_dir():
        raise RenderError(f"out '{out}' is a folder; give an .mp4 file path")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out.parent):
            pass
    except OSError as exc:
        raise RenderError(f"out '{out}': its folder is not writable ({exc.strerror or exc})"
                          ) from exc
    return out


def render_run(run_dir, out, fps: int = 30, width: int = 640, height: int = 360,
               plot_width: int = 320, progress=None) -> Path:
    """Render the run in ``run_dir`` (folder or log.npz) to the mp4 ``out``.

    Args:
        run_dir: A run folder (``log.npz``) written by ``wbc run``.
        out: The mp4 file to write.
        fps: Frames per second, in [5, 60].
        width: Width of the 3-D view [px], in [160, 1920] (rounded down to a multiple of 8).
        height: Its height [px], in [120, 1080] (likewise).
        plot_width: Width of the force plot beside it [px], in [0, 960]; 0: none.
        progress: Called with the fraction done after each frame, or None.

    Returns:
        The written file.

    Raises:
        RenderError: A setting out of range, ``out`` not an .mp4 path in a writable folder,
            the video cannot be written, or no GL context (set ``MUJOCO_GL=egl``).
        LogError: The log cannot be read or replayed.
    """
    out = check_out(out)
    fps = _check("fps", fps, 5, 60)
    width = _check("width", width, 160, 1920) // 8 * 8
    height = _check("height", height, 120, 1080) // 8 * 8
    plot_width = _check("plot_width", plot_width, 0, 960) // 8 * 8
    import imageio.v2 as imageio

    replay = _Replayer(run_dir, width, height)
    t = replay.time
    samples = np.minimum(np.searchsorted(t, np.arange(t[0], t[-1] + 1e-9, 1.0 / fps)),
                         len(t) - 1)
    panel = _plot_panel(replay.log, replay.threshold, plot_width, height) if plot_width \
        else None
    try:
        with imageio.get_writer(out, fps=fps, codec="libx264", quality=7,
                                macro_block_size=8) as writer:
            for n, i in enumerate(samples):
                frame = replay.frame(i)
                if panel is not None:
                    image, column, (top, bottom) = panel
                    side = image.copy()
                    c = min(max(column(t[i]), 0), side.shape[1] - 2)
                    side[top:bottom, c:c + 2] = (40, 40, 40)
                    frame = np.concatenate([frame, side], axis=1)
                writer.append_data(frame)
                if progress is not None:
                    progress((n + 1) / len(samples))
    except OSError as exc:  # ffmpeg gone, disk full: imageio reports a broken pipe
        raise RenderError(f"cannot write the video '{out}' ({exc.strerror or exc})") from exc
    finally:
        replay.close()
    return out
