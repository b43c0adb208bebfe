"""The one settings mechanism of nmsid: pydantic v2 models, TOML loading, one-line errors.

Every settings file kind (protocol, hardware, identification, study, GUI script) declares
its keys as a frozen pydantic dataclass built with :data:`SETTINGS_CONFIG`: typed fields
with units in their names, bounds next to the fields (:func:`bounded`, which carries the
reason of each bound), cross-field rules as ``model_validator`` methods raising
:class:`SettingProblem`, and unknown keys refused (``extra="forbid"``). :func:`validate_settings`
turns pydantic's ``ValidationError`` into the package's own exception, one line naming the
file, the dotted key, the value and what is valid (``docs/settings.md``).
"""

from __future__ import annotations

import dataclasses
import functools
import os
import re
import types
import typing
from collections.abc import Callable, Mapping
from typing import Any

from pydantic import ConfigDict, Field, TypeAdapter, ValidationError
from pydantic.dataclasses import dataclass as pydantic_dataclass

from nmsid.errors import InputFileMissing

SETTINGS_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False, validate_default=False,
                             hide_input_in_errors=True)
"""Model configuration shared by every settings model: unknown keys refused, NaN/inf
refused, pydantic's own input echo left out (the message shows the value itself)."""

MAX_TOML_BYTES = 1_000_000
"""A settings file is a few kB; a bigger one is not a settings file (refused unread)."""

ErrorFactory = Callable[[str, str, Any, str], Exception]
"""``make_error(source, key, value, valid)`` -> the package's ConfigError-style exception."""


class SettingProblem(ValueError):
    """Raised inside a ``model_validator`` to refuse one key of the model.

    Parameters
    ----------
    key : str
        The key relative to the model that validates (``chirp_f1_Hz``,
        ``manual.Iemax_mA``).
    value : object
        The refused value.
    valid : str
        What would be valid, and why.
    """

    def __init__(self, key: str, value, valid: str):
        self.key, self.value, self.valid = key, value, valid
        super().__init__(f"{key} = {value!r}: {valid}")


IN_CODE = "(in code)"
"""The source named for settings built in Python rather than read from a file."""


def bounded(default=dataclasses.MISSING, *, why: str, **bounds):
    """A field with bounds (``ge``, ``gt``, ``le``, ``lt``, ``max_length``) and the reason.

    The reason is stored as the field's description and appended to the message of a
    value outside the bounds, so a refusal says the limit and why it is there.
    """
    if default is dataclasses.MISSING:
        return Field(description=why, **bounds)
    return Field(default, description=why, **bounds)


# dataclass_transform: type checkers see the keyword constructor and dataclasses.replace;
# no field_specifiers, so `bounded(...)` / `Field(...)` count as defaults (a missing
# required key is refused by pydantic at run time, in one line)
@typing.dataclass_transform(frozen_default=True)
def settings_dataclass(make_error: ErrorFactory, *, frozen: bool = True, prefix: str = ""):
    """Declare a settings class: a pydantic dataclass with :data:`SETTINGS_CONFIG`.

    Built in code (``ProtocolConfig(fs_Hz=-1)``, ``dataclasses.replace``), a bad value
    raises ``make_error(IN_CODE, key, value, valid)`` instead of pydantic's
    ``ValidationError``, so every settings object fails the same way a file does.

    Parameters
    ----------
    make_error : callable
        The package's ConfigError-style factory ``(source, key, value, valid)``.
    frozen : bool
        Instances are immutable (as every settings object but a study's).
    prefix : str
        Dotted table name put before keys in messages (``"protocol"``).
    """
    def wrap(cls):
        model = pydantic_dataclass(frozen=frozen, config=SETTINGS_CONFIG)(cls)
        init = model.__init__

        @functools.wraps(init)
        def __init__(self, *args, **kwargs):
            try:
                init(self, *args, **kwargs)
            except ValidationError as exc:
                raise convert_error(exc, kwargs, IN_CODE, make_error, model, prefix) from None

        model.__init__ = __init__  # type: ignore[method-assign]  # (the validated one, wrapped)
        return model
    return wrap


