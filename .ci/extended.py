"""CI's second step: every test marked `extended`, each test file in a fresh Python process.

The extended tests compile many large XLA programs. In one long-lived process (a pytest-xdist
worker) XLA's CPU compiler has crashed late in the step (SIGSEGV in `backend_compile_and_load`),
which takes every test left on that worker with it. A process per file bounds what one process
compiles and confines a crash to the file it happened in, which fails with its output shown.

Two files run at a time (CI's two cores). Each file's output is printed whole when it ends, then a
table of files, outcomes and durations. The exit status is 0 only when every file passed.
"""

import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor, as_completed

PYTEST = [sys.executable, "-m", "pytest", "--extended", "-m", "extended"]
PARALLEL = int(os.environ.get("JAXROBOT_EXTENDED_PARALLEL", "2"))


def extended_files() -> list[str]:
    """The test files that hold at least one test marked `extended`, in collection order."""
    listing = subprocess.run(PYTEST + ["-n", "0", "-q", "--collect-only"], capture_output=True, text=True)
    if listing.returncode != 0:
        sys.stdout.write(listing.stdout + listing.stderr)
        raise SystemExit(f"collecting the extended tests failed (exit {listing.returncode})")
    files = []
    for line in listing.stdout.splitlines():
        if "::" in line:
            name = line.split("::", 1)[0]
            if name not in files:
                files.append(name)
    if not files:
        raise SystemExit("no test is marked extended: the collection found none")
    return files


def run_file(name: str) -> tuple[str, int, float, str]:
    start = time.perf_counter()
    result = subprocess.run(PYTEST + ["-n", "0", name], capture_output=True, text=True)
    return name, result.returncode, time.perf_counter() - start, result.stdout + result.stderr


def outcome(returncode: int) -> str:
    if returncode == 0:
        return "passed"
    if returncode < 0:
        return f"crashed ({signal.Signals(-returncode).name})"
    return f"failed (exit {returncode})"


def main() -> int:
    files = extended_files()
    print(f"extended: {len(files)} files, {PARALLEL} at a time, each in its own process", flush=True)
    rows = []
    with ThreadPoolExecutor(PARALLEL) as pool:
        for future in as_completed([pool.submit(run_file, name) for name in files]):
            name, returncode, seconds, output = future.result()
            rows.append((name, returncode, seconds))
            print(f"\n===== {name}: {outcome(returncode)} in {seconds:.0f} s =====\n{output}", flush=True)
    print("\n| file | outcome | s |\n|---|---|---|")
    for name, returncode, seconds in sorted(rows):
        print(f"| {name} | {outcome(returncode)} | {seconds:.0f} |")
    failed = [name for name, returncode, _ in rows if returncode != 0]
    print(f"\nextended: {len(rows) - len(failed)} of {len(rows)} files passed"
          + (f"; failed: {' '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
