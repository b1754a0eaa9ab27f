"""Read, override, validate and write scenario files, with errors a user can act on.

Every error names the file (or the ``--set`` override), the line of the offending key, the dotted
field, what was expected and what was given: a run that fails at start-up must say exactly which
line to fix. ``tomllib`` reports no positions for parsed keys, so :func:`_locate_keys` recovers them
from the text with a small scanner (tables, dotted keys, multi-line arrays and strings).
"""

from __future__ import annotations

import difflib
import json
import math
import re
import tomllib
import types
import typing
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError

from config.agent_params import LAW_REF
from config.scenario import RecordSpec, Scenario



class ScenarioError(Exception):
    """A scenario that cannot be used, located as precisely as the input allows.

    ``file`` is the path (or ``--set key=value`` for an override, or the source given to
    :func:`scenario_from_dict`), ``line`` is 1-based or None, ``field`` the dotted path ("" for the
    file as a whole). ``errors`` holds every problem found (this one first) so that a user can fix
    them all in one pass; ``str()`` lists them one per line.
    """

    def __init__(
        self, file: str, line: int | None, field: str, message: str, errors: Sequence[ScenarioError] = ()
    ) -> None:
        self.file = file
        self.line = line
        self.field = field
        self.message = message
        self.errors: tuple[ScenarioError, ...] = tuple(errors) or (self,)
        super().__init__("\n".join(e._one_line() for e in self.errors))

    def _one_line(self) -> str:
        where = self.file if self.line is None else f"{self.file}:{self.line}"
        return f"{where}: {self.field}: {self.message}" if self.field else f"{where}: {self.message}"


# --------------------------------------------------------------------------------------------------
# Overrides


def _parse_override(item: str) -> tuple[str, list[str], Any]:
    """``"key=value"`` (optionally prefixed by ``--set``) -> (label for errors, key path, value)."""
    text = item.strip().removeprefix("--set").strip().removeprefix("=").strip()
    label = f"--set {text}"
    if "=" not in text:
        raise ScenarioError(label, None, "", "expected key=value (e.g. --set noise.sigma_v=0.1)")
    key, raw = (part.strip() for part in text.split("=", 1))
    parts = [p.strip() for p in key.split(".")]
    if any(not re.fullmatch(r"[A-Za-z0-9_-]+", p) for p in parts):
        raise ScenarioError(label, None, "", f"bad key {key!r}: expected a dotted name such as load.mass")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw  # a bare word such as `complete` is meant as a string
    return label, parts, value


def _merge(data: dict, overrides: Iterable[str]) -> dict[tuple[str, ...], str]:
    """Merge overrides into ``data`` in place; return which override set each dotted key."""
    origin: dict[tuple[str, ...], str] = {}
    for item in overrides:
        label, parts, value = _parse_override(item)
        node = data
        for depth, p in enumerate(parts[:-1]):
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                field = ".".join(parts[: depth + 1])
                raise ScenarioError(label, None, field, f"is a value, not a table (got {_show(nxt)})")
            node = nxt
        node[parts[-1]] = value
        origin[tuple(parts)] = label
    return origin


def parse_overrides(overrides: Iterable[str]) -> dict:
    """``["load.mass=60", "graph.topology=complete"]`` -> nested dict; values parsed as TOML values.

    A value that is not valid TOML is taken as a bare string, so ``graph.topology=ring`` works
    without shell-quoting the quotes. A later override of the same key wins.
    """
    out: dict = {}
    _merge(out, overrides)
    return out


def deep_merge(base: dict, extra: dict) -> dict:
    """Merge the nested dict ``extra`` (e.g. from :func:`parse_overrides`) into ``base`` in place."""
    for k, v in extra.items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            deep_merge(base[k], v)
        else:
            base[k] = v
    return base


# --------------------------------------------------------------------------------------------------
# Locating keys in TOML text


_KEY_RE = re.compile(r"""\s*((?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*')(?:\s*\.\s*(?:[A-Za-z0-9_-]+|"[^"]*"|'[^']*'))*)\s*=""")
_HEADER_RE = re.compile(r"""\s*\[\[?\s*([^\]]+?)\s*\]\]?\s*(?:#.*)?$""")


