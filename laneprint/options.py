"""Command-line options built from the settings dataclasses, and `--config FILE.toml`.

A command names the settings it takes (`Section`: a TOML table and a dataclass) with the
`configurable` decorator, which adds to it

- one option per field of each section (`--learning-rate` for `learning_rate`), its help the
  field's docstring or trailing comment and its default the field's: one place for both;
  hidden from `--help` unless the section names it visible (research knobs stay settable);
- `--config FILE.toml`: a file whose tables are sections (`[dqn]`, `[analysis]`, ...) or
  commands (`[train]`, `[drive]`: that command's own options, by their option names).

A value resolves as: the dataclass default, then the file, then the command line. The same
file serves every command: each reads the tables it knows. The command receives the built
dataclasses as `settings` (a `Settings`).
"""

from __future__ import annotations

import ast
import dataclasses
import difflib
import functools
import inspect
import io
import textwrap
import tokenize
import tomllib
import typing
from pathlib import Path
from typing import Annotated, Any, Callable, Mapping, Optional

import typer

from laneprint.errors import SettingError, UserError

#: A config file larger than this is no settings file.
MAX_CONFIG_BYTES = 64 * 1024
#: table name -> settings dataclass, of every section any command takes (filled as commands are declared)
SECTIONS: dict[str, type] = {}
#: the commands, each of which reads a `[command]` table of its own options
COMMANDS: set[str] = set()
SCALARS = (bool, int, float, str)


@dataclasses.dataclass(frozen=True)
class Section:
    """A settings dataclass a command takes, read from the `[table]` of the config file."""

    table: str
    cls: type
    visible: tuple[str, ...] = ()  # fields shown in --help (the others are hidden, still settable)
    aliases: Mapping[str, tuple[str, ...]] = dataclasses.field(default_factory=dict)  # field -> older flags
    options: bool = True  # offer the fields on the command line (False: in the config file only)


class Settings:
    """The built settings of a command: `settings.dqn` is the `[dqn]` section's dataclass."""

    def __init__(self, values: dict[str, Any], given: dict[str, set[str]]) -> None:
        self._values, self._given = values, given

    def __getattr__(self, table: str) -> Any:
        try:
            return self._values[table]
        except KeyError:
            raise AttributeError(table) from None

    def given(self, table: str) -> set[str]:
        """The fields of `table` set by the config file or the command line (not left at the default)."""
        return self._given.get(table, set())


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """field -> its help: the docstring under it, or its trailing comment (and the comment lines after it)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            src = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        body = ast.parse(src).body[0].body  # type: ignore[attr-defined]
        comments: dict[int, str] = {}
        for tok in tokenize.generate_tokens(io.StringIO(src).readline):
            if tok.type == tokenize.COMMENT:
                comments[tok.start[0]] = tok.string.lstrip("#").strip()
        lines = src.splitlines()
        for i, node in enumerate(body):
            if not (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)):
                continue
            nxt = body[i + 1] if i + 1 < len(body) else None
            if isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str):
                docs[node.target.id] = " ".join(inspect.cleandoc(nxt.value.value).split())
                continue
            parts = [comments[n] for n in range(node.lineno, (node.end_lineno or node.lineno) + 1) if n in comments]
            n = (node.end_lineno or node.lineno) + 1
            while parts and n <= len(lines) and lines[n - 1].strip().startswith("#"):
                parts.append(comments.get(n, ""))
                n += 1
            if parts:
                docs[node.target.id] = " ".join(" ".join(parts).split())
    return docs


def _scalar(annotation: Any) -> type | None:
    """The scalar type of a field (`int`, `float | None` -> float), or None when it is none."""
    if annotation in SCALARS:
        return annotation
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    return args[0] if len(args) == 1 and args[0] in SCALARS else None


def _flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def _own_flags(param: inspect.Parameter) -> tuple[str, list[str]]:
    """(config key, flags) of a command's own parameter."""
    info = next((m for m in typing.get_args(param.annotation)[1:] if isinstance(m, typer.models.ParameterInfo)), None)
    decls = [d for decl in (getattr(info, "param_decls", None) or ()) for d in decl.split("/")]
    flags = [d.strip() for d in decls if d.strip().startswith("--")] or [_flag(param.name)]
    if isinstance(info, typer.models.ArgumentInfo):
        return param.name, []
    return flags[0][2:].replace("-", "_"), flags


def _default_text(value: Any) -> str:
    return "none" if value is None else str(value).lower() if isinstance(value, bool) else str(value)


