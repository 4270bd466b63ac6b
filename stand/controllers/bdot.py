"""``controller.kind = "bdot"``: the reference B-dot detumbling (:class:`stand.adcs.BDot`) on one magnetorquer
board, through its host driver."""

from __future__ import annotations

import functools
from pathlib import Path

from drivers.magnetorquer.codec import MagnetorquerCodec
from stand import devices as kinds
from stand.adcs import BDot
from stand.checks import Table
from stand.controllers import ControllerKind


@functools.cache
def max_command_s() -> float:
    """The longest coil on-time one dipole command carries, s: the range of its duration field in the board's ICD
    (the DBC takes milliseconds to parse: read once)."""
    return MagnetorquerCodec().dbc.signal_range("MTQ_DIPOLE_CMD", "duration_ms")[1] * 1e-3


def _field_sensor(t: Table, devices, board: str) -> str | None:
    """``magnetometer``: the device B-dot reads the field from, any device whose kind senses the magnetic field
    (None: the board's own magnetometer)."""
    if not t.has("magnetometer"):
        return None
    sensing = [d for d in devices if "magnetic_field" in kinds.get(d.kind).senses and d.name != board]
    names = [d.name for d in sensing]
    if not names:
        raise t.error("magnetometer", t.raw("magnetometer", None), "the name of a device that senses the magnetic "
                      "field; this scenario has none besides the board (leave it out to read the board's)")
    name = t.choice("magnetometer", names, names[0])
    if sensing[names.index(name)].link == "served":
        raise t.error("magnetometer", name, "a magnetometer the stand's B-dot can read: this one is served to a "
                      "flight computer outside (link = 'served')")
    return name


class BDotKind(ControllerKind):
    name = "bdot"
    keys = ("rate_hz", "budget_s", "device", "magnetometer", "gain_A_m2_s_per_T", "max_dipole_A_m2",
            "skip_coil_active", "duty_cycle")
    row_floats = 3  # the commanded dipole
    column_meanings = {"dipole_cmd_B": "the dipole the B-dot law commanded (held until the next command), body axes"}

    def parse_params(self, t: Table, rate_hz: float, step_s: float, devices, params: dict) -> None:
        boards = [d for d in devices if d.kind == "magnetorquer"]
        if not boards:
            raise t.error("kind", "bdot", "a controller that has its devices: B-dot needs a [[devices]] entry "
                          "of kind 'magnetorquer'")
        names = [d.name for d in boards]
        params["device"] = t.choice("device", names, names[0])
        board = boards[names.index(params["device"])]
        if board.link == "served":
            raise t.error("device", board.name, "a board the stand's B-dot can command: this one is served to a "
                          "flight computer outside (link = 'served'); use controller.kind = 'external' or another "
                          "link")
        params["magnetometer"] = _field_sensor(t, devices, board.name)
        params["gain_A_m2_s_per_T"] = t.number("gain_A_m2_s_per_T", lo=0.0, lo_open=True, hi=1e12)
        # A command the board cannot carry would abort the run at its first saturation.
        params["max_dipole_A_m2"] = t.number("max_dipole_A_m2", lo=0.0, lo_open=True, hi=board.max_dipole_A_m2)
        params["skip_coil_active"] = t.flag("skip_coil_active", True)
        # Coils on for this fraction of the control period; the on-time must be whole dynamics steps so the
        # zero-order hold switches exactly on a step boundary, and it must fit the command's duration field.
        duty = t.number("duty_cycle", 1.0, lo=0.0, lo_open=True, hi=1.0)
        on_steps = duty / (rate_hz * step_s)
        if abs(on_steps - round(on_steps)) > 1e-9 * on_steps:
            raise t.error("duty_cycle", duty, f"a fraction whose on-time is whole dynamics steps of {step_s:g} s "
                          f"(the control period is {1.0 / rate_hz:g} s)")
        max_on_s = max_command_s()
        if duty / rate_hz > max_on_s:
            raise t.error("rate_hz", rate_hz, f"a control rate whose on-time (duty_cycle / rate_hz = "
                          f"{duty / rate_hz:g} s) fits the command's duration field (at most {max_on_s:g} s), "
                          f"i.e. rate_hz >= {duty / max_on_s:.6g}")
        params["duty_cycle"] = duty

    def build(self, scenario, devices: dict, base: Path | None):
        p = scenario.controller.params
        board = next(d for d in scenario.devices if d.name == p["device"])
        sensor = next((d for d in scenario.devices if d.name == p.get("magnetometer")), board)
        return BDot(devices[board.name].host, 1.0 / scenario.controller.rate_hz, p["gain_A_m2_s_per_T"],
                    p["max_dipole_A_m2"], q_SB=sensor.q_SB, skip_coil_active=p["skip_coil_active"],
                    duty_cycle=p.get("duty_cycle", 1.0),
                    sensor=None if sensor is board else devices[sensor.name].host)


KIND = BDotKind()
