"""The ``groundstation`` script's entry: the arguments are read (:mod:`.parser`, which imports
nothing numerical), and only then the command's code. ``groundstation --help`` and a usage error
answer before numpy, scipy, filterpy or viser are loaded (they had made every one-line error wait
for 4 s of imports); so does a file that is missing or is no log, checked here by its first bytes,
a file another argument names that is not there, a connection string that names no transport, a
vehicle command short of what it needs, and a simulator's scenario it cannot fly (with numpy alone
loaded: the effects are built to be checked).
"""

from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path

from drivers.connection import ConnectionStringError, parse_connection  # pure parsing: nothing numerical
from groundstation.estimation.vehicles import vehicle_file  # a JSON file read: nothing numerical
from web.authority import remote_refusal  # an address's check: nothing numerical

from .interrupts import is_interrupt
from .parser import build_parser, command_usage_problem

#: the commands that read a log file given as ``file``
READS_A_LOG = frozenset({"replay", "info", "noise", "evaluate", "diagnose", "triage"})
#: a log's first bytes, by format: a DataFlash record header, a ULog magic, a Crazyflie uSD log's
#: magic; a tlog begins with a big-endian UNIX time [us] (its first byte 0x00 until 2106)
MAGIC = (b"\xa3\x95", b"ULog\x01\x12\x35", b"\xbc")
#: the commands that need no dashboard -> the module that runs them and its function: that module is
#: loaded alone (the whole command line loads viser and the control station as well: 0.2-0.26 s more
#: after ``diagnose``'s own imports). A module's ``ONE_LINE_ERRORS`` are its errors beside ValueError
#: and OSError
ALONE = {
    "triage": ("groundstation.app.triage_cli", "cmd_triage"),
    "info": ("groundstation.app.info_cli", "cmd_info"),
    "sim": ("groundstation.app.sim_cli", "cmd_sim"),
    "param": ("groundstation.app.param_cli", "cmd_param"),
    "logs": ("groundstation.app.logs_cli", "cmd_logs"),
    "command": ("groundstation.app.command_cli", "cmd_command"),
    "diagnose": ("groundstation.app.diagnose_cli", "cmd_diagnose"),
    "fleet": ("groundstation.app.fleet_cli", "cmd_fleet"),
    "evaluate": ("groundstation.app.evaluate_cli", "cmd_evaluate"),
    "noise": ("groundstation.app.evaluate_cli", "cmd_noise"),
}
#: of those, the commands that need no filter either: filterpy loads scipy.stats, 2 s before a
#: vehicle's parameters are asked for or a simulated vehicle speaks, a third of a second without it
NO_FILTER = frozenset({"triage", "info", "sim", "param", "logs", "command"})
#: the commands that talk to a vehicle -> the argument holding its connection string
CONNECTS = {"connect": "url", "param": "connection", "logs": "connection", "command": "connection"}


