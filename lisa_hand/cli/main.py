"""The ``lisa`` command line: thin verbs over the library. The only module that imports typer."""

from __future__ import annotations

import os
import sys

import typer

from ..training.distributed import end_process, group_was_created
from . import (
    animate,
    blend,
    demo,
    evaluate,
    fit_images,
    fit_photo,
    fit_points,
    fit_video,
    import_data,
    mesh,
    metrics,
    render,
    synth,
    train,
    view,
)

app = typer.Typer(
    name="lisa",
    help=(
        "LISA-open: train, fit, mesh, render and animate neural implicit hands "
        "(LISA, CVPR 2022). Run 'lisa COMMAND --help' for each command."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Plain click help: docstrings are re-wrapped to the terminal instead of keeping their
    # source line breaks.
    rich_markup_mode=None,
)

@app.callback()
def _root() -> None:
    """LISA-open command line."""


# Each verb lives in its own module with a ``register(app)`` function.
for _module in (demo, synth, train, fit_points, fit_images, fit_photo, fit_video, mesh, render,
                animate, blend, metrics, evaluate, view, import_data):
    _module.register(app)


class UserError(Exception):
    """An error caused by the user's input: printed as one line, no traceback."""


def error_line(exc: BaseException) -> str:
    """The one line ``lisa: error: ...`` prints for ``exc``.

    An OSError raised by the system (``[Errno 21] Is a directory: 'x'``) becomes ``x: Is a
    directory``; a message of several lines is joined into one.
    """
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        message = f"{exc.filename}: {exc.strerror}"
        if exc.filename2 is not None:
            message += f" (-> {exc.filename2})"
    else:
        message = str(exc) or type(exc).__name__
    return "; ".join(line.strip() for line in message.splitlines() if line.strip())


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``lisa`` console script.

    Errors from bad input (``ValueError``, ``TypeError``, ``OSError``) print one line naming the
    problem (:func:`error_line`) and exit with status 2; set ``LISA_DEBUG=1`` to see the
    traceback instead.
    """
    try:
        try:
            app(args=argv)
        except (ValueError, TypeError, OSError, UserError) as exc:
            if os.environ.get("LISA_DEBUG"):
                raise
            print(f"lisa: error: {error_line(exc)}", file=sys.stderr)
            raise SystemExit(2) from None
    except SystemExit as done:
        if group_was_created():  # a torchrun worker: end without the interpreter's teardown
            end_process(_exit_status(done.code))
        raise


def _exit_status(code: object) -> int:
    """The process status ``SystemExit(code)`` gives: None 0, an int itself, else 1 (printed)."""
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    print(code, file=sys.stderr)
    return 1


if __name__ == "__main__":
    main()