def _split_key(key: str) -> tuple[str, ...]:
    parts = re.findall(r"""[A-Za-z0-9_-]+|"[^"]*"|'[^']*'""", key)
    return tuple(p[1:-1] if p[0] in "\"'" else p for p in parts)


def _bracket_delta(text: str, state: list[str | None]) -> int:
    """Net [ / { depth change in a line, outside strings and comments. ``state[0]``: open ml string."""
    depth = 0
    i = 0
    while i < len(text):
        if state[0] is not None:  # inside a multi-line string
            end = text.find(state[0], i)
            if end < 0:
                return depth
            i = end + 3
            state[0] = None
            continue
        ch = text[i]
        if text.startswith('"""', i) or text.startswith("'''", i):
            state[0] = text[i : i + 3]
            i += 3
        elif ch in "\"'":
            j = i + 1
            while j < len(text) and text[j] != ch:
                j += 2 if (ch == '"' and text[j] == "\\") else 1
            i = j + 1
        elif ch == "#":
            break
        else:
            depth += ch in "[{"
            depth -= ch in "]}"
            i += 1
    return depth


def _locate_keys(text: str) -> dict[tuple[str, ...], int]:
    """Map each table and key path to the 1-based line where it is first written."""
    lines: dict[tuple[str, ...], int] = {}
    table: tuple[str, ...] = ()
    depth = 0
    ml: list[str | None] = [None]
    for lineno, line in enumerate(text.splitlines(), start=1):
        if depth == 0 and ml[0] is None:
            header = _HEADER_RE.match(line)
            if header:
                table = _split_key(header.group(1))
                lines.setdefault(table, lineno)
                continue
            key = _KEY_RE.match(line)
            if key:
                path = table + _split_key(key.group(1))
                for k in range(len(table) + 1, len(path) + 1):
                    lines.setdefault(path[:k], lineno)
                depth += _bracket_delta(line[key.end() :], ml)
                continue
        depth = max(0, depth + _bracket_delta(line, ml))
    return lines


def _line_of(lines: dict[tuple[str, ...], int], path: Sequence[str | int]) -> int | None:
    """The line of the longest prefix of ``path`` that is written in the file."""
    keys = [str(p) for p in path]
    for k in range(len(keys), 0, -1):
        if tuple(keys[:k]) in lines:
            return lines[tuple(keys[:k])]
    return None


# --------------------------------------------------------------------------------------------------
# Validation errors -> ScenarioError


