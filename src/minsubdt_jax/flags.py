"""Flags from a dataclass: one ``--field-name`` per field, typed from its annotation, its help from the field's
comment (as tyro reads them). :mod:`minsubdt_jax.config` and :mod:`minsubdt_jax.behavior.config` build their CLIs
with it; :func:`load_fields` reads the train CLI's ``--config`` files."""

from __future__ import annotations

import argparse
import dataclasses
import json
import types
import typing


def base_type(tp):
    if isinstance(tp, types.UnionType) or typing.get_origin(tp) is typing.Union:
        return next(a for a in typing.get_args(tp) if a is not type(None))
    return tp


def field_help(cls) -> dict[str, str]:
    """Each field's help, from the comments of ``cls``'s source (as tyro reads them): the comment on the field's
    line, else the comment lines directly above it."""
    import inspect
    import io
    import re
    import tokenize

    src = inspect.getsource(cls)
    comments = {tok.start[0]: tok.string.lstrip("# ").rstrip()
                for tok in tokenize.generate_tokens(io.StringIO(src).readline) if tok.type == tokenize.COMMENT}
    lines, out = src.splitlines(), {}
    for i, line in enumerate(lines, 1):
        m = re.match(r"\s+(\w+)\s*:[^=]*=", line)
        if not m or line.lstrip().startswith("#"):
            continue
        if i in comments:
            out[m.group(1)] = comments[i]
            continue
        block, j = [], i - 1
        while j in comments and lines[j - 1].lstrip().startswith("#"):
            block.insert(0, comments[j])
            j -= 1
        out[m.group(1)] = " ".join(block)
    return out


def add_flags(parser: argparse.ArgumentParser, cls, choices: dict, presets: dict | None = None,
              default_preset: str | None = None, aliases: dict | None = None) -> None:
    """One ``--field-name`` flag per field of dataclass ``cls``, typed from its annotation, default ``None``
    (so that only the flags given override a preset), its help from the field's comment (:func:`field_help`) and
    its default: the ``default_preset``'s value, with the other ``presets``' where they differ. ``aliases`` maps a
    field to more flag names (``{"learning_rate": ("--lr",)}``)."""
    hints, helps = typing.get_type_hints(cls), field_help(cls)
    for f in dataclasses.fields(cls):
        default = f"default: {f.default}"
        if presets and f.name != "preset":
            values = {name: getattr(pc, f.name) for name, pc in presets.items()}
            if len(set(map(repr, values.values()))) > 1:
                default = f"default: {values[default_preset]}, the {default_preset} preset's; " + ", ".join(
                    f"{name}: {v}" for name, v in values.items() if name != default_preset)
        kw = {"default": None, "type": base_type(hints[f.name]),
              "help": f"{helps.get(f.name, '')} ({default})".replace("%", "%%").lstrip()}
        if f.name in choices:
            kw["choices"] = choices[f.name]
        parser.add_argument("--" + f.name.replace("_", "-"), *(aliases or {}).get(f.name, ()), **kw)


def load_fields(path: str, cls, help_cmd: str) -> dict:
    """The fields of ``cls`` (a dataclass) in a config file: JSON (a run's ``config.json``: every field) or YAML
    (``.yaml``/``.yml``: any of them). Raises ValueError on a file that does not parse, an unknown field, or a
    value of the wrong type."""
    try:
        with open(path) as f:
            text = f.read()
        if path.endswith((".yaml", ".yml")):
            import yaml

            data = yaml.safe_load(text)
        else:
            data = json.loads(text)
    except OSError as e:
        raise ValueError(f"--config {path}: cannot read it ({e.strerror})") from None
    except Exception as e:  # noqa: BLE001  (json.JSONDecodeError, yaml.YAMLError)
        raise ValueError(f"--config {path}: does not parse ({type(e).__name__}: {str(e).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ValueError(f"--config {path}: needs a mapping of field names to values, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    unknown = sorted(set(data) - set(hints))
    if unknown:
        raise ValueError(f"--config {path}: unknown field(s) {unknown}; the fields are {cls.__name__}'s "
                         f"({help_cmd})")
    for k, v in data.items():
        tp = base_type(hints[k])
        optional = hints[k] is not tp
        ok = (v is None and optional) or isinstance(v, tp) and not (tp is int and isinstance(v, bool)) or (
            tp is float and isinstance(v, int) and not isinstance(v, bool))
        if not ok:
            raise ValueError(f"--config {path}: field {k!r} must be {tp.__name__}"
                             f"{' or null' if optional else ''}, got {v!r}")
    return {k: float(v) if base_type(hints[k]) is float and v is not None else v for k, v in data.items()}
