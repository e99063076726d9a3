"""The build backend: setuptools, plus the compiled core where it can be built.

A wheel (`pip install .`, `pip wheel .`, `python -m build`) compiles the firmware
model's hot modules (setup.py, NATIVE_MODULES) with mypyc into C extensions; the same
.py files stay beside them as the pure-Python fallback, and `robox.native.describe()`
tells which one runs. `ROBOX_NATIVE` in the environment chooses:

- unset (or `auto`): compiled when it can be; with no C compiler, or when compiling
  fails, the wheel is pure Python and one line on stderr says why;
- `1`: compiled or nothing (a failure to compile fails the build);
- `0`: pure Python.

A compiled build takes minutes (about 3 of CPU on a current x86-64 core). pip's `-q`
hides what a backend prints, so its stages and a line every 30 s go to the terminal
(/dev/tty) where there is one, else to stderr (`pip install -v` shows them).

An editable install (`pip install -e .`) is always pure Python: compiled modules would
shadow later edits of the sources. Each kind of build keeps its own build directory
(build/native, build/pure), so a pure wheel never picks up an extension a compiled
build left behind.
"""

from __future__ import annotations

import contextlib
import os
import shlex
import shutil
import sys
import sysconfig
import tempfile
import threading
import time

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F403  (the standard hooks, unchanged)
from setuptools.command.build_ext import build_ext
from setuptools.errors import CompileError

MYPYC = "mypy[mypyc]>=2.4"  # librt.vecs (src/robox/packed.py)
CHOICE = "ROBOX_NATIVE"
BUILD = "ROBOX_BUILD_KIND"  # what setup.py builds: "native" or "pure" (set here only)


def _choice() -> str:
    value = os.environ.get(CHOICE, "auto").strip().lower() or "auto"
    if value not in ("auto", "0", "1"):
        raise SystemExit(f"robox: {CHOICE} must be 1, 0 or auto, not {value!r}")
    return value


def _say(text: str) -> None:
    print(f"robox: {text}", file=sys.stderr)


def _terminal():
    """Where progress goes: the terminal, which pip's -q does not silence, else stderr."""
    try:
        return open("/dev/tty", "w", encoding="utf-8")
    except OSError:
        return None


def _minutes(seconds: float) -> str:
    return f"{seconds / 60:.0f} min {seconds % 60:.0f} s" if seconds >= 60 else \
        f"{seconds:.0f} s"


@contextlib.contextmanager
def stage(text: str, tick_s: float = 30.0):
    """Say that a long build step began, that it still runs every `tick_s` and when it
    ended (the build's own process: a thread here waits, it does no work)."""
    tty = _terminal()
    out = tty or sys.stderr
    started = time.monotonic()

    def say(line: str) -> None:  # ("robox build:", apart from the one-line "robox:" notes)
        with contextlib.suppress(OSError, ValueError):
            print(f"robox build: {line}", file=out, flush=True)

    say(f"{text} ...")
    done = threading.Event()

    def ticking() -> None:
        while not done.wait(tick_s):
            say(f"{text}: {_minutes(time.monotonic() - started)} so far")

    ticker = threading.Thread(target=ticking, daemon=True)
    ticker.start()
    try:
        yield
    finally:
        done.set()
        ticker.join()
        say(f"{text}: done in {_minutes(time.monotonic() - started)}")
        if tty is not None:
            tty.close()


# The compiled core is one large C file whose functions call each other at every step.
# By default a shared library's functions may be replaced by another library's of the
# same name at load time, so the compiler neither inlines one into another nor calls it
# directly: these let it (Python finds a module by its exported PyInit_ function alone,
# which Python's headers keep visible). They change no arithmetic: no FMA, no fast math.
SPEED_FLAGS = ["-fno-semantic-interposition", "-fvisibility=hidden", "-fno-plt"]

# Compiled functions whose whole work is what one C expression does and mypyc cannot
# write: the build gives them that expression as their body, in a copy of the C mypyc
# wrote (where the definition is not found, mypyc's compiled Python body stays, and a
# line says so). carith.f32, a double rounded to a C float, runs a dozen times a move;
# C's conversion is one instruction that rounds as the printer's soft floats do (to
# nearest, ties to even, overflow to an infinity).
C_BODIES = {
    "double CPyDef_carith___f32(double cpy_r_value)": "return (double)(float)cpy_r_value;",
}


def replace_bodies(text: str, bodies: dict[str, str]) -> tuple[str, list[str]]:
    """`text` (C as mypyc writes it: a definition's signature and `{` on one line, its
    closing `}` alone at the start of a line) with the body of each function whose
    signature `bodies` names replaced by the one given; and the signatures not found."""
    missing = []
    for signature, body in bodies.items():
        start = text.find(f"\n{signature} {{\n")
        end = text.find("\n}\n", start) if start >= 0 else -1
        if end < 0:
            missing.append(signature)
            continue
        opened = start + len(signature) + 3  # past "\n", the signature and " {"
        text = f"{text[:opened]}\n    {body}{text[end:]}"
    return text, missing


