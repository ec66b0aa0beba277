"""Gazebo SDF worlds as obstacles: footprints of static boxes, cylinders and spheres; hostile files refused."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from apf_physics import WorldError, load_world
from apf_physics.cli import main
from apf_physics.world.io.sdfworld import MAX_DEPTH, convex_hull, parse_xml, read_sdf_obstacles, sdf_footprints
from apf_physics.world.io.worldfile import dump_world_yaml

COLLISION = """<link name="link"><collision name="c"><geometry>{shape}</geometry></collision></link>"""


def model(name: str, shape: str, pose: str = "0 0 0 0 0 0", static: bool = True, extra: str = "") -> str:
    return (f"<model name='{name}'><static>{int(static)}</static><pose>{pose}</pose>"
            + COLLISION.format(shape=shape) + extra + "</model>")


def world(*models: str, state: str = "") -> str:
    return ("<?xml version='1.0'?><sdf version='1.6'><world name='default'>"
            "<include><uri>model://ground_plane</uri></include><include><uri>model://sun</uri></include>"
            + "".join(models) + state + "</world></sdf>")


BOX = "<box><size>2 1 1</size></box>"
CYLINDER = "<cylinder><radius>0.5</radius><length>1</length></cylinder>"


def footprints(text: str, **kwargs):
    return sdf_footprints(parse_xml(text.encode(), "w.world"), "w.world", **kwargs)


def test_boxes_cylinders_and_spheres_give_their_footprints():
    shapes = footprints(world(
        model("box", BOX, "1 2 0.5 0 0 1.5707963267948966"),
        model("pillar", CYLINDER, "5 5 0.5 0 0 0.3"),
        model("ball", "<sphere><radius>0.25</radius></sphere>", "3 3 0.25 0 0 0"),
        model("floor", "<plane><normal>0 0 1</normal><size>10 10</size></plane>"),
        model("robot", BOX, "8 8 0.2 0 0 0", static=False)))
    by_name = {s.name: s for s in shapes}
    assert set(by_name) == {"box::link::c", "pillar::link::c", "ball::link::c"}
    box = by_name["box::link::c"].vertices                    # 2 x 1, turned a quarter: 1 wide in x, 2 in y
    assert np.allclose(box.min(axis=0), [0.5, 1.0]) and np.allclose(box.max(axis=0), [1.5, 3.0])
    assert by_name["pillar::link::c"].center == pytest.approx((5, 5)) and by_name["pillar::link::c"].radius == 0.5
    assert by_name["ball::link::c"].radius == 0.25


def test_poses_compose_model_link_collision_and_nested_models():
    inner = ("<model name='inner'><pose>1 0 0 0 0 0</pose><link name='l'><pose>0 1 0 0 0 0</pose>"
             "<collision name='c'><pose>0 0 0.5 0 0 0</pose><geometry>" + CYLINDER + "</geometry></collision></link></model>")
    outer = f"<model name='outer'><static>true</static><pose>10 0 0 0 0 {math.pi / 2}</pose>{inner}</model>"
    (shape,) = footprints(world(outer))
    assert shape.name == "outer::inner::l::c"
    assert shape.center == pytest.approx((10 - 1, 1))          # (1, 1) turned a quarter about (10, 0)


def test_a_tilted_cylinder_casts_a_polygon_that_contains_its_outline():
    (shape,) = footprints(world(model("log", CYLINDER, f"0 0 0.5 {math.pi / 2} 0 0")))   # lying along y
    assert shape.vertices is not None
    lo, hi = shape.vertices.min(axis=0), shape.vertices.max(axis=0)
    assert lo[0] <= -0.5 and hi[0] >= 0.5 and lo[1] <= -0.5 and hi[1] >= 0.5
    assert hi[0] - lo[0] < 1.1 and hi[1] - lo[1] < 1.1


def test_heights_leave_out_floors_and_ceilings():
    slab = model("slab", "<box><size>4 4 0.02</size></box>", "0 0 0 0 0 0")
    lamp = model("lamp", "<sphere><radius>0.1</radius></sphere>", "0 0 3 0 0 0")
    assert footprints(world(slab, lamp)) == []
    assert len(footprints(world(slab, lamp), heights=(-1.0, 4.0))) == 2


def test_a_saved_state_moves_top_level_models():
    state = "<state world_name='default'><model name='pillar'><pose>7 8 0.5 0 0 0</pose></model></state>"
    (shape,) = footprints(world(model("pillar", CYLINDER, "1 1 0.5 0 0 0"), state=state))
    assert shape.center == pytest.approx((7, 8))


@pytest.mark.parametrize("text, words", [
    (world(model("statue", "<mesh><uri>model://statue/mesh.dae</uri></mesh>")), ["statue", "mesh", "skip"]),
    (world("<include><uri>model://bookshelf</uri></include>"), ["bookshelf", "sdf.skip"]),
    (world(model("box", BOX, "1 2 3")), ["box", "6 numbers"]),
    (world(model("box", "<box><size>1 -1 1</size></box>")), ["box", "positive"]),
    (world("<model name='m'><static>1</static><pose relative_to='other'>0 0 0 0 0 0</pose></model>"), ["other"]),
    ("<robot name='r'/>", ["<robot>", "not an SDF world"]),
])
def test_what_cannot_be_read_is_named(text, words):
    with pytest.raises(WorldError) as err:
        footprints(text)
    assert all(w in str(err.value) for w in words), str(err.value)


def test_models_can_be_skipped_by_name():
    text = world(model("statue", "<mesh><uri>x.dae</uri></mesh>"), "<include><uri>model://bookshelf</uri></include>",
                 model("box", BOX))
    assert [s.name for s in footprints(text, skip=["stat*", "bookshelf"])] == ["box::link::c"]


@pytest.mark.parametrize("data, words", [
    (b'<?xml version="1.0"?><!DOCTYPE sdf [<!ENTITY a "aaaa">]><sdf><world name="w"/></sdf>', ["DOCTYPE", "refused"]),
    (b'<sdf><world name="w">&lt;<!ENTITY x SYSTEM "file:///etc/passwd"></world></sdf>', ["ENTITY"]),
    (b"<sdf>" + b"<a>" * (MAX_DEPTH + 1) + b"</a>" * (MAX_DEPTH + 1) + b"</sdf>", ["nested"]),
    (b"<sdf><world name='w'>", ["not well-formed"]),
    ("<sdf>é</sdf>".encode("latin-1"), ["not UTF-8"]),
    (b'<?xml version="1.0" encoding="UTF-16"?><sdf/>', ["UTF-16"]),
    (b"", ["not well-formed"]),
])
def test_hostile_files_are_refused(data, words):
    with pytest.raises(WorldError) as err:
        parse_xml(data, "bad.world")
    assert str(err.value).startswith("bad.world: ") and all(w in str(err.value) for w in words), str(err.value)


def test_a_huge_or_odd_file_is_refused(tmp_path):
    with pytest.raises(WorldError, match="no such"):
        read_sdf_obstacles(tmp_path / "missing.world")
    with pytest.raises(WorldError, match="directory"):
        read_sdf_obstacles(tmp_path)


def test_convex_hull_is_counter_clockwise():
    hull = convex_hull(np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]]))
    assert len(hull) == 4
    area = 0.5 * np.sum(hull[:, 0] * np.roll(hull[:, 1], -1) - np.roll(hull[:, 0], -1) * hull[:, 1])
    assert area == pytest.approx(1.0)


# -- the world file's sdf: and origin: keys -------------------------------------------------------
def write_world(tmp_path, sdf_text: str, **overrides) -> str:
    (tmp_path / "gazebo.world").write_text(sdf_text)
    data = {"name": "gz", "origin": [-2, -2], "size": [12, 12], "robot": {"radius": 0.2, "step": 0.25},
            "goal_tolerance": 0.5, "field": "thesis-general", "sdf": {"file": "gazebo.world"},
            "targets": [[8, 8]], "starts": [[-1, -1]], **overrides}
    path = tmp_path / "w.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_a_world_file_takes_its_obstacles_from_an_sdf_world(tmp_path):
    far = model("far", CYLINDER, "50 50 0.5 0 0 0")                # wholly outside the map: not in this world
    path = write_world(tmp_path, world(model("box", BOX, "3 3 0.5 0 0 0"), model("pillar", CYLINDER, "6 2 0.5 0 0 0"), far),
                       obstacles=[{"circle": {"center": [0, 6], "radius": 0.5}}])
    w = load_world(path)
    assert len(w.obstacles) == 3 and w.frame.offset == (-2.0, -2.0) and w.frame.unit == 0.25
    assert w.size == pytest.approx((48, 48))
    assert [o.name for o in w.obstacles] == [None, "box::link::c", "pillar::link::c"]
    assert w.obstacle_distance((np.array([[6.0, 2.0]]) + 2.0) / 0.25)[0] < 0     # inside the pillar
    again = tmp_path / "again.yaml"
    again.write_text(dump_world_yaml(w))
    back = load_world(again)                                        # saved: the footprints written out, origin kept
    assert len(back.obstacles) == 3 and back.frame.offset == (-2.0, -2.0)


def test_placement_problems_name_the_sdf_collision(tmp_path):
    path = write_world(tmp_path, world(model("pillar", CYLINDER, "6 2 0.5 0 0 0")), starts=[[6, 2.2]])
    with pytest.raises(WorldError, match="starts\\[0\\]: .* inside the SDF world's collision 'pillar::link::c'"):
        load_world(path)


def test_an_sdf_model_across_the_map_edge_is_refused_with_the_way_out(tmp_path):
    path = write_world(tmp_path, world(model("wall", "<box><size>20 0.2 1</size></box>", "0 5 0.5 0 0 0")))
    with pytest.raises(WorldError, match="'wall::link::c' reaches outside the map.*sdf.skip"):
        load_world(path)


def test_bad_sdf_keys_give_one_line_each_and_exit_2(tmp_path, capsys):
    path = write_world(tmp_path, world(model("statue", "<mesh><uri>x.dae</uri></mesh>")),
                       origin=[0, "a"])
    assert main(["eval", path]) == 2
    err = capsys.readouterr().err
    assert "origin[1]: expected a number" in err and "Traceback" not in err
    path = write_world(tmp_path, world(model("statue", "<mesh><uri>x.dae</uri></mesh>")), sdf={"file": "gazebo.world",
                                                                                               "skip": "statue"})
    assert main(["eval", path]) == 2
    assert "sdf.skip: expected a list" in capsys.readouterr().err
    path = write_world(tmp_path, world(model("statue", "<mesh><uri>x.dae</uri></mesh>")))
    assert main(["eval", path]) == 2
    err = capsys.readouterr().err
    assert "sdf: " in err and "gazebo.world: collision 'statue::link::c'" in err and "Traceback" not in err


def test_origin_is_not_for_grids(tmp_path):
    (tmp_path / "m.map").write_text("type octile\nheight 4\nwidth 4\nmap\n....\n....\n....\n....\n")
    path = tmp_path / "g.yaml"
    path.write_text(yaml.safe_dump({"grid": {"movingai": "m.map"}, "origin": [1, 1], "field": "thesis-general",
                                    "targets": [[3, 3]]}))
    with pytest.raises(WorldError, match="origin: a world with a grid takes its origin from the grid"):
        load_world(path)
