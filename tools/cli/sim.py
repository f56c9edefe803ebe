"""``aider-exo sim``: walk the simulated HHEA with the scripted exoskeleton gait.

* ``sim sweep``: fixed step lengths x seeds, cycles walked, falls (phase, support margin), mean
  stick force and upper-body torque per length;
* ``sim walk``: one walk, optionally in a PyBullet window (``--gui``);
* ``sim render``: one walk rendered offscreen to a PNG strip and an animated GIF.

Every result names the model mode that produced it (``full3d`` or ``sagittal``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from config import ConfigError, default_config_path, load_config
from config.files import check_output_folder
from tools.cli.common import add_mode_option, bounded, positive_float, positive_int, print_json, seed_type


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sim", help="walk the simulated HHEA (sweeps, single walks, rendering)")
    sim_sub = p.add_subparsers(dest="sim_command", metavar="SIM_COMMAND", required=True)

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--config", help="YAML configuration (default: the packaged one)")
        add_mode_option(sp)
        sp.add_argument("--json", action="store_true", help="machine-readable output")

    sw = sim_sub.add_parser("sweep", help="fixed step lengths x seeds: cycles walked, falls, effort")
    common(sw)
    sw.add_argument("--lengths", default="0.10,0.12,0.14,0.16,0.18,0.20", help="step lengths in m, comma-separated")
    sw.add_argument("--seeds", type=positive_int, default=5, help="seeds per length (0..N-1)")
    sw.add_argument("--cycles", type=positive_int, default=10, help="gait cycles per walk (two steps each)")
    sw.add_argument("--processes", type=positive_int, default=2, help="parallel worker processes")
    sw.set_defaults(func=run_sweep)

    wk = sim_sub.add_parser("walk", help="one walk at a fixed step length")
    common(wk)
    wk.add_argument("--length", type=_length, default=0.12, help="step length in m (0.02..0.5)")
    wk.add_argument("--seed", type=seed_type, default=0)
    wk.add_argument("--cycles", type=positive_int, default=10)
    wk.add_argument("--gui", action="store_true", help="open a PyBullet window")
    wk.add_argument("--max-time", type=positive_float, default=120.0, metavar="S", help="simulated seconds before a walk counts as stalled")
    wk.set_defaults(func=run_walk)

    rd = sim_sub.add_parser("render", help="render one walk to a PNG strip and a GIF")
    common(rd)
    rd.add_argument("--length", type=_length, default=0.12, help="step length in m (0.02..0.5)")
    rd.add_argument("--seed", type=seed_type, default=0)
    rd.add_argument("--cycles", type=positive_int, default=3)
    rd.add_argument("--out", type=Path, default=Path("docs"), help="output folder (default docs/)")
    rd.set_defaults(func=run_render)


def _sim_config(args: argparse.Namespace):
    cfg = load_config(args.config or default_config_path())
    if cfg.sim is None:
        raise ConfigError("section required by the simulation", key="sim")
    from sim.sweep import with_mode

    return with_mode(cfg.sim, args.mode) if args.mode else cfg.sim


#: the step lengths a fixed-step walk accepts (--length, --lengths), m
LENGTH_MIN_M, LENGTH_MAX_M = 0.02, 0.5


def _lengths(text: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"--lengths: {text!r} is not a comma-separated list of numbers") from None
    if not values or any(not LENGTH_MIN_M <= v <= LENGTH_MAX_M for v in values):
        raise ConfigError(f"--lengths: every step length must lie in {LENGTH_MIN_M}..{LENGTH_MAX_M} m")
    return values


_length = bounded(float, LENGTH_MIN_M, LENGTH_MAX_M, "step length", " m")  # one step length, within the bounds of --lengths


def run_sweep(args: argparse.Namespace) -> int:
    from sim.sweep import run_sweep as sweep

    cfg = _sim_config(args)

    def progress(row: dict, done: int, total: int) -> None:
        fell = f"fell in {row['fall_phase']} ({row['fall_reason']})" if row["fell"] else "no fall"
        print(f"[{done}/{total}] {row['step_length_m']:.2f} m seed {row['seed']}: "
              f"{row['cycles_completed']} cycles, {fell}", file=sys.stderr, flush=True)

    result = sweep(cfg, _lengths(args.lengths), list(range(args.seeds)), args.cycles, processes=args.processes, progress=progress)
    if args.json:
        print_json(result)
        return 0
    print(f"fixed-step sweep, {result['mode']} mode, {args.cycles} gait cycles per walk, {args.seeds} seeds")
    print(f"{'step m':>7}{'cycles mean':>12}{'min':>5}{'full':>6}{'falls':>6}{'stalls':>7}  {'fall phases':<22}{'margin m':>9}{'stick N':>9}{'arm N.m':>9}")
    for row in result["table"]:
        margin = "" if row["fall_margin_m_mean"] is None else f"{row['fall_margin_m_mean']:.3f}"
        force = "" if row["mean_stick_force_n"] is None else f"{row['mean_stick_force_n']:.0f}"
        torque = "" if row["mean_arm_torque_nm"] is None else f"{row['mean_arm_torque_nm']:.0f}"
        print(f"{row['step_length_m']:>7.2f}{row['cycles_walked_mean']:>12.1f}{row['cycles_walked_min']:>5}"
              f"{row['full_walks']:>4}/{row['episodes']}{row['falls']:>6}{row['stalls']:>7}  {','.join(row['fall_phases']):<22}{margin:>9}{force:>9}{torque:>9}")
    return 0


def run_walk(args: argparse.Namespace) -> int:
    from sim.sweep import episode_summary
    from sim.walk import gait_settings, walk

    cfg = _sim_config(args)
    if not args.max_time > 0:
        raise ConfigError("--max-time must be positive")
    result = walk(cfg, gait_settings(cfg, step_length_m=args.length), seed=args.seed, max_steps=2 * args.cycles, gui=args.gui,
                  max_time_s=args.max_time)
    summary = dict(episode_summary(result), mode=cfg.mode)
    if args.json:
        print_json(summary)
    else:
        fall = f"fell in the {summary['fall_phase']} phase: {summary['fall_reason']}" if summary["fell"] else "no fall"
        if not summary["fell"] and summary["cycles_completed"] < args.cycles:
            fall += " (stalled: the patient waited for a safe stick move)"
        print(f"{cfg.mode}: {summary['steps_completed']} steps ({summary['cycles_completed']} cycles) in "
              f"{summary['simulated_s']} s, {fall}; mean stick force {summary['mean_stick_force_n']} N, "
              f"upper-body torque {summary['mean_arm_torque_nm']} N.m")
    return 0


def run_render(args: argparse.Namespace) -> int:
    from sim.render import Camera, Recorder
    from sim.sweep import episode_summary
    from sim.walk import gait_settings, walk

    cfg = _sim_config(args)
    check_output_folder(args.out, parents=True, option="--out")  # before the walk, not after it
    camera = Camera(target_xyz=(0.3, 0.0, 0.7), distance_m=2.8, yaw_deg=20.0, pitch_deg=-10.0, width_px=320, height_px=240)
    recorder = Recorder(every_n=5)

    def on_tick(world, t: float) -> None:
        base_x = world.link_frame("trunk")[0][0]
        recorder.maybe_capture(world.client, t, camera.follow(float(base_x)))

    result = walk(cfg, gait_settings(cfg, step_length_m=args.length), seed=args.seed, max_steps=2 * args.cycles, on_tick=on_tick)
    gif = recorder.save_gif(args.out / f"hhea-walk-{cfg.mode}.gif")
    strip = recorder.save_strip(args.out / f"hhea-walk-{cfg.mode}.png", 6)
    summary = dict(episode_summary(result), mode=cfg.mode, gif=str(gif), strip=str(strip), frames=len(recorder))
    if args.json:
        print_json(summary)
    else:
        print(f"{cfg.mode}: {summary['steps_completed']} steps, {'fell' if summary['fell'] else 'no fall'}; "
              f"wrote {strip} and {gif} ({summary['frames']} frames)")
    return 0
