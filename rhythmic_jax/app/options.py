"""An option declared once: a field of a job's frozen dataclass, with metadata.

A field is an option when its metadata holds ``help`` (:func:`option`; None: one
a job offers only where it words it, by its part's ``helps``; :func:`like`: one
declared by another job). Its default is the field's (none: a positional, or a
``required`` option); one of False is a flag. The metadata holds what
``add_argument`` takes (:data:`ARGPARSE`) and: ``domain``, the
:class:`rhythmic_jax.validate.Domain` a number is parsed with, stated in
``--help`` and checked when a job is made (a whole range: a bound it leaves out
is the largest the number's kind takes, so a huge value is refused there);
``dest``, the option's name where it is not the field's; ``positional``;
``path``: what the job does with it (``reads``, ``writes``, ``frames``: reads
frames from it; :func:`check_paths`; :func:`written`); for an output,
``output``, how its place is checked before the work (:data:`OUTPUTS`), and
``suffix``, the file names it takes; ``show_default``: the default in words,
where the field's own (None, '') is settled by the job, or words after a
declared value; ``default_from``: the class whose field of the same name holds
the default (``module.Class``, read without importing it).
Every default is stated by :func:`add_options` from the declaration alone
(:func:`default_phrase`); no help text words its own.
A field holding a part of the settings (:func:`part`) offers the part's options,
titled ``group`` in ``--help`` and made into its value by ``make`` (default: the
part's class).

A command's parser is rendered from its job's class (:func:`add_options`) and
the job made from what it parsed (:func:`make`). A job checks itself when it is
made (:class:`Checked`: each number in its domain, then the job's rules,
:class:`Rule`), and :func:`check_paths` refuses a job whose outputs would
overwrite what it reads. Imports no numpy, JAX or torch.
"""

from __future__ import annotations

import argparse
import ast
import importlib.util
from collections.abc import Callable
from dataclasses import MISSING, Field, dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar

from rhythmic_jax.errors import InputError
from rhythmic_jax.validate import is_number

__all__ = [
    "OUTPUTS", "Checked", "OptionRefused", "Rule", "add_options", "check_paths",
    "declared_default", "default_phrase", "like", "make", "option", "options",
    "outputs", "part", "settings", "written",
]  # fmt: skip

ARGPARSE = ("nargs", "metavar", "choices", "required")


def option(help_: str | None, default: Any = None, **meta) -> Any:
    """A field offered as an option (a positional or a required one: no default)."""
    if meta.get("positional") or meta.get("required"):
        default = MISSING
    return field(default=default, metadata={"help": help_, **meta})


def like(cls: type, name: str, help_: str | None = None) -> Any:
    """A field offered as the option ``name`` of ``cls`` is (with ``help_`` where
    given): an option declared once for jobs that share it."""
    f = next(f for f in fields(cls) if f.name == name)
    meta = {**f.metadata, "help": help_ or f.metadata["help"]}
    return field(default=f.default, metadata=meta)


def part(cls: type, default: Any = MISSING, **meta) -> Any:
    """A field holding settings of ``cls`` (default ``cls()``), its options offered."""
    if default is MISSING:
        return field(default_factory=cls, metadata={"part": cls, **meta})
    return field(default=default, metadata={"part": cls, **meta})


def default_of(f: Field) -> Any:
    return f.default if f.default_factory is MISSING else f.default_factory()


def options(cls: type, helps: dict | None = None, group: str | None = None):
    """``(dest, field, help, group)`` of each option of ``cls`` and of its parts,
    in the order ``--help`` lists them (inherited keyword-only fields last)."""
    for f in sorted(fields(cls), key=lambda f: f.kw_only):
        meta = f.metadata
        if "part" in meta:
            yield from options(meta["part"], meta.get("helps"), meta.get("group"))
        elif "help" in meta and (helps or {}).get(f.name, meta["help"]) is not None:
            help_ = (helps or {}).get(f.name, meta["help"])
            yield meta.get("dest", f.name), f, help_, group


def declared_default(where: str, name: str) -> Any:
    """The literal default of the field ``name`` of the class ``where``
    (``module.Class``), read from the module's source: a class whose module
    imports JAX states its defaults to ``--help`` without being imported."""
    module, cls = where.rsplit(".", 1)
    source = Path(importlib.util.find_spec(module).origin).read_text()
    body = next(n for n in ast.parse(source).body
                if isinstance(n, ast.ClassDef) and n.name == cls).body  # fmt: skip
    return next(ast.literal_eval(n.value) for n in body
                if isinstance(n, ast.AnnAssign) and n.target.id == name)  # fmt: skip


