"""``aider-exo dmp``: fit the swing DMP to its demonstration and cache the weights."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from config import ConfigError, default_config_path, load_config
from config.files import check_output
from tools.cli.common import print_json


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("dmp", help="fit the swing DMP (weights cached in config/swing_weights.json)")
    dsub = p.add_subparsers(dest="dmp_command", metavar="DMP_COMMAND", required=True)
    f = dsub.add_parser("fit", help="fit the weights to the demonstration and write the cache")
    f.add_argument("--config", help="YAML configuration (default: the packaged one)")
    f.add_argument("--out", type=Path, help="weights file (default: config/swing_weights.json)")
    f.add_argument("--json", action="store_true", help="machine-readable output")
    f.set_defaults(func=run_fit)


def run_fit(args: argparse.Namespace) -> int:
    from controller.dmp import Dmp
    from protocol.clock import TICK_S
    from controller.swing import WEIGHTS_PATH, demonstration, fit_swing, save_swing

    cfg = load_config(args.config or default_config_path())
    if cfg.controller is None:
        raise ConfigError("section required by the swing generator", key="controller")
    out = args.out or WEIGHTS_PATH
    check_output(out, inputs=[args.config or default_config_path()], option="--out")  # before the fit
    weights = fit_swing(cfg.controller)
    path = save_swing(cfg.controller, weights, out)
    # Reproduction error of the fitted DMP on its own demonstration, ticked as the controller will.
    times, xz = demonstration(cfg.controller)
    dmp = Dmp(weights)
    ticks, positions = dmp.rollout(TICK_S, float(times[-1]), substeps=cfg.controller.swing.substeps)
    reference = np.column_stack([np.interp(ticks, times, xz[:, k]) for k in range(xz.shape[1])])
    error_mm = float(np.max(np.linalg.norm(positions - reference, axis=1)) * 1000)
    result = {"file": str(path), "basis_functions": weights.weights.shape[1], "step_m": cfg.controller.swing.demonstration_step_m,
              "duration_s": weights.tau_s, "max_reproduction_error_mm": round(error_mm, 3)}
    if args.json:
        print_json(result)
    else:
        print(f"fitted {result['basis_functions']} basis functions per dimension to the {result['step_m']} m, "
              f"{result['duration_s']} s demonstration; reproduction error {error_mm:.3f} mm; wrote {path}")
    return 0
