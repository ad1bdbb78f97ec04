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
import contextlib
import math
import numbers
import os
import signal
import sys
import textwrap
import threading
import time
from pathlib import Path

import jax

import jaxmpm
from jaxmpm import diagnostics, io
from jaxmpm.run import compile_cache, restart
from jaxmpm.io.files import remove_stale_temporaries
from jaxmpm.io.plot import plot_run
from jaxmpm.io.scenefile import parse_value
from jaxmpm.materials.library import (
    USED_TABLES,
    constant_origins,
    default_model,
    known_keys,
    library_table,
    table_provenance,
)
from jaxmpm.materials.models import model_of
from jaxmpm.model.memory import check_run_memory
from jaxmpm.model.state import phase_slices
from jaxmpm.run.driver import interrupt_on
from jaxmpm.run.restart import dtype
from jaxmpm.scenes import BUILTINS, DEFAULT_SCENE, describe, initial_state
from jaxmpm.scenes.options import builder_options
from jaxmpm.version import __version__


def _pairs(items, flag: str) -> dict:
    """{'key': value} from ['key=value', ...]; values parsed as TOML (numbers, lists, strings)."""
    out = {}
    for item in items or ():
        key, sep, value = item.partition("=")
        example = "grid.h=0.01" if flag == "--set" else "resolution=0.5"
        if not sep or not key.strip():
            raise ValueError(f"{flag} {item!r} is invalid: allowed {flag} key=value (e.g. {flag} {example})")
        if key.strip() in out:
            raise ValueError(
                f"{flag} {key.strip()} is given twice ({out[key.strip()]!r} and {value.strip()!r}): allowed once"
            )
        out[key.strip()] = parse_value(value.strip())
    return out


def _load(name: str, overrides: dict, options: dict):
    """The scene `name` (built-in or .toml) with builder options and --set overrides applied."""
    if options and name in BUILTINS:
        parameters = builder_options(BUILTINS[name].build)
        allowed = list(parameters)
        for k, v in options.items():
            if k not in allowed:
                raise ValueError(f"--opt {k} is unknown for scene {name!r}: its options are {allowed}")
            _check_option_type(k, v, parameters[k].default)
    return jaxmpm.load_scene(name, overrides=overrides, **options)


def _check_option_type(name: str, value, default) -> None:
    """A builder option must be of its default's kind: a number for a number, a string for a string."""

    def number(x):
        return isinstance(x, numbers.Real) and not isinstance(x, bool)

    if number(default) and not number(value):
        raise ValueError(f"--opt {name}={value!r} is invalid: allowed a number (default {default!r})")
    if isinstance(default, str) and not isinstance(value, str):
        raise ValueError(f"--opt {name}={value!r} is invalid: allowed a name (default {default!r})")


def _resume_file(where: str) -> Path:
    """The restart file --resume names: a *.restart.h5 file, or a folder holding exactly one."""
    path = Path(where)
    if path.is_file():
        if not path.name.endswith(".restart.h5"):
            raise ValueError(
                f"--resume {where!r} is invalid: allowed a folder with one *.restart.h5 file, or such a file"
            )
        return path
    if not path.is_dir():
        raise ValueError(
            f"--resume {where!r} does not exist: allowed a folder with one *.restart.h5 file, or such a file"
        )
    files = sorted(path.glob("*.restart.h5"))
    if len(files) != 1:
        raise ValueError(
            f"--resume {where!r}: expected one *.restart.h5 file there, found {[f.name for f in files]}"
            + (f" (name one: --resume {path / files[0].name})" if files else "")
        )
    return files[0]


def _check_run_args(args) -> None:
    """What `run` can check before anything is loaded: --resume continues the saved run as it was
    (its scene, t_end, outputs and settings), and --out names a folder."""
    if args.resume:
        given = [
            flag
            for flag, value in (
                ("a scene", args.scene is not None),
                ("--out", args.out is not None),
                ("--t-end", args.t_end is not None),
                ("--n-out", args.n_out is not None),
                ("--set", bool(args.set)),
                ("--opt", bool(args.opt)),
                ("--debug", args.debug),
            )
            if value
        ]
        if given:
            raise ValueError(
                f"{', '.join(given)} is invalid with --resume: the run continues with the scene, t_end and "
                "outputs of its restart file, in DIR (allowed with --resume: --overwrite, --no-progress, "
                "--restart-every, --x64)"
            )
        return
    args.scene = DEFAULT_SCENE if args.scene is None else args.scene
    args.out = "out" if args.out is None else args.out
    if not args.out.strip():
        raise ValueError("--out '' is invalid: allowed a folder name (new or existing)")
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise ValueError(f"--out {args.out} is a file: allowed a folder (new or existing)")
    if args.t_end is not None and not (math.isfinite(args.t_end) and args.t_end > 0):
        raise ValueError(f"--t-end {args.t_end} is invalid: allowed a finite time > 0 s")
    if args.n_out is not None and args.n_out < 1:
        raise ValueError(f"--n-out {args.n_out} is invalid: allowed an integer >= 1")
    if args.max_minutes is not None and not (args.max_minutes > 0):
        raise ValueError(f"--max-minutes {args.max_minutes} is invalid: allowed a number of minutes > 0")


