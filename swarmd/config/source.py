"""Reading a YAML config file: its data, the line of every field, and pydantic errors
turned into `Problem`s that name the file and the field.

PyYAML's `safe_load` silently keeps the last of two equal keys; in a swarm file that
would drop a function or a robot without a word, so duplicates are reported here.

Hostile or broken files get one line, never a hang, a crash or a memory blow-up: only a
regular file of at most `MAX_FILE_BYTES` is read (`swarmd.base.files`); before the nodes are
composed, one pass over libyaml's parser events (iterative, safe at any depth) refuses
nesting deeper than `MAX_DEPTH` (libyaml's composer recurses in C and segfaults near
30,000 nested `[`) and aliases that would add more than `MAX_ALIAS_NODES` nodes when
expanded (the "billion laughs": a few lines that expand to 10^9 items).
"""

from __future__ import annotations

import contextlib
import difflib
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ValidationError

from swarmd.base.files import FileRefused, read_regular_file
from swarmd.config.errors import ConfigError, ConfigUnreadable, Loc, Problem, format_loc

MAX_FILE_BYTES = 8 * 1024 * 1024
"""A 255-function swarm with 5,000 standbys is about 0.35 MB; 8 MiB is room to spare."""
MAX_DEPTH = 64
"""Nesting of mappings and lists; a real config nests 5 deep (robots[i].home)."""
MAX_NUMBER_CHARS = 100
"""A plain scalar that looks like a number and is longer than this is refused."""
MAX_ALIAS_NODES = 100_000
"""Nodes that aliases add when expanded (`home: *park` adds 3). The whole 5,255-robot
swarm file has ~60,000 nodes; a billion-laughs file adds 10^9."""


@dataclass
class Source:
    """One parsed YAML file: data plus the line (1-based) of each field path."""

    name: str
    """How the file is named in messages: the path as the user gave it."""
    path: Path | None
    data: Any
    lines: dict[Loc, int] = field(default_factory=dict)

    @property
    def directory(self) -> Path:
        """Relative paths inside a config file are relative to the file itself."""
        return self.path.parent if self.path is not None else Path.cwd()

    def line_of(self, loc: Loc) -> int | None:
        """Line of `loc`, or of its nearest ancestor that is in the file."""
        for n in range(len(loc), -1, -1):
            if loc[:n] in self.lines:
                return self.lines[loc[:n]]
        return None

    def problem(self, loc: Loc, message: str, severity: str = "error") -> Problem:
        return Problem(
            file=self.name,
            field=format_loc(loc),
            message=message,
            severity="warning" if severity == "warning" else "error",
            line=self.line_of(loc),
        )

    def resolve(self, value: str) -> Path:
        p = Path(value).expanduser()
        return p if p.is_absolute() else self.directory / p


def read_source(path: str | Path) -> Source:
    """Read and parse a YAML file. Raises ConfigUnreadable / ConfigError."""
    name = str(path)
    try:
        text = read_regular_file(path, MAX_FILE_BYTES).decode("utf-8")
    except FileRefused as exc:
        raise ConfigUnreadable([Problem(name, "<file>", exc.reason)]) from None
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ConfigUnreadable(
            [Problem(name, "<file>", f"cannot read the file: {reason}")]
        ) from exc
    return parse_source(text, name, Path(path))


_LOADER: type[yaml.SafeLoader] = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def parse_source(text: str, name: str = "<string>", path: Path | None = None) -> Source:
    """Parse YAML text. Syntax errors and duplicate keys raise ConfigError with lines."""
    if len(text) > MAX_FILE_BYTES:
        raise ConfigError([Problem(name, "<file>", f"is {len(text)} characters, above the "
                                   f"limit of {MAX_FILE_BYTES}")])
    # libyaml parses ~10x faster (grid100: 0.25 s -> 0.03 s) and keeps the marks.
    loader = _LOADER(text)
    try:
        _check_shape(text, name)
        node = loader.get_single_node()
        lines: dict[Loc, int] = {}
        dups: list[Problem] = []
        if node is not None:
            _walk(node, (), lines, dups, name)
        if dups:
            raise ConfigError(dups)
        data = loader.construct_document(node) if node is not None else None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark is not None else None
        if "nesting depth" in (exc.problem or ""):
            # libyaml from 0.2.6 (PyYAML 6.0.4 wheels) stops deep nesting itself, before
            # `_check_shape` sees it: the same refusal, in the same words.
            raise ConfigError([Problem(name, "<yaml>",
                                       f"nested more than {MAX_DEPTH} levels deep",
                                       line=line)]) from None
        what = " ".join(s for s in (exc.context, exc.problem) if s)
        raise ConfigError(
            [Problem(name, "<yaml>", f"YAML syntax error: {what}", line=line)]
        ) from None
    except yaml.YAMLError as exc:
        raise ConfigError([Problem(name, "<yaml>", f"YAML error: {exc}")]) from exc
    except (ValueError, RecursionError, MemoryError) as exc:  # a value YAML cannot build
        raise ConfigError([Problem(name, "<yaml>", f"unusable YAML: {type(exc).__name__}: "
                                   f"{str(exc)[:120]}")]) from None
    finally:
        loader.dispose()
    return Source(name=name, path=path, data=data, lines=lines)


