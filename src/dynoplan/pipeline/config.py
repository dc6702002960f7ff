"""A pipeline run's settings as a TOML file: read by ``dynoplan pipeline --config FILE``,
written to ``OUT/settings.toml`` so that ``--config OUT/settings.toml`` repeats the run.

.. code-block:: toml

    env = "MountainCarContinuous-v0"                  # the task (references, as on
    options = "examples.mountain_car.options:make_options"  # the command line)
    success = "my_task:reached"                       # optional
    demos = 5                                         # PipelineSettings
    seed = 0

    [fit]                                             # FitSettings
    region_components = 2
    region_slack = 1.5

    [control]                                         # ControllerSettings
    horizon = 20
    risk = 0.5

Every key is a field of :class:`~dynoplan.pipeline.PipelineSettings`, of
:class:`~dynoplan.pipeline.FitSettings` (``[fit]``) or of the generic pipeline's part of
:class:`~dynoplan.pipeline.ControllerSettings` (``[control]``), or one of
:data:`TASK_KEYS`; paths and references are read from the current folder, as on the
command line. A key left out keeps its default; ``replan_every = 0`` means "only when
the option stops", ``no_effect_share = 0``, ``loop_share = 0`` and
``stall_progress = 0`` "no such rule". Any mistake (an unknown key, a value of the
wrong kind or out of range) is one :class:`~dynoplan.errors.DynoplanError` naming the
file and the key.
"""

import difflib
import json
import math
import tomllib
import types
import typing
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any

from dynoplan.errors import DynoplanError
from dynoplan.limits import SETTING_BOUNDS
from dynoplan.pipeline.control_settings import ControllerSettings
from dynoplan.pipeline.fit import FitSettings
from dynoplan.pipeline.run_settings import PipelineSettings

TASK_KEYS = ("env", "options", "demonstrator", "demo_dataset", "success", "state_fn",
             "disturbance")
"""Top-level keys that name the task: the Gymnasium id, ``MODULE:FUNCTION`` references
and a dataset folder (``dynoplan pipeline``'s flags of the same names)."""
UNUSED_CONTROL = ("oracle_horizon", "oracle_samples", "risk_level")
"""Controller settings the generic pipeline's controllers do not read (simulator oracles
and safety constraints are the gear's)."""
UNUSED_FIT = ("goal_features", "region_features")
"""Fit settings that name a task's feature maps, which a Gymnasium task has none of."""
UNUSED = {"control": UNUSED_CONTROL, "fit": UNUSED_FIT}
SECTIONS: dict[str, type] = {"": PipelineSettings, "fit": FitSettings,
                             "control": ControllerSettings}

BOUNDS = SETTING_BOUNDS
"""Smallest and largest value of every numeric setting (:data:`dynoplan.limits.SETTING_BOUNDS`,
where the command line's flags read them without importing the pipeline)."""


def setting_keys() -> list[str]:
    """Every settings key, ``section.field`` (``field`` at the top level), in file order."""
    keys = []
    for section, cls in SECTIONS.items():
        for f in fields(cls):
            if f.name in ("fit", "control") or f.name in UNUSED.get(section, ()):
                continue
            keys.append(f"{section}.{f.name}" if section else f.name)
    return keys


def _hints() -> dict[str, Any]:
    out = {}
    for section, cls in SECTIONS.items():
        for name, hint in typing.get_type_hints(cls).items():
            out[f"{section}.{name}" if section else name] = hint
    return out


