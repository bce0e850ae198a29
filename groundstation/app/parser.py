"""The ``groundstation`` command line's arguments, every command's, and nothing else: parsing them,
and ``--help`` and a usage error, import nothing numerical (the commands themselves, in
:mod:`.cli` and its siblings, are imported once the arguments are read: :mod:`.main`). The choices
come from the light modules that hold the names: the models (:mod:`groundstation.estimation.
model_names`, :mod:`groundstation.diagnosis.model_names`) and the simulator's (:mod:`sim_bridge.names`).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from drivers.speed import check_speed
from groundstation.core.cores import available_cores
from groundstation.diagnosis.model_names import MODEL_HELP, RIG_MODEL_HELP
from groundstation.estimation.model_names import CLI_MODELS
from sim_bridge.names import FLIGHTS, UNASKED_RATE, VEHICLES

DESCRIPTION = "groundstation: a hardware-in-the-loop ground station for small rotorcraft"


def add_web_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--no-web", action="store_true", help="headless: no dashboard")
    p.add_argument(
        "--host", default="127.0.0.1", help="dashboard address (default 127.0.0.1; another needs --allow-remote)"
    )
    p.add_argument("--port", type=int, default=8080, help="dashboard port (a free one if taken)")
    p.add_argument(
        "--allow-remote",
        action="store_true",
        help="serve the dashboard on a network address (--host): viewable from the network, "
        "control only with the session's token",
    )


def add_signing_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--signing",
        metavar="KEY",
        help="MAVLink 2 signing, required both ways: a key file (32 bytes or 64 hex digits) or a passphrase "
        "(SHA-256 of it, as MAVProxy's 'signing setup' makes the key)",
    )


def add_diagnose_parser(sub) -> None:
    d = sub.add_parser("diagnose", help="find the effects the model lacks, add them, report before/after")
    d.add_argument("file", type=Path)
    d.add_argument(
        "--model",
        default="auto",
        choices=("auto", *MODEL_HELP, *RIG_MODEL_HELP),
        help="; ".join(f"{name}: {text}" for name, text in {**MODEL_HELP, **RIG_MODEL_HELP}.items())
        + " (default auto: the one the vehicle and the log's readings allow, the altitude model first; "
        "with a throttle and a battery voltage, thrust lost with the battery is traced beside it)",
    )
    d.add_argument("--out", type=Path, help="report directory (default: LOG.diagnosis/)")
    d.add_argument("--declared", type=Path, help="effects the model is told of (default: LOG.declared.json)")
    d.add_argument(
        "--vehicle",
        help="vehicle parameter file for the noise (its known effects are NOT applied: finding them is the point)",
    )
    d.add_argument(
        "--truth",
        type=Path,
        help="truth CSV (t, h) for the error before/after (default: LOG.csv "
        "when it is a simulator sidecar; motion capture in the log is used)",
    )
    d.add_argument(
        "--no-truth-veto",
        action="store_true",
        help="keep an effect even when its fix makes the error against truth worse (default: rejected)",
    )
    d.add_argument(
        "--jobs",
        type=positive_int,
        default=available_cores(),
        help="processes the candidates' filter runs are spread over (default: every core, here "
        f"{available_cores()}; the findings do not depend on it)",
    )


def positive_int(text: str) -> int:
    """A count of 1 or more, for argparse (its one-line error otherwise)."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number of 1 or more, got {text!r}")
    return n


def positive_seconds(text: str) -> float:
    """A length of time above 0 [s], for argparse (its one-line error otherwise: a negative or NaN
    duration had run a simulation of nothing and written an empty log)."""
    try:
        x = float(text)
    except ValueError:
        x = math.nan
    if not (x > 0.0 and math.isfinite(x)):
        raise argparse.ArgumentTypeError(f"expected seconds above 0, got {text!r}")
    return x


def add_triage_parser(sub) -> None:
    t = sub.add_parser(
        "triage", help="what the log says happened (crash, failsafes, vibration, motors, EKF), in seconds"
    )
    t.add_argument("file", type=Path)
    t.add_argument("--json", action="store_true", help="the findings as JSON on stdout")


