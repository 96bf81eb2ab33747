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
second waits on a file lock.

The cache folder is ``$REACH_JIT_CACHE``, else ``$XDG_CACHE_HOME/reach/jit``,
else ``~/.cache/reach/jit``. Deleting it is always safe.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

import casadi as ca

# Each compile is said (at INFO) before it starts and when it ends: a first build or query compiles for minutes and,
# silent, looked hung. The command line prints these on standard error.
LOG = logging.getLogger("reach.jit")
COMPILER = "gcc"  # the C compiler
FLAGS = ("-O1", "-fPIC", "-shared")  # -O1: most of -O2's speed at a third of its compile time here


def cache_folder() -> Path:
    """Where compiled programs are kept (see the module docstring)."""
    if os.environ.get("REACH_JIT_CACHE"):
        return Path(os.environ["REACH_JIT_CACHE"])
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "reach" / "jit"


def compiled_nlpsol(name: str, solver: str, nlp: dict[str, Any], opts: dict[str, Any]) -> ca.Function:
    """``ca.nlpsol(name, solver, nlp, opts)`` with its functions compiled, from the cache when there.

    Raises:
        RuntimeError: the compiler failed or is missing (its message last).
    """
    parts = [k for k in ("x", "p", "f", "g") if k in nlp]
    graph = ca.Function(f"{name}_graph", [nlp[k] for k in parts if k in ("x", "p")],
                        [nlp[k] for k in parts if k in ("f", "g")]).serialize()
    identity = f"{graph}|{solver}|{sorted(opts.items())!r}|{parts}"
    library = _library(name, lambda file: ca.nlpsol(name, solver, nlp, opts).generate_dependencies(file), identity)
    return ca.nlpsol(name, solver, str(library), opts)


def compiled_function(name: str, function: ca.Function) -> ca.Function:
    """A CasADi function compiled to machine code (``oracles.ik.batch``'s mapped kinematics), from the cache when there.

    Raises:
        RuntimeError: the compiler failed or is missing (its message last).
    """
    library = _library(name, lambda file: function.generate(file), function.serialize())
    return ca.external(function.name(), str(library))


def _library(name: str, generate: Any, identity: str) -> Path:
    """The shared library compiled from the C that ``generate(file name)`` writes, kept in the cache folder under the
    hash of ``identity`` (what determines the C); the C is written only when the library is not there."""
    key = hashlib.sha256(f"{identity}|{ca.CasadiMeta.version()}|{' '.join((COMPILER, *FLAGS))}".encode()).hexdigest()
    folder = cache_folder()
    folder.mkdir(parents=True, exist_ok=True)
    library = folder / f"{name}-{key[:24]}.so"
    if library.exists():
        return library
    with tempfile.TemporaryDirectory(prefix="reach-jit-") as scratch:
        source = Path(scratch) / f"{name}.c"
        with open(folder / f"{library.name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # one process compiles; the others wait and load
            if not library.exists():
                LOG.info("compiling %s to machine code (once: kept in %s)", name, folder)
                t0 = time.perf_counter()
                # CasADi writes into the working directory.
                home = os.getcwd()
                os.chdir(scratch)
                try:
                    generate(source.name)
                finally:
                    os.chdir(home)
                built = Path(scratch) / library.name
                try:
                    subprocess.run([COMPILER, *FLAGS, str(source), "-o", str(built)], check=True,
                                   capture_output=True, text=True)
                except FileNotFoundError as exc:
                    raise RuntimeError(f"{COMPILER} not found") from exc
                except subprocess.CalledProcessError as exc:
                    raise RuntimeError(f"{COMPILER} failed on {name}: {exc.stderr.strip()[-500:]}") from exc
                os.replace(built, library)  # atomic: a reader sees the whole library or none
                LOG.info("compiled %s in %.0f s", name, time.perf_counter() - t0)
    return library