def _field_option(sec: Section, f: dataclasses.Field, typ: type, doc: str) -> Any:
    """The `typer.Option` of one field."""
    flags = [_flag(f.name), *sec.aliases.get(f.name, ())]
    default = f.default if f.default is not dataclasses.MISSING else None
    help_ = f"{doc} [{sec.table}.{f.name}, default {_default_text(default)}]".strip()
    if typ is bool:
        decls = [f"{flags[0]}/--no-{flags[0][2:]}", *flags[1:]]
    else:
        decls = flags
    return Annotated[
        Optional[typ], typer.Option(*decls, help=help_, hidden=f.name not in sec.visible, show_default=False)
    ]


def read_tables(path: Path) -> dict[str, dict[str, Any]]:
    """The tables of a TOML config file (one line of error for anything else)."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_CONFIG_BYTES:
            raise UserError(f"--config {path}: larger than {MAX_CONFIG_BYTES // 1024} KB, not a settings file")
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UserError(f"--config {path}: {exc.strerror or exc}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise UserError(f"--config {path}: not valid TOML ({exc})") from None
    loose = [k for k, v in data.items() if not isinstance(v, dict)]
    if loose:
        raise UserError(
            f"--config {path}: {loose[0]} is outside any table; put settings under their table, "
            f"e.g. [analysis] or [train] (tables: {', '.join(sorted(known_tables()))})"
        )
    unknown = [t for t in data if t not in known_tables()]
    if unknown:
        raise UserError(
            f"--config {path}: unknown table [{unknown[0]}]{_suggest(unknown[0], known_tables())}; "
            f"tables: {', '.join(sorted(known_tables()))}"
        )
    return data


def known_tables() -> set[str]:
    return set(SECTIONS) | set(COMMANDS)


def _suggest(word: str, choices: Any) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f" (did you mean {close[0]}?)" if close else ""


def coerce(where: str, key: str, value: Any, typ: Any) -> Any:
    """`value` from the file as `typ` (a field's or an option's type), or a one-line error."""
    if isinstance(value, list):
        value = tuple(value)
    base = _scalar(typ)
    optional = type(None) in typing.get_args(typ)
    if value is None and optional:
        return None
    if base is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if base is not None:
        if isinstance(value, base) and (base is bool) == isinstance(value, bool):
            return value
        raise UserError(f"{where}: {key} must be {base.__name__}, not {value!r}")
    if typ is Path or Path in typing.get_args(typ):
        if isinstance(value, str):
            return Path(value)
        raise UserError(f"{where}: {key} must be a path (a string), not {value!r}")
    origin = typing.get_origin(typ)
    if origin in (tuple, list) or any(typing.get_origin(a) in (tuple, list) for a in typing.get_args(typ)):
        if isinstance(value, tuple):
            as_list = origin is list or any(typing.get_origin(a) is list for a in typing.get_args(typ))
            return list(value) if as_list else value
        raise UserError(f"{where}: {key} must be a list, not {value!r}")
    return value


def build(sec: Section, table: Mapping[str, Any], given: Mapping[str, Any], where: str) -> tuple[Any, set[str]]:
    """`sec.cls` from its defaults, the file's `table` and the command line's `given` (checked)."""
    hints = typing.get_type_hints(sec.cls)
    fields = {f.name: f for f in dataclasses.fields(sec.cls) if f.init}
    values: dict[str, Any] = {}
    for key, value in table.items():
        if key not in fields or dataclasses.is_dataclass(hints[key]):
            raise UserError(f"{where}: [{sec.table}] has no setting {key!r}{_suggest(key, fields)}")
        values[key] = coerce(f"{where} [{sec.table}]", key, value, hints[key])
    values.update(given)
    try:
        return sec.cls(**values), set(values)
    except SettingError as exc:  # it names the fields: say their flags
        raise UserError(exc.as_flags()) from None
    except (TypeError, ValueError) as exc:
        raise UserError(f"bad {sec.table} setting: {exc}") from None


def configurable(command: str, *sections: Section) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Add the sections' options and `--config` to a command function (see the module doc).

    The function may take `settings` (a `Settings`); its own options also read the file's
    `[command]` table, where a value counts unless the option was given on the command line.
    """

    def decorate(fn: Callable[..., Any]) -> Callable[..., Any]:
        sig = inspect.signature(fn, eval_str=True)
        own = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in sig.parameters.values() if p.name != "settings"]
        keys = {p.name: _own_flags(p)[0] for p in own}
        taken = {flag for p in own for flag in _own_flags(p)[1]}
        extra, generated = [], {}
        for sec in sections:
            SECTIONS[sec.table] = sec.cls
            hints, docs = typing.get_type_hints(sec.cls), field_docs(sec.cls)
            for f in dataclasses.fields(sec.cls):
                typ = _scalar(hints[f.name])
                flags = {_flag(f.name), *sec.aliases.get(f.name, ())}
                if not sec.options or typ is None or not f.init or flags & taken:
                    continue
                taken |= flags
                name = f"{sec.table}__{f.name}"
                generated[name] = (sec.table, f.name)
                extra.append(
                    inspect.Parameter(
                        name,
                        inspect.Parameter.KEYWORD_ONLY,
                        default=None,
                        annotation=_field_option(sec, f, typ, docs.get(f.name, "")),
                    )
                )
        COMMANDS.add(command)
        by_field = {field: (table, field) for table, field in generated.values()}  # `[command]` keys of sections
        config = inspect.Parameter(
            "config",
            inspect.Parameter.KEYWORD_ONLY,
            default=None,
            annotation=Annotated[
                Optional[Path],
                typer.Option(
                    "--config",
                    metavar="FILE.toml",
                    help=(
                        "Settings from a TOML file: tables "
                        + ", ".join(f"[{s.table}]" for s in sections)
                        + (" and " if sections else "")
                        + f"[{command}] (this command's options by name); "
                        "options given here take precedence."
                    ),
                ),
            ],
        )
        own_types = {
            p.name: typing.get_args(p.annotation)[0] if typing.get_args(p.annotation) else p.annotation for p in own
        }
        takes_settings = "settings" in sig.parameters

        @functools.wraps(fn)
        def wrapper(**kwargs: Any) -> Any:
            from laneprint.cliutil import err_console

            try:
                call = _resolve(kwargs)
            except UserError as exc:
                text = exc.as_flags() if isinstance(exc, SettingError) else str(exc)
                err_console.print(f"error: {text}", markup=False, highlight=False, soft_wrap=True)
                raise typer.Exit(1) from None
            return fn(**call)

        def _resolve(kwargs: dict[str, Any]) -> dict[str, Any]:
            path = kwargs.pop("config", None)
            tables = read_tables(path) if path is not None else {}
            where = f"--config {path}"
            call = {p.name: kwargs[p.name] for p in own}
            by_key = {k: n for n, k in keys.items()}
            ctx = kwargs.pop("typer_context", None)
            same = next((sec for sec in sections if sec.table == command), None)  # e.g. [drive]: both
            shared = {f.name for f in dataclasses.fields(same.cls)} if same else set()
            from_command: dict[str, dict[str, Any]] = {}  # section options set in `[command]`, e.g. [train] episodes
            for key, value in tables.get(command, {}).items():
                name = by_key.get(key)
                if name is None and key in shared:
                    continue
                if name is None and key in by_field:
                    table, field = by_field[key]
                    from_command.setdefault(table, {})[field] = value
                    continue
                if name is None:
                    choices = set(by_key) | shared | set(by_field)
                    raise UserError(f"{where}: [{command}] has no option {key!r}{_suggest(key, choices)}")
                source = ctx.get_parameter_source(name) if ctx is not None else None
                if source is None or source.name in ("DEFAULT", "DEFAULT_MAP"):
                    call[name] = coerce(f"{where} [{command}]", key, value, own_types[name])
            values, given = {}, {}
            for sec in sections:
                cli = {
                    field: kwargs[name]
                    for name, (table, field) in generated.items()
                    if table == sec.table and kwargs.get(name) is not None
                }
                merged = {
                    **{k: v for k, v in tables.get(sec.table, {}).items() if sec.table != command or k not in by_key},
                    **from_command.get(sec.table, {}),
                }
                values[sec.table], given[sec.table] = build(sec, merged, cli, where)
            if takes_settings:
                call["settings"] = Settings(values, given)
            return call

        context = inspect.Parameter("typer_context", inspect.Parameter.KEYWORD_ONLY, annotation=typer.Context)
        params = [context] + own + extra + [config]
        wrapper.__signature__ = sig.replace(parameters=params)  # type: ignore[attr-defined]
        wrapper.__annotations__ = {p.name: p.annotation for p in params}
        return wrapper

    return decorate


def config_reference() -> str:
    """Markdown: every table of the config file, its keys, types, defaults and help."""
    out = []
    for table in sorted(SECTIONS):
        cls = SECTIONS[table]
        hints, docs = typing.get_type_hints(cls), field_docs(cls)
        out.append(
            f"## [{table}]\n\n{inspect.getdoc(cls) or ''}\n\n| key | type | default | what it sets |\n|---|---|---|---|"
        )
        for f in dataclasses.fields(cls):
            if not f.init or dataclasses.is_dataclass(hints[f.name]):
                continue
            default = (
                f.default
                if f.default is not dataclasses.MISSING
                else (f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
            )
            typ = getattr(_scalar(hints[f.name]), "__name__", None) or "list"
            text = docs.get(f.name, "").replace("|", "\\|")
            out.append(f"| `{f.name}` | {typ} | `{_default_text(default)}` | {text} |")
        out.append("")
    return "\n".join(out)