def add_fleet_parser(sub) -> None:
    f = sub.add_parser("fleet", help="diagnose every log of an archive on Dask; what recurs across flights")
    fsub = f.add_subparsers(dest="fleet_command", required=True)
    d = fsub.add_parser("diagnose", help="every log under ARCHIVE_DIR, resumable, one table and a fleet report")
    d.add_argument("archive", type=Path)
    d.add_argument("--out", type=Path, required=True, help="the fleet's folder: a report folder per log, the table")
    d.add_argument(
        "--model",
        default="auto",
        choices=("auto", *MODEL_HELP, *RIG_MODEL_HELP),
        help="as diagnose's (default auto: by each log)",
    )
    d.add_argument("--scheduler", help="an existing Dask scheduler, tcp://HOST:PORT (default: a local cluster)")
    d.add_argument("--workers", type=int, help="local worker processes (default: the machine's cores)")


def _vehicle_parser(sub, name: str, help: str):
    """A command that talks to one vehicle: its connection, ``--sysid`` and the signing key."""
    p = sub.add_parser(name, help=help)
    p.add_argument("connection", help="as for connect: udpin:0.0.0.0:14550, tcp:HOST:PORT, /dev/ttyUSB0,57600")
    p.add_argument("--sysid", type=int, help="the vehicle's system id (default: the first one heard)")
    add_signing_option(p)
    return p


def add_param_parser(sub) -> None:
    p = _vehicle_parser(sub, "param", "a vehicle's parameters: fetch all (to a file), get, set with verification, load")
    a = p.add_subparsers(dest="param_command", required=True)
    f = a.add_parser("fetch", help="every parameter; printed, or written to --out")
    f.add_argument("--out", type=Path, help="write them here (MAVProxy's format; --qgc for QGroundControl's)")
    f.add_argument("--qgc", action="store_true")
    g = a.add_parser("get", help="read parameters by name")
    g.add_argument("names", nargs="+")
    s = a.add_parser("set", help="set one and verify the vehicle's echo")
    s.add_argument("name")
    s.add_argument("value", type=float)
    ld = a.add_parser("load", help="set every parameter of a file (MAVProxy, QGroundControl or Mission Planner format)")
    ld.add_argument("file", type=Path)


def add_logs_parser(sub) -> None:
    p = _vehicle_parser(sub, "logs", "a vehicle's onboard logs over MAVLink: list, download N, latest, erase")
    a = p.add_subparsers(dest="logs_command", required=True)
    a.add_parser("list", help="the logs on the vehicle: number, time, size")
    d = a.add_parser("download", help="download log N (lost packets asked for again)")
    d.add_argument("number", type=int)
    d.add_argument("--out", type=Path, help="write it here (default: logN-DATE-TIME.bin)")
    la = a.add_parser("latest", help="download the last log (the last flight)")
    la.add_argument("--out", type=Path, help="write it here (default: logN-DATE-TIME.bin)")
    e = a.add_parser("erase", help="remove every log on the vehicle")
    e.add_argument("--yes", action="store_true", help="confirm")


def add_command_parser(sub) -> None:
    c = sub.add_parser("command", help="arm, disarm, mode NAME, takeoff ALT, land: each with the vehicle's ACK")
    c.add_argument("connection", help="as for connect: udpin:0.0.0.0:14550, tcp:HOST:PORT, /dev/ttyUSB0,57600")
    c.add_argument("what", choices=("arm", "disarm", "mode", "takeoff", "land"))
    c.add_argument("arg", nargs="?", help="the mode's name (mode), the altitude in metres (takeoff)")
    c.add_argument("--sysid", type=int, help="the vehicle's system id (default: the first one heard)")
    c.add_argument("--yes", action="store_true", help="confirm a command that starts the motors (arm, takeoff)")
    add_signing_option(c)


#: ``command``'s commands that start the motors: only with --yes
STARTS_MOTORS = frozenset({"arm", "takeoff"})


def command_usage_problem(args) -> str | None:
    """Why ``command``'s arguments cannot be run (one line), or None: read before anything is loaded."""
    if args.what in STARTS_MOTORS and not args.yes:
        return f"{args.what} starts the motors: add --yes to confirm"
    if args.what in ("mode", "takeoff") and args.arg is None:
        return f"{args.what} needs {'a mode name' if args.what == 'mode' else 'an altitude [m]'}"
    if args.what == "takeoff":
        try:
            float(args.arg)
        except ValueError:
            return f"takeoff {args.arg!r}: an altitude in metres"
    return None


