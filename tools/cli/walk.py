"""aider-exo walk: the main controller, the node boards and the simulated HHEA walking together.

The main controller (gait FSM, DMP swing, CoM compensation, optionally learning) walks the simulated
HHEA through the four emulated node boards, every value a CAN frame, in lock-step (deterministic for
a seed). By default everything runs in this process on the in-process virtual bus; with --bus
socketcan (or udp_multicast) the node boards run as a second process (aider-exo nodes) on that
channel. A one-line status while it walks (on stderr), a summary at the end: steps and cycles
walked, falls, mean stick force, and the error of the estimated X_CoM/X_SP against the simulation's
ground truth.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from protocol.clock import TICK_S
from tools.cli.common import StopSignals, add_config_options, add_mode_option, config_path, load_cli_config, learned_folder, positive_float, positive_int, print_json, sim_mode, port, seed_type


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "walk",
        help="walk the simulated HHEA under the main controller, over CAN in lock-step",
        description=__doc__,
    )
    add_config_options(p)
    p.add_argument("--steps", type=positive_int, default=10, metavar="N",
                   help="gait cycles to walk (the paper's steps: a left and a right swing each; default 10)")
    p.add_argument("--seed", type=seed_type, default=0, help="seed of the patient's stick placement and sensor noise (default 0)")
    add_mode_option(p)
    p.add_argument("--fixed-step", type=positive_float, metavar="M", help="every step this long: no compensation (the baseline)")
    p.add_argument("--learn", action="store_true", help="learn the compensation online with PI² (saved to --patient's learned file)")
    p.add_argument("--patient", metavar="NAME", help="walk with (and, learning, update) this patient's learned parameters "
                   "(no such file: an error, unless --learn creates it)")
    p.add_argument("--learned-dir", metavar="DIR", help="folder of the learned files (default: controller.learned_dir, relative: to the configuration file's folder)")
    p.add_argument("--virtual-patient", metavar="FILE", type=Path,
                   help="in-process only: walk this simulated patient (config/patients/*.yaml: body, arms, stick placement, "
                        "the controller's body model; docs/POPULATION.md)")
    p.add_argument("--max-time", type=positive_float, metavar="S", help="simulated seconds before the walk counts as stalled")
    p.add_argument("--render", metavar="DIR", type=Path, help="in-process only: write a PNG strip and a GIF of the walk to DIR")
    p.add_argument("--log", metavar="FILE", help="the controller's per-tick telemetry as JSON lines")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.add_argument("--quiet", action="store_true", help="no status line")
    p.add_argument("--pace", type=float, metavar="X",
                   help="walk at X times real time, so it can be watched (default: 1 with --view, otherwise 0: as fast as it computes)")
    v = p.add_argument_group("live view (docs/VIEW.md)")
    v.add_argument("--view", action="store_true",
                   help="serve the live view of this walk (aider-exo view, listening to the walk's bus) and print its address")
    v.add_argument("--view-port", type=port, default=8050, metavar="PORT", help="--view: port on 127.0.0.1 (default 8050; 0: any free one)")
    v.add_argument("--linger", type=positive_float, default=0.0, metavar="S",
                   help="--view: keep serving the page S seconds after the walk ends (default 0)")
    p.set_defaults(func=run)


class StatusLine:
    """The walk's live one-line status on stderr: rewritten in place on a terminal, otherwise a
    line every simulated second and at every step."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.tty = sys.stderr.isatty()
        self.last_s = -math.inf
        self.steps = 0

    def __call__(self, result: Any, session: Any) -> None:
        if not self.enabled:
            return
        t = result.tick * TICK_S
        steps = len(session.core.steps)
        if not (self.tty or steps != self.steps or t - self.last_s >= 1.0):
            return
        self.steps, self.last_s = steps, t
        text = f"walk {session.status().line(t)}"
        if self.tty:
            print("\r" + text.ljust(100), end="", file=sys.stderr, flush=True)
        else:
            print(text, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.enabled and self.tty:
            print(file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from config import ConfigError
    from config.files import check_output, check_output_folder
    from controller.factory import step_policy
    from controller.learned import learned_path
    from controller.telemetry import TelemetryLog
    from tools.pipeline import Pace, walk

    cfg = load_cli_config(args)
    if cfg.controller is None or cfg.sim is None or cfg.nodes is None:
        raise ConfigError("walking in simulation needs the controller, sim and nodes sections", key="controller")
    args.mode = sim_mode(args, cfg)
    two_processes = cfg.bus.interface != "virtual"
    if args.virtual_patient:
        if two_processes:
            raise ConfigError(f"--virtual-patient needs the simulation in this process (not --bus {cfg.bus.interface})",
                              key="bus.interface")
        from tools.population import load_patient

        virtual_patient, cfg = load_patient(args.virtual_patient, cfg)
    if two_processes and args.render:
        raise ConfigError(f"--render needs the simulation in this process (not --bus {cfg.bus.interface})", key="bus.interface")
    # Every output is checked before the walk starts (an unwritable one must not lose the walk's summary).
    inputs = [config_path(args), args.virtual_patient]
    if args.render:
        check_output_folder(args.render, option="--render")  # created now; its parent must exist
        inputs += [args.render / f"walk-{args.mode}.png", args.render / f"walk-{args.mode}.gif"]
    if args.log:
        check_output(args.log, inputs=inputs, option="the telemetry log --log")
    patients = learned_folder(args, cfg)
    # Exploration seeded from --seed (its own stream): a learning walk is as repeatable as any other.
    rng = np.random.default_rng(np.random.SeedSequence([args.seed, 1]))
    policy, saver = step_policy(cfg.controller, fixed_m=args.fixed_step, learn=args.learn, patient=args.patient,
                                learned_dir=str(patients), rng=rng)
    if args.learn and not args.patient:
        print("aider-exo walk: warning: learning without --patient: what is learnt is not kept", file=sys.stderr)
    if args.patient and not (args.quiet or args.json):
        print(f"aider-exo walk: patient {args.patient}: {learned_path(patients, args.patient)}", file=sys.stderr)
    if args.pace is not None and args.pace < 0:
        raise ConfigError(f"--pace {args.pace}: give 0 (as fast as it computes) or a positive factor", key="pace")
    pace = Pace(args.pace if args.pace is not None else 1.0 if args.view else 0.0)
    status = StatusLine(not args.quiet)
    telemetry = None
    channel = f"aider-walk-{args.seed}-{id(args)}"
    view = None
    if args.view:
        from tools.pipeline import walk_config
        from tools.view.live import LiveView

        view = LiveView(cfg, cfg.bus if two_processes else walk_config(cfg, args.mode, channel).bus, port=args.view_port)
        print(f"aider-exo walk: live view at {view.start()}", file=sys.stderr, flush=True)
    recorder = camera = None
    if args.render:
        from sim.render import Camera, Recorder

        camera = Camera(target_xyz=(0.3, 0.0, 0.7), distance_m=2.8, yaw_deg=20.0, pitch_deg=-10.0, width_px=320, height_px=240)
        recorder = Recorder(every_n=5)
    nodes_report: dict[str, Any] | None = None
    view_report = None

    def watched(result: Any, session: Any) -> None:
        status(result, session)
        pace(result.tick)

    try:
        telemetry = TelemetryLog(args.log) if args.log else None  # in the try: the saver is closed if it fails
        if telemetry is not None and telemetry.previous is not None:
            print(f"aider-exo walk: the previous log {args.log} was moved to {telemetry.previous}", file=sys.stderr)
        if two_processes:
            outcome, nodes_report = _walk_two_processes(args, cfg, policy, watched, telemetry)
        else:
            def on_tick(result: Any, session: Any, host: Any) -> None:
                watched(result, session)
                if recorder is not None:
                    x = float(host.plant.world.link_frame("trunk")[0][0])
                    recorder.maybe_capture(host.plant.world.client, host.plant.patient.t, camera.follow(x))

            outcome = walk(cfg, cycles=args.steps, seed=args.seed, mode=args.mode, policy=policy,
                           max_time_s=args.max_time, on_tick=on_tick, telemetry=telemetry, channel=channel)
    finally:
        status.close()
        if view is not None:
            view_report = view.close(args.linger)
        log_report = telemetry.close() if telemetry is not None else None
        if saver is not None:
            saver.close()
    summary = outcome.summary()
    summary["cycles_asked"] = args.steps
    if args.virtual_patient:
        summary["virtual_patient"] = virtual_patient.name
    summary["bus"] = f"{cfg.bus.interface}:{cfg.bus.channel}" if two_processes else "virtual (in-process)"
    summary["telemetry"] = log_report
    if saver is not None:
        summary["learned_file"] = {"path": str(saver.path), "writes": saver.writes, "errors": saver.errors}
    if nodes_report is not None:
        summary["nodes"] = nodes_report
    if view_report is not None:
        summary["view"] = view_report
    if recorder is not None and len(recorder):
        summary["render"] = {
            "strip": str(recorder.save_strip(args.render / f"walk-{args.mode}.png", 6)),
            "gif": str(recorder.save_gif(args.render / f"walk-{args.mode}.gif")),
            "frames": len(recorder),
        }
    if args.json:
        print_json(summary)
    else:
        print(_summary_text(summary))
    return 0


def _waiting(patient: dict[str, Any] | None) -> str:
    """Where the patient stood when the walk stalled: its phase and for how long, and in the weight
    shift where its CoM is against the window its next stick lift waits for."""
    if not patient:
        return ""
    where = ""
    if "lift_window_m" in patient:
        lo, hi = patient["lift_window_m"]
        window = f"a stick may lift with it between {lo} and {hi} m" if lo <= hi else "no place to lift a stick from"
        where = f", CoM at {patient['com_x_m']} m, {window}"
    return f": the patient in its {patient['phase']} for {patient['phase_s']} s{where}"


def _summary_text(s: dict[str, Any]) -> str:
    lengths, placed = s["step_length_m"], s["placed_step_m"]
    fall = f"fell: {s['fall_reason']}" if s["falls"] else ("no fall" + (
        f" (FAULT {s['fault']})" if s["fault"] else f" (HOLD {s['hold']})" if s["hold"] else
        f" (stalled{_waiting(s['patient'])})" if s["stalled"] else ""))
    text = (
        f"{s['mode']} walk{' of ' + s['virtual_patient'] if s.get('virtual_patient') else ''}, "
        f"{s['policy']} step length{'' if s['theta'] is None else ' theta ' + str(s['theta'])}, "
        f"seed {s['seed']}: {s['cycles_completed']} of {s['cycles_asked']} gait cycles ({s['steps_completed']} steps), {fall}\n"
        f"  step length {lengths['mean']} m (min {lengths['min']}, max {lengths['max']}; as placed {placed['mean']} m, "
        f"min {placed['min']}, max {placed['max']}), mean stick force "
        f"{s['mean_stick_force_n']} N, upper-body torque {s['mean_arm_torque_nm']} N·m, X_CoM/X_SP error "
        f"{s['x_ratio_mae']} (mean over {s['x_ratio_samples']} ticks)\n"
        f"  {s['sim_time_s']} s simulated in {s['wall_time_s']} s, {s['ticks']} ticks on {s['bus']}; frames rejected "
        f"{s['receiver'].get('rejected', 0)}, lost {s['receiver'].get('lost', 0)}"
    )
    if "render" in s:
        text += f"\n  wrote {s['render']['strip']} and {s['render']['gif']}"
    if "view" in s:
        v = s["view"]
        text += (f"\n  live view at {v['url']}: {v['frames']} frames seen, {v['server']['connects']} browser connections, "
                 f"{v['server']['snapshots']} updates sent")
    if s.get("learned_file"):
        text += f"\n  learned file {s['learned_file']['path']} ({s['learned_file']['writes']} writes)"
    return text


def _walk_two_processes(args: argparse.Namespace, cfg: Any, policy: Any, status: Any, telemetry: Any):
    """The node boards as ``aider-exo nodes`` in a second process on the same bus (SocketCAN or UDP multicast)."""
    from config.errors import AiderError
    from protocol.bus import open_bus
    from tools.pipeline import wait_for_boot_ups, walk_controller

    exe = str(Path(sys.executable).with_name("aider-exo"))
    with tempfile.TemporaryDirectory(prefix="aider-walk-") as tmp:
        truth_path = Path(tmp) / "truth.jsonl"
        cmd = [exe, "nodes", "--bus", cfg.bus.interface, "--channel", cfg.bus.channel, "--lockstep", "--mode", args.mode,
               "--seed", str(args.seed), "--truth", str(truth_path), "--json", "--quiet"]
        if args.config:
            cmd[2:2] = ["--config", args.config]
        estimates: dict[int, float] = {}

        def on_tick(result: Any, session: Any) -> None:
            status(result, session)
            if result.estimate is not None:
                estimates[result.tick] = result.estimate.x_ratio

        # The controller's socket is open before the nodes start, so it keeps their boot-ups; its
        # first SYNC goes out once all four have booted (a deterministic start: no SYNC queues up
        # in the nodes' socket while their simulation loads).
        bus = open_bus(cfg.bus)
        nodes = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            wait_for_boot_ups(cfg.bus, nodes)
            with StopSignals():
                outcome = walk_controller(cfg, bus, cycles=args.steps, seed=args.seed, mode=args.mode, policy=policy,
                                          max_time_s=args.max_time, on_tick=on_tick, telemetry=telemetry)
        finally:
            bus.shutdown()
            if nodes.poll() is None:
                nodes.send_signal(signal.SIGTERM)
            try:
                out, err = nodes.communicate(timeout=30)
            except subprocess.TimeoutExpired:
                nodes.kill()
                out, err = nodes.communicate()
        if nodes.returncode != 0:
            raise AiderError(f"the nodes process exited with {nodes.returncode}: {err.strip().splitlines()[-1:] or ''}")
        try:
            report = json.loads(out)
        except ValueError:
            raise AiderError("the nodes process printed no JSON report") from None
        for line in truth_path.read_text().splitlines():
            row = json.loads(line)
            est = estimates.get(row["tick"])
            if est is not None and math.isfinite(est) and row["x_ratio"] is not None and math.isfinite(row["x_ratio"]):
                outcome.ratio_errors.append(abs(est - row["x_ratio"]))
            if row["fall"] and not outcome.fell:
                outcome.fell, outcome.fall_reason = True, row["fall"]
    outcome.sim_time_s = report.get("sim_time_s", outcome.sim_time_s)
    outcome.patient = report.get("patient")
    return outcome, {"pid": nodes.pid, "syncs": report.get("syncs"), "receiver": report.get("receiver"), "fall": report.get("fall"),
                     "fall_at": report.get("fall_at")}
