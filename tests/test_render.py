"""Rendering: frames, colours at positions, videos read back, output errors, large maps, commands."""

from __future__ import annotations

import argparse
import os
import re
import struct
import subprocess
import sys
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from apf_physics import save_world, world_from_dict
from apf_physics.errors import UserError
from apf_physics.render import (
    FieldImage,
    Snapshot,
    VideoWriter,
    draw_field_plot,
    draw_frame,
    field_figure,
    formation_roles,
    plot_field,
    render_trajectory,
    robot_colours,
    stack_paths,
    trajectory_snapshots,
    write_png,
    write_video,
)
from apf_physics.render.drawing import BLACK, BLUE, OBSTACLE_FILL, RED, YELLOW, heatmap
from apf_physics.render.field_plot import figure_map_origin
from apf_physics.render.video import choose_codec


def make_world(size=(20, 20), **overrides):
    w, h = size
    data = {
        "name": "render-test",
        "size": [w, h],
        "robot_radius": 0.25,
        "field": "thesis-demo",
        "obstacles": [
            {"polygon": [[0.3 * w, 0.4 * h], [0.45 * w, 0.4 * h], [0.45 * w, 0.5 * h], [0.3 * w, 0.5 * h]]},
            {"circle": {"center": [0.7 * w, 0.3 * h], "radius": 0.05 * min(w, h)}},
        ],
        "targets": [[0.8 * w, 0.8 * h]],
        "starts": [[0.1 * w, 0.1 * h], [0.15 * w, 0.85 * h]],
    }
    data.update(overrides)
    return world_from_dict(data)


@pytest.fixture(scope="module")
def world():
    return make_world()


@pytest.fixture(scope="module")
def image(world):
    return FieldImage.from_world(world, 512)


def colour_at(frame: np.ndarray, image: FieldImage, point) -> tuple[int, int, int]:
    col, row = image.pixel_of(np.asarray(point, dtype=float))[0]
    return tuple(int(v) for v in frame[row, col])


def test_frame_draws_the_field_and_the_obstacles_where_they_are(world, image):
    """The background is the field's heatmap (viridis washed to white: low U purple, high U yellow)
    and the obstacles are filled white where they are."""
    frame = draw_frame(image, Snapshot([[2.0, 2.0]], ("single",)))
    assert frame.shape == (512, 512, 3) and frame.dtype == np.uint8
    inside = [0.375 * 20, 0.45 * 20]                      # the middle of the polygon obstacle
    assert colour_at(frame, image, inside) == OBSTACLE_FILL
    assert colour_at(frame, image, [0.7 * 20, 0.3 * 20]) == OBSTACLE_FILL   # the circle's centre

    def patch(point):   # the mean colour of a 5x5 patch (level lines cross some pixels)
        col, row = image.pixel_of(np.asarray(point, float))[0]
        return frame[row - 2:row + 3, col - 2:col + 3].reshape(-1, 3).mean(axis=0)

    low = patch(world.targets[0] + [1.5, 0.0])             # in the target's black hole: the lowest U around
    high = patch([0.3 * 20 - 0.3, 0.45 * 20])              # just outside the polygon, within p0: U is high
    u_low, u_high = world.potential(np.array([world.targets[0] + [1.5, 0.0], [0.3 * 20 - 0.3, 0.45 * 20]]))
    assert u_low < u_high
    assert high[0] > low[0] + 30 and high[2] < low[2]     # yellower (red up, blue down) where U is higher


def test_draw_frame_is_pure(image):
    before = image.background.copy()
    snapshot = Snapshot([[2.0, 2.0]], ("single",), (np.array([[1.0, 1.0], [2.0, 2.0]]),), ("step 1",))
    first = draw_frame(image, snapshot)
    second = draw_frame(image, snapshot)
    assert np.array_equal(first, second)
    assert np.array_equal(image.background, before)
    assert not np.array_equal(first, before)


