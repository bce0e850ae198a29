"""The live estimators ``--model`` offers, by name: the command line's list, loaded before anything
numerical (:mod:`.registry` holds the models themselves and checks it names them all)."""

from __future__ import annotations

CLI_MODELS = ("altitude", "quad_thrust", "heli3dof")