def read_config(path: Path) -> dict[str, Any]:
    """The settings of a TOML file as ``{key: value}`` (``section.field`` keys, see
    :func:`setting_keys`, and :data:`TASK_KEYS`), values as the file has them.

    Raises:
        DynoplanError: an unreadable or malformed file, an unknown section or key.
    """
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DynoplanError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DynoplanError(f"{path}: cannot read it ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise DynoplanError(f"{path}: not valid TOML ({exc})") from None
    known = set(setting_keys()) | set(TASK_KEYS)
    flat: dict[str, Any] = {}
    for key, value in raw.items():
        if isinstance(value, dict):
            if key not in ("fit", "control"):
                raise DynoplanError(f"{path}: unknown section [{key}] (known: [fit], "
                                    "[control])")
            items = [(f"{key}.{k}", v) for k, v in value.items()]
        else:
            items = [(key, value)]
        for name, v in items:
            if name not in known:
                close = difflib.get_close_matches(name, sorted(known), n=1)
                hint = f"did you mean '{close[0]}'?" if close else \
                    "see dynoplan pipeline --help"
                raise DynoplanError(f"{path}: unknown setting '{name}' ({hint})")
            flat[name] = v
    return flat


def flag(key: str) -> str:
    """The command-line flag of setting ``key``: ``fit.region_slack`` -> ``--region-slack``."""
    return "--" + key.rpartition(".")[2].replace("_", "-")


def pipeline_settings(values: Mapping[str, Any], where: str | None = None
                      ) -> PipelineSettings:
    """:class:`PipelineSettings` from ``{key: value}`` (:func:`setting_keys`; task keys are
    ignored); missing keys keep their defaults.

    Args:
        where: the file the values come from, named in errors; ``None``: the command
            line (errors name the flag).

    Raises:
        DynoplanError: an unknown key, or a value of the wrong kind or out of range.
    """
    hints = _hints()
    parts: dict[str, dict[str, Any]] = {"": {}, "fit": {}, "control": {}}
    for key, value in values.items():
        if key in TASK_KEYS:
            continue
        if key not in setting_keys():
            raise DynoplanError(f"{where or 'the command line'}: unknown setting '{key}'")
        section, _, name = key.rpartition(".")
        shown = f"{where}: {key}" if where is not None else flag(key)
        parts[section][name] = _convert(key, shown, hints[key], value)
    settings = PipelineSettings(**parts[""], fit=FitSettings(**parts["fit"]),
                                control=ControllerSettings(**parts["control"]))
    try:
        settings.validate()
    except DynoplanError as exc:
        raise DynoplanError(f"{where or 'the command line'}: {exc}") from None
    return settings


def _convert(key: str, shown: str, hint: Any, value: Any) -> Any:
    """``value`` as setting ``key`` of type ``hint`` holds it (TOML has no ``None``);
    ``shown`` names it in errors."""
    def bad(expected: str) -> DynoplanError:
        return DynoplanError(f"{shown} must be {expected}, got {value!r}")

    if isinstance(value, str) and key in _LISTS:  # "64,64" from the command line
        value = _numbers(value, bad)
    if key == "control.replan_every":
        return None if _number(key, value, int, bad) == 0 else int(value)
    if key in _ZERO_IS_NONE:  # 0: no such rule
        share = _number(key, value, float, bad)
        return None if share == 0 else share
    if key == "control.hold_action":  # a number, or a list of numbers (a Box action)
        if isinstance(value, list | tuple):
            return tuple(_number(key, v, float, bad) for v in value)
        return value if isinstance(value, int) and not isinstance(value, bool) else \
            _number(key, value, float, bad)
    if key == "controllers":
        names = value.split(",") if isinstance(value, str) else value
        if not isinstance(names, list | tuple) or not names or not all(
                isinstance(n, str) and n for n in names):
            raise bad("a list of controller names")
        return tuple(names)
    args = typing.get_args(hint)
    if isinstance(hint, types.UnionType) and type(None) in args:
        hint = next(a for a in args if a is not type(None))
    if hint is bool:
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise bad("a string")
        return value
    if hint in (int, float):
        return _number(key, value, hint, bad)
    if typing.get_origin(hint) is tuple:  # layer widths
        value = [value] if isinstance(value, int) and not isinstance(value, bool) else value
        if not isinstance(value, list | tuple) or not value:
            raise bad("a list of positive integers")
        return tuple(int(_number(key, v, int, bad, (1, 100_000))) for v in value)
    raise bad(f"a {hint}")  # pragma: no cover - every field's type is handled above


_ZERO_IS_NONE = ("control.no_effect_share", "control.loop_share", "control.stall_progress")
"""Settings whose 0 means "no such rule" (``None``; TOML has no ``None``)."""
_LISTS = ("fit.dynamics_hidden", "control.hold_action")
"""Settings whose value a command line gives as comma-separated numbers."""


def _numbers(text: str, bad: Any) -> Any:
    """``"1,2"`` -> ``[1, 2]``, ``"0.5"`` -> ``0.5`` (integers stay integers)."""
    try:
        out = [int(t) if t.strip().lstrip("+-").isdigit() else float(t)
               for t in text.split(",")]
    except ValueError:
        raise bad("comma-separated numbers") from None
    return out[0] if len(out) == 1 and "," not in text else out


def _number(key: str, value: Any, kind: type, bad: Any,
            bounds: tuple[float, float] | None = None) -> Any:
    if isinstance(value, bool) or not isinstance(value, int | float) or (
            kind is int and not isinstance(value, int)):
        raise bad("an integer" if kind is int else "a number")
    low, high = bounds or BOUNDS.get(key, (-math.inf, math.inf))
    if not low <= value <= high or (isinstance(value, float) and math.isnan(value)):
        raise bad(f"in [{low:g}, {high:g}]")
    return kind(value)


def settings_toml(task: Mapping[str, Any], settings: PipelineSettings) -> str:
    """The TOML text of a run: the task's references (:data:`TASK_KEYS`; ``None`` left
    out) and every setting; :func:`read_config` and :func:`pipeline_settings` read it back
    to the same values."""
    lines = []
    for key in TASK_KEYS:
        if task.get(key) is not None:
            lines.append(f"{key} = {_toml_value(str(task[key]))}")
    current = ""
    for key in setting_keys():
        section, _, name = key.rpartition(".")
        if section != current:
            lines.append(f"\n[{section}]")
            current = section
        owner: Any = getattr(settings, section) if section else settings
        value = getattr(owner, name)
        if key in ("control.replan_every", *_ZERO_IS_NONE) and value is None:
            value = 0
        if value is None:
            lines.append(f"# {name}: not set (the default)")
        else:
            lines.append(f"{name} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("nan" if math.isnan(value)
                                                         else "inf" if value > 0 else "-inf")
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if hasattr(value, "tolist"):  # a numpy hold action
        return _toml_value(value.tolist())
    raise DynoplanError(f"cannot write {value!r} to TOML")


__all__ = ["BOUNDS", "TASK_KEYS", "pipeline_settings", "read_config", "setting_keys",
           "settings_toml"]
