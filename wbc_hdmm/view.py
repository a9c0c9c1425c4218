"""``wbc view``: replay a run in MuJoCo's passive viewer, at real time, where a display exists."""

from __future__ import annotations

import os
import time

from wbc_hdmm.render import RenderError
from wbc_hdmm.replay import replay_scene

__all__ = ["view_run"]


def view_run(run_dir) -> None:
    """Open the viewer on the run's model and play its ``qpos`` at real time.

    Raises:
        RenderError: No display to open a window on.
        LogError: The log cannot be read or replayed.
    """
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        raise RenderError("no display for the viewer (DISPLAY is not set); headless, use "
                          "`wbc render RUN_DIR` for an mp4")
    import mujoco
    import mujoco.viewer

    from models.mujoco import build_model

    log, machine, terrain, _ = replay_scene(run_dir)
    model = build_model(machine, terrain)
    data = mujoco.MjData(model)
    t = log["time"]
    with mujoco.viewer.launch_passive(model, data) as viewer:
        start = time.perf_counter()
        for i in range(len(t)):
            if not viewer.is_running():
                break
            data.qpos[:] = log["qpos"][i]
            mujoco.mj_kinematics(model, data)
            viewer.sync()
            delay = (t[i] - t[0]) - (time.perf_counter() - start)
            if delay > 0:
                time.sleep(delay)
