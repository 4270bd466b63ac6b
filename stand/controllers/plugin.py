"""``controller.kind = "plugin"``: flight code of the user's, loaded from ``module = "package.module:ClassName"``
(``path`` when it is not installed) and built as ``ClassName(devices, period_s, **options)`` (the plug-in API,
:mod:`stand.adcs`)."""

from __future__ import annotations

from pathlib import Path

from stand.adcs import PluginError, load_plugin
from stand.checks import Table, unusable
from stand.controllers import ControllerKind, not_opened


class PluginKind(ControllerKind):
    name = "plugin"
    keys = ("rate_hz", "budget_s", "module", "path", "options")
    # A plug-in's own columns are not known before it is built: the estimate assumes a pointing-sized set.
    row_floats = 16

    def parse_params(self, t: Table, rate_hz: float, step_s: float, devices, params: dict) -> None:
        params["module"] = t.text("module")
        params["path"] = t.text("path") if t.has("path") else None
        options = t.raw("options", {})
        if not isinstance(options, dict):
            raise t.error("options", options, "a table of keyword arguments for the plug-in's constructor")
        opt = Table(options, t._name("options"), t.source)
        for key, value in options.items():  # opaque to the stand, but they reach flight code: no NaN, no NUL
            if unusable(value):
                raise opt.error(key, value, "finite numbers of normal size (no subnormals) and text without NUL bytes")
        params["options"] = options

    def build(self, scenario, devices: dict, base: Path | None):
        hosts = {name: d.host for name, d in devices.items()}
        return self._construct(scenario, hosts, base)[1]

    def check(self, scenario, base: Path | None) -> None:
        cls, obj = self._construct(scenario, not_opened(scenario), base)
        if not callable(getattr(obj, "update", None)):
            raise PluginError(f"controller.module = {scenario.controller.params['module']!r}: {cls.__name__} has no "
                              "update(t_s) method.")

    @staticmethod
    def _construct(scenario, hosts: dict, base: Path | None):
        ctl = scenario.controller
        p = ctl.params
        period = 1.0 / ctl.rate_hz
        cls = load_plugin(p["module"], p.get("path"), base)
        try:
            return cls, cls(hosts, period, **p["options"])
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # sys.exit() and the like too: one sentence, not a silent exit
            raise PluginError(f"controller.module = {p['module']!r}: constructing {cls.__name__}(devices, "
                              f"{period:g}, **options) failed: {type(exc).__name__}: {exc}.") from None


KIND = PluginKind()
