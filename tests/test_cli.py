"""The command line: help, and errors as one message without a traceback."""

import io

import pytest

from apf_physics.cli import main
from apf_physics.cli.eval import EvalProgress
from apf_physics.experiments.evaluate import evaluate
from apf_physics.planners import make_planner
from apf_physics.world.io.worldfile import world_from_dict
from conftest import simple_world_dict


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
    from apf_physics.models import SHIPPED

    assert main(["eval", str(worlds_dir / "local_minimum.yaml"), "--planner", "dqn",
                 "--model", str(SHIPPED["thesis-fixed"])]) == 2
    assert "trained in another field" in capsys.readouterr().err


def test_plot_curve_from_a_training_log(tmp_path, capsys):
    import cv2

    log = tmp_path / "train.csv"
    log.write_text("global_step,episodes,stage,epsilon,mean_return,success_rate,loss,eval_success,wall_time\n"
                   "100,3,basic,0.9,-5.0,0.1,0.5,0.2,1.0\n200,7,basic,0.8,-2.0,0.4,0.4,,2.0\n"
                   "300,12,line,0.7,1.0,0.6,0.3,0.7,3.0\n")
    out = tmp_path / "curve.png"
    assert main(["plot-curve", str(log), "--out", str(out)]) == 0
    image = cv2.imread(str(out))
    assert image is not None and image.std() > 5
    assert main(["plot-curve", str(tmp_path / "missing.csv"), "--out", str(out)]) == 2
    assert "no such training log" in capsys.readouterr().err


def test_help_texts_are_plain_text_not_markup(capsys):
    """``--help`` of every command reads as prose: no reST roles or double back-quotes."""
    import re
    for name in ("demo", "eval", "train", "generate", "render", "plot-field", "plot-curve", "worlds", "sweep"):
        with pytest.raises(SystemExit):
            main([name, "--help"])
        text = capsys.readouterr().out
        assert "``" not in text and not re.search(r":(class|func|mod|attr):`", text), name


def test_a_long_evaluation_prints_plain_progress_lines_without_a_terminal():
    """Under nohup, CI or a notebook: one plain line per tenth of the worlds, no carriage return."""
    simple_world = world_from_dict(simple_world_dict())
    stream = io.StringIO()
    worlds = [simple_world] * 20
    progress = EvalProgress("gradient", len(worlds), 2 * len(worlds), stream=stream, quiet=0.0)
    evaluation = evaluate(make_planner("gradient"), worlds, progress=progress)
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue() and len(lines) == 10
    successes = sum(e.success for e in evaluation.episodes)
    assert lines[-1].startswith(f"eval: gradient: world 20/20, episodes 40/40, success {successes / 40:.1%}, ")
    quiet = io.StringIO()   # a short evaluation prints nothing
    evaluate(make_planner("gradient"), worlds, progress=EvalProgress("gradient", 20, 40, stream=quiet))
    assert quiet.getvalue() == ""
