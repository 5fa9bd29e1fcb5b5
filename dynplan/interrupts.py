"""What an interrupt does while a `python -m dynplan…` or `python -m flows…` command is still loading its modules:
"interrupted" and exit status 130, not a traceback of the import machinery. Installed by the first line of each
package, before anything else loads (this module imports only what the interpreter has loaded already), so the
window left is the interpreter's own start-up; `dynplan.cli.run_command` takes over once the command runs."""

from __future__ import annotations

import os
import signal
import sys


def _program() -> str:
    """How the running command was started, e.g. "python -m flows.collect"."""
    argv = getattr(sys, "orig_argv", sys.argv)
    return f"python -m {argv[argv.index('-m') + 1]}" if "-m" in argv[:-1] else os.path.basename(sys.argv[0])


def interrupted_while_loading(signum: int, frame: object) -> None:
    print(f"{_program()}: interrupted", file=sys.stderr, flush=True)
    os._exit(130)  # nothing is written while a command loads its modules


def interrupt_while_loading() -> None:
    """Under `python -m`, an interrupt while the command's modules load is "interrupted" and exit status 130, not a
    traceback of the import machinery. `run_command` installs the command's own handler when the command starts."""
    argv = getattr(sys, "orig_argv", [])
    target = argv[argv.index("-m") + 1] if "-m" in argv[:-1] else ""
    ours = target.split(".")[0] in ("dynplan", "flows")
    if sys.argv[:1] == ["-m"] and ours and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, interrupted_while_loading)
