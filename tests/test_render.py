"""Rendering: frames, colours at positions, videos read back, output errors, large maps, commands."""

from __future__ import annotations

import argparse
import re

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
    formation_roles,
    plot_field,
    render_trajectory,
    robot_colours,
    stack_paths,
    trajectory_snapshots,
    write_png,
    write_video,
)
from apf_physics.render.drawing import BLACK, BLUE, RED, YELLOW


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


def test_frame_shape_dtype_and_not_blank(world, image):
    frame = draw_frame(image, Snapshot([[2.0, 2.0]], ("single",)))
    assert frame.shape == (512, 512, 3)
    assert frame.dtype == np.uint8
    # A heatmap with level lines, obstacles and a target: many colours, not one flat fill.
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 100
    assert frame.std() > 10


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


@pytest.mark.parametrize("suffix, codec", [(".mp4", None), (".avi", None), (".webm", None), (".mp4", "h264")])
def test_video_reads_back_with_frame_count_and_size(world, tmp_path, suffix, codec):
    if codec == "h264":
        pytest.importorskip("imageio_ffmpeg")
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


def test_video_frame_colours_survive_encoding(world, tmp_path):
    image = FieldImage.from_world(world, 256)
    position = np.array([3.0, 3.0])
    frames = [draw_frame(image, Snapshot(position[None], ("single",)))] * 3
    out = tmp_path / "colour.avi"
    write_video(frames, out, fps=5)
    ok, bgr = cv2.VideoCapture(str(out)).read()
    assert ok
    col, row = image.pixel_of(position)[0]
    rgb = bgr[row, col, ::-1].astype(int)
    assert np.abs(rgb - np.array(BLUE)).max() < 40   # lossy codec: close to blue, not exact


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


def test_plot_field_command(world, tmp_path, capsys):
    from apf_physics.commands import plot_field as command

    world_file = tmp_path / "w.yaml"
    save_world(world, world_file)
    parser = argparse.ArgumentParser()
    command.add_parser(parser.add_subparsers())
    out = tmp_path / "field.png"
    args = parser.parse_args(["plot-field", str(world_file), "--out", str(out), "--size", "256"])
    assert args.func(args) == 0
    assert cv2.imread(str(out)).shape == (256, 256, 3)
    assert "2 starts" in capsys.readouterr().out
    bad = parser.parse_args(["plot-field", str(world_file), "--out", str(tmp_path / "x" / "f.png")])
    with pytest.raises(UserError, match="f.png"):
        bad.func(bad)


def test_render_command_writes_video_and_png(world, tmp_path):
    from apf_physics.commands import render as command

    world_file = tmp_path / "w.yaml"
    save_world(world, world_file)
    parser = argparse.ArgumentParser()
    command.add_parser(parser.add_subparsers())
    out, png = tmp_path / "run.mp4", tmp_path / "final.png"
    args = parser.parse_args(["render", str(world_file), "--planner", "gradient", "--all-starts", "--out", str(out),
                              "--png", str(png), "--size", "128", "--hold", "0", "--no-progress"])
    assert args.func(args) == 0
    capture = cv2.VideoCapture(str(out))
    frames = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    assert frames >= 2
    assert cv2.imread(str(png)).shape == (128, 128, 3)
    bad = parser.parse_args(["render", str(world_file), "--start", "7", "--out", str(out), "--no-progress"])
    with pytest.raises(UserError, match="--start 7"):
        bad.func(bad)


def test_formation_roles_and_colours():
    assert formation_roles(3) == ("leader", "follower1", "follower2")
    leader, follower1, follower2 = robot_colours(formation_roles(3))
    assert (leader[0], follower1[0], follower2[0]) == (YELLOW, BLUE, BLACK)
    assert robot_colours(("single",)) == [(BLUE, YELLOW)]
    plain = robot_colours(("leader", "follower", "follower"))
    assert plain[1][0] != plain[2][0]


def test_render_clips_single_robots_together_and_formations_in_turn():
    from types import SimpleNamespace

    from apf_physics.render.episodes import episode_clips as _clips

    def episode(path, outcome="reached"):
        path = np.asarray(path, dtype=float)
        return SimpleNamespace(path=path, positions=path, start=path[0].reshape(-1, 2)[0], outcome=outcome,
                               steps=len(path) - 1)

    singles = [episode(np.linspace([1, 1], [5, 5], 4)), episode(np.linspace([1, 9], [5, 9], 7), "trapped")]
    (trajectory, roles, lines, final), = _clips(singles, ("world w",), False, None)
    assert trajectory.shape == (7, 2, 2) and roles == ("single", "single")
    assert "reached 1, trapped 1" in final[0]
    line = np.linspace([1, 1], [5, 5], 5)
    formation = [episode(np.stack([line, line - 0.5, line - 1.0], axis=1)) for _ in range(2)]
    clips = list(_clips(formation, ("world w",), True, None))
    assert len(clips) == 2
    assert clips[0][0].shape == (5, 3, 2) and clips[0][1] == ("leader", "follower1", "follower2")