def test_single_robot_is_blue_at_its_position_with_yellow_trail(image):
    trail = np.array([[2.0, 2.0], [3.0, 3.0], [4.0, 4.0], [5.0, 5.0]])
    frame = draw_frame(image, Snapshot(trail[-1:], ("single",), (trail,)))
    assert colour_at(frame, image, trail[-1]) == BLUE
    assert colour_at(frame, image, [2.5, 2.5]) == YELLOW  # on the trail, away from the disc


def test_formation_colours_at_positions(image):
    positions = np.array([[3.0, 3.0], [3.0, 6.0], [6.0, 3.0], [2.0, 12.0]])
    frame = draw_frame(image, Snapshot(positions, formation_roles(4)))
    colours = robot_colours(formation_roles(4))
    assert colour_at(frame, image, positions[0]) == YELLOW   # leader
    assert colour_at(frame, image, positions[1]) == BLUE     # follower 1
    assert colour_at(frame, image, positions[2]) == BLACK    # follower 2
    assert colour_at(frame, image, positions[3]) == colours[3][0]
    assert len({c for c, _ in colours}) == 4


def test_target_is_red_at_its_position(world, image):
    frame = draw_frame(image, Snapshot([[2.0, 2.0]], ("single",)))
    assert colour_at(frame, image, world.targets[0]) == RED


def test_world_y_up_is_image_rows_down(image):
    frame_top = draw_frame(image, Snapshot([[2.0, 18.0]], ("single",)))
    col, row = image.pixel_of(np.array([2.0, 18.0]))[0]
    assert row < 512 // 4          # high y: near the top of the image
    assert tuple(frame_top[row, col]) == BLUE
    assert image.pixel_of(np.array([0.0, 0.0]))[0].tolist() == [0, 511]


def test_unknown_role_and_mismatched_lengths_are_rejected():
    with pytest.raises(ValueError, match="role"):
        Snapshot([[1.0, 1.0]], ("pilot",))
    with pytest.raises(ValueError, match="roles"):
        Snapshot([[1.0, 1.0], [2.0, 2.0]], ("single",))
    with pytest.raises(ValueError, match="trails"):
        Snapshot([[1.0, 1.0]], ("single",), (np.zeros((2, 2)), np.zeros((2, 2))))


@pytest.mark.parametrize("size, expected", [((50, 50), (512, 512, 3)), ((50, 20), (205, 512, 3)),
                                            ((20, 50), (512, 205, 3))])
def test_large_worlds_keep_the_long_side_and_visible_robots(size, expected):
    world = make_world(size)
    image = FieldImage.from_world(world)
    assert image.shape == expected
    assert image.scale == pytest.approx(512 / 50)
    # The true radius (0.25 units) is 2.6 px here: it is drawn at least 3 px wide.
    assert image.robot_radius >= 3.0
    position = np.array([0.1 * size[0], 0.1 * size[1]])
    frame = draw_frame(image, Snapshot(position[None], ("single",)))
    col, row = image.pixel_of(position)[0]
    blue = np.all(frame[row - 2: row + 3, col - 2: col + 3] == BLUE, axis=2)
    assert blue.sum() >= 9


def test_bigger_images_scale_lines_and_discs(world):
    small, large = FieldImage.from_world(world, 256), FieldImage.from_world(world, 1024)
    assert large.shape == (1024, 1024, 3)
    assert large.robot_radius == pytest.approx(4 * small.robot_radius)
    assert large.line_width > small.line_width


def test_trajectory_snapshots_and_hold():
    trajectory = np.stack([np.linspace([1, 1], [5, 5], 6), np.linspace([1, 3], [5, 7], 6)], axis=1)
    snapshots = list(trajectory_snapshots(trajectory, formation_roles(2), final_overlay=("done",), hold=3))
    assert len(snapshots) == 9
    assert snapshots[0].overlay[0] == "step 0/5"
    assert "done" in snapshots[-1].overlay and "done" not in snapshots[0].overlay
    assert [len(t) for t in snapshots[2].trails] == [3, 3]


def test_stack_paths_holds_the_last_position():
    stacked = stack_paths([np.zeros((3, 2)), np.ones((5, 2))])
    assert stacked.shape == (5, 2, 2)
    assert np.array_equal(stacked[4, 0], [0.0, 0.0])


