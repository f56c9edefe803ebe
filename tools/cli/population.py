"""``aider-exo population``: virtual patients (docs/POPULATION.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from tools.cli.common import positive_int, print_json, seed_type


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("population", help="draw a population of virtual patients as patient files (docs/POPULATION.md)")
    psub = p.add_subparsers(dest="population_command", metavar="POPULATION_COMMAND", required=True)
    d = psub.add_parser("draw", help="draw N patients for a seed and write one patient file each",
                        description="Draws N virtual patients from the population's documented distributions (the same "
                                    "for the same seed; patient i independent of N) and writes each as a patient file "
                                    "that aider-exo walk --virtual-patient FILE walks.")
    d.add_argument("--patients", type=positive_int, required=True, metavar="N", help="how many patients")
    d.add_argument("--seed", type=seed_type, default=0, help="the population's seed (default 0)")
    d.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder for the patient files (NAME.yaml)")
    d.add_argument("--overwrite", action="store_true", help="replace patient files that exist")
    d.add_argument("--json", action="store_true", help="print the patients as JSON")
    d.set_defaults(func=run_draw)


def run_draw(args: argparse.Namespace) -> int:
    from config import AiderError, config_to_dict
    from config.files import check_output_folder, write_text
    from tools.population import draw_population, patient_yaml

    if args.out.exists() and not args.out.is_dir():
        raise AiderError(f"--out {args.out}: is a file, not a folder (the patient files go into a folder)")
    people = draw_population(args.patients, args.seed)
    paths = [args.out / f"{p.name}.yaml" for p in people]
    existing = [p for p in paths if p.exists()]
    if existing and not args.overwrite:
        raise AiderError(f"{existing[0]} exists (and {len(existing) - 1} more): give --overwrite to replace them")
    check_output_folder(args.out, parents=True, option="--out")
    for person, path in zip(people, paths):
        write_text(path, f"# drawn by aider-exo population draw --patients {args.patients} --seed {args.seed}\n"
                   + patient_yaml(person))
    if args.json:
        print_json({"seed": args.seed, "files": [str(p) for p in paths], "patients": [config_to_dict(p) for p in people]})
    else:
        for person, path in zip(people, paths):
            print(f"{path}: {person.mass_kg} kg, {person.height_m} m, arms {person.arm_strength}, "
                  f"{person.placement.regime} placement, fit {person.fit.length_error_fraction:+.1%} {person.fit.mass_error_kg:+.1f} kg")
    return 0
