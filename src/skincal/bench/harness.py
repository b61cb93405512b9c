"""The one harness protocol of every benchmark, and its options declared once for both front ends.

A benchmark is ``options -> config -> jobs -> records -> summary -> report``:

* :class:`Opt` declares one command-line option (name, type, default, help) ONCE; every benchmark's tuple
  of them is in :mod:`skincal.bench.options` (plain data: the ``skincal`` command imports it at start-up).
  :func:`add_arguments` puts them on an ``argparse`` parser (the scripts in ``benchmarks/``),
  :func:`typer_command` registers a ``skincal benchmark ...`` command with the same names, defaults and
  help; both hand the values to the benchmark as one ``dict`` (:func:`values`).
* :class:`Harness`: ``config(values)`` checks the options and builds a frozen config, ``jobs(config)`` the
  picklable jobs (each a pure function's input, so it runs the same in a local pool or on Dask),
  ``run_job(job)`` one typed record, ``summary(config, records)`` the JSON document, ``report(config, doc)``
  what is printed (``run``: the :class:`RunInfo`, wall time and where the jobs ran). :func:`run_harness`
  maps the jobs (:func:`skincal.workflows.sweep.map_jobs`) and summarises, in job order.

A bool option is a switch ``--x/--no-x`` (typer's default for a bool; ``argparse.BooleanOptionalAction``)
unless declared ``switch=False`` (``--x`` alone); ``repeat=True`` collects every occurrence in a list
(``None`` when absent).
"""

from __future__ import annotations

import argparse
import inspect
import time
import types
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

Config = TypeVar("Config")
Job = TypeVar("Job")
Record = TypeVar("Record")


@dataclass(frozen=True)
class Opt:
    """One option of a benchmark, declared once (module docstring).

    Attributes:
        name: the Python name (the key in :func:`values`), e.g. ``json_out``.
        type: ``int``, ``float``, ``str``, ``Path`` or ``bool``, optionally ``| None``.
        default: the value when absent.
        help: the help text.
        flag: the command-line name (default ``--`` and ``name`` with ``-`` for ``_``).
        switch: a bool as ``--x/--no-x`` (True) or ``--x`` alone (False).
        repeat: may be given several times, the values collected in a list.
        many: takes one or more values after the flag (``--seeds 0 1 2``), a list.
        choices: the allowed values (argparse checks them; typer shows them in the help).
        positional: a required argument without a flag (``skincal benchmark realdata DIR``).
        aliases: older command-line names still accepted (``--runs`` of ``--placements``), shown in the help.
    """

    name: str
    type: Any
    default: Any
    help: str | None = None
    flag: str | None = None
    switch: bool = True
    repeat: bool = False
    many: bool = False
    choices: tuple[Any, ...] | None = None
    positional: bool = False
    aliases: tuple[str, ...] = ()

    @property
    def cli_flag(self) -> str:
        """The option's command-line name, ``--runs``."""
        return self.flag or "--" + self.name.replace("_", "-")

    @property
    def base_type(self) -> Any:
        """``type`` without ``| None``."""
        args = [a for a in typing.get_args(self.type) if a is not type(None)]
        is_union = isinstance(self.type, types.UnionType) or typing.get_origin(self.type) is typing.Union
        return args[0] if is_union and len(args) == 1 else self.type


FORCE = Opt("force", bool, False, "overwrite the --json file if it exists", switch=False)
"""``--force`` of the ``skincal benchmark`` commands that write ``--json``."""
WORKERS = Opt("workers", int, 1, "local worker processes (ignored with --dask)")
DASK = Opt("dask", str | None, None, "address of an existing dask.distributed scheduler")


def add_arguments(parser: argparse.ArgumentParser, options: Sequence[Opt]) -> argparse.ArgumentParser:
    """Put ``options`` on ``parser`` (the scripts in ``benchmarks/``); returns ``parser``."""
    for o in options:
        if o.positional:
            parser.add_argument(o.name, type=o.base_type if o.base_type in (int, float, Path) else None, help=o.help)
            continue
        kw: dict[str, Any] = {"dest": o.name, "default": o.default, "help": o.help}
        base = o.base_type
        if base is bool:
            kw["action"] = argparse.BooleanOptionalAction if o.switch else "store_true"
        else:
            if o.repeat:
                kw["action"] = "append"
            if o.many:
                kw["nargs"] = "+"
            if base in (int, float, Path):
                kw["type"] = base
            if o.choices:
                kw["choices"] = list(o.choices)
        parser.add_argument(o.cli_flag, *o.aliases, **kw)
    return parser


