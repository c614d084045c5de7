"""An option declared once: a field of a job's frozen dataclass, with metadata.

A field is an option when its metadata holds ``help`` (:func:`option`; None: one
a job offers only where it words it, by its part's ``helps``; :func:`like`: one
declared by another job). Its default is
the field's (none: a positional, or a ``required`` option); one of False is a
flag. The metadata holds what ``add_argument`` takes (:data:`ARGPARSE`) and:
``domain``, the :class:`rhythmic_jax.validate.Domain` a number is parsed with,
stated in ``--help`` and checked when a job is made; ``dest``, the option's name
where it is not the field's; ``positional``; ``path``: what the job does with
it (``reads``, ``writes``, ``frames``: reads frames from it;
:func:`rhythmic_jax.app.specs.check_paths`). A field holding a part of the
settings (:func:`part`) offers the part's options, titled ``group`` in ``--help``
and made into its value by ``make`` (default: the part's class).

A command's parser is rendered from its job's class (:func:`add_options`) and
the job made from what it parsed (:func:`make`). Imports no numpy, JAX or torch.
"""

from __future__ import annotations

import argparse
from dataclasses import MISSING, Field, field, fields
from typing import Any

__all__ = ["add_options", "like", "make", "option", "options", "part", "settings"]

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


def add_options(parser: argparse.ArgumentParser, cls: type) -> None:
    """Each option of ``cls`` added to ``parser``; a declared default (not None,
    False or '') stated in its help unless the help says it, and a domain too."""
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
            stated = default is not None and default is not False and default != ""
            if stated and default is not MISSING and "default" not in help_:
                help_ += " (default %(default)s)"
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
