"""The config layer: dataclasses whose fields carry their meaning, unit and allowed values.

Every configurable stage (training, the IPP trainer, evaluation, dataset specs, sweeps)
declares its settings one way::

    @dataclass
    class TD3BCConfig:
        alpha: float = param(0.001, "weight of the Q-term: lambda = alpha / mean|Q|", ge=0)
        policy_delay: int = param(1, "actor and target update every N critic updates", ge=1)
        alpha_schedule: str = param("linear", "alpha over the run", choices=("constant", "linear"))

and this module derives the rest from those declarations, so each fact is written once:

- :func:`validate` checks every field (type, choices, bounds, finiteness), nested
  dataclasses included, and raises :class:`ConfigError` naming the field;
- :func:`from_mapping` builds a config from a mapping (a TOML file, a JSON record, a
  preset) with the one unknown-key check (with a "did you mean" hint) and the one type
  coercion (``[1, 2]`` for a tuple field, an integer for a float field);
- :func:`add_flags` adds one ``--field-name`` flag per field to an argparse parser, its
  help being the field's meaning, unit, choices and default; :func:`given_flags` reads
  back the flags given;
- :func:`load_toml` and :func:`to_toml` read and write the flat TOML form, and
  :func:`load_preset` reads a preset, which is data (a TOML file), not code.

Nested dataclass fields (a section per algorithm, say) are flattened for flags and TOML:
their fields keep their own names, which must be unique across sections.

argparse and a few lines of TOML writing rather than tyro or draccus: the flag spellings
(``--batch-size``), the parse-time one-line errors of :mod:`aerohrl.errors` and a
``--help`` that loads nothing heavy stay as they are; draccus is only installed with the
``[lerobot]`` extra. This module imports only the standard library.
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import math
import tomllib
import types
import typing
from dataclasses import MISSING, field, fields, is_dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from aerohrl.errors import UserError


class ConfigError(UserError):
    """A config value or key that is not allowed: one line naming the field."""


def param(
    default: Any,
    help: str,
    *,
    unit: str = "",
    choices: Sequence[Any] | None = None,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    flag: bool = True,
) -> Any:
    """A dataclass field with its one-line meaning (``help``), its ``unit``, and what it may
    hold: one of ``choices``, or a number within ``ge``/``gt``/``le``/``lt`` (for a tuple,
    every element). ``flag=False`` keeps it off the command line (a run's identity, say).
    Numbers must be finite unless a bound says otherwise (``le=math.inf``). A dict default
    (a free-form table, e.g. a sweep's overrides) is copied for each instance and has no flag."""
    meta = {
        "help": help,
        "unit": unit,
        "choices": tuple(choices) if choices is not None else None,
        "ge": ge,
        "gt": gt,
        "le": le,
        "lt": lt,
        "flag": flag,
    }
    if isinstance(default, (list, set)):
        raise TypeError("a mutable default: use a tuple")
    if isinstance(default, dict):
        return field(default_factory=lambda: dict(default), metadata={**meta, "flag": False})
    if is_dataclass(default):
        instance: Any = default  # an instance (is_dataclass is also true of a class)
        return field(default_factory=lambda: dataclasses.replace(instance), metadata=meta)
    return field(default=default, metadata=meta)


def section(cls: type, help: str = "") -> Any:
    """A nested dataclass field (a section of settings, e.g. one algorithm's), default-built."""
    return field(default_factory=cls, metadata={"help": help, "section": True})


# ----------------------------------------------------------------------------- introspection


def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _is_section(f: dataclasses.Field, hint: Any) -> bool:
    return bool(f.metadata.get("section")) or (isinstance(hint, type) and is_dataclass(hint))


def _default(f: dataclasses.Field) -> Any:
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return MISSING


def leaves(cls: type) -> list[tuple[tuple[str, ...], dataclasses.Field, Any]]:
    """Every setting of ``cls`` as ``(path, field, type hint)``, nested sections flattened
    in declaration order (``path`` ends in the field's name)."""
    out: list[tuple[tuple[str, ...], dataclasses.Field, Any]] = []
    hints = _hints(cls)
    for f in fields(cls):
        if not f.init:
            continue
        hint = hints[f.name]
        if _is_section(f, hint):
            out += [((f.name, *p), g, h) for p, g, h in leaves(hint)]
        else:
            out.append(((f.name,), f, hint))
    return out


def _flat_names(cls: type) -> dict[str, tuple[str, ...]]:
    names: dict[str, tuple[str, ...]] = {}
    for path, f, _ in leaves(cls):
        if f.name in names:
            raise TypeError(f"{cls.__name__}: setting {f.name!r} is declared twice ({'.'.join(names[f.name])}, {'.'.join(path)})")
        names[f.name] = path
    return names


def _kind(hint: Any, default: Any) -> type:
    """The scalar type of a field: bool, int, float, str, or tuple (of ints or floats)."""
    for t in (bool, int, float, str, tuple, dict):
        if isinstance(default, t) and not (t is int and isinstance(default, bool)):
            return t
    origin = typing.get_origin(hint) or hint
    if origin in (tuple, bool, int, float, str, dict):
        return origin
    return str


def _elem(hint: Any, default: Any) -> type:
    args = [a for a in typing.get_args(hint) if a is not Ellipsis]
    if args and args[0] in (int, float, str):
        return args[0]
    return type(default[0]) if default else int


# ----------------------------------------------------------------------------- validation


def check_value(name: str, value: Any, f: dataclasses.Field) -> None:
    """:class:`ConfigError` if ``value`` breaks field ``f``'s choices or bounds."""
    m = f.metadata
    choices = m.get("choices")
    items = value if isinstance(value, tuple) else (value,)
    if choices is not None:  # for a tuple, each element
        bad = next((v for v in items if v not in choices), None)
        if bad is not None or (not isinstance(value, tuple) and value not in choices):
            got = value if not isinstance(value, tuple) else bad
            raise ConfigError(f"{name} must be one of {', '.join(map(str, choices))}, got {got!r}")
    for v in items:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            continue
        unbounded = m.get("le") == math.inf or m.get("lt") == math.inf
        if isinstance(v, float) and (math.isnan(v) or (math.isinf(v) and not unbounded)):
            raise ConfigError(f"{name} must be a finite number, got {v}")
        for key, ok, word in (
            ("ge", lambda a, b: a >= b, ">="),
            ("gt", lambda a, b: a > b, ">"),
            ("le", lambda a, b: a <= b, "<="),
            ("lt", lambda a, b: a < b, "<"),
        ):
            bound = m.get(key)
            if bound is not None and not ok(v, bound):
                raise ConfigError(
                    f"{name} must be {word} {bound:g}, got {v:g}" + (f" ({value!r})" if isinstance(value, tuple) else "")
                )


def validate(cfg: Any) -> None:
    """Check every field of the dataclass ``cfg`` (nested sections too) against its declaration;
    :class:`ConfigError` (one line, naming the field) on the first value not allowed."""
    hints = _hints(type(cfg))
    for f in fields(cfg):
        value = getattr(cfg, f.name)
        if _is_section(f, hints[f.name]):
            validate(value)
        else:
            check_value(f.name, value, f)


# ----------------------------------------------------------------------------- mappings


def _optional(hint: Any) -> Any:
    """The type inside ``X | None`` (``Optional[X]``), or None when ``hint`` admits no None."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType) and type(None) in typing.get_args(hint):
        inner = [a for a in typing.get_args(hint) if a is not type(None)]
        return inner[0] if len(inner) == 1 else str
    return None


def _coerce(name: str, value: Any, f: dataclasses.Field, hint: Any, where: str, integral_floats: bool = False) -> Any:
    """``value`` as the field's type (an int for a float, a list for a tuple, None where the
    type admits it; with ``integral_floats``, 4.0 for an int, as JSON may write it);
    ConfigError otherwise."""
    default = _default(f)
    inner = _optional(hint)
    if inner is not None:
        if value is None:
            return None
        hint = inner
        if default is None:
            default = MISSING
    kind = _kind(hint, default)

    def bad(what: str) -> ConfigError:
        return ConfigError(f"{where}: {name} must be {what}, got {value!r}")

    if kind is bool:
        if not isinstance(value, bool):
            raise bad("true or false")
        return value
    if kind is dict:
        if not isinstance(value, Mapping):
            raise bad("a table")
        return dict(value)
    if kind is tuple:
        if not isinstance(value, (list, tuple)):
            raise bad("a list")
        elem = _elem(hint, default)
        out = []
        for x in value:
            if elem is str:
                if not isinstance(x, str):
                    raise bad("a list of strings")
            elif isinstance(x, bool) or not isinstance(x, (int, float)) or (elem is int and not isinstance(x, int)):
                raise bad(f"a list of {'integers' if elem is int else 'numbers'}")
            out.append(elem(x))
        return tuple(out)
    if kind is int:
        if integral_floats and isinstance(value, float) and math.isfinite(value) and value.is_integer():
            return int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise bad("an integer")
        return value
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad("a number")
        return float(value)
    if value is None and default is None:
        return None
    if not isinstance(value, str):
        raise bad("a string")
    return value


def unknown_keys(given: Sequence[str], known: Sequence[str], where: str, hint: str = "") -> None:
    """The one unknown-key check: :class:`ConfigError` naming the keys not in ``known``, with
    the closest known names as a hint."""
    unknown = sorted(set(given) - set(known))
    if not unknown:
        return
    near = sorted({m for k in unknown for m in difflib.get_close_matches(k, list(known), n=3)})
    tip = f"did you mean {', '.join(near)}?" if near else (hint or f"known: {', '.join(sorted(known))}")
    raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} ({tip})")


def from_mapping(
    cls: type, values: Mapping[str, Any], *, where: str = "config", base: Any = None, check: bool = True, hint: str = ""
) -> Any:
    """A ``cls`` from ``values`` over ``base`` (default: ``cls()``): flat keys (a nested
    section's settings by their own names) or sub-tables named like the sections. Unknown
    keys and values of the wrong type are :class:`ConfigError`; with ``check`` the result is
    :func:`validate`-d."""
    names = _flat_names(cls)
    sections = {s for path in names.values() for s in path[:-1]}
    flat: dict[str, Any] = {}

    def add(items: Mapping[str, Any]) -> None:
        for k, v in items.items():
            if isinstance(v, Mapping) and k in sections and k not in names:  # a section written as a sub-table
                add(v)
            else:
                flat[k] = v

    add(values)
    unknown_keys(list(flat), list(names), where, hint)
    cfg = base if base is not None else cls()
    by_name = {p[-1]: (p, f, h) for p, f, h in leaves(cls)}
    for k, v in flat.items():
        path, f, h = by_name[k]
        cfg = _replace_at(cfg, path, _coerce(k, v, f, h, where))
    if check:
        validate(cfg)
    return cfg


def from_nested(cls: type, values: Mapping[str, Any], *, where: str = "config", base: Any = None, check: bool = True) -> Any:
    """A ``cls`` from the nested mapping ``values`` (:func:`dataclasses.asdict` output, or TOML
    with one table per section) over ``base`` (default ``cls()``): for configs whose sections
    reuse setting names, which :func:`from_mapping`'s flat keys cannot tell apart. Missing keys
    keep their value; unknown keys and values of the wrong type are :class:`ConfigError`
    naming the key's path; with ``check`` the result is :func:`validate`-d."""
    cfg = _read_nested(cls, values, where, "", base if base is not None else cls())
    if check:
        validate(cfg)
    return cfg


def _read_nested(cls: type, values: Any, where: str, prefix: str, base: Any) -> Any:
    if not isinstance(values, Mapping):
        raise ConfigError(f"{where}: {prefix.rstrip('.') or cls.__name__} must be a table, got {values!r}")
    hints = _hints(cls)
    by_name = {f.name: f for f in fields(cls) if f.init}
    unknown_keys(list(values), list(by_name), f"{where}: {prefix.rstrip('.')}" if prefix else where)
    kw = {}
    for k, v in values.items():
        current = getattr(base, k)
        if is_dataclass(current):
            kw[k] = _read_nested(type(current), v, where, f"{prefix}{k}.", current)
        else:
            kw[k] = _coerce(prefix + k, v, by_name[k], hints[k], where, integral_floats=True)
    return dataclasses.replace(base, **kw)


def _replace_at(cfg: Any, path: tuple[str, ...], value: Any) -> Any:
    if len(path) == 1:
        return dataclasses.replace(cfg, **{path[0]: value})
    return dataclasses.replace(cfg, **{path[0]: _replace_at(getattr(cfg, path[0]), path[1:], value)})


def to_flat_dict(cfg: Any) -> dict[str, Any]:
    """Every setting of ``cfg`` by its own name (sections flattened), tuples as lists: the
    form of config.json records and TOML files."""
    out: dict[str, Any] = {}
    for path, _, _ in leaves(type(cfg)):
        v: Any = cfg
        for p in path:
            v = getattr(v, p)
        out[path[-1]] = list(v) if isinstance(v, tuple) else v
    return out


# ----------------------------------------------------------------------------- TOML


def load_toml(path: str | Path) -> dict[str, Any]:
    """The mapping in a TOML file; :class:`ConfigError` (one line) when it is missing,
    unreadable or not TOML."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"no config file at {path}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read {path}: {getattr(e, 'strerror', None) or e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path} is not valid TOML: {e}") from None


def load_preset(folder: str | Path, name: str) -> dict[str, Any]:
    """The preset ``name`` of ``folder`` (``folder/NAME.toml``, data rather than code);
    :class:`ConfigError` naming the presets there when there is no such file."""
    folder = Path(folder)
    path = folder / f"{name}.toml"
    if not path.is_file():
        known = sorted(p.stem for p in folder.glob("*.toml"))
        raise ConfigError(f"unknown preset {name!r} (choose from {', '.join(known)})")
    return load_toml(path)


def preset_names(folder: str | Path) -> tuple[str, ...]:
    """The presets of ``folder`` (its ``*.toml`` files), sorted."""
    return tuple(sorted(p.stem for p in Path(folder).glob("*.toml")))


def to_toml(cfg: Any, header: str = "") -> str:
    """``cfg``'s settings as a flat TOML document (every field), ``header`` as comment lines."""
    from aerohrl.cli_common import to_toml as flat

    return flat({k: v for k, v in to_flat_dict(cfg).items() if v is not None}, header=header)


# ----------------------------------------------------------------------------- flags


def flag_name(name: str) -> str:
    """A field's flag: ``batch_size`` -> ``--batch-size``."""
    return "--" + name.replace("_", "-")


def describe(f: dataclasses.Field, default: Any, *, default_label: str = "", note: str = "") -> str:
    """A field's help text: meaning, unit, default (and ``note`` beside it, e.g. a preset's
    value for one algorithm); argparse shows the choices."""
    m = f.metadata
    h = m.get("help") or f.name.replace("_", " ")
    unit = f" ({m['unit']})" if m.get("unit") else ""
    if isinstance(default, tuple):
        d = " ".join(map(str, default)) or "none"
    else:
        d = "none" if default is None else str(default)
    if d == "" and not note:  # no default (a path the user gives, say)
        return f"{h}{unit}".replace("%", "%%")
    label = f"{default_label}: " if default_label else ""
    extra = f"; {note}" if note else ""
    return f"{h}{unit} [{label}{d}{extra}]".replace("%", "%%")


def add_flags(
    parser: argparse.ArgumentParser | Any,
    cls: type,
    *,
    skip: Sequence[str] = (),
    defaults: Any = None,
    default_label: str = "",
    notes: Mapping[str, str] | None = None,
) -> None:
    """One flag per setting of ``cls`` (but ``skip`` and fields declared ``flag=False``), all
    defaulting to None so that :func:`given_flags` tells the flags given from the others.
    The help shows the default of ``defaults`` (an instance; default: ``cls()``), labelled
    ``default_label`` (e.g. the preset's name), then ``notes[name]`` if any. A number out of its field's bounds is a
    one-line usage error when the command line is parsed, by the same rule
    (:func:`check_value`) that :func:`validate` applies to a TOML key."""
    ref = defaults if defaults is not None else cls()
    flat = to_flat_dict(ref)
    for _path, f, hint in leaves(cls):
        if f.name in skip or not f.metadata.get("flag", True):
            continue
        default = flat[f.name]
        default = tuple(default) if isinstance(default, list) else default
        kind = _kind(hint, _default(f))
        help_ = describe(f, default, default_label=default_label, note=(notes or {}).get(f.name, ""))
        choices = f.metadata.get("choices")
        if kind is bool:
            parser.add_argument(flag_name(f.name), action=argparse.BooleanOptionalAction, default=None, help=help_)
        elif kind is tuple:
            elem = _elem(hint, _default(f))
            typ = _flag_type(f, elem) if elem in (int, float) else str
            parser.add_argument(
                flag_name(f.name), type=typ, nargs="*", default=None, metavar="N" if typ is not str else "X", help=help_
            )
        elif kind in (int, float):
            parser.add_argument(
                flag_name(f.name),
                type=_flag_type(f, kind),
                default=None,
                choices=choices,
                metavar="N" if choices is None else None,
                help=help_,
            )
        else:
            parser.add_argument(flag_name(f.name), default=None, choices=choices, help=help_)


def _flag_type(f: dataclasses.Field, kind: type) -> Any:
    """The argparse type of a numeric field: parse, then the field's own bounds."""

    def parse(text: str) -> Any:
        try:
            v = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not {'an integer' if kind is int else 'a number'}: {text!r}") from None
        try:
            check_value(f.name, v, f)
        except ConfigError as e:
            raise argparse.ArgumentTypeError(str(e).removeprefix(f"{f.name} ")) from None
        return v

    parse.__name__ = "integer" if kind is int else "number"
    return parse


def given_flags(args: argparse.Namespace, cls: type, *, skip: Sequence[str] = ()) -> dict[str, Any]:
    """The settings of ``cls`` given as flags in ``args`` (tuples for list flags)."""
    out: dict[str, Any] = {}
    for _, f, _ in leaves(cls):
        if f.name in skip or not f.metadata.get("flag", True):
            continue
        v = getattr(args, f.name, None)
        if v is not None:
            out[f.name] = tuple(v) if isinstance(v, list) else v
    return out


__all__ = [
    "ConfigError",
    "param",
    "section",
    "leaves",
    "validate",
    "check_value",
    "unknown_keys",
    "from_mapping",
    "from_nested",
    "to_flat_dict",
    "load_toml",
    "load_preset",
    "preset_names",
    "to_toml",
    "flag_name",
    "describe",
    "add_flags",
    "given_flags",
]
