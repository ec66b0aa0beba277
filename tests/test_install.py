"""Install anywhere: build the wheel, install it into a fresh venv, run the demo from an empty folder."""

from __future__ import annotations

import importlib.metadata
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
# What the wheel is built from (a copy, so that the build leaves nothing in the working tree).
SOURCES = ("pyproject.toml", "README.md", "LICENSE", "apf_physics", "worlds")


def _version(name: str) -> tuple[int, ...]:
    try:
        return tuple(int(part) for part in importlib.metadata.version(name).split(".")[:2])
    except (importlib.metadata.PackageNotFoundError, ValueError):
        return (0,)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    # Built without build isolation, from this environment's setuptools: nothing is downloaded.
    if _version("setuptools") < (77,) or _version("pip") < (22, 3):
        pytest.skip("cannot build the wheel here: needs setuptools >= 77 and pip >= 22.3 in this environment")
    source = tmp_path_factory.mktemp("source")
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(ROOT / name, source / name)
    out = tmp_path_factory.mktemp("wheels")
    result = subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation",
                             "--no-index", "-q", "-w", str(out)], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    (built,) = out.glob("apf_physics-*.whl")
    return built


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    """A fresh venv with the wheel installed; its dependencies come from this environment
    through a .pth file (no download). Returns the venv's bin folder."""
    venv = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    ours = dict.fromkeys([sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]])
    (site / "zz_dependencies.pth").write_text("".join(f"{path}\n" for path in ours), encoding="utf-8")
    result = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps",
                             "--no-index", "-q", str(wheel)], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    return venv / "bin"


def run_in_empty_folder(folder: Path, *command: str) -> subprocess.CompletedProcess:
    folder.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    return subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True, timeout=900)


@pytest.mark.slow
def test_wheel_ships_worlds_models_license_and_typing_marker(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    worlds = {p.relative_to(ROOT / "worlds").as_posix() for p in (ROOT / "worlds").rglob("*.yaml")}
    assert {f"apf_physics/worlds/{name}" for name in worlds} <= names
    assert {"apf_physics/worlds/fixed20.yaml", "apf_physics/worlds/thesis/test1.yaml",
            "apf_physics/worlds/curricula/thesis.yaml", "apf_physics/py.typed",
            "apf_physics/models/fixed20.pt", "apf_physics/models/general.pt"} <= names
    assert any(name.endswith(".dist-info/licenses/LICENSE") for name in names)


@pytest.mark.slow
def test_installed_wheel_runs_the_demo_from_an_empty_folder(installed, tmp_path):
    where = run_in_empty_folder(tmp_path / "probe", str(installed / "python"), "-c",
                                "import apf_physics, apf_physics.world.bundled as b; print(apf_physics.__file__); "
                                "print(b.bundled_dir())")
    assert where.returncode == 0, where.stderr
    module, bundled = where.stdout.split()
    venv = installed.parent
    assert Path(module).is_relative_to(venv) and Path(bundled).is_relative_to(venv)   # not the checkout

    listing = run_in_empty_folder(tmp_path / "list", str(installed / "apf-physics"), "worlds")
    assert listing.returncode == 0, listing.stderr
    assert "fixed20" in listing.stdout and "thesis/test1" in listing.stdout

    demo = run_in_empty_folder(tmp_path / "demo", str(installed / "apf-physics"), "demo", "--no-progress")
    assert demo.returncode == 0, demo.stderr[-3000:]
    assert "fixed20" in demo.stdout
    assert not any(word in demo.stderr for word in ("OpenCV", "FFMPEG", "x264", "libav")), demo.stderr
    out = tmp_path / "demo" / "apf-demo"
    assert (out / "index.html").is_file() and (out / "summary.json").is_file()
    assert (out / "fixed20_formation.mp4").stat().st_size > 10_000