def parse_args(
    description: str, options: Sequence[Opt], argv: Sequence[str] | None = None
) -> argparse.Namespace:
    """Parse ``argv`` (default ``sys.argv[1:]``) with ``options`` (a script's ``main``)."""
    return add_arguments(argparse.ArgumentParser(description=description), options).parse_args(argv)


def values(args: argparse.Namespace, options: Sequence[Opt]) -> dict[str, Any]:
    """The parsed ``options`` of ``args`` as ``{name: value}``, the form :func:`typer_command` passes too."""
    return {o.name: getattr(args, o.name) for o in options}


def parse(description: str, options: Sequence[Opt], argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Parse ``argv`` (default ``sys.argv[1:]``) with ``options``: the values of :func:`values`."""
    return values(parse_args(description, options, argv), options)


def _typer_parameter(o: Opt) -> inspect.Parameter:
    import typer

    if o.base_type is bool:
        flag = o.cli_flag
        decl = f"{flag}/--no-{flag[2:]}" if o.switch else flag
    else:
        decl = o.cli_flag
    values_of = types.GenericAlias(list, (o.base_type,))  # list[the option's type]
    annotation = values_of | None if o.repeat else values_of if o.many else o.type
    help_text = o.help
    if o.choices and help_text is not None and not all(str(c) in help_text for c in o.choices):
        help_text = f"{help_text} ({', '.join(o.choices)})"
    if o.positional:
        default = typer.Argument(..., help=help_text)
    else:
        default = typer.Option(o.default, decl, *o.aliases, help=help_text)
    return inspect.Parameter(o.name, inspect.Parameter.KEYWORD_ONLY, default=default, annotation=annotation)


def typer_command(app: Any, name: str, options: Sequence[Opt], body: Callable[[dict[str, Any]], None]) -> None:
    """Register ``skincal <app> name`` on the typer ``app`` with ``options``; ``body(values)`` runs it (its
    docstring is the command's help)."""
    params = [_typer_parameter(o) for o in options]

    def command(**kwargs: Any) -> None:
        body(kwargs)

    command.__signature__ = inspect.Signature(params)  # type: ignore[attr-defined]
    command.__annotations__ = {p.name: p.annotation for p in params} | {"return": None}
    command.__doc__ = body.__doc__
    command.__name__ = body.__name__
    app.command(name)(command)


@dataclass(frozen=True)
class RunInfo:
    """How a harness run went: its wall time (s) and where its jobs ran (``workers`` local processes or
    the Dask scheduler ``dask``)."""

    wall_time_s: float
    workers: int = 1
    dask: str | None = None


class Harness(Protocol[Config, Job, Record]):
    """The protocol every benchmark follows (module docstring)."""

    options: tuple[Opt, ...]

    def config(self, values: Mapping[str, Any]) -> Config: ...

    def jobs(self, config: Config) -> Sequence[Job]: ...

    def run_job(self, job: Job) -> Record: ...

    def summary(self, config: Config, records: list[Record], run: RunInfo) -> dict[str, Any]: ...

    def report(self, config: Config, doc: Mapping[str, Any], run: RunInfo) -> list[Any]: ...


def run_harness(
    harness: Harness[Config, Job, Record],
    config: Config,
    *,
    workers: int = 1,
    dask: str | None = None,
    progress: Callable[[Record], None] | None = None,
) -> tuple[dict[str, Any], RunInfo]:
    """Every job of ``config`` run (``workers`` local processes, or the Dask scheduler at ``dask``; a
    picklable ``run_job``), its records in job order, and ``(summary document, RunInfo)``."""
    from skincal.errors import ConfigError
    from skincal.workflows.sweep import map_jobs

    if workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    start = time.perf_counter()
    records = map_jobs(harness.run_job, harness.jobs(config), workers=workers, dask=dask, progress=progress)
    info = RunInfo(time.perf_counter() - start, workers, dask)
    return harness.summary(config, records, info), info
