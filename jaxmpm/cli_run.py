"""The `jaxmpm run` command: its arguments' checks, the scene with its --set and --opt, the run
(new, or resumed from a restart file), its outputs and its summary; what a stopped run leaves."""

from __future__ import annotations

import argparse
import contextlib
import math
import numbers
import os
import signal
import sys
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path

import jax

import jaxmpm
from jaxmpm import diagnostics, io
from jaxmpm.io.files import remove_stale_temporaries
from jaxmpm.io.plot import plot_run
from jaxmpm.io.scenefile import parse_value
from jaxmpm.model.memory import check_run_memory
from jaxmpm.model.state import State, phase_slices
from jaxmpm.run import compile_cache, restart
from jaxmpm.run.driver import interrupt_on
from jaxmpm.run.restart import dtype
from jaxmpm.scenes import BUILTINS, DEFAULT_SCENE, initial_state
from jaxmpm.scenes.options import builder_options
from jaxmpm.model.scene import Scene


def parse_pairs(items: Sequence[str] | None, flag: str) -> dict:
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


def load_with_options(name: str, overrides: dict, options: dict) -> Scene:
    """The scene `name` (built-in or .toml) with builder options and --set overrides applied."""
    if options and name in BUILTINS:
        parameters = builder_options(BUILTINS[name].build)
        allowed = list(parameters)
        for k, v in options.items():
            if k not in allowed:
                raise ValueError(f"--opt {k} is unknown for scene {name!r}: its options are {allowed}")
            check_option_type(k, v, parameters[k].default)
    return jaxmpm.load_scene(name, overrides=overrides, **options)


def check_option_type(name: str, value: object, default: object) -> None:
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


def stopped(e: KeyboardInterrupt, what: str) -> int:
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


def cmd_run(args: argparse.Namespace) -> int:
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
    # longer than 60 lines on purpose: the run command's steps in order, each a few lines that read and set the
    # same names (paths, the scene, its Params, the history): split further, they would pass most of them around
    path = None
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
    scene, out = scene_and_folder(args, path)
    h5, png = out / f"{scene.name}.h5", out / f"{scene.name}.png"
    xdmf = io.xdmf_path(h5)
    rfile = out / f"{scene.name}.restart.h5"
    if not args.resume and not args.overwrite:
        _check_no_interrupted_run(scene, out, h5, rfile)
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
            return stopped(e, f"{path} holds the progress it saved last: continue with `jaxmpm run --resume {path}`")
        start = diagnostics.summary(scene, params, jax.tree.map(lambda a: None if a is None else a[0], history))
    else:
        t_end = scene.t_end if args.t_end is None else args.t_end
        n_out = scene.n_out if args.n_out is None else args.n_out
        params = jaxmpm.default_params(scene)
        _check_size(scene, n_out, args.x64)
        state = initial_state(scene, params)
        print(run_header(scene, state, t_end, n_out, h5), flush=True)
        start = diagnostics.summary(scene, params, state)
        io.check_space(out, output_bytes(scene, state, n_out, bool(args.restart_every)))
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
            return stopped(
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
    print_summary(
        scene, start, end, wall, (h5, xdmf, png) + ((rfile,) if args.restart_every and not args.resume else ())
    )
    return 0


def _check_no_interrupted_run(scene: Scene, out: Path, h5: Path, rfile: Path) -> None:
    """FileExistsError where `out` holds the restart file `rfile` of an unfinished run (no `h5` yet)."""
    if rfile.is_file() and not h5.exists():
        raise FileExistsError(
            f"{rfile} exists: a run of {scene.name} into {out} was interrupted or failed; continue an "
            f"interrupted run with `jaxmpm run --resume {out}`, or pass --overwrite to start again "
            "(which discards it)"
        )


def run_header(scene: Scene, state: State, t_end: float, n_out: int, h5: Path) -> str:
    """The line `jaxmpm run` prints before a new run: the scene, its grid, particles, phases, end
    time, outputs, precision and output file."""
    phases = f"{len(scene.phases)} phase{'s' if len(scene.phases) > 1 else ''}"
    return (
        f"{scene.name}: {scene.dim}D, grid {'x'.join(map(str, scene.grid.cells))} (h = {scene.grid.h:g} m), "
        f"{state.x.shape[0]} particles in {phases}, to t = {t_end:g} s with {n_out} outputs, "
        f"{state.x.dtype}, into {h5}"
    )


def output_bytes(scene: Scene, state: State, n_out: int, restart: bool) -> int:
    """Bytes a run of `state` with n_out outputs writes: its HDF5 file (n_out + 1 states) and, with
    a restart file, that file (up to n_out + 2 states)."""
    particles, itemsize = state.x.shape[0], state.x.dtype.itemsize
    return io.estimate_bytes(scene, particles, n_out + 1, itemsize) + (
        io.estimate_bytes(scene, particles, n_out + 2, itemsize) if restart else 0
    )


def scene_and_folder(args: argparse.Namespace, path: Path | None) -> tuple[Scene, Path]:
    """(scene, output folder) of `run`: those of the restart file `path` with --resume (refused
    where its run is complete), else the scene named with its --set and --opt, and --out."""
    if path is not None:
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
        scene = load_with_options(args.scene, parse_pairs(args.set, "--set"), parse_pairs(args.opt, "--opt"))
        out = Path(args.out)
    if not scene.name or scene.name in (".", "..") or os.sep in scene.name or "/" in scene.name:
        raise ValueError(f"name = {scene.name!r} is invalid as an output file name: allowed a name without '/'")
    return scene, out


def print_summary(scene: Scene, start: dict, end: dict, wall: float, written: Iterable[Path]) -> None:
    """The run's wall time, its mass and energies at the start and the end, and the files written."""
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
    for p in written:
        print(f"  {p}")


def _check_size(scene, n_out: int, x64: bool) -> None:
    """Before the particles' state is made: refuse a run whose history and grid cannot fit in memory
    (jaxmpm.run.planning.check_run_memory; the particles are counted from the scene's sampling)."""
    check_run_memory(scene, phase_slices(scene)[-1].stop, n_out, 8 if x64 else 4)