def default_phrase(f: Field) -> str | None:
    """How ``--help`` states the option's default, from its declaration alone:
    ``(default V)`` for a value (not None, False or ''; a float as %g; from
    ``default_from`` where declared there), ``(default V: WORDS)`` with its
    ``show_default`` words, ``(default: WORDS)`` for words alone; None where
    there is nothing to state."""
    meta = f.metadata
    value = default_of(f)
    if "default_from" in meta:
        value = declared_default(meta["default_from"], f.name)
    words = meta.get("show_default")
    if value is MISSING or value is None or value is False or value == "":
        return None if words is None else f"(default: {words})"
    shown = f"{value:g}" if isinstance(value, float) else str(value)
    return f"(default {shown})" if words is None else f"(default {shown}: {words})"


def add_options(parser: argparse.ArgumentParser, cls: type) -> None:
    """Each option of ``cls`` added to ``parser``, its default stated in its
    help (:func:`default_phrase`), and its domain too."""
    groups = {}
    for dest, f, help_, group in options(cls):
        meta = {k: v for k, v in f.metadata.items() if k in ARGPARSE}
        default = default_of(f)
        if f.metadata.get("positional"):
            names = [dest]
        else:
            names = ["--" + dest.replace("_", "-")]
            meta["default"] = None if default is MISSING else default
            if default is False:
                meta["action"] = "store_true"
            phrase = default_phrase(f)
            if phrase is not None:  # argparse expands % in help
                help_ += " " + phrase.replace("%", "%%")
        domain = f.metadata.get("domain")
        if domain is not None:
            meta["type"] = domain
            help_ += f" [{domain.text()}]"
        if group is not None and group not in groups:
            groups[group] = parser.add_argument_group(group)
        groups.get(group, parser).add_argument(*names, help=help_, **meta)


def _values(cls: type, ns: argparse.Namespace) -> dict[str, Any]:
    values = {}
    for f in fields(cls):
        meta, dest = f.metadata, f.metadata.get("dest", f.name)
        if "part" in meta:
            values[f.name] = meta.get("make", meta["part"])(**_values(meta["part"], ns))
        elif "help" in meta and hasattr(ns, dest):
            value = getattr(ns, dest)
            values[f.name] = tuple(value) if isinstance(value, list) else value
    return values


def make(cls: type, ns: argparse.Namespace, **extra) -> Any:
    """A ``cls`` made from the parsed options ``ns`` (lists as tuples) and
    ``extra``; a field whose option the command does not offer keeps its default."""
    return cls(**_values(cls, ns), **extra)


def settings(obj: Any, cls: type | None = None) -> dict[str, tuple[Any, Any, dict]]:
    """``{dest: (value, default, metadata)}`` of each option of ``obj`` (read as
    a ``cls``, default its own class) and of the parts it holds, flattened."""
    found = {}
    for f in fields(cls or obj):
        value = getattr(obj, f.name)
        if "part" in f.metadata and value is not None:
            found.update(settings(value, f.metadata["part"]))
        elif "help" in f.metadata:
            found[f.metadata.get("dest", f.name)] = (value, default_of(f), f.metadata)
    return found


class OptionRefused(InputError):
    """A setting given where it has no effect, or without one it needs."""


@dataclass(frozen=True)
class Rule:
    """Where a setting acts: given (away from its default, or named in the job's
    ``given``) where ``holds(job)`` is false, each of ``options`` is refused with
    the line ``{opt:OPTION} says``, or, for options that scripts pass always
    (``warn``), named in one warning line and ignored."""

    options: tuple[str, ...]
    says: str
    holds: Callable[[Any], bool]
    warn: bool = False