def _new_folders(out: Path) -> list[Path]:
    """The folders of `out` (itself and those above it) that do not exist yet, deepest first."""
    new = []
    for folder in (out, *out.parents):
        if os.path.lexists(folder):
            break
        new.append(folder)
    return new


@contextlib.contextmanager
def _sigterm_interrupts():
    """SIGTERM handled as Ctrl-C during `run` (on the main thread): the run stops after its chunk
    with its restart file saved, and `finally` blocks delete temporary files."""

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, interrupt_on)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _stopped(e: KeyboardInterrupt, what: str) -> int:
    """Print `what` after the signal that stopped the run; its exit status (128 + the signal)."""
    signum = getattr(e, "signum", signal.SIGINT)
    print(f"\n{'interrupted' if signum == signal.SIGINT else 'terminated'}: {what}", file=sys.stderr)
    return 128 + int(signum)


def _remove_stale_temporaries(out: Path) -> None:
    gone = remove_stale_temporaries(out)
    if gone:
        print(
            f"removed {len(gone)} temporary file{'s' if len(gone) > 1 else ''} that earlier runs killed while "
            f"writing left in {out}: {', '.join(gone)}",
            flush=True,
        )


def cmd_run(args) -> int:
    """`jaxmpm run`; a run that stops (an error, Ctrl-C) before writing anything removes the folders
    it created for --out, so a refused run leaves nothing behind."""
    _check_run_args(args)
    made = [] if args.resume else _new_folders(Path(args.out))

    def remove_empty():
        for folder in made:
            if folder.is_dir() and not any(folder.iterdir()):
                folder.rmdir()

    try:
        with _sigterm_interrupts():
            code = _run(args)
    except BaseException:
        remove_empty()
        raise
    if code != 0:  # interrupted (130): nothing saved yet leaves no folder
        remove_empty()
    return code