def add_sim_parser(sub) -> None:
    s = sub.add_parser("sim", help="run a simulated vehicle (real time on UDP/serial, or --fast into a tlog)")
    s.add_argument("--vehicle", choices=VEHICLES, default="quad")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument(
        "--flight",
        choices=FLIGHTS,
        default="standard",
        help="the built-in flight: standard; thrust_test (a low hover in ground effect and "
        "throttle steps instead of the altitude sine); or high (a climb to 5-8 m, above the "
        "range sensor's 4 m, where the barometer alone carries the height); or guided (on the ground "
        "until armed and commanded: take-off, land, GUIDED and AUTO with a mission, as ArduCopter SITL)",
    )
    s.add_argument("--scenario", type=Path, help="JSON scenario file (see sim_bridge/scenario.py)")
    s.add_argument(
        "--effect",
        action="append",
        default=[],
        metavar="NAME:k=v,...",
        help="a declared effect (the ground station may be told); repeatable",
    )
    s.add_argument(
        "--undeclared",
        action="append",
        default=[],
        metavar="NAME:k=v,...",
        help="an effect that acts but is told to nobody; repeatable",
    )
    s.add_argument(
        "--duration",
        type=positive_seconds,
        help="seconds of simulated time (default: run until stopped; 60 with --fast)",
    )
    s.add_argument(
        "--udp",
        default="127.0.0.1:14550",
        metavar="HOST:PORT",
        help="send MAVLink to the ground station here (default 127.0.0.1:14550); 'none' for no UDP",
    )
    s.add_argument("--serial", action="store_true", help="also speak MAVLink on a pseudo-terminal (path printed)")
    s.add_argument("--serial-link", type=Path, help="keep a stable symlink to the pty here (like /dev/serial/by-id)")
    s.add_argument(
        "--board",
        action="store_true",
        help="a sensor board on its own pty: binary frames (heli3dof) or NMEA GPS (quad, coax)",
    )
    s.add_argument("--sysid", type=int, default=1, help="the vehicle's MAVLink system id (1-255; default 1)")
    s.add_argument(
        "--unasked-rate",
        type=float,
        default=UNASKED_RATE,
        metavar="HZ",
        help=f"each stream's rate until a ground station asks for it (default {UNASKED_RATE:g}, as an "
        "autopilot's default stream rates; 0: every stream at its sensor's rate from the start)",
    )
    add_signing_option(s)
    s.add_argument("--loss", type=float, default=0.0, help="frame loss [%%]")
    s.add_argument("--corrupt", type=float, default=0.0, help="frames with a flipped bit [%%]")
    s.add_argument("--speed", type=float, default=1.0, help="times real time (real-time mode)")
    s.add_argument("--fast", action="store_true", help="as fast as possible into --log (no transport)")
    s.add_argument(
        "--log",
        type=Path,
        help="with --fast: the tlog to write (.bin: the DataFlash log the vehicle keeps; .ulg: PX4's ULog)",
    )
    s.add_argument("--truth", type=Path, help="truth sidecar CSV (every state at 100 Hz)")
    s.add_argument("--list-effects", action="store_true", help="print the effect catalogue and exit")

    d = sub.add_parser("demo", help="simulated quadcopter + ground station on loopback, no hardware")
    d.add_argument("--duration", type=positive_seconds, default=60.0)
    d.add_argument("--vehicle", choices=VEHICLES, default="quad")
    d.add_argument("--seed", type=int, default=1)
    d.add_argument(
        "--record",
        type=Path,
        help="tlog path (default out/demo-<date-time>.tlog: a fresh file per run, as connect does; "
        "an existing file is appended to)",
    )
    add_web_options(d)
    d.add_argument(
        "--control",
        action="store_true",
        help="fly it from the ground station: the dashboard's Control panel arms the vehicle's controllers "
        "(the 3-DOF rig's motor board on a pseudo-terminal)",
    )
    d.add_argument(
        "--rig",
        type=Path,
        metavar="FILE",
        help="with --vehicle heli3dof: the rig's own constants (the heli3dof_rig.json diagnose --model heli3dof "
        "writes), which its estimator and controllers take",
    )