def _model_of(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        for arg in typing.get_args(annotation):
            found = _model_of(arg)
            if found:
                return found
    return None


def _model_at(path: Sequence[str | int]) -> type[BaseModel] | None:
    """The pydantic model that the dotted path (of string keys) points into, if any."""
    model: type[BaseModel] | None = Scenario
    for p in path:
        if model is None or not isinstance(p, str) or p not in model.model_fields:
            return None
        model = _model_of(model.model_fields[p].annotation)
    return model


def _field_name(path: Sequence[str | int]) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _show(value: Any) -> str:
    text = repr(value) if not isinstance(value, str) else json.dumps(value, ensure_ascii=False)
    return text if len(text) <= 80 else text[:77] + "..."


def _convert(exc: ValidationError, file: str, lines: dict, origin: dict[tuple[str, ...], str]) -> ScenarioError:
    errors: list[ScenarioError] = []
    for err in exc.errors():
        loc = list(err["loc"])
        msg = err["msg"]
        if err["type"] == "value_error":
            msg = msg.removeprefix("Value error, ")
            # Model-level validators name their field as a "dotted.path: " prefix (see config.scenario).
            m = re.match(r"([A-Za-z_][\w.]*): (.*)", msg, re.S)
            model = _model_at(loc)
            if m and model is not None and m.group(1).split(".")[0] in model.model_fields:
                loc += m.group(1).split(".")
                msg = m.group(2)
        elif err["type"] == "extra_forbidden":
            parent = _model_at(loc[:-1])
            near = difflib.get_close_matches(str(loc[-1]), list(parent.model_fields) if parent else [], n=1)
            msg = "unknown key" + (f" (did you mean {near[0]!r}?)" if near else "")
        elif "input" in err and err["type"] != "missing":
            msg += f" (got {_show(err['input'])})"
        src, line = file, _line_of(lines, loc)
        for key, label in origin.items():
            if tuple(str(p) for p in loc[: len(key)]) == key:
                src, line = label, None
        errors.append(ScenarioError(src, line, _field_name(loc), msg))
    first = errors[0]
    return ScenarioError(first.file, first.line, first.field, first.message, errors)


def _validate(data: dict, file: str, lines: dict, origin: dict[tuple[str, ...], str]) -> Scenario:
    data = dict(data)
    edges = data.pop("edges", None)
    # [recording]: free-form provenance a lab's recorder may add to run.toml (rig, operator, date);
    # ignored, except the keys of [record], which in [recording] would silently do nothing
    recording = data.pop("recording", None)
    if recording is not None and not isinstance(recording, dict):
        raise ScenarioError(file, lines.get(("recording",)), "recording", "must be a table")
    for key in sorted(set(recording or {}) & set(RecordSpec.model_fields)):
        raise ScenarioError(file, lines.get(("recording", key)), f"recording.{key}",
                            "[recording] is provenance and is ignored: did you mean [record]?")
    try:
        scenario = Scenario.model_validate(data)
    except ValidationError as exc:
        raise _convert(exc, file, lines, origin) from None
    scenario = _law_path_resolved(scenario, file, origin)
    if edges is not None:
        try:
            given = sorted({(min(int(i), int(j)), max(int(i), int(j))) for i, j in edges})
        except (TypeError, ValueError):
            raise ScenarioError(file, lines.get(("edges",)), "edges", f"expected [[i, j], ...] (got {_show(edges)})")
        if given != scenario.edges():
            raise ScenarioError(
                file,
                lines.get(("edges",)),
                "edges",
                f"disagrees with the graph ({scenario.graph.topology}, n = {scenario.n}): "
                f"expected {_show([list(e) for e in scenario.edges()])} (got {_show(edges)})",
            )
    return scenario


def _law_path_resolved(scenario: Scenario, file: str, origin: dict[tuple[str, ...], str]) -> Scenario:
    """A law file named by a relative path is made absolute: from the scenario file's directory, or from
    the working directory when a --set gave it (or when there is no file), so that the run.toml a run
    writes, and the daemons that read it, find the same file."""
    ref = scenario.control.law
    m = LAW_REF.fullmatch(ref) if ref else None
    if m is None or not m.group("target").endswith(".py"):
        return scenario
    target = Path(m.group("target")).expanduser()
    if target.is_absolute():
        law = f"{target}:{m.group('attr')}"
    else:
        from_set = any(key == ("control", "law")[: len(key)] for key in origin)
        base = Path.cwd() if from_set or file.startswith("<") else Path(file).resolve().parent
        law = f"{(base / target).resolve()}:{m.group('attr')}"
    if law == ref:
        return scenario
    return scenario.model_copy(update={"control": scenario.control.model_copy(update={"law": law})})


# --------------------------------------------------------------------------------------------------
# Public API


BUNDLED_SCENARIOS = Path(__file__).resolve().parent / "scenarios"
"""The scenarios shipped with coload; a bare name such as ``paper-fig4`` means one of these."""


def resolve_scenario_path(path: str | Path) -> Path:
    """A file as given, a run directory's ``run.toml``, or a bundled scenario by its bare name."""
    p = Path(path)
    if p.is_dir() and (p / "run.toml").is_file():
        return p / "run.toml"
    if not p.exists() and len(p.parts) == 1:
        bundled = BUNDLED_SCENARIOS / (p.name if p.suffix == ".toml" else f"{p.name}.toml")
        if bundled.is_file():
            return bundled
    return p


def _bundled_hint(path: Path) -> str:
    """For a bare name that is no file: the bundled scenario it most likely means, then all of them."""
    names = bundled_scenario_names()
    close = difflib.get_close_matches(path.stem, names, n=1, cutoff=0.6)
    return (f" (did you mean {close[0]}?)" if close else "") + f"; bundled scenarios: {', '.join(names)}"


def bundled_scenario_names() -> list[str]:
    return sorted(f.stem for f in BUNDLED_SCENARIOS.glob("*.toml"))


def load_scenario(path: str | Path, overrides: Sequence[str] = ()) -> Scenario:
    """Read a scenario file (a path, a run directory or a bundled name) and apply ``--set`` overrides."""
    path = resolve_scenario_path(path)
    file = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig")  # -sig: an editor's byte-order mark is not TOML
    except UnicodeDecodeError as exc:
        line = exc.object[: exc.start].count(b"\n") + 1
        raise ScenarioError(file, line, "", f"not UTF-8 text (byte {exc.object[exc.start]:#04x}); "
                                            f"TOML files must be UTF-8") from None
    except OSError as exc:
        if not path.exists() and len(path.parts) == 1:  # a bare name: meant as a bundled scenario's
            raise ScenarioError(file, None, "", f"no such file or bundled scenario{_bundled_hint(path)}") from None
        hint = f"; bundled scenarios: {', '.join(bundled_scenario_names())}" if not path.exists() else ""
        raise ScenarioError(file, None, "", f"cannot read: {exc}{hint}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"\(at line (\d+), column \d+\)", str(exc))
        msg = re.sub(r"\s*\(at (line \d+, column \d+|end of document)\)", "", str(exc))
        raise ScenarioError(file, int(m.group(1)) if m else None, "", f"TOML syntax error: {msg}") from None
    origin = _merge(data, overrides)
    return _validate(data, file, _locate_keys(text), origin)


def scenario_from_dict(data: dict, source: str = "<dict>") -> Scenario:
    """Validate an already-parsed scenario (same rules and messages as a file, without line numbers)."""
    return _validate(data, source, {}, {})


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"non-finite float {value!r} cannot be written")
        return repr(value)
    if isinstance(value, str):
        # JSON string escapes are valid TOML basic-string escapes; DEL must be escaped in TOML too.
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (list, tuple)):
        items = [_toml_value(v) for v in value]
        if len(items) > 8 and all(isinstance(v, (list, tuple)) for v in value):
            rows = [", ".join(items[k : k + 8]) for k in range(0, len(items), 8)]
            return "[\n" + "".join(f"    {row},\n" for row in rows) + "]"
        return "[" + ", ".join(items) + "]"
    if isinstance(value, dict):
        # an inline table: only inside arrays (e.g. link.partitions); unset (None) fields are omitted
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items() if v is not None) + "}"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")


def _toml_lines(table: dict, prefix: tuple[str, ...], out: list[str]) -> None:
    scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in table.items() if isinstance(v, dict)}
    if prefix and (scalars or not tables):
        out.append(f"\n[{'.'.join(prefix)}]")
    for k, v in scalars.items():
        out.append(f"{k} = {_toml_value(v)}")
    for k, v in tables.items():
        _toml_lines(v, prefix + (k,), out)


def dump_scenario(scenario: Scenario) -> str:
    """The resolved ``run.toml``: every field that has a value, plus top-level ``edges``.

    TOML has no null, so optional fields left unset (None) are omitted, which reads back as None.
    ``edges`` makes the file double as the measured-data format's header (n, dt, edges).
    """
    data = scenario.model_dump(mode="python", exclude_none=True)
    top = {k: v for k, v in data.items() if not isinstance(v, dict)}
    top["edges"] = [list(e) for e in scenario.edges()]
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    out = ["# coload resolved scenario (written by config.loader.dump_scenario; loads back unchanged)"]
    _toml_lines({**top, **tables}, (), out)
    return "\n".join(out) + "\n"


__all__ = ["ScenarioError", "dump_scenario", "load_scenario", "parse_overrides", "scenario_from_dict"]
