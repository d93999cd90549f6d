"""`nlpcal simulate`: synthetic logs with known truth."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

from ..errors import InputError
from ..io import read_json
from . import emit_csv
from ..simulate import ATTITUDES, PRESETS, parameters_from_json, simulate

#: Presets that write a folder of logs rather than one CSV: name -> "module:function".
#: The function is called as f(out_dir: pathlib.Path, *, seed: int, noise: float | None,
#: n: int | None) and returns the list of files it wrote (it must write them atomically).
DIRECTORY_PRESETS = {
    "qiu2017": "nlpcal.compass:write_qiu2017_replica",
    "liu2022": "nlpcal.drift:write_liu2022_replica",
}


def register(sub):
    parser = sub.add_parser(
        "simulate", help="write a synthetic log with known truth",
        description="Write a synthetic log (columns bx, by, bz in nT) from the forward model of "
                    "Eq. 4, or a folder of logs for the presets that replicate an experiment.")
    parser.add_argument("--preset", default="zhou2010",
                        help="zhou2010 (one log), or a folder preset: "
                             + ", ".join(sorted(DIRECTORY_PRESETS) or ["none installed"]))
    parser.add_argument("--params", metavar="TRUTH.json",
                        help="truth: {\"parameters\": {z_x, ..., gamma_deg}, \"field_nT\": F}")
    parser.add_argument("-n", type=int, default=None, help="number of samples (default 2000)")
    parser.add_argument("--noise", type=float, default=None, metavar="NT",
                        help="white noise per axis [nT] (default 1)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--attitudes", default="uniform", choices=sorted(ATTITUDES),
                        help="attitude distribution (default uniform)")
    parser.add_argument("--field", type=float, default=None, metavar="NT",
                        help="field magnitude [nT] (default: the preset's)")
    parser.add_argument("-o", "--output", metavar="PATH",
                        help="output CSV (stdout when absent); a folder for folder presets")
    parser.set_defaults(func=run)


def run(args) -> int:
    if args.preset in DIRECTORY_PRESETS:
        if not args.output:
            raise InputError(f"preset {args.preset} writes a folder of logs; pass -o DIR")
        module, _, name = DIRECTORY_PRESETS[args.preset].partition(":")
        writer = getattr(importlib.import_module(module), name)
        out_dir = Path(args.output)
        if out_dir.exists() and not out_dir.is_dir():
            raise InputError(f"{out_dir}: exists and is not a folder")
        out_dir.mkdir(parents=True, exist_ok=True)
        written = writer(out_dir, seed=args.seed, noise=args.noise, n=args.n)
        for path in written:
            print(f"wrote {path}", file=sys.stderr)
        return 0
    if args.preset not in PRESETS:
        known = sorted(set(PRESETS) | set(DIRECTORY_PRESETS))
        raise InputError(f"unknown preset {args.preset!r}; expected one of {', '.join(known)}")
    preset = PRESETS[args.preset]
    parameters, field = preset.parameters, preset.field
    if args.params:
        parameters, given_field = parameters_from_json(read_json(args.params, "parameters JSON"))
        field = given_field if given_field is not None else field
    if args.field is not None:
        field = args.field
    frame = simulate(2000 if args.n is None else args.n, parameters=parameters, field=field,
                     noise=1.0 if args.noise is None else args.noise, seed=args.seed,
                     attitudes=args.attitudes)
    emit_csv(frame, args.output, "%.10g")  # 10 digits: 1e-5 nT in a 50 000 nT field
    if args.output:
        print(f"wrote {len(frame)} samples to {args.output}", file=sys.stderr)
    return 0