def read_with_pyav(path):
    """(codec name, pix_fmt, decoded frames, duration in s, RGB frames) of a video file."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        frames = [frame.to_ndarray(format="rgb24") for frame in container.decode(stream)]
        duration = container.duration / av.time_base
        return stream.codec_context.name, stream.codec_context.pix_fmt, len(frames), duration, frames


@pytest.mark.parametrize("suffix, codec, expected", [(".mp4", None, "h264"), (".webm", None, "vp9")])
def test_browser_video_is_h264_or_vp9_yuv420p_with_frames_and_duration(world, tmp_path, suffix, codec, expected):
    trajectory = np.linspace([2.0, 2.0], [10.0, 15.0], 12)
    out = tmp_path / f"run{suffix}"
    written = write_video(render_trajectory(world, trajectory, long_side=256), out, fps=10, codec=codec)
    assert written == 12
    name, pix_fmt, count, duration, frames = read_with_pyav(out)
    assert (name, pix_fmt, count) == (expected, "yuv420p", 12)
    assert duration == pytest.approx(1.2, abs=0.05)
    assert frames[0].shape == (256, 256, 3)


def test_h264_mp4_has_its_index_first(world, tmp_path):
    # +faststart: the moov atom comes before the media data, so a browser can start at once.
    out = tmp_path / "run.mp4"
    write_video(render_trajectory(world, np.linspace([2.0, 2.0], [10.0, 15.0], 5), long_side=128), out)
    data = out.read_bytes()
    assert data.index(b"moov") < data.index(b"mdat")


def test_odd_frame_sizes_are_padded_for_yuv420p(tmp_path):
    frames = [np.full((33, 47, 3), 200, np.uint8)] * 3
    write_video(frames, tmp_path / "odd.mp4")
    _, _, count, _, decoded = read_with_pyav(tmp_path / "odd.mp4")
    assert count == 3 and decoded[0].shape == (34, 48, 3)


@pytest.mark.parametrize("suffix, codec", [(".avi", None), (".mp4", "mp4v")])
def test_opencv_video_reads_back_with_frame_count_and_size(world, tmp_path, suffix, codec):
    trajectory = np.linspace([2.0, 2.0], [10.0, 15.0], 12)
    out = tmp_path / f"run{suffix}"
    written = write_video(render_trajectory(world, trajectory, long_side=256), out, fps=10, codec=codec)
    assert written == 12
    capture = cv2.VideoCapture(str(out))
    assert capture.isOpened()
    count = 0
    while True:
        ok, frame = capture.read()
        if not ok:
            break
        assert frame.shape == (256, 256, 3)
        count += 1
    capture.release()
    assert count == 12
    assert read_with_pyav(out)[0] == {".avi": "mjpeg", ".mp4": "mpeg4"}[suffix]


def test_codec_choice_by_extension_and_mismatches():
    assert choose_codec("a.mp4").name == "h264"
    assert choose_codec("a.webm").name == "vp9"
    assert choose_codec("a.avi").name == "mjpg"
    assert choose_codec("a.mp4", "mp4v").browsers is False
    with pytest.raises(UserError, match=r"H\.264 needs a \.mp4 file"):
        choose_codec("a.webm", "h264")
    with pytest.raises(UserError, match="unknown codec 'x265'"):
        choose_codec("a.mp4", "x265")


def test_without_pyav_mp4_falls_back_to_mp4v_and_says_so(monkeypatch):
    from apf_physics.render import video

    monkeypatch.setattr(video, "av", None)
    fallback = choose_codec("a.mp4")
    assert (fallback.name, fallback.browsers) == ("mp4v", False)
    with pytest.raises(UserError, match=r"VP9 needs PyAV \(pip install av\)"):
        choose_codec("a.webm")
    with pytest.raises(UserError, match=r"H\.264 needs PyAV"):
        choose_codec("a.mp4", "h264")


def test_writing_videos_prints_no_codec_warnings(tmp_path):
    # OpenCV's FFMPEG backend printed "tag ... is not supported" for every .webm; FFmpeg and
    # x264 print statistics unless their log is off. Nothing may reach the terminal.
    script = f"""