def _line_of(event: yaml.Event) -> int | None:
    mark = event.start_mark
    return mark.line + 1 if mark is not None else None


_OPEN = (yaml.SequenceStartEvent, yaml.MappingStartEvent)
_CLOSE = (yaml.SequenceEndEvent, yaml.MappingEndEvent)


def _check_shape(text: str, name: str) -> None:
    """Refuse too deep nesting and alias bombs from the parser's event stream, before
    anything recursive sees the document. Syntax errors surface here as YAMLError."""
    # Per open collection: [its expanded size so far, its anchor]; sizes of anchors.
    stack: list[list[Any]] = [[0, None]]
    anchors: dict[str, int] = {}
    expanded = 0
    for event in yaml.parse(text, Loader=_LOADER):
        if isinstance(event, _OPEN):
            if len(stack) > MAX_DEPTH:
                raise ConfigError([Problem(
                    name, "<yaml>", f"nested more than {MAX_DEPTH} levels deep",
                    line=_line_of(event))])
            stack.append([1, event.anchor])
        elif isinstance(event, _CLOSE):
            size, anchor = stack.pop()
            if anchor is not None:
                anchors[anchor] = size
            stack[-1][0] += size
        elif isinstance(event, yaml.AliasEvent):
            added = anchors.get(event.anchor or "", 1)
            stack[-1][0] += added
            expanded += added
            if expanded > MAX_ALIAS_NODES:
                raise ConfigError([Problem(
                    name, "<yaml>", f"aliases expand to more than {MAX_ALIAS_NODES:,} "
                    "nodes (an alias bomb?)", line=_line_of(event))])
        elif isinstance(event, yaml.ScalarEvent):
            stack[-1][0] += 1
            if event.anchor is not None:
                anchors[event.anchor] = 1
            value = event.value
            if (len(value) > MAX_NUMBER_CHARS and event.implicit[0]
                    and value.lstrip("+-.")[:1].isdigit()):
                # YAML would turn it into an int: a ValueError beyond 4300 digits.
                raise ConfigError([Problem(
                    name, "<yaml>", f"a number of {len(value)} characters (at most "
                    f"{MAX_NUMBER_CHARS})", line=_line_of(event))])


def _walk(
    node: yaml.Node,
    loc: Loc,
    lines: dict[Loc, int],
    dups: list[Problem],
    name: str,
    path: set[int] | None = None,
) -> None:
    if path is None:
        path = set()
    lines.setdefault(loc, node.start_mark.line + 1)
    if id(node) in path:
        # `&a [*a]`: an alias inside itself would recurse forever in any consumer.
        raise ConfigError([Problem(name, format_loc(loc), "recursive YAML alias",
                                   line=node.start_mark.line + 1)])
    if not isinstance(node, yaml.MappingNode | yaml.SequenceNode):
        return
    path.add(id(node))
    _walk_children(node, loc, lines, dups, name, path)
    path.discard(id(node))


def _walk_children(node: yaml.Node, loc: Loc, lines: dict[Loc, int], dups: list[Problem],
                   name: str, path: set[int]) -> None:
    if isinstance(node, yaml.MappingNode):
        seen: set[Any] = set()
        for key_node, value_node in node.value:
            key: str | int = key_node.value
            if isinstance(key_node, yaml.ScalarNode) and key_node.tag.endswith(":int"):
                with contextlib.suppress(ValueError):
                    key = int(key_node.value)
            sub = (*loc, key)
            if key in seen:
                dups.append(
                    Problem(name, format_loc(sub), "key given twice (YAML keeps only the "
                            "last one, the first would be silently lost)",
                            line=key_node.start_mark.line + 1)
                )
            seen.add(key)
            lines.setdefault(sub, key_node.start_mark.line + 1)
            _walk(value_node, sub, lines, dups, name, path)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _walk(item, (*loc, i), lines, dups, name, path)


