"""Compiled nonlinear programs, cached on disk by the hash of their expression graph.

CasADi's own jit compiles a program's functions each time a solver is made:
once per worker process, strategy and stage in a build (0.3-4 s each with
gcc -O1), and again in every later build, test or server. Here the program's
functions are written as C (``generate_dependencies``), and the shared
library compiled from them is kept under the cache folder, named by the
SHA-256 of the program's serialised expression graph (CasADi's
``serialize``, from which the C is generated), the solver and its options,
CasADi's version and the compiler flags; any process that asks for the same
program loads it (``nlpsol`` from a library) without generating its C again
(writing the C to hash it cost a fresh ``reach query`` 3.2 s of its 7 s).
Two processes that need the same missing library compile it once: the
second waits on a file lock. Programs asked for together (a solver's
stages, a batched program's functions) are compiled by several compilers
at once (``$REACH_JIT_JOBS``, else one a processor), each said with how many
are done and about how long is left.

The cache folder is ``$REACH_JIT_CACHE``, else ``$XDG_CACHE_HOME/reach/jit``,
else ``~/.cache/reach/jit``. Deleting it is always safe. Its ``compiles.log`` says
what was compiled, when, how long it took and by which command.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import fcntl
import hashlib
import logging
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca

# Each compile is said (at INFO) before it starts and when it ends: a first build or query compiles for minutes and,
# silent, looked hung. The command line prints these on standard error.
LOG = logging.getLogger("reach.jit")
COMPILER = "gcc"  # the C compiler
FLAGS = ("-O1", "-fPIC", "-shared")  # -O1: most of -O2's speed at a third of its compile time here
LOG_FILE = "compiles.log"  # in the cache folder: a line a compile (see _logged)


def cache_folder() -> Path:
    """Where compiled programs are kept (see the module docstring)."""
    if os.environ.get("REACH_JIT_CACHE"):
        return Path(os.environ["REACH_JIT_CACHE"])
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "reach" / "jit"


def compiled_nlpsols(solver: str, programs: Sequence[tuple[str, dict[str, Any], dict[str, Any]]]) -> list[ca.Function]:
    """``ca.nlpsol(name, solver, nlp, opts)`` for each ``(name, nlp, opts)``, their functions compiled together (see
    :func:`libraries`), each from the cache when there.

    Raises:
        RuntimeError: the compiler failed or is missing (its message last).
    """
    jobs = []
    for name, nlp, opts in programs:
        parts = [k for k in ("x", "p", "f", "g") if k in nlp]
        graph = ca.Function(f"{name}_graph", [nlp[k] for k in parts if k in ("x", "p")],
                            [nlp[k] for k in parts if k in ("f", "g")]).serialize()

        def generate(file: str, name: str = name, nlp: dict[str, Any] = nlp, opts: dict[str, Any] = opts) -> None:
            ca.nlpsol(name, solver, nlp, opts).generate_dependencies(file)

        jobs.append(Job(name, generate, f"{graph}|{solver}|{sorted(opts.items())!r}|{parts}"))
    return [ca.nlpsol(name, solver, str(library), opts)
            for (name, _, opts), library in zip(programs, libraries(jobs), strict=True)]


def compiled_functions(functions: Sequence[ca.Function]) -> list[ca.Function]:
    """CasADi functions compiled to machine code together (``oracles.ik.batch``'s mapped kinematics), each from the
    cache when there.

    Raises:
        RuntimeError: the compiler failed or is missing (its message last).
    """
    def writer(f: ca.Function) -> Callable[[str], Any]:
        return lambda file: f.generate(file)

    jobs = [Job(f.name(), writer(f), f.serialize()) for f in functions]
    return [ca.external(f.name(), str(library)) for f, library in zip(functions, libraries(jobs), strict=True)]


@dataclass(frozen=True)
class Job:
    """One program to compile: its ``name``, what writes its C (``generate(file name)``, in the working directory)
    and what determines that C (``identity``: the cache's key)."""

    name: str
    generate: Callable[[str], Any]
    identity: str


def compilers() -> int:
    """How many compilers run at once: ``$REACH_JIT_JOBS``, else the processors this process may use."""
    raw = os.environ.get("REACH_JIT_JOBS", "")
    if raw.strip():
        try:
            return max(1, int(raw))
        except ValueError as exc:
            raise RuntimeError(f"REACH_JIT_JOBS: expected a whole number of compilers, got {raw!r}") from exc
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def libraries(jobs: Sequence[Job]) -> list[Path]:
    """Each job's shared library in the cache folder, named by the hash of its identity; the missing ones compiled,
    their C written one at a time and the compiler run on ``compilers()`` of them at once (the compiler is 96 % of a
    compile: 79 of 82 s for the whole body's programs here), each compile said with how many are left and about how
    long. Two processes that need the same missing library compile it once: the second waits on its lock (the locks
    taken in the libraries' order, so that two batches never deadlock)."""
    folder = cache_folder()
    folder.mkdir(parents=True, exist_ok=True)
    version = f"{ca.CasadiMeta.version()}|{' '.join((COMPILER, *FLAGS))}"
    paths = [folder / f"{job.name}-{hashlib.sha256(f'{job.identity}|{version}'.encode()).hexdigest()[:24]}.so"
             for job in jobs]
    missing = sorted({path: job for path, job in zip(paths, jobs, strict=True) if not path.exists()}.items())
    if not missing:
        return paths
    with contextlib.ExitStack() as stack:
        for path, _ in missing:
            lock = stack.enter_context(open(folder / f"{path.name}.lock", "w"))
            fcntl.flock(lock, fcntl.LOCK_EX)  # one process compiles; the others wait and load
        todo = [(path, job) for path, job in missing if not path.exists()]
        if todo:
            _compile(todo, folder, stack.enter_context(tempfile.TemporaryDirectory(prefix="reach-jit-")))
    return paths


def _compile(todo: list[tuple[Path, Job]], folder: Path, scratch: str) -> None:
    """The C of each job written in ``scratch``, then compiled into its library, ``compilers()`` at a time."""
    workers = min(compilers(), len(todo))
    if len(todo) == 1:
        LOG.info("compiling %s to machine code (once: kept in %s)", todo[0][1].name, folder)
    else:
        LOG.info("compiling %d programs (%s ... %s) to machine code, %d at a time (once: kept in %s)", len(todo),
                 todo[0][1].name, todo[-1][1].name, workers, folder)
    t0 = time.perf_counter()
    sources = []
    home = os.getcwd()
    try:
        for k, (_, job) in enumerate(todo):
            # CasADi writes into the working directory, and names the C's symbols after the file: one folder a job
            sources.append(Path(scratch) / str(k) / f"{job.name}.c")
            sources[-1].parent.mkdir()
            os.chdir(sources[-1].parent)
            job.generate(sources[-1].name)
    finally:
        os.chdir(home)
    with concurrent.futures.ThreadPoolExecutor(workers) as pool:
        running = {pool.submit(_gcc, source, path, job.name): (job.name, path.stem)
                   for source, (path, job) in zip(sources, todo, strict=True)}
        for done, future in enumerate(concurrent.futures.as_completed(running), start=1):
            seconds = future.result()
            name, library = running[future]
            _logged(folder, library, seconds)
            elapsed = time.perf_counter() - t0
            if len(todo) == 1:
                LOG.info("compiled %s in %.0f s", name, seconds)
            elif done < len(todo):
                LOG.info("compiled %s in %.0f s (%d of %d; about %.0f s left)", name, seconds, done, len(todo),
                         elapsed / done * (len(todo) - done))
            else:
                LOG.info("compiled %s in %.0f s (%d of %d; all in %.0f s)", name, seconds, done, len(todo), elapsed)


def _logged(folder: Path, library: str, seconds: float) -> None:
    """One line of the cache's ``compiles.log`` (UTC time, seconds, the library's name, process, command): what each
    command compiled, so that a program compiled twice shows."""
    stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    command = " ".join(Path(sys.argv[0]).name if k == 0 else a for k, a in enumerate(sys.argv[:3]))
    with open(folder / LOG_FILE, "a") as log:
        log.write(f"{stamp}\t{seconds:.1f}\t{library}\t{os.getpid()}\t{command}\n")


def _gcc(source: Path, library: Path, name: str) -> float:
    """One library compiled from its C and moved into the cache atomically (a reader sees all of it or none); the
    seconds it took."""
    t0 = time.perf_counter()
    built = source.parent / library.name
    try:
        subprocess.run([COMPILER, *FLAGS, str(source), "-o", str(built)], check=True, capture_output=True, text=True)
    except FileNotFoundError as exc:
        raise RuntimeError(f"{COMPILER} not found") from exc
    except subprocess.CalledProcessError as exc:
        raise RuntimeError(f"{COMPILER} failed on {name}: {exc.stderr.strip()[-500:]}") from exc
    os.replace(built, library)
    return time.perf_counter() - t0