import numpy as np
from apf_physics.render import write_video
frames = [np.full((64, 64, 3), i * 20, np.uint8) for i in range(5)]
for name, codec in [("a.mp4", None), ("b.webm", None), ("c.avi", None), ("d.mp4", "mp4v")]:
    write_video(frames, {str(tmp_path)!r} + "/" + name, codec=codec)
print("done")
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "done"
    assert result.stderr == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mp4", "b.webm", "c.avi", "d.mp4"]


def test_video_colours_survive_h264(tmp_path):
    # BT.709 limited range, tagged in the stream: a decoder shows the colours that were drawn
    # (decoding as BT.601 shifts the red by 23 levels; flat quadrants keep 4:2:0 out of it).
    colours = np.array([BLUE, YELLOW, RED, (235, 235, 235)], np.uint8)
    frame = np.empty((128, 128, 3), np.uint8)
    for i, colour in enumerate(colours):
        frame[64 * (i // 2): 64 * (i // 2 + 1), 64 * (i % 2): 64 * (i % 2 + 1)] = colour
    write_video([frame] * 3, tmp_path / "colour.mp4", fps=5)
    decoded = read_with_pyav(tmp_path / "colour.mp4")[4][0].astype(int)
    for i, colour in enumerate(colours):
        centre = decoded[64 * (i // 2) + 32, 64 * (i % 2) + 32]
        assert np.abs(centre - colour).max() <= 4, (colour, centre)


def test_failed_render_leaves_the_old_video_and_no_temporary_file(world, tmp_path):
    out = tmp_path / "run.mp4"
    out.write_bytes(b"the old video")

    def frames_then_failure():
        yield from render_trajectory(world, np.linspace([2.0, 2.0], [10.0, 15.0], 5), long_side=128)
        raise KeyboardInterrupt  # a render stopped half-way

    with pytest.raises(KeyboardInterrupt):
        write_video(frames_then_failure(), out)
    assert out.read_bytes() == b"the old video"
    assert [p.name for p in tmp_path.iterdir()] == ["run.mp4"]
    write_video(render_trajectory(world, np.linspace([2.0, 2.0], [10.0, 15.0], 5), long_side=128), out)
    assert read_with_pyav(out)[2] == 5
    assert [p.name for p in tmp_path.iterdir()] == ["run.mp4"]


def test_videos_and_pngs_refuse_to_replace_what_is_not_a_regular_file(tmp_path):
    target = tmp_path / "real.mp4"
    target.write_bytes(b"keep")
    link = tmp_path / "link.mp4"
    link.symlink_to(target)
    fifo = tmp_path / "pipe.mp4"
    os.mkfifo(fifo)
    with pytest.raises(UserError, match="link.mp4: it is a symbolic link"):
        VideoWriter(link, 10, (64, 64))
    with pytest.raises(UserError, match="pipe.mp4: it is a FIFO"):
        VideoWriter(fifo, 10, (64, 64))
    png_link = tmp_path / "final.png"
    png_link.symlink_to(target)
    with pytest.raises(UserError, match="final.png: it is a symbolic link"):
        write_png(np.zeros((8, 8, 3), np.uint8), png_link)
    assert target.read_bytes() == b"keep" and link.is_symlink() and fifo.exists()


def test_unwritable_video_path_names_the_path(world, tmp_path):
    out = tmp_path / "no" / "such" / "dir" / "run.mp4"
    with pytest.raises(UserError, match=re.escape(str(out))):
        write_video(render_trajectory(world, np.zeros((2, 2)) + 2), out)
    with pytest.raises(UserError, match="run.mp4"):
        VideoWriter(tmp_path / "missing" / "run.mp4", 10, (64, 64))
    folder = tmp_path / "folder.mp4"
    folder.mkdir()
    with pytest.raises(UserError, match="is a directory"):
        VideoWriter(folder, 10, (64, 64))


def test_unsupported_extension_is_a_user_error(tmp_path):
    with pytest.raises(UserError, match=r"run\.gif"):
        VideoWriter(tmp_path / "run.gif", 10, (64, 64))
    with pytest.raises(UserError, match=r"final\.jpg"):
        write_png(np.zeros((8, 8, 3), np.uint8), tmp_path / "final.jpg")


def test_png_written_and_unwritable_png_names_the_path(image, tmp_path):
    frame = draw_frame(image, Snapshot([[2.0, 2.0]], ("single",)))
    out = tmp_path / "final.png"
    write_png(frame, out)
    back = cv2.imread(str(out))[:, :, ::-1]
    assert np.array_equal(back, frame)
    missing = tmp_path / "nope" / "final.png"
    with pytest.raises(UserError, match=re.escape(str(missing))):
        write_png(frame, missing)


def test_write_video_rejects_frames_of_another_size(tmp_path):
    frames = [np.zeros((64, 64, 3), np.uint8), np.zeros((32, 32, 3), np.uint8)]
    with pytest.raises(ValueError, match="64"):
        write_video(frames, tmp_path / "bad.mp4")


def test_field_plot_draws_yellow_paths_blue_starts_and_rings_for_traps(world, tmp_path):
    reached_path = np.linspace([2.0, 2.0], world.targets[0], 20)
    trapped_path = np.linspace([3.0, 17.0], [5.0, 12.0], 10)
    image = FieldImage.from_world(world, 512)
    plot = draw_field_plot(world, [reached_path, trapped_path], image=image)
    assert colour_at(plot, image, reached_path[0]) == BLUE
    assert colour_at(plot, image, reached_path[8]) == YELLOW
    assert colour_at(plot, image, world.targets[0]) == RED        # targets stay on top of the paths
    # A trapped end is a ring: blue around a centre that is not blue.
    end = trapped_path[-1]
    assert colour_at(plot, image, end) != BLUE
    ring = image.pixel_of(end)[0] + [0, int(round(0.7 * image.robot_radius))]
    assert tuple(plot[ring[1], ring[0]]) == BLUE
    out = tmp_path / "field.png"
    written = plot_field(world, [reached_path], out)
    assert out.is_file() and cv2.imread(str(out)).shape == written.shape


def test_field_figure_keeps_the_map_clear_and_adds_a_colour_bar(world):
    image = FieldImage.from_world(world, 512)
    paths = [np.linspace([2.0, 2.0], world.targets[0], 20)]
    plot = draw_field_plot(world, paths, image=image)
    figure = field_figure(world, paths, title=["render-test", "1 start"], image=image)
    row, col = figure_map_origin(2, image)
    # The map is pasted whole: no title, legend or colour bar drawn over the data.
    assert np.array_equal(figure[row: row + 512, col: col + 512], plot)
    assert figure.shape[1] > 512 + 150 and row > 0
    # The colour bar: the heatmap's top colour (shade 1) above its bottom colour (shade 0).
    panel = figure[row:, 512:]
    top, bottom = heatmap(np.array([[1.0]], np.float32))[0, 0], heatmap(np.array([[0.0]], np.float32))[0, 0]
    top_rows = np.argwhere(np.abs(panel.astype(int) - top).max(axis=2) <= 3)[:, 0]
    bottom_rows = np.argwhere(np.abs(panel.astype(int) - bottom).max(axis=2) <= 3)[:, 0]
    assert len(top_rows) > 20 and len(bottom_rows) > 20
    assert top_rows.max() < bottom_rows.min()


@pytest.mark.parametrize("scaling", ["log", "rank"])
def test_colour_scale_runs_from_the_lowest_potential_upwards(world, scaling):
    image = FieldImage.from_world(world, 128, scaling=scaling)
    scale = image.shade_potential
    assert np.all(np.diff(scale) >= 0) and scale[-1] > scale[0]
    lowest = world.raster(4).values.min()
    assert scale[0] == pytest.approx(lowest, rel=1e-6, abs=1e-6) if scaling == "log" else scale[0] >= lowest


def test_plot_field_command(world, tmp_path, capsys):
    from apf_physics.cli import plot_field as command

    world_file = tmp_path / "w.yaml"
    save_world(world, world_file)
    parser = argparse.ArgumentParser()
    command.add_parser(parser.add_subparsers())
    out = tmp_path / "new" / "field.png"
    args = parser.parse_args(["plot-field", str(world_file), "--out", str(out), "--size", "256"])
    assert args.func(args) == 0
    height, width = cv2.imread(str(out)).shape[:2]
    assert height >= 256 and width > 256       # the map, a title above and the colour bar beside it
    assert "2 starts" in capsys.readouterr().out
    bad = parser.parse_args(["plot-field", str(world_file), "--out", str(tmp_path / "f.jpg")])
    with pytest.raises(UserError, match="f.jpg"):
        bad.func(bad)


def test_render_command_writes_h264_and_png_into_a_new_folder(world, tmp_path, capsys):
    from apf_physics.cli import render as command

    world_file = tmp_path / "w.yaml"
    save_world(world, world_file)
    parser = argparse.ArgumentParser()
    command.add_parser(parser.add_subparsers())
    out, png = tmp_path / "new" / "dir" / "run.mp4", tmp_path / "final.png"
    args = parser.parse_args(["render", str(world_file), "--planner", "gradient", "--all-starts", "--out", str(out),
                              "--png", str(png), "--size", "128", "--hold", "0", "--no-progress"])
    assert args.func(args) == 0
    name, pix_fmt, frames, _, _ = read_with_pyav(out)
    assert (name, pix_fmt) == ("h264", "yuv420p") and frames >= 2
    assert f"wrote {out} (H.264;" in capsys.readouterr().out
    assert cv2.imread(str(png)).shape == (128, 128, 3)
    bad = parser.parse_args(["render", str(world_file), "--start", "7", "--out", str(out), "--no-progress"])
    with pytest.raises(UserError, match="--start 7"):
        bad.func(bad)
    mp4v = parser.parse_args(["render", str(world_file), "--out", str(tmp_path / "old.mp4"), "--codec", "mp4v",
                              "--hold", "0", "--size", "64", "--no-progress"])
    assert mp4v.func(mp4v) == 0
    assert "mp4v, which browsers do not play" in capsys.readouterr().out
    avi = parser.parse_args(["render", str(world_file), "--out", str(tmp_path / "run.avi"), "--hold", "0",
                             "--size", "64", "--no-progress"])
    assert avi.func(avi) == 0
    said = capsys.readouterr().out     # PyAV is installed: an .avi is MJPG by choice of extension, not for want of PyAV
    assert "MJPG, which browsers do not play (write .mp4 for H.264 or .webm for VP9)" in said
    assert "not installed" not in said


def test_render_refuses_a_symlink_before_any_work(tmp_path):
    from apf_physics.cli import main

    target = tmp_path / "kept.mp4"
    target.write_bytes(b"keep")
    (tmp_path / "link.mp4").symlink_to(target)
    # The world does not exist: the output is checked first, so that is not what is reported.
    with pytest.raises(UserError, match="link.mp4: it is a symbolic link"):
        from apf_physics.cli import render as command

        parser = argparse.ArgumentParser()
        command.add_parser(parser.add_subparsers())
        args = parser.parse_args(["render", str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "link.mp4")])
        args.func(args)
    assert main(["render", str(tmp_path / "missing.yaml"), "--out", str(tmp_path / "link.mp4")]) == 2
    assert target.read_bytes() == b"keep"


def run_with_terminal_stderr(command: list[str]) -> tuple[int, bytes]:
    """Run ``command`` with stderr on a pseudo-terminal; returns (exit status, what reached stderr)."""
    pty = pytest.importorskip("pty")
    fcntl, termios = pytest.importorskip("fcntl"), pytest.importorskip("termios")
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))  # a new pty is 0x0: no room for a bar
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=slave)
    os.close(slave)
    received = b""
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:  # EIO: the process closed its end
            break
        if not chunk:
            break
        received += chunk
    os.close(master)
    return process.wait(timeout=120), received


