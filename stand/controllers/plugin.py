"""``controller.kind = "plugin"``: flight code of the user's, loaded from ``module = "package.module:ClassName"``
(``path`` when it is not installed) and built as ``ClassName(devices, period_s, **options)`` (the plug-in API,
:mod:`stand.adcs`, docs/plugins.md), with ``spacecraft=`` (:class:`stand.controllers.spacecraft.Spacecraft`) when
the constructor takes that keyword. The columns its ``telemetry_columns()`` declares are checked against the
criteria once it is built (``stand check`` and before ``stand run`` starts): a criterion reading a column nothing
records is refused."""

from __future__ import annotations

import inspect
from pathlib import Path

from stand.adcs import PluginError, load_plugin
from stand.checks import Table, unusable
from stand.controllers import ControllerKind, not_opened
from stand.controllers.spacecraft import spacecraft_of, unwritten, unwritten_text

#: The keyword a plug-in's constructor takes to be handed the spacecraft's description.
SPACECRAFT_KEYWORD = "spacecraft"


class PluginKind(ControllerKind):
    name = "plugin"
    keys = ("rate_hz", "budget_s", "module", "path", "options")
    # A plug-in's own columns are not known before it is built: the estimate assumes a pointing-sized set.
    row_floats = 16
    # Its columns are its telemetry_columns(): checked against the criteria once it is built.
    columns_when_built = True

    def parse_params(self, t: Table, rate_hz: float, step_s: float, devices, params: dict) -> None:
        params["module"] = t.text("module")
        params["path"] = t.text("path") if t.has("path") else None
        options = t.raw("options", {})
        if not isinstance(options, dict):
            raise t.error("options", options, "a table of keyword arguments for the plug-in's constructor")
        opt = Table(options, t._name("options"), t.source)
        for key, value in options.items():  # opaque to the stand, but they reach flight code: no NaN, no NUL
            if key == SPACECRAFT_KEYWORD:
                raise opt.error(key, value, "another name: the stand passes spacecraft= itself, the scenario's "
                                "description (docs/plugins.md), to a constructor that takes it")
            if unusable(value):
                raise opt.error(key, value, "finite numbers of normal size (no subnormals) and text without NUL bytes")
        params["options"] = options

    def build(self, scenario, devices: dict, base: Path | None):
        hosts = {name: d.host for name, d in devices.items()}
        cls, obj = self._construct(scenario, hosts, base)
        self._check_columns(scenario, cls, obj)
        return obj

    def check(self, scenario, base: Path | None) -> None:
        cls, obj = self._construct(scenario, not_opened(scenario), base)
        if not callable(getattr(obj, "update", None)):
            raise PluginError(f"controller.module = {scenario.controller.params['module']!r}: {cls.__name__} has no "
                              "update(t_s) method.")
        self._check_columns(scenario, cls, obj)

    @staticmethod
    def _check_columns(scenario, cls, obj) -> None:
        """Every column a criterion reads is one the plug-in declares (else the criterion could never be computed)."""
        module = scenario.controller.params["module"]
        declare = getattr(obj, "telemetry_columns", None)
        try:
            names = [col[0] for col in declare()] if callable(declare) else []
        except KeyboardInterrupt:
            raise
        except BaseException as exc:
            raise PluginError(f"controller.module = {module!r}: {cls.__name__}.telemetry_columns() failed: "
                              f"{type(exc).__name__}: {exc}.") from None
        problems = unwritten(scenario.criteria, names)
        if problems:
            raise PluginError(f"controller.module = {module!r}: " + unwritten_text(problems, cls.__name__))

    @staticmethod
    def _construct(scenario, hosts: dict, base: Path | None):
        ctl = scenario.controller
        p = ctl.params
        period = 1.0 / ctl.rate_hz
        cls = load_plugin(p["module"], p.get("path"), base)
        extra = {SPACECRAFT_KEYWORD: spacecraft_of(scenario)} if _takes_spacecraft(cls) else {}
        try:
            return cls, cls(hosts, period, **extra, **p["options"])
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # sys.exit() and the like too: one sentence, not a silent exit
            raise PluginError(f"controller.module = {p['module']!r}: constructing {cls.__name__}(devices, "
                              f"{period:g}, **options) failed: {type(exc).__name__}: {exc}.") from None


def _takes_spacecraft(cls) -> bool:
    """Whether the constructor names a ``spacecraft`` parameter (a ``**options`` catch-all does not count: a plug-in
    written before the description existed is built as it always was)."""
    try:
        params = inspect.signature(cls).parameters
    except (TypeError, ValueError):
        return False
    p = params.get(SPACECRAFT_KEYWORD)
    return p is not None and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)


KIND = PluginKind()
