"""`nlpcal simulate`: synthetic logs with known truth."""

from __future__ import annotations

from .common import add_command, add_field_argument, emit_table, warn

ATTITUDE_NAMES = ("clustered", "tilt", "tilt_band", "turntable", "uniform")


def register(sub):
    parser = add_command(
        sub,
        "simulate",
        help="write a synthetic log with known truth (to try nlpcal without a sensor)",
        description="""\
Write a synthetic log: a sensor with known offsets, scale errors and axis angles (Eq. 4 of Zhou
et al. 2010) turned through many orientations in a steady field, with white noise; columns bx,
by, bz in nT. 'nlpcal calibrate' on it should find the truth again. The presets liu2022 and
qiu2017 write a folder of logs that replicate those papers' experiments.""",
        examples=(
            "nlpcal simulate -o log.csv && nlpcal calibrate log.csv",
            "nlpcal simulate -n 500 --noise 5 --attitudes tilt --seed 3 -o tilted.csv",
            "nlpcal simulate --noise 5 --attitudes tilt --max-tilt-deg 20 -o tilted.csv",
            "nlpcal simulate --preset liu2022 -o replica/",
        ),
    )
    parser.add_argument(
        "--preset",
        default="zhou2010",
        help="zhou2010: one log with the parameters and field of Zhou et al. (2010) (default); "
        "liu2022, qiu2017: a folder of logs replicating those experiments (needs -o DIR)",
    )
    parser.add_argument(
        "--params",
        metavar="TRUTH.json",
        help='the truth to simulate instead of the preset\'s, e.g. {"parameters": {"z_x": 100, '
        '..., "gamma_deg": 0.2}, "field_nT": 50000}',
    )
    parser.add_argument(
        "-n", type=int, default=None, metavar="N", help="number of samples (default 2000)"
    )
    parser.add_argument(
        "--noise",
        type=float,
        default=None,
        metavar="NT",
        help="white noise per axis [nT] (default 1)",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        metavar="S",
        help="random seed: the same seed gives the same log (default 0)",
    )
    parser.add_argument(
        "--attitudes",
        default="uniform",
        choices=ATTITUDE_NAMES,
        help="how the orientations are spread: uniform over the sphere (default), turntable "
        "(turns about a few axes), tilt (heading free, roll and pitch uniform within "
        "--max-tilt-deg; tilt_band is its earlier name), clustered (a few spots)",
    )
    parser.add_argument(
        "--max-tilt-deg",
        type=float,
        metavar="D",
        help="with --attitudes tilt: the largest roll and pitch, 0 < D <= 90 [deg] (default 30)",
    )
    add_field_argument(
        parser, "field magnitude [nT], e.g. 48000 (default: the preset's)", legacy="--field"
    )
    parser.add_argument(
        "-o",
        "--output",
        metavar="PATH",
        help="output: Parquet for *.parquet, else CSV (stdout when absent); a folder for "
        "folder presets",
    )
    parser.add_argument(
        "--precision",
        type=int,
        default=10,
        metavar="N",
        help="significant digits of the numbers of a CSV output (default 10: 1e-5 nT in a "
        "50 000 nT field)",
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
            warn(f"wrote {path}")
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
    if args.reference_field is not None:
        field = args.reference_field
    frame = sim.simulate(
        2000 if args.n is None else args.n,
        parameters=parameters,
        reference_field=field,
        noise=1.0 if args.noise is None else args.noise,
        seed=args.seed,
        attitudes=args.attitudes,
        max_tilt_deg=args.max_tilt_deg,
    )
    emit_table(frame, args.output, args.precision)
    if args.output:
        warn(f"wrote {len(frame)} samples to {args.output}")
    return 0