def reason_of(cls, key: str) -> str:
    """The ``why`` of a field given by a dotted key below ``cls`` ('' if none)."""
    info = _field_info(cls, key.split("."))
    return (info.description or "") if info is not None else ""


def _field_info(cls, parts: list[str]):
    info = None
    for part in parts:
        fields = getattr(cls, "__pydantic_fields__", None)
        if not fields or part not in fields:
            return None
        info = fields[part]
        cls = _settings_class(info.annotation)
    return info


def _settings_class(annotation):
    if hasattr(annotation, "__pydantic_fields__"):
        return annotation
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        for arg in typing.get_args(annotation):
            if hasattr(arg, "__pydantic_fields__"):
                return arg
    return None


def known_keys(cls) -> list[str]:
    """The keys a settings model accepts (for 'unknown setting' messages)."""
    return sorted(k for k in getattr(cls, "__pydantic_fields__", {})
                  if k not in getattr(cls, "_hidden_keys", ("source",)))


_TYPE_WORDS = {
    "float_type": "a number", "float_parsing": "a number", "int_type": "a whole number",
    "int_parsing": "a whole number", "int_from_float": "a whole number",
    "bool_type": "true or false", "bool_parsing": "true or false",
    "string_type": "a string", "list_type": "a list", "tuple_type": "a list",
    "dict_type": "a table", "dataclass_type": "a table", "dataclass_args_type": "a table",
    "model_type": "a table", "finite_number": "a finite number",
    "missing": "missing: this setting is required",
    "missing_argument": "missing: this setting is required",
    "int_too_big": "a whole number of reasonable size",
}


def _valid_words(err: Mapping[str, Any], model, key: str) -> str:
    kind, ctx = err["type"], err.get("ctx") or {}
    if kind in ("extra_forbidden", "unexpected_keyword_argument"):
        parent = key.rsplit(".", 1)[0] if "." in key else ""
        info_cls = model if not parent else _settings_class(
            getattr(_field_info(model, parent.split(".")), "annotation", None))
        known = known_keys(info_cls) if info_cls is not None else []
        return "unknown setting" + ("; known settings here are: " + ", ".join(known)
                                    if known else "")
    if kind == "enum":
        return "one of " + str(ctx.get("expected", ""))
    if kind == "literal_error":
        return "one of " + str(ctx.get("expected", ""))
    bound_words = {"greater_than_equal": ">= {ge}", "greater_than": "> {gt}",
                   "less_than_equal": "<= {le}", "less_than": "< {lt}",
                   "too_long": "at most {max_length} entries",
                   "too_short": "at least {min_length} entries"}
    if kind in bound_words:
        words = bound_words[kind].format(**{k: _num(v) for k, v in ctx.items()})
        reason = reason_of(model, key) if model is not None else ""
        words = words if kind.startswith("too_") else f"a value {words}"
        return words + (f" ({reason})" if reason else "")
    if kind in _TYPE_WORDS:
        return _TYPE_WORDS[kind]
    if kind == "value_error" and isinstance(ctx.get("error"), SettingProblem):
        return ctx["error"].valid
    msg = str(err.get("msg", kind))
    return msg.removeprefix("Value error, ")


def _num(v):
    if isinstance(v, float) and v.is_integer() and abs(v) < 1e15:
        return int(v)
    return v


_RANK = {"extra_forbidden": 0, "unexpected_keyword_argument": 0, "value_error": 1,
         "greater_than_equal": 2, "greater_than": 2, "less_than_equal": 2, "less_than": 2,
         "too_long": 2, "too_short": 2, "finite_number": 2}
_TYPE_TAGS = {"float", "int", "str", "bool", "none", "list", "tuple", "dict",
              "constrained-float", "constrained-int", "constrained-str", "lax-or-strict",
              "nullable", "default"}


def _is_tag(part) -> bool:
    """True for the parts of a pydantic error location that name a type, not a key."""
    return isinstance(part, str) and ("[" in part or part in _TYPE_TAGS
                                      or part.startswith("function-"))


