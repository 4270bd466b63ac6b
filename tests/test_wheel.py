"""The installed wheel runs on its own: built from this checkout, installed into a fresh virtual environment
outside it (its dependencies come from the test environment's site-packages, the checkout is not on sys.path),
it runs the default scenario to PASS, renders a star screen and solves it, and checks a scenario by name."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

from tests.oracles import unavailable

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    if not (REPO / "pyproject.toml").exists():
        pytest.skip("needs the source checkout to build the wheel")
    root = tmp_path_factory.mktemp("wheel")
    dist = root / "dist"
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(REPO)],
                           capture_output=True, text=True, timeout=600)
    if build.returncode != 0 and "Could not find a version that satisfies" in build.stderr:
        unavailable("the build backend (setuptools) cannot be fetched from the package index here")
    assert build.returncode == 0, build.stderr
    wheel = next(dist.glob("adcs_stand-*.whl"))
    env_dir = root / "venv"
    # No pip of its own (ensurepip takes 5-15 s): this environment's pip installs into it with --python, the same
    # files a pip inside would write.
    venv.create(env_dir, with_pip=False)
    py = env_dir / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    # The dependencies, not the project: a plain path entry (the test environment's .pth files, among them an
    # editable install of this checkout, are not processed from it).
    (Path(site) / "_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    # Without PYTHONPATH: a checkout on it (with the egg-info a build leaves there) reads as adcs-stand installed.
    subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--no-deps", "--no-index",
                    str(wheel)], check=True, timeout=300, env=_env())
    work = root / "work"
    work.mkdir()
    return env_dir / "bin", work


def _env() -> dict:
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


def _stand(installed, *args, timeout=300):
    bindir, work = installed
    return subprocess.run([str(bindir / "stand"), *args], cwd=work, env=_env(), capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.slow
def test_the_wheel_carries_its_data_and_not_the_checkout(installed):
    bindir, work = installed
    out = subprocess.run([str(bindir / "python"), "-c",
                          "import stand, fixtures, sim, drivers, star_screen; print(stand.__file__); "
                          "print(fixtures.path('scenarios/detumble.toml')); "
                          "print(fixtures.path('catalog/hip2_hp9.npz'))"],
                         cwd=work, env=_env(), capture_output=True, text=True, check=True).stdout.split()
    assert all("site-packages" in p and str(REPO) not in p for p in out)
    # With a C compiler here, the wheel carries every hot path compiled (compiled_paths), its own build.
    active = subprocess.run([str(bindir / "python"), "-c", "import json, compiled_paths, sim.truth; "
                             "print(json.dumps(compiled_paths.active())); print(sim.truth._step.__file__)"],
                            cwd=work, env=_env(), capture_output=True, text=True, check=True).stdout.split("\n")
    if shutil.which("cc") is None:
        pytest.skip("no C compiler here: the wheel carries the plain Python of the compiled paths")
    assert set(json.loads(active[0]).values()) == {"compiled"}, active[0]
    assert "site-packages" in active[1] and str(REPO) not in active[1]


@pytest.mark.slow
def test_the_installed_stand_runs_the_default_scenario_to_pass(installed):
    _, work = installed
    proc = _stand(installed, "run", "--out", "default", "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((work / "default" / "summary.json").read_text())
    assert summary["pass"] and summary["sim_duration_s"] == pytest.approx(5677.0)


@pytest.mark.slow
def test_the_installed_stand_renders_a_screen_and_solves_it(installed):
    _, work = installed
    proc = _stand(installed, "screen", "--ra", "83.8", "--dec", "-5.4", "--roll", "10", "--out", "screen")
    assert proc.returncode == 0, proc.stderr
    raw = work / "screen" / "detector_raw.png"
    proc = _stand(installed, "solve", str(raw))
    assert proc.returncode == 0, proc.stderr
    solved = json.loads(proc.stdout)
    assert solved["valid"] and solved["stars_matched"] >= 10


@pytest.mark.slow
def test_the_installed_stand_checks_and_lists_the_shipped_scenarios(installed):
    proc = _stand(installed, "check", "detumble_star_tracker_image")
    assert proc.returncode == 0 and "star_screen" in proc.stdout, proc.stderr
    proc = _stand(installed, "scenarios")
    assert proc.returncode == 0 and "detumble_external" in proc.stdout
