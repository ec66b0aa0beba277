"""The command line: help, and errors as one message without a traceback."""

from apf_physics.cli import main


def test_help_lists_the_commands(capsys):
    assert main([]) == 2
    out = capsys.readouterr().out
    for name in ("demo", "eval", "train", "generate", "render", "plot-field"):
        assert name in out


def test_missing_curriculum_file(tmp_path, capsys):
    assert main(["train", "--curriculum", str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "nope.yaml" in err and "Traceback" not in err


def test_unknown_planner(worlds_dir, capsys):
    assert main(["eval", str(worlds_dir / "local_minimum.yaml"), "--planner", "magic"]) == 2
    assert "unknown planner 'magic'" in capsys.readouterr().err


def test_model_for_another_field_is_refused(worlds_dir, capsys):
    from apf_physics.planners.dqn import SHIPPED

    assert main(["eval", str(worlds_dir / "local_minimum.yaml"), "--planner", "dqn",
                 "--model", str(SHIPPED["thesis-fixed"])]) == 2
    assert "trained in another field" in capsys.readouterr().err
