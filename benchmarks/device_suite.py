"""The GPU checks and benchmarks in one prepared run, for a machine with an accelerator that is
lent for minutes: each step is a subprocess with its own time limit, a step that would not fit in
what is left of --budget is skipped (and says so), every step's output is streamed into one log as
it runs, and the results are packed after every step, so a run stopped at any moment still
returns its log and what it measured.

    python benchmarks/device_suite.py --out DIR [--budget 480] [--quick] [--only STEPS]

Runs from the repository's root with the machine's python3 and PYTHONPATH=. (no install of
jaxmpm). Wheels in ./.whl (e.g. taichi for its CUDA peer) are installed first into /tmp/site
(pip --no-index --no-deps --target) and put on PYTHONPATH; a peer whose module does not import is
skipped with a note. The peer scripts are read from --peers (default ./.whl/peers where it holds
them, else ../shared/bench/peers).
Steps, in order of what the performance issue asks of a GPU:
  device       nvidia-smi -L, jax.devices() with the device's model, versions, the peers' modules
  tests        the transfer forms on the device: every step traced in the GPU form equals the CPU
               form (values and gradients; APIC 2D, DDMP axisymmetric, two fields), no loop in the
               GPU form (pytest, < 1 min)
  throughput3  the peers' scene in 3D at 128^3, 2 particles per cell per axis (1.07 M; the peers
               run as many): jaxmpm APIC and DDMP musl, each in the CPU form and the GPU form (the
               before and after of the GPU forms), against the naive JAX peer (and Taichi on CUDA
               where importable); each jaxmpm row gives its kernels and launches per step
  throughput2  the same in 2D at 512^2 (168 k particles), with Warp on CUDA where importable
  multifield   a 3-field DDMP step against one field (target: <= 2x)
  kernels      kernels and launches per step of APIC, linear and DDMP musl, 2D and 3D, CPU form
               against GPU form, on the device's backend (benchmarks/kernel_count.py)
  grad         the debris cloud's gradient at 100 steps ("steps" checkpointing)
DIR gets two files: suite.log (every step's command, its whole output as it runs, status and
seconds) and results.tar.gz (each step's CSV, markdown and PNG under results/, and suite.log;
`python benchmarks/throughput.py --replot` redraws a table). --quick runs every step at toy sizes:
a dry run of the script on a CPU.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
WHEELS = ROOT / ".whl"
SITE = Path("/tmp/site")

# the form-pair configurations of benchmarks/throughput.py, and the peers that run on a GPU
FORM_ROWS = "jaxmpm-apic-gpuform,jaxmpm-apic-cpuform,jaxmpm-ddmp-musl-gpuform,jaxmpm-ddmp-musl-cpuform"
FORM_TESTS = "gpu_forms_equal and (apic-2d or ddmp-axisymmetric or two-fields-1d) or gpu_form_has_no_loop"


def default_peers() -> str:
    carried = WHEELS / "peers"
    return str(carried if (carried / "jax_mpm.py").is_file() else ROOT.parent / "shared" / "bench" / "peers")


def steps(out: Path, quick: bool, peers: str):
    """(name, command, time limit s) of each step, writing their tables under out; commands run in
    the repository's root."""
    py = sys.executable
    r = out
    pytest = [
        py,
        "-m",
        "pytest",
        "-x",
        "-q",
        "-p",
        "no:cacheprovider",
        "-o",
        "addopts=",
        "tests/test_transfer_forms.py",
        "-k",
    ]
    if quick:
        return [
            ("device", [py, "-c", DEVICE_REPORT], 60),
            ("tests", pytest + ["gpu_forms_equal and apic-1d"], 300),
            (
                "throughput3",
                [
                    py,
                    "benchmarks/throughput.py",
                    "--dim",
                    "3",
                    "--n-grid",
                    "16",
                    "--steps",
                    "5",
                    "--repeats",
                    "1",
                    "--ppc",
                    "2",
                    "--configs",
                    "jaxmpm-apic-gpuform,jaxmpm-apic-cpuform,jax-naive,taichi-cuda",
                    "--peers",
                    peers,
                    "--timeout",
                    "200",
                    "--out",
                    str(r / "throughput_3d.csv"),
                ],
                400,
            ),
            (
                "throughput2",
                [
                    py,
                    "benchmarks/throughput.py",
                    "--n-grid",
                    "32",
                    "--steps",
                    "5",
                    "--repeats",
                    "1",
                    "--ppc",
                    "2",
                    "--configs",
                    "jaxmpm-ddmp-musl-gpuform,jax-naive,warp-cuda",
                    "--peers",
                    peers,
                    "--timeout",
                    "200",
                    "--out",
                    str(r / "throughput.csv"),
                ],
                300,
            ),
            (
                "multifield",
                [
                    py,
                    "benchmarks/multifield_cost.py",
                    "--short",
                    "--n-grid",
                    "32",
                    "--steps",
                    "3",
                    "--repeats",
                    "1",
                    "--out",
                    str(r / "multifield_cost.csv"),
                ],
                300,
            ),
            (
                "kernels",
                [
                    py,
                    "benchmarks/kernel_count.py",
                    "--schemes",
                    "linear-musl",
                    "--dims",
                    "2",
                    "--out",
                    str(r / "kernel_count.csv"),
                ],
                300,
            ),
            ("grad", [py, "benchmarks/grad_cost.py", "--steps", "10", "--modes", "steps", "--out", str(r)], 300),
        ]
    return [
        ("device", [py, "-c", DEVICE_REPORT], 60),
        ("tests", pytest + [FORM_TESTS], 100),
        (
            "throughput3",
            [
                py,
                "benchmarks/throughput.py",
                "--dim",
                "3",
                "--n-grid",
                "128",
                "--steps",
                "100",
                "--repeats",
                "2",
                "--ppc",
                "2",
                "--configs",
                FORM_ROWS + ",jax-naive,taichi-cuda",
                "--peers",
                peers,
                "--timeout",
                "110",
                "--out",
                str(r / "throughput_3d_128.csv"),
            ],
            260,
        ),
        (
            "throughput2",
            [
                py,
                "benchmarks/throughput.py",
                "--n-grid",
                "512",
                "--steps",
                "200",
                "--repeats",
                "2",
                "--ppc",
                "2",
                "--configs",
                FORM_ROWS + ",jax-naive,taichi-cuda,warp-cuda",
                "--peers",
                peers,
                "--timeout",
                "60",
                "--out",
                str(r / "throughput_2d_512.csv"),
            ],
            130,
        ),
        (
            "multifield",
            [
                py,
                "benchmarks/multifield_cost.py",
                "--short",
                "--steps",
                "50",
                "--repeats",
                "3",
                "--out",
                str(r / "multifield_cost.csv"),
            ],
            90,
        ),
        ("kernels", [py, "benchmarks/kernel_count.py", "--out", str(r / "kernel_count_gpu.csv")], 120),
        ("grad", [py, "benchmarks/grad_cost.py", "--steps", "100", "--modes", "steps", "--out", str(r)], 90),
    ]