@pytest.mark.parametrize("flags, shown", [((), True), (("--no-progress",), False)])
def test_render_progress_bar_only_on_a_terminal_and_not_with_no_progress(world, tmp_path, flags, shown):
    world_file = tmp_path / "w.yaml"
    save_world(world, world_file)
    command = [sys.executable, "-m", "apf_physics.cli", "render", str(world_file), "--all-starts", "--size", "64",
               "--out", str(tmp_path / "run.mp4"), *flags]
    status, terminal = run_with_terminal_stderr(command)
    assert status == 0
    assert (b"frame" in terminal) is shown, terminal
    piped = subprocess.run(command[:-len(flags) or None], capture_output=True, text=True, timeout=120)
    assert piped.returncode == 0 and piped.stderr == ""   # stderr not a terminal: no bar


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux's /proc, a folder that takes no new files")
def test_plot_curve_to_an_unwritable_place_fails_with_one_line(tmp_path):
    csv = tmp_path / "train.csv"
    csv.write_text("global_step,success_rate,mean_return,eval_success\n0,0,-5,\n100,0.5,-2,0.4\n")
    result = subprocess.run([sys.executable, "-m", "apf_physics.cli", "plot-curve", str(csv), "--out", "/proc/c.png"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert "wrote" not in result.stdout
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("apf-physics: error: cannot write /proc/c.png")
    ok = subprocess.run([sys.executable, "-m", "apf_physics.cli", "plot-curve", str(csv), "--out",
                         str(tmp_path / "new" / "c.png")], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and cv2.imread(str(tmp_path / "new" / "c.png")).shape == (480, 720, 3)


def test_plot_curve_legend_stays_outside_the_axes(tmp_path):
    from apf_physics.learning.plot import plot_training_curve

    # No data: whatever is drawn inside the axes boxes can only be the legend.
    csv = tmp_path / "train.csv"
    csv.write_text("global_step,success_rate,mean_return,eval_success\n")
    image = plot_training_curve(csv)
    for top, height in ((30, 190), (260, 190)):   # the two panels' boxes
        inside = image[top + 2: top + height - 1, 72: image.shape[1] - 22]
        assert np.all(inside == 255)
    assert np.any(image[:28, 360:] != 255)       # the legend, on the title line


def test_formation_roles_and_colours():
    assert formation_roles(3) == ("leader", "follower1", "follower2")
    leader, follower1, follower2 = robot_colours(formation_roles(3))
    assert (leader[0], follower1[0], follower2[0]) == (YELLOW, BLUE, BLACK)
    assert robot_colours(("single",)) == [(BLUE, YELLOW)]
    plain = robot_colours(("leader", "follower", "follower"))
    assert plain[1][0] != plain[2][0]


def test_render_clips_single_robots_together_and_formations_in_turn():
    from types import SimpleNamespace

    from apf_physics.render.episodes import episode_clips, is_formation

    def episode(positions, outcome="reached"):
        # A rollout's episode: the (leader's) path; a formation's also its record of every robot.
        positions = np.asarray(positions, dtype=float)
        path = positions if positions.ndim == 2 else positions[:, 0]
        record = None if positions.ndim == 2 else SimpleNamespace(positions=positions)
        return SimpleNamespace(path=path, formation=record, start=path[0], outcome=outcome, steps=len(path) - 1)

    singles = [episode(np.linspace([1, 1], [5, 5], 4)), episode(np.linspace([1, 9], [5, 9], 7), "trapped")]
    assert not is_formation(singles)
    (trajectory, roles, lines, final, families), = episode_clips(singles, ("world w",), False, None)
    assert families == ()
    assert trajectory.shape == (7, 2, 2) and roles == ("single", "single")
    assert "reached 1, trapped 1" in final[0]
    line = np.linspace([1, 1], [5, 5], 5)
    formation = [episode(np.stack([line, line - 0.5, line - 1.0], axis=1)) for _ in range(2)]
    assert is_formation(formation)
    clips = list(episode_clips(formation, ("world w",), True, None))
    assert len(clips) == 2
    assert clips[0][0].shape == (5, 3, 2) and clips[0][1] == ("leader", "follower1", "follower2")
