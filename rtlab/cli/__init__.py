"""The `rtlab` command line, one module a command group: scene (info, scenes, build, inspect), render,
bench (rtlab.benches' tables), course (lab, grade). Each registers its commands on :data:`app`.

Errors the user can act on (RtlabError, and typer's usage errors: an unknown option, a value out
of range) print one line on stderr and exit with status 2, never a traceback (``main``); rtlab's
warnings (RtlabWarning) print one line "warning: ..." on stderr.
"""
from __future__ import annotations

import sys
import warnings
from typing import Optional

import typer
from rich.markup import escape

from .. import settings
from ..errors import RtlabError, RtlabWarning
from . import bench, bench_paper, course, render, scene  # noqa: F401 (each registers its commands)
from .common import err_console
from .supervise import run_supervised

app = typer.Typer(add_completion=False, no_args_is_help=True,
                  help="rtlab: GPU ray tracing lab (Shih et al. 2009) on CUDA and OpenCL.")
for group in (scene, render, bench, course):       # bench_paper's commands join bench's group
    group.register(app)


@app.callback()
def _options(verbose: bool = typer.Option(False, "--verbose", "-v",
                                          help="show compiler output (build logs, warnings) of every kernel built; "
                                               "$RTLAB_VERBOSE=1 does the same")):
    """rtlab: GPU ray tracing lab (Shih et al. 2009) on CUDA and OpenCL."""
    if verbose:
        settings.setenv("RTLAB_VERBOSE", "1")     # read by rtlab.backends.base.verbose() at each build


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _usage_error_line(e: typer.TyperException) -> str:
    """A typer usage error (unknown option, bad value, missing argument) as one line naming the
    command, instead of typer's boxed usage panel."""
    ctx = getattr(e, "ctx", None)
    command = ctx.command_path if ctx is not None else "rtlab"
    return f"{command}: {_one_line(e.format_message())} (see {command} --help)"


def main(argv: Optional[list[str]] = None) -> int:
    """Run the command line; returns the exit status. Errors the user can act on (usage errors,
    RtlabError, files that cannot be read or written) are one line on stderr and a non-zero
    status, never a traceback; anything else is a bug, reported in one line too unless
    RTLAB_TRACEBACK=1 asks for the traceback."""
    if argv is not None:              # called from Python (tests, scripts): in this process, unsupervised
        return _run(list(argv))
    args = sys.argv[1:]               # the program itself: a student's kernels run in a child (supervise.py)
    return run_supervised(args, lambda: _run(args))


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """rtlab's own warnings (a mesh's zero-area triangles, a missing MTL, a scale float32 cannot
    resolve) as one line on stderr, like its errors; any other warning as Python shows it."""
    if issubclass(category, RtlabWarning):
        err_console.print(f"[yellow]warning:[/] {escape(_one_line(message))}", highlight=False)
    else:
        _python_show_warning(message, category, filename, lineno, file, line)


_python_show_warning = warnings.showwarning


def _run(argv: list[str]) -> int:
    shown, warnings.showwarning = warnings.showwarning, _show_warning
    try:
        status = app(args=argv, prog_name="rtlab", standalone_mode=False)
    except RtlabError as e:
        err_console.print(f"[bold red]rtlab:[/] {escape(str(e))}", highlight=False)
        return 2
    except (typer.Abort, KeyboardInterrupt):
        err_console.print("rtlab: interrupted")
        return 130
    except typer.Exit as e:
        return e.exit_code
    except typer.TyperException as e:    # typer's usage errors (its own click since typer 0.2x)
        if e.format_message().strip():   # (empty after `rtlab` alone: the help is the message)
            print(_usage_error_line(e), file=sys.stderr)
        return getattr(e, "exit_code", 2) or 2
    except OSError as e:                 # a file or folder that cannot be read or written
        where = f" {e.filename}" if e.filename else ""
        err_console.print(f"[bold red]rtlab:[/]{escape(where)}: {escape(e.strerror or str(e))}", highlight=False)
        return 1
    except Exception as e:
        if settings.flag("RTLAB_TRACEBACK"):
            raise
        err_console.print(f"[bold red]rtlab: unexpected error[/] ({escape(type(e).__name__)}: "
                          f"{escape(_one_line(e))}); this is a bug: RTLAB_TRACEBACK=1 shows where", highlight=False)
        return 1
    finally:
        warnings.showwarning = shown
    return status if isinstance(status, int) else 0


if __name__ == "__main__":
    sys.exit(main())
