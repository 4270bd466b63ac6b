"""A device kind from a package of its own, found through the entry point ``adcs_stand.devices`` with not a line of
the stand changed: the GNSS receiver in ``tests/data/oot_gnss`` (the example of ``docs/adding_a_device_kind.md``).

The package is built into a wheel and installed with pip into a temporary virtual environment that sees this
checkout and its dependencies (a ``.pth`` file adds this interpreter's site directories), never into the project's
own environment. In that environment ``stand run`` runs a scenario with the receiver emulated, and ``stand emulate
gnss`` serves it, fed by the same scenario's truth, to a flight program in another process that reads its fixes
with the package's host driver over a socat pty pair. The fixes are checked against the truth's telemetry and
against closed forms: the radius of a circular orbit under point-mass gravity, and the GPS week and time of week of
the scenario's epoch."""

from __future__ import annotations

import base64
import hashlib
import importlib.metadata
import importlib.util
import json
import math
import os
import select
import site
import subprocess
import tomllib
import venv
import zipfile
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from stand import telemetry
from tests.stand.processes import REPO, stand_env

PACKAGE = REPO / "tests" / "data" / "oot_gnss"
GUIDE = REPO / "docs" / "adding_a_device_kind.md"
SCENARIO = PACKAGE / "scenarios" / "gnss_orbit.toml"
GROUP = "adcs_stand.devices"
R_EARTH_M = 6378137.0  # WGS-84 equatorial radius, which the stand's altitude_km is measured from
MU_EARTH_M3_S2 = 3.986004418e14
ALTITUDE_M = 500e3  # the scenario's [orbit]
SIGMA_R_M, SIGMA_V_M_S = 5.0, 0.05  # the scenario's position_noise_m, velocity_noise_m_s
#: The fix's length error is a 3-D Gaussian of SIGMA per axis: beyond 6 SIGMA with a probability below 1e-7.
BOUND_R_M = 6 * SIGMA_R_M
GPS_UTC_S = 18  # leap seconds between GPS time and UTC since 2017-01-01 (none announced since)
WEEK_S = 604800


def gps_seconds_of(utc: datetime) -> float:
    """GPS seconds since 1980-01-06 of a UTC instant after 2017-01-01 (closed form, independent of the stand)."""
    return (utc - datetime(1980, 1, 6)).total_seconds() + GPS_UTC_S


EPOCH_GPS_S = gps_seconds_of(datetime(2026, 3, 20, 12, 0, 0))  # the scenario's epoch


