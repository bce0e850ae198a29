"""The command line answers at once: ``--help``, a usage error and a file that is no log are
answered before anything numerical is loaded (groundstation/app/main.py, parser.py)."""

from __future__ import annotations

import subprocess
import sys
import time

from groundstation.app.main import ALONE, NO_FILTER

HEAVY = ("numpy", "scipy", "filterpy", "viser", "pymavlink", "matplotlib", "dask", "pyulog", "numba")


def _loaded_after(code: str) -> set[str]:
    r = subprocess.run(
        [sys.executable, "-c", code + "\nimport sys; print(' '.join(sorted(sys.modules)))"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    return set(r.stdout.split())


def test_the_entry_and_its_parser_load_nothing_numerical():
    mods = _loaded_after(
        "from groundstation.app.main import build_parser\n"
        "p = build_parser()\n"
        "p.parse_args(['diagnose', 'x.bin', '--model', 'auto'])"
    )
    assert not {m for m in mods if m.split(".")[0] in HEAVY}, sorted(m for m in mods if m.split(".")[0] in HEAVY)


def test_the_commands_that_need_no_filter_load_none():
    """``triage`` and ``info`` (a log's reader and checks), ``param``, ``logs`` and ``command`` (the
    MAVLink link) and ``sim --fast`` (the simulator) answer in a fraction of a second: what the entry
    loads for each (main.NO_FILTER) holds no filter library and no dashboard (filterpy pulls in
    scipy.stats, viser its web server: two seconds of imports before a vehicle is asked anything).
    ``diagnose`` and ``fleet`` load their filters, and neither the dashboard nor the control station."""
    assert {"triage", "info", "param", "logs", "command", "sim"} <= NO_FILTER <= set(ALONE)
    for command, (module, name) in ALONE.items():
        mods = _loaded_after(f"from {module} import {name}")
        heavy = ("filterpy", "scipy", "matplotlib", "numba", "viser") if command in NO_FILTER else ("viser",)
        assert not sorted(m for m in mods if m.split(".")[0] in heavy), (command, heavy)
        assert "groundstation.control.station" not in mods, command
        if command in NO_FILTER:
            assert "groundstation.estimation.estimator" not in mods, command


def test_help_usage_errors_and_a_file_that_is_no_log_answer_in_one_line(tmp_path):
    gs = [sys.executable, "-m", "groundstation"]
    r = subprocess.run([*gs, "--help"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0 and "diagnose" in r.stdout
    r = subprocess.run([*gs, "diagnose"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "the following arguments are required: file" in r.stderr
    notes = tmp_path / "notes.txt"
    notes.write_text("not a log\n")
    for f, why in (
        (notes, "not a MAVLink tlog"),
        (tmp_path / "gone.bin", "No such file"),
        (tmp_path, "folder"),
    ):
        r = subprocess.run([*gs, "triage", str(f)], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and why in r.stderr and len(r.stderr.splitlines()) == 1, r.stderr


def _heavy_after_one_line(argv: list[str], why: str) -> list[str]:
    """The entry given ``argv`` answers with exit status 2 and one line saying ``why``: the heavy
    packages it had loaded by then."""
    code = (
        "import contextlib, io\n"
        "from groundstation.app.main import main\n"
        "err = io.StringIO()\n"
        "with contextlib.redirect_stderr(err):\n"
        f"    rc = main({argv!r})\n"
        "assert rc == 2 and len(err.getvalue().splitlines()) == 1, (rc, err.getvalue())\n"
        f"assert {why!r} in err.getvalue(), err.getvalue()"
    )
    return sorted({m.split(".")[0] for m in _loaded_after(code)} & set(HEAVY))


def _one_line_before_any_import(argv: list[str], why: str) -> None:
    """The entry given ``argv`` answers in one line saying ``why``, with nothing numerical loaded."""
    heavy = _heavy_after_one_line(argv, why)
    assert not heavy, (argv, heavy)


def test_a_bad_connection_string_and_a_command_short_of_its_confirmation_answer_before_any_import():
    """What the user typed wrong is said in one line, from the arguments alone: no transport, no
    pymavlink, nothing numerical loaded first (each had waited a second and a half for them)."""
    for argv, why in (
        (["connect", "bogus://x"], "unknown connection"),
        (["param", "udpin:nohost", "fetch"], "expected host:port"),
        (["logs", "bogus://x", "list"], "unknown connection"),
        (["command", "udpin:0.0.0.0:14550", "arm"], "add --yes to confirm"),
        (["command", "udpin:0.0.0.0:14550", "takeoff", "high", "--yes"], "an altitude in metres"),
        (["command", "udpin:0.0.0.0:14550", "mode"], "needs a mode name"),
    ):
        _one_line_before_any_import(argv, why)


def test_a_file_an_option_names_that_is_not_there_and_a_duration_of_nothing_are_usage_errors(tmp_path):
    """Said before anything loads, in one line: a truth file that is not there had been passed over in
    silence (the diagnosis ran without the error it was asked for), and ``sim --duration -5`` wrote
    an empty log."""
    log = tmp_path / "flight.tlog"
    log.write_bytes(b"\x00" * 64)  # a tlog's first byte: past the check of the log itself
    gone = tmp_path / "gone"
    for argv, why in (
        (["diagnose", str(log), "--truth", f"{gone}.csv"], "no such truth file"),
        (["evaluate", str(log), "--truth", f"{gone}.csv"], "no such truth file"),
        (["diagnose", str(log), "--declared", f"{gone}.json"], "no such file of declared effects"),
        (["fleet", "diagnose", str(gone), "--out", str(tmp_path / "fleet")], "not a folder"),
        (["param", "udpin:0.0.0.0:14550", "load", f"{gone}.param"], "cannot read: no such file"),
        (["diagnose", str(log), "--vehicle", "nosuch"], "no vehicle configuration 'nosuch'; known: apm2_sonar"),
        (["replay", str(log), "--vehicle", f"{gone}.json"], "no vehicle file"),
        (["evaluate", str(log), "--vehicle", "nosuch"], "no vehicle configuration"),
        (["replay", str(log), "--host", "0.0.0.0"], "exposes it to the network; pass --allow-remote"),
    ):
        _one_line_before_any_import(argv, why)
    assert not (tmp_path / "fleet").exists() and not log.with_name("flight.tlog.diagnosis").exists()
    gs = [sys.executable, "-m", "groundstation"]
    for argv in (
        ["sim", "--fast", "--duration", "-5", "--log", str(tmp_path / "x.tlog")],
        ["demo", "--duration", "nan"],
    ):
        r = subprocess.run([*gs, *argv], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "expected seconds above 0" in r.stderr, r.stderr
    assert not (tmp_path / "x.tlog").exists()


def test_the_entrys_start_up_is_a_small_multiple_of_a_bare_interpreters():
    """``python -m groundstation --help`` against ``python -c pass``, the best of five each (one run
    measures the machine's load as much as the code): it had been 4 s of imports, about 200 times."""

    def best(cmd: list[str]) -> float:
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            subprocess.run(cmd, capture_output=True, timeout=60, check=True)
            times.append(time.perf_counter() - t0)
        return min(times)

    bare = best([sys.executable, "-c", "pass"])
    entry = best([sys.executable, "-m", "groundstation", "--help"])
    assert entry < 5.0 * bare + 0.05, (entry, bare)


def test_the_light_lists_name_what_the_registries_hold():
    from groundstation.diagnosis.model_names import MODEL_HELP
    from groundstation.diagnosis.models import DIAGNOSABLE
    from groundstation.estimation.model_names import CLI_MODELS
    from groundstation.estimation.registry import MODELS

    assert tuple(MODEL_HELP) == tuple(DIAGNOSABLE)
    assert CLI_MODELS == tuple(n for n, s in MODELS.items() if s.cli)


def test_the_simulators_bad_arguments_answer_with_numpy_alone_loaded(tmp_path):
    """A mistyped effect, a scenario file the simulator cannot fly, ``--fast`` without its log, a bad
    ``--udp`` or system id: one line from the arguments, with the scenario built (its effects need
    numpy) and nothing else numerical loaded (each had waited a second and a half for the filters
    and the dashboard). ``--list-effects`` likewise."""
    scenario = tmp_path / "s.json"
    scenario.write_text('{"sensors": {"esc": "oneshot"}}')
    for argv, why in (
        (["sim", "--effect", "warp_drive:k=1"], "unknown effect 'warp_drive'"),
        (["sim", "--undeclared", "accel_bias:z=lots"], "not a number"),
        (["sim", "--scenario", str(scenario)], "unknown ESC protocol 'oneshot'"),
        (["sim", "--fast"], "--fast needs --log"),
        (["sim", "--udp", "nohost"], "expected HOST:PORT"),
        (["sim", "--sysid", "0"], "system id is 1-255"),
    ):
        assert _heavy_after_one_line(argv, why) == ["numpy"], argv
    code = (
        "import contextlib, io\n"
        "from groundstation.app.main import main\n"
        "out = io.StringIO()\n"
        "with contextlib.redirect_stdout(out):\n"
        "    assert main(['sim', '--list-effects']) == 0\n"
        "assert '`baro_thrust`' in out.getvalue()"
    )
    assert sorted({m.split(".")[0] for m in _loaded_after(code)} & set(HEAVY)) == ["numpy"]
