"""`nlpcal simulate`: synthetic logs with known truth."""

from __future__ import annotations

import sys

from .common import emit_csv

#: What --preset accepts (the library's `nlpcal.simulation.PRESETS` and `DIRECTORY_PRESETS`).
PRESET_NAMES = ("zhou2010", "liu2022", "qiu2017")
ATTITUDE_NAMES = ("clustered", "tilt_band", "turntable", "uniform")


def register(sub):
    parser = sub.add_parser(
        "simulate",
        help="write a synthetic log with known truth",
        description="Write a synthetic log (columns bx, by, bz in nT) from the forward model of "
        "Eq. 4, or a folder of logs for the presets that replicate an experiment.",
    )
    parser.add_argument(
        "--preset",
        default="zhou2010",
        help="zhou2010 (one log), or a folder preset: liu2022, qiu2017",
    )
    parser.add_argument(
        "--params",
        metavar="TRUTH.json",
        help='truth: {"parameters": {z_x, ..., gamma_deg}, "field_nT": F}',
    )
    parser.add_argument("-n", type=int, default=None, help="number of samples (default 2000)")
    parser.add_argument(
        "--noise",
        type=float,
        default=None,
        metavar="NT",
        help="white noise per axis [nT] (default 1)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--attitudes",
        default="uniform",
        choices=ATTITUDE_NAMES,
        help="attitude distribution (default uniform)",
    )
    parser.add_argument(
        "--field",
        type=float,
        default=None,
        metavar="NT",
        help="field magnitude [nT] (default: the preset's)",
    )
    parser.add_argument(
        "-o",
        "--output",
        metavar="PATH",
        help="output CSV (stdout when absent); a folder for folder presets",
    )
    parser.set_defaults(func=run)


def run(args) -> int:
    from .. import simulation as sim
    from ..errors import InputError
    from ..io import check_output_path
    from ..results import read_json_document

    if args.preset in sim.DIRECTORY_PRESETS:
        if not args.output:
            raise InputError(f"preset {args.preset} writes a folder of logs; pass -o DIR")
        written = sim.write_directory_preset(
            args.preset, args.output, seed=args.seed, noise=args.noise, n=args.n
        )
        for path in written:
            print(f"wrote {path}", file=sys.stderr)
        return 0
    if args.preset not in sim.PRESETS:
        known = sorted(set(sim.PRESETS) | set(sim.DIRECTORY_PRESETS))
        raise InputError(f"unknown preset {args.preset!r}; expected one of {', '.join(known)}")
    check_output_path(args.output, args.params)
    preset = sim.PRESETS[args.preset]
    parameters, field = preset.parameters, preset.field
    if args.params:
        parameters, given_field = sim.parameters_from_json(
            read_json_document(args.params, "parameters JSON"), str(args.params)
        )
        field = given_field if given_field is not None else field
    if args.field is not None:
        field = args.field
    frame = sim.simulate(
        2000 if args.n is None else args.n,
        parameters=parameters,
        field=field,
        noise=1.0 if args.noise is None else args.noise,
        seed=args.seed,
        attitudes=args.attitudes,
    )
    emit_csv(frame, args.output, "%.10g")  # 10 digits: 1e-5 nT in a 50 000 nT field
    if args.output:
        print(f"wrote {len(frame)} samples to {args.output}", file=sys.stderr)
    return 0
