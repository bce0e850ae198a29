"""``groundstation sim``: the simulated vehicle from the command line, on its own: a log written at
once (``--fast``), or a real vehicle's stand-in for another program (:mod:`.sim_live`, loaded only
then: its autopilot's own height filter is filterpy's, a second of imports a log written at once does
not need). Neither loads the ground station's filters or its dashboard (``demo``, :mod:`.demo_cli`,
runs both sides)."""

from __future__ import annotations

import importlib

from sim_bridge.fast import declared_path, run_fast

from .sim_args import catalogue_markdown, checked, sysid


def cmd_sim(args) -> int:
    if args.list_effects:
        print(catalogue_markdown())
        return 0
    scenario = checked(args)  # the entry checked them without the simulator loaded; here it is made
    if args.fast:
        r = run_fast(scenario, args.log, args.truth, args.duration or scenario.duration, sysid=sysid(args.sysid))
        print(
            f"sim: {scenario.vehicle} seed {scenario.seed}: {r.seconds:g} s simulated in {r.wall:.2f} s "
            f"({r.speedup:.0f}x real time), {r.frames} frames -> {r.log}"
            + (f"; truth -> {r.truth}" if r.truth else "")
            + f"; declared -> {declared_path(r.log)}"
        )
        return 0
    return importlib.import_module(f"{__package__}.sim_live").run(args, scenario)
