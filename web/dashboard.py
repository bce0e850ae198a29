"""The browser dashboard: live estimates and their uncertainty in a viser 3D view.

``Dashboard.feed_measurement`` / ``feed_snapshot`` only store the latest data
(cheap, never blocking the estimation loop); two tasks push to the browsers at
their own rates: the 3D scene at <= ``scene_hz`` (30 Hz) and the plots at <=
``plot_hz`` (10 Hz), from windowed buffers.

Frames: the world is NED and the body FRD (MAVLink's); viser's world is z-up.
Shown as x = north, y = west, z = up, i.e. vectors ``(n, -e, -d)`` and body
quaternions ``(w, x, -y, -z)`` (a half turn about x): a right-handed frame
in which north/up read naturally and nothing is mirrored.

Scene: the vehicle at its estimated pose (box + axes; height from the
session's model, horizontal place from the IMU + GPS filter of
``groundstation.estimation.models.horizontal``), the truth as a ghost
when the session has truth, a trail, the position covariance as a 3-sigma
ellipsoid oriented by its eigenvectors, the range sensor's ray, a ground grid.
Panels: link status, the state table with +-sigma (and, with truth in the stream, the height's
error against it and whether its sigma holds it: ``LiveTruthScore``), time plots (estimate with
+-2 sigma against its measurements; innovations with +-2 sqrt(S); NIS with its
95 % chi-square band; a bias or parameter state, chosen in a dropdown, +-2
sigma), replay controls, and the diagnosis panel.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import math
import multiprocessing
import os
import socket
import sys
import time
from collections import deque
from collections.abc import Callable

import numpy as np
import viser
from scipy.stats import chi2

from groundstation.core.counts import counted
from groundstation.core.frames import quaternion_from_euler, quaternion_from_matrix
from groundstation.core.measurement import Kind, Measurement
from groundstation.diagnosis.live import DIAGNOSIS_NICE, SessionBuffer, diagnose_window, markdown
from groundstation.diagnosis.model_names import RIG_MODEL_HELP
from groundstation.diagnosis.models import DIAGNOSABLE
from groundstation.estimation.models.ground import LANDED
from groundstation.estimation.truth import LiveTruthScore

from .authority import Authority, is_loopback
from .control_panel import ControlPanel
from .session_loop import SessionLoop
from .vehicle_panel import VehiclePanel

_FLIP = np.array([1.0, -1.0, -1.0])
#: the models the Diagnosis panel offers (the 3-DOF rig's own diagnosis among them)
DIAGNOSIS_MODELS = (*DIAGNOSABLE, *RIG_MODEL_HELP)


def ned_to_view(v) -> np.ndarray:
    return np.asarray(v, dtype=float) * _FLIP


def frd_quat_to_view(q) -> tuple[float, float, float, float]:
    w, x, y, z = q
    return (float(w), float(x), float(-y), float(-z))


def free_port(host: str, port: int) -> int:
    """``port`` if it can be bound on ``host``, else a free one."""
    with socket.socket() as s:
        try:
            s.bind((host, port))
            return port
        except OSError:
            s.bind((host, 0))
            return s.getsockname()[1]


class Dashboard:
    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        scene_hz: float = 30.0,
        plot_hz: float = 10.0,
        window_s: float = 20.0,
        title: str = "groundstation",
        allow_remote: bool = False,
    ) -> None:
        """``allow_remote``: serve on an address other than loopback (refused otherwise, in one
        line: :class:`~web.authority.RemoteRefused`); control then needs the session's token."""
        if not is_loopback(host) and not allow_remote:
            Authority(host, port)  # raises RemoteRefused with the one-line reason
        self.port = free_port(host, port)
        self.host = host
        self.server = viser.ViserServer(host=host, port=self.port, label=title, verbose=False)
        self.port = self.server.get_port()  # the one bound (``port=0``: the OS's choice)
        self.scene_hz, self.plot_hz, self.window_s = scene_hz, plot_hz, window_s
        #: who may command from which tab (web/authority.py)
        self.authority = Authority(host, self.port, allow_remote)
        #: the session's event loop, where the panels' commands run (viser's callbacks run on its own)
        self.session_loop = SessionLoop()
        self.url = self.authority.view_url
        self.control_url = self.authority.control_url
        self.server.on_client_disconnect(self._client_left)
        self.scene_updates = 0
        self.plot_updates = 0
        self._snap = None
        self._att = (0.0, 0.0, 0.0)
        self._truth: Measurement | None = None
        self._pos_ne = np.zeros(2)
        self._P_ne: np.ndarray | None = None  # horizontal covariance, once estimated
        self._range = math.nan
        self._trail: deque = deque(maxlen=300)
        self._trail_changed = False
        self._ellipsoid_shape = None
        self._ray_shown = math.inf
        self._series: deque = deque()  # (t, z, sigma_z)
        self._meas: deque = deque()  # (t, range)
        self._innov: deque = deque()  # (t, nu, 2 sqrt S, nis)
        self._params: deque = deque()  # (t, x[2:], sigma[2:])
        #: the height against truth, when the session streams it (is the sigma shown honest?)
        self.truth_score = LiveTruthScore(window_s=max(window_s, 60.0))
        self._dirty = False
        self.status_text = "waiting for data"
        #: the estimator's counters (its skipped readings are listed under the state), if one is attached
        self.estimator_counters = None
        self.session = SessionBuffer()
        self._diagnosing = False
        self._pool: concurrent.futures.ProcessPoolExecutor | None = None
        self.last_diagnosis: dict | None = None
        #: effects the session declares (the diagnosis does not look for them)
        self.declared: list[dict] = []
        #: the airframe file the session's estimator was given (--vehicle): the diagnosis starts from it too
        self.airframe: str | None = None
        self.vehicle_panel: VehiclePanel | None = None
        #: called with a system id when the user picks another vehicle (:meth:`set_vehicles`)
        self.on_vehicle: Callable[[int], None] | None = None
        self._build()
        #: update failures by one-line description, with their counts (:meth:`run`)
        self.update_errors: dict[str, int] = {}

    # -- layout -----------------------------------------------------------------------------
    def _build(self) -> None:
        sc, gui = self.server.scene, self.server.gui
        # viser's default camera puts a vehicle hovering near the origin behind the control panel;
        # this one frames the flight volume (0-3 m up, a few metres around) left of the panel
        self.server.initial_camera.position = (-5.0, -3.0, 3.5)
        self.server.initial_camera.look_at = (0.0, 1.2, 1.0)
        sc.add_grid("/ground", width=20.0, height=20.0, cell_size=0.5, section_size=2.0)
        self.vehicle_frame = sc.add_frame("/vehicle", axes_length=0.3, axes_radius=0.012)
        sc.add_box("/vehicle/body", color=(40, 110, 220), dimensions=(0.35, 0.35, 0.08))
        self.ghost = sc.add_box(
            "/truth", color=(60, 200, 90), dimensions=(0.35, 0.35, 0.08), opacity=0.35, visible=False
        )
        # an uncertainty is not a solid: no shadow on the ground (it read as a grey disc)
        self.ellipsoid = sc.add_icosphere(
            "/covariance",
            radius=1.0,
            color=(240, 160, 40),
            opacity=0.25,
            scale=(0.05, 0.05, 0.05),
            cast_shadow=False,
            receive_shadow=False,
        )
        self.trail = sc.add_line_segments("/trail", points=np.zeros((1, 2, 3)), colors=(90, 90, 90), thickness=0.01)
        self.ray = sc.add_line_segments(
            "/vehicle/range_ray", points=np.zeros((1, 2, 3)), colors=(230, 50, 50), thickness=0.015, visible=False
        )
        with gui.add_folder("Link"):
            self.link_md = gui.add_markdown("waiting for data")
            # several vehicles on the link: which one the view shows (hidden while there is one)
            self.vehicle_choice = gui.add_dropdown("vehicle", options=("1",), visible=False)

        @self.vehicle_choice.on_update
        async def _(_e) -> None:
            if self.on_vehicle is not None:
                self.on_vehicle(int(self.vehicle_choice.value))

        with gui.add_folder("State"):
            self.state_md = gui.add_markdown("no estimate yet")
        with gui.add_folder("Plots"):
            t0 = np.zeros(2)
            self.plot_z = gui.add_uplot(
                data=(t0, t0, t0, t0, t0),
                series=(
                    {"label": "t [s]"},
                    {"label": "z", "stroke": "#1f6fd1", "width": 2},
                    {"label": "-2σ", "stroke": "#9bb9e8"},
                    {"label": "+2σ", "stroke": "#9bb9e8"},
                    {"label": "range", "stroke": "#d23a3a", "width": 1},
                ),
                scales={"x": {"time": False, "auto": True}},
                title="height: estimate ±2σ vs range",
                aspect=1.6,
            )
            self.plot_nu = gui.add_uplot(
                data=(t0, t0, t0, t0),
                series=(
                    {"label": "t [s]"},
                    {"label": "ν", "stroke": "#444", "width": 1},
                    {"label": "-2√S", "stroke": "#e39b3b"},
                    {"label": "+2√S", "stroke": "#e39b3b"},
                ),
                scales={"x": {"time": False, "auto": True}},
                title="innovation (last sensor) ±2√S",
                aspect=1.6,
            )
            self.plot_nis = gui.add_uplot(
                data=(t0, t0, t0, t0),
                series=(
                    {"label": "t [s]"},
                    {"label": "NIS", "stroke": "#7a3fc0", "width": 1},
                    {"label": "χ² 2.5 %", "stroke": "#aaa"},
                    {"label": "χ² 97.5 %", "stroke": "#aaa"},
                ),
                scales={"x": {"time": False, "auto": True}},
                title="NIS and its 95 % band",
                aspect=1.6,
            )
            # bias and parameter states (all but the kinematic first two), one at a time:
            # their scales differ by orders of magnitude (alpha ~ 20, biases ~ 0.01)
            self.param_choice = gui.add_dropdown("parameter", options=("(none yet)",))
            self.plot_param = gui.add_uplot(
                data=(t0, t0, t0, t0),
                series=(
                    {"label": "t [s]"},
                    {"label": "estimate", "stroke": "#2a8a4a", "width": 2},
                    {"label": "-2σ", "stroke": "#9fd4b0"},
                    {"label": "+2σ", "stroke": "#9fd4b0"},
                ),
                scales={"x": {"time": False, "auto": True}},
                title="bias / parameter state ±2σ",
                aspect=1.6,
            )
        self.replay_folder = gui.add_folder("Replay")
        with self.replay_folder:
            self.play = gui.add_button("pause")
            self.speed = gui.add_slider("speed ×", min=0.1, max=100.0, step=0.1, initial_value=1.0)
            self.position = gui.add_slider("time [s]", min=0.0, max=1.0, step=0.1, initial_value=0.0)
        self.replay_folder.visible = False
        with gui.add_folder("Diagnosis"):
            self.diagnosis_md = gui.add_markdown("No diagnosis has been run on this session.")
            self.diagnosis_model = gui.add_dropdown("model", options=DIAGNOSIS_MODELS, initial_value="altitude")
            self.diagnosis_window = gui.add_slider("last [s]", min=20.0, max=600.0, step=10.0, initial_value=120.0)
            self.diagnose_button = gui.add_button("Diagnose")

        @self.diagnose_button.on_click
        async def _(e) -> None:
            # minutes of a core: only a tab opened at the control address starts one (any tab sees
            # the result); holding control is not needed, as a replay has nothing else to control
            why = self.client_refusal(e.client_id)
            if why is not None:
                if e.client is not None:
                    e.client.add_notification("Not yours to start", why, auto_close_seconds=6.0, color="yellow")
                return
            await self.run_diagnosis()

    def attach_session(self, *, model: str, declared: list[dict], counters=None, vehicle: str | None = None) -> None:
        """What the session's estimator was built with: its declared effects and airframe file (the
        Diagnosis panel assumes the same; without the airframe a diagnosis of a replay run with
        ``--vehicle`` would read another sonar's limits and thrust curve than ``diagnose --vehicle``),
        its model (the panel's choice, where it can diagnose it) and its counters (its skips, listed
        under the state)."""
        self.declared = list(declared)
        self.airframe = vehicle
        self.estimator_counters = counters
        if model in DIAGNOSIS_MODELS:
            self.diagnosis_model.value = model  # type: ignore[misc]  # viser's setter is typed apart from its getter

    async def run_diagnosis(self) -> dict | None:
        """Diagnose the last ``diagnosis_window`` seconds in a worker process; show the result."""
        if self._diagnosing:
            return None
        seconds = float(self.diagnosis_window.value)
        ms = self.session.window(seconds)
        if len(ms) < 100:
            self.diagnosis_md.content = "Not enough data yet to diagnose."
            return None
        self._diagnosing = True
        self.diagnose_button.disabled = True
        self.diagnosis_md.content = f"Diagnosing the last {seconds:.0f} s ({len(ms)} measurements)…"
        try:
            if self._pool is None:
                self._pool = concurrent.futures.ProcessPoolExecutor(
                    1, mp_context=multiprocessing.get_context("spawn"), initializer=os.nice, initargs=(DIAGNOSIS_NICE,)
                )
            j = await asyncio.get_running_loop().run_in_executor(
                self._pool, diagnose_window, ms, str(self.diagnosis_model.value), self.declared, self.airframe
            )
            self.diagnosis_md.content = markdown(j, seconds)
            self.last_diagnosis = j
            return j
        finally:
            self._diagnosing = False
            self.diagnose_button.disabled = False

    # -- feeding (cheap: store only) ----------------------------------------------------------
    def feed_measurement(self, m: Measurement) -> None:
        self.session.add(m)
        k = m.kind
        if k is Kind.ATTITUDE:
            self._att = (float(m.value[0]), float(m.value[1]), float(m.value[2]))
        elif k is Kind.RANGE:
            self._range = float(m.value[0])
            if self._meas and m.t < self._meas[-1][0] - 1.0:  # time went back (seek, loop): start over
                self._meas.clear()
            self._meas.append((m.t, self._range))
        elif k is Kind.TRUTH_POSE:
            self._truth = m
            self.truth_score.truth(m.t, -float(m.value[2]))  # NED down: the height is up
        self._dirty = True

    def feed_snapshot(self, snap) -> None:
        if snap.estimator == "horizontal":  # place and covariance in the horizontal plane
            self._pos_ne = np.array(snap.x[:2], dtype=float)
            self._P_ne = np.array(snap.P[:2, :2], dtype=float)
            self._dirty = True
            return
        self._snap = snap
        if self._series and snap.t < self._series[-1][0] - 1.0:
            # time went back (a seek, a looping replay, a reboot): the plots start over,
            # or their windows, pruned by the newest time, would never empty
            self._series.clear()
            self._innov.clear()
            self._params.clear()
        if "z" in snap.states:
            i = snap.states.index("z")
            self._series.append((snap.t, float(snap.x[i]), float(snap.sigma[i])))
            if self._truth is not None:
                self.truth_score.estimate(snap.t, float(snap.x[i]), float(snap.sigma[i]))
        if len(snap.states) > 2:
            self._params.append((snap.t, snap.x[2:].copy(), snap.sigma[2:]))
        rec = snap.innovation
        if rec is not None and rec.sensor != LANDED:  # the ground's pseudo-sensor (models.ground)
            self._innov.append((rec.t, float(rec.nu[0]), 2.0 * math.sqrt(float(rec.S[0, 0])), rec.nis, len(rec.nu)))
        self._dirty = True

    def set_link_status(self, text: str) -> None:
        self.status_text = text

    def set_vehicles(self, sysids: list[int]) -> None:
        """The vehicles on the link (their system ids): offered in the vehicle picker."""
        current = self.vehicle_choice.value
        self.vehicle_choice.options = tuple(str(k) for k in sysids)
        if current in self.vehicle_choice.options:
            self.vehicle_choice.value = current  # type: ignore[misc]  # viser's setter is typed apart from its getter
        self.vehicle_choice.visible = len(sysids) > 1

    def clear_view(self) -> None:
        """Forget what is shown (another vehicle comes next): its place, trail, plots and window."""
        self._snap, self._truth, self._P_ne = None, None, None
        self.truth_score.clear()
        self._att, self._pos_ne, self._range = (0.0, 0.0, 0.0), np.zeros(2), math.nan
        for buf in (self._trail, self._series, self._meas, self._innov, self._params):
            buf.clear()
        self._ellipsoid_shape = None
        self.session = SessionBuffer()
        self._dirty = True

    def add_vehicle_panel(self, link) -> VehiclePanel:
        """Show the Vehicle panel (mode, arm, takeoff, land, parameters) for the vehicle shown, on
        ``link`` (a :class:`~drivers.mavlink.link.MavlinkLink`), commanded as the Control panel is."""
        self.session_loop.bind_if_running()
        self.vehicle_panel = VehiclePanel(
            self.server.gui,
            link,
            self.authority,
            self.client_refusal,
            lambda: self.shown_vehicle(link),
            take_button=getattr(self, "control", None) is None,
            session=self.session_loop,
        )
        return self.vehicle_panel

    def shown_vehicle(self, link) -> int | None:
        """The system id the view shows: the picker's, or the link's first vehicle."""
        if self.vehicle_choice.visible:
            return int(self.vehicle_choice.value)
        return next(iter(link.vehicles), None)

    def add_control(self, station):
        """Show the control panel for ``station`` (a :class:`~groundstation.control.station.ControlStation`),
        commanded only from a tab the :attr:`authority` admits."""
        self.session_loop.bind_if_running()
        self.control = ControlPanel(
            self.server.gui,
            station,
            self.authority,
            self.client_refusal,
            window_s=self.window_s,
            session=self.session_loop,
        )
        return self.control

    def client_refusal(self, client_id: int | None) -> str | None:
        """Why the tab ``client_id`` may not command (its websocket's path and headers), or None.

        The request is read from viser's table of live connections: viser offers no public hook
        for it (its version is pinned by the tests that exercise this). A tab it cannot find is
        refused."""
        connections = getattr(getattr(self.server, "_websock_server", None), "_live_connections", {})
        conn = connections.get(client_id) if client_id is not None else None
        request = getattr(conn, "request", None)
        if request is None:
            return "view only: this tab's connection cannot be checked"
        return self.authority.refusal(request.path, request.headers)

    def _client_left(self, client) -> None:
        self.authority.left(client.client_id)

    def attach_replay(self, replay) -> None:
        """Show the replay controls and wire them to ``replay`` (pause/resume, speed, seek)."""
        self.replay_folder.visible = True
        self.position.max = max(0.1, round(replay.duration, 1))

        # async callbacks run on the event loop the replay runs on (plain ones go to
        # viser's thread pool)
        @self.play.on_click
        async def _(_e) -> None:
            if replay.status.state.value == "paused":
                replay.resume()
                self.play.label = "pause"
            else:
                replay.pause()
                self.play.label = "play"

        @self.speed.on_update
        async def _(_e) -> None:
            replay.set_speed(float(self.speed.value))

        @self.position.on_update
        async def _(_e) -> None:
            if abs(self.position.value - replay.position) > 0.5:
                replay.seek(float(self.position.value))

        self._replay = replay

    # -- pushing to browsers --------------------------------------------------------------------
    def _pose(self):
        s = self._snap
        z = 0.0
        if s is not None and "z" in s.states:
            z = float(s.x[s.states.index("z")])
        pos = np.array([self._pos_ne[0], self._pos_ne[1], -z])  # NED
        return pos, quaternion_from_euler(*self._att)

    def update_scene(self) -> None:
        pos, q = self._pose()
        p_view = ned_to_view(pos)
        self.vehicle_frame.position = p_view
        self.vehicle_frame.wxyz = frd_quat_to_view(q)
        if not self._trail or np.linalg.norm(self._trail[-1] - p_view) > 0.02:
            self._trail.append(p_view)
            self._trail_changed = True
        # the trail is the heaviest scene message: every third frame (10 Hz) is smooth enough
        if self._trail_changed and len(self._trail) > 1 and self.scene_updates % 3 == 0:
            pts = np.array(self._trail)
            self.trail.points = np.stack([pts[:-1], pts[1:]], axis=1)
            self._trail_changed = False
        s = self._snap
        if s is not None:
            sig_z = float(s.sigma[s.states.index("z")]) if "z" in s.states else 0.05
            cov = np.diag([0.05**2, 0.05**2, sig_z**2])  # horizontal: until it is estimated
            if self._P_ne is not None:
                cov[:2, :2] = self._P_ne
            cov = cov * np.outer(_FLIP, _FLIP)  # NED -> view axes
            w, V = np.linalg.eigh(cov)
            if np.linalg.det(V) < 0:
                V[:, 0] = -V[:, 0]
            scale = 3.0 * np.sqrt(np.clip(w, 1e-12, None))
            q = np.array(quaternion_from_matrix(V))
            # each message goes to every client: the shape only when it visibly changed
            last = self._ellipsoid_shape
            if last is None or np.max(np.abs(scale / last[0] - 1.0)) > 0.02 or abs(q @ last[1]) < 0.9995:
                self.ellipsoid.scale = tuple(float(x) for x in scale)
                self.ellipsoid.wxyz = tuple(float(x) for x in q)
                self._ellipsoid_shape = (scale, q)
            self.ellipsoid.position = p_view
        if self._range == self._range and abs(self._range - self._ray_shown) > 0.005:
            # a child of the vehicle frame: along body z (down), i.e. -z in the view's body axes
            self.ray.points = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, -self._range]]])
            self.ray.visible = True
            self._ray_shown = self._range
        if self._truth is not None:
            self.ghost.visible = True
            self.ghost.position = ned_to_view(self._truth.value[:3])
            self.ghost.wxyz = frd_quat_to_view(self._truth.value[3:7])
        self.scene_updates += 1

    def update_panels(self) -> None:
        self.link_md.content = self.status_text
        s = self._snap
        if s is not None:
            rows = "\n".join(f"| {n} | {v:+.4f} | ±{sg:.4f} |" for n, v, sg in zip(s.states, s.x, s.sigma))
            rejected = self.estimator_counters.rejected if self.estimator_counters is not None else {}
            skipped = f"\n\nskipped: {counted(rejected)}" if rejected else ""
            score = self.truth_score.summary()
            vs_truth = ""
            if score is not None:
                _, rms, within, nees = score
                vs_truth = (
                    f"\n\nagainst truth, last {self.truth_score.window_s:.0f} s: height {rms * 100:.1f} cm RMS, "
                    f"within 2σ {within:.0%} (95 % if σ is honest), NEES {nees:.2f}"
                )
            self.state_md.content = (
                f"t = {s.t:.2f} s ({s.estimator})\n\n| state | value | σ |\n|---|---|---|\n{rows}" + vs_truth + skipped
            )
        t_now = self._series[-1][0] if self._series else 0.0
        for buf in (self._series, self._meas, self._innov, self._params):
            while buf and buf[0][0] < t_now - self.window_s:
                buf.popleft()
        if len(self._series) > 1:
            a = np.array(self._series)
            t, z, sg = a[:, 0], a[:, 1], a[:, 2]
            # the range on the estimate's time axis (uPlot needs one x axis, and NaN
            # gaps break its scales, blanking the panel)
            if self._meas:
                m = np.array(self._meas)
                rng = np.interp(t, m[:, 0], m[:, 1])
            else:
                rng = z.copy()
            self.plot_z.data = _f32(t, z, z - 2 * sg, z + 2 * sg, rng)
        if len(self._innov) > 1:
            a = np.array(self._innov)
            dof = int(a[-1, 4])
            lo, hi = chi2.ppf([0.025, 0.975], dof)
            self.plot_nu.data = _f32(a[:, 0], a[:, 1], -a[:, 2], a[:, 2])
            self.plot_nis.data = _f32(a[:, 0], a[:, 3], np.full(len(a), lo), np.full(len(a), hi))
        if s is not None and len(s.states) > 2 and self.param_choice.options != tuple(s.states[2:]):
            self.param_choice.options = tuple(s.states[2:])
            self.param_choice.value = s.states[2]
        if len(self._params) > 1 and s is not None and self.param_choice.value in s.states[2:]:
            j = s.states[2:].index(self.param_choice.value)
            t = np.array([p[0] for p in self._params])
            v = np.array([p[1][j] for p in self._params])
            sg = np.array([p[2][j] for p in self._params])
            self.plot_param.data = _f32(t, v, v - 2 * sg, v + 2 * sg)
        control = getattr(self, "control", None)
        if control is not None:
            control.update()
        if self.vehicle_panel is not None:
            self.vehicle_panel.update()
        replay = getattr(self, "_replay", None)
        if replay is not None and abs(self.position.value - replay.position) > 0.5:
            self.position.value = round(replay.position, 1)  # type: ignore[misc]  # viser's setter is typed apart from its getter
        self.plot_updates += 1

    async def run(self) -> None:
        """Push scene and panels at their rates until cancelled. An update that raises is reported
        (:attr:`update_errors`, one line on stderr per new error) and the schedule goes on: one bad
        frame must not freeze the view for the rest of the session."""

        self.session_loop.bind()  # the loop the session runs on, where the panels' commands go

        def scene():
            if self._dirty:
                self.update_scene()

        await asyncio.gather(
            _every(1.0 / self.scene_hz, scene, self._report),
            _every(1.0 / self.plot_hz, self.update_panels, self._report),
        )

    def _report(self, what: str, e: BaseException) -> None:
        line = f"{what}: {type(e).__name__}: {e}"
        self.update_errors[line] = self.update_errors.get(line, 0) + 1
        if self.update_errors[line] == 1:
            print(f"dashboard: {line} (the updates go on)", file=sys.stderr, flush=True)

    def stop(self) -> None:
        if self.vehicle_panel is not None:
            self.vehicle_panel.close()
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
        self.server.stop()


