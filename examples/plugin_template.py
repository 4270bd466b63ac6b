"""A flight-software plug-in template: copy this file, rename the class, put your ADCS code in ``update``.

Use it from a scenario::

    [controller]
    kind = "plugin"
    rate_hz = 10.0
    module = "plugin_template:MyAdcs"    # package.module:ClassName
    path = "../examples"                 # the folder holding it, relative to the scenario file
    options = { gain = 2.0 }             # keyword arguments of the constructor

or from an installed package of your own (then leave ``path`` out). ``stand check SCENARIO`` imports and
constructs the class (over devices that are not opened) and says in one sentence what is wrong.

What the stand guarantees:

* ``devices`` maps every scenario device name to its host driver, whatever the link (emulated, hardware): the
  same classes a flight program uses against real devices. Served devices (for a flight computer outside) map to
  None. Stable methods: magnetorquer ``take_sample()`` (``.b_T`` sensor axes, ``.valid``, ``.coil_active``) and
  ``command_dipole(m_A_m2, duration_s)``; star tracker ``take_solution()`` (``.q_TN`` tracker frame in GCRS,
  ``.valid``, ``.time_us``); sun sensor ``take_sun()`` (``.currents_A`` or ``.angles_rad``, ``.valid``).
  ``take_*`` return the newest reading once, or None when nothing new arrived. Every method of every kind, with
  signs and units: docs/plugins.md.
* A constructor that names a ``spacecraft`` parameter also gets the scenario's description of the spacecraft and
  its devices (mass properties, mounts, wheel axes, ratings: ``stand.controllers.spacecraft.Spacecraft``); a
  pointing plug-in built on it: ``examples/pointing_template.py``.
* ``update(t_s)`` is called once per control period (``period_s``) with sim time.
* ``telemetry_columns()`` / ``telemetry()``: columns of your own, recorded with every telemetry row
  (read them back with ``stand.telemetry.load(run_dir)["fsw.mode"]``).
* An exception in ``update`` ends the run "aborted" (exit code 3) with your traceback in ``events.jsonl``; the
  summary, telemetry and plots written so far are kept.
"""

from __future__ import annotations


class MyAdcs:
    def __init__(self, devices, period_s, gain=1.0):
        self.period_s = period_s
        self.gain = gain
        # Keep the drivers you need; a missing name is a KeyError here, which `stand check` reports.
        self.board = devices["mtq"]
        self.mode = 0.0
        self.last_b_T = (0.0, 0.0, 0.0)

    def telemetry_columns(self):
        return [("fsw.mode", 1, "1"), ("fsw.b_S", 3, "T")]

    def telemetry(self):
        return (self.mode, *self.last_b_T)

    def update(self, t_s):
        sample = self.board.take_sample()
        if sample is None or not sample.valid:
            return
        self.last_b_T = sample.b_T
        # Your control law here; this template commands nothing (zero dipole for one period).
        self.board.command_dipole((0.0, 0.0, 0.0), self.period_s)

    def close(self):
        """Called once at the end of the run (optional)."""
