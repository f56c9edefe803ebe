"""aider-exo experiment: the paper's experiments through the whole pipeline (docs/EXPERIMENTS.md).

The paper's experiments (section IV) through the real pipeline: the controller, CAN frames on a
virtual bus, the node boards and the simulation, in lock-step, one walk per roll-out, walks in
parallel worker processes. Deterministic for the seeds; every finished walk is kept under OUT/cache,
so an interrupted run resumes where it stopped.
"""

from __future__ import annotations

import argparse
import contextlib
import shutil
import sys
from pathlib import Path

from tools.cli.common import StopSignals, add_config_options, add_mode_option, load_cli_config, positive_int, print_json, sim_mode, seed_type

DEFAULT_OUT = Path("build/experiment")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "experiment",
        help="reproduce the paper's experiments (learning curves, adaptive against fixed steps)",
        description=__doc__,
    )
    xsub = p.add_subparsers(dest="experiment", metavar="EXPERIMENT", required=True)

    def common(sp: argparse.ArgumentParser) -> None:
        add_config_options(sp)
        sp.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a configuration value, e.g. controller.learning.noise_alpha=0.5 (repeatable)")
        sp.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output folder (default {DEFAULT_OUT})")
        sp.add_argument("--workers", type=int, default=2,
                        help="worker processes (default 2; 0 runs in this process); with --executor ray and no --address, "
                             "the local Ray instance's CPUs (0: all of this machine's)")
        sp.add_argument("--executor", choices=("local", "ray"), default="local",
                        help="local: a pool of worker processes here (default); ray: every walk a Ray task (docs/CLUSTER.md)")
        sp.add_argument("--address", metavar="ADDR",
                        help="--executor ray: the cluster to join (host:port, or auto); default: start a local Ray instance")
        add_mode_option(sp)
        sp.add_argument("--fresh", action="store_true", help="discard the stored walks of OUT/cache first")
        sp.add_argument("--json", action="store_true", help="print summary.json on stdout")
        sp.add_argument("--quiet", action="store_true", help="no progress bar")

    def seeds(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--seed", type=seed_type, default=0, help="first seed (default 0)")
        sp.add_argument("--seeds", type=positive_int, default=1, metavar="N", help="learning runs per start: seeds S..S+N-1 (default 1)")
        sp.add_argument("--updates", type=positive_int, default=15, help="PI² updates per learning run (default 15)")
        design(sp)

    def design(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--unpaired", action="store_true",
                        help="every roll-out its own patient seed (default: the roll-outs of an update share one, "
                             "common random numbers; docs/EXPERIMENTS.md)")
        sp.add_argument("--evaluation-walks", type=positive_int, default=5, metavar="W",
                        help="noise-free walks per update on fixed seeds, their mean cost the learning curve's (default 5)")

    lp = xsub.add_parser("learn", help="online PI² from the paper's starts (Fig. 7)")
    common(lp)
    seeds(lp)
    lp.add_argument("--init", action="append", choices=("A", "B"), metavar="A|B",
                    help="the paper's starting point: A = (Xhat 0.6, alpha -1.0), B = (Xhat 0.9, alpha -0.4); repeatable (default both)")
    lp.set_defaults(func=run_learn)

    cp = xsub.add_parser("compare", help="the adaptive gait against fixed step lengths 0.10-0.20 m (Figs. 8, 12)")
    common(cp)
    cp.add_argument("--seed", type=seed_type, default=0, help="seed of the compared walks (default 0)")
    cp.add_argument("--theta", type=float, nargs=2, metavar=("ALPHA", "XHAT"),
                    help="the adaptive gait's theta (default: the configured controller.compensation)")
    cp.add_argument("--walks", type=positive_int, default=10, help="walks (seeds) per gait (default 10)")
    cp.set_defaults(func=run_compare)

    def walks_and_span(sp: argparse.ArgumentParser, walks: int, walks_help: str, lo: float, hi: float, step: str) -> None:
        sp.add_argument("--seed", type=seed_type, default=0, help="seed of the walks (default 0)")
        sp.add_argument("--walks", type=positive_int, default=walks, help=f"{walks_help} (default {walks})")
        sp.add_argument("--min", type=float, default=lo, dest="min_m", help=f"shortest {step}, m (default {lo})")
        sp.add_argument("--max", type=float, default=hi, dest="max_m", help=f"longest {step}, m (default {hi})")

    fp = xsub.add_parser("falls", help="walks with random step lengths: what makes the model fall, and whether X_CoM/X_SP tells")
    common(fp)
    walks_and_span(fp, 30, "walks", 0.09, 0.19, "step drawn")
    fp.set_defaults(func=run_falls)

    ip = xsub.add_parser("intention", help="fixed step lengths crossed with X_CoM/X_SP bins: which step fits which intention")
    common(ip)
    walks_and_span(ip, 10, "walks (patients) per step length", 0.06, 0.22, "step")
    ip.add_argument("--every", type=float, default=0.02, dest="every_m", help="step length spacing, m (default 0.02)")
    ip.add_argument("--bins", type=positive_int, default=4, help="X_CoM/X_SP bins of equal counts (default 4)")
    ip.add_argument("--regime", choices=("steady", "noisy", "drifting", "obstacle"), default="noisy",
                    help="the patient's intention (sim.patient.intention.regime; default noisy: the bins need a varying one)")
    ip.add_argument("--spread", type=float, metavar="M",
                    help="its spread, m (sim.patient.intention.spread_m; default the configured one)")
    ip.add_argument("--bin-by", choices=("stance", "planted", "intention"), default="stance",
                    help="bin the swings by X_CoM/X_SP at their start over the support that carries the swing (stance: "
                         "the stance ankle and both tips, the compensation's input, default), over both ankles and both "
                         "tips (planted), or by the patient's intention (the physics alone)")
    ip.set_defaults(func=run_intention)

    mp = xsub.add_parser("costmap", help="the noise-free cost of a grid of theta, the learning runs drawn on it",
                         description="Walks every theta = (alpha, Xhat_CoM) of an N x N grid on the same W patient seeds and "
                                     "maps their mean cost (equation (11)): its minimum, the theta within 3 % of it, and the "
                                     "learning runs of --learning drawn on it (docs/EXPERIMENTS.md).")
    common(mp)
    mp.add_argument("--seed", type=seed_type, default=0, help="seed of the map's walks (default 0)")
    mp.add_argument("--grid", type=positive_int, default=7, metavar="N", help="grid points per parameter (default 7)")
    mp.add_argument("--walks", type=positive_int, default=5, metavar="W", help="paired walks per theta (default 5)")
    mp.add_argument("--alpha", type=float, nargs=2, default=costmap_spans()[0], metavar=("LO", "HI"),
                    help="alpha's span, m (default %(default)s)")
    mp.add_argument("--xhat", type=float, nargs=2, default=costmap_spans()[1], metavar=("LO", "HI"),
                    help="Xhat_CoM's span (default %(default)s)")
    mp.add_argument("--learning", type=Path, metavar="SUMMARY",
                    help="summary.json of `experiment learn` or `all` whose runs to draw (default OUT/summary.json when it has them)")
    mp.set_defaults(func=run_costmap)

    pp = xsub.add_parser("population", help="per virtual patient: learning from A, then the learned gait against fixed step lengths",
                         description="Draws N virtual patients for a seed (docs/POPULATION.md; or takes patient files), and for each "
                                     "learns from the paper's start A, then compares the learned gait with the fixed step lengths "
                                     "0.10-0.20 m on that patient. The report gives the distribution over the patients: the stick "
                                     "force against the best fixed length that never fell, falls per gait, updates to converge, and "
                                     "the learned theta against the patient; figures, CSV, summary.json.")
    common(pp)
    pp.add_argument("--patients", type=positive_int, default=8, metavar="N", help="patients to draw (default 8)")
    pp.add_argument("--seed", type=seed_type, default=0, help="the population's seed (default 0)")
    pp.add_argument("--patient-file", type=Path, action="append", metavar="FILE",
                    help="a patient file (config/patients/*.yaml) instead of drawing; repeatable")
    pp.add_argument("--updates", type=positive_int, default=15, help="PI² updates per patient (default 15)")
    design(pp)
    pp.add_argument("--walks", type=positive_int, default=10, help="walks (seeds) per gait in each comparison (default 10)")
    pp.set_defaults(func=run_population)

    ap = xsub.add_parser("all", help="learning from A and B, then the comparison with the learned theta; figures, CSV, report")
    common(ap)
    seeds(ap)
    ap.add_argument("--walks", type=positive_int, default=10, help="walks (seeds) per gait in the comparison (default 10)")
    ap.set_defaults(func=run_all)


def _design(args: argparse.Namespace):
    from tools.experiment.learn import RolloutDesign

    return RolloutDesign(paired=not args.unpaired, evaluation_walks=args.evaluation_walks)


def _plan(args: argparse.Namespace, **kw):
    from config import parse_override, with_overrides
    from tools.experiment.experiment import Plan
    from tools.experiment.runner import ExperimentError

    cfg = load_cli_config(args)
    if args.set:
        cfg = with_overrides(cfg, dict(parse_override(s) for s in args.set))
    if cfg.controller is None or cfg.sim is None:
        raise ExperimentError("the experiments need the controller and sim sections of the configuration")
    args.mode = sim_mode(args, cfg)
    if args.workers < 0:
        raise ExperimentError(f"--workers must be >= 0, got {args.workers}")
    from config.files import check_output_folder

    check_output_folder(args.out, parents=True, option="--out")  # a file of that name: one line, before any walk
    if args.fresh and (args.out / "cache").exists():
        shutil.rmtree(args.out / "cache")
    if args.address and args.executor != "ray":
        raise ExperimentError("--address is the Ray cluster's: give it with --executor ray")
    return Plan(cfg=cfg, out=args.out, mode=args.mode, workers=args.workers, executor=args.executor, address=args.address, **kw)


def _finish(args: argparse.Namespace, plan) -> int:
    from tools.experiment import experiment
    from tools.experiment.report import write_all

    with StopSignals() as signals, _stdout_for_the_report():
        res = experiment.run(plan, progress=not args.quiet, stop=lambda: signals.requested)
    s = write_all(res, args.out)
    if args.json:
        print_json(s)
    else:
        print((args.out / "report.md").read_text())
        print(f"written to {args.out}/: summary.json, report.md, CSV data and PNG figures", file=sys.stderr)
    return 0


def run_learn(args: argparse.Namespace) -> int:
    plan = _plan(args, seeds=list(range(args.seed, args.seed + args.seeds)), starts=sorted(set(args.init or ["A", "B"])),
                 updates=args.updates, design=_design(args))
    return _finish(args, plan)


def run_compare(args: argparse.Namespace) -> int:
    plan = _plan(args, seeds=[args.seed], compare=True, compare_walks=args.walks)
    c = plan.cfg.controller.compensation
    plan.compare_theta = (args.theta[0], args.theta[1]) if args.theta else (c.alpha, c.xhat_com)
    return _finish(args, plan)


def run_all(args: argparse.Namespace) -> int:
    plan = _plan(args, seeds=list(range(args.seed, args.seed + args.seeds)), starts=["A", "B"], updates=args.updates, design=_design(args),
                 compare=True, compare_walks=args.walks)
    return _finish(args, plan)


def _check_span(plan, lo: float, hi: float) -> None:
    from tools.experiment.runner import ExperimentError

    from controller.factory import step_bounds

    bounds = step_bounds(plan.cfg.controller)
    if not bounds.min_m <= lo <= hi <= bounds.max_m:
        raise ExperimentError(f"--min {lo} and --max {hi} must lie in the safe range "
                              f"[{bounds.min_m:.3f}, {bounds.max_m:.3f}] m (controller.step), min <= max")


def _walk_batch(args: argparse.Namespace, plan, jobs) -> list:
    """Every job of ``jobs`` on the pool (progress bar, stored under OUT/cache, a stop keeps them)."""
    from tools.experiment.experiment import Progress
    from tools.experiment.runner import WalkPool
    from tools.experiment.schedule import batch, drive

    bar = Progress(len(jobs), enabled=not args.quiet)
    with StopSignals() as signals, _stdout_for_the_report(), WalkPool(plan.cfg, plan.workers, args.out / "cache", on_done=bar,
                                                                      executor=plan.executor, address=plan.address) as pool:
        return drive(pool, {"batch": batch(jobs)}, stop=lambda: signals.requested)["batch"]


def _stdout_for_the_report():
    """While the walks run, what anything writes to stdout goes to stderr: stdout is the report's
    and ``--json``'s alone (Ray's driver prints a dead worker's notice to stdout)."""
    return contextlib.redirect_stdout(sys.stderr)


def _print(args: argparse.Namespace, summary: dict, lines: list[str], files: str) -> int:
    if args.json:
        print_json(summary)
    else:
        print("\n".join(lines))
        print(f"written to {args.out}/: {files}", file=sys.stderr)
    return 0


def run_falls(args: argparse.Namespace) -> int:
    from tools.experiment.falls import falls_jobs, report_lines
    from tools.experiment.report import write_falls

    plan = _plan(args)
    _check_span(plan, args.min_m, args.max_m)
    jobs = falls_jobs(seed=args.seed, walks=args.walks, span=(args.min_m, args.max_m), cycles=plan.cycles, mode=args.mode)
    s = write_falls(_walk_batch(args, plan, jobs), args.out)
    return _print(args, s, report_lines(s), "falls.csv, falls.json, falls.md, falls.png")


def run_intention(args: argparse.Namespace) -> int:
    from tools.experiment.intention import intention_jobs, lengths, report_lines
    from tools.experiment.report import write_intention
    from tools.experiment.runner import ExperimentError

    args.set = [*args.set, f"sim.patient.intention.regime={args.regime}"]
    if args.spread is not None:
        args.set.append(f"sim.patient.intention.spread_m={args.spread}")
    plan = _plan(args)
    _check_span(plan, args.min_m, args.max_m)
    if args.every_m <= 0:
        raise ExperimentError(f"--every must be > 0, got {args.every_m}")
    grid = lengths(args.min_m, args.max_m, args.every_m)
    jobs = intention_jobs(seed=args.seed, walks=args.walks, lengths_m=grid, cycles=plan.cycles, mode=args.mode)
    s = write_intention(_walk_batch(args, plan, jobs), args.out, args.bins, args.bin_by)
    return _print(args, s, report_lines(s), "intention.csv, intention.json, intention.md, intention.png")


def costmap_spans() -> tuple[list[float], list[float]]:
    from tools.experiment.costmap import ALPHA_SPAN, XHAT_SPAN

    return list(ALPHA_SPAN), list(XHAT_SPAN)


def run_costmap(args: argparse.Namespace) -> int:
    from tools.experiment import costmap
    from tools.experiment.report import write_costmap

    plan = _plan(args)
    grid = costmap.Grid.spanning(args.grid, tuple(args.alpha), tuple(args.xhat))
    costmap.check_span(grid, plan.cfg)
    learning = _learning_summary(args.learning or args.out / "summary.json", given=args.learning is not None)
    jobs = costmap.costmap_jobs(grid, seed=args.seed, walks=args.walks, cycles=plan.cycles, mode=args.mode,
                                ends=costmap.learned_ends(learning))
    s = write_costmap(_walk_batch(args, plan, jobs), args.out, grid, args.walks, plan.cfg, learning)
    return _print(args, s, costmap.report_lines(s), "costmap.csv, costmap.json, costmap.md, costmap.png")


def _learning_summary(path: Path, given: bool) -> dict | None:
    """The ``learning`` part of an experiment's summary.json (None when there is none and it was not asked for)."""
    import json

    from tools.experiment.runner import ExperimentError

    if not path.is_file():
        if given:
            raise ExperimentError(f"--learning {path}: no such file")
        return None
    try:
        learning = json.loads(path.read_text()).get("learning")
    except (OSError, ValueError, AttributeError) as exc:
        raise ExperimentError(f"{path}: not an experiment's summary.json ({exc})") from None
    if learning is None and given:
        raise ExperimentError(f"{path}: has no learning runs (from `experiment learn` or `all`)")
    return learning


def run_population(args: argparse.Namespace) -> int:
    from config.loader import load_as
    from config.patient_schema import VirtualPatient
    from tools.experiment import population
    from tools.experiment.experiment import Progress
    from tools.experiment.population_report import write_population
    from tools.population import draw_population, patient_config

    base = _plan(args)  # the configuration, the executor and the checks every experiment shares
    if args.patient_file:
        patients = [load_as(VirtualPatient, f) for f in args.patient_file]
        for patient, f in zip(patients, args.patient_file):
            patient_config(base.cfg, patient, source=str(f))  # a patient the model cannot build fails now, naming its file
    else:
        patients = draw_population(args.patients, args.seed)
    plan = population.PopulationPlan(cfg=base.cfg, out=args.out, patients=patients, seed=args.seed, updates=args.updates,
                                     design=_design(args), compare_walks=args.walks, mode=args.mode, workers=args.workers, executor=args.executor,
                                     address=args.address)
    bar = Progress(len(patients) * plan.walks_per_patient(), enabled=not args.quiet)
    with StopSignals() as signals, _stdout_for_the_report():
        res = population.run(plan, on_done=bar, stop=lambda: signals.requested)
    s = write_population(res, args.out)
    return _print(args, s, (args.out / "report.md").read_text().splitlines(),
                  "summary.json, patients.csv, gaits.csv, population-gaits.png, population-theta.png, report.md")