# -- pydantic errors -> problems ---------------------------------------------------------

UNION_TAGS = frozenset(
    {"slot", "patrol", "udp", "serial", "xbee", "none", "socket", "exec"}
)
"""Discriminator values: pydantic puts the tag into an error's location
(`functions.f1.slot.position`); users never wrote it, so it is dropped."""


def _all_field_names(model: type[BaseModel], acc: set[str]) -> set[str]:
    """Field names of `model` and of every model nested in it (for typo hints)."""
    for name, info in model.model_fields.items():
        acc.add(name)
        for sub in _models_in(info.annotation):
            if sub is not model:
                _all_field_names(sub, acc)
    return acc


def _models_in(annotation: Any) -> Iterable[type[BaseModel]]:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield annotation
        return
    for arg in getattr(annotation, "__args__", ()) or ():
        yield from _models_in(arg)


def validation_problems(
    exc: ValidationError, source: Source, model: type[BaseModel]
) -> list[Problem]:
    """Every pydantic error as a Problem with a user-facing path and message."""
    known = sorted(_all_field_names(model, set()))
    out: list[Problem] = []
    seen: set[tuple[str, str]] = set()
    for err in exc.errors(include_url=False):
        raw: Loc = tuple(err["loc"])
        raw = tuple(p for p in raw if p != "[key]")  # pydantic's marker for a dict key
        if err["type"] == "missing" and raw and isinstance(raw[-1], int):
            # A too-short tuple ([x, y] for a position) reports its missing item.
            raw = raw[:-1]
            err = {**err, "type": "too_short_tuple"}
        loc: Loc = tuple(
            p for i, p in enumerate(raw) if not (i > 0 and isinstance(p, str) and p in UNION_TAGS
                                                 and _is_tag_position(raw, i))
        )
        message = _message(err, loc, known)
        key = (format_loc(loc), message)
        if key in seen:
            continue
        seen.add(key)
        out.append(source.problem(loc, message))
    return out


def _is_tag_position(loc: Loc, i: int) -> bool:
    # A tag follows the union field: functions.<name>.<tag>, transport.<tag>, link.<tag>.
    head = loc[0]
    return (head == "functions" and i == 2) or (head in ("transport", "link") and i == 1)


def _message(err: Any, loc: Loc, known: list[str]) -> str:
    kind = err["type"]
    ctx = err.get("ctx") or {}
    if kind == "extra_forbidden":
        name = str(loc[-1]) if loc else "?"
        if name in known:  # e.g. `position` under a patrol: right word, wrong place
            return f"unknown field '{name}' here (it belongs to another kind or section)"
        hint = difflib.get_close_matches(name, known, n=1)
        did = f"; did you mean '{hint[0]}'?" if hint else ""
        return f"unknown field '{name}' (typo?){did}"
    if kind == "too_short_tuple":
        return "too few items (a position is [x, y, z], a home [x, y])"
    if kind == "missing":
        return "required field is missing"
    if kind == "union_tag_invalid":
        return (
            f"unknown kind {ctx.get('tag')!r}; expected one of {ctx.get('expected_tags')}"
        )
    if kind == "union_tag_not_found":
        return f"'kind' is missing; expected one of {_tags_for(loc)}"
    msg = re.sub(r" or instance of \w+", "", str(err["msg"]).replace(" after validation", ""))
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    if kind not in ("value_error", "assertion_error"):
        msg = f"{msg[:1].lower()}{msg[1:]}, got {_short(err.get('input'))}"
    return msg


def _tags_for(loc: Loc) -> str:
    head = loc[0] if loc else ""
    return {
        "functions": "'slot', 'patrol'",
        "transport": "'udp', 'serial', 'xbee'",
        "link": "'none', 'socket', 'exec'",
    }.get(str(head), "?")


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def validate(model: type[BaseModel], source: Source) -> Any:
    """Validate `source.data` against `model`; ConfigError with every problem."""
    if not isinstance(source.data, dict):
        got = "an empty file" if source.data is None else type(source.data).__name__
        raise ConfigError([source.problem((), f"expected a YAML mapping at the top, got {got}")])
    try:
        return model.model_validate(source.data)
    except ValidationError as exc:
        raise ConfigError(validation_problems(exc, source, model)) from None