def _value_at(data, loc) -> Any:
    cur = data
    for part in loc:
        if isinstance(cur, dict) and part in cur:
            cur = cur[part]
        elif isinstance(cur, (list, tuple)) and isinstance(part, int) and part < len(cur):
            cur = cur[part]
        else:
            return "(missing)" if cur is data else cur
    return cur


def convert_error(exc: ValidationError, data, source: str, make_error: ErrorFactory,
                  model=None, prefix: str = "") -> Exception:
    """The first problem of a pydantic ``ValidationError`` as the package's exception.

    Parameters
    ----------
    exc : pydantic.ValidationError
    data : object
        What was validated (to show the refused value).
    source : str
        The file (or ``"built-in defaults"``, ``"--seed"``) the values came from.
    make_error : callable
        ``make_error(source, key, value, valid)`` building the package's exception.
    model : type, optional
        The settings class validated (to find each bound's reason).
    prefix : str
        Prepended to every key (a model loaded as one table of a bigger file).
    """
    errors = exc.errors(include_url=False, include_input=True)
    # a misspelt key explains the 'missing' one beside it; of a union's alternatives
    # (``"hold"`` or a delay in s) the one that failed on its bounds says the most
    err = min(errors, key=lambda e: _RANK.get(e["type"], 3))
    loc = [p for p in err["loc"] if not _is_tag(p)]
    ctx = err.get("ctx") or {}
    parts = [str(p) for p in loc if not isinstance(p, int)]
    value = err.get("input", _value_at(data, loc))
    if err["type"] == "value_error" and isinstance(ctx.get("error"), SettingProblem):
        problem = ctx["error"]
        parts = parts + [problem.key] if problem.key else parts
        value = problem.value
    elif err["type"] in ("missing", "missing_argument"):
        value = "(missing)"
    key = ".".join(parts)
    valid = _valid_words(err, model, key)
    key = (prefix + "." + key if key else prefix) if prefix else (key or "(top level)")
    return make_error(source, key, _printable(value), valid)


def _printable(value):
    """The refused value, shortened if huge (a message is one line)."""
    text = repr(value)
    if len(text) > 80:
        return text[:77] + "..."
    return value


def validate_settings(cls, data, *, source: str, make_error: ErrorFactory, prefix: str = ""):
    """Build settings ``cls`` from ``data`` (a dict with the file's layout), or raise.

    Raises
    ------
    Exception
        ``make_error(...)``: one line naming source, dotted key, value and what is valid.
    """
    if not isinstance(data, dict):
        raise make_error(source, prefix or "(top level)", _printable(data), "a table of settings")
    try:
        return _adapter(cls).validate_python(data)
    except ValidationError as exc:
        raise convert_error(exc, data, source, make_error, cls, prefix) from None
    except RecursionError:
        raise make_error(source, prefix or "(top level)", "...", "a table nested less deeply"
                         ) from None


def replace_settings(obj, make_error: ErrorFactory, source: str, /, **changes):
    """``dataclasses.replace`` on a settings object, errors converted like a file's."""
    try:
        return dataclasses.replace(obj, **changes)
    except ValidationError as exc:
        raise convert_error(exc, changes, source, make_error, type(obj)) from None
    except TypeError as exc:     # a keyword the dataclass does not have
        raise make_error(source, ", ".join(sorted(changes)), "", f"not a setting ({exc})"
                         ) from None


_ADAPTERS: dict[type, TypeAdapter] = {}


def _adapter(cls) -> TypeAdapter:
    if cls not in _ADAPTERS:
        _ADAPTERS[cls] = TypeAdapter(cls)
    return _ADAPTERS[cls]


