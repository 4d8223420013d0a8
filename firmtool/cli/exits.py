"""How a command ends: library exceptions as one-line messages and exit codes, never a traceback.

Exit codes: 0 success, 1 a run that failed on its own terms (unreachable goal, numerical failure,
disk full), 2 bad input (scenario, roadmap file, option or output path), 130 interrupted (Ctrl-C).
Errors are one line on stderr; that includes usage errors (a bad option value, an unknown command,
a missing argument), which click would print as a multi-line panel (:class:`OneLineErrors`).
"""

from __future__ import annotations

import functools
import os
import sys
from typing import Any, Callable, NoReturn

import typer
from threadpoolctl import threadpool_limits
from typer.core import TyperGroup

from firmtool import progress
from firmtool.cli import console
from firmtool.errors import MAX_EXPECTED, FirmtoolError, InputError, NumericalError, RunFailure, ScenarioError, cut
from firmtool.io.atomic import write_failure
from firmtool.util import interrupts

# The click that typer's commands raise from: recent typer vendors its own copy as typer._click,
# whose exceptions are not the click package's; older typer uses the click package (typer.core.click),
# which firmtool does not import itself (it is typer's dependency, not firmtool's).
click: Any = getattr(typer, "_click", None) or typer.core.click
_NoArgsIsHelp: type = getattr(click.exceptions, "NoArgsIsHelpError", ())  # click >= 8.2


class OneLineErrors(TyperGroup):
    """The command group: usage errors in one line (``error: ...``, exit 2) instead of click's panel."""

    def main(self, args: Any = None, prog_name: str | None = None, complete_var: str | None = None,
             standalone_mode: bool = True, **extra: Any) -> Any:
        try:
            rv = super().main(args=args, prog_name=prog_name, complete_var=complete_var, standalone_mode=False,
                              **extra)
            code = rv if isinstance(rv, int) and not isinstance(rv, bool) else 0
        except _NoArgsIsHelp as exc:  # 'firmtool' alone: the help (typer's rich help printed itself already)
            text = exc.format_message()
            if text.strip():
                typer.echo(text)
            code = 0
        except click.exceptions.UsageError as exc:
            where = f"{exc.ctx.command_path}: " if exc.ctx is not None else ""
            hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
            typer.echo(f"error: {where}{cut(_one_line(exc.format_message()), MAX_EXPECTED)}{hint}", err=True)
            code = 2
        except click.exceptions.ClickException as exc:
            typer.echo(f"error: {cut(_one_line(exc.format_message()), MAX_EXPECTED)}", err=True)
            code = exc.exit_code
        except (typer.Abort, KeyboardInterrupt):
            typer.echo("error: interrupted", err=True)
            code = interrupts.INTERRUPTED_EXIT
        if standalone_mode:
            sys.exit(code)
        return code


def _one_line(text: str) -> str:
    return " ".join(text.split())


def fail(message: str, code: int) -> NoReturn:
    """End the command: ``error: MESSAGE`` on stderr, exit ``code``."""
    console.close_progress()
    typer.echo(f"error: {message}", err=True)
    raise typer.Exit(code)


def fail_scenario(exc: ScenarioError) -> NoReturn:
    """Every mistake of a scenario file, one line each (``error: FILE: FIELD: expected``), exit 2."""
    console.close_progress()
    for field, expected in exc.errors:
        path, expected = cut(exc.path), cut(expected, MAX_EXPECTED)  # a user's key or value: at most 200 characters
        typer.echo(f"error: {path}: {cut(field)}: {expected}" if field else f"error: {path}: {expected}", err=True)
    raise typer.Exit(2)


# What a cold compile of the engine took, measured on the 2-core machines firmtool is tested on
# (benchmarks/README.md: the kernel's cold compile ~25 s CPU, bench_kernel_compile.py; arm7_shelf's cold
# build 56 s of which ~45 s compiling on a quiet machine, ~3 min under a busy one's load; issue 54)
COMPILE_SECONDS = {"planar": "20-60 s", "3-D": "45 s-3 min"}


def _say_compiling(kind: str = "planar") -> None:
    typer.echo(f"firmtool: compiling the Monte Carlo engine, once per install, for a {kind} robot "
               f"({COMPILE_SECONDS.get(kind, COMPILE_SECONDS['3-D'])} on 2 cores, measured; longer on a busy "
               f"machine; later runs load it)", err=True)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0][:300] if text else type(exc).__name__


def handles_errors(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Map library exceptions to one-line messages and exit codes."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        console.configure(quiet=bool(kwargs.get("quiet", False)), json=bool(kwargs.get("as_json", False)))
        try:
            return _run(fn, args, kwargs)
        except ScenarioError as exc:
            fail_scenario(exc)
        except InputError as exc:
            fail(str(exc), 2)
        except KeyboardInterrupt as exc:
            if isinstance(exc, FirmtoolError):  # the stage saved what it had (EstimationInterrupted)
                fail(str(exc), 130)
            fail("interrupted; the roadmap file is unchanged by the stage that was running", 130)
        except (RunFailure, NumericalError) as exc:
            fail(str(exc), 1)
        except FirmtoolError as exc:  # pragma: no cover - every subclass is mapped above
            fail(str(exc), 1)
        except (typer.Exit, typer.Abort, click.exceptions.ClickException):
            raise
        except OSError as exc:
            if os.environ.get("FIRMTOOL_DEBUG") or not exc.filename:
                raise
            # a file the user named that cannot be read or written (permissions, disk full, ...)
            failure = write_failure(exc.filename, exc)
            fail(str(failure), 1 if isinstance(failure, RunFailure) else 2)
        except MemoryError:
            fail("out of memory; lower roadmap.nodes, estimation.particles or estimation.chunk", 1)
        except RecursionError:
            fail("input nested too deeply to process (a bug in firmtool if it came from a checked file)", 1)
        except Exception as exc:
            if os.environ.get("FIRMTOOL_DEBUG"):
                raise
            fail(f"unexpected error (a bug in firmtool; rerun with FIRMTOOL_DEBUG=1 for the traceback): "
                 f"{type(exc).__name__}: {_first_line(exc)}", 1)
        finally:
            console.close_progress()

    return wrapper


def _run(fn: Callable[..., Any], args: tuple, kwargs: dict) -> Any:
    """Run a command with one BLAS thread, and a notice on stderr when the engine compiles."""
    # lazy: saves firmtool --help and a usage error, which need neither, scipy.linalg's import (0.22 s)
    import scipy.linalg  # noqa: F401  (loads scipy's own BLAS, so that the limit below covers it)

    # a background compile on a cold cache says so on stderr; set where the warm-up module reads it,
    # without importing that module (numba, 1.3 s), which check, inspect and solve never need
    progress.set_compile_notifier(_say_compiling)
    # firmtool's linear algebra is many small matrices: threaded BLAS only adds contention
    with threadpool_limits(limits=1):
        return fn(*args, **kwargs)