DEVICE_REPORT = """
import importlib, platform, subprocess, jax
try:
    print(subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=20).stdout.strip())
except (OSError, subprocess.TimeoutExpired) as e:
    print("nvidia-smi:", e)
print("python", platform.python_version(), "jax", jax.__version__, "backend", jax.default_backend())
for d in jax.devices():
    print(d, d.platform, d.device_kind)
for name in ("taichi", "warp"):
    try:
        m = importlib.import_module(name)
        print(name, getattr(m, "__version__", "?"))
    except Exception as e:
        print(name, "not importable:", repr(e)[:120])
"""


def install_wheels(say) -> str | None:
    """Install the wheels of ./.whl into SITE; returns SITE for PYTHONPATH, or None (no wheels, or
    the install failed: said in the log)."""
    wheels = sorted(WHEELS.glob("*.whl")) if WHEELS.is_dir() else []
    if not wheels:
        say("wheels: none in .whl (peers that need a module this python lacks are skipped)")
        return None
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "install",
        "-q",
        "--no-index",
        "--no-deps",
        "--no-compile",
        "--no-cache-dir",
        "--upgrade",
        "--target",
        str(SITE),
    ] + [str(w) for w in wheels]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        ok, text = p.returncode == 0, (p.stdout + p.stderr).strip()
    except subprocess.TimeoutExpired:
        ok, text = False, "timed out after 120 s"
    say(
        f"wheels: {', '.join(w.name for w in wheels)}: {'installed in ' + str(SITE) if ok else 'NOT installed'}"
        + (f"\n{text[-2000:]}" if text else "")
    )
    return str(SITE) if ok else None