def _run(args) -> int:
    if args.resume:
        path = _resume_file(args.resume)
        if dtype(path) == "float64":
            args.x64 = True
    if args.x64:
        jax.config.update("jax_enable_x64", True)
    if not args.no_cache:
        compile_cache.enable()
    if args.restart_every < 0:
        raise ValueError(
            f"--restart-every {args.restart_every} is invalid: allowed an integer >= 0 (0: no restart file)"
        )
    if args.resume:
        saved = restart.load(path)
        scene = saved["scene"]
        out = path.parent
        if saved["next_out"] == saved["n_out"]:
            raise ValueError(
                f"--resume {args.resume}: the run saved in {path} is complete (t_end = {saved['t_end']:g} s "
                f"reached, {saved['n_out']} outputs): nothing to resume; its outputs are written beside "
                f"it, as {scene.name}.h5 (run it again: jaxmpm run with --overwrite)"
            )
    else:
        scene = _load(args.scene, _pairs(args.set, "--set"), _pairs(args.opt, "--opt"))
        out = Path(args.out)
    if not scene.name or scene.name in (".", "..") or os.sep in scene.name or "/" in scene.name:
        raise ValueError(f"name = {scene.name!r} is invalid as an output file name: allowed a name without '/'")
    h5, png = out / f"{scene.name}.h5", out / f"{scene.name}.png"
    xdmf = io.xdmf_path(h5)
    rfile = out / f"{scene.name}.restart.h5"
    if not args.resume and not args.overwrite and rfile.is_file() and not h5.exists():
        raise FileExistsError(
            f"{rfile} exists: a run of {scene.name} into {out} was interrupted or failed; continue an "
            f"interrupted run with `jaxmpm run --resume {out}`, or pass --overwrite to start again "
            "(which discards it)"
        )
    _remove_stale_temporaries(out)
    io.check_new(h5, xdmf, png, *(() if args.resume else (rfile,)), overwrite=args.overwrite)
    wall = time.perf_counter()
    if args.resume:
        print(f"resuming {scene.name} from {path}", flush=True)
        try:
            scene, params, final, history = restart.resume(
                path, progress=not args.no_progress, restart_every=args.restart_every
            )
        except KeyboardInterrupt as e:
            return _stopped(e, f"{path} holds the progress it saved last: continue with `jaxmpm run --resume {path}`")
        start = diagnostics.summary(scene, params, jax.tree.map(lambda a: None if a is None else a[0], history))
    else:
        t_end = scene.t_end if args.t_end is None else args.t_end
        n_out = scene.n_out if args.n_out is None else args.n_out
        params = jaxmpm.default_params(scene)
        _check_size(scene, n_out, args.x64)
        state = initial_state(scene, params)
        phases = f"{len(scene.phases)} phase{'s' if len(scene.phases) > 1 else ''}"
        print(
            f"{scene.name}: {scene.dim}D, grid {'x'.join(map(str, scene.grid.cells))} (h = {scene.grid.h:g} m), "
            f"{state.x.shape[0]} particles in {phases}, to t = {t_end:g} s with {n_out} outputs, "
            f"{state.x.dtype}, into {h5}",
            flush=True,
        )
        start = diagnostics.summary(scene, params, state)
        itemsize = state.x.dtype.itemsize
        io.check_space(
            out,
            io.estimate_bytes(scene, state.x.shape[0], n_out + 1, itemsize)
            + (io.estimate_bytes(scene, state.x.shape[0], n_out + 2, itemsize) if args.restart_every else 0),
        )
        try:
            final, history = jaxmpm.simulate(
                scene,
                params,
                state,
                t_end=t_end,
                n_out=n_out,
                progress=not args.no_progress,
                restart_file=str(rfile) if args.restart_every else None,
                restart_every=args.restart_every or 1,
                debug=args.debug,
                overwrite=args.overwrite,
                yes=args.yes,
                max_minutes=args.max_minutes,
                announce=lambda line: print(line, flush=True),
            )
        except KeyboardInterrupt as e:
            return _stopped(
                e,
                f"its progress is saved in {rfile}: continue with `jaxmpm run --resume {out}`"
                if args.restart_every and rfile.is_file()
                else "nothing was saved (no restart file yet)",
            )
        except FloatingPointError as e:
            if args.restart_every and rfile.is_file():
                e.args = (
                    f"{e}\n{rfile} holds the last state saved before the failure: resuming it meets the same "
                    "failure; fix the scene and start again with --overwrite",
                )
            raise
    jax.block_until_ready(final)
    wall = time.perf_counter() - wall
    end = diagnostics.summary(scene, params, final)
    io.write(h5, scene, history, params=params, overwrite=args.overwrite)
    plot_run(scene, history, png, field=args.plot_field, params=params, overwrite=args.overwrite)
    print(f"done in {wall:.3g} s wall time (compilation included)")
    w = 26
    print(f"  {'':<{w}}{'start':>14}{'end':>14}")
    print(f"  {'t (s)':<{w}}{start['t']:>14.6g}{end['t']:>14.6g}")
    print(
        f"  {'mass (' + io.units('mass', scene.dim, scene.axisymmetric) + ')':<{w}}{start['mass']:>14.6g}{end['mass']:>14.6g}"
    )
    for k in ("kinetic", "internal", "total_energy"):
        name = "total, with gravity" if k == "total_energy" and scene.gravity is not None else k.replace("_energy", "")
        label = f"{name} ({io.units(k, scene.dim, scene.axisymmetric)})"
        print(f"  {label:<{w}}{start[k]:>14.6g}{end[k]:>14.6g}")
    print("wrote:")
    for p in (h5, xdmf, png) + ((rfile,) if args.restart_every and not args.resume else ()):
        print(f"  {p}")
    return 0


def _check_size(scene, n_out: int, x64: bool) -> None:
    """Before the particles' state is made: refuse a run whose history and grid cannot fit in memory
    (jaxmpm.run.planning.check_run_memory; the particles are counted from the scene's sampling)."""
    check_run_memory(scene, phase_slices(scene)[-1].stop, n_out, 8 if x64 else 4)


def cmd_scenes(args) -> int:
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


def cmd_materials(args) -> int:
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


def cmd_show(args) -> int:
    print(io.summary(args.file))
    if args.png:
        scene, history = io.read(args.file)
        last = jax.tree.map(lambda a: None if a is None else a[-1], history)
        print(f"wrote: {io.plot_state(scene, last, args.png, overwrite=args.overwrite)}")
    return 0


def build_parser() -> argparse.ArgumentParser:

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


def main(argv=None) -> int:
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
        return _stopped(e, "the command did not finish (outputs are written whole or not at all)")


if __name__ == "__main__":
    sys.exit(main())