def read_toml(path: str | os.PathLike, make_error: ErrorFactory, *, what: str) -> dict:
    """Read a TOML settings file into a dict.

    Parameters
    ----------
    path : path-like
    make_error : callable
        The package's exception factory (for a file that is not TOML).
    what : str
        What the file is, for 'not found' (``"configuration file (--config)"``).

    Raises
    ------
    nmsid.errors.InputFileMissing
        If ``path`` is not a file.
    Exception
        ``make_error(path, "(file)", ...)`` if the file is too big, not UTF-8 or not TOML.
    """
    import tomllib  # here: most runs read no settings file (`nmsid identify` reads none)

    source = str(path)
    if not os.path.isfile(path):
        raise InputFileMissing(f"{source}: no such {what}")
    size = os.path.getsize(path)
    if size > MAX_TOML_BYTES:
        raise make_error(source, "(file)", f"{size} bytes",
                         f"a settings file of at most {MAX_TOML_BYTES} bytes")
    with open(path, "rb") as fh:
        raw = fh.read()
    try:
        data = tomllib.loads(raw.decode("utf-8"))
        hint = _drive_path_hint(raw.decode("utf-8"))
        if hint is not None:  # "C:\temp\new" parses, as C:<tab>emp<newline>ew
            raise make_error(source, *hint)
        return data
    except UnicodeDecodeError as exc:
        raise make_error(source, "(file)", "bytes", f"UTF-8 text ({exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        hint = _backslash_hint(raw.decode("utf-8"), str(exc))
        if hint is not None:
            raise make_error(source, *hint) from None
        raise make_error(source, "(file)", "TOML", f"not valid TOML: {exc}") from None
    except RecursionError:
        raise make_error(source, "(file)", "TOML", "a table nested less deeply") from None


class _Verbatim(str):
    """A value shown as written (a TOML line keeps its single backslashes)."""

    def __repr__(self) -> str:
        return str(self)


_UNESCAPED = re.compile(r"Unescaped '\\' in a string \(at line (\d+)")


def _backslash_hint(text: str, message: str) -> tuple[str, str, str] | None:
    """``(where, value, valid)`` for a backslash TOML refused in a double-quoted string
    (a Windows path such as ``"C:\\Program Files\\..."``, written with single
    backslashes), else None.

    TOML's basic strings ("...") treat a backslash as the start of an escape; literal
    strings ('...') keep it (toml.io, "String").
    """
    m = _UNESCAPED.search(message)
    if m is None:
        return None
    n = int(m.group(1))
    lines = text.splitlines()
    line = lines[n - 1].strip() if 0 < n <= len(lines) else ""
    valid = ("a backslash in a double-quoted TOML string starts an escape: write a Windows "
             "path in single quotes ('C:\\Program Files\\...') or with forward slashes")
    return f"line {n}", _Verbatim(line), valid


_DRIVE_PATH = re.compile(r'"[A-Za-z]:\\(?!\\)')


def _drive_path_hint(text: str) -> tuple[str, str, str] | None:
    """The :func:`_backslash_hint` refusal for a Windows path with single backslashes in a
    double-quoted string that TOML accepted because each escape happened to be valid
    (``"C:\\temp\\new"`` is ``C:`` + tab + ``emp`` + newline + ``ew``)."""
    for n, line in enumerate(text.splitlines(), 1):
        if _DRIVE_PATH.search(line.split("#", 1)[0]):
            return _backslash_hint(text, f"Unescaped '\\' in a string (at line {n}")
    return None


def settings_rows(cls, prefix: str = "") -> list[tuple[str, str, str, str]]:
    """``(key, default, bounds, why)`` of every key below ``cls``, nested tables expanded.

    ``docs/settings.md`` is generated from these rows, so the page and the models agree.
    """
    rows = []
    for name, info in getattr(cls, "__pydantic_fields__", {}).items():
        if name in getattr(cls, "_hidden_keys", ("source",)):
            continue
        key = f"{prefix}.{name}" if prefix else name
        sub = _settings_class(info.annotation)
        if sub is not None and sub is not cls:
            rows.extend(settings_rows(sub, key))
            continue
        bounds = []
        for m in info.metadata:
            for attr, sign in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<"),
                               ("min_length", "entries >="), ("max_length", "entries <=")):
                v = getattr(m, attr, None)
                if v is not None:
                    bounds.append(f"{sign} {v:g}" if isinstance(v, float) else f"{sign} {v}")
        if info.default_factory is not None:
            default = repr(info.default_factory())
        else:
            default = "required" if info.is_required() else repr(getattr(info.default, "value",
                                                                          info.default))
        if len(default) > 40:
            default = default[:37] + "..."
        rows.append((key, default, ", ".join(bounds), info.description or ""))
    return rows