def build_wheel(project: Path, out: Path) -> Path:
    """A pure-Python wheel of ``project`` made with the standard library (name, version and entry points from its
    pyproject.toml, the files of its packages), so installing it needs neither network nor setuptools' ``wheel``."""
    meta = tomllib.loads((project / "pyproject.toml").read_text())
    proj = meta["project"]
    dist = proj["name"].replace("-", "_")
    info = f"{dist}-{proj['version']}.dist-info"
    files: dict[str, bytes] = {}
    for package in meta["tool"]["setuptools"]["packages"]:
        for path in sorted((project / package).rglob("*")):
            if path.is_file() and "__pycache__" not in path.parts:
                files[path.relative_to(project).as_posix()] = path.read_bytes()
    entry = "".join(f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in eps.items()) + "\n"
                    for group, eps in proj["entry-points"].items())
    files[f"{info}/METADATA"] = f"Metadata-Version: 2.1\nName: {proj['name']}\nVersion: {proj['version']}\n".encode()
    files[f"{info}/WHEEL"] = (b"Wheel-Version: 1.0\nGenerator: tests.stand.test_out_of_tree_kind\n"
                              b"Root-Is-Purelib: true\nTag: py3-none-any\n")
    files[f"{info}/entry_points.txt"] = entry.encode()

    def digest(data: bytes) -> str:
        return base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()

    record = "".join(f"{name},sha256={digest(data)},{len(data)}\n" for name, data in files.items())
    files[f"{info}/RECORD"] = (record + f"{info}/RECORD,,\n").encode()
    wheel = out / f"{dist}-{proj['version']}-py3-none-any.whl"
    with zipfile.ZipFile(wheel, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(name, data)
    return wheel


def project_has_gnss() -> list[str]:
    """What of the package this (the project's) environment can see: it must stay empty."""
    seen = [f"entry point {ep.name}" for ep in importlib.metadata.entry_points(group=GROUP) if ep.name == "gnss"]
    seen += ["module stand_gnss"] if importlib.util.find_spec("stand_gnss") is not None else []
    seen += [f"distribution {d.metadata['Name']}" for d in importlib.metadata.distributions()
             if (d.metadata["Name"] or "").lower() == "stand-gnss"]
    return seen


@pytest.fixture(scope="module")
def gnss_python(tmp_path_factory):
    """The python of a temporary environment with the package installed; checks the project's stays clean."""
    assert project_has_gnss() == [], "the project's own environment already holds the example package"
    root = tmp_path_factory.mktemp("oot_gnss")
    env_dir = root / "env"
    venv.EnvBuilder(system_site_packages=True, with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    purelib = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                             capture_output=True, text=True, timeout=30, check=True).stdout.strip()
    # this interpreter's site directories (the stand's dependencies, pip), after the environment's own
    dirs = [*site.getsitepackages(), *([site.getusersitepackages()] if site.ENABLE_USER_SITE else [])]
    lines = "; ".join(f"site.addsitedir({d!r})" for d in dirs if Path(d).is_dir())
    Path(purelib, "_adcs_stand_parent.pth").write_text(f"import site; {lines}\n")
    wheel = build_wheel(PACKAGE, root)
    pip_env = {**os.environ, "PIP_NO_INDEX": "1", "PIP_NO_CACHE_DIR": "1", "PIP_DISABLE_PIP_VERSION_CHECK": "1",
               "PIP_CONSTRAINT": ""}
    done = subprocess.run([str(python), "-m", "pip", "install", "--no-deps", "--no-build-isolation", str(wheel)],
                          capture_output=True, text=True, timeout=120, env=pip_env, cwd=root)
    assert done.returncode == 0, done.stdout + done.stderr
    assert Path(purelib, "stand_gnss", "icd.toml").is_file(), "pip installed the package outside the environment"
    seen = in_env(python, "-c", "import importlib.metadata as m, stand_gnss; print(stand_gnss.__file__); "
                  f"print(*[e.value for e in m.entry_points(group={GROUP!r}) if e.name == 'gnss'])", cwd=root)
    assert seen.stdout.split() == [str(Path(purelib, "stand_gnss", "__init__.py")), "stand_gnss.kind:KIND"], seen
    yield python
    assert project_has_gnss() == [], "installing into the temporary environment reached the project's own"


def in_env(python: Path, *args: str, cwd: Path, timeout_s: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run([str(python), *args], cwd=cwd, env=stand_env(), capture_output=True, text=True,
                          timeout=timeout_s)


def check_fix_time(week, tow_s, t_fix_s, t_s):
    """A fix's GPS time is the scenario epoch's (closed form) plus its sim time, which is the row's own."""
    assert t_fix_s == pytest.approx(t_s, abs=1e-6)
    assert week * WEEK_S + tow_s == pytest.approx(EPOCH_GPS_S + t_s, abs=1e-6)


def test_a_scenario_runs_with_the_installed_kind_emulated_and_its_fixes_follow_the_truth(gnss_python, tmp_path):
    out = tmp_path / "run"
    done = in_env(gnss_python, "-m", "stand.cli", "run", str(SCENARIO), "--out", str(out), "--no-progress",
                  "--no-plots", cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["pass"] and summary["status"] == "completed", summary
    assert {c["name"]: c["pass"] for c in summary["criteria"]} == {"fixes on the truth": True,
                                                                 "no rejected frames": True}
    host = summary["device_counters"]["gps"]["host_counters"]
    assert host["fixes"] == 61 and host["fixes_lost"] == 0 and host["rejected_crc"] == 0  # 1 Hz, t = 0..60 s

    tel = telemetry.load(out)
    assert {"gps.r_N", "gps.v_N", "gps.gps_week", "gps.tow_s", "gps.t_fix_s", "gps.valid"} <= set(tel)
    at_fix = np.isclose(tel["gps.t_fix_s"], tel["t_s"], rtol=0, atol=1e-6)
    assert at_fix.sum() == 61  # one row at each fix's own time (rows at 10 Hz, fixes at 1 Hz)
    r_fix, r_true = tel["gps.r_N"][at_fix], tel["r_BN_N"][at_fix]
    v_fix, v_true = tel["gps.v_N"][at_fix], tel["v_BN_N"][at_fix]
    assert np.all(tel["gps.valid"][at_fix] == 1.0)
    for week, tow, t_fix, t in zip(tel["gps.gps_week"][at_fix], tel["gps.tow_s"][at_fix], tel["gps.t_fix_s"][at_fix],
                                   tel["t_s"][at_fix], strict=True):
        check_fix_time(int(week), float(tow), float(t_fix), float(t))
    # the truth: a circular orbit under point-mass gravity keeps its radius (to the integrator's error, < 1 m here)
    radius_m = R_EARTH_M + ALTITUDE_M
    assert np.abs(np.linalg.norm(r_true, axis=1) - radius_m).max() < 1.0
    assert np.abs(np.linalg.norm(v_true, axis=1) - math.sqrt(MU_EARTH_M3_S2 / radius_m)).max() < 1e-3
    # the fixes: the truth plus noise of the stated sigma (not zero, not more)
    err_r, err_v = r_fix - r_true, v_fix - v_true
    assert np.linalg.norm(err_r, axis=1).max() < BOUND_R_M
    assert np.abs(np.linalg.norm(r_fix, axis=1) - radius_m).max() < BOUND_R_M
    assert np.linalg.norm(err_v, axis=1).max() < 6 * SIGMA_V_M_S
    # 183 samples per quantity: the sample sigma lies within 30 % of the stated one (about 6 standard errors)
    assert 0.7 * SIGMA_R_M < err_r.std() < 1.3 * SIGMA_R_M, err_r.std()
    assert 0.7 * SIGMA_V_M_S < err_v.std() < 1.3 * SIGMA_V_M_S, err_v.std()


FLIGHT_PROGRAM = """
import json, sys, time
from stand_gnss.host import GnssHost

fixes, deadline = [], time.monotonic() + 40.0
with GnssHost(sys.argv[1], name="fc gnss") as gnss:
    print("ready", flush=True)
    last = None
    while time.monotonic() < deadline and (last is None or time.monotonic() - last < 3.0):  # till fixes stop 3 s
        fix = gnss.take_fix()
        if fix is None:
            time.sleep(0.01)
            continue
        last = time.monotonic()
        if not fixes:
            gnss.set_output_period(0.5)  # a command the served receiver must apply
        fixes.append({"r": fix.r_N_m, "week": fix.gps_week, "tow": fix.tow_s, "valid": fix.valid})
    print(json.dumps({"fixes": fixes, "counters": gnss.counters}), flush=True)
"""


def test_stand_emulate_serves_the_installed_kind_to_a_flight_program_in_another_process(gnss_python, pty_pair,
                                                                                          tmp_path):
    stand_end, fc_end = pty_pair
    out = tmp_path / "served"
    fc = subprocess.Popen([str(gnss_python), "-c", FLIGHT_PROGRAM, fc_end], cwd=tmp_path, env=stand_env(),
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([fc.stdout], [], [], 30.0)  # bounded: the program prints once its port is open
        assert ready and fc.stdout.readline().strip() == "ready", fc.stderr.read() if fc.poll() is not None else ""
        done = in_env(gnss_python, "-m", "stand.cli", "emulate", "gnss", "--port", stand_end, "--scenario",
                      str(SCENARIO), "--name", "gps", "--speed", "4", "--duration", "8", "--out", str(out),
                      cwd=tmp_path)
        fc_out, fc_err = fc.communicate(timeout=30)
    finally:
        if fc.poll() is None:
            fc.kill()
            fc.communicate()
    assert done.returncode == 0, done.stdout + done.stderr
    assert "stand emulate: gnss 'gps' of scenario gnss_orbit, served on" in done.stdout
    assert fc.returncode == 0, fc_err
    got = json.loads(fc_out.strip().splitlines()[-1])
    summary = json.loads((out / "summary.json").read_text())
    emulator = summary["device_counters"]["gps"]["emulator_counters"]
    assert emulator["commands_applied"] == 1 and summary["device_counters"]["gps"]["rejected_frames"] == 0
    assert "host_counters" not in summary["device_counters"]["gps"]  # the flight program has the host, not the stand
    # 1 Hz until the command (sent at the first fix), then 2 Hz, over 8 s: 16 fixes when the command takes a tick
    assert got["counters"]["fixes"] == emulator["fixes"] >= 10 and got["counters"]["rejected_crc"] == 0

    tel = telemetry.load(out)
    rows = {round(t * 1000): k for k, t in enumerate(tel["t_s"])}  # every tick is recorded (10 Hz)
    for fix in got["fixes"]:
        t = fix["week"] * WEEK_S + fix["tow"] - EPOCH_GPS_S  # the fix's sim time, from its GPS time (closed form)
        k = rows[round(t * 1000)]
        check_fix_time(fix["week"], fix["tow"], float(tel["gps.t_fix_s"][k]), float(tel["t_s"][k]))
        assert fix["valid"] and np.linalg.norm(np.array(fix["r"]) - tel["r_BN_N"][k]) < BOUND_R_M
    periods = np.diff([f["week"] * WEEK_S + f["tow"] for f in got["fixes"]])
    # 1 s between fixes until SET_OUTPUT_PERIOD (sent at the first fix) is applied, 0.5 s from one period after it;
    # how soon it is applied depends on the machine's load, the periods at the end do not
    assert np.all((periods > 0.5 - 1e-6) & (periods < 1.5 + 1e-6)), periods
    assert periods[-3:] == pytest.approx([0.5] * 3, abs=1e-6) and periods[0] > 0.5 + 1e-6, periods


def test_a_bad_option_of_the_installed_kind_is_one_sentence_and_exit_2(gnss_python, tmp_path):
    done = in_env(gnss_python, "-m", "stand.cli", "emulate", "gnss", "--port", "loop://", "--position-m", "1,2",
                  cwd=tmp_path, timeout_s=60)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "--position-m '1,2' is not allowed; give 3 numbers" in done.stderr and "Traceback" not in done.stderr


def test_the_guides_loopback_test_runs_where_the_package_is_installed(gnss_python, tmp_path):
    """The loopback block of docs/adding_a_device_kind.md (its section "Testing"), as a reader would copy it."""
    text = GUIDE.read_text(encoding="utf-8")
    blocks = [b.split("```", 1)[0] for b in text.split("```python\n")[1:]]
    (loopback,) = [b for b in blocks if "pipe_pair" in b]
    done = in_env(gnss_python, "-c", loopback + "print('loopback ok')\n", cwd=tmp_path, timeout_s=60)
    assert done.returncode == 0 and done.stdout.strip() == "loopback ok", done.stdout + done.stderr
