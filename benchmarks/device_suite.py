"""The GPU checks and benchmarks in one prepared run, for a machine with an accelerator that is
lent for minutes: each step is a subprocess with its own time limit, a step that would not fit in
what is left of --budget is skipped (and says so), and the results are packed after every step, so
a run stopped at its limit still returns what it measured.

    python benchmarks/device_suite.py --out DIR [--budget 480] [--quick]

Steps, in order of what the performance issue asks of a GPU:
  device       nvidia-smi -L, jax.devices() with the device's model, versions
  tests        the transfer forms (optimised = straightforward, values and gradients, 1D/2D/3D and
               axisymmetric) and the conservation tests, on the device (pytest -x)
  throughput3  the peers' scene in 3D at 128^3 (524,288 peer particles): jaxmpm APIC, linear, DDMP
               against the naive JAX peer on the same device (target: >= 1000 Mpart-steps/s)
  throughput2  the same in 2D at 128^2
  apic3        the APIC step's three transfer forms in 3D (which one a GPU should take)
  multifield   a 3-field DDMP step against one field (target: <= 2x)
  grad         the debris cloud's gradient at 100 and 300 steps, "steps" and "nested"
DIR gets two files: suite.log (every step's command, output tail, status and seconds) and
results.tar.gz (each step's CSV and PNG, under results/; `python benchmarks/throughput.py --replot`
redraws a table). --quick runs every step at toy sizes: a dry run of the script on a CPU.
The peer scripts are read from --peers (default ../shared/bench/peers).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent


def steps(out: Path, quick: bool, peers: str):
    """(name, command, time limit s) of each step, writing their tables under out; commands run in
    the repository's root."""
    py = sys.executable
    r = out
    if quick:
        return [
            ("device", [py, "-c", DEVICE_REPORT], 60),
            ("tests", [py, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "tests/test_transfer_forms.py",
                       "-k", "add_corners_equals or offset_transfers_equal"], 300),
            ("throughput3", [py, "benchmarks/throughput.py", "--dim", "3", "--n-grid", "16", "--steps", "5", "--repeats", "1",
                             "--configs", "jaxmpm,jax-naive", "--peers", peers, "--out", str(r / "throughput_3d.csv")], 300),
            ("throughput2", [py, "benchmarks/throughput.py", "--n-grid", "32", "--steps", "5", "--repeats", "1",
                             "--configs", "jaxmpm,jax-naive", "--peers", peers, "--out", str(r / "throughput.csv")], 300),
            ("apic3", [py, "benchmarks/apic_transfer.py", "--dim", "3", "--n-grid", "12", "--steps", "2", "--repeats", "1",
                       "--out", str(r / "apic_transfer_3d.csv")], 300),
            ("multifield", [py, "benchmarks/multifield_cost.py", "--n-grid", "32", "--steps", "3", "--repeats", "1",
                            "--out", str(r / "multifield_cost.csv")], 300),
            ("grad", [py, "benchmarks/grad_cost.py", "--steps", "10", "--modes", "steps", "--out", str(r)], 300),
        ]
    return [
        ("device", [py, "-c", DEVICE_REPORT], 60),
        ("tests", [py, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "tests/test_transfer_forms.py",
                   "tests/test_conservation.py"], 150),
        ("throughput3", [py, "benchmarks/throughput.py", "--dim", "3", "--n-grid", "128", "--steps", "100", "--repeats", "3",
                         "--configs", "jaxmpm,jaxmpm-linear-musl,jaxmpm-ddmp-musl,jax-naive", "--peers", peers,
                         "--out", str(r / "throughput_3d_128.csv")], 150),
        ("throughput2", [py, "benchmarks/throughput.py", "--configs", "jaxmpm,jaxmpm-linear-musl,jaxmpm-ddmp-musl,jax-naive",
                         "--peers", peers, "--out", str(r / "throughput.csv")], 90),
        ("apic3", [py, "benchmarks/apic_transfer.py", "--dim", "3", "--out", str(r / "apic_transfer_3d.csv")], 60),
        ("multifield", [py, "benchmarks/multifield_cost.py", "--repeats", "3", "--out", str(r / "multifield_cost.csv")], 60),
        ("grad", [py, "benchmarks/grad_cost.py", "--steps", "100,300", "--modes", "steps,nested", "--out", str(r)], 90),
    ]