class BuildExt(build_ext):
    """setup.py's build_ext: its stage on the terminal, and SPEED_FLAGS where the
    compiler takes them."""

    def run(self):
        if not self.extensions:
            return super().run()
        with stage("compiled core 2/2: compiling the C (the long part)"):
            return super().run()

    def build_extensions(self):
        flags = [flag for flag in SPEED_FLAGS if self._takes(flag)]
        missing = set(C_BODIES)
        for ext in self.extensions:
            ext.sources = [self._with_bodies(source, missing) for source in ext.sources]
            ext.extra_compile_args = [*ext.extra_compile_args, *flags]
        for signature in sorted(missing):
            _say(f"kept mypyc's own body for {signature.split('(')[0].split()[-1]} (its "
                 "definition was not found as expected in the C mypyc wrote)")
        super().build_extensions()

    @staticmethod
    def _with_bodies(source: str, missing: set[str]) -> str:
        """The C file to compile for `source`: itself, or where it defines a function of
        C_BODIES a copy beside it with C_BODIES' bodies (written only when it changes, so
        an unchanged core is not compiled again). Signatures found leave `missing`."""
        if not source.endswith(".c"):
            return source
        with open(source, encoding="utf-8") as f:
            text = f.read()
        changed, absent = replace_bodies(text, C_BODIES)
        missing.intersection_update(absent)
        if changed == text:
            return source
        copy = source[:-2] + "-bodies.c"
        try:
            with open(copy, encoding="utf-8") as f:
                current = f.read()
        except OSError:
            current = None
        if current != changed:
            with open(copy, "w", encoding="utf-8") as f:
                f.write(changed)
        return copy

    def _takes(self, flag: str) -> bool:
        """Whether this build's compiler accepts `flag` without a warning."""
        if self.compiler.compiler_type != "unix":
            return False
        with tempfile.TemporaryDirectory() as scratch:
            probe = os.path.join(scratch, "probe.c")
            with open(probe, "w") as f:
                f.write("int probe(void) { return 0; }\n")
            try:
                self.compiler.compile([probe], output_dir=scratch,
                                      extra_postargs=[flag, "-Werror"])
            except CompileError:
                return False
        return True


def compiler() -> str | None:
    """The C compiler a build would run (CC, as setuptools takes it), if it exists."""
    command = os.environ.get("CC") or sysconfig.get_config_var("CC") or "cc"
    words = shlex.split(command)
    return shutil.which(words[0]) if words else None


@contextlib.contextmanager
def _kind(kind: str):
    """ROBOX_BUILD_KIND set to `kind` for the duration of a build step."""
    before = os.environ.get(BUILD)
    os.environ[BUILD] = kind
    try:
        yield
    finally:
        if before is None:
            os.environ.pop(BUILD, None)
        else:
            os.environ[BUILD] = before


def get_requires_for_build_wheel(config_settings=None):
    with _kind("pure"):  # setuptools runs setup.py to list what it needs: without mypyc
        needed = list(_setuptools.get_requires_for_build_wheel(config_settings))
    choice = _choice()
    if choice == "1" or (choice == "auto" and compiler() is not None):
        needed.append(MYPYC)
    return needed


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    choice = _choice()
    if choice == "0":
        return _pure(wheel_directory, config_settings, metadata_directory)
    if choice == "auto" and compiler() is None:
        _say("no C compiler found (CC); building the pure-Python package (ROBOX_NATIVE=1 "
             "tries the compiled core all the same)")
        return _pure(wheel_directory, config_settings, metadata_directory)
    try:
        with _kind("native"):
            return _setuptools.build_wheel(wheel_directory, config_settings,
                                           metadata_directory)
    except (Exception, SystemExit) as error:
        if choice == "1":
            raise
        _say(f"the compiled core did not build ({_reason(error)}); building the pure-Python "
             "package")
        return _pure(wheel_directory, config_settings, metadata_directory)


def _reason(error: BaseException) -> str:
    """The last line of what went wrong, at most 200 characters (a failed compiler
    command names every flag)."""
    lines = str(error).strip().splitlines()
    text = lines[-1] if lines else type(error).__name__
    return text if len(text) <= 200 else text[:197] + "..."


def _pure(wheel_directory, config_settings, metadata_directory):
    with _kind("pure"):
        return _setuptools.build_wheel(wheel_directory, config_settings, metadata_directory)


def get_requires_for_build_editable(config_settings=None):
    with _kind("pure"):
        return _setuptools.get_requires_for_build_editable(config_settings)


def build_editable(wheel_directory, config_settings=None, metadata_directory=None):
    if _choice() == "1":
        _say(f"{CHOICE}=1 is ignored for an editable install (compiled modules would hide "
             "later edits of the sources); building pure Python")
    with _kind("pure"):
        return _setuptools.build_editable(wheel_directory, config_settings, metadata_directory)


def prepare_metadata_for_build_wheel(metadata_directory, config_settings=None):
    with _kind("pure"):
        return _setuptools.prepare_metadata_for_build_wheel(metadata_directory, config_settings)


def prepare_metadata_for_build_editable(metadata_directory, config_settings=None):
    with _kind("pure"):
        return _setuptools.prepare_metadata_for_build_editable(metadata_directory,
                                                               config_settings)


def build_sdist(sdist_directory, config_settings=None):
    with _kind("pure"):
        return _setuptools.build_sdist(sdist_directory, config_settings)