def pack(results: Path, out: Path):
    """out/results.tar.gz of the tables under results and the log so far (rewritten after each step)."""
    shutil.copyfile(out / "suite.log", results / "suite.log")
    with tarfile.open(out / "results.tar.gz.part", "w:gz") as tar:
        tar.add(results, arcname="results")
    os.replace(out / "results.tar.gz.part", out / "results.tar.gz")


def run_step(cmd, env, limit, log) -> str:
    """Run cmd in the repository's root with its output streamed into the open log file; kill its
    whole process group at the limit. Returns its status."""
    p = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        return f"rc {p.wait(timeout=limit)}"
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        return f"TIMED OUT after {limit:.0f} s"


def main(argv=None):
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument(
        "--out", required=True, help="folder for suite.log and results.tar.gz (created; must hold no suite.log yet)"
    )
    ap.add_argument("--budget", type=float, default=480.0, help="seconds for all steps together (default 480)")
    ap.add_argument("--quick", action="store_true", help="toy sizes: a dry run of this script")
    ap.add_argument(
        "--peers",
        default=None,
        help="folder of the peer scripts (default ./.whl/peers if there, else ../shared/bench/peers)",
    )
    ap.add_argument("--only", default=None, help="comma-separated step names to run (default: all)")
    a = ap.parse_args(argv)
    if a.budget <= 0:
        ap.error(f"--budget {a.budget} is invalid: allowed seconds > 0")
    out = Path(a.out)
    if (out / "suite.log").exists():
        ap.error(f"--out {out} is invalid: it already holds a suite.log (allowed: a new or empty folder)")
    peers = a.peers or default_peers()
    results = Path(tempfile.mkdtemp(prefix="device_suite_"))  # packed into out: a few files travel back, not many
    plan = steps(results, a.quick, peers)
    if a.only:
        names = {n.strip() for n in a.only.split(",")}
        unknown = sorted(names - {s[0] for s in plan})
        if unknown:
            ap.error(f"--only {','.join(unknown)} is invalid: allowed {', '.join(s[0] for s in plan)}")
        plan = [s for s in plan if s[0] in names]
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    with open(out / "suite.log", "a") as log:

        def say(text):
            print(text, flush=True)
            log.write(text + "\n")
            log.flush()

        say(
            f"device_suite: budget {a.budget:.0f} s{' (quick)' if a.quick else ''}, steps {', '.join(s[0] for s in plan)}; "
            f"peers {peers}"
        )
        site = install_wheels(say)
        paths = [str(ROOT)] + ([site] if site else []) + [p for p in [os.environ.get("PYTHONPATH")] if p]
        env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=os.pathsep.join(paths))
        pack(results, out)
        for name, cmd, limit in plan:
            left = a.budget - (time.perf_counter() - start)
            if left < min(limit, 30):
                say(f"\n== {name}: SKIPPED, {left:.0f} s of the budget left (its limit {limit} s)")
                continue
            limit = min(limit, left)
            say(f"\n== {name} (limit {limit:.0f} s, {left:.0f} s left): {' '.join(cmd)}")
            begin = log.tell()
            t0 = time.perf_counter()
            status = run_step(cmd, env, limit, log)
            log.seek(0, os.SEEK_END)
            with open(out / "suite.log") as f:  # the step's tail on the console too
                f.seek(begin)
                tail = f.read().strip().splitlines()[-30:]
            print("\n".join(tail), flush=True)
            log.write(f"== {name}: {status}, {time.perf_counter() - t0:.0f} s\n")
            log.flush()
            print(f"== {name}: {status}, {time.perf_counter() - t0:.0f} s", flush=True)
            pack(results, out)
        say(f"\ndevice_suite: done in {time.perf_counter() - start:.0f} s; {out / 'results.tar.gz'}")
        pack(results, out)


if __name__ == "__main__":
    main()