DEVICE_REPORT = """
import platform, subprocess, jax
try:
    print(subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=20).stdout.strip())
except (OSError, subprocess.TimeoutExpired) as e:
    print("nvidia-smi:", e)
print("python", platform.python_version(), "jax", jax.__version__, "backend", jax.default_backend())
for d in jax.devices():
    print(d, d.platform, d.device_kind)
"""


def pack(results: Path, out: Path):
    """out/results.tar.gz of the tables under results (rewritten after each step)."""
    with tarfile.open(out / "results.tar.gz.part", "w:gz") as tar:
        tar.add(results, arcname="results")
    os.replace(out / "results.tar.gz.part", out / "results.tar.gz")


def main(argv=None):
    ap = argparse.ArgumentParser(description=" ".join(__doc__.split("\n\n")[0].split()))
    ap.add_argument("--out", required=True, help="folder for suite.log and results.tar.gz (created; must hold no "
                    "suite.log yet)")
    ap.add_argument("--budget", type=float, default=480.0, help="seconds for all steps together (default 480)")
    ap.add_argument("--quick", action="store_true", help="toy sizes: a dry run of this script")
    ap.add_argument("--peers", default=str(ROOT.parent / "shared" / "bench" / "peers"))
    ap.add_argument("--only", default=None, help="comma-separated step names to run (default: all)")
    a = ap.parse_args(argv)
    if a.budget <= 0:
        ap.error(f"--budget {a.budget} is invalid: allowed seconds > 0")
    out = Path(a.out)
    if (out / "suite.log").exists():
        ap.error(f"--out {out} is invalid: it already holds a suite.log (allowed: a new or empty folder)")
    out.mkdir(parents=True, exist_ok=True)
    results = Path(tempfile.mkdtemp(prefix="device_suite_"))   # packed into out: a few files travel back, not many
    plan = steps(results, a.quick, a.peers)
    if a.only:
        names = {n.strip() for n in a.only.split(",")}
        unknown = sorted(names - {s[0] for s in plan})
        if unknown:
            ap.error(f"--only {','.join(unknown)} is invalid: allowed {', '.join(s[0] for s in plan)}")
        plan = [s for s in plan if s[0] in names]
    start = time.perf_counter()
    env = dict(os.environ, PYTHONUNBUFFERED="1", PYTHONPATH=os.pathsep.join([str(ROOT)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    with open(out / "suite.log", "w") as log:
        def say(text):
            print(text, flush=True)
            log.write(text + "\n")
            log.flush()

        say(f"device_suite: budget {a.budget:.0f} s{' (quick)' if a.quick else ''}, steps {', '.join(s[0] for s in plan)}")
        for name, cmd, limit in plan:
            left = a.budget - (time.perf_counter() - start)
            if left < min(limit, 30):
                say(f"\n== {name}: SKIPPED, {left:.0f} s of the budget left (its limit {limit} s)")
                continue
            limit = min(limit, left)
            say(f"\n== {name} (limit {limit:.0f} s): {' '.join(cmd)}")
            t0 = time.perf_counter()
            try:
                p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=limit)
                status, text = f"rc {p.returncode}", p.stdout + p.stderr
            except subprocess.TimeoutExpired as e:
                status = f"TIMED OUT after {limit:.0f} s"
                text = "".join(x.decode() if isinstance(x, bytes) else (x or "") for x in (e.stdout, e.stderr))
            say("\n".join(text.strip().splitlines()[-40:]))
            say(f"== {name}: {status}, {time.perf_counter() - t0:.0f} s")
            pack(results, out)
        say(f"\ndevice_suite: done in {time.perf_counter() - start:.0f} s; {out / 'results.tar.gz'}")


if __name__ == "__main__":
    main()