def _speed(text: str) -> float:
    if text.lower() in ("max", "inf"):
        return math.inf
    try:
        return check_speed(float(text.rstrip("x")))
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _add_output_options(p: argparse.ArgumentParser) -> None:
    add_web_options(p)
    p.add_argument("--model", default="altitude", choices=CLI_MODELS, help="the estimator to run (default altitude)")
    p.add_argument(
        "--vehicle",
        help="vehicle parameter file (groundstation/vehicles/NAME.json): the estimator's "
        "noise, thrust curve and sensor limits for this airframe; default: what the "
        "log implies (a Crazyflie log: crazyflie)",
    )
    p.add_argument("--noise", type=Path, help="measurement covariances from 'groundstation noise'")
    p.add_argument(
        "--declared",
        type=Path,
        help="declared effects (JSON); default: FILE.declared.json beside a replayed file, if any",
    )
    p.add_argument(
        "--export",
        metavar="OUT.csv",
        type=Path,
        help="write the estimates: t, states, sigma_<state> (one row per estimate)",
    )
    p.add_argument(
        "--export-measurements", metavar="M.csv", type=Path, help="write the decoded measurements (long format)"
    )
    p.add_argument("--quiet", action="store_true", help="no status lines")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="groundstation", description=DESCRIPTION)
    sub = ap.add_subparsers(dest="command", required=True)

    c = sub.add_parser("connect", help="connect to a vehicle (UDP, TCP or serial) and record the session")
    c.add_argument(
        "url", help="udpin:0.0.0.0:14550, udpout:HOST:PORT, tcp:HOST:PORT, tcpin:HOST:PORT, /dev/ttyUSB0,57600"
    )
    c.add_argument("--record", type=Path, help="tlog path (default sessions/<date-time>.tlog)")
    c.add_argument("--no-record", action="store_true", help="do not record the session")
    c.add_argument(
        "--lost-after", type=positive_seconds, default=3.0, help="seconds of silence before the link counts as lost"
    )
    c.add_argument("--duration", type=positive_seconds, help="stop after this many seconds")
    c.add_argument(
        "--max-rate", type=float, help="the link's budget [bytes/s] the streams are fitted to (serial: baud/10)"
    )
    add_signing_option(c)
    c.add_argument(
        "--control",
        choices=("quad", "coax"),
        help="offer altitude hold for this vehicle in the dashboard's Control panel (armed only there)",
    )
    _add_output_options(c)

    r = sub.add_parser("replay", help="play a recorded .tlog through the live path")
    r.add_argument("file", type=Path)
    r.add_argument("--speed", type=_speed, default=1.0, help="0.1 to 100, or 'max' (default 1)")
    r.add_argument("--start", type=float, default=0.0, help="start this many seconds into the file")
    r.add_argument("--loop", action="store_true")
    _add_output_options(r)

    i = sub.add_parser("info", help="summarise a log (tlog, DataFlash, ULog, Crazyflie): duration, contents, damage")
    i.add_argument("file", type=Path)
    n = sub.add_parser("noise", help="measurement covariances (R) from a stationary stretch of a recording")
    n.add_argument("file", type=Path)
    n.add_argument("--model", default="altitude", choices=CLI_MODELS)
    n.add_argument("--start", type=float, default=0.0, help="window start, vehicle time [s]")
    n.add_argument(
        "--end",
        type=float,
        default=None,
        help="window end, vehicle time [s] (default: just before the log first states the vehicle armed; "
        "a log that states no arming: 1.9)",
    )
    n.add_argument("--out", type=Path, help="write the JSON for --noise here")
    e = sub.add_parser("evaluate", help="run the estimators on a log; errors vs truth, NIS, whiteness")
    e.add_argument("file", type=Path)
    e.add_argument("--model", default="altitude", choices=CLI_MODELS)
    e.add_argument("--vehicle", help="vehicle parameter file (groundstation/vehicles/NAME.json)")
    e.add_argument(
        "--truth",
        type=Path,
        help="truth CSV (t, h or z) to score against (default: motion capture in the log, else LOG.csv or"
        " LOG_truth.csv)",
    )
    add_sim_parser(sub)
    add_diagnose_parser(sub)
    add_triage_parser(sub)
    add_fleet_parser(sub)
    add_param_parser(sub)
    add_logs_parser(sub)
    add_command_parser(sub)
    return ap