@dataclass(frozen=True, kw_only=True)
class Checked:
    """A job that checks itself when made: every numeric setting against its
    option's domain, then every rule of ``RULES`` (:class:`Rule`); a refused
    rule raises :class:`OptionRefused`, and ``warnings`` holds the lines naming
    settings a warning rule ignores. ``given`` names settings given explicitly,
    as the command line's options are: a rule refuses them even at their default.
    """

    RULES: ClassVar[tuple[Rule, ...]] = ()
    given: frozenset[str] = frozenset()
    warnings: tuple[str, ...] = field(default=(), init=False, compare=False)

    def __post_init__(self):
        values = settings(self)
        for name, (value, _, meta) in values.items():
            if meta.get("domain") is not None and is_number(value):
                try:
                    meta["domain"].check(value)
                except InputError as err:
                    raise InputError(f"{{opt:{name}}} {err}") from None
            choices = meta.get("choices")
            if choices and value is not None and value not in choices:
                raise InputError(f"{{opt:{name}}} {value!r}: one of "
                                 f"{', '.join(map(str, choices))}")  # fmt: skip
        given = {k for k, (v, d, _) in values.items() if v != d} | set(self.given)
        warned: dict[str, str] = {}
        for rule in self.RULES:
            named = [o for o in rule.options if o in given]
            if not named or rule.holds(self):
                continue
            for option_ in named:
                line = f"{{opt:{option_}}} {rule.says}"
                if not rule.warn:
                    raise OptionRefused(line)
                warned.setdefault(option_, line)
        object.__setattr__(self, "warnings", tuple(warned.values()))

    def implied_writes(self) -> list[tuple[str, str]]:
        """(option, path) of what the job writes where an option is left at its
        default (checked by :func:`check_paths` too)."""
        return []

    @property
    def images(self) -> bool:
        """Whether a source of the job may be images (not only .npy descriptors)."""
        return not all(p.lower().endswith(".npy") for _, p in _paths(self, "frames"))


ROLES = {"map": "the map", "source": "the queries", "sources": "the source",
         "queries": "the queries"}  # fmt: skip
NAMES = ("names",)  # --positions / --ground-truth names: no file


def _paths(job, *how: str) -> list[tuple[str, str]]:
    """(option, path) of every path the job ``how`` (reads, writes; frames: reads
    frames from)."""
    found = []
    for dest, (value, _, meta) in settings(job).items():
        for v in value if isinstance(value, tuple) else [value]:
            if meta.get("path") in how and v is not None and v not in NAMES:
                found.append((dest, str(v)))
    return found


def written(job) -> list[tuple[str, str]]:
    """(option, path) of every file or folder the job was told to write."""
    return _paths(job, "writes")


#: How an output's place is checked before the work (its option's ``output``):
#: ``map``: a map or embedding folder, replaced whole; ``file``: one file in a
#: folder that exists; ``made``: one file, its missing folders made; ``into``:
#: a folder written into and kept (a checkpoint, a report folder; a file there
#: refused); ``kept``: a folder made once
#: and reused when there (its place checked only when it is not); ``place``:
#: a new file or folder, missing folders made.
OUTPUTS = ("map", "file", "made", "into", "kept", "place")


def outputs(job) -> list[tuple[str, str, str]]:
    """(option, path, how its place is checked, :data:`OUTPUTS`) of every
    output of ``job``: those it was told to write, then its implied ones; a
    path its option's ``suffix`` does not end is refused (:class:`InputError`)."""
    found, listed = settings(job), []
    for dest, path in written(job) + job.implied_writes():
        meta = found[dest][2]
        suffix = meta.get("suffix")
        if suffix and not path.lower().endswith(suffix):
            raise InputError(f"{{opt:{dest}}} {path}: give a "
                             f"{' or '.join(suffix)} file name")  # fmt: skip
        listed.append((dest, path, meta.get("output", "place")))
    return listed


def _clash(w: Path, r: Path) -> str | None:
    if w == r:
        return "the same path as"
    if r in w.parents and not r.is_file():  # under a file: no path (said later)
        return "inside"
    if w in r.parents:
        return "holding"
    return None


def check_paths(job) -> str | None:
    """The line refusing a path the job would write over something it reads
    (or writes twice), compared resolved (through links and ``..``), or None:
    no path written may be, hold or lie inside another the job reads or writes."""
    writes, reads = _paths(job, "writes"), _paths(job, "reads", "frames")
    writes += job.implied_writes()
    for i, (dest, path) in enumerate(writes):
        w = Path(path).expanduser().resolve()
        others = [(d, p, "reads") for d, p in reads]
        others += [(d, p, "writes") for d, p in writes[i + 1 :]]
        for other, opath, verb in others:
            how = _clash(w, Path(opath).expanduser().resolve())
            if how is not None:
                flag, oflag = (ROLES.get(d) or "--" + d.replace("_", "-")
                               for d in (dest, other))  # fmt: skip
                return (f"{flag} {path}: {how} {oflag} {opath}, which this job "
                        f"{verb}; give another path")  # fmt: skip
    return None
