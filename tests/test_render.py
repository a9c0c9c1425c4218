"""wbc render: the video of a short run, the arrows' colours, and refused outputs."""

import imageio.v2 as imageio
import numpy as np
import pytest

from models.log import load_log
from scenarios import registry
from wbc_hdmm.render import MARGIN_WARN, RenderError, frame_at, render_run


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("swing")
    registry.run("swing-out", out, controller="tracking", duration=1.2, progress=False)
    return out


def _red(image):
    image = np.asarray(image, int)
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    return (r > 120) & (r > 2 * g) & (r > 2 * b)  # shaded red, as MuJoCo lights it


def _green(image):
    image = np.asarray(image, int)
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    return (g > 120) & (g > 1.6 * r) & (g > 1.6 * b)


def test_mp4_opens_with_one_frame_per_period_and_content(run, tmp_path):
    out = render_run(run, tmp_path / "clip.mp4", fps=5, width=160, height=120, plot_width=96)
    t = load_log(run)["time"]
    with imageio.get_reader(out) as reader:
        frames = [frame for frame in reader]  # len(reader) is inf for ffmpeg: no list()
        assert reader.get_meta_data()["fps"] == 5
    assert len(frames) == len(np.arange(t[0], t[-1] + 1e-9, 0.2))
    assert frames[0].shape == (120, 256, 3)
    view = np.asarray(frames[-1][:, :160], float)
    assert view.std() > 10.0
    yellow = (view[..., 0] > 150) & (view[..., 1] > 100) & (view[..., 2] < 80)
    assert yellow.sum() > 20  # the machine's paint


def _with_forces(run, tmp_path, forces):
    log = dict(load_log(run))
    log["normal_force"] = np.broadcast_to(forces, log["normal_force"].shape).copy()
    tmp_path.mkdir()
    np.savez(tmp_path / "log.npz", **log)
    return tmp_path, float(log["meta_threshold"])


def test_arrows_are_green_above_the_margin_and_red_below_the_threshold(run, tmp_path):
    thr = float(load_log(run)["meta_threshold"])
    high = thr + MARGIN_WARN + 8e3  # [N] a 1 m arrow or so
    views = {}
    for name, forces in (("high", [high] * 4), ("low", [high] * 3 + [0.5 * thr])):
        views[name] = frame_at(_with_forces(run, tmp_path / name, np.array(forces))[0], 1.0,
                               width=320, height=240)
    border = {k: np.concatenate([v[:4].reshape(-1, 3), v[-4:].reshape(-1, 3)])
              for k, v in views.items()}
    assert _red(border["high"]).mean() < 0.1
    assert _red(border["low"]).mean() > 0.9  # the frame is red-bordered while a wheel is low
    inner = {k: v[8:-8, 8:-8] for k, v in views.items()}
    assert _green(inner["high"]).sum() > 100  # four green arrows
    assert _green(inner["low"]).sum() < 0.85 * _green(inner["high"]).sum()  # three
    assert _red(inner["low"]).sum() >= _red(inner["high"]).sum() + 5  # and a short red one


def test_outputs_are_checked_before_rendering(run, tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    cases = {tmp_path / "clip.avi": "must end in .mp4", a_file / "x.mp4": "not writable",
             None: "must be an .mp4 file path"}
    (tmp_path / "dir.mp4").mkdir()
    cases[tmp_path / "dir.mp4"] = "is a folder"
    for out, message in cases.items():
        with pytest.raises(RenderError, match=message):
            render_run(run, out, fps=5, width=160, height=120)
    for name, value in (("fps", 0), ("width", 100), ("height", 2000), ("plot_width", -1)):
        with pytest.raises(RenderError, match=f"{name} {value} outside"):
            render_run(run, tmp_path / "x.mp4", **{name: value})