def problem_with(path: Path) -> str | None:
    """Why ``path`` cannot be a log (one line), read from its first bytes; None: it may be one."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except IsADirectoryError:
        return f"{path}: is a folder, not a log"
    except OSError as e:
        return f"{path}: cannot read: {e.strerror or e}"
    if not head:
        return f"{path}: empty: not a MAVLink tlog, nor any log"
    text_dataflash = b"FMT," in head  # a text DataFlash log: FMT lines near the top
    if head.startswith(MAGIC) or head[0] == 0x00 or text_dataflash:
        return None
    return f"{path}: not a MAVLink tlog, nor an ArduPilot DataFlash, PX4 ULog or Crazyflie log (by its first bytes)"


def argument_problem(args) -> str | None:
    """Why the arguments cannot be run (one line), or None: a file or folder an argument names that
    cannot be read (the truth a diagnosis is scored against, the effects it is told of, the archive a
    fleet reads, the parameter file loaded onto a vehicle), a connection string that names no
    transport, a vehicle command short of what it needs, a dashboard asked for on a network address
    without ``--allow-remote`` (before a recording is begun). A truth file that is not there had been
    passed over in silence, and the diagnosis ran for minutes without the error it was asked for. A
    vehicle file that is not there, or a name no airframe file has, is said before the log is read:
    a log no model describes (a submarine's) is reported on without one, and would pass it unseen."""
    if args.command in CONNECTS:
        try:
            parse_connection(getattr(args, CONNECTS[args.command]))
        except ConnectionStringError as e:
            return str(e)
    if args.command == "command":
        return command_usage_problem(args)
    named: list[tuple[Path | None, str]] = []
    if args.command in ("diagnose", "evaluate"):
        named.append((getattr(args, "truth", None), "no such truth file"))
    if args.command == "diagnose":
        named.append((args.declared, "no such file of declared effects"))
    if args.command == "param" and args.param_command == "load":
        named.append((args.file, "cannot read: no such file"))
    for path, why in named:
        if path is not None and not path.is_file():
            return f"{path}: {why}"
    if args.command == "fleet" and not args.archive.is_dir():
        return f"{args.archive}: not a folder"
    refusal = remote_refusal(args.host, args.allow_remote) if hasattr(args, "allow_remote") else None
    if refusal is not None and not args.no_web:
        return refusal
    vehicle = getattr(args, "vehicle", None)  # an airframe's file; sim's and demo's name a simulated vehicle
    if args.command not in ("sim", "demo") and isinstance(vehicle, str) and vehicle:
        try:
            vehicle_file(vehicle)
        except ValueError as e:
            return str(e)
    return None


#: BLAS's own threads, one (unless the user's environment says otherwise): the estimators' matrices
#: are a few states wide, where OpenBLAS's worker threads only spin: a diagnosis of
#: ``underpowered.log`` takes the same 71 s with one thread as with two, and half the processor time
#: (a second core's worth that parallel work, a dashboard or a test runner beside it then lacks)
ONE_BLAS_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def main(argv: list[str] | None = None) -> int:
    """The command line; Ctrl-C at any point of it, the imports a command loads included, is exit
    status 130 without a traceback."""
    try:
        return _main(argv)
    except (KeyboardInterrupt, SystemError) as e:
        if not is_interrupt(e):
            raise
        return 130


def _main(argv: list[str] | None) -> int:
    for name, value in ONE_BLAS_THREAD.items():  # before numpy is loaded: the count is read once
        os.environ.setdefault(name, value)
    args = build_parser().parse_args(argv)
    if args.command in READS_A_LOG and getattr(args, "file", None) is not None:
        why = problem_with(args.file)
        if why is not None:
            print(f"groundstation: error: {why}", file=sys.stderr)
            return 2
    why = argument_problem(args)
    if why is not None:
        print(f"groundstation: error: {why}", file=sys.stderr)
        return 2
    if args.command == "sim":  # the scenario and the simulator's options, before the simulator loads
        sim_args = importlib.import_module("groundstation.app.sim_args")
        if args.list_effects:
            print(sim_args.catalogue_markdown())
            return 0
        why = sim_args.problem(args)
        if why is not None:
            print(f"groundstation: error: {why}", file=sys.stderr)
            return 2
    if args.command in ALONE:
        module, name = ALONE[args.command]
        m = importlib.import_module(module)
        return one_line_errors(getattr(m, name), args, getattr(m, "ONE_LINE_ERRORS", ()))
    cli = importlib.import_module("groundstation.app.cli")  # the commands, loaded once they are asked for
    return cli.run(args)


def one_line_errors(command, args, also: tuple[type[Exception], ...] = ()) -> int:
    """``command(args)``, its errors a user can cause (every reader's is a ValueError or an
    OSError, and those of ``also``: a vehicle's refusals) as one line and exit status 2."""
    errors: tuple[type[Exception], ...] = (ValueError, OSError, *also)
    try:
        return command(args)
    except BrokenPipeError:  # output piped into `head` and closed: not an error
        sys.stdout = open(os.devnull, "w")
        return 0
    except errors as e:
        print(f"groundstation: error: {e}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemError) as e:
        if not is_interrupt(e):
            raise
        return 130


if __name__ == "__main__":
    sys.exit(main())
