"""The `jaxmpm` command (also `python -m jaxmpm`).

    jaxmpm run [SCENE|file.toml] [--out DIR] [--t-end S] [--n-out N] [--set key=value ...]
               [--opt name=value ...] [--overwrite] [--no-progress] [--x64] [--debug]
               [--restart-every N] [--yes] [--max-minutes M] [--plot-field NAME]
    jaxmpm run --resume DIR [--overwrite] [--no-progress] [--restart-every N]
    jaxmpm scenes [NAME] [--verbose]
    jaxmpm show FILE.h5 [--png OUT.png] [--overwrite]
    jaxmpm materials [KEY] [--model KIND]

`run` writes <out>/<scene name>.h5 (HDF5), .xdmf (open in ParaView) and .png (a field at several
times and energy against time: `--plot-field`), and
<name>.restart.h5 every N chunks (`--restart-every`, 20 by default, 0: never), from which
`--resume DIR` finishes an interrupted run; it refuses, before simulating, to overwrite any of
them without --overwrite. Bad input (an unknown
scene or key, a value out of range, an existing output) prints `error: <message>` to stderr and
exits with status 2; a run that becomes non-finite exits with status 1. Ctrl-C (SIGINT) or SIGTERM
stops a run after its current chunk with its restart file saved (exit status 130 or 143); a second
one stops it at once.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from collections.abc import Sequence

import jax

from jaxmpm import io
from jaxmpm.materials.library import (
    USED_TABLES,
    constant_origins,
    default_model,
    known_keys,
    library_table,
    table_provenance,
)
from jaxmpm.materials.models import model_of
from jaxmpm.scenes import BUILTINS, DEFAULT_SCENE, describe
from jaxmpm.cli_run import cmd_run, load_with_options, parse_pairs, stopped
from jaxmpm.version import __version__


# the run command's parsing of key=value pairs and its scene loading, under their former names
_pairs = parse_pairs
_load = load_with_options


def cmd_scenes(args: argparse.Namespace) -> int:
    """`jaxmpm scenes [NAME] [--verbose]`: the built-in scenes; with NAME or --verbose, every builder
    option with its default and allowed values (jaxmpm.scenes.options, the table the builders check)."""
    if args.name is not None and args.name not in BUILTINS:
        raise ValueError(f"scene {args.name!r} is not a built-in scene: allowed {' | '.join(BUILTINS)}")
    names = [args.name] if args.name is not None else list(BUILTINS)
    width = max(map(len, BUILTINS))
    for name in names:
        b = BUILTINS[name]
        print(f"{name:<{width}}  {b.summary}{'  [default]' if name == DEFAULT_SCENE else ''}")
        if args.verbose or args.name is not None:
            print(format_scene_options(name))
    if not (args.verbose or args.name is not None):
        print(
            "\n`jaxmpm scenes NAME` (or --verbose): the options of a scene (--opt name=value) with defaults and ranges"
        )
    return 0


def format_scene_options(name: str) -> str:
    """The builder options of the built-in scene `name`, one a line: name, default, allowed values."""
    rows = describe(name)
    w = max(len(k) for k, _, _ in rows)
    d = max(len(repr(v)) for _, v, _ in rows)
    lines = [f"    --opt {k:<{w}}  default {v!r:<{d}}  allowed {words}" for k, v, words in rows]
    return "\n".join(lines)


def cmd_materials(args: argparse.Namespace) -> int:
    if args.key is None and args.model is not None:
        raise ValueError(f"--model {args.model} needs a library key: jaxmpm materials KEY --model {args.model}")
    if args.key is None:
        width = max(map(len, known_keys()))
        print(f"{'key':<{width}}  {'default model':<62}  sub-tables it reads that are not yet verified")
        for key in known_keys():
            model = default_model(key)
            origins = constant_origins(key, model)
            used = {origins[name][1] for name in model_of(model).constants if name in origins}
            unverified = [sub for sub, (_, ok, _) in table_provenance(key).items() if sub in used and not ok]
            print(f"{key:<{width}}  {model:<62}  {', '.join(unverified) or '-'}")
        print("\n`jaxmpm materials KEY`: a key's constants with units, sub-tables and sources")
        return 0
    model = args.model or default_model(args.key)
    origins, prov = constant_origins(args.key, model), table_provenance(args.key)
    needed = model_of(model).constants
    print(f"{args.key}: {library_table()[args.key].get('name', '')}")
    print(f"model: {model}{'  (default)' if model == default_model(args.key) else ''}")
    print(f"  {'constant':<12}{'value':>14}  {'unit':<10}{'sub-table':<11}verified")
    tables = []
    for name, (*_, unit) in needed.items():
        if name not in origins:
            print(f"  {name:<12}{'-':>14}  {unit:<10}{'-':<11}not in the library: give it in the material")
            continue
        value, sub = origins[name]
        tables += [sub] if sub not in tables else []
        print(f"  {name:<12}{value:>14.6g}  {unit:<10}{sub:<11}{'yes' if prov[sub][1] else 'NO'}")
    print("sources (verified: every number of the sub-table was read in its source):")
    for sub in tables:
        source, ok, checks = prov[sub]
        print(f"  {sub} [{'verified' if ok else 'not verified'}]: {source}")
        if "note" in checks:
            print(
                textwrap.fill(
                    f"note ({checks.get('checked', '')}): {' '.join(checks['note'].split())}",
                    100,
                    initial_indent="    ",
                    subsequent_indent="    ",
                )
            )
    others = [sub for sub in prov if sub not in USED_TABLES]
    if others:
        print(f"also in the table, not read by the models (alternative fits): {', '.join(others)}")
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    print(io.summary(args.file))
    if args.png:
        scene, history = io.read(args.file)
        last = jax.tree.map(lambda a: None if a is None else a[-1], history)
        print(f"wrote: {io.plot_state(scene, last, args.png, overwrite=args.overwrite)}")
    return 0


def build_parser() -> argparse.ArgumentParser:

    # longer than 60 lines on purpose: one declaration per command and flag, in the order --help lists them
    parser = argparse.ArgumentParser(prog="jaxmpm", description="Differentiable multiphase MPM in JAX.")
    parser.add_argument("--version", action="version", version=f"jaxmpm {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser(
        "run",
        help="run a scene and write HDF5 + XDMF + PNG",
        description="Run a scene to t_end; write <out>/<name>.h5, .xdmf (ParaView) and .png, and "
        "<name>.restart.h5 for --resume.",
    )
    run.add_argument(
        "scene",
        nargs="?",
        default=None,
        help=f"built-in scene name (see `jaxmpm scenes`) or a .toml file (default: {DEFAULT_SCENE})",
    )
    run.add_argument("--out", default=None, help="output folder (default: out)")
    run.add_argument("--t-end", type=float, help="end time, s (default: the scene's t_end)")
    run.add_argument("--n-out", type=int, help="number of outputs after the initial one (default: the scene's)")
    run.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help="override a scene-file key, e.g. --set 'grid.cells=[32,32]' --set 'phase.disk_a.velocity=[0.2,0.2]' (quoted for the shell)",
    )
    run.add_argument(
        "--opt",
        action="append",
        metavar="NAME=VALUE",
        help="option of a built-in scene's builder, e.g. --opt resolution=0.5",
    )
    run.add_argument("--overwrite", action="store_true", help="replace existing output files")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.add_argument("--x64", action="store_true", help="double precision (float64)")
    run.add_argument(
        "--no-cache",
        action="store_true",
        help="no persistent compilation cache (default: on, in "
        "~/.cache/jaxmpm/xla or $JAXMPM_CACHE_DIR; JAXMPM_NO_CACHE=1 also turns it off)",
    )
    run.add_argument(
        "--debug",
        action="store_true",
        help="check every step under checkify (slower): stop at the first non-finite or out-of-grid "
        "particle, or the first NaN, naming the step",
    )
    run.add_argument(
        "--restart-every",
        type=int,
        default=20,
        metavar="N",
        help="save <out>/<name>.restart.h5 every N chunks and at each output (default 20; 0: never)",
    )
    run.add_argument(
        "--plot-field",
        choices=("speed", "pressure", "damage", "phase"),
        default="speed",
        help="the field the PNG shows at several times, with a colorbar, above energy against time (default: speed)",
    )
    run.add_argument(
        "--yes", action="store_true", help="run even when the estimate after the first chunk passes --max-minutes"
    )
    run.add_argument(
        "--max-minutes",
        type=float,
        default=None,
        metavar="M",
        help="a run estimated (after its first chunk) to take longer stops before saving anything unless "
        "--yes (default: $JAXMPM_MAX_MINUTES, else 60)",
    )
    run.add_argument(
        "--resume",
        metavar="DIR",
        help="continue the run whose restart file is in DIR, or the one named (DIR/NAME.restart.h5: "
        "where DIR holds several); bit-identical to an uninterrupted run",
    )
    run.set_defaults(func=cmd_run)

    scenes = sub.add_parser("scenes", help="list the built-in scenes (with NAME or --verbose: their options)")
    scenes.add_argument(
        "name", nargs="?", default=None, help="a built-in scene: list its options with defaults and ranges"
    )
    scenes.add_argument("--verbose", "-v", action="store_true", help="every scene's options with defaults and ranges")
    scenes.set_defaults(func=cmd_scenes)

    materials = sub.add_parser(
        "materials",
        help="list the material library, or one key's constants and sources",
        description="Without KEY: the library's keys, default models and which of the "
        "sub-tables they read await verification. With KEY: every constant of "
        "the model with its unit, the sub-table it is read from, its source and "
        "whether every number of that sub-table was read in that source.",
    )
    materials.add_argument("key", nargs="?", default=None, help="a library key (e.g. al2024)")
    materials.add_argument("--model", help="another model kind than the key's default, e.g. hypoelastic")
    materials.set_defaults(func=cmd_materials)

    show = sub.add_parser("show", help="summarize an output file (and with --png plot its last output)")
    show.add_argument("file", help="an .h5 file written by `jaxmpm run`")
    show.add_argument("--png", help="write a PNG of the last output here")
    show.add_argument("--overwrite", action="store_true", help="replace an existing PNG")
    show.set_defaults(func=cmd_show)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `jaxmpm` command. Returns the exit status (0 ok, 1 failed run, 2 bad input)."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except FloatingPointError as e:
        print(f"error: the run failed: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as e:  # outside the run's loop (planning, compiling, writing the outputs)
        return stopped(e, "the command did not finish (outputs are written whole or not at all)")


if __name__ == "__main__":
    sys.exit(main())