async def _every(period: float, fn: Callable[[], None], report: Callable[[str, BaseException], None]) -> None:
    """Call ``fn`` on a fixed schedule (not sleep-after-work, which runs slow);
    after a stall, resume the schedule rather than burst to catch up. An exception of ``fn`` goes
    to ``report`` with the function's name, and the schedule goes on."""
    nxt = time.monotonic()
    while True:
        try:
            fn()
        except Exception as e:  # noqa: BLE001 - any failure of one frame is reported, not fatal
            report(getattr(fn, "__name__", "update"), e)
        nxt += period
        delay = nxt - time.monotonic()
        if delay < 0:
            nxt, delay = time.monotonic(), 0.0
        await asyncio.sleep(delay)


#: a plot panel is ~300 px wide: more points than this only cost bytes, per client
PLOT_POINTS = 400


def _f32(*arrays) -> tuple[np.ndarray, ...]:
    """Plot data as float32, at most ``PLOT_POINTS`` samples (every k-th, the
    newest kept): half the bytes of float64, and (seen in headless Chromium with
    viser 1.1.1) float64 series that are constant, like the chi-square bounds,
    blank the whole control panel, while float32 ones draw."""
    n = len(arrays[0])
    k = max(1, -(-n // PLOT_POINTS))
    idx = np.arange(n - 1, -1, -k)[::-1]
    return tuple(np.ascontiguousarray(np.asarray(a)[idx], dtype=np.float32) for a in arrays)
